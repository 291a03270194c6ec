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

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.continuation._blas import one_blas_thread
from bifid.continuation._correctors import (
    AbstractCorrector,
    Correction,
    NewtonCorrector,
    ZeroProblem,
    correct,
    tangent_at,
)
from bifid.continuation._options import ContinuationOptions
from bifid.errors import BifidInputError

#: a step the monitor rejects with factor ``f`` is retried with ``MONITOR_SAFETY * f`` of it
MONITOR_SAFETY = 0.8

__all__ = [
    "AbstractCorrector",
    "Continuation",
    "ContinuationState",
    "Correction",
    "NewtonCorrector",
    "PalcResult",
    "Step",
    "ZeroProblem",
    "correct",
    "palc",
    "tangent_at",
]

Array = jnp.ndarray


@dataclass
class PalcResult:
    """Raw output of :func:`palc`.

    ``folds`` are ``(i, y, precision)``: a fold located between points ``i`` and ``i+1``
    (not yet verified: see ``bifid.continuation._folds``); ``fold_failures`` the ``i``
    where the parameter component of the tangent changed sign but the fold could not be
    located; ``branch_points`` the ``i`` where ``det [G_y; t^T]`` changed sign.
    """

    ys: np.ndarray
    tangents: np.ndarray
    iterations: np.ndarray
    folds: list[tuple[int, np.ndarray, float]] = field(default_factory=list)
    branch_points: list[int] = field(default_factory=list)
    status: str = "completed"  # one of bifid.continuation.END_REASONS
    message: str = ""
    args: Any = None
    fold_failures: list[int] = field(default_factory=list)


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
    ``("fold", y, precision)`` (``y`` None when the fold could not be located) and
    ``("branch_point", None, nan)`` found between the previous point and this one.
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
        accepted; a return value ``f < 1`` rejects the step (e.g. when the amplitude or
        the harmonic content changed too much to trust the curve between the two points)
        and retries with ``ds * max(MONITOR_SAFETY * f, 0.1)`` (the safety factor keeps a
        monitor that is linear in ``ds`` from rejecting ever closer to its limit);
        ``f >= 1`` accepts it, and the next step grows by at most ``MONITOR_SAFETY * f``
        (a monitor that returns its headroom, limit / change, avoids a rejection after
        every growth; one with nothing to say returns ``inf``).
    param_name : str, optional
        Name of the parameter in messages (default: ``args["param_name"]`` when ``args``
        is a dict that has it, else "parameter").
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
        param_name: str | None = None,
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
        self.param_name = param_name

    def _w(self, n: int) -> np.ndarray:
        return np.ones(n) if self.weights is None else self.weights

    def start(
        self, y0: Array, t0: Array, args: Any, *, correct_start: bool = True
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
                    y=y,
                    t=np.zeros(n),
                    ds=self.options.ds,
                    sign=math.nan,
                    n_points=0,
                    args=args,
                    status="failed",
                    message="Newton did not converge at the starting point "
                    f"(parameter {float(y[pi]):.6g}).",
                )
            y = r.y
            self.corrector.accept(r)
        t0 = np.asarray(t0, dtype=float)
        t, sign = self.corrector.tangent(y, t0, w, args)
        if t0[pi] != 0.0 and t[pi] * t0[pi] < 0:
            t, sign = -t, -sign
        if self.update_args is not None:
            args = self.update_args(y, args)
        return ContinuationState(
            y=y,
            t=t,
            ds=self.options.ds,
            sign=sign,
            n_points=1,
            args=args,
            corrector=self.corrector.state(),
        )

    def _land_on_bound(
        self, state: ContinuationState, y_new: np.ndarray, direction: np.ndarray, w, hit: float
    ) -> Step:
        """The last point of a step that crossed the parameter bound ``hit``: corrected
        onto it from the chord between ``state.y`` and ``y_new`` (status ``"range"``)."""
        y, args, n = state.y, state.args, state.y.shape[0]
        pi = self.param_index % n
        frac = (hit - float(y[pi])) / (float(y_new[pi]) - float(y[pi]))
        e_p = np.zeros(n)
        e_p[pi] = 1.0
        rb = self.corrector.correct(y + frac * (y_new - y), e_p, hit, args)
        if not rb.converged:
            return Step(
                replace(
                    state,
                    status="failed",
                    message=f"could not converge on the parameter bound {hit:g}",
                )
            )
        self.corrector.accept(rb)
        t_b, sign_b = self.corrector.tangent(rb.y, direction, w, args)
        new = replace(
            state,
            y=rb.y,
            t=t_b,
            sign=sign_b,
            n_points=state.n_points + 1,
            y_prev=y,
            status="range",
            message=f"reached the parameter bound {hit:g}",
            corrector=self.corrector.state(),
        )
        return Step(new, rb, t_b)

    def step(self, state: ContinuationState) -> Step:
        """Try one step from ``state``; see :class:`Step`."""
        o = self.options
        if not state.running:
            return Step(state)
        if state.n_points >= o.max_steps:
            return Step(
                replace(
                    state,
                    status="steps",
                    message=f"maximum number of steps ({o.max_steps}) reached",
                )
            )
        y, t, ds, args = state.y, state.t, state.ds, state.args
        n = y.shape[0]
        pi = self.param_index % n
        w = self._w(n)
        direction = t
        if self.predictor == "secant" and state.y_prev is not None:
            sec = y - state.y_prev
            direction = sec / math.sqrt(float(sec @ (w * sec)))
        if abs(float(direction[pi])) * ds > o.dp_max:  # the parameter limit per step
            ds = max(o.dp_max / abs(float(direction[pi])), o.ds_min)
        y_pred = y + ds * direction
        row = w * direction
        r = self.corrector.correct(y_pred, row, float(row @ y_pred), args)
        ok = r.converged
        t_new, sign_new, growth = None, math.nan, o.growth
        if ok:
            t_new, sign_new = self.corrector.tangent(r.y, direction, w, args)
            # reject steps that turn too sharply: the corrector may have jumped branch
            ok = float(t_new @ (w * direction)) > 0.8 or ds <= o.ds_min * 1.0001
        if ok and self.monitor is not None and ds > o.ds_min * 1.0001:
            factor = float(self.monitor(y, r.y, args))
            growth = min(o.growth, max(1.0, MONITOR_SAFETY * factor))
            if factor < 1.0:
                return Step(
                    replace(
                        state,
                        ds=max(ds * max(MONITOR_SAFETY * factor, 0.1), o.ds_min),
                        corrector=self.corrector.state(),
                    )
                )
        if not ok:
            if ds <= o.ds_min * 1.0001:
                name = self.param_name or problem_param_name(args)
                return Step(
                    replace(
                        state,
                        status="failed",
                        message=f"the corrector failed near {name}={float(y[pi]):.8g} even with "
                        f"the minimum step ds_min={o.ds_min:g}",
                    )
                )
            return Step(
                replace(state, ds=max(ds / 2.0, o.ds_min), corrector=self.corrector.state())
            )

        y_new = r.y
        p_new = float(y_new[pi])
        hit = o.p_max if p_new > o.p_max else o.p_min if p_new < o.p_min else None
        if hit is not None:
            return self._land_on_bound(state, y_new, direction, w, hit)

        events: list[tuple[str, np.ndarray | None, float]] = []
        if o.detect_folds and float(t[pi]) * float(t_new[pi]) < 0:
            y_f, prec = _locate_fold(self.corrector, y, t, ds, w, args, pi)
            events.append(("fold", None if y_f is None else np.asarray(y_f), prec))
        if o.detect_bifurcations and float(sign_new) * float(state.sign) < 0:
            events.append(("branch_point", None, math.nan))
        self.corrector.accept(r)
        if self.update_args is not None:
            args = self.update_args(y_new, args)
        if r.iterations <= 3:
            ds = min(ds * growth, o.ds_max)
        elif r.iterations >= o.newton_max_iter - 2:
            ds = max(ds / 2.0, o.ds_min)
        new = replace(
            state,
            y=y_new,
            t=t_new,
            ds=ds,
            sign=sign_new,
            n_points=state.n_points + 1,
            y_prev=y,
            args=args,
            corrector=self.corrector.state(),
        )
        if self.stop is not None and self.stop(y_new):
            new.status, new.message = "completed", "stopping condition met"
        elif (bound := _at_bound(p_new, float(y[pi]), o)) is not None:
            new.status = "range"
            new.message = (
                f"reached the parameter bound {bound:g} "
                f"(to {abs(p_new - bound):.1e}; it is approached asymptotically)"
            )
        return Step(new, r, t_new, events)

    def run(
        self,
        y0: Array,
        t0: Array,
        args: Any,
        *,
        correct_start: bool = True,
        progress: Callable[[int, float], None] | None = None,
    ) -> PalcResult:
        """Follow the branch until it ends; the points, tangents and events in one result."""
        state = self.start(y0, t0, args, correct_start=correct_start)
        n = np.asarray(y0).shape[0]
        if state.status == "failed":
            return PalcResult(
                ys=np.empty((0, n)),
                tangents=np.empty((0, n)),
                iterations=np.empty(0, int),
                status="failed",
                message=state.message,
                args=args,
            )
        pi = self.param_index % n
        ys, ts, its = [state.y], [state.t], [0]
        folds: list[tuple[int, np.ndarray, float]] = []
        bps: list[int] = []
        fold_failures: list[int] = []
        if progress is not None:
            progress(1, float(state.y[pi]))
        while state.running:
            s = self.step(state)
            if s.point is not None:
                for kind, y_e, prec in s.events:
                    if kind == "fold" and y_e is not None:
                        folds.append((len(ys) - 1, y_e, prec))
                    elif kind == "fold":
                        fold_failures.append(len(ys) - 1)
                    elif kind == "branch_point":
                        bps.append(len(ys) - 1)
                ys.append(np.asarray(s.point.y))
                ts.append(np.asarray(s.tangent))
                its.append(int(s.point.iterations))
                if progress is not None:
                    progress(len(ys), float(s.point.y[pi]))
            state = s.state
        return PalcResult(
            ys=np.array(ys),
            tangents=np.array(ts),
            iterations=np.array(its),
            folds=folds,
            branch_points=bps,
            status=state.status,
            message=state.message,
            args=state.args,
            fold_failures=fold_failures,
        )


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
    monitor: Callable[[np.ndarray, np.ndarray, Any], float] | None = None,
    param_name: str | None = None,
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
    monitor, param_name
        As for :class:`Continuation`.

    Returns
    -------
    PalcResult
        Points, tangents, located folds, flagged branch points and why it ended.
    """
    corrector = NewtonCorrector(problem, tol=options.newton_tol, max_iter=options.newton_max_iter)
    driver = Continuation(
        corrector,
        problem.param_index,
        options,
        weights=weights,
        update_args=update_args,
        stop=stop,
        monitor=monitor,
        param_name=param_name,
    )
    # Single-threaded BLAS: these dense systems are small, and a multi-threaded OpenBLAS
    # on a loaded machine is 10-30x slower (threads spin against each other).
    with one_blas_thread():
        return driver.run(y0, t0, args, correct_start=correct_start, progress=progress)


#: a branch whose parameter comes this close to a bound (relative to the range, or to
#: max(1, |bound|) for a half-open range) while moving towards it has reached it: a branch
#: that approaches the bound only asymptotically would otherwise creep towards it forever
BOUND_TOL = 1e-9


def _at_bound(p_new: float, p_old: float, o: ContinuationOptions) -> float | None:
    """The bound that ``p_new`` has reached while moving towards it, else None."""
    span = o.p_max - o.p_min
    for bound in (o.p_min, o.p_max):
        if not math.isfinite(bound):
            continue
        tol = BOUND_TOL * (span if math.isfinite(span) else max(1.0, abs(bound)))
        if abs(p_new - bound) <= tol and abs(p_new - bound) < abs(p_old - bound):
            return bound
    return None


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
