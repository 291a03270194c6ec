"""Save continued branches as bifid datasets, sampled over one period, so that
``bifid fit`` can train on continuation output exactly as on a measurement."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bifid.continuation._branch import Branch
from bifid.signal import evaluate_fourier, fourier_coefficients
from bifid.systems import System


def sample_orbit(values: np.ndarray, n_samples: int) -> np.ndarray:
    """Trigonometric interpolant of periodic mesh values ``(M, n)`` at ``n_samples``
    equispaced times over one period (the first at the orbit's first mesh point)."""
    a0, a, b = fourier_coefficients(values)
    tau = 2.0 * np.pi * np.arange(n_samples) / n_samples
    return np.asarray(evaluate_fourier(a0, a, b, tau))


def branch_records(
    branch: Branch, system: System, samples_per_period: int = 256, curve: int = 0
) -> list[Any]:
    """Dataset records (one per branch point) with the orbit sampled over one period."""
    from bifid.data import ForcedRecord, LCORecord

    M = int(branch.meta["n_mesh"])
    n = system.n_states
    recs: list[Any] = []
    for i in range(len(branch)):
        V = branch.solutions[i, : M * n].reshape(M, n)
        sig = sample_orbit(V, samples_per_period)
        if branch.kind == "periodic":
            T = float(branch.data["period"][i])
            recs.append(
                LCORecord(
                    param=float(branch.params[i]),
                    signals=sig,
                    sample_rate=samples_per_period / T,
                    stable=bool(branch.stable[i]),
                    frequency=2 * np.pi / T,
                    extra={"floquet_max": float(branch.data["floquet_max"][i])},
                )
            )
        else:
            om = float(branch.data["omega"][i])
            F = float(branch.data["forcing"][i])
            T = 2 * np.pi / om
            t = np.arange(samples_per_period) * T / samples_per_period
            recs.append(
                ForcedRecord(
                    omega=om,
                    forcing=F,
                    signals=sig,
                    sample_rate=samples_per_period / T,
                    stable=bool(branch.stable[i]),
                    force=F * np.cos(om * t),
                    amplitude=float(branch.data["observed_amplitude"][i]),
                    phase=float(branch.data["phase"][i]),
                    curve=curve,
                )
            )
    return recs


def save_branch_dataset(
    branches: Sequence[Branch],
    system: System,
    path: str | os.PathLike,
    *,
    settings: Mapping[str, Any] | None = None,
    samples_per_period: int = 256,
) -> None:
    """Write the points of ``branches`` (all of one kind) as one dataset file."""
    from bifid.data import forced_dataset, lco_dataset, save_dataset

    recs: list[Any] = []
    for c, br in enumerate(branches):
        recs.extend(branch_records(br, system, samples_per_period, curve=c))
    source = f"bifid continuation of {system.name}"
    if branches[0].kind == "periodic":
        param = branches[0].param
        unit = next((p.unit for p in system.parameters if p.name == param), "")
        ds = lco_dataset(
            recs,
            list(system.states),
            param_name=param,
            param_units=unit,
            system=system.name,
            settings=dict(settings or {}),
            source=source,
        )
    else:
        ds = forced_dataset(
            recs,
            list(system.states),
            observed=branches[0].meta["observed"],
            system=system.name,
            settings=dict(settings or {}),
            source=source,
        )
    save_dataset(ds, path)
