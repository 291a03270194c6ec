"""``bifid cbc SYSTEM --protocol ppcbc|scurve|frc --out DATA.nc``: CBC on a virtual rig.

The campaign runs through :func:`bifid.cbc.ppcbc_campaign` / :func:`bifid.cbc.forced_campaign`
(the one campaign runner): each recorded point is written to the dataset at once, with
the campaign's state, so ``--resume`` continues an interrupted run exactly where it
stopped (and refuses a file of another campaign). Points that cannot be measured after
the retries are recorded as failures with their reason (exit 3, ``"complete": false``);
the JSON is the measured diagram (``Diagram.to_json``).
"""

from __future__ import annotations

import math
import sys
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from bifid.cli import _common as cli
from bifid.errors import BifidInputError

Opt = typer.Option


class _Bars:
    """Two rich progress bars on stderr: recorded points and rig evaluations."""

    def __init__(self, description: str, total: int | None, quiet: bool) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            SpinnerColumn,
            TextColumn,
            TimeElapsedColumn,
        )

        self.p = Progress(
            SpinnerColumn(),
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("{task.fields[info]}"),
            TimeElapsedColumn(),
            console=Console(stderr=True),
            disable=quiet,
        )
        self.description, self.total = description, total

    def __enter__(self) -> _Bars:
        self.p.__enter__()
        self.points = self.p.add_task(f"{self.description}: points", total=self.total, info="")
        self.evals = self.p.add_task("rig evaluations", total=None, info="")
        return self

    def point(self, pt: Any) -> None:
        if hasattr(pt, "param"):
            info = f"{pt.param:.5g} A={pt.amplitude[pt.signal]:.4g} " + (
                "stable" if pt.stable else "unstable" if pt.stable is False else ""
            )
        else:
            info = f"γ={pt.forcing:.4g} Ω={pt.omega:.4g} A={pt.amplitude:.4g}"
        self.p.advance(self.points)
        self.p.update(self.points, info=info)

    def evaluation(self, k: int = 1) -> None:
        self.p.advance(self.evals, k)

    def __exit__(self, *exc: object) -> None:
        self.p.__exit__(*exc)


def _measure(description: str, total: int | None, quiet: bool, campaign, *args, **kwargs):
    """``campaign(*args, **kwargs)`` under the progress bars (``total`` points expected;
    None: unknown), its warnings silenced (failures are in the result)."""
    with _Bars(description, total, quiet) as bars, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return campaign(*args, on_point=bars.point, on_evaluation=bars.evaluation, **kwargs)


def _parse_noise(spec: str | None) -> float | dict[str, float] | None:
    if spec is None:
        return None
    spec = spec.strip()
    try:
        return float(spec)
    except ValueError:
        pass
    out: dict[str, float] = {}
    for item in spec.split(","):
        name, eq, value = item.partition("=")
        if not eq:
            raise BifidInputError(f"--noise expects a number or NAME=STD[,NAME=STD], got {spec!r}.")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise BifidInputError(f"--noise {name}: {value!r} is not a number.") from None
    return out


def _floats(text: str | None, what: str) -> list[float] | None:
    if text is None:
        return None
    try:
        vals = [float(t) for t in text.replace(" ", "").split(",") if t]
    except ValueError:
        raise BifidInputError(f"{what} must be comma-separated numbers, got {text!r}.") from None
    if not vals or not all(math.isfinite(v) for v in vals):
        raise BifidInputError(f"{what} must be finite numbers, got {text!r}.")
    return vals


@cli.app.command("cbc")
def cbc_cmd(
    system_name: Annotated[str, typer.Argument(metavar="SYSTEM", help="System name or file.")],
    out: Annotated[Path, Opt("--out", help="Dataset to write (netCDF), point by point.")],
    protocol: Annotated[
        str | None, Opt("--protocol", help="ppcbc (default if self-excited) | scurve | frc")
    ] = None,
    resume: Annotated[bool, Opt("--resume", help="Continue the campaign in --out.")] = False,
    force: cli.ForceOpt = False,
    sets: Annotated[list[str] | None, Opt("--set", help="NAME=VALUE (repeatable).")] = None,
    param: Annotated[str | None, Opt("--param", help="ppcbc: bifurcation parameter.")] = None,
    values: Annotated[str | None, Opt("--values", help="ppcbc: values, e.g. 15,15.5,16.")] = None,
    prange: Annotated[
        tuple[float, float] | None,
        Opt(
            "--range", help="ppcbc: A B (scan: --n-values values; --continuation: from A towards B)"
        ),
    ] = None,
    n_values: Annotated[int, Opt("--n-values", help="ppcbc: values in --range.")] = 6,
    amplitude_range: Annotated[
        tuple[float, float] | None,
        Opt("--amplitude-range", help="ppcbc: target amplitudes scanned, A B."),
    ] = None,
    n_amplitudes: Annotated[int | None, Opt("--n-amplitudes", help="ppcbc: grid size.")] = None,
    target: Annotated[str, Opt("--target", help="ppcbc: polar | elliptic.")] = "polar",
    n_harmonics: Annotated[int | None, Opt("--n-harmonics", help="Target harmonics.")] = None,
    continuation: Annotated[
        int,
        Opt(
            "--continuation",
            help="ppcbc: follow the LCO branches from the first value by "
            "continuation for this many points (0: scan at every value).",
        ),
    ] = 0,
    ds: Annotated[
        float | None, Opt("--ds", help="Arclength step (PP-CBC: range/5, ≤ 0.5).")
    ] = None,
    omega: Annotated[
        float | None, Opt("--omega", help="scurve: Ω; ppcbc: frequency guess.")
    ] = None,
    forcing_range: Annotated[
        tuple[float, float] | None, Opt("--forcing-range", help="scurve: γ range A B.")
    ] = None,
    forcing: Annotated[float | None, Opt("--forcing", help="frc: forcing γ.")] = None,
    omega_range: Annotated[
        tuple[float, float] | None, Opt("--omega-range", help="frc: Ω range A B.")
    ] = None,
    kp: Annotated[float | None, Opt("--kp", help="Proportional gain.")] = None,
    kd: Annotated[float | None, Opt("--kd", help="Derivative gain.")] = None,
    filter_hz: Annotated[
        float | None, Opt("--filter-hz", help="ppcbc: controller output low-pass [Hz] (0: none).")
    ] = None,
    x1: Annotated[str | None, Opt("--x1", help="ppcbc: first phase-plane signal.")] = None,
    x2: Annotated[str | None, Opt("--x2", help="ppcbc: second signal ('h_dot' = dh/dt).")] = None,
    observe: Annotated[str | None, Opt("--observe", help="forced: controlled signal.")] = None,
    noise: Annotated[str | None, Opt("--noise", help="Noise std: one number or h=1e-4,...")] = None,
    noise_fraction: Annotated[
        float | None,
        Opt(
            "--noise-fraction",
            help="ppcbc: noise std as a fraction of the smallest limit "
            "cycle's amplitude of each output (0.01: 1 %).",
        ),
    ] = None,
    seed: Annotated[int, Opt("--seed", help="Seed of the measurement noise.")] = 0,
    sample_rate: Annotated[float | None, Opt("--sample-rate", help="Rig rate [Hz].")] = None,
    derivative: Annotated[str, Opt("--derivative", help="samples | state.")] = "samples",
    settle: Annotated[float | None, Opt("--settle-periods", help="Periods to settle.")] = None,
    measure: Annotated[float | None, Opt("--measure-periods", help="Periods recorded.")] = None,
    tol: Annotated[float | None, Opt("--tol", help="Relative control-error tolerance.")] = None,
    stability: Annotated[
        bool | None, Opt("--stability/--no-stability", help="Switch-off stability test.")
    ] = None,
    plot: Annotated[Path | None, Opt("--plot", help="Figure over the continuation truth.")] = None,
    truth: Annotated[
        bool,
        Opt("--truth/--no-truth", help="Compare with continuation of the model (JSON and plot)."),
    ] = True,
    json_out: Annotated[bool, Opt("--json", help="Print one JSON object on stdout.")] = False,
    quiet: Annotated[bool, Opt("--quiet", help="No progress display.")] = False,
) -> None:
    """Control-based continuation on a virtual rig of SYSTEM (thesis ch. 3)."""
    with cli.user_errors():
        from bifid.systems import get_system

        system = get_system(system_name)
        overrides = cli.parse_sets(sets)
        system.param_vector(overrides)
        protocol = _check_protocol(system, system_name, protocol)
        cli.check_outputs(out=out, plot=plot, force=force, resume=resume)
        options = _protocol_options(kp, kd, n_harmonics, settle, measure, tol, stability)
        rig_options: dict[str, Any] = {"derivative": derivative}
        if sample_rate is not None:
            rig_options["sample_rate"] = cli.option_value("--sample-rate", sample_rate, gt=0)
        common = dict(
            overrides=overrides,
            noise=_parse_noise(noise),
            seed=seed,
            rig_options=rig_options,
            out=out,
            resume=resume,
        )
        given = locals()
        if protocol == "ppcbc":
            result = _ppcbc(system, options, common, quiet, **{k: given[k] for k in _PPCBC})
            key = "param"
        else:
            if noise_fraction is not None:
                raise BifidInputError("--noise-fraction is for ppcbc; give --noise (std).")
            result = _forced(
                system, protocol, options, common, quiet, **{k: given[k] for k in _FORCED}
            )
            key = "forcing" if protocol == "scurve" else "omega"
        diagram = result.diagram
        payload = diagram.to_json()
        model = None
        if truth and (plot is not None or json_out):
            model = _truth(system, overrides, protocol, diagram, payload)
        if plot is not None:
            _plot(system, protocol, diagram, model, plot, payload)
        _finish(system, protocol, result, payload, key, out, resume, json_out)


def _check_protocol(system, system_name: str, protocol: str | None) -> str:
    """The protocol to run: as given, or PP-CBC for a self-excited system."""
    if protocol is None:
        if system.kind != "autonomous":
            raise BifidInputError(
                f"{system_name!r} is forced: give --protocol scurve or --protocol frc."
            )
        return "ppcbc"
    if protocol not in ("ppcbc", "scurve", "frc"):
        raise BifidInputError(f"--protocol must be ppcbc, scurve or frc, got {protocol!r}.")
    if protocol == "ppcbc" and system.kind != "autonomous":
        raise BifidInputError(f"{system_name!r} is forced: use --protocol scurve or frc.")
    if protocol != "ppcbc" and system.kind != "forced":
        raise BifidInputError(f"{system_name!r} is autonomous: use --protocol ppcbc.")
    return protocol


def _protocol_options(kp, kd, n_harmonics, settle, measure, tol, stability) -> dict[str, Any]:
    """The protocol options given on the command line, each checked."""
    options = dict(
        kp=cli.option_value("--kp", kp),
        kd=cli.option_value("--kd", kd),
        n_harmonics=cli.option_value("--n-harmonics", n_harmonics, ge=1, integer=True),
        settle_periods=cli.option_value("--settle-periods", settle, gt=0),
        measure_periods=cli.option_value("--measure-periods", measure, ge=1),
        tol=cli.option_value("--tol", tol, gt=0),
        stability=stability,
    )
    return {k: v for k, v in options.items() if v is not None}


def _finish(system, protocol, result, payload, key, out, resume, json_out) -> None:
    """The JSON diagram or a summary line on stdout; warnings and incompleteness on
    stderr (exit 3 when incomplete)."""
    diagram = result.diagram
    if json_out:
        cli.emit_json(payload)
    else:
        folds = payload.get("folds")
        print(
            f"{system.name}: {protocol} CBC recorded {len(result.points)} points to {out}"
            + (f" (resumed after {result.resumed_from})" if resume else "")
            + (f"; folds at {', '.join(f'{f[key]:.6g}' for f in folds)}" if folds else "")
            + (f"; {len(result.failures)} failures" if result.failures else "")
        )
    for w in diagram.warnings:
        print(f"bifid: warning: {w}", file=sys.stderr)
    if not diagram.complete:
        print(f"bifid: error: CBC incomplete: {diagram.message}", file=sys.stderr)
        raise typer.Exit(cli.EXIT_NUMERICAL)


_PPCBC = (
    "param",
    "values",
    "prange",
    "n_values",
    "amplitude_range",
    "n_amplitudes",
    "target",
    "continuation",
    "ds",
    "omega",
    "filter_hz",
    "x1",
    "x2",
    "noise_fraction",
)
_FORCED = ("ds", "omega", "forcing_range", "forcing", "omega_range", "observe")


def _ppcbc(
    system,
    options,
    common,
    quiet,
    *,
    param,
    values,
    prange,
    n_values,
    amplitude_range,
    n_amplitudes,
    target,
    continuation,
    ds,
    omega,
    filter_hz,
    x1,
    x2,
    noise_fraction,
):
    from bifid.cbc import defaults_for, ppcbc_campaign

    param = param or system.default_param
    system.index(param)
    vals = _floats(values, "--values")
    continuation = cli.option_value("--continuation", continuation, ge=0, integer=True)
    rng = None
    if continuation:
        if prange is not None:
            rng = cli.finite_range("--range", *prange)
        elif vals is not None and len(vals) >= 2:
            rng = (vals[0], vals[-1])
        else:
            raise BifidInputError("--continuation needs --range START END.")
        vals = None
    elif vals is None:
        if prange is None:
            raise BifidInputError("ppcbc needs --values V1,V2,... or --range A B.")
        lo, hi = cli.finite_range("--range", *prange)
        n_values = cli.option_value("--n-values", n_values, ge=1, integer=True)
        vals = list(np.linspace(lo, hi, n_values)) if n_values > 1 else [lo]
    span = rng if rng is not None else (min(vals), max(vals))
    dflt = defaults_for(
        system,
        common["overrides"],
        param=param,
        param_range=(min(span), max(span)),
        noise_reference=noise_fraction is not None,
    )
    if omega is not None:
        dflt = replace(dflt, omega_guess=cli.option_value("--omega", omega, gt=0))
    grid = None
    if amplitude_range is not None or n_amplitudes is not None:
        a_lo, a_hi = amplitude_range or dflt.amplitude_range
        cli.finite_range("--amplitude-range", a_lo, a_hi, gt=0)
        n_amp = cli.option_value(
            "--n-amplitudes", n_amplitudes, dflt.n_amplitudes, ge=2, integer=True
        )
        grid = np.linspace(min(a_lo, a_hi), max(a_lo, a_hi), n_amp)
    opts = dict(options, target=target)
    for k, v in (("x1", x1), ("x2", x2)):
        if v is not None:
            opts[k] = v
    if filter_hz is not None:
        cut = cli.option_value("--filter-hz", filter_hz, ge=0)
        opts["filter_hz"] = cut if cut > 0 else None  # 0: no filter
    total = continuation or 2 * len(vals)
    return _measure(
        f"PP-CBC {system.name}",
        total,
        quiet,
        ppcbc_campaign,
        system,
        param=param,
        values=vals,
        span=rng,
        continuation=continuation,
        amplitudes=grid,
        ds=None if ds is None else cli.option_value("--ds", ds, gt=0),
        options=opts,
        noise_fraction=noise_fraction,
        defaults=dflt,
        **common,
    )


def _forced(
    system,
    protocol,
    options,
    common,
    quiet,
    *,
    ds,
    omega,
    forcing_range,
    forcing,
    omega_range,
    observe,
):
    from bifid.cbc import forced_campaign

    if protocol == "scurve":
        if omega is None or forcing_range is None:
            raise BifidInputError("scurve needs --omega W and --forcing-range A B.")
        rng = cli.finite_range("--forcing-range", *forcing_range, gt=0)
        cli.option_value("--omega", omega, gt=0)
    else:
        if forcing is None or omega_range is None:
            raise BifidInputError("frc needs --forcing F and --omega-range A B.")
        rng = cli.finite_range("--omega-range", *omega_range, gt=0)
        cli.option_value("--forcing", forcing, gt=0)
    opts = dict(options)
    if observe is not None:
        system.state_index(observe)
        opts["signal"] = observe
    if ds is not None:
        opts["ds"] = cli.option_value("--ds", ds, gt=0)
        opts["ds_max"] = max(opts["ds"], 0.1)
    return _measure(
        f"{protocol} {system.name}",
        None,
        quiet,
        forced_campaign,
        system,
        protocol,
        omega=omega,
        forcing=forcing,
        span=rng,
        options=opts,
        **common,
    )


def _truth(system, overrides, protocol, diagram, payload):
    """Continuation of the model: per-point errors in the JSON; the model's diagram (None
    when continuation finds nothing)."""
    from bifid.cbc._truth import forced_truth, lco_truth

    p = system.param_vector(overrides)
    points = payload["points"]
    if protocol == "ppcbc":
        signals = list(diagram.branches[0].signals)
        x1 = str(diagram.settings.get("campaign", {}).get("options", {}).get("x1", signals[0]))
        params = [pt["param"] for pt in points] or [0.0]
        curve = (
            lco_truth(system, p, diagram.param, min(params), max(params), points, signals, x1)
            if points
            else None
        )
        errors = [abs(e) for pt in points for e in pt.get("relative_error", {}).values()]
        payload["truth"] = {
            "max_relative_error": max(errors) if errors else None,
            "compared": sum("relative_error" in pt for pt in points),
        }
        return None if curve is None else curve["diagram"]
    spec = diagram.settings.get("campaign", {})
    lo, hi = sorted(spec.get("range", (0.0, 1.0)))
    got = forced_truth(
        system, p, protocol, float(spec.get("fixed")), lo, hi, str(diagram.info.get("observed"))
    )
    if got is None:
        return None
    curve, folds = got
    payload["truth"] = {"folds": folds}
    return curve["diagram"]


def _plot(system, protocol, diagram, truth, plot: Path, payload) -> None:
    """The measured diagram over the model's (when computed), by :mod:`bifid.report`."""
    from bifid.report import plot_diagram, save_figure

    shown = ([truth] if truth is not None else []) + [diagram]
    labels = (["continuation of the model"] if truth is not None else []) + ["CBC"]
    fig = plot_diagram(*shown, labels=labels, title=f"{system.name}: CBC {protocol}")
    save_figure(fig, plot)
    payload["plot"] = str(plot)


__all__ = ["cbc_cmd"]
