r"""The hybrid normal-form + neural-network estimator (thesis ch. 5).

:class:`HopfHybridModel` is a thin shell: it checks hyperparameters, runs the training
stages (:mod:`._train`, :mod:`._speed_stage`) on the prepared data (:mod:`._prepare`) and
keeps the result as one :class:`~._state.HybridState`, which the prediction functions
(:mod:`._cycles`, :mod:`._diagram`) read.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from bifid.continuation import Diagram
from bifid.continuation._blas import one_blas_thread
from bifid.errors import BifidInputError
from bifid.identify._base import DiagramQuery, IdentifiedModel, Orbit
from bifid.identify._intervals import warn_extrapolation
from bifid.identify._persistence import register_model_type
from bifid.identify._records import LCOData, as_lco_data
from bifid.identify.hopf_hybrid import _cycles as cy
from bifid.identify.hopf_hybrid import _uncertainty as uq
from bifid.identify.hopf_hybrid._cv import leave_one_out
from bifid.identify.hopf_hybrid._diagram import ensemble_spread, hybrid_diagram, spread
from bifid.identify.hopf_hybrid._hyper import check_hyperparameters
from bifid.identify.hopf_hybrid._normal_form import raw_a2
from bifid.identify.hopf_hybrid._prepare import Preprocessing, measured_amplitudes
from bifid.identify.hopf_hybrid._speed_stage import PhaseMatcher, speed_stage
from bifid.identify.hopf_hybrid._state import HybridState
from bifid.identify.hopf_hybrid._timing import StageTimer, progress_bar
from bifid.identify.hopf_hybrid._train import (
    configure,
    select_map_hyper,
    train_members,
    train_observation,
)

__all__ = ["HopfHybridModel"]


@register_model_type
class HopfHybridModel(IdentifiedModel):
    r"""Hybrid mechanistic/machine-learnt model of a system with a Hopf bifurcation.

    Parameters
    ----------
    criticality : {"auto", "subcritical", "supercritical"}
        Sign of :math:`a_2`. ``"auto"``: subcritical if any record is labelled unstable.
    quintic : bool, optional
        Keep the :math:`-r^5` term (needed for a fold of cycles). Default: on for
        subcritical, off for supercritical (then :math:`a_2 = -1` is fixed, §5.4.1).
    plane : pair of str or int, optional
        The two signals :math:`(z_1, z_2)` whose orbits are closed curves around a centre
        (default: the first two signals).
    n_harmonics : int or "auto"
        Harmonics of the polar representation (eq. 5.5). ``"auto"``: the smallest number
        representing every measured orbit to 0.3 % of its radius above the noise floor.
    n_points : int or "auto"
        Points per model cycle in the map loss (``"auto"``: ``max(64, 4 n_harmonics + 8)``).
    width, depth : int
        Hidden width and layers of :math:`\mathrm{NN}_{\Theta_U}`.
    n_linear : int
        L-BFGS iterations of stage 1 (linear part).
    n_adam, n_lbfgs : int
        Adam then L-BFGS iterations of stage 2 (network, :math:`\mu_0`, :math:`a_2`).
    learning_rate : float
        Peak Adam learning rate (cosine decay) of stage 2.
    regularization : "cv" or float
        L2 weight :math:`\lambda` on the network's weight matrices; ``"cv"`` picks it from
        ``regularization_grid`` by leave-one-orbit-out cross-validation.
    regularization_grid : sequence of float
    stopping : {"cv", "final"} or int
        ``"cv"``: stop stage 2 at the iteration with the smallest leave-one-out error (early
        stopping); ``"final"``: after all iterations; an int: after that many.
    cv_score : {"median", "mean"}
        How the held-out losses of the folds are combined (the mean is dominated by the folds
        that extrapolate; the median scores the typical orbit).
    n_ensemble : int
        Members trained from different network initialisations; predictions use the medoid
        member, :meth:`ensemble_spread` the others.
    omega_harmonics : int
        :math:`n_\Omega` of eq. 5.10.
    omega_form : {"log", "additive"}
        ``"additive"``: eq. 5.10 as printed; ``"log"``: the Fourier series gives
        :math:`\log\Omega`, so the speed is positive by construction.
    omega_width, omega_depth : int
        Shape of :math:`\mathrm{NN}_{\Theta_\Omega}`.
    omega_fit_iterations, omega_iterations : int
        Adam iterations fitting the network to the measured speed profiles, then L-BFGS
        iterations on eq. 5.13 (time series through the phase equation).
    omega_learning_rate : float
    omega_regularization : "cv" or float
        L2 weight on :math:`\mathrm{NN}_{\Theta_\Omega}` (``"cv"``: leave-one-orbit-out).
    omega_regularization_grid : sequence of float
    omega_samples : int
        At most this many samples per record in eq. 5.13 (records are decimated).
    omega_periods : float
        At most this many periods per record in eq. 5.13.
    seed : int
        Seed of every random initialisation.
    progress : bool
        Show progress on stderr.
    """

    model_type = "hopf_hybrid"
    kinds = ("bifurcation",)
    uncertainty_note = (
        "it was fitted without uncertainty=True (bifid fit hopf --level); ensemble_spread() "
        "gives the spread over training seeds, not a confidence interval"
    )
    _fitted_attribute = "state_"

    def __init__(
        self,
        *,
        criticality: str = "auto",
        quintic: bool | None = None,
        plane: Sequence[str | int] | None = None,
        n_harmonics: int | str = "auto",
        n_points: int | str = "auto",
        width: int = 16,
        depth: int = 2,
        n_linear: int = 100,
        n_adam: int = 0,
        n_lbfgs: int = 600,
        learning_rate: float = 3e-3,
        regularization: str | float = "cv",
        regularization_grid: Sequence[float] = (1e-6, 1e-5, 1e-4),
        stopping: str | int = "cv",
        cv_score: str = "median",
        n_ensemble: int = 5,
        omega_harmonics: int = 6,
        omega_form: str = "log",
        omega_width: int = 16,
        omega_depth: int = 2,
        omega_fit_iterations: int = 400,
        omega_iterations: int = 100,
        omega_learning_rate: float = 3e-3,
        omega_regularization: str | float = "cv",
        omega_regularization_grid: Sequence[float] = (1e-6, 1e-4, 1e-2),
        omega_samples: int = 500,
        omega_periods: float = 10.0,
        seed: int = 0,
        progress: bool = False,
    ) -> None:
        self.criticality = criticality
        self.quintic = quintic
        self.plane = plane
        self.n_harmonics = n_harmonics
        self.n_points = n_points
        self.width = width
        self.depth = depth
        self.n_linear = n_linear
        self.n_adam = n_adam
        self.n_lbfgs = n_lbfgs
        self.learning_rate = learning_rate
        self.regularization = regularization
        self.regularization_grid = regularization_grid
        self.stopping = stopping
        self.cv_score = cv_score
        self.n_ensemble = n_ensemble
        self.omega_harmonics = omega_harmonics
        self.omega_form = omega_form
        self.omega_width = omega_width
        self.omega_depth = omega_depth
        self.omega_fit_iterations = omega_fit_iterations
        self.omega_iterations = omega_iterations
        self.omega_learning_rate = omega_learning_rate
        self.omega_regularization = omega_regularization
        self.omega_regularization_grid = omega_regularization_grid
        self.omega_samples = omega_samples
        self.omega_periods = omega_periods
        self.seed = seed
        self.progress = progress

    # ----------------------------------------------------------------------------- fit
    @property
    def calibrated(self) -> bool:  # type: ignore[override]
        """Whether ``predict_diagram(level=...)`` gives intervals (``fit(uncertainty=True)``)."""
        return bool(getattr(self, "replicates_", None))

    def fit(
        self,
        dataset: Any,
        *,
        signal_names: Sequence[str] | None = None,
        uncertainty: bool = False,
    ) -> HopfHybridModel:
        """Train on limit cycles, stable and unstable.

        Parameters
        ----------
        dataset
            An LCO dataset (xarray or path), a list of them, :class:`~bifid.identify.LCOData`
            or records ``(param, signals (n, m), sample_rate, stable)``.
        signal_names : sequence of str, optional
            Names of the signals of bare records.
        uncertainty : bool
            Also retrain the model on resamplings of the records' noise (one member
            each, the selected hyperparameters fixed: on the order of the fit's own time),
            so that ``predict_diagram(level=...)`` gives intervals and :meth:`summary`
            standard errors (bootstrap and ensemble, :mod:`._uncertainty`).

        Returns
        -------
        self

        Raises
        ------
        BifidInputError
            Invalid data or hyperparameters.
        ConvergenceError
            If no ensemble member produces finite parameters.
        """
        check_hyperparameters(self)
        data = as_lco_data(dataset, signal_names)
        with one_blas_thread():
            self._fit(data, np.ones(len(data), dtype=bool))
            t0 = time.perf_counter()
            self.training_["amplitude"] = measured_amplitudes(data, self.training_["frequency"])
            self.timings_["total"] += time.perf_counter() - t0
        self.replicates_: list[HybridState] = []
        if uncertainty:
            t0 = time.perf_counter()
            self.replicates_ = uq.bootstrap(self, data)
            self.timings_["bootstrap"] = time.perf_counter() - t0
            self.timings_["total"] += self.timings_["bootstrap"]
        return self

    def _fit(
        self,
        data: LCOData,
        active: np.ndarray,
        init: Any = None,
        pre: Preprocessing | None = None,
    ) -> HopfHybridModel:
        """Fit on the records ``active`` (others keep their slot, weight 0), map from ``init``,
        the records' preprocessing from ``pre`` (their :class:`~._prepare.Preprocessing`)."""
        t_start = time.perf_counter()
        if len(data) < 2 or not data.has_records:
            raise BifidInputError(
                f"The hybrid Hopf model needs at least 2 limit-cycle records with samples; got "
                f"{len(data)}{'' if data.has_records else ' without samples'}."
            )
        pre = pre or Preprocessing(data)
        setup = configure(
            data,
            plane=self.plane,
            criticality=self.criticality,
            quintic=self.quintic,
            n_harmonics=self.n_harmonics,
            n_points=self.n_points,
            width=self.width,
            depth=self.depth,
            n_linear=self.n_linear,
            n_adam=self.n_adam,
            n_lbfgs=self.n_lbfgs,
            learning_rate=self.learning_rate,
            preprocessing=pre,
        )
        prep = pre.prepared(setup.plane, setup.n_harmonics)
        timer = StageTimer()
        with progress_bar(self.progress, 4, "hopf_hybrid") as tick:
            grid = (
                self.regularization_grid if self.regularization == "cv" else (self.regularization,)
            )
            lam, stop, cv = select_map_hyper(
                prep,
                setup,
                active,
                grid=grid,
                choose_lambda=self.regularization == "cv",
                stopping=self.stopping,
                cv_score=self.cv_score,
                seed=self.seed,
                timer=timer,
            )
            tick("map: cross-validation")
            map_params, primary, losses = train_members(
                prep,
                setup,
                lam,
                stop,
                active,
                n_members=self.n_ensemble,
                seed=self.seed,
                timer=timer,
                init=init,
            )
            tick("map: ensemble")
            matcher = PhaseMatcher(map_params, setup.map_config, prep, active, data.param_name)
            speed = speed_stage(
                self.get_params(), prep, setup.map_config, matcher, active, primary, timer
            )
            tick("oscillation speed")
            n_members = int(np.asarray(map_params["mu0"]).shape[0])
            order = [primary] + [s for s in range(n_members) if s != primary]
            rho = np.array([matcher.rho(s) for s in range(n_members)])
            observation = train_observation(
                prep,
                setup.others,
                order,
                rho,
                lambda s, i, pts: matcher.phases(s, i, rho[s, i], pts),
                active,
                timer,
            )
            tick("other signals")
        self.state_ = HybridState(
            map_config=setup.map_config,
            speed_config=speed.config,
            map_params=map_params,
            speed_params=speed.params,
            observation=observation,
            plane=setup.plane,
            others=setup.others,
            mu_c=prep.mu_c,
            mu_s=prep.mu_s,
            z_scale=prep.z_scale,
            white=prep.white,
            direction=prep.direction,
            q5=setup.q5,
            a2_mode=setup.a2_mode,
            omega_scale=speed.omega_scale,
            signal_names=data.signal_names,
            param_name=data.param_name,
            param_units=data.param_units,
            signal_units=dict(data.signal_units),
            primary=primary,
        )
        self.criticality_ = setup.criticality
        self.regularization_ = lam
        self.n_iterations_ = int(stop)
        self.cv_ = cv
        self.speed_regularization_ = speed.regularization
        self.speed_cv_ = speed.cv
        self.losses_ = {**losses, "speed": speed.losses}
        idx = np.nonzero(active)[0]
        # the measured amplitudes are added by fit (a refit does not need them)
        self.training_ = {k: v[idx] for k, v in (("param", data.param), ("stable", data.stable))}
        self.training_["frequency"] = prep.omega[idx]
        self.timings_ = {k: float(v) for k, v in timer.times.items()}
        self.timings_["total"] = time.perf_counter() - t_start
        return self

    # ---------------------------------------------------------------- fitted numbers
    def hopf_point(self, member: int | None = None) -> dict[str, Any]:
        r"""The Hopf point :math:`\mu_0` of the primary (or a given) ensemble member:
        ``param``, ``omega`` (rad/s), ``lyapunov`` (:math:`a_2` in raw units, its sign the
        criticality) and ``criticality``."""
        self._check_fitted()
        h = cy.hopf_point(self.state_, self._member(member))
        return {k: h[k] for k in ("param", "omega", "lyapunov", "criticality")}

    def cycle_fold(self, member: int | None = None) -> dict[str, Any] | None:
        r"""The fold of cycles :math:`\mu_0 - a_2^2/4`: ``param``, ``period`` and
        ``amplitude`` by signal (None if the model has no fold)."""
        self._check_fitted()
        f = cy.cycle_fold(self.state_, self._member(member))
        if f is None:
            return None
        return {
            "param": f["param"],
            "period": f["period"],
            "amplitude": dict(zip(self.state_.signal_names, f["amplitude"].tolist(), strict=True)),
        }

    def _member(self, member: int | None) -> int:
        s = self.state_.primary if member is None else int(member)
        if not 0 <= s < self.state_.n_members:
            raise BifidInputError(f"member must be in 0..{self.state_.n_members - 1}, got {s}.")
        return s

    @property
    def mu0_(self) -> float:
        """Hopf point (raw units) of the primary member."""
        return self.hopf_point()["param"]

    @property
    def a2_(self) -> float:
        """:math:`a_2` of eq. 5.3 in raw parameter units (primary member)."""
        self._check_fitted()
        st = self.state_
        return raw_a2(st.a2(st.primary), st.mu_s, st.q5)

    @property
    def omega0_(self) -> float:
        """:math:`\\omega_0` of eq. 5.10 [rad/s]: the speed's constant term (primary member)."""
        self._check_fitted()
        return uq.omega0(self.state_, self.state_.primary)

    # --------------------------------------------------------------------- predictions
    def _range(self, rng: tuple[float, float] | None) -> tuple[float, float]:
        if rng is not None:
            return rng
        lo, hi = float(np.min(self.training_["param"])), float(np.max(self.training_["param"]))
        pad = 0.25 * (hi - lo)
        return min(lo - pad, self.mu0_ - pad), max(hi + pad, self.mu0_ + pad)

    def _predict_diagram(self, query: DiagramQuery) -> Diagram:
        st = self.state_
        if query.param not in (None, st.param_name):
            raise BifidInputError(
                f"This model's bifurcation parameter is {st.param_name!r}, not {query.param!r}."
            )
        lo, hi = self._range(query.range)
        return hybrid_diagram(st, st.primary, lo, hi, query.n_points, self.model_type)

    def _add_intervals(self, diagram: Diagram, query: DiagramQuery, level: float) -> None:
        """Bootstrap-and-ensemble intervals (:func:`._uncertainty.add_intervals`), with a
        warning where the prediction leaves the trained parameter range."""
        trained = (float(np.min(self.training_["param"])), float(np.max(self.training_["param"])))
        warn_extrapolation(self.state_.param_name, self._range(query.range), trained, 4)
        uq.add_intervals(diagram, self, level)

    def ensemble_spread(
        self, range: tuple[float, float] | None = None, n_points: int = 50
    ) -> dict[str, Any]:
        """Spread of the ensemble over training seeds on a parameter grid: per branch the
        minimum, median and maximum amplitude of each signal, and the spread of the Hopf and
        fold parameters. A spread, not a confidence interval."""
        self._check_fitted()
        lo, hi = self._range(None if range is None else tuple(sorted(map(float, range))))
        return ensemble_spread(self.state_, lo, hi, n_points)

    def _cycle(self, value: float, stable: bool) -> tuple[float, float]:
        return cy.cycle(self.state_, self.state_.primary, float(value), stable)

    def _predict_amplitude(
        self, values: np.ndarray, stable: bool, forcing: float | None, omega: float | None
    ) -> np.ndarray:
        """``max_t |z_k(t)|`` of every signal on the cycles at ``values``, shape
        ``(len(values), n_signals)`` (about the signals' zero, as measured)."""
        st = self.state_
        out = []
        for v in values:
            mu_t, rho = self._cycle(v, stable)
            out.append(cy.amplitudes(st, st.primary, np.array([mu_t]), np.array([rho]))[0])
        return np.asarray(out)

    def predict_frequency(
        self, values: Sequence[float] | float, *, stable: bool = True
    ) -> np.ndarray:
        """Angular frequency :math:`2\\pi/T` [rad/s] of the cycles at ``values``."""
        self._check_fitted()
        out = []
        for v in self._values(values):
            mu_t, rho = self._cycle(v, stable)
            out.append(2 * math.pi / cy.period(self.state_, self.state_.primary, rho, mu_t)[0])
        return np.asarray(out)

    def _predict_orbit(
        self, value: float, stable: bool, forcing: float | None, omega: float | None, n: int
    ) -> Orbit:
        """One period of every signal on the cycle at ``value``."""
        mu_t, rho = self._cycle(value, stable)
        T = float(cy.period(self.state_, self.state_.primary, rho, mu_t)[0])
        t = np.linspace(0.0, T, n, endpoint=False)
        z = cy.time_series(self.state_, self.state_.primary, mu_t, rho, t)
        return Orbit(
            param=self.state_.param_name,
            value=value,
            stable=stable,
            period=T,
            t=t,
            signals=z,
            signal_names=self.state_.signal_names,
        )

    def predict_time_series(
        self,
        value: float,
        times: np.ndarray,
        *,
        stable: bool = True,
        initial: np.ndarray | None = None,
        initial_phase: float = 0.0,
    ) -> np.ndarray:
        """Every signal on the cycle at ``value`` at ``times`` (increasing, [s]), shape
        ``(len(times), n_signals)``; ``initial`` (a measured sample at ``times[0]``) matches
        the initial phase by its polar angle in the plane (eq. 5.12), else ``initial_phase``
        (normal-form phase) is used."""
        self._check_fitted()
        mu_t, rho = self._cycle(value, stable)
        times = np.asarray(times, dtype=float)
        if times.ndim != 1 or len(times) < 1 or np.any(np.diff(times) <= 0):
            raise BifidInputError("times must be a 1-D increasing array.")
        return cy.time_series(
            self.state_, self.state_.primary, mu_t, rho, times, initial, initial_phase
        )

    def cross_validate(
        self, dataset: Any, *, signal_names: Sequence[str] | None = None
    ) -> dict[str, Any]:
        """Leave-one-orbit-out validation with the fitted hyperparameters: every record is
        left out in turn and predicted by a model trained on the others
        (:func:`~bifid.identify.hopf_hybrid._cv.leave_one_out`)."""
        self._check_fitted()
        return leave_one_out(self, as_lco_data(dataset, signal_names))

    # ------------------------------------------------------------------------ summary
    def summary(self) -> dict[str, Any]:
        """``parameters`` (Hopf point ``mu0``, ``a2``, ``omega0``, fold, criticality and the
        selected hyperparameters), ``standard_errors`` of ``mu0``, ``a2``, ``omega0``,
        ``hopf_omega`` and ``fold`` (after ``fit(..., uncertainty=True)``; else empty),
        ``ensemble`` (the spread over seeds), ``losses``, ``cv`` and ``timings``."""
        self._check_fitted()
        st = self.state_
        n = st.n_members
        fold = self.cycle_fold()
        ensemble = {
            "mu0": spread([cy.hopf_point(st, s)["param"] for s in range(n)]),
            "a2": spread([raw_a2(st.a2(s), st.mu_s, st.q5) for s in range(n)]),
        }
        folds = [f["param"] for s in range(n) if (f := cy.cycle_fold(st, s))]
        if folds:
            ensemble["fold"] = spread(folds)
        return {
            "parameters": {
                "mu0": self.mu0_,
                "a2": self.a2_,
                "q5": st.q5,
                "omega0": self.omega0_,
                "hopf_omega": self.hopf_point()["omega"],
                "fold": fold["param"] if fold else None,
                "criticality": self.criticality_,
                "param_name": st.param_name,
                "regularization": self.regularization_,
                "n_iterations": self.n_iterations_,
                "omega_regularization": self.speed_regularization_,
                "n_members": n,
                "primary_member": st.primary,
            },
            "standard_errors": uq.named_standard_errors(self) if self.calibrated else {},
            "ensemble": ensemble,
            "losses": {**self.losses_, "cv_score": self.cv_.get("best_score")},
            "cv": self.cv_,
            "speed_cv": self.speed_cv_,
            "timings": self.timings_,
        }

    _FITTED = ("criticality", "regularization", "n_iterations", "cv", "losses", "timings")
    _FITTED += ("speed_regularization", "speed_cv")

    def _state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        settings, arrays = self.state_.to_json()
        replicates, rep_arrays = uq.replicates_to_json(self.replicates_)
        arrays.update(rep_arrays)
        arrays.update({f"training_{k}": np.asarray(v) for k, v in self.training_.items()})
        fitted = {k: getattr(self, f"{k}_") for k in self._FITTED}
        return {"model": settings, "fitted": fitted, **replicates}, arrays

    def _restore(self, state: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        self.state_ = HybridState.from_json(state["model"], arrays)
        for k in self._FITTED:
            setattr(self, f"{k}_", state["fitted"][k])
        self.replicates_ = uq.saved_replicates(state, arrays)
        prefix = "training_"
        self.training_ = {k[len(prefix) :]: v for k, v in arrays.items() if k.startswith(prefix)}
