r"""Intervals of a kernel model's predicted forced responses: posterior samples and jackknife.

Every quantity ``q`` of a predicted FRC, S-curve or backbone (below) is read off many reduced
models at once, each solved where the mean response was (:mod:`._bands`):

- **posterior samples** of ``a(ρ, Ω)`` and ``b(ρ, Ω)`` (eqs. 6.15, 6.19; pathwise
  conditioning, :meth:`~._state.ReducedFit.samples`, seeded) give the spread the Gaussian
  processes claim at their fitted hyperparameters, :math:`v_\mathrm{post}` (the squared
  half-distance between the 16 % and 84 % sample quantiles, robust to a few wild samples);
- the **leave-one-out jackknife**: the ``n`` posterior means fitted without training point
  ``i`` (closed form at fixed hyperparameters, :math:`\alpha^{(-i)} = \alpha - K_y^{-1}e_i\,
  \alpha_i/[K_y^{-1}]_{ii}`, point ``i`` leaving ``a`` and ``b`` together) give
  :math:`q_{(i)}` and the jackknife variance
  :math:`v_\mathrm{jack} = \frac{n-1}{n}\sum_i (q_{(i)} - \bar q_{(\cdot)})^2`. It measures
  how much the estimate moves with the data actually seen — robust to what the GP's
  homoscedastic noise model gets wrong (noise on the inputs ρ and ψ, noise that varies
  along the curve, a noise level selected too small), which the posterior is not.

What each measures. At fixed hyperparameters the posterior mean is linear in the data,
:math:`m(x) = w(x)^\mathsf{T}y` with :math:`w(x) = K_y^{-1}k(X, x)`, and with
:math:`y = f(X) + \varepsilon` the posterior variance splits as

.. math::

    v_\mathrm{post}(x) = \mathbb{E}\,[(f(x) - m(x))^2]
    = \mathbb{E}\,[(f(x) - w^\mathsf{T}f(X))^2] + \sigma_n^2\,\lVert w(x)\rVert^2,

the prior-expected squared error of the mean: what no noise-free data at ``X`` would fix
(the interpolation to an untrained forcing level) plus the variance the modelled noise
puts into the mean.
The jackknife of a linear smoother, :math:`q_{(i)} - q \approx -w_i\,r_i^{(-i)}` with the
leave-one-out residual :math:`r_i^{(-i)}`, gives
:math:`v_\mathrm{jack} \approx \sum_i w_i^2 (r_i^{(-i)})^2`, a sandwich estimate of the
variance the *actual* noise puts into the mean — the same term as
:math:`\sigma_n^2\lVert w\rVert^2` when the GP's noise model holds, larger when it does
not (noise on the inputs ρ and ψ, noise that varies along the curve, a noise level
selected too small). Adding them counts the noise term twice; the standard error is
instead the larger of the two, each valid under its own assumptions:

.. math::

    s = \max\Bigl(\sqrt{v_\mathrm{post}},\;
    \frac{t_{0.975,\,\nu}}{z_{0.975}}\sqrt{v_\mathrm{jack}}\Bigr),\qquad
    \nu = \frac{(\sum_i d_i^2)^2}{\sum_i d_i^4},\; d_i = q_{(i)} - \bar q_{(\cdot)}:

the posterior's holds where the GP's noise model does, and it alone grows away from the
data; the jackknife's holds where the estimate moves with the data more than the posterior
claims. A jackknife variance is a sum of ``n`` squared influences of which a few may
dominate (a peak seen by two measurements); :math:`\nu`, the Satterthwaite effective
number of them, weights it by Student's t at 95 %. Where fewer than three jackknife
replicates solve, the posterior's is used alone.

The errors standardised by ``s`` are smaller than ``s`` says (``s`` is the larger of two
standard errors, each conservative where the other's assumptions hold) and heavier-tailed
than normal (how far off ``s`` is varies from fit to fit). The interval at level
:math:`\ell` is

.. math::

    q \pm c\, t_{(1+\ell)/2,\,\nu_e}\, s,\qquad c = 0.56,\ \nu_e = 6.2,

the maximum-likelihood scaled Student t of :math:`|\hat q - q|/s` over 1032 tuning trials
with known truth (``bench_calibration.py --tune-kernel --reps 24 --ode-reps 10``: three
sets of 88 fits of FRCs at an untrained forcing level on the averaged Duffing oscillator,
the Duffing ODE and Shaw–Pierre at 0.5–2 % noise, 6 of them failed; over bootstrap
resamples of the fits ``c`` 0.51–0.62 and ``ν_e`` 4.2–16, 90 % range). It covers 0.962,
0.951 and 0.935 of the three sets at nominal 95 %: the sets differ more than their size
suggests, because the four quantities of one fit err together. The reported run is on
other seeds (``docs/uncertainty.md``). The quantities:

- **FRC points** (eq. 6.11): the amplitude ρ at the mean branch's phase ψ (ψ is a regular
  parameter along an FRC of a single-mode response).
- **FRC folds**: a fold of the mean curve is a local extremum of Ω(ψ); on each sampled model
  the extremum of the same kind within a window of the mean fold's index gives its fold
  frequency and amplitude (a model whose extremum lies on the window's edge has no fold
  there and is left out). Extrema are refined between the branch's points by the parabola
  through the extreme point and its neighbours.
- **Peak**: the largest amplitude and its frequency (refined the same way).
- **S-curve points and folds**: the forcing ``F = sqrt(a² + (b − Ω)² ρ²)/Γ₁`` (``Γ₁``: Γ per
  unit F at Ω, :meth:`~._state.ReducedFit.gamma`) at the mean
  branch's ρ, and its extrema near the mean's folds.
- **Backbone points** (eq. 6.21): the frequency at each amplitude.

The amplitudes along a predicted branch err with a heavier-tailed spread relative to ``s``
than the special points do (a few errors are large where the branch is steep in
ψ and between training levels): their intervals have their own shape, fitted the same way
on the FRC amplitude at seven phase lags in the same tuning fits (1806 trials):
:math:`c = 0.57`, :math:`\nu_e = 4.3` (``BAND_SCALE``, ``BAND_DOF``; bootstrap over fits
:math:`c` 0.54–0.64, :math:`\nu_e` 3.3–7.0), covering 0.972, 0.966 and 0.931 of the three
sets at nominal 95 %. The S-curve's forcing and the backbone's frequency use the same shape.

The intervals are on the response of the noise-free system (what the model predicts), not
on a new noisy measurement of it. Hyperparameters are held at their fitted values: how
their selection varies from one noise draw to the next is in neither variance.
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import scipy.stats

from bifid.continuation import Branch, Diagram
from bifid.identify._intervals import critical_value
from bifid.identify.forced_kernel._bands import (
    add_backbone_band,
    add_frc_band,
    add_scurve_band,
    backbone_sample_omega,
    branch_key,
    frc_sample_curves,
    scurve_sample_forcing,
)
from bifid.identify.forced_kernel._gp_core import GPSamples
from bifid.identify.forced_kernel._reduced import ReducedSamples
from bifid.identify.forced_kernel._state import ReducedFit

__all__ = [
    "BAND_DOF",
    "BAND_SCALE",
    "ERROR_DOF",
    "ERROR_SCALE",
    "add_intervals",
    "jackknife_samples",
]

_Q16 = float(scipy.stats.norm.cdf(-1.0))
# the standard error is the 95 % interval's half width over z_0.975 ...
REFERENCE_LEVEL = 0.95
# ... and the standardised errors of the tuning replications follow ERROR_SCALE times
# Student's t with ERROR_DOF degrees of freedom (maximum likelihood, module docstring)
ERROR_SCALE, ERROR_DOF = 0.56, 6.2
# ... and those of the amplitudes along the predicted FRCs (the branch bands) their own
BAND_SCALE, BAND_DOF = 0.57, 4.3
_SPECIAL, _BAND = (ERROR_SCALE, ERROR_DOF), (BAND_SCALE, BAND_DOF)


@jax.jit
def _kinv(chol: jnp.ndarray) -> jnp.ndarray:
    """``K_y⁻¹`` from the Cholesky factor of ``K_y``."""
    return jax.scipy.linalg.cho_solve((chol, True), jnp.eye(chol.shape[0], dtype=chol.dtype))


def jackknife_samples(rf: ReducedFit) -> ReducedSamples:
    """The ``n`` leave-one-point-out posterior means of ``a`` and ``b`` as function samples.

    Leaving training point ``i`` out of a GP at fixed hyperparameters changes its weights
    to ``α⁽⁻ⁱ⁾ = α − K_y⁻¹e_i α_i / [K_y⁻¹]_ii`` (``α⁽⁻ⁱ⁾_i = 0``); the mean
    ``k(x, X) α⁽⁻ⁱ⁾`` is a pathwise sample with no prior part. Point ``i`` leaves ``a`` and
    ``b`` together (the pseudo-observations of ``a`` are never left out).
    """
    n = int(np.sum(np.asarray(rf.gp_b.state_.mask) > 0))

    def gp(st) -> GPSamples:
        kinv = np.asarray(_kinv(st.chol))
        alpha = np.asarray(st.alpha)
        idx = np.arange(n)
        v = alpha[None, :] - kinv[idx, :] * (alpha[idx] / kinv[idx, idx])[:, None]
        d, m = st.n_dim, len(st.monomials)
        return GPSamples(
            freq=jnp.zeros((n, 1, d)),
            phase=jnp.zeros((n, 1)),
            weight=jnp.zeros((n, 1)),
            beta=jnp.zeros((n, m)),
            v=jnp.asarray(v),
        )

    return ReducedSamples(a=gp(rf.gp_a.state_), b=gp(rf.gp_b.state_))


def _interval(
    post: np.ndarray,
    jack: np.ndarray,
    level: float,
    centre: np.ndarray | float,
    shape: tuple[float, float] = _SPECIAL,
) -> tuple[np.ndarray, np.ndarray]:
    """``centre ± c t_ℓ,ν* s`` over axis 0 (``shape``: ``(c, ν*)``) with the standard error
    ``s = max(sqrt(v_post), t_0.95,ν sqrt(v_jack) / z_0.95)`` (module docstring): ``v_post``
    from the posterior samples ``post`` (S, ...), ``v_jack`` the jackknife variance of the
    leave-one-out values ``jack`` (n, ...) with its effective degrees of freedom ``ν``.
    NaN-aware (failed samples and replicates are left out); undefined where no posterior
    sample solved."""
    c = np.asarray(centre, dtype=float)
    post, jack = np.asarray(post, dtype=float), np.asarray(jack, dtype=float)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        q16, q84 = np.nanquantile(post, [_Q16, 1.0 - _Q16], axis=0)
        v_post = (0.5 * (q84 - q16)) ** 2  # robust to a few wild samples
        n = np.sum(np.isfinite(jack), axis=0)
        d2 = (jack - np.nanmean(jack, axis=0)) ** 2
        v_jack = (n - 1) / np.maximum(n, 1) * np.nansum(d2, axis=0)
        dof = np.nansum(d2, axis=0) ** 2 / np.nansum(d2**2, axis=0)
        ok = (n >= 3) & np.isfinite(v_jack) & (v_jack > 0)
        dof = np.where(ok, np.maximum(np.nan_to_num(dof, nan=1.0), 1.0), np.inf)
        t_jack = np.vectorize(critical_value)(REFERENCE_LEVEL, dof) / critical_value(
            REFERENCE_LEVEL
        )
        se = np.maximum(np.sqrt(v_post), np.where(ok, t_jack * np.sqrt(v_jack), 0.0))
        half = shape[0] * critical_value(level, shape[1]) * se  # NaN stays NaN
    return c - half, c + half


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


def _frc_intervals(rf: ReducedFit, b: Branch, level: float, n_samples: int, seed: int) -> None:
    add_frc_band(rf, b, n_samples, level, seed)
    curves = {
        "post": (b.data["sample_omega"], b.data["sample_amplitude"]),
        "jack": rf.cached(
            ("frc-jackknife", *branch_key(b)),
            lambda: frc_sample_curves(rf, b, jackknife_samples(rf)),
        ),
    }
    rho_mean = np.asarray(b.solutions)[:, 0]
    lo, hi = _interval(curves["post"][1], curves["jack"][1], level, rho_mean, _BAND)
    b.intervals["amplitude"] = (lo[:, None], hi[:, None])
    window = max(len(b) // 10, 3)
    for sp in b.special_points:
        if sp.kind not in ("fold", "peak"):
            continue
        om, rho = {}, {}
        for k, (om_s, rho_s) in curves.items():
            if sp.kind == "fold":
                om[k], rho[k] = _sample_extrema(
                    om_s, rho_s, np.asarray(b.params), int(sp.index), window
                )
            else:
                i = int(np.argmax(rho_mean))
                rho[k], om[k] = _sample_extrema(rho_s, om_s, rho_mean, i, len(b))
        iv = _interval(om["post"], om["jack"], level, sp.param)
        sp.intervals["param"] = tuple(float(v) for v in iv)
        amp = float(np.ravel(sp.data["amplitude"])[0])
        a_lo, a_hi = _interval(rho["post"], rho["jack"], level, amp)
        sp.intervals["amplitude"] = ([float(a_lo)], [float(a_hi)])


def _scurve_intervals(rf: ReducedFit, b: Branch, level: float, n_samples: int, seed: int) -> None:
    add_scurve_band(rf, b, n_samples, level, seed)
    f_s = b.data["sample_forcing"]
    f_j = scurve_sample_forcing(rf, b, jackknife_samples(rf))
    f_mean = np.asarray(b.params, float)
    b.intervals["forcing"] = _interval(f_s, f_j, level, f_mean, _BAND)
    window = max(len(b) // 10, 3)
    for sp in b.special_points:
        if sp.kind == "fold":
            f, _ = _sample_extrema(f_s, f_s, f_mean, int(sp.index), window)
            fj, _ = _sample_extrema(f_j, f_j, f_mean, int(sp.index), window)
            sp.intervals["param"] = tuple(float(v) for v in _interval(f, fj, level, sp.param))


def add_intervals(
    rf: ReducedFit, diagram: Diagram, level: float, n_samples: int, seed: int
) -> None:
    """Fill ``intervals`` of a predicted FRC, S-curve or backbone and of its folds and peak
    at ``level`` from ``n_samples`` posterior samples (module docstring); sets
    ``diagram.level``."""
    for b in diagram.branches:
        if diagram.kind == "frc":
            _frc_intervals(rf, b, level, n_samples, seed)
        elif diagram.kind == "scurve":
            _scurve_intervals(rf, b, level, n_samples, seed)
        else:
            add_backbone_band(rf, b, n_samples, level, seed)
            om_j = backbone_sample_omega(rf, b, jackknife_samples(rf))
            om_s, om_mean = b.data["sample_omega"], b.data["omega"]
            b.intervals["omega"] = _interval(om_s, om_j, level, om_mean, _BAND)
    diagram.level = level
