"""Nonlinear least squares of residuals computed outside JAX, by optimistix.

The mechanistic stages (thesis §4.3.2–4.3.3) minimise ``½‖r(φ)‖²`` where an evaluation of
``r`` is not a JAX function: it re-solves periodic orbits by Newton's method from the orbits
of earlier evaluations (warm starts, homotopy substeps, a check of the side of a cycle
fold), and the exact Jacobian comes from implicit differentiation at the converged orbits.
:func:`least_squares` drives such a residual with :class:`optimistix.LevenbergMarquardt`
(a trust-region Levenberg–Marquardt whose damped step
:math:`-(J^\\mathsf{T}J + \\lambda I)^{-1}J^\\mathsf{T}r` lies in the row space of ``J``:
directions the data do not inform are never moved, so a rank-deficient problem ends at
the solution nearest its start). The residual and the Jacobian enter through
:func:`jax.pure_callback`; a :func:`jax.custom_jvp` makes the Jacobian the derivative of
the residual, so optimistix's linearisation costs one Jacobian per step.

An evaluation may be infeasible (the residual function returns ``None``, e.g. an orbit
that moved past a fold): it is reported as NaN, the trust region rejects the step and
shrinks. The compiled solver depends only on the sizes and settings (the callbacks find
the current problem by an integer id passed as an argument); residuals are padded with zeros
to a power of two (which changes neither the cost nor the steps), so it is compiled once per
``(padded n_residuals, n_parameters)`` and reused by every later fit of that size.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from bifid.errors import ConvergenceError

__all__ = ["LeastSquaresResult", "least_squares"]

Residual = Callable[[np.ndarray], np.ndarray | None]


@dataclass
class LeastSquaresResult:
    """Result of :func:`least_squares`.

    Attributes
    ----------
    x : ndarray
        The solution.
    fun : ndarray
        Residuals at ``x``.
    jac : ndarray
        Jacobian at ``x``.
    cost : float
        ``½‖fun‖²``.
    n_iter, n_fev, n_jev : int
        Solver steps, residual and Jacobian evaluations.
    converged : bool
        The solver's tolerance was met (not the step budget).
    message : str
    history : list of dict
        Cost after each evaluation that improved on all earlier ones (the accepted path).
    """

    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    cost: float
    n_iter: int
    n_fev: int
    n_jev: int
    converged: bool
    message: str
    history: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class _Problem:
    residual: Residual
    jacobian: Callable[[np.ndarray], np.ndarray]
    m: int
    m_pad: int
    n_fev: int = 0
    n_jev: int = 0
    best: float = math.inf
    history: list[dict[str, Any]] = field(default_factory=list)

    def r(self, x: np.ndarray) -> np.ndarray:
        self.n_fev += 1
        out = self.residual(np.array(x, dtype=float))
        if out is None:
            return np.full(self.m_pad, np.nan)
        out = np.asarray(out, dtype=float).reshape(self.m)
        cost = 0.5 * float(out @ out)
        if math.isfinite(cost) and cost < self.best:
            self.best = cost
            self.history.append({"iter": len(self.history), "cost": cost, "x": x.tolist()})
        return np.concatenate([out, np.zeros(self.m_pad - self.m)])

    def J(self, x: np.ndarray) -> np.ndarray:
        self.n_jev += 1
        x = np.array(x, dtype=float)
        if not np.all(np.isfinite(x)):
            return np.full((self.m_pad, x.shape[0]), np.nan)
        jac = np.asarray(self.jacobian(x), dtype=float).reshape(self.m, x.shape[0])
        return np.concatenate([jac, np.zeros((self.m_pad - self.m, x.shape[0]))])


_PROBLEMS: dict[int, _Problem] = {}
_IDS = itertools.count()


# JAX runs a callback under ``jax.default_device(<its device>)``, which is part of the key
# of every jit cache: the JAX functions the residual calls would be traced and compiled a
# second time inside the solver (seconds each). The callbacks clear it again.


def _host_residual(pid: np.ndarray, x: np.ndarray) -> np.ndarray:
    with jax.default_device(None):
        return _PROBLEMS[int(pid)].r(np.asarray(x))


def _host_jacobian(pid: np.ndarray, x: np.ndarray) -> np.ndarray:
    with jax.default_device(None):
        return _PROBLEMS[int(pid)].J(np.asarray(x))


@functools.lru_cache(maxsize=16)
def _solver(m: int, n: int, max_steps: int, rtol: float, atol: float) -> Callable:
    """Compiled ``(x0, problem id) -> (x, converged, n_steps)`` for ``m`` residuals."""
    r_shape = jax.ShapeDtypeStruct((m,), jnp.float64)
    j_shape = jax.ShapeDtypeStruct((m, n), jnp.float64)

    @jax.custom_jvp
    def residual(x, pid):
        return jax.pure_callback(_host_residual, r_shape, pid, x)

    @residual.defjvp
    def _residual_jvp(primals, tangents):
        x, pid = primals
        dx, _ = tangents
        jac = jax.pure_callback(_host_jacobian, j_shape, pid, x)
        return residual(x, pid), jac @ dx

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

    @jax.jit
    def run(x0, pid):
        sol = optx.least_squares(
            lambda y, a: residual(y, a), solver, x0, args=pid, max_steps=max_steps, throw=False
        )
        return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]

    return run


def least_squares(
    residual: Residual,
    jacobian: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    *,
    max_iter: int = 50,
    rtol: float = 1e-10,
    atol: float = 1e-14,
) -> LeastSquaresResult:
    """Minimise ``½‖residual(x)‖²`` from ``x0`` (module docstring).

    Parameters
    ----------
    residual : callable
        ``x -> r`` (ndarray of fixed length), or ``None`` where ``x`` is infeasible.
    jacobian : callable
        ``x -> dr/dx`` (exact), called at every point the solver linearises at.
    x0 : ndarray
        Start; must be feasible.
    max_iter : int
        Step budget.
    rtol, atol : float
        Termination: relative and absolute changes of ``x`` and ``r`` (optimistix's
        Cauchy criterion).

    Raises
    ------
    ConvergenceError
        If ``x0`` is infeasible or no feasible point is left at the end.
    """
    x0 = np.asarray(x0, dtype=float)
    r0 = residual(x0.copy())
    if r0 is None or not np.all(np.isfinite(r0)):
        raise ConvergenceError("The starting point of the fit is infeasible.")
    m = int(np.asarray(r0).size)
    m_pad = max(8, 1 << (m - 1).bit_length())
    pid = next(_IDS)
    problem = _PROBLEMS[pid] = _Problem(residual, jacobian, m, m_pad)
    try:
        run = _solver(m_pad, x0.shape[0], int(max_iter), float(rtol), float(atol))
        x, ok, steps = run(jnp.asarray(x0), jnp.asarray(pid))
        x = np.asarray(x, dtype=float)
        r = residual(x.copy())
        if r is None:
            raise ConvergenceError("The least-squares solver ended at an infeasible point.")
        r = np.asarray(r, dtype=float)
        jac = np.asarray(jacobian(x.copy()), dtype=float)
    finally:
        del _PROBLEMS[pid]
    converged = bool(ok)
    return LeastSquaresResult(
        x=x,
        fun=r,
        jac=jac,
        cost=0.5 * float(r @ r),
        n_iter=int(steps),
        n_fev=problem.n_fev + 2,
        n_jev=problem.n_jev + 1,
        converged=converged,
        message="converged (optimistix Cauchy criterion)"
        if converged
        else "maximum number of iterations reached",
        history=problem.history,
    )
