"""Correctors of the continuation driver: the zero problem and Newton's method on it.

A corrector solves the extended system ``[G(y); row . y - c] = 0`` near a prediction
and gives the unit tangent of the solution curve (:class:`AbstractCorrector`).
:class:`NewtonCorrector` is Newton's method with the exact Jacobian of a
:class:`ZeroProblem`; measured problems (a rig) implement their own (``bifid.cbc``).

Convergence is judged on the Newton update *relative to the size of the unknowns*,
``max|dy| <= tol * (1 + max|y|)`` (as AUTO and MatCont do), so the same tolerance serves
states of size 1e-3 and 1e3. The dense linear algebra runs in SciPy (LAPACK LU), which for
the few-hundred-unknown systems of collocation is several times faster on CPU than inside
XLA; the residual and Jacobian are jitted once per problem.
"""

from __future__ import annotations

import abc
import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
from threadpoolctl import threadpool_limits

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

    Converged when the update is small relative to the unknowns,
    ``max|dy| <= tol * (1 + max|y|)``, and the residual is finite.
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
            err = float(np.max(np.abs(dy))) / (1.0 + float(np.max(np.abs(y))))
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
    """Newton on ``[G(y, args); row . y - c] = 0`` from ``y_guess`` (converged when
    ``max|dy| <= tol * (1 + max|y|)``).

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
