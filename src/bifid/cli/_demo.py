"""``bifid demo flutter|forced --out DIR``: the main job on a built-in virtual experiment.

The work is in :mod:`bifid.demo`; this module parses options, applies the overwrite
policy (an earlier demo in DIR is reused with ``--resume`` or replaced with ``--force``),
prints the JSON summary of the contract and turns failures into one-line errors.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from bifid.cli._common import (
    ForceOpt,
    app,
    check_outputs,
    emit_json,
    option_value,
    user_errors,
)
from bifid.demo._cache import MANIFEST
from bifid.errors import BifidInputError
from bifid.io import atomic_write_text, jsonable, run_info


@app.command("demo")
def demo_cmd(
    which: Annotated[str, typer.Argument(help="flutter or forced")] = "flutter",
    out: Annotated[Path, typer.Option("--out", help="Output directory.")] = Path("out"),
    resume: Annotated[
        bool,
        typer.Option(
            "--resume",
            help="Reuse the stages of an earlier demo in --out whose settings did "
            "not change; recompute the others.",
        ),
    ] = False,
    force: ForceOpt = False,
    seed: Annotated[int, typer.Option("--seed", help="Seed of noise and training.")] = 0,
    noise: Annotated[
        float | None,
        typer.Option(
            "--noise",
            help="Measurement noise, fraction of each channel's amplitude "
            "(default: flutter 0.01, forced 0).",
        ),
    ] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", help="No progress display.")] = False,
) -> None:
    """Run a whole virtual experiment, identify a model, compare with the truth.

    Writes DIR/report.html, the figures, the dataset and the model. An existing non-empty
    DIR needs --resume (reuse the stages of the earlier demo there) or --force (recompute
    every stage and replace its files).
    """
    with user_errors():
        if which not in ("flutter", "forced"):
            raise BifidInputError(f"demo must be 'flutter' or 'forced', got {which!r}.")
        if resume and force:
            raise BifidInputError(
                "--resume and --force exclude each other: reuse the earlier "
                "demo's stages, or replace them."
            )
        option_value("--noise", noise, ge=0.0, lt=0.5)
        check_outputs(out=out, force=force, resume=resume, directory=True)
        if resume and out.is_dir() and any(out.iterdir()) and not (out / MANIFEST).is_file():
            raise BifidInputError(
                f"--resume: {out} holds no earlier demo (no {MANIFEST}); "
                "choose another --out, or --force to write into it."
            )
        out.mkdir(exist_ok=True)
        settings = run_info(
            "demo", which=which, out=str(out), seed=seed, noise=noise, resume=resume, force=force
        )
        if which == "flutter":
            from bifid.demo import FlutterDemoSettings, run_flutter_demo

            cfg = FlutterDemoSettings(
                seed=seed,
                noise_fraction=0.01 if noise is None else noise,
                model={"n_ensemble": 3, "seed": seed},
            )
            summary = run_flutter_demo(out, cfg, refresh=force, progress=not quiet)
        else:
            from bifid.demo import ForcedDemoSettings, run_forced_demo

            cfg = ForcedDemoSettings(
                seed=seed, noise_fraction=0.0 if noise is None else noise, model={"seed": seed}
            )
            summary = run_forced_demo(out, cfg, refresh=force, progress=not quiet)
        payload = {"summary": summary, "report": str(out / "report.html"), "settings": settings}
        atomic_write_text(out / "summary.json", json.dumps(jsonable(payload), indent=2))
        if json_out:
            emit_json(payload)
        else:
            checks = summary.get("checks", {})
            print(
                f"bifid demo {which}: report {out / 'report.html'} "
                f"({sum(c['passed'] for c in checks.values())}/{len(checks)} checks pass, "
                f"{summary.get('wall_time_s', 0):.0f} s)"
            )
