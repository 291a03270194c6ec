"""``bifid continue | frc | scurve | backbone``: continuation of a system.

Every command builds a :class:`~bifid.continuation.Diagram` and prints its
:meth:`~bifid.continuation.Diagram.to_json` (the contract of ``DESIGN.md``) with the
``settings`` that produced it. The one-line summary lists only located and verified
points; candidates (detected, not verified) are listed as such. A branch cut short (step
budget, failed step, unresolved mesh) makes the result incomplete: ``complete: false``
and exit status 3, after the JSON.
"""

from __future__ import annotations

import functools
import inspect
import math
import sys
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from bifid.cli._common import (
    EXIT_NUMERICAL,
    ForceOpt,
    app,
    check_outputs,
    emit_json,
    finite_range,
    option_value,
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
OutOpt = Annotated[Path | None, typer.Option("--out", help="Save the branch as a netCDF dataset.")]
MeshOpt = Annotated[
    int, typer.Option("--mesh", help="Fourier collocation points to start with (even, >= 8).")
]
MaxMeshOpt = Annotated[
    int | None,
    typer.Option(
        "--max-mesh",
        help="Largest mesh the orbits may need (even; default: at "
        "most 4096 unknowns, points x states).",
    ),
]
AdaptOpt = Annotated[
    bool,
    typer.Option(
        "--adapt/--no-adapt",
        help="Refine and coarsen the mesh to the orbits "
        "(--no-adapt keeps --mesh; an unresolved orbit then ends the branch).",
    ),
]
QuietOpt = Annotated[bool, typer.Option("--quiet", help="No progress display.")]
ObserveOpt = Annotated[str | None, typer.Option("--observe", help="Observed state.")]


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


# ------------------------------------------------------------------------ validation
def _system_and_params(name: str, sets: list[str] | None):
    from bifid.systems import get_system

    system = get_system(name)
    p = system.param_vector(parse_sets(sets))
    return system, p


def _check_mesh(mesh: int, max_mesh: int | None = None) -> int:
    option_value("--mesh", mesh, ge=8, integer=True)
    if mesh % 2:
        raise BifidInputError(f"--mesh must be an even number of points, got {mesh}.")
    if max_mesh is not None:
        option_value("--max-mesh", max_mesh, ge=mesh, integer=True)
        if max_mesh % 2:
            raise BifidInputError(f"--max-mesh must be an even number of points, got {max_mesh}.")
    return mesh


def parse_x0(text: str | None, system) -> np.ndarray | None:
    """``--x0 v1,v2,…``: one finite number per state, in state order."""
    if text is None:
        return None
    expected = f"{system.n_states} comma-separated numbers (states {', '.join(system.states)})"
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise BifidInputError(f"--x0 expects {expected}; got {text[:80]!r}.") from None
    if len(values) != system.n_states:
        raise BifidInputError(f"--x0 expects {expected}; got {len(values)} values.")
    if not all(math.isfinite(v) for v in values):
        raise BifidInputError(f"--x0 values must be finite, got {text[:80]!r}.")
    return np.array(values)


# --------------------------------------------------------------------------- output
def _unit(system, name: str) -> str:
    return next((p.unit for p in system.parameters if p.name == name), "")


def _caught(caught: list[warnings.WarningMessage]) -> list[str]:
    out = []
    for w in caught:
        text = str(w.message)
        if text not in out:
            out.append(text)
            print(f"bifid: warning: {text}", file=sys.stderr)
    return out


def _candidates_line(diagram) -> str:
    cands = [c for b in diagram.branches for c in b.candidates] + list(diagram.candidates)
    if not cands:
        return ""
    shown = "; ".join(f"{c.kind} in [{c.bracket[0]:.6g}, {c.bracket[1]:.6g}]" for c in cands[:5])
    more = f" and {len(cands) - 5} more" if len(cands) > 5 else ""
    return f"\ncandidates (detected, not verified): {shown}{more}"


def _outputs(
    diagram, system, plot: Path | None, out: Path | None, payload: dict, **plot_kw: Any
) -> None:
    if plot is not None:
        from bifid.report.plots import plot_diagram, save_figure

        save_figure(plot_diagram(diagram, labels=[""], **plot_kw), plot)
        payload["plot"] = str(plot)
    if out is not None:
        from bifid.continuation._export import save_branch_dataset

        data = [b for b in diagram.branches if b.kind != "equilibrium" and len(b)]
        if data:
            save_branch_dataset(data, system, out, settings=diagram.settings)
            payload["out"] = str(out)
        else:
            payload["warnings"].append(f"no periodic orbits: nothing was saved to {out}")
            print(
                f"bifid: warning: no periodic orbits: nothing was saved to {out}", file=sys.stderr
            )


def _finish(diagram, payload: dict, json_out: bool, summary: str) -> None:
    if json_out:
        emit_json(payload)
    else:
        print(summary + _candidates_line(diagram))
    if not diagram.complete:
        print(
            f"bifid: error: continuation incomplete ({diagram.status}): {diagram.message}",
            file=sys.stderr,
        )
        raise typer.Exit(EXIT_NUMERICAL)


# ------------------------------------------------------------------------- continue
def _located(sp) -> str:
    """A located parameter to 10 digits, without digits below its precision."""
    prec = sp.precision if math.isfinite(sp.precision) else 0.0
    return "0" if abs(sp.param) <= prec else f"{sp.param:.10g}"


def _continue_summary(diagram, name: str, param: str) -> str:
    hopf = (
        ", ".join(
            f"{_located(h)} ({h.data['criticality']}, ω = {h.data['omega']:.6g})"
            for h in diagram.special("hopf")
        )
        or "none"
    )
    eq_folds = [sp for b in diagram.of_kind("equilibrium") for sp in b.special("fold")]
    folds = ", ".join(_located(sp) for sp in eq_folds) or "none"
    cfolds = ", ".join(_located(sp) for sp in diagram.special("cycle_fold")) or "none"
    n_orbits = sum(len(b) for b in diagram.branches if b.kind != "equilibrium")
    return (
        f"{name}: Hopf at {param} = {hopf}; folds at {folds}; cycle folds at {cfolds}; "
        f"{n_orbits} orbits"
    )


@app.command("continue")
def continue_cmd(
    system_name: Annotated[str, typer.Argument(metavar="SYSTEM", help="System name or file.")],
    param: Annotated[str | None, typer.Option("--param", help="Continuation parameter.")] = None,
    prange: Annotated[
        tuple[float, float] | None,
        typer.Option("--range", help="Parameter range A B; the run starts at A."),
    ] = None,
    x0: Annotated[
        str | None,
        typer.Option(
            "--x0",
            help="Guess of the equilibrium at A: v1,v2,… in state order "
            "(default: the system's x0, else the origin).",
        ),
    ] = None,
    mesh: MeshOpt = 64,
    max_mesh: MaxMeshOpt = None,
    adapt: AdaptOpt = True,
    sets: SetOpt = None,
    plot: PlotOpt = None,
    out: OutOpt = None,
    max_steps: Annotated[int, typer.Option("--max-steps", help="Points per branch.")] = 1000,
    orbits: Annotated[
        bool, typer.Option("--orbits/--no-orbits", help="Continue the orbits of every Hopf point.")
    ] = True,
    force: ForceOpt = False,
    json_out: JsonOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """Equilibria over a range, their Hopf points and folds, and the periodic orbits born
    at every Hopf point."""
    with user_errors():
        check_outputs(out=out, plot=plot, force=force)
        from bifid.continuation import bifurcation_diagram

        system, p = _system_and_params(system_name, sets)
        if system.kind != "autonomous":
            raise BifidInputError(f"{system_name!r} is forced: use 'bifid frc' or 'bifid scurve'.")
        param = param or system.default_param
        system.index(param)
        if prange is None:
            raise BifidInputError("--range A B is required.")
        a, b = finite_range("--range", *prange)
        x0v = parse_x0(x0, system)
        if x0v is None and system.x0 is not None:
            x0v = np.array(system.x0)
        _check_mesh(mesh, max_mesh)
        option_value("--max-steps", max_steps, ge=1, integer=True)
        settings = run_info(
            "continue",
            system=system_name,
            param=param,
            range=[a, b],
            x0=None if x0v is None else x0v.tolist(),
            mesh=mesh,
            max_mesh=max_mesh,
            adapt=adapt,
            max_steps=max_steps,
            orbits=orbits,
            parameters=system.param_dict(p),
        )
        with (
            _Progress(f"{system_name}: continuation in {param}", quiet) as progress,
            warnings.catch_warnings(record=True) as caught,
        ):
            warnings.simplefilter("always")
            diagram = bifurcation_diagram(
                system,
                param,
                a,
                b,
                p=p,
                x0=x0v,
                n_mesh=mesh,
                max_mesh=max_mesh,
                adapt=adapt,
                max_steps=max_steps,
                orbits=orbits,
                progress=progress,
                settings=settings,
                units={param: _unit(system, param)},
            )
        diagram.warnings.extend(_caught(caught))
        payload = diagram.to_json()
        shown = [s for s in system.states if not s.endswith("d")][:2] or [system.states[0]]
        _outputs(
            diagram,
            system,
            plot,
            out,
            payload,
            signals=shown,
            title=f"{system_name}: bifurcation diagram in {param}",
        )
        _finish(diagram, payload, json_out, _continue_summary(diagram, system_name, param))


# ---------------------------------------------------------------- forced responses
@dataclass(frozen=True)
class _ForcedOptions:
    """The options every forced-response command shares (declared once, below)."""

    mesh: int
    max_mesh: int | None
    adapt: bool
    observe: str | None
    sets: list[str] | None
    plot: Path | None
    out: Path | None
    force: bool
    json_out: bool
    quiet: bool


_FORCED_OPTIONS = (
    ("mesh", MeshOpt, 64),
    ("max_mesh", MaxMeshOpt, None),
    ("adapt", AdaptOpt, True),
    ("observe", ObserveOpt, None),
    ("sets", SetOpt, None),
    ("plot", PlotOpt, None),
    ("out", OutOpt, None),
    ("force", ForceOpt, False),
    ("json_out", JsonOpt, False),
    ("quiet", QuietOpt, False),
)


def _forced_command(name: str):
    """Register ``fn`` as the command ``name`` with the shared options of
    :data:`_FORCED_OPTIONS` added to its own; ``fn`` receives them as ``opts``."""

    def deco(fn: Callable[..., None]) -> Callable[..., None]:
        own = [
            q for q in inspect.signature(fn, eval_str=True).parameters.values() if q.name != "opts"
        ]
        shared = [
            inspect.Parameter(n, inspect.Parameter.POSITIONAL_OR_KEYWORD, default=d, annotation=a)
            for n, a, d in _FORCED_OPTIONS
        ]

        @functools.wraps(fn)
        def command(**kwargs: Any) -> None:
            opts = _ForcedOptions(**{n: kwargs.pop(n) for n, _, _ in _FORCED_OPTIONS})
            fn(**kwargs, opts=opts)

        command.__signature__ = inspect.Signature(own + shared, return_annotation=None)
        return app.command(name)(command)

    return deco


def _forced_run(
    kind: str,
    label: str,
    system_name: str,
    opts: _ForcedOptions,
    solve: Callable[..., Any],
    title: str,
    **settings: Any,
):
    """Validate the options, run ``solve(system, p, progress, mesh_kw)`` with warnings
    caught, build the forced diagram (``kind``) with its settings and write the outputs;
    returns the branch, the diagram and its JSON payload."""
    from bifid.continuation._diagram import diagram_of

    check_outputs(out=opts.out, plot=opts.plot, force=opts.force)
    system, p = _system_and_params(system_name, opts.sets)
    _check_mesh(opts.mesh, opts.max_mesh)
    mesh_kw = {
        "n_mesh": opts.mesh,
        "max_mesh": opts.max_mesh,
        "adapt": opts.adapt,
        "observed": opts.observe,
    }
    with (
        _Progress(f"{system_name}: {label}", opts.quiet) as progress,
        warnings.catch_warnings(record=True) as caught,
    ):
        warnings.simplefilter("always")
        br = solve(system, p, progress, mesh_kw)
    settings = run_info(
        kind,
        system=system_name,
        **settings,
        mesh=opts.mesh,
        max_mesh=opts.max_mesh,
        adapt=opts.adapt,
        parameters=system.param_dict(p),
    )
    info = {"observed": br.meta.get("observed", system.observed)}
    if kind == "backbone":
        info["linear_frequency"] = br.meta.get("linear_frequency")
    diagram = diagram_of(kind, [br], settings=settings, warnings=_caught(caught), info=info)
    payload = diagram.to_json()
    _outputs(diagram, system, opts.plot, opts.out, payload, title=title)
    return br, diagram, payload


def _folds_text(diagram) -> str:
    return ", ".join(f"{sp.param:.8g}" for sp in diagram.special("fold")) or "none"


@_forced_command("frc")
def frc_cmd(
    system_name: Annotated[str, typer.Argument(metavar="SYSTEM")],
    forcing: Annotated[float, typer.Option("--forcing", help="Forcing amplitude F (> 0).")],
    omega_range: Annotated[
        tuple[float, float],
        typer.Option("--omega-range", help="Frequency range A B [rad/s], both > 0."),
    ],
    opts: _ForcedOptions,
) -> None:
    """Frequency response curve at fixed forcing (continuation in Omega)."""
    with user_errors():
        from bifid.continuation import frc

        lo, hi = finite_range("--omega-range", *omega_range, gt=0)
        option_value("--forcing", forcing, gt=0)
        _, diagram, payload = _forced_run(
            "frc",
            "FRC",
            system_name,
            opts,
            lambda s, p, progress, kw: frc(s, forcing, (lo, hi), p=p, progress=progress, **kw),
            f"{system_name}: FRC, F = {forcing:g}",
            forcing=forcing,
            omega_range=[lo, hi],
        )
        peak = payload.get("peak") or {}
        summary = (
            f"{system_name}: FRC at F = {forcing:g}: peak {peak.get('amplitude', 0):.6g} "
            f"at Ω = {peak.get('omega', math.nan):.6g}; folds at Ω = " + _folds_text(diagram)
        )
        _finish(diagram, payload, opts.json_out, summary)


@_forced_command("scurve")
def scurve_cmd(
    system_name: Annotated[str, typer.Argument(metavar="SYSTEM")],
    omega: Annotated[float, typer.Option("--omega", help="Forcing frequency [rad/s] (> 0).")],
    forcing_range: Annotated[
        tuple[float, float], typer.Option("--forcing-range", help="Forcing range A B (>= 0).")
    ],
    opts: _ForcedOptions,
) -> None:
    """S-curve at fixed forcing frequency (continuation in F)."""
    with user_errors():
        from bifid.continuation import scurve

        lo, hi = finite_range("--forcing-range", *forcing_range, ge=0)
        option_value("--omega", omega, gt=0)
        br, diagram, payload = _forced_run(
            "scurve",
            "S-curve",
            system_name,
            opts,
            lambda s, p, progress, kw: scurve(s, omega, (lo, hi), p=p, progress=progress, **kw),
            f"{system_name}: S-curve, Ω = {omega:g}",
            omega=omega,
            forcing_range=[lo, hi],
        )
        summary = (
            f"{system_name}: S-curve at Ω = {omega:g}: {len(br)} points; folds at F = "
            + _folds_text(diagram)
        )
        _finish(diagram, payload, opts.json_out, summary)


@_forced_command("backbone")
def backbone_cmd(
    system_name: Annotated[str, typer.Argument(metavar="SYSTEM")],
    amplitude_range: Annotated[
        tuple[float, float],
        typer.Option("--amplitude-range", help="Amplitude range A B (both > 0)."),
    ],
    opts: _ForcedOptions,
    mode: Annotated[int, typer.Option("--mode", help="Linear mode (0 = lowest).")] = 0,
) -> None:
    """Backbone curve: the locus of phase quadrature (response lags the force by π/2)."""
    with user_errors():
        from bifid.continuation import backbone

        lo, hi = finite_range("--amplitude-range", *amplitude_range, gt=0)
        option_value("--mode", mode, ge=0, integer=True)
        br, diagram, payload = _forced_run(
            "backbone",
            "backbone",
            system_name,
            opts,
            lambda s, p, progress, kw: backbone(
                s, (lo, hi), p=p, mode=mode, progress=progress, **kw
            ),
            f"{system_name}: backbone",
            amplitude_range=[lo, hi],
            mode=mode,
        )
        om = br.data.get("omega") if len(br) else None
        om = np.array([math.nan]) if om is None else om
        summary = (
            f"{system_name}: backbone from Ω = {om[0]:.6g} to {om[-1]:.6g} over "
            f"amplitude {lo:g}..{hi:g} ({len(br)} points)"
        )
        _finish(diagram, payload, opts.json_out, summary)
