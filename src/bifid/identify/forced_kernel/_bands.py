r"""Posterior-sample bands of predicted forced responses, and how often they hold the truth.

Posterior function samples of ``a`` and ``b`` (pathwise conditioning,
:meth:`~._state.ReducedFit.samples`) are continued like the mean: FRC samples are solved at
the phases ψ of the mean branch (ψ is a regular parameter along an FRC of a single-mode
response), S-curve and backbone samples at the same ρ. The band is the central ``level``
quantile of the samples' offsets from the mean curve along its normal (FRC: in coordinates
scaled by the curve's extent) or along F (S-curve) / Ω (backbone). It is the spread of the
Gaussian-process posterior at fitted hyperparameters — a credible band under the model, not
a calibrated confidence interval (:func:`band_coverage` measures how often it holds a known
truth).
"""

from __future__ import annotations

import warnings
from typing import Any

import jax.numpy as jnp
import numpy as np
from scipy.interpolate import CubicSpline

from bifid.continuation import Branch
from bifid.errors import BifidInputError
from bifid.identify.forced_kernel._reduced import (
    ReducedSamples,
    ab_grid_samples,
    backbone_samples,
    frc_samples_at_psi,
)
from bifid.identify.forced_kernel._state import ReducedFit

__all__ = [
    "add_backbone_band",
    "add_frc_band",
    "add_scurve_band",
    "backbone_sample_omega",
    "band_coverage",
    "branch_key",
    "frc_sample_curves",
    "scurve_sample_forcing",
]


#: residual (relative to the forcing term Γ) below which a sampled FRC point is solved
FRC_SAMPLE_TOL = 1e-6


def _band_meta(level: float, n_samples: int, seed: int, **extra: float) -> dict[str, Any]:
    """``Branch.meta["band"]`` of a posterior-sample band."""
    return {
        "kind": "posterior samples",
        "level": level,
        "n_samples": n_samples,
        "seed": seed,
        **extra,
    }


def _quantiles(values: np.ndarray, level: float) -> np.ndarray:
    q = (1.0 - level) / 2.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.stack(
            [np.nanquantile(values, q, axis=0), np.nanquantile(values, 1.0 - q, axis=0)], axis=1
        )


def branch_key(branch: Branch) -> tuple[bytes, bytes]:
    """A key of a predicted branch's points (for :meth:`ReducedFit.cached`)."""
    return (
        np.asarray(branch.params, dtype=float).tobytes(),
        np.asarray(branch.solutions, dtype=float).tobytes(),
    )


def frc_sample_curves(
    rf: ReducedFit, branch: Branch, samples: ReducedSamples
) -> tuple[np.ndarray, np.ndarray]:
    """Every sampled reduced model's FRC ``(Ω, ρ)`` (S, n) at the phases of the mean
    ``branch``; NaN where the solve failed."""
    gamma = rf.forcing_scale * float(branch.data["forcing"][0])  # κF; Γ(Ω) in the solve
    rho, psi, om = branch.solutions[:, 0], branch.solutions[:, 1], branch.params
    u, res = frc_samples_at_psi(rf.model, samples, jnp.asarray(gamma), psi, rho, om)
    r_s, o_s, res = np.asarray(u[..., 0]), np.asarray(u[..., 1]), np.asarray(res)
    # A converged solve leaves the rounding floor of evaluating a sampled function (1e-10
    # to 1e-9 of the forcing term where the kernel matrices are ill-conditioned); a solve
    # that failed (diverged, or no solution near the mean's) leaves a far larger one.
    bad = ~(
        np.isfinite(res)
        & (res < FRC_SAMPLE_TOL * max(gamma, 1e-300))
        & (r_s > 0)
        & np.isfinite(o_s)
    )
    return np.where(bad, np.nan, o_s), np.where(bad, np.nan, r_s)


def scurve_sample_forcing(rf: ReducedFit, branch: Branch, samples: ReducedSamples) -> np.ndarray:
    """Every sampled reduced model's forcing ``F`` (S, n) at the amplitudes of the mean
    S-curve ``branch``."""
    rho = branch.solutions[:, 0]
    om = branch.data["omega"]
    a_s, b_s = (np.asarray(v) for v in ab_grid_samples(rf.model, samples, rho, om))
    return np.sqrt(a_s**2 + (b_s - om) ** 2 * rho**2) / rf.gamma(1.0, om)


def backbone_sample_omega(rf: ReducedFit, branch: Branch, samples: ReducedSamples) -> np.ndarray:
    """Every sampled reduced model's backbone frequency (S, n) at the amplitudes of the
    mean backbone ``branch``; NaN where the solve failed."""
    om = branch.data["omega"]
    om_s, res_s = (
        np.asarray(v)
        for v in backbone_samples(rf.model, samples, branch.params, jnp.asarray(om[0]))
    )
    tol = 1e-9 * max(abs(float(branch.meta.get("backbone_start", om[0]))), 1.0)
    return np.where(res_s < tol, om_s, np.nan)


def add_frc_band(rf: ReducedFit, branch: Branch, n_samples: int, level: float, seed: int) -> None:
    """Add the posterior-sample band of an FRC to ``branch.data`` (``band_lower`` /
    ``band_upper`` (n, 2) as (Ω, amplitude) points, ``band_offset``, ``normal``,
    ``sample_omega`` / ``sample_amplitude`` (S, n)) and ``branch.meta["band"]``."""
    s_om, s_rho = branch.meta["scales"]["omega"], branch.meta["scales"]["amplitude"]
    rho, om = branch.solutions[:, 0], branch.params
    o_s, r_s = rf.cached(
        ("frc", n_samples, seed, *branch_key(branch)),
        lambda: frc_sample_curves(rf, branch, rf.samples(n_samples, seed)),
    )
    bad = np.isnan(r_s)
    # normal of the mean curve in scaled coordinates (Ω/s_Ω, ρ/s_ρ)
    t_om, t_r = np.gradient(om / s_om), np.gradient(rho / s_rho)
    nrm = np.hypot(t_om, t_r)
    nrm[nrm == 0] = 1.0
    n_om, n_r = -t_r / nrm, t_om / nrm
    offsets = _quantiles((o_s - om) / s_om * n_om + (r_s - rho) / s_rho * n_r, level)
    lo_d, hi_d = offsets[:, 0], offsets[:, 1]
    branch.data.update(
        band_lower=np.stack([om + lo_d * n_om * s_om, rho + lo_d * n_r * s_rho], axis=1),
        band_upper=np.stack([om + hi_d * n_om * s_om, rho + hi_d * n_r * s_rho], axis=1),
        band_offset=offsets,
        normal=np.stack([n_om, n_r], axis=1),
        sample_omega=o_s,
        sample_amplitude=r_s,
    )
    branch.meta["band"] = _band_meta(level, n_samples, seed, failed_fraction=float(np.mean(bad)))


def add_scurve_band(
    rf: ReducedFit, branch: Branch, n_samples: int, level: float, seed: int
) -> None:
    """Add the posterior-sample band of F along an S-curve (``band_forcing`` (n, 2),
    ``sample_forcing`` (S, n))."""
    g_s = rf.cached(
        ("scurve", n_samples, seed, *branch_key(branch)),
        lambda: scurve_sample_forcing(rf, branch, rf.samples(n_samples, seed)),
    )
    branch.data.update(band_forcing=_quantiles(g_s, level), sample_forcing=g_s)
    branch.meta["band"] = _band_meta(level, n_samples, seed)


def add_backbone_band(
    rf: ReducedFit, branch: Branch, n_samples: int, level: float, seed: int
) -> None:
    """Add the posterior-sample band of Ω along a backbone (``band_omega`` (n, 2),
    ``sample_omega`` (S, n))."""
    om_s = rf.cached(
        ("backbone", n_samples, seed, *branch_key(branch)),
        lambda: backbone_sample_omega(rf, branch, rf.samples(n_samples, seed)),
    )
    branch.data.update(band_omega=_quantiles(om_s, level), sample_omega=om_s)
    branch.meta["band"] = _band_meta(
        level, n_samples, seed, failed_fraction=float(np.mean(np.isnan(om_s)))
    )


def band_coverage(
    branch: Branch, true_omega: Any, true_amplitude: Any, true_phase: Any
) -> dict[str, float]:
    """Fraction of a predicted FRC's points whose amplitude interval holds the true curve.

    ``branch`` is an FRC of ``predict_diagram(forcing=F, level=...)`` (its
    ``intervals["amplitude"]``, :mod:`._uncertainty`); the true curve (Ω, A, lag) is
    interpolated (cubic splines in the lag) at the branch's phases (ψ is a regular
    parameter along both) and its amplitude there compared with the interval. Points
    outside the true curve's phase range or without an interval are not counted. Returns
    ``coverage``, ``n`` (points compared) and ``median_width`` (the interval's median
    width relative to the amplitude).

    Raises
    ------
    BifidInputError
        If the branch has no amplitude interval or the true curve has fewer than 4
        distinct phases.
    """
    if "amplitude" not in branch.intervals:
        raise BifidInputError(
            "the branch has no amplitude interval: predict it with predict_diagram(level=...)."
        )
    tp = np.asarray(true_phase, float)
    order = np.argsort(tp)
    tp, ta = tp[order], np.asarray(true_amplitude, float)[order]
    keep = np.concatenate([[True], np.diff(tp) > 0])
    if np.sum(keep) < 4:
        raise BifidInputError("the true curve needs at least 4 points of distinct phase.")
    tp, ta = tp[keep], ta[keep]
    lag = np.asarray(branch.data["phase"])
    inside = (lag >= tp.min()) & (lag <= tp.max())
    # cubic interpolation in the phase (linear interpolation errors of a dense branch are
    # already comparable with the widths of a model trained on exact data)
    truth = CubicSpline(tp, ta)(np.clip(lag, tp.min(), tp.max()))
    lo, hi = (np.asarray(v, float)[:, 0] for v in branch.intervals["amplitude"])
    valid = inside & np.isfinite(lo) & np.isfinite(hi)
    cov = (truth >= lo) & (truth <= hi)
    amp = np.asarray(branch.data["amplitude"], float)[:, 0]
    return {
        "coverage": float(np.mean(cov[valid])) if np.any(valid) else float("nan"),
        "n": int(np.sum(valid)),
        "median_width": float(np.median(((hi - lo) / amp)[valid]))
        if np.any(valid)
        else float("nan"),
    }
