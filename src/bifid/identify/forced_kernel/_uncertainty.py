r"""Intervals of a kernel model's predicted forced responses, from posterior function samples.

The Gaussian processes of ``a(ρ, Ω)`` and ``b(ρ, Ω)`` (eqs. 6.15, 6.19) were fitted with
their measurement noise as a hyperparameter; their posterior over functions (pathwise
conditioning, :meth:`~._state.ReducedFit.samples`, seeded) carries the uncertainty that
noise leaves in the reduced dynamics. Every posterior sample is a reduced model of its own;
its response is solved where the mean response was (:mod:`._bands`) and every predicted
quantity is read off each sample's response. An interval at level :math:`\ell` is the
central :math:`\ell` quantile of a quantity over the samples (an equal-tailed credible
interval at the fitted hyperparameters):

- **FRC points** (eq. 6.11): the amplitude ρ of each sample at the mean branch's phase ψ
  (ψ is a regular parameter along an FRC of a single-mode response).
- **FRC folds**: a fold of the mean curve is a local extremum of Ω(ψ); on each sample the
  extremum of the same kind within a window of the mean fold's index gives the sample's fold
  frequency and amplitude (a sample whose extremum lies on the window's edge has no fold
  there and is left out). Extrema are refined between the branch's points by the parabola
  through the extreme point and its neighbours.
- **Peak**: the sample's largest amplitude and its frequency (refined the same way).
- **S-curve points and folds**: the forcing ``F = sqrt(a² + (b − Ω)² ρ²)/κ`` of each sample at
  the mean branch's ρ, and its extrema near the mean's folds.
- **Backbone points** (eq. 6.21): the sample's frequency at each amplitude.

**Calibration of the spread.** At fitted hyperparameters the posterior is over-confident
when the selected noise level or length scales are too small (few points: the marginal
likelihood may interpolate the noise). The standardised leave-one-out residuals
:math:`z_i = [K_y^{-1}y]_i / \sqrt{[K_y^{-1}]_{ii}}` of both GPs (closed form, one Cholesky
factor) are standard normal when the posterior is calibrated; their split-conformal quantile
:math:`q_\ell` at level :math:`\ell` (:func:`~bifid.identify._intervals.conformal_quantile`)
against the normal one :math:`z_\ell` gives the factor
:math:`\lambda = \max(1, q_\ell / z_\ell)` by which every interval's distance from the mean
model's prediction is stretched (it never narrows an interval).

The intervals are on the response of the noise-free system (what the model predicts), not
on a new noisy measurement of it. Hyperparameters are held at their fitted values; their
uncertainty enters only through :math:`\lambda`.
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np

from bifid.continuation import Branch, Diagram
from bifid.identify._intervals import conformal_quantile, critical_value
from bifid.identify.forced_kernel._bands import (
    add_backbone_band,
    add_frc_band,
    add_scurve_band,
)
from bifid.identify.forced_kernel._state import ReducedFit

__all__ = ["add_intervals"]


@jax.jit
def _standardised_loo(chol: jnp.ndarray, alpha: jnp.ndarray) -> jnp.ndarray:
    """``[K_y⁻¹y]_i / sqrt([K_y⁻¹]_ii)`` from the Cholesky factor of ``K_y``."""
    kinv = jax.scipy.linalg.cho_solve((chol, True), jnp.eye(chol.shape[0], dtype=chol.dtype))
    return alpha / jnp.sqrt(jnp.diag(kinv))


def loo_scale(rf: ReducedFit, level: float) -> float:
    """The factor ``λ = max(1, q_ℓ / z_ℓ)`` of the module docstring (pooled over ``a`` and
    ``b``)."""
    z = np.concatenate(
        [
            np.asarray(_standardised_loo(st.chol, st.alpha))[np.asarray(st.mask) > 0]
            for st in (rf.gp_a.state_, rf.gp_b.state_)
        ]
    )
    q = conformal_quantile(z, level)
    if not np.isfinite(q):  # too few residuals for the level: the largest one
        q = float(np.max(np.abs(z)))
    return max(1.0, q / critical_value(level))


def _interval(
    samples: np.ndarray, level: float, centre: np.ndarray | float, scale: float
) -> tuple[np.ndarray, np.ndarray]:
    """Central ``level`` quantiles over axis 0 (samples), NaN-aware, their distances from
    ``centre`` (the mean model's value) stretched by ``scale``."""
    q = 0.5 * (1.0 - level)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        lo, hi = np.nanquantile(samples, q, axis=0), np.nanquantile(samples, 1.0 - q, axis=0)
    c = np.asarray(centre, dtype=float)
    return c + scale * (lo - c), c + scale * (hi - c)


def _sample_extrema(
    curves: np.ndarray, other: np.ndarray, mean: np.ndarray, index: int, window: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per sample, the local extremum of ``curves`` (S, n) of the same kind as the mean's at
    ``index`` (max or min), searched in ``index ± window`` and refined by the parabola
    through it and its neighbours, and ``other`` (S, n) interpolated there. NaN where the
    extremum sits on the window's edge (no extremum of that sample there)."""
    n = mean.size
    lo, hi = max(index - window, 0), min(index + window + 2, n)
    sign = 1.0 if mean[index] >= 0.5 * (mean[lo] + mean[hi - 1]) else -1.0
    seg = sign * curves[:, lo:hi]
    j = np.argmax(np.where(np.isfinite(seg), seg, -np.inf), axis=1)
    j = np.clip(j, 1, seg.shape[1] - 2)
    rows = np.arange(seg.shape[0])
    y0, y1, y2 = seg[rows, j - 1], seg[rows, j], seg[rows, j + 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.clip(np.where(y0 - 2 * y1 + y2 != 0, 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2), 0), -1, 1)
    ok = np.isfinite(y0 + y1 + y2) & (y1 >= y0) & (y1 >= y2)
    value = sign * (y1 - 0.25 * (y0 - y2) * d)
    oth = other[:, lo:hi]
    k = j + np.where(d >= 0, 1, -1)
    o = oth[rows, j] + np.abs(d) * (oth[rows, k] - oth[rows, j])
    return np.where(ok, value, np.nan), np.where(ok, o, np.nan)


def _frc_intervals(
    rf: ReducedFit, b: Branch, level: float, n_samples: int, seed: int, lam: float
) -> None:
    add_frc_band(rf, b, n_samples, level, seed)
    om_s, rho_s = b.data["sample_omega"], b.data["sample_amplitude"]
    lo, hi = _interval(rho_s, level, np.asarray(b.solutions)[:, 0], lam)
    b.intervals["amplitude"] = (lo[:, None], hi[:, None])
    window = max(len(b) // 10, 3)
    rho_mean = np.asarray(b.solutions)[:, 0]
    for sp in b.special_points:
        if sp.kind == "fold":
            om, rho = _sample_extrema(om_s, rho_s, np.asarray(b.params), int(sp.index), window)
        elif sp.kind == "peak":
            i = int(np.argmax(rho_mean))
            rho, om = _sample_extrema(rho_s, om_s, rho_mean, i, len(b))
        else:
            continue
        sp.intervals["param"] = tuple(float(v) for v in _interval(om, level, sp.param, lam))
        a_lo, a_hi = _interval(rho, level, float(np.ravel(sp.data["amplitude"])[0]), lam)
        sp.intervals["amplitude"] = ([float(a_lo)], [float(a_hi)])


def _scurve_intervals(
    rf: ReducedFit, b: Branch, level: float, n_samples: int, seed: int, lam: float
) -> None:
    add_scurve_band(rf, b, n_samples, level, seed)
    f_s = b.data["sample_forcing"]
    b.intervals["forcing"] = _interval(f_s, level, np.asarray(b.params, float), lam)
    window = max(len(b) // 10, 3)
    for sp in b.special_points:
        if sp.kind == "fold":
            f, _ = _sample_extrema(f_s, f_s, np.asarray(b.params, float), int(sp.index), window)
            sp.intervals["param"] = tuple(float(v) for v in _interval(f, level, sp.param, lam))


def add_intervals(
    rf: ReducedFit, diagram: Diagram, level: float, n_samples: int, seed: int
) -> None:
    """Fill ``intervals`` of a predicted FRC, S-curve or backbone and of its folds and peak
    at ``level`` from ``n_samples`` posterior samples (module docstring); sets
    ``diagram.level``."""
    lam = loo_scale(rf, level)
    for b in diagram.branches:
        b.meta["interval_scale"] = lam
        if diagram.kind == "frc":
            _frc_intervals(rf, b, level, n_samples, seed, lam)
        elif diagram.kind == "scurve":
            _scurve_intervals(rf, b, level, n_samples, seed, lam)
        else:
            add_backbone_band(rf, b, n_samples, level, seed)
            b.intervals["omega"] = _interval(b.data["sample_omega"], level, b.data["omega"], lam)
    diagram.level = level
