"""``bifid predict MODEL …``: a fitted model answers what continuation answers.

Any model directory is loaded through the estimator contract (:func:`bifid.identify.load`,
the class chosen by the type in ``model.json``) and asked with the options of ``bifid
continue`` (``--param``, ``--range``), ``bifid frc`` (``--forcing``, ``--omega-range``),
``bifid scurve`` (``--omega``, ``--forcing-range``) or ``bifid backbone``
(``--amplitude-range``); it prints ``Diagram.to_json()`` — the same keys as the matching
continuation command — and exits 3 when the diagram is incomplete.
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path
from typing import Annotated, Any

import typer

from bifid.cli._common import (
    EXIT_NUMERICAL,
    ForceOpt,
    app,
    check_outputs,
    emit_json,
    finite_range,
    user_errors,
)
from bifid.errors import BifidInputError
from bifid.io import run_info

RangeOpt = tuple[float, float] | None


def _query(
    prange: RangeOpt,
    frc: bool,
    scurve: bool,
    backbone: bool,
    forcing: float | None,
    omega: float | None,
    omega_range: RangeOpt,
    forcing_range: RangeOpt,
    amplitude_range: RangeOpt,
) -> dict[str, Any]:
    """The ``predict_diagram`` question of the command line (one range at most)."""
    flags = [k for k, on in (("frc", frc), ("scurve", scurve), ("backbone", backbone)) if on]
    if len(flags) > 1:
        raise BifidInputError("give only one of --frc, --scurve, --backbone.")
    ranges = {
        name: r
        for name, r in (
            ("--range", prange),
            ("--omega-range", omega_range),
            ("--forcing-range", forcing_range),
            ("--amplitude-range", amplitude_range),
        )
        if r is not None
    }
    if len(ranges) > 1:
        raise BifidInputError(f"give one range, not {' and '.join(ranges)}.")
    for name, r in ranges.items():
        finite_range(name, *r, ge=0 if name != "--range" else None)
    kind = flags[0] if flags else None
    expected = {
        "frc": "--omega-range",
        "scurve": "--forcing-range",
        "backbone": "--amplitude-range",
    }
    for name in ranges:
        want = expected.get(
            kind or ("frc" if forcing is not None else "scurve" if omega is not None else ""),
            "--range",
        )
        if name not in (want, "--range"):
            raise BifidInputError(
                f"{name} does not apply here; the range of this prediction is {want}."
            )
    return {
        "kind": kind,
        "range": next(iter(ranges.values()), None),
        "forcing": forcing,
        "omega": omega,
    }


@app.command("predict")
def predict_cmd(
    model: Annotated[Path, typer.Argument(help="Model directory written by `bifid fit`.")],
    param: Annotated[str | None, typer.Option("--param", help="Continuation parameter.")] = None,
    prange: Annotated[RangeOpt, typer.Option("--range", help="Parameter range A B.")] = None,
    frc: Annotated[bool, typer.Option("--frc", help="Predict an FRC.")] = False,
    scurve: Annotated[bool, typer.Option("--scurve", help="Predict an S-curve.")] = False,
    backbone: Annotated[bool, typer.Option("--backbone", help="Predict the backbone.")] = False,
    forcing: Annotated[float | None, typer.Option("--forcing", help="Forcing of an FRC.")] = None,
    omega_range: Annotated[RangeOpt, typer.Option("--omega-range")] = None,
    omega: Annotated[float | None, typer.Option("--omega", help="Frequency of an S-curve.")] = None,
    forcing_range: Annotated[RangeOpt, typer.Option("--forcing-range")] = None,
    amplitude_range: Annotated[RangeOpt, typer.Option("--amplitude-range")] = None,
    level: Annotated[
        float | None,
        typer.Option(
            "--level", help="Confidence level of intervals (models with calibrated intervals)."
        ),
    ] = None,
    n_points: Annotated[int, typer.Option("--n-points", help="Points per curve.")] = 100,
    plot: Annotated[Path | None, typer.Option("--plot", help="Write a figure (PNG/SVG).")] = None,
    force: ForceOpt = False,
    json_out: Annotated[bool, typer.Option("--json", help="One JSON object on stdout.")] = False,
) -> None:
    """Predict a bifurcation diagram, FRC, S-curve or backbone from a fitted model."""
    with user_errors():
        from bifid.identify import load

        check_outputs(plot=plot, force=force)
        question = _query(
            prange,
            frc,
            scurve,
            backbone,
            forcing,
            omega,
            omega_range,
            forcing_range,
            amplitude_range,
        )
        estimator = load(model)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            diagram = estimator.predict_diagram(
                param=param, level=level, n_points=n_points, **question
            )
        diagram.warnings += [str(w.message) for w in caught]
        diagram.settings = run_info(
            "predict",
            model=str(model),
            type=estimator.model_type,
            level=level,
            n_points=n_points,
            **question,
        )
        if plot is not None:
            from bifid.report import plot_diagram, save_figure

            save_figure(plot_diagram(diagram, labels=[estimator.model_type]), plot)
        payload = diagram.to_json()
        if plot is not None:
            payload["plot"] = str(plot)
        if json_out:
            emit_json(payload)
        else:
            print(
                json.dumps({k: v for k, v in payload.items() if k != "settings"}, indent=1)[:4000]
            )
        if not diagram.complete:
            print(f"bifid: error: prediction incomplete: {diagram.message}", file=sys.stderr)
            raise typer.Exit(EXIT_NUMERICAL)
