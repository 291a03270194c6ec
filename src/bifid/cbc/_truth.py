"""Ground truth for CBC campaigns: the model's curves by continuation, each measured point
compared with the uncontrolled system's orbit at exactly its own parameter.

CBC measures an orbit of the *uncontrolled* system when the control is non-invasive; the
check is Newton's method on the collocation equations of the uncontrolled system at the
measured parameter (:func:`bifid.continuation.truth.correct_orbit`), started from the
nearest orbit of the continued branch: the corrected orbit does not depend on the start,
so it is an independent reference (``bifid cbc --truth``, the benchmarks).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from bifid.cbc._derive import model_cycles
from bifid.continuation import frc, scurve
from bifid.continuation._diagram import diagram_of
from bifid.continuation.truth import centred_amplitudes, correct_orbit
from bifid.errors import BifidInputError, ConvergenceError
from bifid.systems import System

__all__ = ["forced_truth", "lco_truth"]


def lco_truth(
    system: System,
    p,
    param: str,
    lo: float,
    hi: float,
    points: list[dict],
    signals: Sequence[str],
    x1: str,
) -> dict | None:
    """The model's limit cycles over ``[lo, hi]`` by continuation
    (:func:`bifid.cbc._derive.model_cycles`, steps of at most 1/30 of the window), and
    each measured point compared with the orbit Newton-corrected at its own parameter from
    the nearest branch orbit (``truth_amplitude``, ``relative_error``, ``truth_stable``
    added to the point dicts). Returns the branch's ``param``, ``stable``, ``amplitude``
    per signal and its ``diagram``; None when continuation finds no cycles."""
    try:
        branches, _ = model_cycles(system, p, param, lo, hi, ds_max=1 / 30)
    except ConvergenceError:
        return None
    n = system.n_states
    orbits = []
    for br in branches:
        M = int(br.meta.get("n_mesh", 32))
        for i in range(len(br)):
            orbits.append(
                (
                    float(br.params[i]),
                    br.solutions[i, : M * n].reshape(M, n),
                    float(br.data["period"][i]),
                    bool(br.stable[i]),
                )
            )
    if not orbits:
        return None
    amps = np.array([centred_amplitudes(o[1]) for o in orbits])
    truth = {
        "param": np.array([o[0] for o in orbits]),
        "stable": np.array([o[3] for o in orbits]),
        "amplitude": {s: amps[:, system.state_index(s)] for s in signals},
        "diagram": diagram_of("bifurcation", branches, source="continuation"),
    }
    i1 = system.state_index(x1)
    for pt in points:
        a_meas = pt["amplitude"][x1]
        best = min(
            orbits,
            key=lambda o: (
                abs(o[0] - pt["param"]) / max(abs(pt["param"]), 1)
                + abs(float(np.ptp(o[1][:, i1])) / 2 - a_meas) / a_meas
            ),
        )
        try:
            V, _ = correct_orbit(system, param, pt["param"], best[1], best[2], p=p)
        except ConvergenceError:
            continue
        amp = centred_amplitudes(V)
        if amp[i1] < 0.01 * a_meas:
            # collapsed onto the equilibrium (next to a cycle fold the nearest orbit of
            # the branch can lie outside Newton's basin): no truth for this point
            continue
        pt["truth_amplitude"] = {s: float(amp[system.state_index(s)]) for s in pt["amplitude"]}
        pt["relative_error"] = {
            s: pt["amplitude"][s] / pt["truth_amplitude"][s] - 1.0 for s in pt["amplitude"]
        }
        pt["truth_stable"] = best[3]
    return truth


def forced_truth(
    system: System, p, protocol: str, fixed: float, lo: float, hi: float, signal: str
) -> tuple[dict, list[dict]] | None:
    """The model's S-curve (``protocol="scurve"``, ``Ω = fixed``) or FRC (``γ = fixed``)
    over the range by continuation (``curve``: forcing or frequency, amplitude, stable and
    its ``diagram``), and its folds; None when continuation fails."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            if protocol == "scurve":
                br = scurve(system, fixed, (0.5 * lo, 1.1 * hi), p=p, n_mesh=32, observed=signal)
            else:
                br = frc(system, fixed, (lo, hi), p=p, n_mesh=32, observed=signal)
        except (BifidInputError, ConvergenceError):
            return None
    key = "forcing" if protocol == "scurve" else "omega"
    curve = {
        key: np.asarray(br.data[key]),
        "amplitude": np.asarray(br.data["observed_amplitude"]),
        "stable": np.asarray(br.stable),
        "diagram": diagram_of(protocol, [br], source="continuation"),
    }
    folds = [{key: sp.param, "amplitude": sp.data.get("amplitude")} for sp in br.special("fold")]
    return curve, folds
