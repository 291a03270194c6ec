"""Leave-one-orbit-out validation of a fitted hybrid model."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from bifid.continuation._blas import one_blas_thread
from bifid.errors import BifidInputError, ConvergenceWarning
from bifid.identify._records import LCOData
from bifid.identify.hopf_hybrid._prepare import Preprocessing, measured_amplitude, prepare
from bifid.identify.hopf_hybrid._state import member

__all__ = ["leave_one_out", "refit"]


def _errors(folds: list[dict[str, Any]], names: tuple[str, ...]) -> dict[str, Any]:
    ok = [f for f in folds if "amplitude_error" in f]

    def over(agg: Any) -> dict[str, float | None]:
        return {k: float(agg([f["amplitude_error"][k] for f in ok])) if ok else None for k in names}

    return {
        "n_folds": len(folds),
        "n_missing": len(folds) - len(ok),
        "amplitude_error_mean": over(np.mean),
        "amplitude_error_max": over(np.max),
        "frequency_error_max": float(np.max([f["frequency_error"] for f in ok])) if ok else None,
    }


def refit(
    model: Any,
    data: LCOData,
    leave_out: int | None = None,
    warm: bool = False,
    pre: Preprocessing | None = None,
) -> Any:
    """A copy of ``model`` trained on ``data`` (without record ``leave_out`` if given): one
    ensemble member, the regularisation, stopping, criticality, quintic term, plane and
    number of polar harmonics selected by ``model`` fixed. A left-out record keeps its slot
    with weight 0 (the compiled training loops are reused; only the normalisation constants
    of the parameter and signals see it, so they are those of the full fit). ``pre``: the
    :class:`~._prepare.Preprocessing` of ``data`` when several refits share the records
    (computed otherwise).

    With ``warm``, the coordinate map starts from the full fit's reported (primary) member
    and trains for the same number of iterations: the refit stays in the full fit's basin
    of the training loss (the bootstrap of the intervals, :mod:`._uncertainty`). Without
    it, a cold start from the model's seed (the cross-validation of :func:`leave_one_out`).

    Raises
    ------
    ConvergenceError
        If the refit produces no finite parameters.
    """
    st = model.state_
    hyper = model.get_params()
    hyper.update(
        regularization=float(model.regularization_),
        stopping=int(model.n_iterations_),
        n_ensemble=1,
        omega_regularization=float(model.speed_regularization_),
        criticality=model.criticality_,
        quintic=bool(st.q5),
        plane=tuple(st.signal_names[k] for k in st.plane),
        n_harmonics=st.map_config.n_harmonics,
        n_points=st.map_config.n_points,
        progress=False,
    )
    fold_model = type(model)(**hyper)
    with one_blas_thread(), warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        init = member(st.map_params, st.primary) if warm else None
        active = np.ones(len(data), dtype=bool)
        if leave_out is not None:
            active[leave_out] = False
        fold_model._fit(data, active, init, pre)
    return fold_model


def leave_one_out(model: Any, data: LCOData) -> dict[str, Any]:
    """Retrain ``model`` without each record in turn and predict the held-out orbit.

    Each fold trains all stages with one ensemble member and the regularisation and
    stopping selected by ``model`` (so the errors are slightly optimistic); the left-out
    record keeps its slot with weight 0, so every fold reuses the compiled training loops
    (only the normalisation constants of the parameter and signals see it).

    Returns
    -------
    dict
        ``folds``: per record ``param``, ``stable``, measured and predicted ``amplitude``
        {signal}, relative ``amplitude_error`` {signal}, ``frequency`` and its error, the
        fold model's ``hopf`` and ``fold`` parameters (``error`` when the held-out cycle
        does not exist in the fold model); ``summary``: mean and largest errors.
    """
    st = model.state_
    prep_all = prepare(
        data,
        st.plane,
        st.map_config.n_harmonics,
        mu_c=st.mu_c,
        mu_s=st.mu_s,
        z_scale=st.z_scale,
        white=st.white,
    )
    folds = []
    pre = Preprocessing(data)  # the folds train on the same records
    for i in range(len(data)):
        fold_model = refit(model, data, leave_out=i, pre=pre)
        omega_i = float(prep_all.omega[i])
        meas = measured_amplitude(data.signals[i], omega_i, data.sample_rate[i])
        stable = bool(data.stable[i] != 0)
        fold = fold_model.cycle_fold()
        entry: dict[str, Any] = {
            "param": float(data.param[i]),
            "stable": stable,
            "measured_amplitude": dict(zip(data.signal_names, meas.tolist(), strict=True)),
            "measured_frequency": omega_i,
            "hopf": fold_model.hopf_point()["param"],
            "fold": fold["param"] if fold else None,
        }
        try:
            amp = fold_model.predict_amplitude([data.param[i]], stable=stable)[0]
            freq = float(fold_model.predict_frequency([data.param[i]], stable=stable)[0])
        except BifidInputError as exc:
            entry["error"] = str(exc)
        else:
            entry["amplitude"] = dict(zip(data.signal_names, amp.tolist(), strict=True))
            entry["amplitude_error"] = {
                k: float(abs(a - b) / b)
                for k, a, b in zip(data.signal_names, amp, meas, strict=True)
            }
            entry["frequency"] = freq
            entry["frequency_error"] = abs(freq - omega_i) / omega_i
        folds.append(entry)
    return {"folds": folds, "summary": _errors(folds, data.signal_names)}
