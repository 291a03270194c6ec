"""Ground truth of the demos: continuation of the true model the virtual rig simulates.

Saved as ``truth.json`` (special points, branch amplitudes) and ``truth.npz`` (orbits at
the test parameter values), so a second demo run does not recompute it.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bifid.io import atomic_path, atomic_write_text, jsonable

__all__ = ["flutter_truth", "forced_truth", "load_truth"]


def _save(directory: Path, stem: str, facts: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    with atomic_path(directory / f"{stem}.npz") as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **{k: np.asarray(v, dtype=float) for k, v in arrays.items()})
    atomic_write_text(directory / f"{stem}.json", json.dumps(jsonable(facts), indent=2))


def load_truth(directory: Path, stem: str = "truth") -> tuple[dict[str, Any], dict[str, Any]]:
    """The facts (JSON) and arrays (npz, no pickle) of a saved ground truth."""
    facts = json.loads((directory / f"{stem}.json").read_text())
    with np.load(directory / f"{stem}.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return facts, arrays


def flutter_truth(
    directory: Path,
    param_range: tuple[float, float],
    test_points: Sequence[tuple[float, bool]],
    n_mesh: int = 64,
    measured_speeds: Sequence[float] = (),
) -> dict[str, Any]:
    """Continuation of the flutter model: Hopf point, cycle fold, the orbit branch, and the
    exact orbits (Newton-corrected on the collocation mesh) at ``test_points`` =
    ``[(U, stable), ...]``; also the exact amplitudes of both LCOs at ``measured_speeds``
    (to judge the measurements themselves).
    """
    from bifid.continuation import continue_from_hopf
    from bifid.continuation.truth import correct_orbit
    from bifid.signal import max_abs
    from bifid.systems import get_system

    s = get_system("flutter")
    eq, branches = continue_from_hopf(s, "U", *param_range, n_mesh=n_mesh)
    (hopf,) = eq.special("hopf")
    (br,) = branches
    folds = br.special("cycle_fold")
    M, n = br.meta["n_mesh"], s.n_states
    orbits = br.solutions[:, : M * n].reshape(-1, M, n)
    periods = np.asarray(br.data["period"])
    test_orbits, test_periods = [], []
    extra = [
        (float(U), st)
        for U in measured_speeds
        for st in (True, False)
        if U > (folds[0].param if folds else -np.inf) and U < hopf.param
    ]
    for U, want_stable in [*test_points, *extra]:
        idx = np.flatnonzero(br.stable == want_stable)
        if idx.size == 0:
            raise RuntimeError(f"no {'stable' if want_stable else 'unstable'} orbit on the branch")
        k = idx[np.argmin(np.abs(br.params[idx] - U))]
        orb, T = correct_orbit(s, "U", float(U), orbits[k], float(periods[k]), n_mesh=n_mesh)
        test_orbits.append(orb)
        test_periods.append(T)
    # a rig measures signals with their static offsets removed (the LCOs of the flutter
    # model are not symmetric: k_a2 shifts their mean), so the truth is centred the same way
    all_orbits = np.asarray(test_orbits)
    all_orbits = all_orbits - all_orbits.mean(axis=1, keepdims=True)
    all_amps = np.array([max_abs(o) for o in all_orbits]) if len(all_orbits) else np.zeros((0, n))
    nt = len(test_points)
    test_orbits_arr, amps = all_orbits[:nt], all_amps[:nt]
    branch_amps = np.array([max_abs(o - o.mean(axis=0)) for o in orbits])
    ih, ia = s.state_index("h"), s.state_index("alpha")
    facts = {
        "system": "flutter",
        "hopf": {
            "U": hopf.param,
            "omega": hopf.data["omega"],
            "lyapunov": hopf.data["lyapunov"],
            "criticality": hopf.data["criticality"],
        },
        "fold": ({"U": folds[0].param} if folds else None),
        "amplitude": "max_t |x(t) - mean(x)| (centred, as measured)",
        "measured_speeds": [
            {"U": U, "stable": st, "h": float(a[ih]), "alpha": float(a[ia])}
            for (U, st), a in zip(extra, all_amps[nt:], strict=True)
        ],
        "test_points": [
            {
                "U": float(U),
                "stable": bool(st),
                "period": float(T),
                "omega": 2 * np.pi / T,
                "h": float(a[ih]),
                "alpha": float(a[ia]),
            }
            for (U, st), T, a in zip(test_points, test_periods[:nt], amps, strict=True)
        ],
    }
    arrays = {
        "U": br.params,
        "stable": br.stable.astype(float),
        "period": periods,
        "h": branch_amps[:, ih],
        "alpha": branch_amps[:, ia],
        "test_orbits": test_orbits_arr[:, :, [ih, ia]] if len(test_orbits) else np.zeros((0, M, 2)),
    }
    _save(directory, "truth", facts, arrays)
    return facts


def forced_truth(
    directory: Path,
    forcings: Sequence[float],
    omega_range: tuple[float, float],
    amplitude_range: tuple[float, float],
    omegas: Sequence[float] = (),
    forcing_range: tuple[float, float] = (0, 1),
) -> dict[str, Any]:
    """FRCs of ``shaw_pierre`` at ``forcings``, S-curves at ``omegas`` and the backbone."""
    from bifid.continuation import backbone, frc, scurve
    from bifid.systems import get_system

    s = get_system("shaw_pierre")
    facts: dict[str, Any] = {"system": "shaw_pierre", "frcs": []}
    arrays: dict[str, np.ndarray] = {}
    for i, F in enumerate(forcings):
        br = frc(s, float(F), omega_range)
        amp = np.asarray(br.data["observed_amplitude"])
        k = int(np.argmax(amp))
        facts["frcs"].append(
            {
                "forcing": float(F),
                "peak": {"omega": float(br.data["omega"][k]), "amplitude": float(amp[k])},
                "folds": [
                    {"omega": float(f.data["omega"]), "amplitude": float(f.data["amplitude"])}
                    for f in br.special("fold")
                ],
            }
        )
        arrays[f"frc{i}_omega"] = br.data["omega"]
        arrays[f"frc{i}_amplitude"] = amp
        arrays[f"frc{i}_stable"] = br.stable.astype(float)
    for i, om in enumerate(omegas):
        sc = scurve(s, float(om), forcing_range)
        arrays[f"sc{i}_forcing"] = sc.data["forcing"]
        arrays[f"sc{i}_amplitude"] = sc.data["observed_amplitude"]
        arrays[f"sc{i}_stable"] = sc.stable.astype(float)
    bb = backbone(s, amplitude_range)
    arrays["backbone_omega"] = bb.data["omega"]
    arrays["backbone_amplitude"] = bb.data["observed_amplitude"]
    _save(directory, "truth", facts, arrays)
    return facts
