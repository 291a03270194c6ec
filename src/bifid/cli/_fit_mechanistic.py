"""``bifid fit mechanistic DATA.nc --model flutter --free ka2,ka3 … --out MODEL`` (thesis ch. 4).

Runs the three stages of :class:`bifid.identify.mechanistic.MechanisticModel`: linear
prediction-error identification from a free decay (``--free-decay``), the normal-form fit
of the nonlinear parameters to the unstable LCOs near the Hopf point, and the
whole-diagram update against every measured LCO by spectral collocation with exact
implicit gradients. ``bifid predict MODEL --range A B`` continues the fitted model and
returns the keys of ``bifid continue``.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from bifid.cli._common import (
    emit_json,
    fit_app,
    parse_sets,
    register_predictor,
    user_errors,
)
from bifid.errors import BifidInputError
from bifid.io import run_info

# scalars stored in the flutter rig's free-decay files -> flutter parameter names
RIG_GUESSES = {
    "I__alpha": "Ia", "c__alpha": "ca", "c__h": "ch", "k__alpha": "ka", "k__h": "kh",
    "x__alpha": "xa", "m": "mw", "m__T": "mT", "b": "b", "a": "a", "rho": "rho",
}


def _names(value: str, what: str) -> tuple[str, ...]:
    items = tuple(v.strip() for v in value.split(",") if v.strip())
    if not items:
        raise BifidInputError(f"{what} must list at least one name (comma-separated).")
    return items


def _ties(items: list[str] | None) -> dict[str, str]:
    out = {}
    for item in items or []:
        dep, sep, src = item.partition("=")
        if not sep or not dep.strip() or not src.strip():
            raise BifidInputError(f"--tie expects DEPENDENT=SOURCE (e.g. ka=Ia), got {item!r}.")
        out[dep.strip()] = src.strip()
    return out


def _load_lco(paths: list[Path]) -> Any:
    from bifid.data import combine_datasets, load_dataset

    if not paths:
        raise BifidInputError("give at least one LCO dataset (netCDF, from `bifid import`).")
    ds = [load_dataset(p) for p in paths]
    return ds[0] if len(ds) == 1 else combine_datasets(ds)


@fit_app.command("mechanistic")
def fit_mechanistic_cmd(
    data: Annotated[list[Path], typer.Argument(help="LCO datasets (netCDF), labelled.")],
    model: Annotated[str, typer.Option("--model", help="Registered system to identify.")]
    = "flutter",
    free: Annotated[str, typer.Option(
        "--free", help="Nonlinear parameters of stages 2-3, comma-separated.")] = "ka2,ka3",
    free_decay: Annotated[Path | None, typer.Option(
        "--free-decay", help="Free-decay record for the linear stage (flutter rig .mat file).")]
    = None,
    linear_free: Annotated[str, typer.Option(
        "--linear-free", help="Parameters of the linear stage.")] = "Ia,ca,ch",
    tie: Annotated[list[str] | None, typer.Option(
        "--tie", help="DEPENDENT=SOURCE: keep their ratio in the linear stage (e.g. ka=Ia).")]
    = None,
    stages: Annotated[str, typer.Option(
        "--stages", help="'auto' or a subset of linear,normal_form,whole_diagram.")] = "auto",
    outputs: Annotated[str, typer.Option(
        "--outputs", help="Signals whose amplitudes are fitted (eq. 4.15: h).")] = "h",
    param: Annotated[str | None, typer.Option("--param", help="Bifurcation parameter.")] = None,
    param_ref: Annotated[str, typer.Option(
        "--param-ref", help="Reference of mu in the normal-form stage: model | data.")]
    = "model",
    mesh: Annotated[int, typer.Option("--mesh", help="Collocation points per orbit.")] = 32,
    gradient: Annotated[str, typer.Option(
        "--gradient", help="implicit (exact) | fd (finite differences).")] = "implicit",
    max_iter: Annotated[int, typer.Option("--max-iter", help="Iterations per stage.")] = 40,
    decay_start: Annotated[str, typer.Option(
        "--decay-start", help="Start of the free decay: 'release' or seconds.")] = "release",
    file_guesses: Annotated[bool, typer.Option(
        "--file-guesses/--no-file-guesses",
        help="Use the rig file's stored values as starting/measured parameters.")] = True,
    sets: Annotated[list[str] | None, typer.Option(
        "--set", help="Override a system parameter, NAME=VALUE (repeatable).")] = None,
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Model directory to write.")]
    = None,
    plot: Annotated[Path | None, typer.Option(
        "--plot", help="Write the fitted diagram with the data (PNG/SVG).")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", help="No progress on stderr.")] = False,
    json_out: Annotated[bool, typer.Option("--json", help="One JSON object on stdout.")] = False,
) -> None:
    """Identify a physical model with a Hopf bifurcation in three stages (thesis ch. 4)."""
    with user_errors():
        from bifid.identify.mechanistic import LCOData, MechanisticModel
        from bifid.systems import get_system

        if out is None:
            raise BifidInputError("--out MODEL is required.")
        system = get_system(model)
        if system.kind != "autonomous":
            raise BifidInputError(f"{model!r} is a forced system; mechanistic fits need a Hopf "
                                  "bifurcation of an autonomous system.")
        free_names = _names(free, "--free")
        out_names = _names(outputs, "--outputs")
        if stages.strip().lower() == "auto":
            stage_list = (("linear",) if free_decay is not None else ()) + (
                "normal_form", "whole_diagram")
        else:
            stage_list = _names(stages, "--stages")
        if "linear" in stage_list and free_decay is None:
            raise BifidInputError("the linear stage needs --free-decay FILE.")
        if gradient not in ("implicit", "fd"):
            raise BifidInputError(f"--gradient must be 'implicit' or 'fd', got {gradient!r}.")
        if param_ref not in ("model", "data"):
            raise BifidInputError(f"--param-ref must be 'model' or 'data', got {param_ref!r}.")
        start: str | float = "release"
        if decay_start.strip().lower() != "release":
            try:
                start = float(decay_start)
            except ValueError:
                raise BifidInputError(
                    f"--decay-start must be 'release' or a time in seconds, got {decay_start!r}."
                ) from None
        params: dict[str, float] = {}
        fd = None
        if free_decay is not None:
            from bifid.data import load_free_decay

            fd = load_free_decay(free_decay)
            if file_guesses and system.name == "flutter":
                params.update({RIG_GUESSES[k]: float(v) for k, v in fd.guesses.items()
                               if k in RIG_GUESSES})
        params.update(parse_sets(sets))
        for name in params:
            system.index(name)
        ds = _load_lco(data)
        lco = LCOData.from_dataset(ds, out_names)
        est = MechanisticModel(
            model, free_names, param=param, params=params, outputs=out_names,
            stages=stage_list, linear_free=_names(linear_free, "--linear-free"),
            linear_ratios=_ties(tie), param_ref=param_ref, n_mesh=mesh, gradient=gradient,
            max_iter=max_iter, decay_start=start,
        )
        if not quiet:
            print(f"bifid: fitting {model} ({', '.join(stage_list)}) to {len(lco)} LCOs ...",
                  file=sys.stderr)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            est.fit(lco, fd)
        for w in caught:
            print(f"bifid: warning: {w.message}", file=sys.stderr)
        est.save(out)
        summary = est.summary()
        payload: dict[str, Any] = {
            "parameters": summary["parameters"],
            "losses": summary["losses"],
            "hopf": summary["hopf"],
            "cycle_fold": getattr(est, "cycle_fold_", None),
            "data_flutter": summary["data_flutter"],
            "identifiability": summary["identifiability"],
            "stages": summary["stages"],
            "model": str(out),
            "warnings": [str(w.message) for w in caught],
            "settings": run_info(
                "fit mechanistic", data=[str(p) for p in data], model=model,
                free=list(free_names), free_decay=str(free_decay) if free_decay else None,
                stages=list(stage_list), outputs=list(out_names), mesh=mesh, gradient=gradient,
                param_ref=param_ref, ties=_ties(tie), start_parameters=params,
            ),
        }
        if plot is not None:
            from bifid.identify.mechanistic import plot_diagram

            with warnings.catch_warnings(record=True) as caught_plot:
                warnings.simplefilter("always")
                _, branches = est.predict_diagram(*_plot_range(lco))
            for w in caught_plot:
                print(f"bifid: warning (plot): {w.message}", file=sys.stderr)
            payload["warnings"] += [f"plot: {w.message}" for w in caught_plot]
            plot_diagram(branches, lco, plot, output=out_names[0], title=f"{model}: fitted model")
            payload["plot"] = str(plot)
        if json_out:
            emit_json(payload)
        else:
            p = ", ".join(f"{k} = {v:.6g}" for k, v in summary["parameters"].items())
            losses = ", ".join(f"{k}: {v:.3g}" if v is not None else f"{k}: n/a"
                               for k, v in summary["losses"].items())
            print(f"{model}: {p}; Hopf at {summary['hopf']['param']:.6g} "
                  f"({summary['hopf']['frequency_hz']:.4g} Hz); RMS amplitude error {losses}; "
                  f"saved to {out}")


def _plot_range(lco: Any) -> tuple[float, float]:
    lo, hi = float(np.min(lco.param)), float(np.max(lco.param))
    span = max(hi - lo, 1.0)
    return lo - 0.5 * span, hi + 0.5 * span


def predict_mechanistic(model_dir: Path, options: dict[str, Any]) -> dict[str, Any]:
    """``bifid predict`` for mechanistic models: continuation of the fitted system.

    Returns the keys of ``bifid continue``: ``hopf``, ``cycle_folds``, ``secondary``,
    ``orbits`` (plus ``parameters``).
    """
    import jax.numpy as jnp

    from bifid.continuation import ContinuationOptions, continue_from_hopf
    from bifid.identify.mechanistic import MechanisticModel
    from bifid.systems import get_system

    if options.get("frc") or options.get("scurve") or options.get("backbone"):
        raise BifidInputError("a mechanistic model of a Hopf system predicts LCO branches only "
                              "(--param/--range), not FRCs, S-curves or backbones.")
    m = MechanisticModel.load(model_dir)
    system = get_system(m.system)
    param = options.get("param") or m.param_
    if param != m.param_:
        system.index(param)
    if options.get("range") is None:
        raise BifidInputError("--range A B is required.")
    lo, hi = sorted(float(v) for v in options["range"])
    p = np.array(m.p_, dtype=float)
    for name, value in (options.get("sets") or {}).items():
        p[system.index(name)] = value
    opts = ContinuationOptions(ds=1e-3, ds_max=0.25, ds_min=1e-9, p_min=lo, p_max=hi,
                               max_steps=600)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        eq, branches = continue_from_hopf(system, param, lo, hi, p=jnp.asarray(p),
                                          n_mesh=max(m.n_mesh, 32), orbit_options=opts)
    states = system.states
    payload = {
        "system": m.system,
        "param": param,
        "parameters": system.param_dict(p),
        "hopf": [{"param": h.param, "omega": h.data["omega"], "lyapunov": h.data["lyapunov"],
                  "criticality": h.data["criticality"]} for h in eq.special("hopf")],
        "cycle_folds": [
            {"param": sp.param, "period": sp.data["period"],
             "amplitude": dict(zip(states, map(float, sp.data["amplitude"]), strict=True))}
            for br in branches for sp in br.special("cycle_fold")
        ],
        "secondary": [
            {"kind": sp.kind, "param": sp.param}
            for br in branches for sp in br.special_points
            if sp.kind in ("period_doubling", "torus", "branch_point")
        ],
        "orbits": [
            {"param": float(br.params[i]), "period": float(br.data["period"][i]),
             "stable": bool(br.stable[i]), "floquet_max": float(br.data["floquet_max"][i]),
             "amplitude": dict(zip(states, map(float, br.data["amplitude"][i]), strict=True)),
             # about the orbit's mean: what a rig with offsets removed measures
             "amplitude_centred": dict(zip(states, map(float, br.data["amplitude_centred"][i]),
                                           strict=True))}
            for br in branches for i in range(len(br))
        ],
        "complete": all(br.complete for br in branches),
        "warnings": [str(w.message) for w in caught],
    }
    if options.get("plot") is not None:
        from bifid.identify.mechanistic import plot_diagram

        plot_diagram(branches, m.data_, options["plot"], output=m.outputs[0],
                     title=f"{m.system}: predicted diagram")
        payload["plot"] = str(options["plot"])
    return payload


register_predictor("mechanistic", predict_mechanistic)
