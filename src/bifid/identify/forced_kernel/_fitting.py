r"""Training steps of the kernel model (thesis §6.2.3–6.2.4): the forcing scale with ``b``,
the observation ``φ``, and the training diagnostics.

Forcing scale. ``Γ = κF`` is the forcing projected onto the SSM; only ``F`` is measured.
With several forcing frequencies ``κ`` is fitted by maximising the marginal likelihood of the
measured quantity ``e_j = −F_j cos ψ_j / ρ_j`` under ``b = Ω + κe ~ GP``, i.e. the likelihood
of ``b`` plus the Jacobian ``n log κ``, jointly with ``b``'s hyperparameters, from a
least-squares start under ``b = B(ρ)`` (:func:`fit_kappa`); with one frequency and a known
small-amplitude frequency ω₀ it follows by least squares of ``Ω_j + κe_j = ω₀ + c₁ρ_j² +
c₂ρ_j⁴``. With ``forcing_frequency="inverse"`` every ``F_j`` here is ``F_j Ω̄/Ω_j``
(:func:`._reduced.frequency_factor`).
"""

from __future__ import annotations

import functools
import math
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError, ConvergenceError, ConvergenceWarning
from bifid.identify.forced_kernel._gp import GPRegressor, HyperBounds
from bifid.identify.forced_kernel._gp_core import neg_log_marginal_likelihood, padded_args
from bifid.identify.forced_kernel._reduced import ReducedModel, ab_grid, eigs_mean_g
from bifid.identify.forced_kernel._search import laplace_log_errors, minimize_multistart
from bifid.signal import evaluate_series, fourier_project

__all__ = ["a_samples", "fit_kappa", "fit_observation", "training_losses"]


@functools.lru_cache(maxsize=16)
def _kappa_objective(basis):
    """Jitted value and gradient of ``−log p(e | κ, θ)`` (module docstring), once per basis."""

    def f(z, xp, om_p, e_p, ys, xs, xc, evp, mask, log_k0):
        th, lk = z[:-1], z[-1]
        y = (om_p + jnp.exp(lk) * e_p) / ys * mask
        n = jnp.sum(mask)
        return neg_log_marginal_likelihood(th, xp, y, xs, xc, basis, evp, mask) - n * (lk - log_k0)

    return jax.jit(jax.value_and_grad(f))


def _kappa_least_squares(
    x: np.ndarray, om: np.ndarray, e: np.ndarray, linear_frequency: float | None
) -> float:
    """``κ`` from ``Ω_j + κ e_j ≈ c0 + c1 ρ² + c2 ρ⁴`` (``c0 = ω₀`` when known)."""
    rs = x[:, 0] / x[:, 0].max()
    if linear_frequency is None:
        design = np.stack([-e, np.ones_like(rs), rs**2, rs**4], axis=1)
        coef, *_ = np.linalg.lstsq(design, om, rcond=None)
    else:
        design = np.stack([-e, rs**2, rs**4], axis=1)
        coef, *_ = np.linalg.lstsq(design, om - linear_frequency, rcond=None)
    return float(coef[0])


def fit_kappa(
    gp_b: GPRegressor,
    x: np.ndarray,
    om: np.ndarray,
    e: np.ndarray,
    omega_c: float,
    linear_frequency: float | None,
    n_restarts: int,
    seed: int,
) -> tuple[float, dict[str, Any]]:
    """The forcing scale ``κ`` (module docstring) and how it was found.

    Raises
    ------
    BifidInputError
        One forcing frequency and no ``linear_frequency``.
    ConvergenceError
        If ``linear_frequency`` gives a non-positive scale.
    """
    w0 = linear_frequency
    kappa_ls = _kappa_least_squares(x, om, e, w0)
    if np.ptp(om) <= 1e-9 * np.mean(om):
        if w0 is None:
            raise BifidInputError(
                "forcing_scale='fit' needs responses at several forcing frequencies (the "
                "scale of Γ is identified by how b varies with Ω) or a known "
                "linear_frequency; all points share one frequency. Give forcing_scale "
                "as a number or linear_frequency."
            )
        if not (kappa_ls > 0 and math.isfinite(kappa_ls)):
            raise ConvergenceError(
                f"the forcing scale from linear_frequency={w0:g} came out non-positive "
                f"({kappa_ls:.3g}): ω₀ is on the wrong side of the forcing frequency for "
                "these phases."
            )
        return kappa_ls, {
            "method": "linear frequency (least squares)",
            "kappa_least_squares": kappa_ls,
        }
    if not (kappa_ls > 0 and math.isfinite(kappa_ls)):
        kappa_ls = float(np.std(om) / max(np.std(e), 1e-300))
    p0 = om + kappa_ls * e - omega_c
    prep = gp_b.prepare(x, p0)
    ys = prep["y_scale"]
    n = x.shape[0]
    xp, _, xs, xc, evp, mask, _ = padded_args(
        prep["x"], p0 / ys, prep["extra_var"], prep["x_scale"], prep["x_center"]
    )
    log_k0 = math.log(kappa_ls)
    consts = (
        xp,
        jnp.zeros(xp.shape[0]).at[:n].set(om - omega_c),
        jnp.zeros(xp.shape[0]).at[:n].set(e),
        jnp.asarray(ys),
        xs,
        xc,
        evp,
        mask,
        jnp.asarray(log_k0),
    )
    kernel = _kappa_objective(gp_b.basis)
    lo = np.concatenate([prep["lo"], [log_k0 - math.log(100.0)]])
    hi = np.concatenate([prep["hi"], [log_k0 + math.log(100.0)]])
    best = minimize_multistart(
        lambda z: kernel(jnp.asarray(z), *consts),
        np.concatenate([prep["theta0"], [log_k0]]),
        lo,
        hi,
        n_restarts=n_restarts,
        seed=seed,
    )
    kappa = float(np.exp(best.x[-1]))
    at_bound = bool(abs(best.x[-1] - lo[-1]) < 1e-6 or abs(best.x[-1] - hi[-1]) < 1e-6)
    if at_bound:
        warnings.warn(
            f"the fitted forcing scale κ = {kappa:.4g} sits at its search bound; the data do "
            "not identify it well (too few forcing frequencies?).",
            ConvergenceWarning,
            stacklevel=3,
        )
    se_log = laplace_log_errors(lambda z: kernel(z, *consts)[1], best.x, lo, hi)
    return kappa, {
        "method": "marginal likelihood",
        "kappa_least_squares": kappa_ls,
        "objective": float(best.fun),
        "at_bound": at_bound,
        "standard_error": kappa * float(se_log[-1]),
    }


def phase_samples(
    t: np.ndarray, y: np.ndarray, omega: float, n_phase: int, n_harm: int
) -> tuple[np.ndarray, np.ndarray]:
    """Denoised observation at ``n_phase`` phases θ of ``z`` over one period (eq. 6.20).

    The least-squares Fourier series of ``y`` (:func:`bifid.signal.fourier_project`); the
    first harmonic's phase gives ``θ(t) = Ωt + arg c₁ + π`` (``y ≈ −ρ cos θ`` under the
    phase convention of :mod:`bifid.identify.forced_kernel`).
    """
    coef = fourier_project(y, omega * np.asarray(t), n_harm)
    phi0 = math.atan2(-coef[n_harm + 1], coef[1])
    theta = np.linspace(0.0, 2.0 * np.pi, n_phase, endpoint=False)
    return theta, evaluate_series(coef, theta - phi0 - np.pi) - coef[0]


def fit_observation(
    series: list,
    om: np.ndarray,
    rho: np.ndarray,
    *,
    selection: str,
    noise_floor: float,
    phase_points: int,
    max_phi_points: int,
    seed: int,
    notes: list[str],
) -> GPRegressor | None:
    """The observation ``y = φ(z)`` (eq. 6.20) from the records' time series (None without
    any); what was left out is added to ``notes``."""
    recs = [(s, o, r) for s, o, r in zip(series, om, rho, strict=True) if s is not None]
    if not recs:
        notes.append("no time series in the data: the observation φ is not learned")
        return None
    n_phase = int(np.clip(max_phi_points // max(len(recs), 1), 8, phase_points))
    # records spread over the amplitude range when there are too many
    if n_phase * len(recs) > max_phi_points:
        keep = max(1, max_phi_points // n_phase)
        order = np.argsort([r for _, _, r in recs])
        pick = order[np.round(np.linspace(0, len(recs) - 1, keep)).astype(int)]
        notes.append(f"φ trained on {keep} of {len(recs)} records (max_phi_points)")
        recs = [recs[i] for i in sorted(set(pick.tolist()))]
    zs, ys = [], []
    for (t, y), o, r in recs:
        if t[-1] - t[0] < 0.9 * 2 * np.pi / o:
            continue
        theta, yy = phase_samples(t, y, o, n_phase, int(max(1, min(7, len(t) // 4 - 1))))
        zs.append(np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1))
        ys.append(yy)
    if not zs:
        notes.append("time series shorter than one period: φ not learned")
        return None
    gp = GPRegressor(
        basis=((1, 0), (0, 1)),
        basis_center=(0.0, 0.0),
        criterion=selection,
        n_restarts=0,
        seed=seed,
        bounds=HyperBounds(length_scale=(0.05, 100.0), noise=(noise_floor, 1.0)),
    )
    rs = float(np.max(rho))
    n = sum(len(y) for y in ys)
    return gp.fit(  # φ(0) = 0: a pseudo-observation
        np.concatenate([*zs, np.zeros((1, 2))]),
        np.concatenate([*ys, np.zeros(1)]),
        pseudo=np.arange(n + 1) == n,
        x_scale=np.array([rs, rs]),
    )


def gp_losses(gp: GPRegressor) -> dict[str, float]:
    """Marginal likelihood, leave-one-out and training RMS errors of a fitted GP."""
    return {
        "log_marginal_likelihood": gp.log_marginal_likelihood_,
        "loo_rmse": gp.loo_rmse_,
        "train_rmse": gp.train_rmse_,
        "n": gp.n_train_,
    }


def training_losses(
    model: ReducedModel,
    gps: dict[str, GPRegressor | None],
    om: np.ndarray,
    gamma: np.ndarray,
    rho: np.ndarray,
    psi: np.ndarray,
    stable: np.ndarray,
) -> dict[str, Any]:
    """How well the fitted dynamics reproduce the training points: forcing (relative RMS)
    and phase misfit of eq. 6.11, agreement of the stability labels, GP diagnostics."""
    a_hat, b_hat = (np.asarray(v) for v in ab_grid(model, rho, om))
    g_hat = np.sqrt(a_hat**2 + (b_hat - om) ** 2 * rho**2)
    psi_hat = np.arctan2(-a_hat, -(b_hat - om) * rho)
    dpsi = (psi_hat - psi + np.pi) % (2 * np.pi) - np.pi
    out: dict[str, Any] = {k: gp_losses(gp) for k, gp in gps.items() if gp is not None}
    out["forcing_rel_rms"] = float(np.sqrt(np.mean(((g_hat - gamma) / gamma) ** 2)))
    out["phase_rms"] = float(np.sqrt(np.mean(dpsi**2)))
    lab = stable >= 0
    if np.any(lab):
        eig = np.asarray(eigs_mean_g(model, rho, psi, om, gamma))
        pred = np.all(eig.real < 0, axis=1)
        out["stability_agreement"] = float(np.mean(pred[lab] == (stable[lab] == 1)))
    return out


def a_samples(
    x: np.ndarray,
    gamma: np.ndarray,
    psi: np.ndarray,
    b_fit: np.ndarray,
    *,
    target: str,
    n_pseudo: int,
    notes: list[str],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Training inputs and targets of ``a`` (eq. 6.19 or the phase) with the
    pseudo-observations ``a(0, Ω) = 0``, and which points are those."""
    rho, om = x[:, 0], x[:, 1]
    if target == "eq6.19":
        rad = gamma**2 - (b_fit - om) ** 2 * rho**2
        if np.any(rad < 0):
            notes.append(
                f"eq. 6.19: {int(np.sum(rad < 0))} points with Γ² < (b−Ω)²ρ² (b "
                "misfit or noise) get a = 0"
            )
        a_t = -np.sqrt(np.maximum(rad, 0.0))
    else:
        a_t = -gamma * np.sin(psi)
    if n_pseudo <= 0:
        return x, a_t, np.zeros(a_t.size, dtype=bool)
    om_ps = np.linspace(om.min(), om.max(), n_pseudo) if np.ptp(om) > 0 else np.full(1, om[0])
    return (
        np.concatenate([x, np.stack([np.zeros_like(om_ps), om_ps], axis=1)]),
        np.concatenate([a_t, np.zeros_like(om_ps)]),
        np.arange(a_t.size + om_ps.size) >= a_t.size,
    )
