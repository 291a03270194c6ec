r"""Kernel models of forced systems on a 2-D spectral submanifold (thesis ch. 6).

A harmonically forced, damped structure near a resonance behaves like its dynamics on a
two-dimensional forced spectral submanifold (SSM, thesis §2.3.2, Theorem 2.2). In polar
coordinates ``z = ρ e^{iθ}`` with ``ψ = θ − φ`` the phase of the response relative to the
force ``φ = Ωt``, the reduced dynamics are (eq. 6.10)

.. math::

    \dot ρ = a(ρ, Ω) + Γ \sin ψ, \qquad
    \dot ψ = b(ρ, Ω) - Ω + \frac{Γ}{ρ}\cos ψ,

whose fixed points are the periodic responses (eq. 6.11). With the coordinate choice
``ρ = A`` (eq. 6.14: ``ρ`` *is* the measured amplitude ``max_t |y(t)|``) every measured
response ``(Ω_j, Γ_j, ρ_j, ψ_j)`` gives one sample of ``b`` (eq. 6.15)

.. math::  b_j = Ω_j - \frac{Γ_j}{ρ_j}\cos ψ_j

and, once ``b`` is learned, one of ``a`` (eq. 6.19, the sign for a stable origin)

.. math::  a_j = -\sqrt{Γ_j^2 - (b(ρ_j, Ω_j) - Ω_j)^2 ρ_j^2},

plus pseudo-observations ``a(0, Ω) = 0``. ``a`` and ``b`` are Gaussian-process / kernel
ridge regressions (:mod:`bifid.identify.kernels`) with squared-exponential ARD kernels on
``(ρ, Ω)`` and explicit basis functions carrying the structure of eq. 6.9
(``a ≈ α₁ρ + α₃ρ³``, ``b ≈ β₀ + β₂ρ²``), so that predictions extrapolate in amplitude
like the normal form rather than decaying to the prior mean. The observation
``y = φ(z)`` is a third GP learned from the time series (eq. 6.20).

Phase convention. Datasets store ``phase`` = lag of the observed first harmonic behind the
force, in ``(0, π)`` for a forced damped oscillator (0 below resonance, π/2 at resonance).
The thesis's ``ψ`` is the phase of ``z`` relative to a forcing term ``iΓe^{iφ}``; for
``ÿ + … = F cos Ωt`` that is ``ψ = π − lag``, which makes eqs. 6.10–6.21 hold with
``Γ > 0`` (at resonance ``ψ = π/2`` and ``b = Ω``, eq. 6.21). A dataset whose force was
recorded with the opposite sign (lags in ``(π, 2π)``: energy would flow *out* of the force)
is detected from the median of ``sin(lag)`` and shifted by π; ``forcing_sign_`` records it.

Forcing scale. ``Γ = κF`` is the forcing projected onto the SSM; only ``F`` is measured.
Predicted amplitudes, phases, folds, backbone and stability are *exactly* invariant to
``κ`` if ``a`` and ``b`` fit the data exactly (``a``, ``b − Ω`` and the vector field scale
by κ). ``κ`` still matters for a learned model: with the right κ, ``b`` hardly depends on
``Ω`` (eq. 6.9: ``b(0, Ω) = Im λ``), which a GP learns and extrapolates best. ``κ`` is
given (``forcing_scale=1.0`` is the thesis's assumption Γ = F) or fitted
(``forcing_scale="fit"``) by maximising the marginal likelihood of the measured quantity
``e_j = −F_j cos ψ_j / ρ_j`` under ``b = Ω + κe ~ GP``, i.e. the likelihood of ``b`` plus the
Jacobian ``n log κ`` — jointly with ``b``'s hyperparameters, starting from a least-squares
estimate under ``b = B(ρ)``. Several forcing frequencies are needed to identify κ.

Predictions (all return :class:`~bifid.continuation.Branch`):

* :meth:`ForcedKernelModel.frc` — pseudo-arclength continuation in Ω of the fixed points
  of eq. 6.10 (equivalent to eq. 6.11, better conditioned) with folds located;
* :meth:`ForcedKernelModel.scurve` — at fixed Ω, ``Γ(ρ) = sqrt(a² + (b − Ω)²ρ²)`` is
  explicit in ρ (eq. 6.11), so the S-curve is exact on a ρ grid; folds where ``dΓ/dρ = 0``;
* :meth:`ForcedKernelModel.backbone` — eq. 6.21, ``b(ρ, Ω) = Ω`` solved for Ω along ρ;
* stability of every point from the eigenvalues of the Jacobian of eq. 6.10 in ``(ρ, ψ)``;
* :meth:`ForcedKernelModel.time_series` — ``y(t) = φ(ρ cos(Ωt + ψ), ρ sin(Ωt + ψ))``.

Uncertainty (beyond the thesis). Posterior function samples of ``a`` and ``b`` (pathwise
conditioning) are continued like the mean: FRC samples are solved at the same phases ψ as
the mean branch (ψ is a regular parameter along an FRC of a single-mode response), S-curve
samples at the same ρ, backbone samples at the same ρ. The band is the central
``band_level`` quantile of the samples' offsets from the mean curve along its normal
(FRC: in coordinates scaled by the curve's extent) or along Γ (S-curve) / Ω (backbone).
"""

from __future__ import annotations

import functools
import math
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from bifid.continuation import (
    Branch,
    ContinuationOptions,
    SpecialPoint,
    ZeroProblem,
    correct,
    palc,
)
from bifid.errors import (
    BifidInputError,
    ConvergenceError,
    ConvergenceWarning,
    NotFittedError,
)
from bifid.identify.kernels import (
    GPRegressor,
    GPSamples,
    GPState,
    HyperBounds,
    _bucket,
    gp_mean,
    minimize_multistart,
    neg_log_marginal_likelihood,
    padded_args,
    sample_eval,
)

Array = jnp.ndarray
MODEL_TYPE = "forced_kernel"

__all__ = [
    "MODEL_TYPE",
    "ForcedKernelModel",
    "ForcedTrainingData",
    "band_coverage",
    "training_data",
]


# =============================================================================================
# training data
# =============================================================================================


@dataclass
class ForcedTrainingData:
    """Forced-response points ``(Ω_j, F_j, ρ_j, lag_j)`` and optional time series.

    ``series[j]`` is ``(t, y)`` (times [s], centred observed signal) or None.
    """

    omega: np.ndarray
    forcing: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray
    stable: np.ndarray
    curve: np.ndarray
    series: list[tuple[np.ndarray, np.ndarray] | None]
    sources: list[str]

    def __len__(self) -> int:
        return int(self.omega.shape[0])


def _as_1d(name: str, v: Any, n: int | None = None) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise BifidInputError(f"{name} must be a numeric array.") from None
    if n is not None and a.shape[0] != n:
        raise BifidInputError(f"{name} must have {n} values (one per point), got {a.shape[0]}.")
    return a


def _harmonic_amplitude(t: np.ndarray, y: np.ndarray, omega: float) -> float:
    basis = np.stack([np.ones_like(t), np.cos(omega * t), np.sin(omega * t)], axis=1)
    c, *_ = np.linalg.lstsq(basis, y, rcond=None)
    return float(np.hypot(c[1], c[2]))


def training_data(
    data: Any = None,
    *,
    omega: Any = None,
    forcing: Any = None,
    amplitude: Any = None,
    phase: Any = None,
    stable: Any = None,
    time_series: Sequence[tuple[Any, Any] | None] | None = None,
    amplitude_kind: Literal["max", "harmonic"] = "max",
) -> ForcedTrainingData:
    """Collect training points from forced datasets and/or plain arrays.

    Parameters
    ----------
    data : xarray.Dataset, path, or a sequence of them, optional
        ``"forced"`` datasets (:mod:`bifid.data`). Their ``amplitude`` (max |y|),
        ``phase`` (lag behind the force), ``omega``, ``forcing``, ``stable``, and the
        observed signal's time series are used.
    omega, forcing, amplitude, phase : arrays, optional
        Points given directly (phase = lag of the response's first harmonic behind the
        force [rad]); appended to ``data``'s.
    stable : array, optional
        1 stable, 0 unstable, -1 unknown (only used for diagnostics).
    time_series : sequence of ``(t, y)`` or None, optional
        One per directly given point: the observed signal over whole periods.
    amplitude_kind : {"max", "harmonic"}
        ``"max"``: ``max_t |y|`` (thesis eq. 6.5, the dataset's ``amplitude``);
        ``"harmonic"``: amplitude of the first harmonic of the time series (less sensitive
        to noise and higher harmonics in measured data).
    """
    if amplitude_kind not in ("max", "harmonic"):
        raise BifidInputError(
            f"amplitude_kind must be 'max' or 'harmonic', got {amplitude_kind!r}."
        )
    parts: dict[str, list] = {k: [] for k in
                              ("omega", "forcing", "amplitude", "phase", "stable", "curve")}
    series: list[tuple[np.ndarray, np.ndarray] | None] = []
    sources: list[str] = []
    curve_offset = 0
    if data is not None:
        items = data if isinstance(data, (list, tuple)) else [data]
        for item in items:
            ds = item
            if isinstance(item, (str, os.PathLike)):
                from bifid.data import load_dataset

                ds = load_dataset(item)
                sources.append(os.fspath(item))
            else:
                sources.append(str(getattr(ds, "attrs", {}).get("source", "dataset")))
            if getattr(ds, "attrs", {}).get("bifid_kind") != "forced":
                raise BifidInputError(
                    "forced kernel models train on 'forced' datasets (S-curves, FRCs); got a "
                    f"{getattr(ds, 'attrs', {}).get('bifid_kind')!r} dataset."
                )
            from bifid.data import forced_records

            obs = str(ds.attrs.get("observed", ""))
            names = [str(s) for s in ds["signal"].values.tolist()]
            j_obs = names.index(obs) if obs in names else 0
            recs = forced_records(ds)
            for r in recs:
                parts["omega"].append(r.omega)
                parts["forcing"].append(r.forcing)
                parts["phase"].append(np.nan if r.phase is None else r.phase)
                parts["stable"].append(-1 if r.stable is None else int(r.stable))
                parts["curve"].append(r.curve + curve_offset)
                y = np.asarray(r.signals[:, j_obs], dtype=float)
                t = np.arange(y.shape[0]) / r.sample_rate
                y = y - y.mean()
                series.append((t, y) if y.shape[0] >= 4 else None)
                if amplitude_kind == "harmonic" and y.shape[0] >= 4:
                    parts["amplitude"].append(_harmonic_amplitude(t, y, r.omega))
                else:
                    parts["amplitude"].append(
                        r.amplitude if r.amplitude is not None else float(np.max(np.abs(y)))
                    )
            if recs:
                curve_offset = max(parts["curve"]) + 1
    if omega is not None or forcing is not None or amplitude is not None or phase is not None:
        if omega is None or forcing is None or amplitude is None or phase is None:
            raise BifidInputError(
                "give all four arrays omega, forcing, amplitude and phase (or a dataset)."
            )
        om = _as_1d("omega", omega)
        n = om.shape[0]
        fo = _as_1d("forcing", forcing, n)
        am = _as_1d("amplitude", amplitude, n)
        ph = _as_1d("phase", phase, n)
        st = np.full(n, -1) if stable is None else _as_1d("stable", stable, n).astype(int)
        ts = list(time_series) if time_series is not None else [None] * n
        if len(ts) != n:
            raise BifidInputError(f"time_series needs one entry (or None) per point ({n}).")
        for i in range(n):
            s = ts[i]
            if s is not None:
                t_i = _as_1d("time_series t", s[0])
                y_i = _as_1d("time_series y", s[1], t_i.shape[0])
                s = (t_i, y_i - y_i.mean())
                if amplitude_kind == "harmonic":
                    am[i] = _harmonic_amplitude(s[0], s[1], om[i])
            series.append(s)
        parts["omega"].extend(om)
        parts["forcing"].extend(fo)
        parts["amplitude"].extend(am)
        parts["phase"].extend(ph)
        parts["stable"].extend(st)
        parts["curve"].extend(np.full(n, curve_offset))
        sources.append("arrays")
    if not parts["omega"]:
        raise BifidInputError("no training data: give forced datasets or the four arrays.")
    out = ForcedTrainingData(
        omega=np.asarray(parts["omega"], dtype=float),
        forcing=np.asarray(parts["forcing"], dtype=float),
        amplitude=np.asarray(parts["amplitude"], dtype=float),
        phase=np.asarray(parts["phase"], dtype=float),
        stable=np.asarray(parts["stable"], dtype=int),
        curve=np.asarray(parts["curve"], dtype=int),
        series=series,
        sources=sources,
    )
    if not np.all(np.isfinite(out.omega)) or np.any(out.omega <= 0):
        raise BifidInputError("forcing frequencies omega must be finite and > 0 [rad/s].")
    return out


# =============================================================================================
# pure JAX model functions
# =============================================================================================


class ReducedModel(eqx.Module):
    """The learned ``a``, ``b`` (posterior means) and the offset added to ``b``."""

    a: GPState
    b: GPState
    omega_c: Array


class ReducedSamples(eqx.Module):
    """Posterior function samples of ``a`` and ``b`` (leading axis = sample)."""

    a: GPSamples
    b: GPSamples


def _ab_mean(m: ReducedModel, rho: Array, omega: Array) -> tuple[Array, Array]:
    x = jnp.stack([rho, omega])
    return gp_mean(m.a, x), gp_mean(m.b, x) + m.omega_c


def _ab_sample(m: ReducedModel, s: ReducedSamples, rho: Array, omega: Array):
    x = jnp.stack([rho, omega])
    return sample_eval(m.a, s.a, x), sample_eval(m.b, s.b, x) + m.omega_c


def _fixed_point_residual(ab, y: Array, gamma: Array) -> Array:
    """Eq. 6.10 at a fixed point: ``[a + Γ sin ψ, (b − Ω)ρ + Γ cos ψ]`` (⇔ eq. 6.11)."""
    rho, psi, omega = y[0], y[1], y[2]
    a, b = ab(rho, omega)
    return jnp.stack([a + gamma * jnp.sin(psi), (b - omega) * rho + gamma * jnp.cos(psi)])


def _frc_residual(y: Array, args: dict) -> Array:
    m = args["model"]
    return _fixed_point_residual(lambda r, o: _ab_mean(m, r, o), y, args["gamma"])


_FRC_PROBLEM = ZeroProblem(_frc_residual, param_index=2)


def _polar_field(ab, rho_psi: Array, omega: Array, gamma: Array) -> Array:
    """Right-hand side of eq. 6.10 in ``(ρ, ψ)``."""
    rho, psi = rho_psi[0], rho_psi[1]
    a, b = ab(rho, omega)
    return jnp.stack([a + gamma * jnp.sin(psi), b - omega + gamma / rho * jnp.cos(psi)])


@jax.jit
def _eigs_mean(m: ReducedModel, rho: Array, psi: Array, omega: Array, gamma: Array) -> Array:
    """Eigenvalues (complex, shape (N, 2)) of the Jacobian of eq. 6.10 at each point."""

    def one(r, p, o):
        jac = jax.jacfwd(lambda u: _polar_field(lambda rr, oo: _ab_mean(m, rr, oo), u, o,
                                                gamma))(jnp.stack([r, p]))
        tr = jac[0, 0] + jac[1, 1]
        det = jac[0, 0] * jac[1, 1] - jac[0, 1] * jac[1, 0]
        disc = jnp.sqrt((tr * tr / 4.0 - det).astype(jnp.complex128))
        return jnp.stack([tr / 2.0 + disc, tr / 2.0 - disc])

    return jax.vmap(one)(rho, psi, omega)


@jax.jit
def _eigs_mean_g_jit(m: ReducedModel, rho, psi, omega, gamma) -> Array:
    """As :func:`_eigs_mean` with one Γ per point."""
    return jax.vmap(lambda r, p, o, g: _eigs_mean(m, r[None], p[None], o[None], g)[0])(
        rho, psi, omega, gamma
    )


@jax.jit
def _ab_grid_jit(m: ReducedModel, rho: Array, omega: Array) -> tuple[Array, Array]:
    return jax.vmap(lambda r, o: _ab_mean(m, r, o))(rho, omega)


@jax.jit
def _ab_grid_samples_jit(m: ReducedModel, s: ReducedSamples, rho: Array, omega: Array):
    """(S, N) values of a and b of every sample at the points."""

    def per_sample(si):
        return jax.vmap(lambda r, o: _ab_sample(m, si, r, o))(rho, omega)

    return jax.vmap(per_sample)(s)


def _newton2(fun, u0: Array, n_iter: int = 25) -> tuple[Array, Array]:
    """Plain Newton on a 2×2 system from ``u0``; returns (u, max|F(u)|)."""

    def body(_, u):
        j, f = jax.jacfwd(lambda v: (fun(v), fun(v)), has_aux=True)(u)  # one forward pass
        det = j[0, 0] * j[1, 1] - j[0, 1] * j[1, 0]  # Cramer's rule: cheap under vmap
        du = jnp.stack([j[0, 1] * f[1] - j[1, 1] * f[0], j[1, 0] * f[0] - j[0, 0] * f[1]])
        return u + du / det

    u = jax.lax.fori_loop(0, n_iter, body, u0)
    return u, jnp.max(jnp.abs(fun(u)))


@jax.jit
def _frc_samples_at_psi_jit(m, s, gamma, psi, rho0, omega0):
    """Each sample's FRC point at each phase ψ_i: Newton in (ρ, Ω) from the mean point."""

    def per_sample(si):
        def per_point(p, r0, o0):
            def fun(u):
                return _fixed_point_residual(
                    lambda rr, oo: _ab_sample(m, si, rr, oo), jnp.stack([u[0], p, u[1]]), gamma
                )

            return _newton2(fun, jnp.stack([r0, o0]), n_iter=6)

        return jax.vmap(per_point)(psi, rho0, omega0)

    return jax.vmap(per_sample)(s)


def _backbone_scan(bfun, rho: Array, omega0: Array) -> tuple[Array, Array]:
    """Solve ``b(ρ, Ω) = Ω`` (eq. 6.21) along the ρ grid by warm-started Newton."""

    def g(o, r):
        return bfun(r, o) - o

    def step(o_prev, r):
        def body(_, o):
            val, der = jax.jvp(lambda oo: g(oo, r), (o,), (jnp.ones_like(o),))
            return o - val / der

        o = jax.lax.fori_loop(0, 8, body, o_prev)
        return o, (o, jnp.abs(g(o, r)))

    _, (om, res) = jax.lax.scan(step, omega0, rho)
    return om, res


@jax.jit
def _backbone_mean_jit(m: ReducedModel, rho: Array, omega0: Array):
    return _backbone_scan(lambda r, o: gp_mean(m.b, jnp.stack([r, o])) + m.omega_c, rho,
                          omega0)


@jax.jit
def _backbone_samples_jit(m: ReducedModel, s: ReducedSamples, rho: Array, omega0: Array):
    def one(sb):
        return _backbone_scan(lambda r, o: sample_eval(m.b, sb, jnp.stack([r, o])) + m.omega_c,
                              rho, omega0)

    return jax.vmap(one)(s.b)


def _sgamma(a: Array, b: Array, rho: Array, omega: Array) -> tuple[Array, Array]:
    """Eq. 6.11 at fixed Ω: ``Γ = sqrt(a² + (b−Ω)²ρ²)`` and ``ψ`` of the fixed point."""
    gamma = jnp.sqrt(a * a + (b - omega) ** 2 * rho * rho)
    psi = jnp.arctan2(-a, -(b - omega) * rho)
    return gamma, psi


@jax.jit
def _dgamma_drho_jit(m: ReducedModel, rho: Array, omega: Array) -> Array:
    def gam(r, o):
        a, b = _ab_mean(m, r, o)
        return _sgamma(a, b, r, o)[0]

    return jax.vmap(jax.grad(gam), in_axes=(0, None))(rho, omega)


# ---- padded wrappers (few compiled shapes) ------------------------------------------------


def _ab_grid(m, rho, omega):
    return _pad_call(lambda r, o: _ab_grid_jit(m, r, o), rho, omega)


def _eigs_mean_g(m, rho, psi, omega, gamma):
    return _pad_call(lambda r, p, o, g: _eigs_mean_g_jit(m, r, p, o, g), rho, psi, omega, gamma)


def _ab_grid_samples(m, s, rho, omega):
    return _pad_call(lambda r, o: _ab_grid_samples_jit(m, s, r, o), rho, omega, axis_out=1)


def _frc_samples_at_psi(m, s, gamma, psi, rho0, omega0):
    return _pad_call(lambda p, r, o: _frc_samples_at_psi_jit(m, s, gamma, p, r, o),
                     psi, rho0, omega0, axis_out=1)


def _backbone_mean(m, rho, omega0):
    return _pad_call(lambda r: _backbone_mean_jit(m, r, omega0), rho, chunked=False)


def _backbone_samples(m, s, rho, omega0):
    return _pad_call(lambda r: _backbone_samples_jit(m, s, r, omega0), rho, axis_out=1,
                     chunked=False)


def _dgamma_drho(m, rho, omega):
    return _pad_call(lambda r: _dgamma_drho_jit(m, r, jnp.asarray(float(omega))), rho)


# =============================================================================================
# observation model helpers
# =============================================================================================


def _phase_samples(t: np.ndarray, y: np.ndarray, omega: float, n_phase: int, n_harm: int):
    """Denoised observation at ``n_phase`` phases θ of ``z`` over one period (eq. 6.20).

    Fits ``y ≈ Σ_k c_k cos kΩt + s_k sin kΩt`` by least squares; the first harmonic's phase
    gives ``θ(t) = Ωt + arg c₁ + π`` (``y ≈ −ρ cos θ`` under the phase convention of the
    module docstring).
    """
    cols = [np.ones_like(t)]
    for k in range(1, n_harm + 1):
        cols += [np.cos(k * omega * t), np.sin(k * omega * t)]
    basis = np.stack(cols, axis=1)
    coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
    c1 = complex(coef[1], -coef[2])
    phi0 = math.atan2(c1.imag, c1.real)
    theta = np.linspace(0.0, 2.0 * np.pi, n_phase, endpoint=False)
    tt = (theta - phi0 - np.pi) / omega
    cols = [np.ones_like(tt)]
    for k in range(1, n_harm + 1):
        cols += [np.cos(k * omega * tt), np.sin(k * omega * tt)]
    yy = np.stack(cols, axis=1) @ coef - coef[0]
    return theta, yy


# =============================================================================================
# the model
# =============================================================================================


def _wrap_lag(psi: np.ndarray) -> np.ndarray:
    """Phase lag ``π − ψ`` wrapped to ``[−π/2, 3π/2)`` (the datasets' convention)."""
    lag = np.pi - np.asarray(psi)
    return (lag + np.pi / 2) % (2 * np.pi) - np.pi / 2


_CHUNK = 128


def _pad_call(fn, *arrays, axis_out: int = 0, chunked: bool = True):
    """Call a jitted vectorised ``fn`` on 1-D arrays in fixed-size chunks.

    Every call sees arrays of length ``_CHUNK`` (the last chunk padded with its last
    value), so each function compiles once whatever the number of points; outputs are
    concatenated along ``axis_out`` and trimmed. With ``chunked=False`` the arrays are
    padded to a bucket length instead and ``fn`` is called once (for sequential scans).
    """
    arrs = [np.atleast_1d(np.asarray(a, dtype=float)) for a in arrays]
    n = arrs[0].shape[0]
    size = _CHUNK if chunked else _bucket(n)
    n_pad = int(math.ceil(n / size) * size)
    padded = [np.concatenate([a, np.full(n_pad - n, a[-1])]) for a in arrs]
    outs = [fn(*(jnp.asarray(a[k : k + size]) for a in padded)) for k in range(0, n_pad, size)]

    def cat(*vs):
        v = np.concatenate([np.asarray(x) for x in vs], axis=axis_out)
        return v[(slice(None),) * axis_out + (slice(0, n),)]

    return jax.tree_util.tree_map(cat, *outs)


@functools.lru_cache(maxsize=16)
def _kappa_objective(basis):
    """Jitted value and gradient of ``−log p(e | κ, θ)`` (module docstring), once per basis."""

    def f(z, xp, om_p, e_p, ys, xs, xc, evp, mask, log_k0):
        th, lk = z[:-1], z[-1]
        y = (om_p + jnp.exp(lk) * e_p) / ys * mask
        n = jnp.sum(mask)
        return (neg_log_marginal_likelihood(th, xp, y, xs, xc, basis, evp, mask)
                - n * (lk - log_k0))

    return jax.jit(jax.value_and_grad(f))


class ForcedKernelModel:
    """Reduced dynamics ``a(ρ, Ω)``, ``b(ρ, Ω)`` on a forced SSM, learned from forced responses.

    Parameters
    ----------
    forcing_scale : float, "fit" or "auto"
        ``κ`` in ``Γ = κF``. A number is used as given (1.0: the thesis's Γ = F); "fit"
        maximises the marginal likelihood of ``b`` (module docstring; needs several Ω, or
        ``linear_frequency``); "auto" fits when the data hold several forcing frequencies
        or ``linear_frequency`` is given, else uses 1.0 and says so in ``notes_``.
    linear_frequency : float, optional
        A known small-amplitude natural frequency ω₀ [rad/s] (hammer test, or the first
        point of a measured backbone). With one forcing frequency it identifies κ by least
        squares of ``Ω_j + κ e_j = ω₀ + c₁ρ_j² + c₂ρ_j⁴`` (``b(0) = ω₀``, eq. 6.9); with
        several it only gives the starting value of the likelihood fit.
    selection : {"ml", "loo"}
        Hyperparameter criterion of the three GPs (marginal likelihood or closed-form
        leave-one-out predictive probability).
    a_target : {"eq6.19", "phase"}
        Samples of ``a``: eq. 6.19 from the fitted ``b`` (thesis; keeps the amplitude
        equation exact at the data) or ``a_j = −Γ_j sin ψ_j`` directly from the phase
        (better conditioned far from resonance).
    a_basis, b_basis : tuple of exponent pairs
        Monomials in ``(ρ/s_ρ, (Ω − Ω̄)/s_Ω)`` added to the SE kernels (eq. 6.9 structure).
    n_pseudo : int
        Pseudo-observations ``a(0, Ω) = 0`` spread over the trained Ω range.
    rho_min_fraction : float
        Points with ``ρ`` below this fraction of the largest amplitude are not used
        (``Γ/ρ`` in eq. 6.15 amplifies their noise without bound).
    observation : bool
        Learn ``φ`` from the time series (eq. 6.20) when the data have them.
    phase_points : int
        Phases per record used to train ``φ`` (capped so the GP has ≤ ``max_phi_points``).
    max_phi_points : int
    noise_floor : float
        Lower bound of the GPs' noise standard deviation relative to the targets' RMS.
        Keeps ``K_y`` well conditioned (its condition number ≲ noise_floor⁻²) so the
        posterior mean is free of round-off that would stall Newton's method; noise-free
        (simulated) data put the noise on this bound.
    n_restarts : int
        Extra seeded L-BFGS starts per GP.
    seed : int
    """

    def __init__(
        self,
        *,
        forcing_scale: float | Literal["fit", "auto"] = "auto",
        linear_frequency: float | None = None,
        selection: Literal["ml", "loo"] = "ml",
        a_target: Literal["eq6.19", "phase"] = "eq6.19",
        a_basis: tuple[tuple[int, int], ...] = ((1, 0), (3, 0)),
        b_basis: tuple[tuple[int, int], ...] = ((0, 0), (2, 0)),
        n_pseudo: int = 12,
        rho_min_fraction: float = 0.02,
        observation: bool = True,
        phase_points: int = 16,
        max_phi_points: int = 128,
        noise_floor: float = 1e-5,
        n_restarts: int = 1,
        seed: int = 0,
    ) -> None:
        self.forcing_scale = forcing_scale
        self.linear_frequency = linear_frequency
        self.selection = selection
        self.a_target = a_target
        self.a_basis = tuple(tuple(int(e) for e in m) for m in a_basis)
        self.b_basis = tuple(tuple(int(e) for e in m) for m in b_basis)
        self.n_pseudo = n_pseudo
        self.rho_min_fraction = rho_min_fraction
        self.observation = observation
        self.phase_points = phase_points
        self.max_phi_points = max_phi_points
        self.noise_floor = noise_floor
        self.n_restarts = n_restarts
        self.seed = seed

    # ------------------------------------------------------------------ helpers
    def get_params(self) -> dict[str, Any]:
        """Constructor hyperparameters (JSON-able)."""
        return {
            "forcing_scale": self.forcing_scale, "linear_frequency": self.linear_frequency,
            "selection": self.selection,
            "a_target": self.a_target, "a_basis": [list(m) for m in self.a_basis],
            "b_basis": [list(m) for m in self.b_basis], "n_pseudo": self.n_pseudo,
            "rho_min_fraction": self.rho_min_fraction, "observation": self.observation,
            "phase_points": self.phase_points, "max_phi_points": self.max_phi_points,
            "noise_floor": self.noise_floor, "n_restarts": self.n_restarts, "seed": self.seed,
        }

    def _check_params(self) -> None:
        fs = self.forcing_scale
        if not (fs in ("fit", "auto") or (isinstance(fs, (int, float))
                                          and not isinstance(fs, bool)
                                          and math.isfinite(fs) and fs > 0)):
            raise BifidInputError(
                f"forcing_scale must be a positive number, 'fit' or 'auto', got {fs!r}."
            )
        w0 = self.linear_frequency
        if w0 is not None and not (isinstance(w0, (int, float)) and math.isfinite(w0)
                                   and w0 > 0):
            raise BifidInputError(
                f"linear_frequency must be a positive number [rad/s] or None, got {w0!r}."
            )
        if self.selection not in ("ml", "loo"):
            raise BifidInputError(f"selection must be 'ml' or 'loo', got {self.selection!r}.")
        if self.a_target not in ("eq6.19", "phase"):
            raise BifidInputError(
                f"a_target must be 'eq6.19' or 'phase', got {self.a_target!r}."
            )
        for name, basis in (("a_basis", self.a_basis), ("b_basis", self.b_basis)):
            if any(len(m) != 2 or min(m) < 0 for m in basis):
                raise BifidInputError(
                    f"{name} must be pairs of non-negative exponents (rho, omega), got {basis}."
                )
        if any(m[0] == 0 for m in self.a_basis):
            raise BifidInputError(
                "a_basis terms must vanish at rho = 0 (a(0, Ω) = 0): every exponent of rho "
                f"must be >= 1, got {self.a_basis}."
            )
        if not (0 <= self.rho_min_fraction < 1) or self.n_pseudo < 0:
            raise BifidInputError("rho_min_fraction must be in [0, 1) and n_pseudo >= 0.")

    def _gp(self, basis, center) -> GPRegressor:
        return GPRegressor(
            basis=basis, basis_center=center, criterion=self.selection,
            n_restarts=self.n_restarts, seed=self.seed,
            bounds=HyperBounds(length_scale=(0.05, 100.0), noise=(self.noise_floor, 1.0)),
        )

    def _check_fitted(self) -> None:
        if not hasattr(self, "model_"):
            raise NotFittedError(
                "this ForcedKernelModel is not fitted yet; call fit(...) or load(...) first."
            )

    # ------------------------------------------------------------------ fit
    def fit(
        self,
        data: Any = None,
        *,
        omega: Any = None,
        forcing: Any = None,
        amplitude: Any = None,
        phase: Any = None,
        stable: Any = None,
        time_series: Sequence[tuple[Any, Any] | None] | None = None,
        amplitude_kind: Literal["max", "harmonic"] = "max",
    ) -> ForcedKernelModel:
        """Learn ``b`` (eq. 6.15), ``a`` (eq. 6.19) and ``φ`` (eq. 6.20) from forced responses.

        Parameters are those of :func:`training_data` (datasets and/or arrays; ``phase`` is
        the lag of the response behind the force).

        Returns
        -------
        self
        """
        self._check_params()
        td = training_data(
            data, omega=omega, forcing=forcing, amplitude=amplitude, phase=phase,
            stable=stable, time_series=time_series, amplitude_kind=amplitude_kind,
        )
        notes: list[str] = []
        ok = (np.isfinite(td.forcing) & np.isfinite(td.amplitude) & np.isfinite(td.phase)
              & (td.forcing > 0) & (td.amplitude > 0))
        if not np.any(ok):
            raise BifidInputError(
                "no usable training point: every point lacks a phase, has zero forcing or "
                "zero amplitude (the phase needs a recorded force signal)."
            )
        rho_max = float(np.max(td.amplitude[ok]))
        small = ok & (td.amplitude < self.rho_min_fraction * rho_max)
        if np.any(~ok):
            notes.append(f"{int(np.sum(~ok))} points without phase, forcing or amplitude "
                         "were skipped")
        if np.any(small):
            notes.append(f"{int(np.sum(small))} points with amplitude < "
                         f"{self.rho_min_fraction:g} × max were skipped (eq. 6.15 divides by ρ)")
        use = ok & ~small
        if int(np.sum(use)) < 4:
            raise BifidInputError(
                f"need at least 4 usable forced-response points, got {int(np.sum(use))}."
            )
        om = td.omega[use]
        fo = td.forcing[use]
        rho = td.amplitude[use]
        lag = td.phase[use]
        sign = 1
        if np.median(np.sin(lag)) < 0:
            sign = -1
            lag = lag + np.pi
            notes.append("the force was recorded with the opposite sign (lags in (π, 2π)); "
                         "lags shifted by π")
        psi = np.pi - lag
        self.forcing_sign_ = sign
        self.notes_ = notes
        self.train_ = {
            "omega": om, "forcing": fo, "amplitude": rho, "phase": (lag + np.pi / 2)
            % (2 * np.pi) - np.pi / 2, "stable": td.stable[use], "curve": td.curve[use],
        }
        self.sources_ = td.sources
        omega_c = float(np.mean(om))
        x = np.stack([rho, om], axis=1)
        e = -fo * np.cos(psi) / rho  # b = Ω + κ e   (eq. 6.15)

        # ----------------------------------------------------------- b (eq. 6.15) and κ
        gp_b = self._gp(self.b_basis, (0.0, None))
        several = bool(np.ptp(om) > 1e-9 * np.mean(om))
        mode = self.forcing_scale
        if mode == "auto":
            mode = "fit" if (several or self.linear_frequency is not None) else 1.0
            if mode == 1.0:
                notes.append("one forcing frequency only: the forcing scale κ cannot be "
                             "identified and is set to 1 (Γ = F, the thesis's assumption); "
                             "predictions at other frequencies depend on it — give "
                             "forcing_scale or linear_frequency")
        if mode == "fit":
            kappa, kappa_info = self._fit_kappa(gp_b, x, om, e, omega_c)
        else:
            kappa, kappa_info = float(mode), {"method": "given"}
        p_b = om + kappa * e - omega_c
        # b's hyperparameters are (re)selected at the final κ with the usual restarts
        kappa_info.pop("theta", None)
        kappa_info.pop("y_scale", None)
        gp_b.fit(x, p_b)
        gamma = kappa * fo

        # ----------------------------------------------------------- a (eq. 6.19)
        b_fit = np.asarray(gp_b.predict(x)) + omega_c
        if self.a_target == "eq6.19":
            rad = gamma**2 - (b_fit - om) ** 2 * rho**2
            n_neg = int(np.sum(rad < 0))
            if n_neg:
                notes.append(f"eq. 6.19: {n_neg} points with Γ² < (b−Ω)²ρ² (b misfit or "
                             "noise) get a = 0")
            a_t = -np.sqrt(np.maximum(rad, 0.0))
        else:
            a_t = -gamma * np.sin(psi)
        x_a, y_a = x, a_t
        if self.n_pseudo > 0:
            om_ps = np.linspace(om.min(), om.max(), self.n_pseudo) if np.ptp(om) > 0 \
                else np.full(1, om[0])
            x_a = np.concatenate([x, np.stack([np.zeros_like(om_ps), om_ps], axis=1)])
            y_a = np.concatenate([a_t, np.zeros_like(om_ps)])
        gp_a = self._gp(self.a_basis, (0.0, None))
        gp_a.fit(x_a, y_a, x_scale=np.array([np.std(rho), np.std(om)]))

        self.gp_a_, self.gp_b_ = gp_a, gp_b
        self.forcing_scale_ = kappa
        self.kappa_info_ = kappa_info
        self.omega_c_ = omega_c
        self.model_ = ReducedModel(a=gp_a.state_, b=gp_b.state_, omega_c=jnp.asarray(omega_c))
        self.rho_range_ = (float(rho.min()), float(rho.max()))
        self.omega_range_ = (float(om.min()), float(om.max()))
        self.forcing_range_ = (float(fo.min()), float(fo.max()))
        self.n_train_ = int(rho.shape[0])

        # ----------------------------------------------------------- φ (eq. 6.20)
        self.gp_phi_ = None
        if self.observation:
            series = [s for s, u in zip(td.series, use, strict=True) if u]
            self.gp_phi_ = self._fit_observation(series, om, rho)

        # ----------------------------------------------------------- diagnostics
        self.losses_ = self._losses(x, om, gamma, rho, psi, self.train_["stable"])
        for gp in (gp_a, gp_b) + ((self.gp_phi_,) if self.gp_phi_ is not None else ()):
            self.notes_.extend(gp.notes_)
        return self

    def _fit_kappa(self, gp_b: GPRegressor, x, om, e, omega_c):
        """Joint ML of ``log κ`` and ``b``'s hyperparameters (module docstring)."""
        # least-squares start: Ω_j + κ e_j ≈ c0 + c1 ρ² + c2 ρ⁴
        rho = x[:, 0]
        rs = rho / rho.max()
        w0 = self.linear_frequency
        if w0 is None:
            design = np.stack([-e, np.ones_like(rho), rs**2, rs**4], axis=1)
            coef, *_ = np.linalg.lstsq(design, om, rcond=None)
        else:
            design = np.stack([-e, rs**2, rs**4], axis=1)
            coef, *_ = np.linalg.lstsq(design, om - w0, rcond=None)
        kappa_ls = float(coef[0])
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
            return kappa_ls, {"method": "linear frequency (least squares)",
                              "kappa_least_squares": kappa_ls}
        if not (kappa_ls > 0 and math.isfinite(kappa_ls)):
            kappa_ls = float(np.std(om) / max(np.std(e), 1e-300))
        k0 = kappa_ls
        p0 = om + k0 * e - omega_c
        prep = gp_b.prepare(x, p0)
        ys = prep["y_scale"]
        n = x.shape[0]
        xp, _, xs, xc, evp, mask = padded_args(prep["x"], p0 / ys, prep["extra_var"],
                                               prep["x_scale"], prep["x_center"])
        om_p = jnp.zeros(xp.shape[0]).at[:n].set(om - omega_c)
        e_p = jnp.zeros(xp.shape[0]).at[:n].set(e)
        log_k0 = math.log(k0)
        kernel = _kappa_objective(gp_b.basis)
        consts = (xp, om_p, e_p, jnp.asarray(ys), xs, xc, evp, mask, jnp.asarray(log_k0))

        def vg(z):
            return kernel(jnp.asarray(z), *consts)

        z0 = np.concatenate([prep["theta0"], [log_k0]])
        lo = np.concatenate([prep["lo"], [log_k0 - math.log(100.0)]])
        hi = np.concatenate([prep["hi"], [log_k0 + math.log(100.0)]])
        best = minimize_multistart(vg, z0, lo, hi, n_restarts=self.n_restarts, seed=self.seed)
        kappa = float(np.exp(best.x[-1]))
        # refit scale: keep the θ found, expressed for the final targets' scale
        info = {
            "method": "marginal likelihood", "kappa_least_squares": kappa_ls,
            "objective": float(best.fun), "theta": best.x[:-1], "y_scale": ys,
            "at_bound": bool(abs(best.x[-1] - lo[-1]) < 1e-6 or abs(best.x[-1] - hi[-1]) < 1e-6),
        }
        if info["at_bound"]:
            warnings.warn(
                f"the fitted forcing scale κ = {kappa:.4g} sits at its search bound; the data "
                "do not identify it well (too few forcing frequencies?).",
                ConvergenceWarning, stacklevel=3,
            )
        return kappa, info

    def _fit_observation(self, series, om, rho) -> GPRegressor | None:
        recs = [(s, o, r) for s, o, r in zip(series, om, rho, strict=True) if s is not None]
        if not recs:
            self.notes_.append("no time series in the data: the observation φ is not learned")
            return None
        n_phase = int(np.clip(self.max_phi_points // max(len(recs), 1), 8, self.phase_points))
        # records spread over the amplitude range when there are too many
        if n_phase * len(recs) > self.max_phi_points:
            keep = max(1, self.max_phi_points // n_phase)
            order = np.argsort([r for _, _, r in recs])
            pick = order[np.round(np.linspace(0, len(recs) - 1, keep)).astype(int)]
            self.notes_.append(f"φ trained on {keep} of {len(recs)} records (max_phi_points)")
            recs = [recs[i] for i in sorted(set(pick.tolist()))]
        zs, ys = [], []
        for (t, y), o, r in recs:
            period = 2 * np.pi / o
            if t[-1] - t[0] < 0.9 * period:
                continue
            n_harm = int(max(1, min(7, (len(t) // 4 - 1) // 1)))
            theta, yy = _phase_samples(t, y, o, n_phase, min(n_harm, 7))
            zs.append(np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1))
            ys.append(yy)
        if not zs:
            self.notes_.append("time series shorter than one period: φ not learned")
            return None
        z = np.concatenate([*zs, np.zeros((1, 2))])
        y = np.concatenate([*ys, np.zeros(1)])
        gp = GPRegressor(
            basis=((1, 0), (0, 1)), basis_center=(0.0, 0.0), criterion=self.selection,
            n_restarts=0, seed=self.seed,
            bounds=HyperBounds(length_scale=(0.05, 100.0), noise=(self.noise_floor, 1.0)),
        )
        rs = float(np.max(rho))
        return gp.fit(z, y, x_scale=np.array([rs, rs]))

    def _losses(self, x, om, gamma, rho, psi, stable) -> dict[str, Any]:
        a_hat, b_hat = (np.asarray(v) for v in _ab_grid(self.model_, jnp.asarray(rho),
                                                        jnp.asarray(om)))
        g_hat = np.sqrt(a_hat**2 + (b_hat - om) ** 2 * rho**2)
        psi_hat = np.arctan2(-a_hat, -(b_hat - om) * rho)
        dpsi = (psi_hat - psi + np.pi) % (2 * np.pi) - np.pi
        out: dict[str, Any] = {
            "b": self._gp_losses(self.gp_b_), "a": self._gp_losses(self.gp_a_),
            "forcing_rel_rms": float(np.sqrt(np.mean(((g_hat - gamma) / gamma) ** 2))),
            "phase_rms": float(np.sqrt(np.mean(dpsi**2))),
        }
        if self.gp_phi_ is not None:
            out["phi"] = self._gp_losses(self.gp_phi_)
        lab = stable >= 0
        if np.any(lab):
            eig = np.asarray(_eigs_mean_g(self.model_, jnp.asarray(rho), jnp.asarray(psi),
                                          jnp.asarray(om), jnp.asarray(gamma)))
            pred = np.all(eig.real < 0, axis=1)
            out["stability_agreement"] = float(np.mean(pred[lab] == (stable[lab] == 1)))
        return out

    @staticmethod
    def _gp_losses(gp: GPRegressor) -> dict[str, float]:
        return {"log_marginal_likelihood": gp.log_marginal_likelihood_,
                "loo_rmse": gp.loo_rmse_, "train_rmse": gp.train_rmse_, "n": gp.n_train_}

    # ------------------------------------------------------------------ reduced dynamics
    def reduced_dynamics(self, rho: Any, omega: Any) -> tuple[np.ndarray, np.ndarray]:
        """Posterior means of ``a(ρ, Ω)`` and ``b(ρ, Ω)`` (broadcast arrays)."""
        self._check_fitted()
        r, o = np.broadcast_arrays(np.asarray(rho, float), np.asarray(omega, float))
        a, b = _ab_grid(self.model_, jnp.asarray(r.ravel()), jnp.asarray(o.ravel()))
        return np.asarray(a).reshape(r.shape), np.asarray(b).reshape(r.shape)

    def eigenvalues(self, rho: Any, psi: Any, omega: Any, forcing: Any) -> np.ndarray:
        """Eigenvalues of the Jacobian of eq. 6.10 in ``(ρ, ψ)`` at fixed points, (N, 2).

        ``forcing`` is ``F`` (Γ = κF). A point is stable iff both have negative real part.
        """
        self._check_fitted()
        r, p, o, f = (np.atleast_1d(np.asarray(v, dtype=float)) for v in
                      np.broadcast_arrays(rho, psi, omega, forcing))
        return np.asarray(_eigs_mean_g(self.model_, jnp.asarray(r), jnp.asarray(p),
                                       jnp.asarray(o), jnp.asarray(f * self.forcing_scale_)))

    def sample_reduced(
        self, n_samples: int, *, seed: int = 0, n_features: int = 256
    ) -> ReducedSamples:
        """Posterior function samples of ``a`` and ``b`` (pathwise conditioning).

        ``n_features`` random Fourier features per sample approximate the prior part; the
        conditioning on the data is exact, so near the data the samples are accurate even
        with few features.
        """
        self._check_fitted()
        return ReducedSamples(
            a=self.gp_a_.sample_functions(n_samples, seed=seed, n_features=n_features),
            b=self.gp_b_.sample_functions(n_samples, seed=seed + 1, n_features=n_features),
        )

    # ------------------------------------------------------------------ fixed points
    def fixed_points(self, omega: float, forcing: float, *, rho_max: float | None = None,
                     n_grid: int = 2000) -> list[dict[str, float]]:
        """All fixed points of eq. 6.10 at ``(Ω, F)``: roots in ρ of eq. 6.11.

        Returns a list of ``{rho, psi, phase, stable}`` sorted by amplitude.
        """
        self._check_fitted()
        gamma = float(forcing) * self.forcing_scale_
        rmax = 3.0 * self.rho_range_[1] if rho_max is None else float(rho_max)
        rr = np.linspace(rmax / n_grid, rmax, n_grid)
        a, b = (np.asarray(v) for v in _ab_grid(self.model_, jnp.asarray(rr),
                                                jnp.full(n_grid, float(omega))))
        res = a**2 + (b - omega) ** 2 * rr**2 - gamma**2
        out = []
        for i in np.nonzero(np.sign(res[:-1]) * np.sign(res[1:]) < 0)[0]:
            lo, hi = rr[i], rr[i + 1]
            flo = res[i]
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                am, bm = (float(v[0]) for v in _ab_grid(self.model_, jnp.asarray([mid]),
                                                        jnp.asarray([float(omega)])))
                fm = am**2 + (bm - omega) ** 2 * mid**2 - gamma**2
                if fm * flo > 0:
                    lo, flo = mid, fm
                else:
                    hi = mid
            r = 0.5 * (lo + hi)
            am, bm = (float(v[0]) for v in _ab_grid(self.model_, jnp.asarray([r]),
                                                    jnp.asarray([float(omega)])))
            psi = math.atan2(-am / gamma, -(bm - omega) * r / gamma)
            eig = self.eigenvalues(r, psi, omega, forcing)[0]
            out.append({"rho": r, "psi": psi, "phase": float(_wrap_lag(psi)),
                        "stable": bool(np.all(eig.real < 0))})
        return out

    # ------------------------------------------------------------------ FRC
    def frc(
        self,
        forcing: float,
        omega_range: tuple[float, float] | None = None,
        *,
        n_samples: int = 0,
        band_level: float = 0.95,
        seed: int = 0,
        options: ContinuationOptions | None = None,
        rho_cap: float | None = None,
    ) -> Branch:
        """Forced response curve at forcing ``F``: continuation of eq. 6.11 in Ω.

        Parameters
        ----------
        forcing : float
            ``F`` (the model uses Γ = κF).
        omega_range : (float, float), optional
            Frequency window; default the trained range widened by 25 % on each side.
        n_samples : int
            Posterior samples for the uncertainty band (0: none).
        band_level : float
            Central probability of the band.
        seed : int
        options : ContinuationOptions, optional
            Steps are in the arclength of ``(ρ/s_ρ, ψ, Ω/s_Ω)``.
        rho_cap : float, optional
            Stop when the amplitude exceeds it (default 4 × the largest trained amplitude).

        Returns
        -------
        Branch
            ``kind="forced"``, ``param="Omega"``, ``solutions`` = (ρ, ψ), ``stable``;
            ``data``: ``amplitude`` (n, 1), ``phase`` (lag, n), ``omega``, ``forcing``,
            ``eigenvalues`` (n, 2); with samples also ``band_lower``/``band_upper`` (n, 2)
            as (Ω, amplitude) points, ``sample_omega``/``sample_amplitude`` (S, n), and
            ``meta["peak"]``. Folds are ``SpecialPoint(kind="fold")``.
        """
        self._check_fitted()
        f = float(forcing)
        if not (math.isfinite(f) and f > 0):
            raise BifidInputError(f"forcing must be a positive number, got {forcing!r}.")
        gamma = f * self.forcing_scale_
        lo, hi = self._omega_window(omega_range)
        cap = 4.0 * self.rho_range_[1] if rho_cap is None else float(rho_cap)
        starts = self.fixed_points(lo, f, rho_max=cap)
        if not starts:
            raise ConvergenceError(
                f"no response of the model at Ω = {lo:.6g}, F = {f:.6g} below amplitude "
                f"{cap:.4g}; widen omega_range or raise rho_cap."
            )
        s0 = starts[0]
        s_rho = max(self.rho_range_[1], 1e-12)
        s_om = max(hi - lo, 1e-12)
        weights = jnp.asarray([1.0 / s_rho**2, 1.0, 1.0 / s_om**2])
        opts = options or ContinuationOptions(
            ds=0.01, ds_min=1e-8, ds_max=0.04, max_steps=4000, newton_tol=1e-9,
        )
        opts = opts.with_(p_min=lo - 1e-12, p_max=hi)
        args = {"model": self.model_, "gamma": jnp.asarray(gamma)}
        y0 = jnp.asarray([s0["rho"], s0["psi"], lo])
        res = palc(
            _FRC_PROBLEM, y0, jnp.asarray([0.0, 0.0, 1.0]), args, opts, weights=weights,
            stop=lambda y: bool(y[0] <= 0 or y[0] > cap),
        )
        if res.ys.shape[0] < 2:
            raise ConvergenceError(f"FRC continuation failed at the start: {res.message}")
        ys = res.ys
        status, message = res.status, res.message
        if status == "completed":
            status, message = "range", f"amplitude left (0, {cap:.4g}]"
        branch = self._forced_branch(ys, res, "Omega", ys[:, 2], np.full(len(ys), f), gamma,
                                     status, message, opts)
        branch.meta["peak"] = self._refine_peak(ys, res.tangents, args, weights)
        if n_samples > 0:
            self._frc_band(branch, gamma, weights, n_samples, band_level, seed, s_rho, s_om)
        return branch

    def _omega_window(self, omega_range) -> tuple[float, float]:
        if omega_range is None:
            lo, hi = self.omega_range_
            w = max(hi - lo, 0.02 * hi)
            return lo - 0.25 * w, hi + 0.25 * w
        lo, hi = (float(v) for v in omega_range)
        if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
            raise BifidInputError(f"omega_range must be 0 < low < high, got {omega_range!r}.")
        return lo, hi

    def _forced_branch(self, ys, res, param, params, forcing, gamma, status, message, opts):
        rho, psi, om = ys[:, 0], ys[:, 1], ys[:, 2]
        g = np.broadcast_to(np.asarray(gamma, dtype=float), rho.shape)
        eig = np.asarray(_eigs_mean_g(self.model_, jnp.asarray(rho), jnp.asarray(psi),
                                      jnp.asarray(om), jnp.asarray(g)))
        stable = np.all(eig.real < 0, axis=1)
        specials = []
        for idx, yf, prec in getattr(res, "folds", []):
            specials.append(SpecialPoint(
                kind="fold", param=float(yf[2] if param == "Omega" else yf[3]),
                index=int(idx), bracket=(float(params[idx]), float(params[idx + 1])),
                solution=np.asarray(yf[:2]), precision=float(prec), status="converged",
                data={"amplitude": float(yf[0]), "phase": float(_wrap_lag(yf[1])),
                      "omega": float(yf[2]), "forcing": float(np.asarray(forcing)[0])},
            ))
        return Branch(
            kind="forced", system=MODEL_TYPE, param=param, params=np.asarray(params),
            solutions=np.stack([rho, psi], axis=1), stable=stable, special_points=specials,
            data={"amplitude": rho[:, None], "observed_amplitude": rho,
                  "phase": _wrap_lag(psi), "omega": om,
                  "forcing": np.asarray(forcing, dtype=float), "eigenvalues": eig},
            p=np.array([self.forcing_scale_]), status=status, message=message, options=opts,
            meta={"observed": "y", "forcing_scale": self.forcing_scale_, "states": ("y",)},
        )

    def _refine_peak(self, ys, tangents, args, weights) -> dict[str, float]:
        i = int(np.argmax(ys[:, 0]))
        if 0 < i < len(ys) - 1:
            w = np.asarray(weights)
            seg = np.sqrt(np.sum(np.diff(ys[i - 1 : i + 2], axis=0) ** 2 * w, axis=1))
            s = np.array([-seg[0], 0.0, seg[1]])
            r = ys[i - 1 : i + 2, 0]
            den = (s[0] - s[1]) * (s[0] - s[2]) * (s[1] - s[2])
            if den != 0:
                a2 = (s[2] * (r[1] - r[0]) + s[1] * (r[0] - r[2]) + s[0] * (r[2] - r[1])) / den
                a1 = (s[2] ** 2 * (r[0] - r[1]) + s[1] ** 2 * (r[2] - r[0])
                      + s[0] ** 2 * (r[1] - r[2])) / den
                if a2 < 0:
                    s_star = float(np.clip(-a1 / (2 * a2), s[0], s[2]))
                    t = np.asarray(tangents[i])
                    row = w * t
                    guess = ys[i] + s_star * t
                    y, ok, _, _ = correct(_FRC_PROBLEM, jnp.asarray(guess), jnp.asarray(row),
                                          float(row @ guess), args, tol=1e-12)
                    if ok and y[0] >= ys[i, 0]:
                        return {"omega": float(y[2]), "amplitude": float(y[0]),
                                "phase": float(_wrap_lag(y[1]))}
        return {"omega": float(ys[i, 2]), "amplitude": float(ys[i, 0]),
                "phase": float(_wrap_lag(ys[i, 1]))}

    def _frc_band(self, branch, gamma, weights, n_samples, level, seed, s_rho, s_om) -> None:
        samples = self.sample_reduced(n_samples, seed=seed)
        rho, psi = branch.solutions[:, 0], branch.solutions[:, 1]
        om = branch.params
        u, res = _frc_samples_at_psi(self.model_, samples, jnp.asarray(gamma), psi, rho, om)
        r_s, o_s, res = np.asarray(u[..., 0]), np.asarray(u[..., 1]), np.asarray(res)
        bad = ~(np.isfinite(res) & (res < 1e-8 * max(gamma, 1e-300) + 1e-12) & (r_s > 0)
                & np.isfinite(o_s))
        r_s = np.where(bad, np.nan, r_s)
        o_s = np.where(bad, np.nan, o_s)
        # normal of the mean curve in scaled coordinates (Ω/s_Ω, ρ/s_ρ)
        t_om = np.gradient(om / s_om)
        t_r = np.gradient(rho / s_rho)
        nrm = np.hypot(t_om, t_r)
        nrm[nrm == 0] = 1.0
        n_om, n_r = -t_r / nrm, t_om / nrm
        d = (o_s - om) / s_om * n_om + (r_s - rho) / s_rho * n_r
        q = (1.0 - level) / 2.0
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            lo_d = np.nanquantile(d, q, axis=0)
            hi_d = np.nanquantile(d, 1.0 - q, axis=0)
        branch.data["band_lower"] = np.stack([om + lo_d * n_om * s_om, rho + lo_d * n_r * s_rho],
                                             axis=1)
        branch.data["band_upper"] = np.stack([om + hi_d * n_om * s_om, rho + hi_d * n_r * s_rho],
                                             axis=1)
        branch.data["band_offset"] = np.stack([lo_d, hi_d], axis=1)
        branch.data["normal"] = np.stack([n_om, n_r], axis=1)
        branch.data["sample_omega"] = o_s
        branch.data["sample_amplitude"] = r_s
        branch.meta["band"] = {"level": level, "n_samples": n_samples, "seed": seed,
                               "failed_fraction": float(np.mean(bad)),
                               "scales": {"omega": s_om, "amplitude": s_rho}}

    # ------------------------------------------------------------------ S-curve
    def scurve(
        self,
        omega: float,
        forcing_range: tuple[float, float] | None = None,
        *,
        n_points: int = 400,
        n_samples: int = 0,
        band_level: float = 0.95,
        seed: int = 0,
        rho_cap: float | None = None,
    ) -> Branch:
        """S-curve at frequency Ω: ``Γ(ρ) = sqrt(a² + (b−Ω)²ρ²)`` on a ρ grid (eq. 6.11).

        The branch runs from small amplitude until ``F`` leaves ``forcing_range`` (default
        ``[0, 1.5 × largest trained F]``) or ρ reaches ``rho_cap``. Folds are where
        ``dΓ/dρ = 0``. With samples: ``band_forcing`` (n, 2) = band of F at each ρ.
        """
        self._check_fitted()
        om = float(omega)
        if not (math.isfinite(om) and om > 0):
            raise BifidInputError(f"omega must be a positive number, got {omega!r}.")
        f_lo, f_hi = (0.0, 1.5 * self.forcing_range_[1]) if forcing_range is None else (
            float(forcing_range[0]), float(forcing_range[1]))
        if not (math.isfinite(f_lo) and math.isfinite(f_hi) and 0 <= f_lo < f_hi):
            raise BifidInputError(
                f"forcing_range must be 0 <= low < high, got {forcing_range!r}."
            )
        cap = 4.0 * self.rho_range_[1] if rho_cap is None else float(rho_cap)
        k = self.forcing_scale_
        rr = np.linspace(cap / (50 * n_points), cap, 20 * n_points)
        a, b = (np.asarray(v) for v in _ab_grid(self.model_, jnp.asarray(rr),
                                                jnp.full(rr.shape, om)))
        g, _ = (np.asarray(v) for v in _sgamma(a, b, rr, om))
        fgrid = g / k
        inside = fgrid >= f_lo
        if not np.any(inside):
            raise ConvergenceError(f"the model's S-curve at Ω = {om:.6g} never reaches F = {f_lo}.")
        i0 = int(np.argmax(inside))
        above = np.nonzero(fgrid[i0:] > f_hi)[0]
        i1 = i0 + int(above[0]) if above.size else len(rr) - 1
        status = "range" if above.size else "steps"
        message = ("reached the forcing bound" if above.size
                   else f"reached the amplitude cap {cap:.4g} before the forcing bound")
        r_lo, r_hi = rr[max(i0 - 1, 0)], rr[i1]
        rho = np.linspace(max(r_lo, rr[0]), r_hi, n_points)
        a, b = (np.asarray(v) for v in _ab_grid(self.model_, jnp.asarray(rho),
                                                jnp.full(rho.shape, om)))
        g, psi = (np.asarray(v) for v in _sgamma(a, b, rho, om))
        forcing = g / k
        eig = np.asarray(_eigs_mean_g(self.model_, jnp.asarray(rho), jnp.asarray(psi),
                                      jnp.full(rho.shape, om), jnp.asarray(g)))
        stable = np.all(eig.real < 0, axis=1)
        specials = self._scurve_folds(rho, om, forcing)
        opts = ContinuationOptions(p_min=f_lo, p_max=max(f_hi, f_lo + 1e-300))
        br = Branch(
            kind="forced", system=MODEL_TYPE, param="F", params=forcing,
            solutions=np.stack([rho, psi], axis=1), stable=stable, special_points=specials,
            data={"amplitude": rho[:, None], "observed_amplitude": rho,
                  "phase": _wrap_lag(psi), "omega": np.full(rho.shape, om), "forcing": forcing,
                  "eigenvalues": eig},
            p=np.array([k]), status=status, message=message, options=opts,
            meta={"observed": "y", "forcing_scale": k, "states": ("y",)},
        )
        if n_samples > 0:
            s = self.sample_reduced(n_samples, seed=seed)
            a_s, b_s = (np.asarray(v) for v in _ab_grid_samples(
                self.model_, s, jnp.asarray(rho), jnp.full(rho.shape, om)))
            g_s = np.sqrt(a_s**2 + (b_s - om) ** 2 * rho**2) / k
            q = (1.0 - band_level) / 2.0
            br.data["band_forcing"] = np.stack([np.quantile(g_s, q, axis=0),
                                                np.quantile(g_s, 1 - q, axis=0)], axis=1)
            br.data["sample_forcing"] = g_s
            br.meta["band"] = {"level": band_level, "n_samples": n_samples, "seed": seed}
        return br

    def _scurve_folds(self, rho, om, forcing) -> list[SpecialPoint]:
        k = self.forcing_scale_
        dg = np.asarray(_dgamma_drho(self.model_, jnp.asarray(rho), jnp.asarray(om)))
        out = []
        for i in np.nonzero(np.sign(dg[:-1]) * np.sign(dg[1:]) < 0)[0]:
            lo, hi, flo = rho[i], rho[i + 1], dg[i]
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                fm = float(_dgamma_drho(self.model_, jnp.asarray([mid]), jnp.asarray(om))[0])
                if fm * flo > 0:
                    lo, flo = mid, fm
                else:
                    hi = mid
            r = 0.5 * (lo + hi)
            a, b = (float(v[0]) for v in _ab_grid(self.model_, jnp.asarray([r]),
                                                  jnp.asarray([om])))
            g, psi = (float(v) for v in _sgamma(a, b, r, om))
            out.append(SpecialPoint(
                kind="fold", param=g / k, index=int(i),
                bracket=(float(forcing[i]), float(forcing[i + 1])),
                solution=np.array([r, psi]), precision=float(abs(hi - lo)), status="converged",
                data={"amplitude": r, "phase": float(_wrap_lag(psi)), "omega": om,
                      "forcing": g / k},
            ))
        return out

    # ------------------------------------------------------------------ backbone
    def backbone(
        self,
        amplitude_range: tuple[float, float] | None = None,
        *,
        n_points: int = 200,
        n_samples: int = 0,
        band_level: float = 0.95,
        seed: int = 0,
    ) -> Branch:
        """Backbone curve, eq. 6.21: ``b(ρ, Ω) = Ω`` solved for Ω at each ρ.

        Returns a Branch with ``kind="backbone"``, ``param="amplitude"``, ``params`` = ρ,
        ``data["omega"]``; with samples ``band_omega`` (n, 2) and ``sample_omega`` (S, n).
        """
        self._check_fitted()
        if amplitude_range is None:
            r_lo, r_hi = 0.01 * self.rho_range_[1], self.rho_range_[1]
        else:
            r_lo, r_hi = (float(v) for v in amplitude_range)
        if not (math.isfinite(r_lo) and math.isfinite(r_hi) and 0 <= r_lo < r_hi):
            raise BifidInputError(
                f"amplitude_range must be 0 <= low < high, got {amplitude_range!r}."
            )
        rho = np.linspace(r_lo, r_hi, n_points)
        # start Ω: fixed-point iteration Ω ← b(ρ0, Ω) from the trained centre
        o0 = self.omega_c_
        for _ in range(50):
            o0 = float(self.reduced_dynamics(rho[0], o0)[1])
        om, res = (np.asarray(v) for v in _backbone_mean(self.model_, jnp.asarray(rho),
                                                          jnp.asarray(o0)))
        ok = np.isfinite(om) & (res < 1e-9 * max(abs(o0), 1.0))
        status, message = "completed", ""
        if not np.all(ok):
            first_bad = int(np.argmin(ok))
            rho, om = rho[:first_bad], om[:first_bad]
            status = "failed"
            message = (f"b(ρ, Ω) = Ω has no solution near the previous one beyond "
                       f"ρ = {rho[-1] if rho.size else r_lo:.4g}")
            if rho.size < 2:
                raise ConvergenceError(f"backbone: {message}")
        br = Branch(
            kind="backbone", system=MODEL_TYPE, param="amplitude", params=rho,
            solutions=np.stack([rho, np.full(rho.shape, np.pi / 2)], axis=1),
            stable=np.ones(rho.shape, dtype=bool), special_points=[],
            data={"omega": om, "amplitude": rho[:, None], "observed_amplitude": rho},
            p=np.array([self.forcing_scale_]),
            status=status, message=message, options=ContinuationOptions(),
            meta={"observed": "y", "states": ("y",)},
        )
        if n_samples > 0:
            s = self.sample_reduced(n_samples, seed=seed)
            om_s, res_s = (np.asarray(v) for v in _backbone_samples(
                self.model_, s, jnp.asarray(rho), jnp.asarray(om[0])))
            om_s = np.where(res_s < 1e-9 * max(abs(o0), 1.0), om_s, np.nan)
            q = (1.0 - band_level) / 2.0
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                br.data["band_omega"] = np.stack([np.nanquantile(om_s, q, axis=0),
                                                  np.nanquantile(om_s, 1 - q, axis=0)], axis=1)
            br.data["sample_omega"] = om_s
            br.meta["band"] = {"level": band_level, "n_samples": n_samples, "seed": seed,
                               "failed_fraction": float(np.mean(np.isnan(om_s)))}
        return br

    # ------------------------------------------------------------------ observation
    def time_series(self, t: Any, rho: float, psi: float, omega: float) -> np.ndarray:
        """Observed signal ``y(t) = φ(ρ cos(Ωt + ψ), ρ sin(Ωt + ψ))`` (eq. 6.20).

        ``t`` is measured from a maximum of the force ``F cos Ωt``. Without a learned
        ``φ`` (no time series in the data) the first-harmonic approximation
        ``−ρ cos(Ωt + ψ)`` is returned (eq. 6.14) and a warning is issued.
        """
        self._check_fitted()
        tt = np.asarray(t, dtype=float)
        th = float(omega) * tt + float(psi)
        if self.gp_phi_ is None:
            warnings.warn("no observation model was learned (no time series in the data); "
                          "returning the first-harmonic approximation −ρ cos(Ωt + ψ).",
                          stacklevel=2)
            return -float(rho) * np.cos(th)
        z = np.stack([rho * np.cos(th.ravel()), rho * np.sin(th.ravel())], axis=1)
        return np.asarray(self.gp_phi_.predict(z)).reshape(tt.shape)

    # ------------------------------------------------------------------ persistence
    def save(self, directory: str | os.PathLike[str], *, settings: dict | None = None) -> Path:
        """Save as ``directory/model.json`` + ``arrays.npz`` (:func:`bifid.io.save_model`)."""
        from bifid.io import save_model

        self._check_fitted()
        arrays = {}
        arrays.update(self.gp_a_.to_arrays("a_"))
        arrays.update(self.gp_b_.to_arrays("b_"))
        if self.gp_phi_ is not None:
            arrays.update(self.gp_phi_.to_arrays("phi_"))
        for k, v in self.train_.items():
            arrays[f"train_{k}"] = np.asarray(v)
        params = {
            "hyperparameters": self.get_params(),
            "gp": {"a": self.gp_a_.get_params(), "b": self.gp_b_.get_params(),
                   "phi": None if self.gp_phi_ is None else self.gp_phi_.get_params()},
            "fitted": self.parameters(),
            "state": {"omega_c": self.omega_c_, "rho_range": list(self.rho_range_),
                      "omega_range": list(self.omega_range_),
                      "forcing_range": list(self.forcing_range_), "n_train": self.n_train_,
                      "forcing_sign": self.forcing_sign_},
            "losses": self.losses_,
            "notes": self.notes_,
        }
        st = {"sources": self.sources_}
        st.update(settings or {})
        return save_model(directory, MODEL_TYPE, params, arrays, st)

    @classmethod
    def load(cls, directory: str | os.PathLike[str]) -> ForcedKernelModel:
        """Load a model saved by :meth:`save` (never unpickles anything)."""
        from bifid.io import load_model

        meta, arrays = load_model(directory)
        if meta.get("type") != MODEL_TYPE:
            raise BifidInputError(
                f"{os.fspath(directory)!r} holds a {meta.get('type')!r} model, not a "
                f"{MODEL_TYPE!r} one."
            )
        p = meta["params"]
        try:
            hp = dict(p["hyperparameters"])
            hp["a_basis"] = tuple(tuple(m) for m in hp["a_basis"])
            hp["b_basis"] = tuple(tuple(m) for m in hp["b_basis"])
            model = cls(**hp)
            stt = p["state"]
            model.gp_a_ = GPRegressor.from_arrays(p["gp"]["a"], arrays, "a_")
            model.gp_b_ = GPRegressor.from_arrays(p["gp"]["b"], arrays, "b_")
            model.gp_phi_ = (None if p["gp"]["phi"] is None
                             else GPRegressor.from_arrays(p["gp"]["phi"], arrays, "phi_"))
            model.forcing_scale_ = float(p["fitted"]["forcing_scale"])
            model.omega_c_ = float(stt["omega_c"])
            model.rho_range_ = tuple(float(v) for v in stt["rho_range"])
            model.omega_range_ = tuple(float(v) for v in stt["omega_range"])
            model.forcing_range_ = tuple(float(v) for v in stt["forcing_range"])
            model.n_train_ = int(stt["n_train"])
            model.forcing_sign_ = int(stt["forcing_sign"])
            model.losses_ = p.get("losses", {})
            model.notes_ = list(p.get("notes", []))
            model.kappa_info_ = {k: v for k, v in p["fitted"].get("forcing_scale_fit", {}).items()}
            model.train_ = {k[len("train_"):]: v for k, v in arrays.items()
                            if k.startswith("train_")}
            model.sources_ = list(meta.get("settings", {}).get("sources", []))
        except (KeyError, TypeError, ValueError) as exc:
            raise BifidInputError(f"malformed forced_kernel model file: missing/invalid {exc}") \
                from None
        model.model_ = ReducedModel(a=model.gp_a_.state_, b=model.gp_b_.state_,
                                    omega_c=jnp.asarray(model.omega_c_))
        return model

    def parameters(self) -> dict[str, Any]:
        """Fitted values by name (JSON-able): forcing scale and GP hyperparameters."""
        self._check_fitted()
        out: dict[str, Any] = {
            "forcing_scale": self.forcing_scale_,
            "forcing_scale_fit": {k: v for k, v in self.kappa_info_.items()
                                  if k not in ("theta", "y_scale")},
            "a": self.gp_a_.hyperparameters_, "b": self.gp_b_.hyperparameters_,
            "omega_offset": self.omega_c_,
            "linear_frequency": None,
        }
        # small-amplitude end of the backbone (eq. 6.21): the linear natural frequency
        try:
            bb = self.backbone((0.0, 0.02 * self.rho_range_[1]), n_points=3)
            out["linear_frequency"] = float(bb.data["omega"][0])
        except ConvergenceError:
            pass
        if self.gp_phi_ is not None:
            out["phi"] = self.gp_phi_.hyperparameters_
        return out


# =============================================================================================
# evaluation helpers
# =============================================================================================


def band_coverage(
    branch: Branch, true_omega: Any, true_amplitude: Any, true_phase: Any
) -> dict[str, float]:
    """Fraction of a model FRC's band points whose true curve lies inside the band.

    The true curve (Ω, A, lag) is interpolated (cubic splines in the lag) at the model
    branch's phases (ψ is a regular parameter along both); its offset from the mean curve
    along the band's normal is compared with the band's offsets. Returns ``coverage``,
    ``n`` (points compared) and the median band width (scaled units).
    """
    if "band_offset" not in branch.data:
        raise BifidInputError("the branch has no band: compute it with n_samples > 0.")
    from scipy.interpolate import CubicSpline

    to = np.asarray(true_omega, float)
    ta = np.asarray(true_amplitude, float)
    tp = np.asarray(true_phase, float)
    order = np.argsort(tp)
    tp, to, ta = tp[order], to[order], ta[order]
    keep = np.concatenate([[True], np.diff(tp) > 0])
    if np.sum(keep) < 4:
        raise BifidInputError("the true curve needs at least 4 points of distinct phase.")
    tp, to, ta = tp[keep], to[keep], ta[keep]
    lag = np.asarray(branch.data["phase"])
    inside = (lag >= tp.min()) & (lag <= tp.max())
    # cubic interpolation in the phase (linear interpolation errors of a dense branch are
    # already comparable with the band widths of a model trained on exact data)
    o_t = CubicSpline(tp, to)(np.clip(lag, tp.min(), tp.max()))
    a_t = CubicSpline(tp, ta)(np.clip(lag, tp.min(), tp.max()))
    sc = branch.meta["band"]["scales"]
    n_om, n_r = branch.data["normal"][:, 0], branch.data["normal"][:, 1]
    d_t = ((o_t - branch.params) / sc["omega"] * n_om
           + (a_t - branch.data["amplitude"][:, 0]) / sc["amplitude"] * n_r)
    lo, hi = branch.data["band_offset"][:, 0], branch.data["band_offset"][:, 1]
    valid = inside & np.isfinite(lo) & np.isfinite(hi)
    cov = (d_t >= lo) & (d_t <= hi)
    return {"coverage": float(np.mean(cov[valid])) if np.any(valid) else float("nan"),
            "n": int(np.sum(valid)),
            "median_width": float(np.median((hi - lo)[valid])) if np.any(valid) else float("nan")}
