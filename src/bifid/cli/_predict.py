"""``bifid predict MODEL ...``: a fitted model answers what continuation answers.

The model directory's ``model.json`` names its type; the handler registered for that type
(``bifid.cli._common.register_predictor``) receives the options below and returns the same
JSON keys as the matching continuation command (``continue``, ``frc``, ``scurve``,
``backbone``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer

from bifid.cli._common import (
    PREDICTORS,
    app,
    emit_json,
    finite_range,
    parse_sets,
    user_errors,
)
from bifid.errors import BifidInputError
from bifid.io import run_info


def _model_type(model: Path) -> str:
    meta_path = model / "model.json"
    if not model.is_dir() or not meta_path.is_file():
        raise BifidInputError(f"{model} is not a bifid model directory (no model.json).")
    try:
        meta = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise BifidInputError(f"{meta_path} is not valid JSON: {exc}") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("type"), str):
        raise BifidInputError(f"{meta_path} has no model 'type'.")
    return meta["type"]


@app.command("predict")
def predict_cmd(
    model: Annotated[Path, typer.Argument(help="Model directory written by `bifid fit`.")],
    param: Annotated[str | None, typer.Option("--param")] = None,
    prange: Annotated[tuple[float, float] | None, typer.Option("--range")] = None,
    frc: Annotated[bool, typer.Option("--frc", help="Predict an FRC.")] = False,
    scurve: Annotated[bool, typer.Option("--scurve", help="Predict an S-curve.")] = False,
    backbone: Annotated[bool, typer.Option("--backbone", help="Predict the backbone.")] = False,
    forcing: Annotated[float | None, typer.Option("--forcing")] = None,
    omega_range: Annotated[tuple[float, float] | None, typer.Option("--omega-range")] = None,
    omega: Annotated[float | None, typer.Option("--omega")] = None,
    forcing_range: Annotated[tuple[float, float] | None,
                             typer.Option("--forcing-range")] = None,
    amplitude_range: Annotated[tuple[float, float] | None,
                               typer.Option("--amplitude-range")] = None,
    n_points: Annotated[int, typer.Option("--n-points", help="Points per curve.")] = 100,
    sets: Annotated[list[str] | None, typer.Option("--set")] = None,
    plot: Annotated[Path | None, typer.Option("--plot")] = None,
    json_out: Annotated[bool, typer.Option("--json")] = False,
) -> None:
    """Predict a bifurcation diagram, FRC, S-curve or backbone from a fitted model."""
    with user_errors():
        kind = _model_type(model)
        handler = PREDICTORS.get(kind)
        if handler is None:
            raise BifidInputError(
                f"No predictor for model type {kind!r}; known: {', '.join(sorted(PREDICTORS))}."
            )
        for name, rng in (("--range", prange), ("--omega-range", omega_range),
                          ("--forcing-range", forcing_range),
                          ("--amplitude-range", amplitude_range)):
            if rng is not None:
                finite_range(name, *rng)
        if n_points < 2:
            raise BifidInputError(f"--n-points must be at least 2, got {n_points}.")
        options: dict[str, Any] = {
            "param": param, "range": prange, "frc": frc, "scurve": scurve,
            "backbone": backbone, "forcing": forcing, "omega_range": omega_range,
            "omega": omega, "forcing_range": forcing_range,
            "amplitude_range": amplitude_range, "n_points": n_points,
            "sets": parse_sets(sets), "plot": plot,
        }
        payload = handler(model, options)
        payload.setdefault("settings", run_info("predict", model=str(model), type=kind,
                                                **{k: v for k, v in options.items()
                                                   if k != "plot"}))
        if json_out:
            emit_json(payload)
        else:
            print(json.dumps({k: v for k, v in payload.items() if k != "settings"},
                             indent=1, default=float)[:4000])
