"""``bifid demo flutter|forced --out DIR``: the main job on a built-in virtual experiment.

Until the end-to-end pipeline lands (CBC → identification → prediction, issue 7) the
flutter demo computes the continuation ground truth of the flutter model: equilibria,
the subcritical Hopf point, the periodic-orbit branch with its fold, stability, and a
bifurcation diagram, written to ``DIR``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from bifid.cli._common import app, emit_json, run_info, user_errors
from bifid.errors import BifidInputError


@app.command("demo")
def demo_cmd(
    which: Annotated[str, typer.Argument(help="flutter or forced")] = "flutter",
    out: Annotated[Path, typer.Option("--out", help="Output directory.")] = Path("out"),
    json_out: Annotated[bool, typer.Option("--json")] = False,
) -> None:
    """Run the demonstration and write its figures and summary into DIR."""
    with user_errors():
        if which not in ("flutter", "forced"):
            raise BifidInputError(f"demo must be 'flutter' or 'forced', got {which!r}.")
        out.mkdir(parents=True, exist_ok=True)
        t0 = time.time()
        summary = _flutter(out) if which == "flutter" else _forced(out)
        summary["wall_time_s"] = time.time() - t0
        payload = {"summary": summary, "settings": run_info("demo", which=which, out=str(out))}
        from bifid.io import atomic_write_text

        atomic_write_text(out / "summary.json", json.dumps(payload, indent=2, default=float))
        if json_out:
            emit_json(payload)
        else:
            print(json.dumps(summary, indent=2, default=float))


def _flutter(out: Path) -> dict:
    from bifid.continuation import continue_from_hopf
    from bifid.report.plots import bifurcation_diagram, save_figure
    from bifid.systems import get_system

    s = get_system("flutter")
    eq, branches = continue_from_hopf(s, "U", 14.0, 20.0, n_mesh=64)
    (h,) = eq.special("hopf")
    (br,) = branches
    folds = br.special("cycle_fold")
    fig = bifurcation_diagram(eq, branches, ["h", "alpha"], title="flutter model (App. A)",
                              units={"h": "m", "alpha": "rad"}, param_unit="m/s")
    save_figure(fig, out / "flutter_bifurcation.png")
    return {
        "system": "flutter",
        "hopf": {"U": h.param, "omega": h.data["omega"],
                 "frequency_hz": h.data["omega"] / 2 / np.pi,
                 "lyapunov": h.data["lyapunov"], "criticality": h.data["criticality"]},
        "cycle_folds": [{"U": f.param, "amplitude_h": f.data["amplitude"][0],
                         "amplitude_alpha": f.data["amplitude"][2]} for f in folds],
        "n_orbits": len(br),
        "figures": ["flutter_bifurcation.png"],
    }


def _forced(out: Path) -> dict:
    from bifid.continuation import backbone, frc
    from bifid.report.plots import forced_diagram, save_figure
    from bifid.systems import get_system

    s = get_system("shaw_pierre")
    branches = [frc(s, F, (0.95, 1.06)) for F in (0.003, 0.006, 0.009)]
    bb = backbone(s, (0.05, max(b.data["observed_amplitude"].max() for b in branches)))
    save_figure(forced_diagram(branches, xkey="omega", title="shaw_pierre FRCs", backbone=bb),
                out / "shaw_pierre_frc.png")
    return {
        "system": "shaw_pierre",
        "frcs": [{"F": float(b.data["forcing"][0]),
                  "peak_amplitude": float(b.data["observed_amplitude"].max()),
                  "folds": [f.param for f in b.special("fold")]} for b in branches],
        "figures": ["shaw_pierre_frc.png"],
    }
