"""``bifid systems | continue | frc | scurve | backbone``: continuation of reference systems."""

from __future__ import annotations

import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from bifid.cli._common import (
    EXIT_NUMERICAL,
    app,
    emit_json,
    finite_range,
    parse_sets,
    user_errors,
)
from bifid.errors import BifidInputError
from bifid.io import run_info

JsonOpt = Annotated[bool, typer.Option("--json", help="Print one JSON object on stdout.")]
SetOpt = Annotated[
    list[str] | None,
    typer.Option("--set", help="Override a system parameter, NAME=VALUE (repeatable)."),
]
PlotOpt = Annotated[Path | None, typer.Option("--plot", help="Write a figure (PNG/SVG).")]
OutOpt = Annotated[
    Path | None, typer.Option("--out", help="Save the branch as a netCDF dataset.")
]
MeshOpt = Annotated[int, typer.Option("--mesh", help="Fourier collocation points (even).")]


class _Progress:
    """A rich progress line on stderr: points computed and the current parameter."""

    def __init__(self, description: str, quiet: bool = False) -> None:
        from rich.console import Console
        from rich.progress import Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

        self._progress = Progress(
            SpinnerColumn(),
            TextColumn("[bold]{task.description}"),
            TextColumn("{task.completed} points"),
            TextColumn("{task.fields[param]}"),
            TimeElapsedColumn(),
            console=Console(stderr=True),
            transient=True,
            disable=quiet,
        )
        self._description = description
        self._task: Any = None

    def __enter__(self) -> Callable[[int, float], None]:
        self._progress.__enter__()
        self._task = self._progress.add_task(self._description, total=None, param="")

        def update(n: int, value: float) -> None:
            self._progress.update(self._task, completed=n, param=f"at {value:.6g}")

        return update

    def __exit__(self, *exc: object) -> None:
        self._progress.__exit__(*exc)


def _system_and_params(name: str, sets: list[str] | None):
    from bifid.systems import get_system

    system = get_system(name)
    p = system.param_vector(parse_sets(sets))
    return system, p


def _finish(payload: dict[str, Any], branches: list, json_out: bool, summary: str) -> None:
    failed = [b for b in branches if not b.complete]
    payload["complete"] = not failed
    payload["status"] = "failed" if failed else "ok"
    if failed:
        payload["message"] = failed[0].message
    if json_out:
        emit_json(payload)
    else:
        print(summary)
    if failed:
        print(f"bifid: error: continuation incomplete: {failed[0].message}", file=sys.stderr)
        raise typer.Exit(EXIT_NUMERICAL)


@app.command("systems")
def systems_cmd(json_out: JsonOpt = False) -> None:
    """List the registered systems with their states and parameters."""
    with user_errors():
        from bifid.systems import get_system, list_systems

        entries = [get_system(n).to_json() for n in list_systems()]
        if json_out:
            emit_json({"systems": entries})
            return
        for e in entries:
            params = ", ".join(f"{p['name']}={p['default']:g}" for p in e["parameters"])
            print(f"{e['name']:12s} {e['kind']:10s} states: {', '.join(e['states'])}")
            print(f"{'':12s} parameters: {params}")


def _orbit_json(system, br) -> list[dict[str, Any]]:
    out = []
    for i in range(len(br)):
        out.append(
            {
                "param": br.params[i],
                "period": br.data["period"][i],
                "stable": bool(br.stable[i]),
                "floquet_max": br.data["floquet_max"][i],
                "amplitude": dict(zip(system.states, br.data["amplitude"][i], strict=True)),
                # about the orbit's mean (what a rig with offsets removed measures)
                "amplitude_centred": dict(zip(system.states, br.data["amplitude_centred"][i],
                                              strict=True)),
            }
        )
    return out


@app.command("continue")
def continue_cmd(
    system_name: Annotated[str, typer.Argument(metavar="SYSTEM", help="Registered system.")],
    param: Annotated[str | None, typer.Option("--param", help="Continuation parameter.")] = None,
    prange: Annotated[
        tuple[float, float] | None, typer.Option("--range", help="Parameter range A B.")
    ] = None,
    mesh: MeshOpt = 64,
    sets: SetOpt = None,
    plot: PlotOpt = None,
    out: OutOpt = None,
    max_steps: Annotated[int, typer.Option("--max-steps", help="Points per branch.")] = 600,
    json_out: JsonOpt = False,
    quiet: Annotated[bool, typer.Option("--quiet", help="No progress display.")] = False,
) -> None:
    """Equilibria over a range, their Hopf points, and the periodic orbits born there."""
    with user_errors():
        from bifid.continuation import ContinuationOptions, continue_from_hopf

        system, p = _system_and_params(system_name, sets)
        if system.kind != "autonomous":
            raise BifidInputError(
                f"{system_name!r} is forced: use 'bifid frc' or 'bifid scurve'."
            )
        param = param or system.default_param
        system.index(param)
        if prange is None:
            raise BifidInputError("--range A B is required.")
        lo, hi = sorted(finite_range("--range", *prange))
        orbit_opts = ContinuationOptions(
            ds=1e-3, ds_max=0.25, ds_min=1e-9, p_min=lo, p_max=hi, max_steps=max_steps
        )
        with _Progress(f"{system_name}: orbits in {param}", quiet) as progress, \
                warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            eq, branches = continue_from_hopf(
                system, param, lo, hi, p=p, n_mesh=mesh, orbit_options=orbit_opts,
                progress=progress,
            )
        for w in caught:
            print(f"bifid: warning: {w.message}", file=sys.stderr)
        hopfs = eq.special("hopf")
        payload: dict[str, Any] = {
            "system": system_name,
            "param": param,
            "hopf": [
                {"param": h.param, "omega": h.data["omega"], "lyapunov": h.data["lyapunov"],
                 "criticality": h.data["criticality"], "precision": h.precision}
                for h in hopfs
            ],
            "cycle_folds": [
                {"param": sp.param, "period": sp.data["period"],
                 "amplitude": dict(zip(system.states, sp.data["amplitude"], strict=True))}
                for br in branches for sp in br.special("cycle_fold")
            ],
            "secondary": [
                {"kind": sp.kind, "param": sp.param, "bracket": list(sp.bracket)}
                for br in branches for sp in br.special_points
                if sp.kind in ("period_doubling", "torus", "branch_point")
            ],
            "orbits": [o for br in branches for o in _orbit_json(system, br)],
            "warnings": [str(w.message) for w in caught],
            "settings": run_info("continue", system=system_name, param=param, range=[lo, hi],
                                 mesh=mesh, parameters=system.param_dict(p)),
        }
        if plot is not None:
            from bifid.report.plots import bifurcation_diagram, save_figure

            shown = [s for s in system.states if not s.endswith("d")][:2] or [system.states[0]]
            units = {s: "" for s in shown}
            fig = bifurcation_diagram(eq, branches, shown, title=f"{system_name}: periodic orbits",
                                      units=units, param_unit=_unit(system, param))
            save_figure(fig, plot)
            payload["plot"] = str(plot)
        if out is not None:
            from bifid.continuation._export import save_branch_dataset

            save_branch_dataset(branches, system, out, settings=payload["settings"])
            payload["out"] = str(out)
        folds = ", ".join(f"{c['param']:.6g}" for c in payload["cycle_folds"]) or "none"
        summary = (
            f"{system_name}: Hopf at {param} = "
            + ", ".join(f"{h['param']:.10g} ({h['criticality']}, ω = {h['omega']:.6g})"
                        for h in payload["hopf"])
            + f"; cycle folds at {folds}; {len(payload['orbits'])} orbits"
        )
        _finish(payload, branches, json_out, summary)


def _unit(system, name: str) -> str:
    return next((p.unit for p in system.parameters if p.name == name), "")


def _forced_points(br, key: str) -> list[dict[str, Any]]:
    return [
        {key: br.data[key][i], "amplitude": br.data["observed_amplitude"][i],
         "phase": br.data["phase"][i], "stable": bool(br.stable[i])}
        for i in range(len(br))
    ]


@app.command("frc")
def frc_cmd(
    system_name: Annotated[str, typer.Argument(metavar="SYSTEM")],
    forcing: Annotated[float, typer.Option("--forcing", help="Forcing amplitude F.")],
    omega_range: Annotated[
        tuple[float, float], typer.Option("--omega-range", help="Frequency range A B [rad/s].")
    ],
    mesh: MeshOpt = 64,
    observe: Annotated[str | None, typer.Option("--observe", help="Observed state.")] = None,
    sets: SetOpt = None,
    plot: PlotOpt = None,
    out: OutOpt = None,
    json_out: JsonOpt = False,
    quiet: Annotated[bool, typer.Option("--quiet")] = False,
) -> None:
    """Frequency response curve at fixed forcing (continuation in Omega)."""
    with user_errors():
        from bifid.continuation import frc

        system, p = _system_and_params(system_name, sets)
        lo, hi = finite_range("--omega-range", *omega_range)
        finite_range("--forcing", forcing, forcing + 1.0)
        with _Progress(f"{system_name}: FRC", quiet) as progress, \
                warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            br = frc(system, forcing, (lo, hi), p=p, n_mesh=mesh, observed=observe,
                     progress=progress)
        for w in caught:
            print(f"bifid: warning: {w.message}", file=sys.stderr)
        amp = br.data["observed_amplitude"]
        k = int(np.argmax(amp))
        payload = {
            "system": system_name,
            "observed": br.meta["observed"],
            "points": _forced_points(br, "omega"),
            "folds": [{"omega": sp.param, "amplitude": sp.data["amplitude"]}
                      for sp in br.special("fold")],
            "peak": {"omega": br.data["omega"][k], "amplitude": amp[k]},
            "warnings": [str(w.message) for w in caught],
            "settings": run_info("frc", system=system_name, forcing=forcing, omega_range=[lo, hi],
                                 mesh=mesh, parameters=system.param_dict(p)),
        }
        _forced_outputs(payload, [br], system, plot, out, "omega",
                        f"{system_name}: FRC, F = {forcing:g}")
        summary = (f"{system_name}: FRC at F = {forcing:g}: peak {amp[k]:.6g} at Ω = "
                   f"{br.data['omega'][k]:.6g}; folds at Ω = "
                   + (", ".join(f"{f['omega']:.8g}" for f in payload["folds"]) or "none"))
        _finish(payload, [br], json_out, summary)


def _forced_outputs(payload, branches, system, plot, out, xkey, title, backbone=None) -> None:
    if plot is not None:
        from bifid.report.plots import forced_diagram, save_figure

        save_figure(forced_diagram(branches, xkey=xkey, title=title, backbone=backbone), plot)
        payload["plot"] = str(plot)
    if out is not None:
        from bifid.continuation._export import save_branch_dataset

        save_branch_dataset(branches or [backbone], system, out, settings=payload["settings"])
        payload["out"] = str(out)


@app.command("scurve")
def scurve_cmd(
    system_name: Annotated[str, typer.Argument(metavar="SYSTEM")],
    omega: Annotated[float, typer.Option("--omega", help="Forcing frequency [rad/s].")],
    forcing_range: Annotated[
        tuple[float, float], typer.Option("--forcing-range", help="Forcing range A B.")
    ],
    mesh: MeshOpt = 64,
    observe: Annotated[str | None, typer.Option("--observe")] = None,
    sets: SetOpt = None,
    plot: PlotOpt = None,
    out: OutOpt = None,
    json_out: JsonOpt = False,
    quiet: Annotated[bool, typer.Option("--quiet")] = False,
) -> None:
    """S-curve at fixed forcing frequency (continuation in F)."""
    with user_errors():
        from bifid.continuation import scurve

        system, p = _system_and_params(system_name, sets)
        lo, hi = finite_range("--forcing-range", *forcing_range)
        finite_range("--omega", omega, omega + 1.0)
        with _Progress(f"{system_name}: S-curve", quiet) as progress, \
                warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            br = scurve(system, omega, (lo, hi), p=p, n_mesh=mesh, observed=observe,
                        progress=progress)
        for w in caught:
            print(f"bifid: warning: {w.message}", file=sys.stderr)
        payload = {
            "system": system_name,
            "observed": br.meta["observed"],
            "points": _forced_points(br, "forcing"),
            "folds": [{"forcing": sp.param, "amplitude": sp.data["amplitude"]}
                      for sp in br.special("fold")],
            "warnings": [str(w.message) for w in caught],
            "settings": run_info("scurve", system=system_name, omega=omega,
                                 forcing_range=[lo, hi], mesh=mesh,
                                 parameters=system.param_dict(p)),
        }
        _forced_outputs(payload, [br], system, plot, out, "forcing",
                        f"{system_name}: S-curve, Ω = {omega:g}")
        summary = (f"{system_name}: S-curve at Ω = {omega:g}: {len(br)} points; folds at F = "
                   + (", ".join(f"{f['forcing']:.8g}" for f in payload["folds"]) or "none"))
        _finish(payload, [br], json_out, summary)


@app.command("backbone")
def backbone_cmd(
    system_name: Annotated[str, typer.Argument(metavar="SYSTEM")],
    amplitude_range: Annotated[
        tuple[float, float], typer.Option("--amplitude-range", help="Amplitude range A B.")
    ],
    mode: Annotated[int, typer.Option("--mode", help="Linear mode (0 = lowest).")] = 0,
    mesh: MeshOpt = 64,
    observe: Annotated[str | None, typer.Option("--observe")] = None,
    sets: SetOpt = None,
    plot: PlotOpt = None,
    out: OutOpt = None,
    json_out: JsonOpt = False,
    quiet: Annotated[bool, typer.Option("--quiet")] = False,
) -> None:
    """Backbone curve: the locus of phase quadrature (response lags the force by π/2)."""
    with user_errors():
        from bifid.continuation import backbone

        system, p = _system_and_params(system_name, sets)
        lo, hi = finite_range("--amplitude-range", *amplitude_range)
        with _Progress(f"{system_name}: backbone", quiet) as progress, \
                warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            br = backbone(system, (lo, hi), p=p, n_mesh=mesh, mode=mode, observed=observe,
                          progress=progress)
        for w in caught:
            print(f"bifid: warning: {w.message}", file=sys.stderr)
        payload = {
            "system": system_name,
            "observed": br.meta["observed"],
            "points": [{"amplitude": br.data["observed_amplitude"][i],
                        "omega": br.data["omega"][i], "forcing": br.data["forcing"][i]}
                       for i in range(len(br))],
            "linear_frequency": br.meta["linear_frequency"],
            "warnings": [str(w.message) for w in caught],
            "settings": run_info("backbone", system=system_name, amplitude_range=[lo, hi],
                                 mode=mode, mesh=mesh, parameters=system.param_dict(p)),
        }
        _forced_outputs(payload, [], system, plot, out, "omega",
                        f"{system_name}: backbone", backbone=br)
        summary = (f"{system_name}: backbone from Ω = {br.data['omega'][0]:.6g} to "
                   f"{br.data['omega'][-1]:.6g} over amplitude {lo:g}..{hi:g} "
                   f"({len(br)} points)")
        _finish(payload, [br], json_out, summary)
