"""Pseudo-arclength continuation of a generic zero problem ``G(y) = 0``, ``G: R^{N+1} -> R^N``.

Written by hand because no maintained JAX library offers predictor–corrector
continuation with fold location, adaptive steps and bounds that we could compose
with our own collocation Jacobians (``jaxcont`` is benchmarked against this in
BENCHMARKS.md). The numerical kernels — Newton corrector and tangent — are jitted
once per problem and reused for every step and every parameter value.

Predictor–corrector (Keller):

* tangent ``t`` solves ``[G_y(y); (W t_prev)^T] t = [0; 1]``, normalised in the
  weighted norm ``||t||_W = sqrt(t^T W t)``;
* predictor ``y_p = y + ds t``;
* corrector: Newton on ``[G(y); (W t)^T (y - y_p)] = 0``.

Folds (limit points of the parameter) are detected as sign changes of the parameter
component of the tangent and located by a secant (Illinois) search on the arclength
``s`` of the zero of that component; branch points are flagged by a sign change of
``det [G_y; t^T]``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits

from bifid.continuation._options import ContinuationOptions

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
    status: str = "completed"
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


def _kernels(problem: ZeroProblem, max_iter: int) -> tuple[Callable, Callable]:
    """Newton corrector and tangent, LAPACK dense LU on the jitted residual/Jacobian.

    The linear algebra runs in SciPy (OpenBLAS) rather than inside XLA: for the
    few-hundred-unknown dense systems of collocation it is several times faster on CPU.
    """
    both = _evaluator(problem)

    def newton(y0, row, c, tol, args):
        y = np.asarray(y0, dtype=float).copy()
        row = np.asarray(row, dtype=float)
        c = float(c)
        tol = float(tol)
        err = np.inf
        it = 0
        while it < max_iter:
            G, Jm = both(y, args)
            G, Jm = np.asarray(G), np.asarray(Jm)
            r = np.concatenate([G, [row @ y - c]])
            if not np.all(np.isfinite(r)):
                return y, False, it, np.inf
            lu, piv = _factor(Jm, row)
            dy = scipy.linalg.lu_solve((lu, piv), -r, check_finite=False)
            if not np.all(np.isfinite(dy)):
                return y, False, it, np.inf
            y = y + dy
            it += 1
            err = float(np.max(np.abs(dy)))
            if err <= tol:
                break
        G, _ = both(y, args)
        res = float(np.max(np.abs(np.asarray(G))))
        ok = bool(err <= tol and np.isfinite(res))
        return y, ok, it, res

    def tangent(y, t_prev, w, args):
        # [G_y; (W t_prev)^T] t = [0; 1]
        _, Jm = both(y, args)
        w = np.asarray(w)
        lu, piv = _factor(np.asarray(Jm), w * np.asarray(t_prev))
        rhs = np.zeros(np.asarray(y).shape[0])
        rhs[-1] = 1.0
        t = scipy.linalg.lu_solve((lu, piv), rhs, check_finite=False)
        t = t / np.sqrt(t @ (w * t))
        return t, _det_sign(lu, piv)

    return newton, tangent


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
    newton, _ = _kernels(problem, max_iter)
    with threadpool_limits(1, user_api="blas"):
        y, ok, it, res = newton(
        np.asarray(y_guess, dtype=float), np.asarray(row, dtype=float), float(c), tol, args,
    )
    return np.asarray(y), bool(ok), int(it), float(res)


def tangent_at(
    problem: ZeroProblem, y: Array, t_prev: Array, args: Any, weights: Array | None = None
) -> np.ndarray:
    """Unit tangent at ``y`` oriented like ``t_prev``."""
    _, tangent = _kernels(problem, 10)
    y = np.asarray(y, dtype=float)
    w = np.ones_like(y) if weights is None else np.asarray(weights, dtype=float)
    t, _ = tangent(y, np.asarray(t_prev, dtype=float), w, args)
    return np.asarray(t)


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
    """Follow the solution curve of ``problem`` from ``y0`` along ``t0``.

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
    # Single-threaded BLAS: these dense systems are small, and a multi-threaded OpenBLAS
    # on a loaded machine is 10-30x slower (threads spin against each other).
    with threadpool_limits(1, user_api="blas"):
        return _palc(problem, y0, t0, args, options, weights, update_args, stop, progress,
                     correct_start)


def _palc(problem, y0, t0, args, options, weights, update_args, stop, progress, correct_start):
    o = options
    pi = problem.param_index % int(np.asarray(y0).shape[0])
    newton, tangent = _kernels(problem, o.newton_max_iter)
    y = np.asarray(y0, dtype=float)
    n = y.shape[0]
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float)
    tol = o.newton_tol

    e_p = np.zeros(n)
    e_p[pi] = 1.0
    if correct_start:
        y_c, ok, it, _ = newton(y, e_p, y[pi], tol, args)
        if not bool(ok):
            return PalcResult(
                ys=np.empty((0, n)), tangents=np.empty((0, n)), iterations=np.empty(0, int),
                status="failed",
                message="Newton did not converge at the starting point "
                f"(parameter {float(y[pi]):.6g}).",
                args=args,
            )
        y = y_c
    t0 = np.asarray(t0, dtype=float)
    t, sign = tangent(y, t0, w, args)
    if t0[pi] != 0.0 and t[pi] * t0[pi] < 0:
        t = -t
        sign = -sign
    if update_args is not None:
        args = update_args(np.asarray(y), args)

    ys, ts, its = [np.asarray(y)], [np.asarray(t)], [0]
    folds: list[tuple[int, np.ndarray, float]] = []
    bps: list[int] = []
    ds = o.ds
    status, message = "max_steps", f"maximum number of steps ({o.max_steps}) reached"
    if progress is not None:
        progress(1, float(y[pi]))

    while len(ys) < o.max_steps:
        y_pred = y + ds * t
        row = w * t
        y_new, ok, it, _ = newton(y_pred, row, row @ y_pred, tol, args)
        ok = bool(ok)
        t_new = sign_new = None
        if ok:
            t_new, sign_new = tangent(y_new, t, w, args)
            # reject steps that turn too sharply: the corrector may have jumped branch
            ok = float(t_new @ (w * t)) > 0.8 or ds <= o.ds_min * 1.0001
        if not ok:
            if ds <= o.ds_min * 1.0001:
                status = "failed"
                message = (
                    f"Newton failed to converge near {problem_param_name(args)}="
                    f"{float(y[pi]):.8g} even with the minimum step ds_min={o.ds_min:g}"
                )
                break
            ds = max(ds / 2.0, o.ds_min)
            continue

        p_new = float(y_new[pi])
        hit = None
        if p_new > o.p_max:
            hit = o.p_max
        elif p_new < o.p_min:
            hit = o.p_min
        if hit is not None:
            frac = (hit - float(y[pi])) / (p_new - float(y[pi]))
            guess = y + frac * (y_new - y)
            y_b, ok_b, _, _ = newton(guess, e_p, hit, tol, args)
            if bool(ok_b):
                t_b, _ = tangent(y_b, t, w, args)
                ys.append(np.asarray(y_b))
                ts.append(np.asarray(t_b))
                its.append(0)
                status, message = "bounds", f"reached the parameter bound {hit:g}"
            else:
                status, message = "failed", f"could not converge on the parameter bound {hit:g}"
            break

        if o.detect_folds and float(t[pi]) * float(t_new[pi]) < 0:
            y_f, prec = _locate_fold(newton, tangent, y, t, ds, w, args, tol, pi)
            if y_f is not None:
                folds.append((len(ys) - 1, np.asarray(y_f), prec))
        if o.detect_bifurcations and float(sign_new) * float(sign) < 0:
            bps.append(len(ys) - 1)

        y, t, sign = y_new, t_new, sign_new
        ys.append(np.asarray(y))
        ts.append(np.asarray(t))
        its.append(int(it))
        if update_args is not None:
            args = update_args(np.asarray(y), args)
        if progress is not None:
            progress(len(ys), p_new)
        if int(it) <= 3:
            ds = min(ds * o.growth, o.ds_max)
        elif int(it) >= o.newton_max_iter - 2:
            ds = max(ds / 2.0, o.ds_min)
        if stop is not None and stop(np.asarray(y)):
            status, message = "completed", "stopping condition met"
            break

    return PalcResult(
        ys=np.array(ys), tangents=np.array(ts), iterations=np.array(its), folds=folds,
        branch_points=bps, status=status, message=message, args=args,
    )


def problem_param_name(args: Any) -> str:
    """Name used in messages (args may carry ``param_name``)."""
    if isinstance(args, dict) and "param_name" in args:
        return str(args["param_name"])
    return "parameter"


def _locate_fold(newton, tangent, y_a, t_a, ds, w, args, tol, pi):
    """Zero of the parameter component of the tangent on the arc from ``y_a``.

    Illinois secant on ``s in [0, ds]``: the point ``y(s)`` is the corrected point with
    ``(W t_a)^T (y - y_a) = s``; ``f(s) = t(y(s))[pi]``.
    """
    row = w * t_a
    c0 = float(row @ y_a)

    def f(s):
        guess = y_a + s * t_a
        y_s, ok, _, _ = newton(guess, row, c0 + s, tol, args)
        if not bool(ok):
            return None, None
        t_s, _ = tangent(y_s, t_a, w, args)
        return float(t_s[pi]), y_s

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
