"""``bifid cbc SYSTEM --protocol ppcbc|scurve|frc --out DATA.nc``: CBC on a virtual rig.

Each converged point is appended to the dataset as soon as it exists (``--resume``
continues an interrupted run from the points already in the file); points that do not
converge, or that the controller cannot hold, are reported on stderr and in the JSON
``failures`` and are never recorded.
"""

from __future__ import annotations

import math
import sys
import warnings
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

Opt = typer.Option


class _Bars:
    """Two rich progress bars on stderr: converged points and rig evaluations."""

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

        self.p = Progress(SpinnerColumn(), TextColumn("[bold]{task.description}"), BarColumn(),
                          MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                          TimeElapsedColumn(), console=Console(stderr=True), disable=quiet)
        self.description, self.total = description, total

    def __enter__(self) -> _Bars:
        self.p.__enter__()
        self.points = self.p.add_task(f"{self.description}: points", total=self.total, info="")
        self.evals = self.p.add_task("rig evaluations", total=None, info="")
        self._n = 0
        return self

    def point(self, info: str) -> None:
        self.p.advance(self.points)
        self.p.update(self.points, info=info)

    def iteration(self, k: int = 1) -> None:
        self._n += k
        self.p.update(self.evals, completed=self._n)

    def set_iterations(self, n: int) -> None:
        self._n = n
        self.p.update(self.evals, completed=n)

    def __exit__(self, *exc: object) -> None:
        self.p.__exit__(*exc)


def _parse_noise(spec: str | None, outputs: tuple[str, ...]) -> dict[str, float] | None:
    if spec is None:
        return None
    spec = spec.strip()
    try:
        v = float(spec)
        return {n: v for n in outputs}
    except ValueError:
        pass
    out: dict[str, float] = {}
    for item in spec.split(","):
        if "=" not in item:
            raise BifidInputError(
                f"--noise expects a number or NAME=STD[,NAME=STD], got {spec!r}."
            )
        name, _, value = item.partition("=")
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


def _warn(msg: str) -> None:
    print(f"bifid: warning: {msg}", file=sys.stderr)


@app.command("cbc")
def cbc_cmd(
    system_name: Annotated[str, typer.Argument(metavar="SYSTEM", help="Registered system.")],
    protocol: Annotated[str, Opt("--protocol", help="ppcbc | scurve | frc")],
    out: Annotated[Path, Opt("--out", help="Dataset to write (netCDF), point by point.")],
    resume: Annotated[bool, Opt("--resume", help="Continue from the points in --out.")] = False,
    sets: Annotated[list[str] | None, Opt("--set", help="NAME=VALUE (repeatable).")] = None,
    param: Annotated[str | None, Opt("--param", help="ppcbc: bifurcation parameter.")] = None,
    values: Annotated[str | None, Opt("--values", help="ppcbc: values, e.g. 15,15.5,16.")] = None,
    prange: Annotated[tuple[float, float] | None, Opt("--range", help="ppcbc: A B.")] = None,
    n_values: Annotated[int, Opt("--n-values", help="ppcbc: values in --range.")] = 6,
    amplitude_range: Annotated[
        tuple[float, float] | None,
        Opt("--amplitude-range", help="ppcbc: target amplitudes scanned, A B."),
    ] = None,
    n_amplitudes: Annotated[int | None, Opt("--n-amplitudes", help="ppcbc: grid size.")] = None,
    target: Annotated[str, Opt("--target", help="ppcbc: polar | elliptic.")] = "polar",
    n_harmonics: Annotated[int | None, Opt("--n-harmonics", help="Target harmonics.")] = None,
    continuation: Annotated[
        int, Opt("--continuation", help="ppcbc: after the first value, follow the branch "
                 "by Newton-Broyden + arclength for this many points (0: scan every value).")
    ] = 0,
    ds: Annotated[float | None, Opt("--ds", help="Arclength step.")] = None,
    omega: Annotated[float | None, Opt("--omega", help="scurve: Ω; ppcbc: frequency guess.")
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
        float | None,
        Opt("--filter-hz", help="ppcbc: controller output low-pass [Hz] (0: none; default "
            "per system, flutter 100)."),
    ] = None,
    x1: Annotated[str | None, Opt("--x1", help="ppcbc: first phase-plane signal.")] = None,
    x2: Annotated[str | None, Opt("--x2", help="ppcbc: second signal ('h_dot' = dh/dt).")
                  ] = None,
    observe: Annotated[str | None, Opt("--observe", help="forced: controlled signal.")] = None,
    noise: Annotated[str | None, Opt("--noise", help="Noise std: one number or h=1e-4,...")
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
    plot: Annotated[Path | None, Opt("--plot", help="Figure over the continuation truth.")
                    ] = None,
    truth: Annotated[bool, Opt("--truth/--no-truth", help="Compute the ground truth "
                               "(continuation) for the plot and the JSON.")] = True,
    json_out: Annotated[bool, Opt("--json", help="Print one JSON object on stdout.")] = False,
    quiet: Annotated[bool, Opt("--quiet", help="No progress display.")] = False,
) -> None:
    """Control-based continuation on a virtual rig of SYSTEM (thesis ch. 3)."""
    with user_errors():
        from bifid.cbc import VirtualRig
        from bifid.cbc._defaults import defaults_for
        from bifid.systems import get_system

        system = get_system(system_name)
        overrides = parse_sets(sets)
        system.param_vector(overrides)  # validates names and values
        if protocol not in ("ppcbc", "scurve", "frc"):
            raise BifidInputError(f"--protocol must be ppcbc, scurve or frc, got {protocol!r}.")
        if protocol == "ppcbc" and system.kind != "autonomous":
            raise BifidInputError(f"{system_name!r} is forced: use --protocol scurve or frc.")
        if protocol != "ppcbc" and system.kind != "forced":
            raise BifidInputError(f"{system_name!r} is autonomous: use --protocol ppcbc.")
        if resume and not out.exists():
            raise BifidInputError(f"--resume: {out} does not exist (nothing to resume).")
        if not resume and out.exists():
            raise BifidInputError(
                f"{out} exists; pass --resume to continue it or choose another --out."
            )
        dflt = defaults_for(system_name)
        fs = float(sample_rate or dflt.sample_rate)
        outputs = dflt.outputs
        if protocol != "ppcbc":
            sig = observe or dflt.signal or system.observed
            outputs = tuple(dict.fromkeys([sig, *(outputs or ())]))
        rig_outputs = outputs or None
        probe = VirtualRig(system, overrides, outputs=rig_outputs, sample_rate=fs)
        noise_map = _parse_noise(noise, probe.output_names)
        rig = VirtualRig(system, overrides, outputs=rig_outputs, sample_rate=fs,
                         noise=noise_map, derivative=derivative, seed=seed,
                         derivative_cutoff=dflt.derivative_cutoff)
        common = dict(system=system, system_name=system_name, rig=rig, dflt=dflt, out=out,
                      resume=resume, overrides=overrides, kp=kp, kd=kd, settle=settle,
                      measure=measure, tol=tol, stability=stability, n_harmonics=n_harmonics,
                      plot=plot, truth=truth, json_out=json_out, quiet=quiet, seed=seed,
                      noise=noise_map, derivative=derivative, ds=ds)
        if protocol == "ppcbc":
            _ppcbc(param=param, values=values, prange=prange, n_values=n_values,
                   amplitude_range=amplitude_range, n_amplitudes=n_amplitudes, target=target,
                   continuation=continuation, omega=omega, x1=x1, x2=x2,
                   filter_hz=filter_hz, **common)
        else:
            _forced(protocol=protocol, omega=omega, forcing_range=forcing_range,
                    forcing=forcing, omega_range=omega_range, signal=outputs[0], **common)


# --------------------------------------------------------------------------------- ppcbc
def _ppcbc(*, system, system_name, rig, dflt, out, resume, overrides, kp, kd, settle, measure,
           filter_hz=None,
           tol, stability, n_harmonics, plot, truth, json_out, quiet, seed, noise, derivative,
           ds, param, values, prange, n_values, amplitude_range, n_amplitudes, target,
           continuation, omega, x1, x2) -> None:
    from bifid.cbc._ppcbc import PPCBCOptions, ppcbc_continuation, ppcbc_scan
    from bifid.cbc._records import lco_record
    from bifid.data import append_record, lco_records, load_dataset

    param = param or system.default_param
    system.index(param)
    vals = _floats(values, "--values")
    if vals is None:
        if prange is None:
            raise BifidInputError("ppcbc needs --values V1,V2,... or --range A B.")
        lo, hi = finite_range("--range", *prange)
        if n_values < 1:
            raise BifidInputError("--n-values must be >= 1.")
        vals = list(np.linspace(lo, hi, n_values)) if n_values > 1 else [lo]
    a_lo, a_hi = amplitude_range or dflt.amplitude_range
    finite_range("--amplitude-range", a_lo, a_hi)
    n_amp = n_amplitudes or dflt.n_amplitudes
    if n_amp < 2:
        raise BifidInputError("--n-amplitudes must be >= 2.")
    grid = np.linspace(min(a_lo, a_hi), max(a_lo, a_hi), n_amp)
    opts_kw: dict[str, Any] = dict(
        x1=x1 or dflt.x1 or rig.output_names[0],
        x2=x2 or dflt.x2 or f"{rig.output_names[0]}_dot",
        kp=dflt.kp if kp is None else kp, kd=dflt.kd if kd is None else kd, target=target,
        n_harmonics=n_harmonics or 10, settle_periods=settle or dflt.settle_periods,
        measure_periods=measure or dflt.measure_periods,
        filter_hz=dflt.filter_hz if filter_hz is None else (filter_hz or None),
    )
    if dflt.bootstrap_gains is not None and opts_kw["x2"] != f"{opts_kw['x1']}_dot":
        opts_kw["bootstrap_gains"] = dflt.bootstrap_gains
    if tol is not None:
        opts_kw["tol"] = tol
    if stability is not None:
        opts_kw["stability"] = stability
    opts = PPCBCOptions(**opts_kw)
    omega_guess = float(omega or dflt.omega_guess)
    units = next((p.unit for p in system.parameters if p.name == param), "")
    settings = run_info(
        "cbc", protocol="ppcbc", system=system_name, param=param, values=vals,
        amplitude_grid=grid.tolist(), options=opts.to_json(), rig=rig.describe(),
        parameters=system.param_dict(system.param_vector(overrides)), omega_guess=omega_guess,
        continuation=continuation, ds=ds,
    )
    ds_kwargs = dict(signal_names=list(rig.output_names), param_name=param, param_units=units,
                     system=system_name, settings=settings,
                     source=f"bifid cbc {system_name} --protocol ppcbc (virtual rig)",
                     signal_units={k: v for k, v in dflt.signal_units.items()
                                   if k in rig.output_names})
    existing: list[tuple[float, float]] = []
    if resume:
        ds_old = load_dataset(out)
        if ds_old.attrs.get("bifid_kind") != "lco" or ds_old.attrs.get("system") != system_name:
            raise BifidInputError(f"--resume: {out} is not an LCO dataset of {system_name!r}.")
        for r in lco_records(ds_old):
            a = r.extra.get(f"amp_{opts.x1}", float(np.max(np.abs(r.signals[:, 0]))))
            existing.append((float(r.param), float(a)))
    points: list[Any] = []
    failures: list[Any] = []
    skipped = 0
    n_expected = 2 * len(vals) if continuation == 0 else continuation

    with _Bars(f"PP-CBC {system_name}", n_expected, quiet) as bars, \
            warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        evals_total = [0]

        def known(pt) -> bool:
            return any(abs(pv - pt.param) <= 1e-9 * max(1.0, abs(pv))
                       and abs(a - pt.amplitude[opts.x1]) <= 0.02 * a for pv, a in existing)

        def on_point(pt) -> None:
            nonlocal skipped
            if known(pt):
                skipped += 1
                bars.point(f"{param}={pt.param:.4g} (already in file)")
                return
            append_record(out, lco_record(pt, "ppcbc"), **ds_kwargs)
            points.append(pt)
            bars.point(f"{param}={pt.param:.4g} A={pt.amplitude[opts.x1]:.4g} "
                       f"{'stable' if pt.stable else 'unstable' if pt.stable is False else '?'}")

        def on_iter(n: int) -> None:
            bars.set_iterations(evals_total[0] + n)

        if continuation == 0:
            for v in vals:
                pts, fails = ppcbc_scan(rig, param, float(v), grid, opts, omega_guess=omega_guess,
                                        on_point=on_point, on_iteration=on_iter)
                evals_total[0] = bars._n
                if pts:
                    omega_guess = pts[-1].frequency
                if not pts and not fails:
                    from bifid.cbc._ppcbc import PPCBCFailure

                    fails = [PPCBCFailure(float(v), "no zero of the control error on the "
                                          "amplitude grid (no LCO in --amplitude-range?)")]
                failures += fails
        else:
            # the scan stops at the first LCO with the rig holding it; the continuation
            # starts from there (as bifid.cbc.lco_campaign does)
            pts, fails = ppcbc_scan(rig, param, float(vals[0]), grid, opts,
                                    omega_guess=omega_guess, on_point=on_point,
                                    on_iteration=on_iter, max_points=1)
            evals_total[0] = bars._n
            failures += fails
            start = pts[0] if pts else None
            if start is None:
                from bifid.cbc._ppcbc import PPCBCFailure

                failures.append(PPCBCFailure(float(vals[0]), "no LCO found to start from"))
            else:
                direction = -1 if len(vals) < 2 or vals[-1] < vals[0] else 1
                _more, fails = ppcbc_continuation(
                    rig, param, start, opts, ds=ds or 0.5, n_points=continuation,
                    direction=direction, on_point=on_point, on_iteration=on_iter)
                failures += fails
    for w in caught:
        _warn(str(w.message))
    all_points = sorted(points, key=lambda p: (p.param, p.amplitude[opts.x1]))
    payload: dict[str, Any] = {
        "system": system_name,
        "protocol": "ppcbc",
        "param": param,
        "points": [p.to_json(param) for p in all_points],
        "failures": [f.to_json() for f in failures],
        "skipped_existing": skipped,
        "out": str(out),
        "settings": settings,
        "warnings": [str(w.message) for w in caught],
    }
    truth_data = None
    if truth and (plot is not None or json_out):
        truth_data = _lco_truth(system, overrides, param, vals, opts, payload)
    if plot is not None:
        from bifid.cbc._plot import plot_lco

        plot_lco(plot, all_points, list(rig.output_names), param, truth_data,
                 f"{system_name}: PP-CBC ({opts.target} target) over continuation",
                 units=dflt.signal_units)
        payload["plot"] = str(plot)
    _finish(payload, failures, json_out,
            f"{system_name}: PP-CBC recorded {len(points)} LCOs to {out}"
            + (f" ({skipped} already there)" if skipped else "")
            + (f"; {len(failures)} failures" if failures else ""))


def _lco_truth(system, overrides, param, vals, opts, payload) -> dict[str, Any] | None:
    """Continuation ground truth: equilibria, Hopf points and their orbit branches."""
    try:
        from bifid.continuation import ContinuationOptions, continue_from_hopf
        from bifid.signal import max_abs

        lo, hi = min(vals), max(vals)
        span = max(hi - lo, 1.0)
        a, b = lo - 0.5 * span, hi + 0.5 * span
        p = system.param_vector(overrides)
        orbit_opts = ContinuationOptions(ds=1e-3, ds_max=0.3, ds_min=1e-9, p_min=a, p_max=b,
                                         max_steps=400)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _, branches = continue_from_hopf(system, param, a, b, p=p, n_mesh=32,
                                             orbit_options=orbit_opts)
    except Exception as exc:  # the figure is still useful without the truth
        payload.setdefault("warnings", []).append(f"ground truth not computed: {exc}")
        return None
    xs, amps, st = [], {}, []
    for br in branches:
        M = br.meta.get("n_mesh", 32)
        n = system.n_states
        orbits = br.solutions[:, : M * n].reshape(-1, M, n)
        xs.append(br.params)
        st.append(br.stable)
        for name in payload["settings"]["rig"]["outputs"]:
            i = system.state_index(name)
            cen = orbits[:, :, i] - orbits[:, :, i].mean(axis=1, keepdims=True)
            amps.setdefault(name, []).append(np.array([max_abs(c) for c in cen]))
    if not xs:
        return None
    truth = {"param": np.concatenate(xs), "stable": np.concatenate(st),
             "amplitude": {k: np.concatenate(v) for k, v in amps.items()}}
    # measured vs truth: the nearest branch orbit, Newton-corrected at the measured value
    from bifid.cbc._truth import centred_amplitudes, correct_orbit

    orbits_all = []
    for br in branches:
        M = br.meta.get("n_mesh", 32)
        n = system.n_states
        for i in range(len(br)):
            orbits_all.append((float(br.params[i]), br.solutions[i, : M * n].reshape(M, n),
                               float(br.data["period"][i]), bool(br.stable[i])))
    i1 = system.state_index(opts.x1)
    for pt in payload["points"]:
        a_meas = pt["amplitude"][opts.x1]
        best = min(orbits_all, key=lambda o: abs(o[0] - pt["param"]) / max(abs(pt["param"]), 1)
                   + abs(float(np.ptp(o[1][:, i1])) / 2 - a_meas) / a_meas)
        try:
            V, _ = correct_orbit(system, param, pt["param"], best[1], best[2], p=p)
        except Exception:
            continue
        amp = centred_amplitudes(V)
        pt["truth_amplitude"] = {name: float(amp[system.state_index(name)])
                                 for name in pt["amplitude"]}
        pt["relative_error"] = {name: pt["amplitude"][name] / pt["truth_amplitude"][name] - 1.0
                                for name in pt["amplitude"]}
        pt["truth_stable"] = best[3]
    return truth


def _segments(truth, name):
    """Monotone-in-parameter pieces of the truth branch (split at folds)."""
    x, y, s = truth["param"], truth["amplitude"][name], truth["stable"]
    start = 0
    for i in range(1, len(x) - 1):
        if (x[i] - x[i - 1]) * (x[i + 1] - x[i]) < 0:
            yield x[start : i + 1], y[start : i + 1], s[start : i + 1]
            start = i
    yield x[start:], y[start:], s[start:]


# -------------------------------------------------------------------------------- forced
def _forced(*, system, system_name, rig, dflt, out, resume, overrides, kp, kd, settle, measure,
            tol, stability, n_harmonics, plot, truth, json_out, quiet, seed, noise, derivative,
            ds, protocol, omega, forcing_range, forcing, omega_range, signal) -> None:
    from bifid.cbc._forced import folds_of, frc_cbc, scurve_cbc
    from bifid.cbc._records import forced_record
    from bifid.data import append_record, forced_records, load_dataset

    # noisy S-curves and FRCs: the system's noisy_options (lower gains, longer records)
    # unless given
    noisy = any(float(v) > 0 for v in rig.describe().get("noise", {}).values())
    given = dict(kp=kp, kd=kd, n_harmonics=n_harmonics or None, settle_periods=settle or None,
                 measure_periods=measure or None)
    opts_kw: dict[str, Any] = {"signal": signal,
                               **{k: v for k, v in given.items() if v is not None}}
    if tol is not None:
        opts_kw["tol"] = tol
    if stability is not None:
        opts_kw["stability"] = stability
    if ds is not None:
        opts_kw["ds"] = ds
        opts_kw["ds_max"] = max(ds, 0.1)
    opts = dflt.forced_options(noisy=noisy, **opts_kw)
    if protocol == "scurve":
        if omega is None or forcing_range is None:
            raise BifidInputError("scurve needs --omega W and --forcing-range A B.")
        lo, hi = sorted(finite_range("--forcing-range", *forcing_range))
        if not omega > 0:
            raise BifidInputError(f"--omega must be > 0, got {omega!r}.")
        spec = {"omega": omega, "forcing_range": [lo, hi]}
    else:
        if forcing is None or omega_range is None:
            raise BifidInputError("frc needs --forcing F and --omega-range A B.")
        w0, w1 = finite_range("--omega-range", *omega_range)
        if not forcing > 0:
            raise BifidInputError(f"--forcing must be > 0, got {forcing!r}.")
        spec = {"forcing": forcing, "omega_range": [w0, w1]}
    settings = run_info("cbc", protocol=protocol, system=system_name, options=opts.to_json(),
                        rig=rig.describe(), **spec,
                        parameters=system.param_dict(system.param_vector(overrides)))
    ds_kwargs = dict(signal_names=list(rig.output_names), observed=signal, system=system_name,
                     settings=settings,
                     source=f"bifid cbc {system_name} --protocol {protocol} (virtual rig)")
    start = previous = None
    n_old = 0
    if resume:
        old = load_dataset(out)
        if old.attrs.get("bifid_kind") != "forced" or old.attrs.get("system") != system_name:
            raise BifidInputError(f"--resume: {out} is not a forced dataset of {system_name!r}.")
        recs = forced_records(old)
        n_old = len(recs)
        if recs:
            pts_old = [_point_from_record(r) for r in recs[-2:]]
            if any(p is None for p in pts_old):
                raise BifidInputError(f"--resume: {out} lacks the CBC target of its points.")
            start = pts_old[-1]
            previous = pts_old[0] if len(pts_old) == 2 else None
    points: list[Any] = []

    with _Bars(f"{protocol} {system_name}", None, quiet) as bars, \
            warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")

        def on_point(pt) -> None:
            append_record(out, forced_record(pt, protocol), **ds_kwargs)
            points.append(pt)
            bars.point(f"γ={pt.forcing:.4g} Ω={pt.omega:.4g} A={pt.amplitude:.4g}")

        if protocol == "scurve":
            _, failures = scurve_cbc(rig, float(omega), (lo, hi), opts, on_point=on_point,
                                       on_iteration=bars.iteration, start=start,
                                       previous=previous)
        else:
            _pts, failures = frc_cbc(rig, float(forcing), (w0, w1), opts, on_point=on_point,
                                    on_iteration=bars.iteration, start=start,
                                    previous=previous)
    for w in caught:
        _warn(str(w.message))
    key = "forcing" if protocol == "scurve" else "omega"
    curve = ([start] if start is not None else []) + points
    if previous is not None:
        curve = [previous, *curve]
    folds = folds_of(curve, key)
    payload: dict[str, Any] = {
        "system": system_name,
        "protocol": protocol,
        "observed": signal,
        "points": [p.to_json() for p in points],
        "folds": folds,
        "failures": [f.to_json() for f in failures],
        "resumed_from": n_old,
        "out": str(out),
        "settings": settings,
        "warnings": [str(w.message) for w in caught],
    }
    truth_data = None
    if truth and (plot is not None or json_out):
        truth_data = _forced_truth(system, overrides, protocol, spec, signal, payload)
    if plot is not None:
        from bifid.cbc._plot import plot_forced

        title = (f"{system_name}: CBC S-curve, Ω = {omega:g}" if protocol == "scurve"
                 else f"{system_name}: CBC FRC, γ = {forcing:g}")
        plot_forced(plot, curve, key, folds, truth_data, title, signal)
        payload["plot"] = str(plot)
    _finish(payload, failures, json_out,
            f"{system_name}: {protocol} CBC recorded {len(points)} points to {out}; folds at "
            + (", ".join(f"{key} = {f[key]:.6g}" for f in folds) or "none")
            + (f"; {len(failures)} failures" if failures else ""))


def _point_from_record(rec) -> Any:
    from bifid.cbc._forced import ForcedPoint
    from bifid.cbc._records import target_from_extra

    tgt = target_from_extra(rec.extra)
    if tgt is None or "force_phase" not in rec.extra:
        return None
    q = (tgt.coefficients.shape[0] - 1) // 2
    coef = np.array([rec.extra.get(f"response_A{k}", np.nan) for k in range(q + 1)]
                    + [rec.extra.get(f"response_B{k}", np.nan) for k in range(1, q + 1)])
    return ForcedPoint(omega=rec.omega, forcing=rec.forcing,
                       force_phase=float(rec.extra["force_phase"]), target=tgt,
                       coefficients=coef, measurement=None, amplitude=float(rec.amplitude),
                       phase=float(rec.phase if rec.phase is not None else np.nan),
                       stable=rec.stable)


def _forced_truth(system, overrides, protocol, spec, signal, payload) -> dict[str, Any] | None:
    try:
        from bifid.continuation import frc, scurve

        p = system.param_vector(overrides)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            if protocol == "scurve":
                lo, hi = spec["forcing_range"]
                br = scurve(system, spec["omega"], (lo * 0.5, hi * 1.1), p=p, n_mesh=32,
                            observed=signal)
            else:
                br = frc(system, spec["forcing"], tuple(spec["omega_range"]), p=p, n_mesh=32,
                         observed=signal)
    except Exception as exc:
        payload.setdefault("warnings", []).append(f"ground truth not computed: {exc}")
        return None
    key = "forcing" if protocol == "scurve" else "omega"
    truth = {key: np.asarray(br.data[key]), "amplitude": np.asarray(br.data["observed_amplitude"]),
             "stable": np.asarray(br.stable)}
    payload["truth_folds"] = [{key: sp.param, "amplitude": sp.data.get("amplitude")}
                              for sp in br.special("fold")]
    return truth


def _finish(payload: dict[str, Any], failures: list, json_out: bool, summary: str) -> None:
    payload["complete"] = not failures
    payload["status"] = "incomplete" if failures else "ok"
    if json_out:
        emit_json(payload)
    else:
        print(summary)
    if failures:
        first = failures[0]
        reason = getattr(first, "reason", str(first))
        print(f"bifid: error: CBC incomplete ({len(failures)} point(s) failed; none of them "
              f"recorded): {reason}", file=sys.stderr)
        raise typer.Exit(EXIT_NUMERICAL)


__all__ = ["cbc_cmd"]
