"""What a fitted mechanistic model predicts: its continued diagram, orbits and amplitudes,
and how far its diagram is from the measured one."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.continuation import Diagram, continue_from_hopf
from bifid.errors import BifidInputError, ConvergenceError
from bifid.identify._records import LCOData
from bifid.identify.mechanistic._branch import (
    data_branch,
    data_range,
    model_branch,
    orbit_options,
)
from bifid.identify.mechanistic._orbits import OrbitSet
from bifid.signal import evaluate_fourier, fourier_coefficients
from bifid.systems import System

__all__ = ["diagram_error", "matched_orbits", "predicted_diagram"]


def predicted_diagram(
    system: System, p: np.ndarray, param: str, lo: float, hi: float, n_mesh: int, source: str
) -> Diagram:
    """Equilibria over ``[lo, hi]`` and the orbit branch of every Hopf point found
    (:func:`bifid.continuation.continue_from_hopf`), as a diagram."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        eq, branches = continue_from_hopf(
            system,
            param,
            lo,
            hi,
            p=jnp.asarray(p),
            n_mesh=n_mesh,
            orbit_options=orbit_options(lo, hi, 600),
        )
    return Diagram(
        kind="bifurcation",
        system=system.name,
        param=param,
        branches=[eq, *branches],
        source=source,
        units={param: system.parameters[system.index(param)].unit},
        warnings=[str(w.message) for w in caught],
    )


def matched_orbits(
    system: System,
    p: np.ndarray,
    param: str,
    values: Sequence[float],
    stable: bool,
    n_mesh: int,
    hopf_guess: float,
    trained: np.ndarray,
) -> OrbitSet:
    """The model's orbits at ``values`` on the stable or unstable side of its cycle fold
    (the branch is continued over the window of the values and the ``trained`` parameters,
    so that it reaches the fold).

    Raises
    ------
    BifidInputError
        Where the model has no orbit of that stability.
    """
    lam = np.atleast_1d(np.asarray(values, dtype=float))
    if lam.size == 0 or not np.all(np.isfinite(lam)):
        raise BifidInputError(f"values must be finite parameter values, got {values!r}.")
    probe = LCOData.from_amplitudes(
        lam,
        np.zeros((lam.size, 1)),
        [bool(stable)] * lam.size,
        (system.states[0],),
        param_name=param,
    )
    branch = model_branch(
        system,
        p,
        param,
        n_mesh=n_mesh,
        guess=hopf_guess,
        param_range=data_range(np.concatenate([lam, trained])),
    )
    orbits = OrbitSet(system, param, n_mesh, system.states)
    matched = orbits.match(branch, probe, p, skip_missing=True)
    if len(matched) < lam.size:
        missing = np.setdiff1d(np.arange(lam.size), matched)
        folds = ", ".join(f"{sp.param:.6g}" for sp in branch.special("cycle_fold")) or "none"
        raise BifidInputError(
            f"The model has no {'stable' if stable else 'unstable'} limit cycle at "
            f"{param} = {', '.join(f'{v:g}' for v in lam[missing])} (Hopf point "
            f"{branch.meta.get('start_param', float('nan')):.6g}, cycle folds at {folds})."
        )
    return orbits


def orbit_samples(orbits: OrbitSet, j: int, n_points: int) -> tuple[float, np.ndarray, np.ndarray]:
    """Period, times and states of orbit ``j`` on ``n_points`` points of one period."""
    M, n = orbits.n_mesh, orbits.system.n_states
    y = orbits.ys[j]
    V, T = y[: M * n].reshape(M, n), float(y[M * n])
    tau = 2.0 * np.pi * np.arange(n_points) / n_points
    return T, tau * T / (2.0 * np.pi), evaluate_fourier(*fourier_coefficients(V), tau)


def diagram_error(
    system: System,
    p: np.ndarray,
    param: str,
    data: LCOData,
    outputs: tuple[str, ...],
    n_mesh: int,
    hopf_guess: float,
) -> dict[str, Any]:
    """RMS amplitude error of the model's diagram at the measured LCOs (fixed parameters).

    LCOs the model has no orbit for (e.g. a stable LCO below the model's cycle fold) are
    listed in ``missing`` and left out of ``rms_all`` (``n_matched`` says how many entered).
    """
    br = data_branch(system, p, param, data.param, n_mesh=n_mesh, guess=hopf_guess)
    folds = [sp.param for sp in br.special("cycle_fold")]
    orbits = OrbitSet(system, param, n_mesh, outputs)
    try:
        matched = orbits.match(br, data, p, skip_missing=True)
    except ConvergenceError as exc:
        return {
            "rms_all": None,
            "n_matched": 0,
            "diagram_error": str(exc),
            "cycle_fold": folds[0] if folds else None,
        }
    amps = orbits.amplitudes()
    meas = np.column_stack([data.column(o) for o in outputs])[matched]
    pred = np.full(len(data), np.nan)
    pred[matched] = amps[:, 0]
    return {
        "rms_all": float(np.sqrt(np.mean((amps - meas) ** 2))),
        "n_matched": len(matched),
        "missing": [
            {"param": float(data.param[i]), "stable": int(data.stable[i])}
            for i in np.setdiff1d(np.arange(len(data)), matched)
        ],
        "predicted_amplitudes": [None if np.isnan(v) else float(v) for v in pred],
        "cycle_fold": folds[0] if folds else None,
    }
