"""The fitted kernel model as data: the three Gaussian processes, the forcing scale and the
trained ranges, with the posterior samples and eigenvalues predictions need."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.identify.forced_kernel._gp import GPRegressor
from bifid.identify.forced_kernel._reduced import (
    ReducedModel,
    ReducedSamples,
    eigs_mean_g,
    frequency_factor,
)

__all__ = ["ReducedFit"]


@dataclass
class ReducedFit:
    """The learned reduced dynamics (thesis eqs. 6.10–6.20).

    Attributes
    ----------
    gp_a, gp_b : GPRegressor
        ``a(ρ, Ω)`` and ``b(ρ, Ω) − omega_c``.
    gp_phi : GPRegressor or None
        The observation ``y = φ(z)`` (None without time series).
    forcing_scale : float
        ``κ`` in ``Γ = κF`` (at ``Ω = omega_c`` when ``forcing_frequency="inverse"``).
    omega_c : float
        Offset of ``b``, the mean trained frequency; also the reference frequency Ω̄ of
        the forcing term.
    rho_range, omega_range, forcing_range : (float, float)
        Trained amplitudes, frequencies and forcings.
    forcing_frequency : {"constant", "inverse"}
        ``Γ = κF`` or ``Γ = κF Ω̄/Ω`` (:func:`._reduced.frequency_factor`).
    """

    gp_a: GPRegressor
    gp_b: GPRegressor
    gp_phi: GPRegressor | None
    forcing_scale: float
    omega_c: float
    rho_range: tuple[float, float]
    omega_range: tuple[float, float]
    forcing_range: tuple[float, float]
    forcing_frequency: str = "constant"
    _last: dict[Any, Any] = field(default_factory=dict, init=False, repr=False, compare=False)

    def cached(self, key: Any, compute: Callable[[], Any]) -> Any:
        """``compute()``, remembered for the last four keys (predicting the same diagram at
        several levels solves its sampled responses once)."""
        if key not in self._last:
            self._last[key] = compute()
            while len(self._last) > 4:
                self._last.pop(next(iter(self._last)))
        return self._last[key]

    @property
    def model(self) -> ReducedModel:
        """The posterior means as a JAX pytree."""
        return ReducedModel(
            a=self.gp_a.state_,
            b=self.gp_b.state_,
            omega_c=jnp.asarray(self.omega_c),
            forcing_frequency=self.forcing_frequency,
        )

    def gamma(self, forcing, omega) -> np.ndarray:
        """The forcing term ``Γ`` of eq. 6.10 at forcing ``F`` and frequency Ω (arrays
        broadcast): ``κF`` times :func:`._reduced.frequency_factor`."""
        f, om = np.broadcast_arrays(np.asarray(forcing, float), np.asarray(omega, float))
        return self.forcing_scale * f * frequency_factor(self.forcing_frequency, self.omega_c, om)

    def samples(self, n_samples: int, seed: int, n_features: int = 256) -> ReducedSamples:
        """Posterior function samples of ``a`` and ``b`` (pathwise conditioning;
        ``n_features`` random Fourier features approximate the prior part)."""
        return ReducedSamples(
            a=self.gp_a.sample_functions(n_samples, seed=seed, n_features=n_features),
            b=self.gp_b.sample_functions(n_samples, seed=seed + 1, n_features=n_features),
        )

    def stable(self, rho, psi, omega, gamma) -> tuple[np.ndarray, np.ndarray]:
        """Eigenvalues of the Jacobian of eq. 6.10 at fixed points and their stability."""
        eig = np.asarray(eigs_mean_g(self.model, rho, psi, omega, gamma))
        return eig, np.all(eig.real < 0, axis=1)
