"""GMRES with a right preconditioner, for the large collocation systems of the corrector.

On a fine Fourier mesh (thousands of unknowns) the corrector's cost is the dense LU
factorisation of the bordered Jacobian, ``O(N^3)``, and forming the Jacobian itself.
Between two nearby Newton iterates, or two nearby points of a branch, the Jacobian changes
little; a factorisation taken at an earlier point is then an excellent preconditioner
``P``, and GMRES on ``A P^{-1} u = b``, ``x = P^{-1} u`` solves the current Newton system
``A x = b`` in a few iterations, each one Jacobian-vector product (``O(N^2)`` for the
dense Fourier differentiation, no Jacobian formed) and one triangular solve with the
stored factors (``O(N^2)``). The solve is to a stated relative residual, so Newton's
iterates and its convergence are those of the exact linear solves (Saad & Schultz 1986;
right preconditioning keeps the residual GMRES minimises the true one, checked again
explicitly at the end).

Written here rather than taken from ``scipy.sparse.linalg.gmres`` or ``lineax.GMRES``:
their stopping test is ``||b - A x|| <= max(rtol ||b||, atol)`` with ``atol`` fixed
before the solve, while a Newton step on a badly scaled collocation system needs the
normwise backward-error floor ``FLOOR ||A|| ||x||`` (below which no solver, a direct one
included, can go), with ``||A||`` and ``||x||`` estimated from the Krylov products as the
iteration proceeds; and lineax works on JAX operators, while the preconditioner here is
a SciPy LU applied on the host.

Used by :class:`bifid.continuation._correctors.NewtonCorrector` when it is built with
``krylov=True`` (the adaptive orbit runs of ``_mesh``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg

#: residual floor relative to ``||A|| ||x||`` (a normwise backward error): the product
#: with the dense Fourier differentiation matrix sums terms far larger than its result,
#: so the residual itself is computed only to a few hundred units of round-off
FLOOR = 1e-13


@dataclass
class KrylovResult:
    """Outcome of :func:`gmres`: the solution, the iterations taken, whether the relative
    residual reached the tolerance, and the final relative residual (recomputed)."""

    x: np.ndarray
    iterations: int
    converged: bool
    residual: float


def gmres(
    matvec: Callable[[np.ndarray], np.ndarray],
    precondition: Callable[[np.ndarray], np.ndarray],
    b: np.ndarray,
    *,
    rtol: float,
    max_iter: int,
) -> KrylovResult:
    """Solve ``A x = b`` by GMRES with the right preconditioner ``P`` (no restarts).

    Parameters
    ----------
    matvec : callable ``v -> A v``
    precondition : callable ``v -> P^{-1} v``
    b : ndarray of shape (N,)
    rtol : float
        Converged when ``||b - A x||_2 <= rtol ||b||_2``, or when the residual is down to
        what rounding allows a backward-stable solver (a direct one included),
        ``||b - A x||_2 <= FLOOR ||A|| ||x||`` (``||A||`` estimated from the products
        formed).
    max_iter : int
        Largest Krylov dimension.

    Returns
    -------
    KrylovResult
        ``converged`` is judged on the explicitly recomputed residual.

    Notes
    -----
    Arnoldi with classical Gram–Schmidt applied twice (orthogonal to working precision,
    and vectorised), Givens rotations on the Hessenberg matrix; the residual estimate
    ``|g_{k+1}|`` decides when to stop, the recomputed residual whether it converged.
    """
    b = np.asarray(b, dtype=float)
    n = b.shape[0]
    beta = float(np.linalg.norm(b))
    if beta == 0.0:
        return KrylovResult(np.zeros(n), 0, True, 0.0)
    if not math.isfinite(beta):
        return KrylovResult(np.full(n, np.nan), 0, False, math.inf)
    V = np.empty((max_iter + 1, n))
    H = np.zeros((max_iter + 1, max_iter))
    cs, sn = np.zeros(max_iter), np.zeros(max_iter)
    g = np.zeros(max_iter + 1)
    g[0] = beta
    V[0] = b / beta
    k = 0
    anorm, xnorm = 0.0, math.nan
    for j in range(max_iter):
        z = precondition(V[j])
        w = matvec(z)
        if not np.all(np.isfinite(w)):
            return KrylovResult(np.full(n, np.nan), j, False, math.inf)
        znorm = float(np.linalg.norm(z))
        if znorm > 0.0:
            anorm = max(anorm, float(np.linalg.norm(w)) / znorm)
        if j == 0:
            xnorm = beta * znorm  # ||P^{-1} b||: the size of the solution
        h = V[: j + 1] @ w
        w = w - h @ V[: j + 1]
        h2 = V[: j + 1] @ w
        w = w - h2 @ V[: j + 1]
        H[: j + 1, j] = h + h2
        hn = float(np.linalg.norm(w))
        H[j + 1, j] = hn
        for i in range(j):  # earlier rotations
            a, c = H[i, j], H[i + 1, j]
            H[i, j], H[i + 1, j] = cs[i] * a + sn[i] * c, -sn[i] * a + cs[i] * c
        rho = math.hypot(H[j, j], H[j + 1, j])
        cs[j], sn[j] = (1.0, 0.0) if rho == 0.0 else (H[j, j] / rho, H[j + 1, j] / rho)
        H[j, j], H[j + 1, j] = rho, 0.0
        g[j + 1] = -sn[j] * g[j]
        g[j] = cs[j] * g[j]
        k = j + 1
        target = max(rtol * beta, FLOOR * anorm * xnorm)
        if abs(g[j + 1]) <= target or not hn > 0.0:  # converged, or an exact solution
            break
        V[j + 1] = w / hn
    R = np.triu(H[:k, :k])
    if np.any(np.diag(R) == 0.0):
        return KrylovResult(np.full(n, np.nan), k, False, math.inf)
    coef = scipy.linalg.solve_triangular(R, g[:k], check_finite=False)
    x = precondition(coef @ V[:k])
    res = float(np.linalg.norm(b - matvec(x)))
    ok = res <= 10.0 * max(rtol * beta, FLOOR * anorm * float(np.linalg.norm(x)))
    return KrylovResult(x, k, bool(math.isfinite(res) and ok), res / beta)
