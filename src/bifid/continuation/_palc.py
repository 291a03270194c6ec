"""Pseudo-arclength continuation of a zero problem ``G(y) = 0``, ``G: R^{N+1} -> R^N``.

Written by hand because no maintained JAX library offers predictor–corrector
continuation with fold location, adaptive steps, bounds and a pluggable corrector that
we could compose with our own collocation Jacobians *and* with measured residuals of a
rig (``jaxcont`` is benchmarked against this in BENCHMARKS.md). The numerical kernels —
Newton corrector and tangent — are jitted once per problem and reused for every step.

Predictor–corrector (Keller), one step at a time (:class:`Continuation`):

* tangent ``t`` solves ``[G_y(y); (W t_prev)^T] t = [0; 1]``, normalised in the
  weighted norm ``||t||_W = sqrt(t^T W t)``;
* predictor ``y_p = y + ds d`` along the tangent (or the secant of the last two points);
* corrector: ``[G(y); (W d)^T (y - y_p)] = 0`` solved by an :class:`AbstractCorrector` —
  Newton with the exact Jacobian for models (:class:`NewtonCorrector`), Broyden on a
  measured residual for rigs (``bifid.cbc``).

The driver's whole state between steps is a :class:`ContinuationState` of plain arrays,
so a run can be stored point by point and resumed exactly. Folds (limit points of the
parameter) are detected as sign changes of the parameter component of the tangent and
located by a secant (Illinois) search on the arclength ``s`` of the zero of that
component; branch points are flagged by a sign change of ``det [G_y; t^T]``.
"""

from __future__ import annotations

import abc
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits

from bifid.continuation._options import ContinuationOptions
from bifid.errors import BifidInputError

Array = jnp.ndarray
Residual = Callable[[Array, Any], Array]
Jacobian = Callable[[Array, Any], Array]


@dataclass(frozen=True, eq=False)
class ZeroProblem:
    """A zero problem for continuation.

    Parameters
    ----------
    residual : callable ``(y, args) -> (N,)``
        Pure JAX function of the unknowns ``y`` of shape ``(N+1,)`` and a pytree
        ``args`` of arrays (changing ``args`` never triggers a re-compilation).
    param_index : int
        Component of ``y`` that is the continuation parameter.
    jacobian : callable ``(y, args) -> (N, N+1)``, optional
        Jacobian of ``residual``; defaults to ``jax.jacfwd``.
    """

    residual: Residual
    param_index: int = -1
    jacobian: Jacobian | None = None

    def __hash__(self) -> int:
        return hash((self.residual, self.param_index, self.jacobian))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ZeroProblem) and (
            (self.residual, self.param_index, self.jacobian)
            == (other.residual, other.param_index, other.jacobian)
        )


@dataclass
class PalcResult:
    """Raw output of :func:`palc`."""

    ys: np.ndarray
    tangents: np.ndarray
    iterations: np.ndarray
    folds: list[tuple[int, np.ndarray, float]] = field(default_factory=list)
    branch_points: list[int] = field(default_factory=list)
    status: str = "completed"  # one of bifid.continuation.END_REASONS
    message: str = ""
    args: Any = None


@functools.lru_cache(maxsize=128)
def _evaluator(problem: ZeroProblem) -> Callable:
    """Jitted ``(y, args) -> (G(y), G_y(y))``, compiled once per problem."""
    J = problem.jacobian if problem.jacobian is not None else jax.jacfwd(problem.residual)

    @jax.jit
    def both(y: Array, args: Any):
        return problem.residual(y, args), J(y, args)

    return both


def _factor(Jm: np.ndarray, row: np.ndarray):
    A = np.vstack([Jm, row[None, :]])
    with np.errstate(all="ignore"):
        lu, piv = scipy.linalg.lu_factor(A, check_finite=False)
    return lu, piv


def _det_sign(lu: np.ndarray, piv: np.ndarray) -> float:
    swaps = np.count_nonzero(piv != np.arange(piv.shape[0]))
    return float((-1) ** swaps * np.prod(np.sign(np.diag(lu))))


@dataclass
class Correction:
    """Outcome of one corrector call.

    Attributes
    ----------
    y : ndarray
        The corrected point (or the last iterate when not converged).
    converged : bool
    iterations : int
        Corrector iterations (for a measured problem: rig evaluations).
    residual : float
        Max-norm of ``G`` at ``y``.
    info : dict
        Anything the corrector wants recorded with the point (e.g. the measurement).
    """

    y: np.ndarray
    converged: bool
    iterations: int
    residual: float
    info: dict[str, Any] = field(default_factory=dict)


class AbstractCorrector(abc.ABC):
    """Solves the extended system ``[G(y); row . y - c] = 0`` near a prediction and
    gives the tangent of the solution curve.

    The predictor–corrector driver (:class:`Continuation`) only talks to a corrector, so
    the same driver follows a model's branch with Newton and exact Jacobians
    (:class:`NewtonCorrector`) and a rig's branch with a Broyden / secant corrector on a
    measured residual (``bifid.cbc``). A corrector may keep state between calls (a
    Jacobian estimate); :meth:`state` / :meth:`restore` make it persistable so that an
    interrupted run continues exactly where it stopped.
    """

    @abc.abstractmethod
    def correct(self, y_pred: np.ndarray, row: np.ndarray, c: float, args: Any) -> Correction:
        """Correct ``y_pred`` onto ``G(y) = 0`` with ``row . y = c``."""

    @abc.abstractmethod
    def tangent(self, y: np.ndarray, t_prev: np.ndarray, weights: np.ndarray,
                args: Any) -> tuple[np.ndarray, float]:
        """Unit tangent at ``y`` (``||t||_W = 1``, ``(W t_prev) . t > 0``) and the sign of
        ``det [G_y; (W t_prev)^T]`` (NaN when unknown)."""

    def accept(self, correction: Correction) -> None:  # noqa: B027 - optional hook
        """Called when the driver accepts ``correction`` as the next point."""

    def state(self) -> dict[str, np.ndarray]:
        """Arrays that :meth:`restore` needs to continue exactly (default: none)."""
        return {}

    def restore(self, state: dict[str, np.ndarray]) -> None:  # noqa: B027 - optional hook
        """Inverse of :meth:`state`."""


class NewtonCorrector(AbstractCorrector):
    """Newton's method with the exact Jacobian of a :class:`ZeroProblem`.

    The residual and Jacobian are jitted once per problem; the dense linear algebra runs
    in SciPy (LAPACK LU), which for the few-hundred-unknown systems of collocation is
    several times faster on CPU than inside XLA.
    """

    def __init__(self, problem: ZeroProblem, *, tol: float = 1e-10, max_iter: int = 10) -> None:
        self.problem = problem
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self._both = _evaluator(problem)

    def evaluate(self, y: np.ndarray, args: Any) -> tuple[np.ndarray, np.ndarray]:
        """``G(y)`` and ``G_y(y)`` as NumPy arrays."""
        G, Jm = self._both(y, args)
        return np.asarray(G), np.asarray(Jm)

    def correct(self, y_pred: np.ndarray, row: np.ndarray, c: float, args: Any) -> Correction:
        y = np.asarray(y_pred, dtype=float).copy()
        row = np.asarray(row, dtype=float)
        err = np.inf
        it = 0
        while it < self.max_iter:
            G, Jm = self.evaluate(y, args)
            r = np.concatenate([G, [row @ y - float(c)]])
            if not np.all(np.isfinite(r)):
                return Correction(y, False, it, np.inf)
            lu, piv = _factor(Jm, row)
            dy = scipy.linalg.lu_solve((lu, piv), -r, check_finite=False)
            if not np.all(np.isfinite(dy)):
                return Correction(y, False, it, np.inf)
            y = y + dy
            it += 1
            err = float(np.max(np.abs(dy)))
            if err <= self.tol:
                break
        G, _ = self._both(y, args)
        res = float(np.max(np.abs(np.asarray(G))))
        return Correction(y, bool(err <= self.tol and np.isfinite(res)), it, res)

    def tangent(self, y, t_prev, weights, args):
        # [G_y; (W t_prev)^T] t = [0; 1]
        _, Jm = self.evaluate(np.asarray(y, dtype=float), args)
        w = np.asarray(weights, dtype=float)
        lu, piv = _factor(Jm, w * np.asarray(t_prev, dtype=float))
        rhs = np.zeros(np.asarray(y).shape[0])
        rhs[-1] = 1.0
        t = scipy.linalg.lu_solve((lu, piv), rhs, check_finite=False)
        t = t / np.sqrt(t @ (w * t))
        return t, _det_sign(lu, piv)


def correct(
    problem: ZeroProblem,
    y_guess: Array,
    row: Array,
    c: float,
    args: Any,
    *,
    tol: float = 1e-10,
    max_iter: int = 10,
) -> tuple[np.ndarray, bool, int, float]:
    """Newton on ``[G(y, args); row . y - c] = 0`` from ``y_guess``.

    Returns
    -------
    y : ndarray
    converged : bool
    iterations : int
    residual : float
        Max-norm of ``G`` at the returned point.
    """
    corrector = NewtonCorrector(problem, tol=tol, max_iter=max_iter)
    with threadpool_limits(1, user_api="blas"):
        r = corrector.correct(np.asarray(y_guess, dtype=float), np.asarray(row, dtype=float),
                              float(c), args)
    return np.asarray(r.y), bool(r.converged), int(r.iterations), float(r.residual)


def tangent_at(
    problem: ZeroProblem, y: Array, t_prev: Array, args: Any, weights: Array | None = None
) -> np.ndarray:
    """Unit tangent at ``y`` oriented like ``t_prev``."""
    y = np.asarray(y, dtype=float)
    w = np.ones_like(y) if weights is None else np.asarray(weights, dtype=float)
    t, _ = NewtonCorrector(problem).tangent(y, np.asarray(t_prev, dtype=float), w, args)
    return np.asarray(t)


@dataclass
class ContinuationState:
    """Everything the driver needs to take the next step; plain arrays and numbers, so a
    campaign can store it beside each recorded point and resume from it exactly.

    Attributes
    ----------
    y, t : ndarray
        The last accepted point and its unit tangent (weighted norm).
    ds : float
        The next arclength step.
    sign : float
        Sign of the bordered Jacobian's determinant at ``y`` (branch-point test).
    n_points : int
        Points accepted so far (including the start).
    y_prev : ndarray or None
        The point before ``y`` (secant predictor).
    args : pytree
        The problem's extra arguments at ``y`` (after ``update_args``).
    status, message : str
        ``"running"`` until the branch ends, then one of
        :data:`~bifid.continuation.END_REASONS`.
    corrector : dict of ndarray
        The corrector's :meth:`AbstractCorrector.state` at ``y``.
    """

    y: np.ndarray
    t: np.ndarray
    ds: float
    sign: float
    n_points: int
    y_prev: np.ndarray | None = None
    args: Any = None
    status: str = "running"
    message: str = ""
    corrector: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def running(self) -> bool:
        return self.status == "running"


@dataclass
class Step:
    """Outcome of :meth:`Continuation.step`.

    ``point`` is the accepted correction (None when the step was rejected and retried
    with a smaller ``ds``, or when the branch ended without a new point); ``events`` lists
    ``("fold", y, precision)`` and ``("branch_point", None, nan)`` found between the
    previous point and this one.
    """

    state: ContinuationState
    point: Correction | None = None
    tangent: np.ndarray | None = None
    events: list[tuple[str, np.ndarray | None, float]] = field(default_factory=list)


class Continuation:
    """Pseudo-arclength predictor–corrector on any corrector, one step at a time.

    Parameters
    ----------
    corrector : AbstractCorrector
    param_index : int
        Component of ``y`` that is the continuation parameter.
    options : ContinuationOptions
    weights : array of shape (N+1,), optional
        Diagonal ``W`` of the arclength inner product.
    update_args : callable ``(y, args) -> args``, optional
        Called after each accepted point (e.g. to move a phase-condition reference).
    stop : callable ``y -> bool``, optional
        Ends the branch (status ``"completed"``) when it returns True.
    predictor : {"tangent", "secant"}
        Euler predictor along the tangent, or along the secant of the last two points
        (the tangent is then only used at the start and for fold location).
    monitor : callable ``(y, y_new, args) -> float``, optional
        Step control beyond the corrector's: called with each corrected step before it is
        accepted; a return value ``f < 1`` rejects the step and retries with ``ds * f``
        (e.g. when the amplitude or the harmonic content changed too much to trust the
        curve between the two points), ``f >= 1`` accepts it.
    """

    def __init__(
        self,
        corrector: AbstractCorrector,
        param_index: int,
        options: ContinuationOptions,
        *,
        weights: Array | None = None,
        update_args: Callable[[np.ndarray, Any], Any] | None = None,
        stop: Callable[[np.ndarray], bool] | None = None,
        predictor: str = "tangent",
        monitor: Callable[[np.ndarray, np.ndarray, Any], float] | None = None,
    ) -> None:
        if predictor not in ("tangent", "secant"):
            raise BifidInputError(f"predictor must be 'tangent' or 'secant', got {predictor!r}.")
        self.corrector = corrector
        self.param_index = int(param_index)
        self.options = options
        self.weights = None if weights is None else np.asarray(weights, dtype=float)
        self.update_args = update_args
        self.stop = stop
        self.predictor = predictor
        self.monitor = monitor

    def _w(self, n: int) -> np.ndarray:
        return np.ones(n) if self.weights is None else self.weights

    def start(self, y0: Array, t0: Array, args: Any, *, correct_start: bool = True
              ) -> ContinuationState:
        """Correct ``y0`` at fixed parameter (unless told not to) and orient the tangent
        like ``t0``; a start that cannot be corrected gives a state with status
        ``"failed"``."""
        y = np.asarray(y0, dtype=float)
        n = y.shape[0]
        pi = self.param_index % n
        w = self._w(n)
        if correct_start:
            e_p = np.zeros(n)
            e_p[pi] = 1.0
            r = self.corrector.correct(y, e_p, float(y[pi]), args)
            if not r.converged:
                return ContinuationState(
                    y=y, t=np.zeros(n), ds=self.options.ds, sign=math.nan, n_points=0,
                    args=args, status="failed",
                    message="Newton did not converge at the starting point "
                    f"(parameter {float(y[pi]):.6g}).")
            y = r.y
            self.corrector.accept(r)
        t0 = np.asarray(t0, dtype=float)
        t, sign = self.corrector.tangent(y, t0, w, args)
        if t0[pi] != 0.0 and t[pi] * t0[pi] < 0:
            t, sign = -t, -sign
        if self.update_args is not None:
            args = self.update_args(y, args)
        return ContinuationState(y=y, t=t, ds=self.options.ds, sign=sign, n_points=1,
                                 args=args, corrector=self.corrector.state())

    def step(self, state: ContinuationState) -> Step:
        """Try one step from ``state``; see :class:`Step`."""
        o = self.options
        if not state.running:
            return Step(state)
        if state.n_points >= o.max_steps:
            return Step(replace(state, status="steps",
                                message=f"maximum number of steps ({o.max_steps}) reached"))
        y, t, ds, args = state.y, state.t, state.ds, state.args
        n = y.shape[0]
        pi = self.param_index % n
        w = self._w(n)
        direction = t
        if self.predictor == "secant" and state.y_prev is not None:
            sec = y - state.y_prev
            direction = sec / math.sqrt(float(sec @ (w * sec)))
        y_pred = y + ds * direction
        row = w * direction
        r = self.corrector.correct(y_pred, row, float(row @ y_pred), args)
        ok = r.converged
        t_new, sign_new = None, math.nan
        if ok:
            t_new, sign_new = self.corrector.tangent(r.y, direction, w, args)
            # reject steps that turn too sharply: the corrector may have jumped branch
            ok = float(t_new @ (w * direction)) > 0.8 or ds <= o.ds_min * 1.0001
        if ok and self.monitor is not None and ds > o.ds_min * 1.0001:
            factor = float(self.monitor(y, r.y, args))
            if factor < 1.0:
                return Step(replace(state, ds=max(ds * max(factor, 0.1), o.ds_min),
                                    corrector=self.corrector.state()))
        if not ok:
            if ds <= o.ds_min * 1.0001:
                return Step(replace(
                    state, status="failed",
                    message=f"the corrector failed near {problem_param_name(args)}="
                    f"{float(y[pi]):.8g} even with the minimum step ds_min={o.ds_min:g}"))
            return Step(replace(state, ds=max(ds / 2.0, o.ds_min),
                                corrector=self.corrector.state()))

        y_new = r.y
        p_new = float(y_new[pi])
        hit = o.p_max if p_new > o.p_max else o.p_min if p_new < o.p_min else None
        if hit is not None:
            frac = (hit - float(y[pi])) / (p_new - float(y[pi]))
            e_p = np.zeros(n)
            e_p[pi] = 1.0
            rb = self.corrector.correct(y + frac * (y_new - y), e_p, hit, args)
            if not rb.converged:
                return Step(replace(state, status="failed",
                                    message=f"could not converge on the parameter bound {hit:g}"))
            self.corrector.accept(rb)
            t_b, sign_b = self.corrector.tangent(rb.y, direction, w, args)
            new = replace(state, y=rb.y, t=t_b, sign=sign_b, n_points=state.n_points + 1,
                          y_prev=y, status="range",
                          message=f"reached the parameter bound {hit:g}",
                          corrector=self.corrector.state())
            return Step(new, rb, t_b)

        events: list[tuple[str, np.ndarray | None, float]] = []
        if o.detect_folds and float(t[pi]) * float(t_new[pi]) < 0:
            y_f, prec = _locate_fold(self.corrector, y, t, ds, w, args, pi)
            if y_f is not None:
                events.append(("fold", np.asarray(y_f), prec))
        if o.detect_bifurcations and float(sign_new) * float(state.sign) < 0:
            events.append(("branch_point", None, math.nan))
        self.corrector.accept(r)
        if self.update_args is not None:
            args = self.update_args(y_new, args)
        if r.iterations <= 3:
            ds = min(ds * o.growth, o.ds_max)
        elif r.iterations >= o.newton_max_iter - 2:
            ds = max(ds / 2.0, o.ds_min)
        new = replace(state, y=y_new, t=t_new, ds=ds, sign=sign_new,
                      n_points=state.n_points + 1, y_prev=y, args=args,
                      corrector=self.corrector.state())
        if self.stop is not None and self.stop(y_new):
            new.status, new.message = "completed", "stopping condition met"
        return Step(new, r, t_new, events)

    def run(self, y0: Array, t0: Array, args: Any, *, correct_start: bool = True,
            progress: Callable[[int, float], None] | None = None) -> PalcResult:
        """Follow the branch until it ends; the points, tangents and events in one result."""
        state = self.start(y0, t0, args, correct_start=correct_start)
        n = np.asarray(y0).shape[0]
        if state.status == "failed":
            return PalcResult(ys=np.empty((0, n)), tangents=np.empty((0, n)),
                              iterations=np.empty(0, int), status="failed",
                              message=state.message, args=args)
        pi = self.param_index % n
        ys, ts, its = [state.y], [state.t], [0]
        folds: list[tuple[int, np.ndarray, float]] = []
        bps: list[int] = []
        if progress is not None:
            progress(1, float(state.y[pi]))
        while state.running:
            s = self.step(state)
            if s.point is not None:
                for kind, y_e, prec in s.events:
                    if kind == "fold":
                        folds.append((len(ys) - 1, y_e, prec))
                    elif kind == "branch_point":
                        bps.append(len(ys) - 1)
                ys.append(np.asarray(s.point.y))
                ts.append(np.asarray(s.tangent))
                its.append(int(s.point.iterations))
                if progress is not None:
                    progress(len(ys), float(s.point.y[pi]))
            state = s.state
        return PalcResult(ys=np.array(ys), tangents=np.array(ts), iterations=np.array(its),
                          folds=folds, branch_points=bps, status=state.status,
                          message=state.message, args=state.args)


def palc(
    problem: ZeroProblem,
    y0: Array,
    t0: Array,
    args: Any,
    options: ContinuationOptions,
    *,
    weights: Array | None = None,
    update_args: Callable[[np.ndarray, Any], Any] | None = None,
    stop: Callable[[np.ndarray], bool] | None = None,
    progress: Callable[[int, float], None] | None = None,
    correct_start: bool = True,
) -> PalcResult:
    """Follow the solution curve of ``problem`` from ``y0`` along ``t0`` with Newton.

    Parameters
    ----------
    problem : ZeroProblem
    y0 : array of shape (N+1,)
        Start (corrected first unless ``correct_start`` is False).
    t0 : array of shape (N+1,)
        Initial direction; its parameter component sets the direction of travel.
    args : pytree
        Extra arrays passed to the residual.
    options : ContinuationOptions
    weights : array of shape (N+1,), optional
        Diagonal weights ``W`` of the arclength inner product.
    update_args : callable ``(y, args) -> args``, optional
        Called after each accepted point (e.g. to move a phase-condition reference).
    stop : callable ``y -> bool``, optional
        Ends the branch (status "completed") when it returns True.
    progress : callable ``(n_points, param) -> None``, optional
    correct_start : bool
        Correct ``y0`` with Newton before starting (fixed parameter).

    Returns
    -------
    PalcResult
        Points, tangents, located folds, flagged branch points and why it ended.
    """
    corrector = NewtonCorrector(problem, tol=options.newton_tol, max_iter=options.newton_max_iter)
    driver = Continuation(corrector, problem.param_index, options, weights=weights,
                          update_args=update_args, stop=stop)
    # Single-threaded BLAS: these dense systems are small, and a multi-threaded OpenBLAS
    # on a loaded machine is 10-30x slower (threads spin against each other).
    with threadpool_limits(1, user_api="blas"):
        return driver.run(y0, t0, args, correct_start=correct_start, progress=progress)


def problem_param_name(args: Any) -> str:
    """Name used in messages (args may carry ``param_name``)."""
    if isinstance(args, dict) and "param_name" in args:
        return str(args["param_name"])
    return "parameter"


def _locate_fold(corrector: AbstractCorrector, y_a, t_a, ds, w, args, pi):
    """Zero of the parameter component of the tangent on the arc from ``y_a``.

    Illinois secant on ``s in [0, ds]``: the point ``y(s)`` is the corrected point with
    ``(W t_a)^T (y - y_a) = s``; ``f(s) = t(y(s))[pi]``.
    """
    row = w * t_a
    c0 = float(row @ y_a)

    def f(s):
        r = corrector.correct(y_a + s * t_a, row, c0 + s, args)
        if not r.converged:
            return None, None
        t_s, _ = corrector.tangent(r.y, t_a, w, args)
        return float(t_s[pi]), r.y

    a, fa = 0.0, float(t_a[pi])
    b = ds
    fb, yb = f(b)
    if fb is None or fa * fb > 0:
        return None, math.nan
    y_best = yb
    for _ in range(60):
        s = (a * fb - b * fa) / (fb - fa)
        fs, ys = f(s)
        if fs is None:
            s = 0.5 * (a + b)
            fs, ys = f(s)
            if fs is None:
                break
        y_best = ys
        if fs * fb < 0:
            a, fa = b, fb
        else:
            fa = fa / 2.0  # Illinois modification keeps the bracket shrinking on both sides
        b, fb = s, fs
        if abs(fs) < 1e-14 or abs(b - a) < 1e-15 * max(1.0, ds):
            break
    # the parameter is stationary at a fold: its error is second order in the s error
    prec = abs(b - a) ** 2 + 1e-14
    return y_best, prec
