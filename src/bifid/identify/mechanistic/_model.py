"""The mechanistic estimator (thesis ch. 4): a physical model's parameters in three stages.

:class:`MechanisticModel` is a thin shell over the stage functions: the linear stage on a
free decay (:mod:`._linear`), the normal-form fit near the Hopf point (:mod:`._near_hopf`)
and the whole-diagram update (:mod:`._whole_diagram`); predictions continue the fitted
system (:mod:`._predict`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.continuation import Diagram
from bifid.continuation._blas import one_blas_thread
from bifid.errors import BifidInputError, ConvergenceError
from bifid.identify._base import DiagramQuery, IdentifiedModel, Orbit
from bifid.identify._intervals import Covariance, warn_extrapolation
from bifid.identify._persistence import register_model_type
from bifid.identify._records import LCOData, as_lco_data
from bifid.identify.mechanistic._branch import hopf_summary
from bifid.identify.mechanistic._cubic import hopf_point_regression
from bifid.identify.mechanistic._linear import linear_stage
from bifid.identify.mechanistic._near_hopf import fit_near_hopf
from bifid.identify.mechanistic._normal_form import hopf_normal_form
from bifid.identify.mechanistic._predict import (
    diagram_error,
    matched_orbits,
    orbit_samples,
    predicted_diagram,
)
from bifid.identify.mechanistic._uncertainty import add_intervals, parameter_covariance
from bifid.identify.mechanistic._whole_diagram import whole_diagram_update
from bifid.systems import System, get_system

TWO_PI = 2.0 * math.pi
STAGES = ("linear", "normal_form", "whole_diagram")

__all__ = ["MechanisticModel"]


@register_model_type
class MechanisticModel(IdentifiedModel):
    """Identification of a physical model with a Hopf bifurcation in three stages (ch. 4).

    Parameters
    ----------
    system : str
        The physical model: a registered system or a system file.
    free : sequence of str
        Nonlinear parameters of the normal-form and whole-diagram stages.
    param : str, optional
        Bifurcation parameter (default: the data's, else the system's).
    params : mapping, optional
        Values of the other parameters, and starting values of the free ones.
    outputs : sequence of str, optional
        Measured signals whose amplitudes are fitted (states of the system; default: the
        data's first signal, as eq. 4.15 uses heave).
    stages : "auto" or sequence of {"linear", "normal_form", "whole_diagram"}
        Stages to run, in this order; "auto": the linear stage when :meth:`fit` is given a
        free decay, then the other two.
    linear_free : sequence of str
        Parameters of the linear stage.
    linear_outputs : sequence of str, optional
        States measured in the free decay, in its column order (default: ``outputs``).
    linear_ratios : mapping, optional
        Tied parameters of the linear stage, e.g. ``{"ka": "Ia"}`` (a measured natural
        frequency kept fixed).
    linear_options : mapping, optional
        Extra keyword arguments of :class:`~bifid.identify.LinearPEM`.
    linear_param_value : float
        The bifurcation parameter during the free decay.
    param_ref : {"model", "data"} or float
        Reference of ``mu`` in the normal-form stage (see :func:`fit_near_hopf`).
    near_hopf : float, optional
        Use only unstable LCOs within this distance of the Hopf point in the normal-form
        stage (default: all unstable LCOs below it).
    n_mesh : int
        Collocation points per orbit (whole-diagram stage and predictions).
    gradient : {"implicit", "fd"}
        Jacobian of the whole-diagram stage.
    max_iter : int
        Iterations of the normal-form and whole-diagram stages.
    hopf_guess : float, optional
        Where to start looking for the Hopf point (default: the largest measured parameter).
    decay_start : "release" or float
        Start of the free decay: "release" (the latest of the outputs' largest excursions)
        or a time [s].
    decay_stop : float, optional
        End of the free decay used [s] (default: the end of the record).
    """

    model_type = "mechanistic"
    kinds = ("bifurcation",)
    uncertainty_note = (
        "Gauss-Newton covariance of the free parameters, propagated to Hopf points, cycle "
        "folds and orbit amplitudes by the delta method"
    )
    calibrated = True
    _fitted_attribute = "p_"

    def __init__(
        self,
        system: str,
        free: Sequence[str],
        *,
        param: str | None = None,
        params: Mapping[str, float] | None = None,
        outputs: Sequence[str] | None = None,
        stages: str | Sequence[str] = "auto",
        linear_free: Sequence[str] = (),
        linear_outputs: Sequence[str] | None = None,
        linear_ratios: Mapping[str, str] | None = None,
        linear_options: Mapping[str, Any] | None = None,
        linear_param_value: float = 0.0,
        param_ref: str | float = "model",
        near_hopf: float | None = None,
        n_mesh: int = 32,
        gradient: str = "implicit",
        max_iter: int = 40,
        hopf_guess: float | None = None,
        decay_start: str | float = "release",
        decay_stop: float | None = None,
    ) -> None:
        self.system = system
        self.free = free
        self.param = param
        self.params = params
        self.outputs = outputs
        self.stages = stages
        self.linear_free = linear_free
        self.linear_outputs = linear_outputs
        self.linear_ratios = linear_ratios
        self.linear_options = linear_options
        self.linear_param_value = linear_param_value
        self.param_ref = param_ref
        self.near_hopf = near_hopf
        self.n_mesh = n_mesh
        self.gradient = gradient
        self.max_iter = max_iter
        self.hopf_guess = hopf_guess
        self.decay_start = decay_start
        self.decay_stop = decay_stop

    # ----------------------------------------------------------------------- validation
    def _system(self) -> System:
        return get_system(self.system)

    def _validate(self, system: System, data: LCOData, free_decay: Any) -> tuple[str, ...]:
        for nm in (*self.free, *dict(self.params or {}), *self.linear_free):
            system.index(nm)
        if not self.free:
            raise BifidInputError("free must name at least one parameter of the system.")
        for o in self._outputs(data):
            system.state_index(o)
            data.index(o)
        stages = (
            (("linear",) if free_decay is not None else ()) + STAGES[1:]
            if self.stages == "auto"
            else tuple(self.stages)
        )
        unknown = set(stages) - set(STAGES)
        if unknown or not stages:
            raise BifidInputError(
                f"stages must be 'auto' or a non-empty subset of {', '.join(STAGES)}; got "
                f"{self.stages!r}."
            )
        if "linear" in stages and free_decay is None:
            raise BifidInputError("the linear stage needs a free decay: fit(data, free_decay=...).")
        if self.gradient not in ("implicit", "fd"):
            raise BifidInputError(f"gradient must be 'implicit' or 'fd', got {self.gradient!r}.")
        if not (isinstance(self.n_mesh, int) and self.n_mesh >= 8 and self.n_mesh % 2 == 0):
            raise BifidInputError(f"n_mesh must be an even integer >= 8, got {self.n_mesh!r}.")
        return stages

    def _outputs(self, data: LCOData) -> tuple[str, ...]:
        return tuple(self.outputs) if self.outputs else (data.signal_names[0],)

    # ------------------------------------------------------------------------------ fit
    @one_blas_thread
    def fit(self, dataset: Any, *, free_decay: Any = None) -> MechanisticModel:
        """Run the stages on measured limit cycles.

        Parameters
        ----------
        dataset : path, xarray.Dataset, list of them, or LCOData
            Measured LCOs with stability labels (:func:`bifid.identify.as_lco_data`).
        free_decay : (y, sample_rate) or bifid.data.FreeDecay, optional
            Free-decay record of the linear stage: ``y`` of shape (n, n_outputs) with the
            columns of ``linear_outputs``.

        Returns
        -------
        self
            ``p_`` (full parameter vector), ``params_`` (identified values by name),
            ``standard_errors_``, ``stages_`` (per-stage summaries with the RMS amplitude
            error over all LCOs), ``hopf_`` (Hopf point of the final model), ``data_hopf_``
            (squared-amplitude regression of the measured unstable LCOs),
            ``identifiability_``, ``cycle_fold_``.

        Raises
        ------
        BifidInputError
            Bad names, options or data.
        ConvergenceError
            A stage failed numerically.
        """
        system = self._system()
        data = as_lco_data(dataset)
        stages = self._validate(system, data, free_decay)
        outputs = self._outputs(data)
        param = self.param or (
            data.param_name if data.param_name in system.parameter_names else system.default_param
        )
        system.index(param)
        p = np.array(system.param_vector(dict(self.params or {})), dtype=float)
        hopf_guess = self.hopf_guess if self.hopf_guess is not None else float(np.max(data.param))
        self.stages_: dict[str, Any] = {}
        self.stage_p_: dict[str, np.ndarray] = {}
        self.params_: dict[str, float] = {}
        self.standard_errors_: dict[str, float] = {}
        self.identifiability_: dict[str, Any] | None = None
        errors: dict[bytes, dict[str, Any]] = {}  # one branch per parameter vector

        def error(q: np.ndarray, guess: float) -> dict[str, Any]:
            key = q.tobytes()
            if key not in errors:
                errors[key] = diagram_error(system, q, param, data, outputs, self.n_mesh, guess)
            return dict(errors[key])

        self.data_hopf_ = self._data_hopf(data, outputs[0])
        if "linear" in stages:
            p, _, summary = linear_stage(
                system,
                p,
                param,
                free_decay,
                free=tuple(self.linear_free),
                outputs=tuple(self.linear_outputs or self._outputs(data)),
                ratios=dict(self.linear_ratios or {}),
                options=dict(self.linear_options or {}),
                param_value=self.linear_param_value,
                start=self.decay_start,
                stop=self.decay_stop,
            )
            self.params_.update({nm: float(p[system.index(nm)]) for nm in self.linear_free})
            self.standard_errors_.update(summary["stderr"])
            self.stages_["linear"] = summary
            self.stage_p_["linear"] = p.copy()
        nf = hopf_normal_form(system, param, p=jnp.asarray(p), guess=hopf_guess)
        hopf_guess = nf.param_value
        if "linear" in stages:
            self.stages_["linear"].update(error(p, hopf_guess), hopf=hopf_summary(nf))
        if "normal_form" in stages:
            p = self._normal_form_stage(system, p, data, outputs[0], param, nf)
            self.stages_["normal_form"].update(error(p, hopf_guess))
        if "whole_diagram" in stages:
            res3 = whole_diagram_update(
                system,
                p,
                tuple(self.free),
                data,
                param=param,
                outputs=outputs,
                n_mesh=self.n_mesh,
                gradient=self.gradient,
                max_iter=self.max_iter,
                hopf_guess=hopf_guess,
            )
            p = res3.p.copy()
            self.stage_p_["whole_diagram"] = p.copy()
            self.stages_["whole_diagram"] = {
                **res3.to_dict(),
                "rms_all": res3.rms,
                "n_matched": len(data),
                "n_lcos": len(data),
                "predicted_amplitudes": res3.amplitudes[:, 0].tolist(),
            }
        self.params_.update({nm: float(p[system.index(nm)]) for nm in self.free})
        self.p_ = p
        nf = hopf_normal_form(system, param, p=jnp.asarray(p), guess=hopf_guess)
        self.hopf_ = hopf_summary(nf)
        last = stages[-1]
        final = error(p, nf.param_value)
        self.cycle_fold_ = final.get("cycle_fold")
        if last != "whole_diagram":
            self.stages_[last].update(
                {k: v for k, v in final.items() if k not in self.stages_[last]}
            )
        self.stages_[last]["cycle_fold"] = self.cycle_fold_
        self.param_ = param
        self.outputs_ = outputs
        self.data_ = data
        return self

    def _normal_form_stage(
        self,
        system: System,
        p: np.ndarray,
        data: LCOData,
        output: str,
        param: str,
        nf: Any,
    ) -> np.ndarray:
        """Stage 2 (eq. 4.10): fit the free parameters to the unstable LCOs below the Hopf
        point of ``nf``; records the stage summary and identifiability, returns the new ``p``."""
        sel = (data.stable == 0) & (data.param < nf.param_value)
        if self.near_hopf is not None:
            sel &= np.abs(data.param - nf.param_value) <= self.near_hopf
        if not np.any(sel):
            raise BifidInputError(
                "the normal-form stage needs unstable LCOs (stable = 0) below the Hopf "
                f"point {param}={nf.param_value:.6g}."
            )
        res = fit_near_hopf(
            system,
            p,
            tuple(self.free),
            data.select(sel),
            output=output,
            param=param,
            nf=nf,
            param_ref=self.param_ref,
            max_iter=self.max_iter,
        )
        p = res.p.copy()
        self.stage_p_["normal_form"] = p.copy()
        self.identifiability_ = {
            "statement": res.statement,
            "identifiable_direction": res.identifiable,
            "unidentifiable_direction": res.unidentifiable,
            "singular_values": res.singular_values.tolist(),
        }
        self.stages_["normal_form"] = {
            **res.to_dict(),
            "n_lcos": int(np.sum(sel)),
        }
        return p

    @staticmethod
    def _data_hopf(data: LCOData, output: str) -> dict[str, Any]:
        """Hopf point from the measured unstable LCOs (squared-amplitude regression)."""
        unstable = data.stable == 0
        if np.sum(unstable) < 2:
            return {}
        reg = hopf_point_regression(
            data.param[unstable], data.column(output)[unstable], data.frequency[unstable]
        )
        return {
            **reg,
            "output": output,
            "frequency_hz": reg.get("frequency", float("nan")) / TWO_PI,
        }

    # -------------------------------------------------------------------------- predict
    @one_blas_thread
    def _predict_diagram(self, query: DiagramQuery) -> Diagram:
        system = self._system()
        if query.param not in (None, self.param_):
            raise BifidInputError(
                f"this model's bifurcation parameter is {self.param_!r}, not {query.param!r}."
            )
        if query.range is None:
            lo, hi = float(np.min(self.data_.param)), float(np.max(self.data_.param))
            hi = max(hi, float(self.hopf_["param"]))
            span = max(hi - lo, 1.0)
            lo, hi = lo - 0.5 * span, hi + 0.5 * span
        else:
            lo, hi = query.range
        return predicted_diagram(
            system, self.p_, self.param_, lo, hi, max(self.n_mesh, 32), self.model_type
        )

    def _matched(self, values: np.ndarray, stable: bool) -> Any:
        return matched_orbits(
            self._system(),
            self.p_,
            self.param_,
            values,
            stable,
            self.n_mesh,
            self.hopf_["param"],
            self.data_.param,
        )

    @one_blas_thread
    def _predict_orbit(
        self, value: float, stable: bool, forcing: float | None, omega: float | None, n: int
    ) -> Orbit:
        """One period of every state on the limit cycle at ``param = value``."""
        T, t, x = orbit_samples(self._matched(np.array([value]), stable), 0, n)
        return Orbit(
            param=self.param_,
            value=value,
            stable=stable,
            period=T,
            t=t,
            signals=x,
            signal_names=tuple(self._system().states),
        )

    @one_blas_thread
    def _predict_amplitude(
        self, values: np.ndarray, stable: bool, forcing: float | None, omega: float | None
    ) -> np.ndarray:
        """``max_t |x_s − x̄_s|`` of every state on the cycles at ``values`` (about the
        orbit's mean, the convention of the measured data the model was fitted to)."""
        return self._matched(values, stable).amplitudes()

    def covariance(self) -> Covariance:
        """Covariance of the fitted parameters: Gauss–Newton at the fit for the free ones, the
        noise variance estimated from the amplitude residuals, with the linear stage's
        uncertainty carried through (:func:`._uncertainty.parameter_covariance`); computed
        once.

        Raises
        ------
        BifidInputError
            With no more measured amplitudes than free parameters.
        """
        self._check_fitted()
        if getattr(self, "_covariance", None) is None:
            self._covariance = parameter_covariance(
                self._system(),
                self.p_,
                self.param_,
                self.data_,
                tuple(self.outputs_),
                tuple(self.free),
                self.n_mesh,
                float(self.hopf_["param"]),
                linear_errors=(self.stages_.get("linear") or {}).get("stderr"),
                ties=dict(self.linear_ratios or {}),
            )
        return self._covariance

    @one_blas_thread
    def _add_intervals(self, diagram: Diagram, query: DiagramQuery, level: float) -> None:
        """Delta-method intervals on the predicted diagram (:func:`._uncertainty.add_intervals`),
        with a warning where the prediction leaves the trained parameter range."""
        lo, hi = float(np.min(self.data_.param)), float(np.max(self.data_.param))
        if query.range is not None:
            warn_extrapolation(self.param_, query.range, (lo, hi), stacklevel=4)
        add_intervals(diagram, self._system(), self.p_, self.param_, self.covariance(), level)

    # -------------------------------------------------------------------------- summary
    def summary(self) -> dict[str, Any]:
        """Fitted parameters (``parameters``), their ``standard_errors`` (linear stage:
        prediction-error covariance; free parameters: Gauss–Newton covariance at the fit,
        :meth:`covariance`), the Hopf point, per-stage summaries, identifiability and
        ``losses`` (RMS amplitude error of each stage's model over the measured LCOs)."""
        self._check_fitted()
        try:
            cov = self.covariance()
            errors = {**self.standard_errors_, **cov.standard_errors()}
            noise = {"residual_std": cov.sigma, "dof": cov.dof}
        except (BifidInputError, ConvergenceError) as exc:
            errors, noise = dict(self.standard_errors_), {"error": str(exc)}
        return {
            "parameters": dict(self.params_),
            "standard_errors": errors,
            "noise": noise,
            "hopf": self.hopf_,
            "cycle_fold": self.cycle_fold_,
            "data_hopf": self.data_hopf_,
            "identifiability": self.identifiability_,
            "stages": self.stages_,
            "losses": {k: v.get("rms_all") for k, v in self.stages_.items()},
        }

    def _state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        d = self.data_
        state = {
            "params": self.params_,
            "standard_errors": self.standard_errors_,
            "hopf": self.hopf_,
            "cycle_fold": self.cycle_fold_,
            "data_hopf": self.data_hopf_,
            "identifiability": self.identifiability_,
            "stages": self.stages_,
            "param": self.param_,
            "outputs": list(self.outputs_),
            "data": {"signal_names": list(d.signal_names), "param_name": d.param_name},
            "all_parameters": self._system().param_dict(self.p_),
        }
        arrays = {
            "p": self.p_,
            "data_param": d.param,
            "data_amplitude": d.amplitude,
            "data_stable": d.stable,
            "data_frequency": d.frequency,
            **{f"p_stage_{k}": v for k, v in self.stage_p_.items()},
        }
        return state, arrays

    def _restore(self, state: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        self.p_ = np.asarray(arrays["p"], dtype=float)
        self.params_ = dict(state["params"])
        self.standard_errors_ = dict(state["standard_errors"])
        self.hopf_ = state["hopf"]
        self.cycle_fold_ = state["cycle_fold"]
        self.data_hopf_ = state["data_hopf"]
        self.identifiability_ = state["identifiability"]
        self.stages_ = state["stages"]
        self.param_ = state["param"]
        self.outputs_ = tuple(state["outputs"])
        self.data_ = LCOData.from_amplitudes(
            arrays["data_param"],
            arrays["data_amplitude"],
            arrays["data_stable"],
            state["data"]["signal_names"],
            frequency=arrays["data_frequency"],
            param_name=state["data"]["param_name"],
        )
        self.stage_p_ = {
            k[len("p_stage_") :]: np.asarray(v, dtype=float)
            for k, v in arrays.items()
            if k.startswith("p_stage_")
        }
