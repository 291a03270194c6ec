"""The kernel-model estimator of forced systems (thesis ch. 6): a thin shell over the
training steps (:mod:`._fitting`) and the predictions (:mod:`._predict`, :mod:`._bands`)."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np

from bifid.continuation import Branch, ContinuationOptions, Diagram
from bifid.errors import BifidInputError, ConvergenceError
from bifid.identify._base import DiagramQuery, IdentifiedModel, Orbit
from bifid.identify._persistence import register_model_type
from bifid.identify.forced_kernel import _predict as fp
from bifid.identify.forced_kernel._data import training_data, usable_points
from bifid.identify.forced_kernel._fitting import (
    a_samples,
    fit_kappa,
    fit_observation,
    training_losses,
)
from bifid.identify.forced_kernel._gp import GPRegressor, HyperBounds
from bifid.identify.forced_kernel._hyper import check_hyperparameters
from bifid.identify.forced_kernel._reduced import (
    ReducedModel,
    ReducedSamples,
    ab_grid,
    frequency_factor,
)
from bifid.identify.forced_kernel._state import ReducedFit
from bifid.identify.forced_kernel._uncertainty import add_intervals

__all__ = ["ForcedKernelModel"]


@register_model_type
class ForcedKernelModel(IdentifiedModel):
    """Reduced dynamics ``a(ρ, Ω)``, ``b(ρ, Ω)`` on a forced SSM, learned from forced responses.

    Parameters
    ----------
    forcing_scale : float, "fit" or "auto"
        ``κ`` in ``Γ = κF``. A number is used as given (1.0: the thesis's Γ = F); "fit"
        maximises the marginal likelihood of ``b`` (:mod:`._fitting`; needs several Ω, or
        ``linear_frequency``); "auto" fits when the data hold several forcing frequencies
        or ``linear_frequency`` is given, else uses 1.0 and says so in ``notes_``.
    forcing_frequency : {"constant", "inverse"}
        How the forcing term varies with Ω: ``Γ = κF`` (the thesis) or ``Γ = κF Ω̄/Ω`` with
        Ω̄ the mean trained frequency (the forcing of ``ẍ + … = F cos Ωt`` reaches the
        averaged amplitude equation as ``F/(2Ω)``; κ is the scale at Ω̄). Every conversion
        between ``F`` and ``Γ`` (training samples, κ, FRCs, S-curves, stability, bands)
        uses it.
    linear_frequency : float, optional
        A known small-amplitude natural frequency ω₀ [rad/s] (hammer test, or the first
        point of a measured backbone); identifies κ from one forcing frequency.
    selection : {"ml", "loo"}
        Hyperparameter criterion of the three GPs (marginal likelihood or closed-form
        leave-one-out predictive probability).
    a_target : {"eq6.19", "phase"}
        Samples of ``a``: eq. 6.19 from the fitted ``b`` (thesis) or ``a_j = −Γ_j sin ψ_j``
        directly from the phase (better conditioned far from resonance).
    a_basis, b_basis : tuple of exponent pairs
        Monomials in ``(ρ/s_ρ, (Ω − Ω̄)/s_Ω)`` added to the SE kernels (eq. 6.9 structure).
    n_pseudo : int
        Pseudo-observations ``a(0, Ω) = 0`` spread over the trained Ω range.
    rho_min_fraction : float
        Points with ``ρ`` below this fraction of the largest amplitude are not used (``Γ/ρ``
        in eq. 6.15 amplifies their noise without bound).
    amplitude_kind : {"max", "harmonic"}
        ``ρ`` of a record: ``max_t |y|`` (eq. 6.5, the dataset's amplitude) or the amplitude
        of its first harmonic (less sensitive to noise and higher harmonics).
    observation : bool
        Learn ``φ`` from the time series (eq. 6.20) when the data have them.
    phase_points : int
        Phases per record used to train ``φ`` (capped so the GP has ≤ ``max_phi_points``).
    max_phi_points : int
    noise_floor : float
        Lower bound of the GPs' noise standard deviation relative to the targets' RMS (keeps
        ``K_y`` well conditioned; noise-free data put the noise on this bound).
    n_restarts : int
        Extra seeded L-BFGS starts per GP.
    seed : int
    """

    model_type = "forced_kernel"
    kinds = ("backbone", "frc", "scurve")
    #: ``predict_diagram(level=...)`` gives intervals (``_uncertainty.add_intervals``)
    #: whose level the calibration benchmark shows is reached
    calibrated = True
    #: posterior function samples behind ``predict_diagram(level=...)`` intervals
    interval_samples = 128
    _fitted_attribute = "reduced_"

    def __init__(
        self,
        *,
        forcing_scale: float | Literal["fit", "auto"] = "auto",
        forcing_frequency: Literal["constant", "inverse"] = "constant",
        linear_frequency: float | None = None,
        selection: Literal["ml", "loo"] = "ml",
        a_target: Literal["eq6.19", "phase"] = "eq6.19",
        a_basis: tuple[tuple[int, int], ...] = ((1, 0), (3, 0)),
        b_basis: tuple[tuple[int, int], ...] = ((0, 0), (2, 0)),
        n_pseudo: int = 12,
        rho_min_fraction: float = 0.02,
        amplitude_kind: Literal["max", "harmonic"] = "max",
        observation: bool = True,
        phase_points: int = 16,
        max_phi_points: int = 128,
        noise_floor: float = 1e-5,
        n_restarts: int = 1,
        seed: int = 0,
    ) -> None:
        self.forcing_scale = forcing_scale
        self.forcing_frequency = forcing_frequency
        self.linear_frequency = linear_frequency
        self.selection = selection
        self.a_target = a_target
        self.a_basis = a_basis
        self.b_basis = b_basis
        self.n_pseudo = n_pseudo
        self.rho_min_fraction = rho_min_fraction
        self.amplitude_kind = amplitude_kind
        self.observation = observation
        self.phase_points = phase_points
        self.max_phi_points = max_phi_points
        self.noise_floor = noise_floor
        self.n_restarts = n_restarts
        self.seed = seed

    # ------------------------------------------------------------------ helpers
    def _gp(self, basis: Any) -> GPRegressor:
        return GPRegressor(
            basis=tuple(tuple(int(e) for e in m) for m in basis),
            basis_center=(0.0, None),
            criterion=self.selection,
            n_restarts=self.n_restarts,
            seed=self.seed,
            bounds=HyperBounds(length_scale=(0.05, 100.0), noise=(self.noise_floor, 1.0)),
        )

    # ------------------------------------------------------------------------ fit
    def fit(
        self,
        dataset: Any = None,
        *,
        omega: Any = None,
        forcing: Any = None,
        amplitude: Any = None,
        phase: Any = None,
        stable: Any = None,
        time_series: Sequence[tuple[Any, Any] | None] | None = None,
    ) -> ForcedKernelModel:
        """Learn ``b`` (eq. 6.15), ``a`` (eq. 6.19) and ``φ`` (eq. 6.20) from forced responses.

        Parameters
        ----------
        dataset : path, xarray.Dataset or a list of them, optional
            ``"forced"`` datasets (S-curves, FRCs).
        omega, forcing, amplitude, phase, stable, time_series : arrays, optional
            Points given directly (``phase``: lag of the response behind the force [rad];
            ``time_series``: ``(t, y)`` per point or None), appended to the datasets'.

        Returns
        -------
        self
        """
        check_hyperparameters(self)
        td = training_data(
            dataset,
            {
                "omega": omega,
                "forcing": forcing,
                "amplitude": amplitude,
                "phase": phase,
                "stable": stable,
                "time_series": time_series,
            },
            amplitude_kind=self.amplitude_kind,
        )
        use, notes = usable_points(td, self.rho_min_fraction)
        om, fo, rho, lag = td.omega[use], td.forcing[use], td.amplitude[use], td.phase[use]
        self.forcing_sign_ = 1
        if np.median(np.sin(lag)) < 0:
            self.forcing_sign_ = -1
            lag = lag + np.pi
            notes.append(
                "the force was recorded with the opposite sign (lags in (π, 2π)); lags shifted by π"
            )
        psi = np.pi - lag
        self.train_ = {
            "omega": om,
            "forcing": fo,
            "amplitude": rho,
            "phase": (lag + np.pi / 2) % (2 * np.pi) - np.pi / 2,
            "stable": td.stable[use],
            "curve": td.curve[use],
        }
        self.sources_ = td.sources
        omega_c = float(np.mean(om))
        x = np.stack([rho, om], axis=1)
        # Γ/κ: F times the frequency law of the forcing term (1 or Ω̄/Ω)
        fo_eff = fo * frequency_factor(self.forcing_frequency, omega_c, om)
        e = -fo_eff * np.cos(psi) / rho  # b = Ω + κ e   (eq. 6.15)
        gp_b = self._gp(self.b_basis)
        mode = self._forcing_scale_mode(om, notes)
        kappa, self.kappa_info_ = (
            fit_kappa(gp_b, x, om, e, omega_c, self.linear_frequency, self.n_restarts, self.seed)
            if mode == "fit"
            else (float(mode), {"method": "given"})
        )
        # b's hyperparameters are (re)selected at the final κ with the usual restarts
        gp_b.fit(x, om + kappa * e - omega_c)
        gamma = kappa * fo_eff
        gp_a = self._gp(self.a_basis)
        b_fit = np.asarray(gp_b.predict(x)) + omega_c
        xa, ya, pseudo = a_samples(
            x, gamma, psi, b_fit, target=self.a_target, n_pseudo=self.n_pseudo, notes=notes
        )
        gp_a.fit(xa, ya, pseudo=pseudo, x_scale=np.array([np.std(rho), np.std(om)]))
        gp_phi = None
        if self.observation:
            gp_phi = fit_observation(
                [s for s, u in zip(td.series, use, strict=True) if u],
                om,
                rho,
                selection=self.selection,
                noise_floor=self.noise_floor,
                phase_points=self.phase_points,
                max_phi_points=self.max_phi_points,
                seed=self.seed,
                notes=notes,
            )
        self.reduced_ = ReducedFit(
            gp_a=gp_a,
            gp_b=gp_b,
            gp_phi=gp_phi,
            forcing_scale=kappa,
            omega_c=omega_c,
            rho_range=(float(rho.min()), float(rho.max())),
            omega_range=(float(om.min()), float(om.max())),
            forcing_range=(float(fo.min()), float(fo.max())),
            forcing_frequency=self.forcing_frequency,
        )
        self.losses_ = training_losses(
            self.reduced_.model,
            {"b": gp_b, "a": gp_a, "phi": gp_phi},
            om,
            gamma,
            rho,
            psi,
            self.train_["stable"],
        )
        self.notes_ = notes + [
            n for gp in (gp_a, gp_b, gp_phi) if gp is not None for n in gp.notes_
        ]
        return self

    def _forcing_scale_mode(self, om: np.ndarray, notes: list[str]) -> float | str:
        """``"fit"`` or the fixed κ: ``"auto"`` fits when the data hold several forcing
        frequencies or ``linear_frequency`` is given, else uses 1 and says so."""
        if self.forcing_scale != "auto":
            return self.forcing_scale
        if np.ptp(om) > 1e-9 * np.mean(om) or self.linear_frequency is not None:
            return "fit"
        notes.append(
            "one forcing frequency only: the forcing scale κ cannot be identified and is set "
            "to 1 (Γ = F, the thesis's assumption); predictions at other frequencies depend "
            "on it — give forcing_scale or linear_frequency"
        )
        return 1.0

    # ------------------------------------------------------------------ fitted numbers
    @property
    def forcing_scale_(self) -> float:
        """``κ`` in ``Γ = κF``."""
        self._check_fitted()
        return self.reduced_.forcing_scale

    @property
    def rho_range_(self) -> tuple[float, float]:
        """Range of the trained amplitudes."""
        self._check_fitted()
        return self.reduced_.rho_range

    @property
    def omega_range_(self) -> tuple[float, float]:
        """Range of the trained forcing frequencies [rad/s]."""
        self._check_fitted()
        return self.reduced_.omega_range

    @property
    def forcing_range_(self) -> tuple[float, float]:
        """Range of the trained forcing amplitudes."""
        self._check_fitted()
        return self.reduced_.forcing_range

    @property
    def n_train_(self) -> int:
        """Number of training points used."""
        return int(np.asarray(self.train_["omega"]).size)

    def reduced_dynamics(self, rho: Any, omega: Any) -> tuple[np.ndarray, np.ndarray]:
        """Posterior means of ``a(ρ, Ω)`` and ``b(ρ, Ω)`` (broadcast arrays)."""
        self._check_fitted()
        r, o = np.broadcast_arrays(np.asarray(rho, float), np.asarray(omega, float))
        a, b = ab_grid(self.reduced_.model, r.ravel(), o.ravel())
        return np.asarray(a).reshape(r.shape), np.asarray(b).reshape(r.shape)

    def eigenvalues(self, rho: Any, psi: Any, omega: Any, forcing: Any) -> np.ndarray:
        """Eigenvalues (N, 2) of the Jacobian of eq. 6.10 in ``(ρ, ψ)`` at fixed points
        (``forcing`` is ``F``; a point is stable iff both have negative real part)."""
        self._check_fitted()
        r, p, o, f = (
            np.atleast_1d(np.asarray(v, dtype=float))
            for v in np.broadcast_arrays(rho, psi, omega, forcing)
        )
        return self.reduced_.stable(r, p, o, self.reduced_.gamma(f, o))[0]

    def sample_reduced(
        self, n_samples: int, *, seed: int = 0, n_features: int = 256
    ) -> ReducedSamples:
        """Posterior function samples of ``a`` and ``b`` (pathwise conditioning)."""
        self._check_fitted()
        return self.reduced_.samples(n_samples, seed, n_features)

    @property
    def model_(self) -> ReducedModel:
        """The posterior means as a JAX pytree (for the pure functions of :mod:`._reduced`)."""
        self._check_fitted()
        return self.reduced_.model

    # ------------------------------------------------------------------ predictions
    def fixed_points(
        self, omega: float, forcing: float, *, rho_max: float | None = None, n_grid: int = 2000
    ) -> list[dict[str, float]]:
        """All fixed points of eq. 6.10 at ``(Ω, F)``: ``{rho, psi, phase, stable}`` sorted
        by amplitude."""
        self._check_fitted()
        return fp.fixed_points(self.reduced_, omega, forcing, rho_max=rho_max, n_grid=n_grid)

    def frc(
        self,
        forcing: float,
        omega_range: Any = None,
        *,
        options: ContinuationOptions | None = None,
        rho_cap: float | None = None,
    ) -> Branch:
        """Forced response curve at ``F`` (:func:`._predict.frc`, eq. 6.10), the posterior
        mean; intervals: ``predict_diagram(forcing=F, level=...)``."""
        self._check_fitted()
        return fp.frc(self.reduced_, forcing, omega_range, options=options, rho_cap=rho_cap)

    def scurve(
        self,
        omega: float,
        forcing_range: Any = None,
        *,
        n_points: int = 400,
        rho_cap: float | None = None,
    ) -> Branch:
        """S-curve at Ω (:func:`._predict.scurve`), the posterior mean; intervals:
        ``predict_diagram(omega=Ω, level=...)``."""
        self._check_fitted()
        return fp.scurve(self.reduced_, omega, forcing_range, n_points=n_points, rho_cap=rho_cap)

    def backbone(self, amplitude_range: Any = None, *, n_points: int = 200) -> Branch:
        """Backbone curve (:func:`._predict.backbone`, eq. 6.21), the posterior mean;
        intervals: ``predict_diagram(kind="backbone", level=...)``."""
        self._check_fitted()
        return fp.backbone(self.reduced_, amplitude_range, n_points=n_points)

    def _predict_diagram(self, query: DiagramQuery) -> Diagram:
        if (
            query.param is not None
            and query.param
            not in {
                "frc": ("Omega", "omega"),
                "scurve": ("F", "forcing"),
                "backbone": ("amplitude",),
            }[query.kind]
        ):
            raise BifidInputError(
                f"the parameter of a forced model's {query.kind} is fixed; "
                f"got param={query.param!r}."
            )
        if query.kind == "frc":
            br = self.frc(query.forcing, query.range)
            info = {"observed": "y", "forcing": query.forcing}
        elif query.kind == "scurve":
            br = self.scurve(query.omega, query.range, n_points=query.n_points)
            info = {"observed": "y", "omega": query.omega}
        else:
            br = self.backbone(query.range, n_points=query.n_points)
            info = {"observed": "y", "linear_frequency": self._linear_frequency()}
        return Diagram(
            kind=query.kind,
            system=self.model_type,
            param=br.param,
            branches=[br],
            source=self.model_type,
            units={"Omega": "rad/s"},
            info=info,
        )

    def _add_intervals(self, diagram: Diagram, query: DiagramQuery, level: float) -> None:
        """Posterior-sample and jackknife intervals on the predicted diagram
        (:func:`._uncertainty.add_intervals`, seeded by ``seed``), with a warning where the
        prediction leaves the trained forcing or frequency range."""
        value, (lo, hi) = {
            "frc": (query.forcing, self.forcing_range_),
            "scurve": (query.omega, self.omega_range_),
        }.get(query.kind, (None, (0.0, 0.0)))
        if value is not None and not lo <= value <= hi:
            warnings.warn(
                f"the prediction at {value:g} lies outside the trained range {lo:g}..{hi:g}: "
                "its intervals rest on the kernels' form there, not on data.",
                UserWarning,
                stacklevel=3,
            )
        add_intervals(self.reduced_, diagram, level, self.interval_samples, self.seed)

    def _response(
        self, value: float, stable: bool, forcing: float | None, omega: float | None
    ) -> tuple[float, float, float, float]:
        """``(Ω, F, ρ, ψ)`` of the response at ``value`` (see :meth:`predict_orbit`)."""
        om, f = (value, float(forcing)) if forcing is not None else (float(omega), value)
        pts = [p for p in self.fixed_points(om, f) if p["stable"] == stable]
        if not pts:
            raise BifidInputError(
                f"The model has no {'stable' if stable else 'unstable'} "
                f"response at Ω = {om:g}, F = {f:g}."
            )
        return om, f, pts[-1]["rho"], pts[-1]["psi"]

    def _predict_orbit(
        self, value: float, stable: bool, forcing: float | None, omega: float | None, n: int
    ) -> Orbit:
        """One period of the observed signal on the response at ``(Ω, F)`` (eq. 6.20); ``t``
        from a maximum of the force ``F cos Ωt``."""
        om, f, rho, psi = self._response(value, stable, forcing, omega)
        t = np.linspace(0.0, 2 * np.pi / om, n, endpoint=False)
        return Orbit(
            param="Omega" if forcing is not None else "F",
            value=value,
            stable=stable,
            period=2 * np.pi / om,
            t=t,
            signals=self.time_series(t, rho, psi, om)[:, None],
            signal_names=("y",),
            forcing=f,
            omega=om,
        )

    def _predict_amplitude(
        self, values: np.ndarray, stable: bool, forcing: float | None, omega: float | None
    ) -> np.ndarray:
        """``ρ = max_t |y|`` (eq. 6.14) of the responses at ``values`` (Ω with ``forcing``,
        F with ``omega``), shape ``(n, 1)``."""
        return np.array([[self._response(v, stable, forcing, omega)[2]] for v in values])

    def time_series(self, t: Any, rho: float, psi: float, omega: float) -> np.ndarray:
        """Observed signal ``y(t) = φ(ρ cos(Ωt + ψ), ρ sin(Ωt + ψ))`` (eq. 6.20).

        ``t`` is measured from a maximum of the force ``F cos Ωt``. Without a learned ``φ``
        (no time series in the data) the first-harmonic approximation ``−ρ cos(Ωt + ψ)``
        (eq. 6.14) is returned, with a warning.
        """
        self._check_fitted()
        tt = np.asarray(t, dtype=float)
        th = float(omega) * tt + float(psi)
        if self.reduced_.gp_phi is None:
            warnings.warn(
                "no observation model was learned (no time series in the data); "
                "returning the first-harmonic approximation −ρ cos(Ωt + ψ).",
                stacklevel=2,
            )
            return -float(rho) * np.cos(th)
        z = np.stack([rho * np.cos(th.ravel()), rho * np.sin(th.ravel())], axis=1)
        return np.asarray(self.reduced_.gp_phi.predict(z)).reshape(tt.shape)

    # --------------------------------------------------------------------- summary
    def _linear_frequency(self) -> float | None:
        """Small-amplitude end of the backbone (eq. 6.21): the linear natural frequency."""
        try:
            bb = fp.backbone(self.reduced_, (0.0, 0.02 * self.rho_range_[1]), n_points=3)
        except ConvergenceError:
            return None
        return float(bb.data["omega"][0])

    def summary(self) -> dict[str, Any]:
        """``parameters`` (forcing scale, GP hyperparameters, linear frequency),
        ``standard_errors`` of the forcing scale (when fitted) and of the GP
        hyperparameters (Laplace approximation of the marginal likelihood,
        :attr:`GPRegressor.hyperparameter_errors_`), ``losses``, trained ranges and notes."""
        self._check_fitted()
        rf = self.reduced_
        params: dict[str, Any] = {
            "forcing_scale": rf.forcing_scale,
            "forcing_scale_fit": dict(self.kappa_info_),
            "forcing_frequency": rf.forcing_frequency,
            "a": rf.gp_a.hyperparameters_,
            "b": rf.gp_b.hyperparameters_,
            "omega_offset": rf.omega_c,
            "linear_frequency": self._linear_frequency(),
        }
        errors: dict[str, Any] = {
            "a": rf.gp_a.hyperparameter_errors_,
            "b": rf.gp_b.hyperparameter_errors_,
        }
        if "standard_error" in self.kappa_info_:
            errors["forcing_scale"] = self.kappa_info_["standard_error"]
        if rf.gp_phi is not None:
            params["phi"] = rf.gp_phi.hyperparameters_
            errors["phi"] = rf.gp_phi.hyperparameter_errors_
        return {
            "parameters": params,
            "standard_errors": errors,
            "losses": self.losses_,
            "n_train": self.n_train_,
            "trained_ranges": {
                "omega": list(rf.omega_range),
                "amplitude": list(rf.rho_range),
                "forcing": list(rf.forcing_range),
            },
            "notes": list(self.notes_),
        }

    def _state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        rf = self.reduced_
        arrays = {
            **rf.gp_a.to_arrays("a_"),
            **rf.gp_b.to_arrays("b_"),
            **(rf.gp_phi.to_arrays("phi_") if rf.gp_phi is not None else {}),
            **{f"train_{k}": np.asarray(v) for k, v in self.train_.items()},
        }
        state = {
            "gp": {
                "a": rf.gp_a.get_params(),
                "b": rf.gp_b.get_params(),
                "phi": None if rf.gp_phi is None else rf.gp_phi.get_params(),
            },
            "forcing_scale": rf.forcing_scale,
            "forcing_frequency": rf.forcing_frequency,
            "omega_c": rf.omega_c,
            "rho_range": list(rf.rho_range),
            "omega_range": list(rf.omega_range),
            "forcing_range": list(rf.forcing_range),
            "forcing_sign": self.forcing_sign_,
            "kappa_info": self.kappa_info_,
            "losses": self.losses_,
            "notes": self.notes_,
            "sources": list(self.sources_),
        }
        return state, arrays

    def _restore(self, state: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        gp = state["gp"]
        self.reduced_ = ReducedFit(
            gp_a=GPRegressor.from_arrays(gp["a"], arrays, "a_"),
            gp_b=GPRegressor.from_arrays(gp["b"], arrays, "b_"),
            gp_phi=None
            if gp["phi"] is None
            else GPRegressor.from_arrays(gp["phi"], arrays, "phi_"),
            forcing_scale=float(state["forcing_scale"]),
            omega_c=float(state["omega_c"]),
            rho_range=tuple(map(float, state["rho_range"])),
            omega_range=tuple(map(float, state["omega_range"])),
            forcing_range=tuple(map(float, state["forcing_range"])),
            forcing_frequency=str(state.get("forcing_frequency", "constant")),
        )
        self.forcing_sign_ = int(state["forcing_sign"])
        self.kappa_info_ = dict(state["kappa_info"])
        self.losses_ = state["losses"]
        self.notes_ = list(state["notes"])
        self.sources_ = list(state["sources"])
        self.train_ = {
            k[len("train_") :]: np.asarray(v) for k, v in arrays.items() if k.startswith("train_")
        }
