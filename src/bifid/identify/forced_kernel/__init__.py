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

Frequency dependence of the forcing. For ``ẍ + … = F cos Ωt`` first-order averaging gives
a forcing term ``F/(2Ω)``, not a constant times ``F``; over a wide frequency range (or when
``a`` is learned from S-curves, where nothing else tells it how ``Γ`` varies with Ω) that
matters. ``forcing_frequency="inverse"`` uses ``Γ = κF Ω̄/Ω`` with Ω̄ the mean trained
frequency (κ keeps its meaning at Ω̄); the default ``"constant"`` is the thesis's
``Γ = κF``. Every conversion between ``F`` and ``Γ`` goes through
:meth:`._state.ReducedFit.gamma` (NumPy) or :func:`._reduced.frequency_factor` (inside the
JAX solves, where Γ varies with Ω along an FRC).

The pipeline, one module per step: :mod:`._data` (training points from datasets and
arrays), :mod:`._fitting` (κ with ``b``, then ``a`` and ``φ``, on the Gaussian processes of
:mod:`._gp` / :mod:`._gp_core`), :mod:`._reduced` (the learned dynamics as pure JAX
functions), :mod:`._predict` (FRCs by pseudo-arclength continuation, S-curves, backbones,
fixed points and their stability), :mod:`._bands` (posterior-sample bands) and
:mod:`._uncertainty` (intervals at a level: posterior samples and the leave-one-out
jackknife).
:class:`ForcedKernelModel` (:mod:`._model`) is the estimator.
"""

from bifid.identify.forced_kernel._bands import band_coverage
from bifid.identify.forced_kernel._data import ForcedTrainingData, training_data
from bifid.identify.forced_kernel._gp import GPRegressor, HyperBounds
from bifid.identify.forced_kernel._gp_core import (
    GPSamples,
    GPState,
    gp_mean,
    neg_log_marginal_likelihood,
    sample_eval,
)
from bifid.identify.forced_kernel._model import ForcedKernelModel

__all__ = [
    "ForcedKernelModel",
    "ForcedTrainingData",
    "GPRegressor",
    "GPSamples",
    "GPState",
    "HyperBounds",
    "band_coverage",
    "gp_mean",
    "neg_log_marginal_likelihood",
    "sample_eval",
    "training_data",
]
