"""The flutter demo's mechanistic stage: the physical model's k_a2, k_a3 from the campaign.

The linear parameters are taken as known (a free decay would give them, thesis §4.3.1);
the nonlinear stiffness coefficients start off by the factors given and are updated by
the whole-diagram stage (§4.3.3: collocation of every measured LCO, exact gradients by
implicit differentiation, Levenberg–Marquardt). Saved as ``mechanistic.json`` +
``mechanistic.npz`` (the fitted model's orbit branch, centred amplitudes).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from bifid.io import atomic_path, atomic_write_text, jsonable

__all__ = ["fit_mechanistic", "load_mechanistic", "write_mechanistic_failure"]


def write_mechanistic_failure(out: Path, reason: str) -> None:
    """Record a failed fit (an empty branch and the reason), so the report can show it."""
    with atomic_path(out / "mechanistic.npz") as tmp, open(tmp, "wb") as fh:
        np.savez(fh, U=np.zeros(0), h=np.zeros(0), alpha=np.zeros(0), stable=np.zeros(0))
    atomic_write_text(out / "mechanistic.json", json.dumps({"failed": reason}, indent=2))


def fit_mechanistic(out: Path, data, start: tuple[float, float]) -> dict[str, Any]:
    """Fit ``ka2, ka3`` of ``flutter`` to the LCO dataset; save the result and its branch."""
    from bifid.identify import LCOData
    from bifid.identify.mechanistic import model_branch, whole_diagram_update
    from bifid.systems import get_system

    s = get_system("flutter")
    true = s.param_dict(s.param_vector({}))
    p0 = s.param_vector({"ka2": start[0] * true["ka2"], "ka3": start[1] * true["ka3"]})
    lco = LCOData.from_dataset(data)
    res = whole_diagram_update(s, p0, ("ka2", "ka3"), lco, outputs=("h",))
    br = model_branch(s, res.p, "U", param_range=(14.0, 20.5))
    folds = br.special("cycle_fold")
    ih, ia = s.state_index("h"), s.state_index("alpha")
    facts = {
        "start": {"ka2": float(p0[s.index("ka2")]), "ka3": float(p0[s.index("ka3")])},
        "fitted": {k: float(v) for k, v in res.params.items()},
        "true": {"ka2": true["ka2"], "ka3": true["ka3"]},
        "rms_start_m": res.rms_start,
        "rms_m": res.rms,
        "converged": res.lm.converged,
        "iterations": res.lm.n_iter,
        "fit_seconds": res.time_s,
        "hopf_U": float(br.meta["start_param"]),
        "fold_U": float(folds[0].param) if folds else None,
    }
    amps = np.asarray(br.data["amplitude_centred"])
    with atomic_path(out / "mechanistic.npz") as tmp, open(tmp, "wb") as fh:
        np.savez(
            fh,
            U=np.asarray(br.params),
            h=amps[:, ih],
            alpha=amps[:, ia],
            stable=np.asarray(br.stable, dtype=float),
        )
    atomic_write_text(out / "mechanistic.json", json.dumps(jsonable(facts), indent=2))
    return facts


def load_mechanistic(out: Path, truth: dict[str, Any]) -> dict[str, Any]:
    """The saved fit, its branch, and its errors against the truth."""
    facts = json.loads((out / "mechanistic.json").read_text())
    if "failed" in facts:
        return {"summary": {"failed": facts["failed"]}, "branch": None}
    with np.load(out / "mechanistic.npz", allow_pickle=False) as z:
        branch = {k: z[k] for k in z.files}
    summary = {
        **facts,
        "param_rel_error": {
            k: abs(facts["fitted"][k] / facts["true"][k] - 1) for k in facts["fitted"]
        },
        "hopf_U_error": abs(facts["hopf_U"] - truth["hopf"]["U"]),
        "fold_U_error": (
            abs(facts["fold_U"] - truth["fold"]["U"])
            if facts["fold_U"] is not None and truth["fold"]
            else math.nan
        ),
    }
    return {"summary": summary, "branch": branch}
