"""Hyperparameter search of the kernel models and its curvature.

:func:`minimize_multistart` is SciPy's L-BFGS-B (gradients by JAX) from seeded random
starts within log-bounds; :func:`laplace_log_errors` turns the curvature of the same
objective at its minimum into standard errors (the Laplace approximation). Both serve the
Gaussian processes (:mod:`._gp`) and the forcing scale's joint fit (:mod:`._fitting`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import numpy as np
import scipy.optimize

from bifid.errors import ConvergenceError

__all__ = ["laplace_log_errors", "minimize_multistart"]


def minimize_multistart(
    value_and_grad: Any,
    theta0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    *,
    n_restarts: int = 0,
    seed: int = 0,
    maxiter: int = 300,
    ftol: float = 1e-8,
) -> scipy.optimize.OptimizeResult:
    """L-BFGS-B from ``theta0`` and ``n_restarts`` seeded random starts; the best result.

    ``value_and_grad(theta) -> (value, grad)`` (JAX arrays are fine); ``ftol`` is
    L-BFGS-B's relative tolerance on the objective. Non-finite values
    are reported to the optimiser as a huge value (it then shortens the step).

    Raises
    ------
    ConvergenceError
        If every start ends without a finite objective.
    """

    def fun(th: np.ndarray) -> tuple[float, np.ndarray]:
        v, g = value_and_grad(th)
        v = float(v)
        g = np.asarray(g, dtype=float)
        if not (math.isfinite(v) and np.all(np.isfinite(g))):
            return 1e25, np.zeros_like(th)
        return v, g

    rng = np.random.default_rng(seed)
    starts = [np.clip(np.asarray(theta0, dtype=float), lo, hi)]
    mid_lo = np.maximum(lo, starts[0] - 1.5)
    mid_hi = np.minimum(hi, starts[0] + 1.5)
    for _ in range(max(0, int(n_restarts))):
        starts.append(rng.uniform(mid_lo, mid_hi))
    best = None
    nfev = 0
    for th0 in starts:
        res = scipy.optimize.minimize(
            fun,
            th0,
            jac=True,
            method="L-BFGS-B",
            bounds=list(zip(lo, hi, strict=True)),
            options={"maxiter": maxiter, "ftol": ftol},
        )
        nfev += int(res.nfev)
        if math.isfinite(res.fun) and res.fun < 1e24 and (best is None or res.fun < best.fun):
            best = res
    if best is None:
        raise ConvergenceError(
            "GP hyperparameter optimisation failed from every start (the kernel matrix "
            "was never positive definite); check the data for duplicates or outliers."
        )
    best.nfev_total = nfev
    return best


def laplace_log_errors(
    gradient: Callable[[jnp.ndarray], Any],
    z: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    step: float = 1e-4,
) -> np.ndarray:
    """Standard errors of log-parameters ``z`` at a minimum of a negative log likelihood.

    The Laplace approximation: covariance = inverse Hessian, the Hessian by central
    differences of ``gradient`` (step ``step`` in ``z``). A component within ``1e-3`` of a
    search bound (``lo``, ``hi``) is not identified by the data: NaN, and it is left out
    of the Hessian; a direction of zero or negative curvature gives ``inf``.
    """
    z = np.asarray(z, dtype=float)
    hess = np.empty((z.size, z.size))
    for i in range(z.size):
        dz = np.zeros(z.size)
        dz[i] = step
        g_plus = np.asarray(gradient(jnp.asarray(z + dz)), dtype=float)
        g_minus = np.asarray(gradient(jnp.asarray(z - dz)), dtype=float)
        hess[i] = (g_plus - g_minus) / (2 * step)
    free = (z > np.asarray(lo) + 1e-3) & (z < np.asarray(hi) - 1e-3)
    var = np.full(z.size, np.nan)
    if np.any(free):
        lam, vec = np.linalg.eigh(0.5 * (hess + hess.T)[np.ix_(free, free)])
        inv_lam = np.where(lam > 0, 1.0 / np.where(lam > 0, lam, 1.0), np.inf)
        with np.errstate(invalid="ignore"):  # 0 · inf where a direction has no loading
            var[free] = np.nansum(vec**2 * inv_lam, axis=1)
    return np.sqrt(var)
