"""Correctors of the continuation driver: the zero problem and Newton's method on it.

A corrector solves the extended system ``[G(y); row . y - c] = 0`` near a prediction
and gives the unit tangent of the solution curve (:class:`AbstractCorrector`).
:class:`NewtonCorrector` is Newton's method with the exact Jacobian of a
:class:`ZeroProblem`; measured problems (a rig) implement their own (``bifid.cbc``).

Convergence is judged on the Newton update *relative to the size of the unknowns*,
``max|dy| <= tol * (1 + max|y|)`` (as AUTO and MatCont do), so the same tolerance serves
states of size 1e-3 and 1e3. The dense linear algebra runs in SciPy (LAPACK LU), which for
the few-hundred-unknown systems of collocation is several times faster on CPU than inside
XLA; the residual, the Jacobian and the Jacobian-vector product are jitted once per problem.

The LU factorisation is the cost of a step on a fine collocation mesh (thousands of
unknowns), so it is reused wherever that changes nothing but the cost:

* **last Newton iteration** — once the corrections converge quadratically and the next one
  is predicted below the tolerance (``C e_k^2 <= tol / 10`` with ``C = e_k / e_{k-1}^2``
  measured), the iteration reuses the factorisation of the previous one: the update
  differs from Newton's by ``O(e_k e_{k+1})``, far below the tolerance, and the iteration
  count is Newton's;
* **tangent** — the tangent at the corrected point ``y`` solves ``[G_y(y); r^T] t = e``
  with the same bordering row ``r`` as the corrector's last factorisation, taken at an
  iterate within the last correction of ``y``: it is solved with that factorisation and
  refined to round-off by iterative refinement with the exact product ``G_y(y) t``
  (a Jacobian-vector product, no new Jacobian). A different row is a rank-one change of
  the last row (Sherman–Morrison). Where refinement does not converge in
  :data:`REFINE_STEPS` sweeps the tangent is factorised afresh.

Problems with fewer than :data:`REUSE_MIN_UNKNOWNS` unknowns factorise afresh each time
(their factorisation is cheaper than compiling the extra functions). The bordered matrix
is factorised as its transpose, which is the C-ordered array itself (no copy), and solved
with ``trans=1``.
"""

from __future__ import annotations

import abc
import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

from bifid.continuation._blas import one_blas_thread
from bifid.continuation._krylov import gmres

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


#: problems with at least this many unknowns reuse factorisations (below it a
#: factorisation costs less than compiling the extra residual and Jacobian-vector product)
REUSE_MIN_UNKNOWNS = 400
#: a corrector built with ``krylov=True`` solves its Newton systems by GMRES (with a stored
#: factorisation as the preconditioner) from this many unknowns on (below it the dense
#: factorisation is cheap)
KRYLOV_MIN_UNKNOWNS = 1000
#: relative residual of a Newton step solved by GMRES (Newton's iterates to far below its
#: tolerance)
KRYLOV_RTOL = 1e-10
#: relative residual of a tangent solved by GMRES
KRYLOV_TANGENT_RTOL = 1e-12
#: largest Krylov dimension; a system not solved within it is factorised afresh
KRYLOV_MAX_ITER = 40
#: a solve that needs more GMRES iterations than this refactorises at the next solve
KRYLOV_REFRESH = 12
#: iterative-refinement sweeps of a tangent solved with a reused factorisation
REFINE_STEPS = 4
#: a reused factorisation's tangent is accepted when the refinement's last update is
#: below this (relative to the tangent)
REFINE_TOL = 1e-13


@functools.lru_cache(maxsize=128)
def _evaluator(problem: ZeroProblem) -> Callable:
    """Jitted ``(y, args) -> (G(y), G_y(y))``, compiled once per problem."""
    J = problem.jacobian if problem.jacobian is not None else jax.jacfwd(problem.residual)

    @jax.jit
    def both(y: Array, args: Any):
        return problem.residual(y, args), J(y, args)

    return both


@functools.lru_cache(maxsize=128)
def _residual_evaluator(problem: ZeroProblem) -> Callable:
    """Jitted ``(y, args) -> G(y)``."""
    return jax.jit(problem.residual)


@functools.lru_cache(maxsize=128)
def _jvp_evaluator(problem: ZeroProblem) -> Callable:
    """Jitted ``(y, v, args) -> G_y(y) v`` (forward mode: no Jacobian is formed)."""

    @jax.jit
    def jvp(y: Array, v: Array, args: Any):
        return jax.jvp(lambda z: problem.residual(z, args), (y,), (v,))[1]

    return jvp


@dataclass
class _Factorisation:
    """LU of the bordered matrix ``[G_y(y); row^T]``."""

    lu: np.ndarray
    piv: np.ndarray
    y: np.ndarray
    row: np.ndarray
    args: Any = None

    def solve(self, b: np.ndarray) -> np.ndarray:
        # lu holds the factors of the transpose (see _factor)
        return scipy.linalg.lu_solve((self.lu, self.piv), b, trans=1, check_finite=False)

    @property
    def det_sign(self) -> float:
        swaps = np.count_nonzero(self.piv != np.arange(self.piv.shape[0]))
        return float((-1) ** swaps * np.prod(np.sign(np.diag(self.lu))))


def _factor(Jm: np.ndarray, row: np.ndarray, y: np.ndarray, args: Any = None) -> _Factorisation:
    n = Jm.shape[0]
    A = np.empty((n + 1, Jm.shape[1]))
    A[:n] = Jm
    A[n] = row
    with np.errstate(all="ignore"):
        # A.T is Fortran-ordered without a copy: LU of A^T, solved with trans=1 (det equal)
        lu, piv = scipy.linalg.lu_factor(A.T, overwrite_a=True, check_finite=False)
    return _Factorisation(lu, piv, np.array(y, dtype=float), np.array(row, dtype=float), args)


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
    def tangent(
        self, y: np.ndarray, t_prev: np.ndarray, weights: np.ndarray, args: Any
    ) -> tuple[np.ndarray, float]:
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
    ``max|dy| <= tol * (1 + max|y|)``, and the residual is finite. The factorisation is
    reused for a last iteration predicted to converge and for the tangent (module
    docstring); the iteration counts and results are Newton's.
    """

    def __init__(
        self,
        problem: ZeroProblem,
        *,
        tol: float = 1e-10,
        max_iter: int = 10,
        krylov: bool = False,
    ) -> None:
        self.problem = problem
        self.tol = float(tol)
        self.max_iter = int(max_iter)
        self.krylov = bool(krylov)
        self._both = _evaluator(problem)
        self._residual = _residual_evaluator(problem)
        self._jvp = _jvp_evaluator(problem)
        self._last: _Factorisation | None = None
        self._stale = False
        #: work done: factorisations, Krylov solves and their iterations
        self.stats = {"factorisations": 0, "krylov_solves": 0, "krylov_iterations": 0}

    def evaluate(self, y: np.ndarray, args: Any) -> tuple[np.ndarray, np.ndarray]:
        """``G(y)`` and ``G_y(y)`` as NumPy arrays."""
        G, Jm = self._both(y, args)
        return np.asarray(G), np.asarray(Jm)

    def residual(self, y: np.ndarray, args: Any) -> np.ndarray:
        """``G(y)`` as a NumPy array (no Jacobian on large problems)."""
        if np.shape(y)[0] < REUSE_MIN_UNKNOWNS:
            return np.asarray(self._both(y, args)[0])
        return np.asarray(self._residual(y, args))

    def _uses_krylov(self, y: np.ndarray) -> bool:
        return self.krylov and np.shape(y)[0] >= KRYLOV_MIN_UNKNOWNS

    def _factor(self, y: np.ndarray, row: np.ndarray, args: Any) -> _Factorisation | None:
        """Factorise ``[G_y(y); row^T]`` (None when the Jacobian is not finite)."""
        _, Jm = self.evaluate(y, args)
        if not np.all(np.isfinite(Jm)):
            return None
        self.stats["factorisations"] += 1
        return _factor(Jm, row, y, args)

    def _krylov_solve(
        self, y: np.ndarray, row: np.ndarray, b: np.ndarray, args: Any, rtol: float
    ) -> np.ndarray | None:
        """``[G_y(y); row^T] x = b`` by GMRES preconditioned with the stored factorisation
        (None when there is none, or GMRES does not reach ``rtol``); a solve that needed
        more than :data:`KRYLOV_REFRESH` iterations marks the factorisation stale."""
        f = self._last
        if f is None or self._stale or f.y.shape != y.shape:
            return None

        def matvec(v: np.ndarray) -> np.ndarray:
            return np.concatenate([np.asarray(self._jvp(y, v, args)), [row @ v]])

        out = gmres(matvec, f.solve, b, rtol=rtol, max_iter=KRYLOV_MAX_ITER)
        self.stats["krylov_solves"] += 1
        self.stats["krylov_iterations"] += out.iterations
        if not out.converged:
            self._stale = True
            return None
        if out.iterations > KRYLOV_REFRESH:
            self._stale = True
        return out.x

    def _correct_krylov(self, y_pred: np.ndarray, row: np.ndarray, c: float, args: Any):
        """Newton with the linear systems solved by preconditioned GMRES (module
        :mod:`~bifid.continuation._krylov`); the Jacobian is formed and factorised only
        when the stored factorisation no longer makes a good preconditioner."""
        y = np.asarray(y_pred, dtype=float).copy()
        err = np.inf
        it = 0
        while it < self.max_iter:
            G = self.residual(y, args)
            r = np.concatenate([G, [row @ y - float(c)]])
            if not np.all(np.isfinite(r)):
                return Correction(y, False, it, np.inf)
            dy = self._krylov_solve(y, row, -r, args, KRYLOV_RTOL)
            if dy is None:
                f = self._factor(y, row, args)
                if f is None:
                    return Correction(y, False, it, np.inf)
                self._last, self._stale = f, False
                dy = f.solve(-r)
            if not np.all(np.isfinite(dy)):
                return Correction(y, False, it, np.inf)
            y = y + dy
            it += 1
            err = float(np.max(np.abs(dy))) / (1.0 + float(np.max(np.abs(y))))
            if err <= self.tol:
                break
        res = float(np.max(np.abs(self.residual(y, args))))
        return Correction(y, bool(err <= self.tol and np.isfinite(res)), it, res)

    def correct(self, y_pred: np.ndarray, row: np.ndarray, c: float, args: Any) -> Correction:
        if self._uses_krylov(y_pred):
            return self._correct_krylov(y_pred, np.asarray(row, dtype=float), c, args)
        y = np.asarray(y_pred, dtype=float).copy()
        row = np.asarray(row, dtype=float)
        large = y.shape[0] >= REUSE_MIN_UNKNOWNS
        err, err_prev = np.inf, np.inf
        fact: _Factorisation | None = None
        reuse = False
        it = 0
        while it < self.max_iter:
            if reuse and fact is not None:
                G = self.residual(y, args)
            else:
                G, Jm = self.evaluate(y, args)
                if not np.all(np.isfinite(Jm)):
                    return Correction(y, False, it, np.inf)
                fact = _factor(Jm, row, y, args)
                self.stats["factorisations"] += 1
            r = np.concatenate([G, [row @ y - float(c)]])
            if not np.all(np.isfinite(r)):
                return Correction(y, False, it, np.inf)
            dy = fact.solve(-r)
            if not np.all(np.isfinite(dy)):
                return Correction(y, False, it, np.inf)
            y = y + dy
            it += 1
            err_prev, err = err, float(np.max(np.abs(dy))) / (1.0 + float(np.max(np.abs(y))))
            if err <= self.tol:
                break
            # reuse the factorisation for one iteration predicted (from the measured
            # quadratic convergence) to end below the tolerance; never twice in a row
            reuse = (
                large
                and not reuse
                and np.isfinite(err_prev)
                and err < err_prev
                and err**3 <= 0.1 * self.tol * err_prev**2
            )
        if fact is not None and large:
            self._last = fact
        res = float(np.max(np.abs(self.residual(y, args))))
        return Correction(y, bool(err <= self.tol and np.isfinite(res)), it, res)

    def tangent(self, y, t_prev, weights, args):
        # [G_y; (W t_prev)^T] t = [0; 1]
        y = np.asarray(y, dtype=float)
        w = np.asarray(weights, dtype=float)
        row = w * np.asarray(t_prev, dtype=float)
        rhs = np.zeros(y.shape[0])
        rhs[-1] = 1.0
        if self._uses_krylov(y):
            found = self._krylov_tangent(y, row, rhs, args)
        else:
            found = self._refined_tangent(y, row, rhs, args)
        if found is None:
            _, Jm = self.evaluate(y, args)
            fact = _factor(Jm, row, y, args)
            self.stats["factorisations"] += 1
            if y.shape[0] >= REUSE_MIN_UNKNOWNS:
                self._last, self._stale = fact, False
            found = fact.solve(rhs), fact.det_sign
        t, sign = found
        t = t / np.sqrt(t @ (w * t))
        return t, sign

    def _krylov_tangent(
        self, y: np.ndarray, row: np.ndarray, rhs: np.ndarray, args: Any
    ) -> tuple[np.ndarray, float] | None:
        """The tangent system by preconditioned GMRES; the determinant's sign is that of
        the stored factorisation where it was taken within the last correction of ``y``
        (as for :meth:`_refined_tangent`), else unknown (NaN)."""
        t = self._krylov_solve(y, row, rhs, args, KRYLOV_TANGENT_RTOL)
        if t is None:
            return None
        f = self._last
        if float(np.max(np.abs(f.y - y))) > 1e-4 * (1.0 + float(np.max(np.abs(y)))):
            return t, math.nan
        e = np.zeros_like(rhs)
        e[-1] = 1.0
        denom = 1.0 + float((row - f.row) @ f.solve(e))
        if not (np.isfinite(denom) and abs(denom) > 1e-12):
            return t, math.nan
        return t, f.det_sign * float(np.sign(denom))

    def _refined_tangent(
        self, y: np.ndarray, row: np.ndarray, rhs: np.ndarray, args: Any
    ) -> tuple[np.ndarray, float] | None:
        """Solve ``[G_y(y); row^T] t = rhs`` with the last factorisation (taken near ``y``,
        perhaps with another last row) and iterative refinement; None when it does not
        converge."""
        f = self._last
        if f is None or f.args is not args or f.y.shape != y.shape:
            return None
        scale = 1.0 + float(np.max(np.abs(y)))
        if float(np.max(np.abs(f.y - y))) > 1e-4 * scale:
            return None
        # a changed last row is the rank-one update A' = A + e (row - f.row)^T
        e = np.zeros_like(rhs)
        e[-1] = 1.0
        delta = row - f.row
        u = f.solve(e) if np.any(delta) else None
        denom = 1.0 + float(delta @ u) if u is not None else 1.0
        if not (np.isfinite(denom) and abs(denom) > 1e-12):
            return None

        def solve(b):
            x = f.solve(b)
            return x if u is None else x - u * (float(delta @ x) / denom)

        t = solve(rhs)
        for _ in range(REFINE_STEPS):
            At = np.concatenate([np.asarray(self._jvp(y, t, args)), [row @ t]])
            dt = solve(rhs - At)
            t = t + dt
            if not np.all(np.isfinite(t)):
                return None
            if float(np.max(np.abs(dt))) <= REFINE_TOL * float(np.max(np.abs(t))):
                return t, f.det_sign * float(np.sign(denom))
        return None


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
    with one_blas_thread():
        r = corrector.correct(
            np.asarray(y_guess, dtype=float), np.asarray(row, dtype=float), float(c), args
        )
    return np.asarray(r.y), bool(r.converged), int(r.iterations), float(r.residual)


def tangent_at(
    problem: ZeroProblem, y: Array, t_prev: Array, args: Any, weights: Array | None = None
) -> np.ndarray:
    """Unit tangent at ``y`` oriented like ``t_prev``."""
    y = np.asarray(y, dtype=float)
    w = np.ones_like(y) if weights is None else np.asarray(weights, dtype=float)
    t, _ = NewtonCorrector(problem).tangent(y, np.asarray(t_prev, dtype=float), w, args)
    return np.asarray(t)
