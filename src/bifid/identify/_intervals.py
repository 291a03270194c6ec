r"""Shared statistics of bifid's intervals: Gauss–Newton covariance, the delta method through
an implicit-function Jacobian, split-conformal quantiles and a binomial coverage test.

**Gauss–Newton covariance.** For a least-squares fit :math:`\hat\theta` of :math:`m`
residuals :math:`r(\theta)` with Jacobian :math:`J` (:math:`m\times k`),

.. math:: \widehat{\mathrm{Cov}}(\hat\theta) = \hat\sigma^2 (J^\mathsf{T}J)^{+},\qquad
          \hat\sigma^2 = \frac{r^\mathsf{T}r}{m-k},

the noise variance estimated from the residuals (the measurement noise is not assumed
known). Intervals use Student's :math:`t` with :math:`m-k` degrees of freedom, which is
what makes them hold at small :math:`m`.

**Delta method.** A predicted quantity :math:`q(\theta)` (a Hopf speed, a fold's amplitude)
has :math:`\mathrm{Var}\,q \approx g^\mathsf{T}\,\mathrm{Cov}(\hat\theta)\,g` with
:math:`g = \partial q/\partial\theta`. When :math:`q` is a component of the solution
:math:`z` of an extended system :math:`H(z,\theta) = 0` (a located Hopf point or fold),
:math:`g` comes from the implicit-function theorem,
:math:`\partial z/\partial\theta = -H_z^{-1}H_\theta` (:func:`implicit_sensitivity`).

**Split conformal.** For held-out absolute residuals :math:`s_1..s_n`, the interval
:math:`\hat q \pm s_{(\lceil (n+1)\ell\rceil)}` holds a new point with probability at least
:math:`\ell` whatever the model (:func:`conformal_quantile`).

**Coverage test.** :func:`coverage_test`: of :math:`n` intervals at level :math:`\ell`,
:math:`k` held the truth; two-sided exact binomial test of :math:`P(\text{hit}) = \ell`
(:func:`scipy.stats.binomtest`) with the Clopper–Pearson interval of the rate.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.stats

from bifid.errors import BifidInputError, ConvergenceError

__all__ = [
    "Covariance",
    "check_level",
    "conformal_quantile",
    "coverage_test",
    "critical_value",
    "gauss_newton_covariance",
    "implicit_sensitivity",
    "warn_extrapolation",
]


def check_level(level: Any) -> float:
    """``level`` as a float in (0, 1), else :class:`BifidInputError`."""
    try:
        lv = float(level)
    except (TypeError, ValueError):
        raise BifidInputError(f"level must be a number in (0, 1), got {level!r}.") from None
    if not 0.0 < lv < 1.0:
        raise BifidInputError(f"level must lie in (0, 1), got {level!r}.")
    return lv


def critical_value(level: float, dof: float | None = None) -> float:
    """Two-sided critical value: the ``(1 + level)/2`` quantile of Student's t with ``dof``
    degrees of freedom (the normal distribution when ``dof`` is None)."""
    q = 0.5 * (1.0 + check_level(level))
    if dof is None or not math.isfinite(dof):
        return float(scipy.stats.norm.ppf(q))
    return float(scipy.stats.t.ppf(q, dof))


@dataclass(frozen=True)
class Covariance:
    """Covariance of estimated parameters, by name.

    Attributes
    ----------
    names : tuple of str
    cov : ndarray of shape (k, k)
    dof : int
        Residual degrees of freedom ``m - k`` (Student's t of the intervals).
    sigma : float
        Residual standard deviation (in the units of the fitted residuals).
    directions : ndarray of shape (k, n), optional
        How a unit change of each estimated parameter moves a full parameter vector (a
        tied parameter moves with the one it is tied to); see :meth:`project`.
    """

    names: tuple[str, ...]
    cov: np.ndarray
    dof: int
    sigma: float
    directions: np.ndarray | None = None

    def project(self, gradient: np.ndarray) -> np.ndarray:
        """Gradients ``(..., n)`` in a full parameter vector as gradients ``(..., k)`` in the
        estimated parameters (``directions`` (k, n): how each moves the full vector)."""
        g = np.asarray(gradient, dtype=float)
        return g if self.directions is None else g @ self.directions.T

    def standard_errors(self) -> dict[str, float]:
        """``sqrt(diag(cov))`` by name."""
        se = np.sqrt(np.maximum(np.diag(self.cov), 0.0))
        return {n: float(s) for n, s in zip(self.names, se, strict=True)}

    def std(self, gradient: np.ndarray) -> np.ndarray:
        """Delta-method standard deviation of quantities with gradients ``(..., k)``."""
        g = np.asarray(gradient, dtype=float)
        return np.sqrt(np.maximum(np.einsum("...i,ij,...j->...", g, self.cov, g), 0.0))

    def interval(
        self, value: np.ndarray | float, gradient: np.ndarray, level: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """``value ± t_{(1+level)/2, dof} * std`` (delta method)."""
        half = critical_value(level, self.dof) * self.std(gradient)
        v = np.asarray(value, dtype=float)
        return v - half, v + half


def warn_extrapolation(
    param: str, predicted: tuple[float, float], trained: tuple[float, float], stacklevel: int = 3
) -> None:
    """Warn (``UserWarning``) when the ``predicted`` parameter range leaves the ``trained``
    one: intervals there rest on the model's form, not on data."""
    (a, b), (lo, hi) = predicted, trained
    if a < lo or b > hi:
        warnings.warn(
            f"the prediction over {param} = {a:g}..{b:g} extrapolates beyond the trained "
            f"range {lo:g}..{hi:g}: its intervals rest on the model's form there, not on data.",
            UserWarning,
            stacklevel=stacklevel + 1,
        )


def gauss_newton_covariance(
    names: tuple[str, ...], jac: np.ndarray, residuals: np.ndarray
) -> Covariance:
    """Covariance ``sigma² (JᵀJ)⁺`` at a least-squares fit, ``sigma²`` from the residuals.

    Raises
    ------
    BifidInputError
        With no more residuals than parameters (no degrees of freedom left to estimate
        the noise).
    """
    J = np.asarray(jac, dtype=float)
    r = np.asarray(residuals, dtype=float).ravel()
    m, k = J.shape
    if m <= k:
        raise BifidInputError(
            f"{m} residuals for {k} parameters leave no degree of freedom to estimate the "
            "measurement noise; intervals need more measured points than free parameters."
        )
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r))):
        raise ConvergenceError("non-finite residuals or Jacobian at the fit: no covariance.")
    sigma2 = float(r @ r) / (m - k)
    return Covariance(tuple(names), sigma2 * np.linalg.pinv(J.T @ J), m - k, math.sqrt(sigma2))


def implicit_sensitivity(h_z: np.ndarray, h_theta: np.ndarray) -> np.ndarray:
    """``dz/dθ = -H_z⁻¹ H_θ`` of a solution of ``H(z, θ) = 0`` (implicit-function theorem).

    Raises
    ------
    ConvergenceError
        If ``H_z`` is singular (the located point is degenerate).
    """
    Hz = np.asarray(h_z, dtype=float)
    if not np.all(np.isfinite(Hz)) or np.linalg.cond(Hz) > 1e14:
        raise ConvergenceError(
            "the extended system of a located point is singular: its sensitivity to the "
            "parameters is undefined (a degenerate point)."
        )
    return -np.linalg.solve(Hz, np.asarray(h_theta, dtype=float))


def conformal_quantile(scores: np.ndarray, level: float) -> float:
    """Split-conformal half-width: the ``ceil((n+1) level)``-th smallest of ``scores``.

    Returns ``inf`` when ``n`` is too small for the level (``ceil((n+1) level) > n``).
    """
    s = np.sort(np.abs(np.asarray(scores, dtype=float).ravel()))
    s = s[np.isfinite(s)]
    k = math.ceil((s.size + 1) * check_level(level))
    return float(s[k - 1]) if 1 <= k <= s.size else math.inf


def coverage_test(hits: np.ndarray, level: float, alpha: float = 0.01) -> dict[str, Any]:
    """Empirical coverage of intervals at ``level`` and a two-sided exact binomial test.

    Parameters
    ----------
    hits : array of bool
        Whether each interval held the truth.
    level : float
        The nominal level.
    alpha : float
        Significance of the test.

    Returns
    -------
    dict
        ``n``, ``covered``, ``rate``, ``p_value``, ``rejected`` (p < alpha) and
        ``rate_ci`` (Clopper–Pearson at ``1 - alpha``).
    """
    h = np.asarray(hits, dtype=bool).ravel()
    if h.size == 0:
        raise BifidInputError("coverage_test needs at least one interval.")
    k, n = int(h.sum()), int(h.size)
    res = scipy.stats.binomtest(k, n, check_level(level))
    ci = res.proportion_ci(confidence_level=1.0 - alpha, method="exact")
    return {
        "n": n,
        "covered": k,
        "rate": k / n,
        "p_value": float(res.pvalue),
        "rejected": bool(res.pvalue < alpha),
        "rate_ci": [float(ci.low), float(ci.high)],
    }
