"""``bifid fit hopf|forced|mechanistic DATA.nc … --out MODEL``: one estimator per method.

Every command builds its estimator from the options and hands it to :func:`run_fit`, which
fits, saves and reports through the estimator contract (:mod:`bifid.identify`): the JSON
holds the model's ``summary()`` (``parameters``, ``standard_errors``, ``losses`` …), the
warnings and the ``settings`` (provenance).
"""

from __future__ import annotations

import math
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from bifid.cli._common import ForceOpt, check_outputs, emit_json, fit_app, parse_sets, user_errors
from bifid.errors import BifidInputError
from bifid.io import run_info

DataArg = Annotated[list[Path], typer.Argument(help="Datasets (netCDF).")]
OutOpt = Annotated[Path | None, typer.Option("--out", "-o", help="Model directory to write.")]
PlotOpt = Annotated[
    Path | None,
    typer.Option("--plot", help="Write the fitted model's diagram with the data (PNG/SVG)."),
]
JsonOpt = Annotated[bool, typer.Option("--json", help="One JSON object on stdout.")]
SeedOpt = Annotated[int, typer.Option("--seed")]


def _number_or(
    value: str, keywords: tuple[str, ...], name: str, *, positive: bool = False
) -> float | str:
    v = value.strip().lower()
    if v in keywords:
        return v
    try:
        f = float(v)
    except ValueError:
        f = math.nan
    if not (math.isfinite(f) and (f > 0 if positive else f >= 0)):
        raise BifidInputError(
            f"{name} must be {' or '.join(map(repr, keywords))} or a number "
            f"{'> 0' if positive else '>= 0'}, got {value!r}."
        )
    return f


def _count_or(value: str, keywords: tuple[str, ...], name: str, low: int) -> int | str:
    v = value.strip().lower()
    if v in keywords:
        return v
    try:
        n = int(v)
    except ValueError:
        n = low - 1
    if n < low:
        raise BifidInputError(
            f"{name} must be {' or '.join(map(repr, keywords))} or an "
            f"integer >= {low}, got {value!r}."
        )
    return n


def _names(value: str, what: str) -> tuple[str, ...]:
    items = tuple(v.strip() for v in value.split(",") if v.strip())
    if not items:
        raise BifidInputError(f"{what} must list at least one name (comma-separated).")
    return items


def _plot(model: Any, data: Any, path: Path) -> None:
    """The model's default diagram, with the training cycles when there are any."""
    from bifid.identify import LCOData
    from bifid.report import plot_diagram, save_figure

    diagrams = [model.predict_diagram()]
    if isinstance(data, LCOData):
        diagrams.append(data.diagram())
    save_figure(plot_diagram(*diagrams, labels=["model", "data"][: len(diagrams)]), path)


def run_fit(
    model: Any,
    data: list[Path],
    *,
    out: Path | None,
    plot: Path | None,
    json_out: bool,
    force: bool,
    command: str,
    fit_kwargs: dict[str, Any] | None = None,
    after: Callable[[Any], dict[str, Any]] | None = None,
    settings: dict[str, Any] | None = None,
) -> None:
    """Fit ``model`` to the datasets, save it to ``out`` and report (module docstring).

    ``after(model)`` adds entries to the report (e.g. a cross-validation); without it
    ``--out`` is required.
    """
    if not data:
        raise BifidInputError("give at least one dataset (netCDF).")
    if out is None and after is None:
        raise BifidInputError("--out MODEL is required.")
    check_outputs(out=out, plot=plot, force=force, directory=True, inputs=data)
    paths = [str(p) for p in data]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model.fit(paths if len(paths) > 1 else paths[0], **(fit_kwargs or {}))
        extra = after(model) if after is not None else {}
    for w in caught:
        print(f"bifid: warning: {w.message}", file=sys.stderr)
    info = run_info(command, data=paths, hyperparameters=model.get_params(), **(settings or {}))
    payload = {
        "type": model.model_type,
        **model.summary(),
        **extra,
        "warnings": [str(w.message) for w in caught],
        "settings": info,
    }
    if out is not None:
        model.save(out, settings=info)
        payload["model"] = str(out)
    if plot is not None:
        from bifid.identify import as_lco_data

        _plot(model, as_lco_data(paths) if model.kinds[0] == "bifurcation" else None, plot)
        payload["plot"] = str(plot)
    if json_out:
        emit_json(payload)
        return
    par = ", ".join(
        f"{k} = {v:.6g}" for k, v in payload["parameters"].items() if isinstance(v, float)
    )
    print(f"{command}: {par}" + (f"; model in {out}" if out is not None else ""))
    for note in payload.get("notes", []):
        print(f"  note: {note}")


@fit_app.command("hopf")
def fit_hopf_cmd(
    data: DataArg,
    out: OutOpt = None,
    criticality: Annotated[
        str, typer.Option("--criticality", help="auto | subcritical | supercritical.")
    ] = "auto",
    quintic: Annotated[
        bool | None,
        typer.Option("--quintic/--no-quintic", help="Quintic term (default: on if subcritical)."),
    ] = None,
    plane: Annotated[
        str | None,
        typer.Option("--plane", help="Two signals forming the closed orbits, e.g. 'h,alpha'."),
    ] = None,
    harmonics: Annotated[
        str,
        typer.Option("--harmonics", help="Polar Fourier harmonics (eq. 5.5): 'auto' or an int."),
    ] = "auto",
    width: Annotated[int, typer.Option("--width", help="Hidden width of the map network.")] = 16,
    depth: Annotated[int, typer.Option("--depth", help="Hidden layers of the map network.")] = 2,
    iterations: Annotated[
        int, typer.Option("--iterations", help="L-BFGS iterations of the map's second stage.")
    ] = 600,
    adam: Annotated[int, typer.Option("--adam", help="Adam iterations before L-BFGS.")] = 0,
    regularization: Annotated[
        str,
        typer.Option("--regularization", help="L2 weight of the map network: 'cv' or a number."),
    ] = "cv",
    stopping: Annotated[
        str,
        typer.Option(
            "--stopping",
            help="'cv' (early stopping by leave-one-out), 'final' or an iteration count.",
        ),
    ] = "cv",
    cv_score: Annotated[
        str, typer.Option("--cv-score", help="Combine held-out losses by 'median' or 'mean'.")
    ] = "median",
    ensemble: Annotated[int, typer.Option("--ensemble", help="Ensemble members (seeds).")] = 5,
    omega_harmonics: Annotated[
        int,
        typer.Option("--omega-harmonics", help="Harmonics of the oscillation speed (eq. 5.10)."),
    ] = 6,
    cv: Annotated[
        str | None,
        typer.Option("--cv", help="'loo': also run leave-one-orbit-out validation and report it."),
    ] = None,
    level: Annotated[
        float | None,
        typer.Option(
            "--level",
            help="Also retrain on resamplings of the records' noise (bootstrap) so the model "
            "has intervals; report the Hopf point's and cycle fold's at this level.",
        ),
    ] = None,
    plot: PlotOpt = None,
    seed: SeedOpt = 0,
    quiet: Annotated[bool, typer.Option("--quiet", help="No progress on stderr.")] = False,
    force: ForceOpt = False,
    json_out: JsonOpt = False,
) -> None:
    """Fit a hybrid normal-form + neural-network Hopf model (thesis ch. 5) to limit cycles."""
    with user_errors():
        from bifid.identify import HopfHybridModel
        from bifid.identify._intervals import check_level

        if cv is not None and cv.strip().lower() != "loo":
            raise BifidInputError(f"--cv must be 'loo', got {cv!r}.")
        lv = None if level is None else check_level(level)
        plane_names = None
        if plane is not None:
            plane_names = _names(plane, "--plane")
            if len(plane_names) != 2:
                raise BifidInputError(f"--plane needs two signal names 'a,b', got {plane!r}.")
        model = HopfHybridModel(
            criticality=criticality,
            quintic=quintic,
            plane=plane_names,
            n_harmonics=_count_or(harmonics, ("auto",), "--harmonics", 1),
            width=width,
            depth=depth,
            n_adam=adam,
            n_lbfgs=iterations,
            regularization=_number_or(regularization, ("cv",), "--regularization"),
            stopping=_count_or(stopping, ("cv", "final"), "--stopping", 0),
            cv_score=cv_score,
            n_ensemble=ensemble,
            omega_harmonics=omega_harmonics,
            seed=seed,
            progress=not quiet,
        )
        source = [str(p) for p in data]

        def after(m: Any) -> dict[str, Any]:
            extra = {"cv": m.cross_validate(source)} if cv is not None else {}
            if lv is not None:
                extra["intervals"] = _hopf_intervals(m, lv)
            return extra

        run_fit(
            model,
            data,
            out=out,
            plot=plot,
            json_out=json_out,
            force=force,
            command="fit hopf",
            fit_kwargs={"uncertainty": lv is not None},
            after=after if (cv is not None or lv is not None) else None,
        )


def _hopf_intervals(model: Any, level: float) -> dict[str, Any]:
    """``level``, ``hopf`` and ``cycle_folds`` (with their ``*_interval`` entries) of the
    fitted model's default diagram at ``level``, as ``bifid predict … --level`` prints them."""
    d = model.predict_diagram(level=level).to_json()
    return {"level": d["level"], "hopf": d["hopf"], "cycle_folds": d["cycle_folds"]}


@fit_app.command("forced")
def fit_forced_cmd(
    data: DataArg,
    out: OutOpt = None,
    forcing_scale: Annotated[
        str,
        typer.Option(
            "--forcing-scale",
            help="κ in Γ = κF: a number, 'fit' or 'auto' (fit if several Ω).",
        ),
    ] = "auto",
    linear_frequency: Annotated[
        float | None,
        typer.Option(
            "--linear-frequency",
            help="Known small-amplitude natural frequency [rad/s] (fixes κ from one S-curve).",
        ),
    ] = None,
    selection: Annotated[
        str,
        typer.Option(
            "--selection", help="Hyperparameter criterion: ml (marginal likelihood) | loo."
        ),
    ] = "ml",
    a_target: Annotated[
        str,
        typer.Option("--a-target", help="Samples of a: eq6.19 (thesis) | phase (a = −Γ sin ψ)."),
    ] = "eq6.19",
    forcing_frequency: Annotated[
        str,
        typer.Option(
            "--forcing-frequency",
            help="Γ = κF (constant, thesis) | κFΩ̄/Ω (inverse: for S-curve data).",
        ),
    ] = "constant",
    amplitude: Annotated[
        str,
        typer.Option(
            "--amplitude",
            help="ρ: max (max|y|, eq. 6.5) | harmonic (first-harmonic amplitude).",
        ),
    ] = "max",
    no_observation: Annotated[
        bool,
        typer.Option(
            "--no-observation",
            help="Do not learn the observation φ from the time series.",
        ),
    ] = False,
    restarts: Annotated[int, typer.Option("--restarts", help="Extra L-BFGS starts per GP.")] = 1,
    plot: PlotOpt = None,
    seed: SeedOpt = 0,
    force: ForceOpt = False,
    json_out: JsonOpt = False,
) -> None:
    """Fit a kernel model of the forced reduced dynamics (thesis ch. 6) to forced datasets."""
    with user_errors():
        from bifid.identify import ForcedKernelModel

        if restarts < 0:
            raise BifidInputError(f"--restarts must be >= 0, got {restarts}.")
        model = ForcedKernelModel(
            forcing_scale=_number_or(
                forcing_scale, ("fit", "auto"), "--forcing-scale", positive=True
            ),
            linear_frequency=linear_frequency,
            selection=selection,
            a_target=a_target,
            forcing_frequency=forcing_frequency,
            amplitude_kind=amplitude,
            observation=not no_observation,
            n_restarts=restarts,
            seed=seed,
        )
        run_fit(
            model, data, out=out, plot=plot, json_out=json_out, force=force, command="fit forced"
        )


def _pairs(items: list[str] | None, option: str, example: str) -> dict[str, str]:
    """``A=B`` items of a repeatable option (each may hold several, comma-separated)."""
    out = {}
    for item in (part for it in items or [] for part in it.split(",") if part.strip()):
        key, sep, value = item.partition("=")
        if not sep or not key.strip() or not value.strip():
            raise BifidInputError(f"{option} expects NAME=NAME (e.g. {example}), got {item!r}.")
        out[key.strip()] = value.strip()
    return out


def _mechanistic_start(
    model: str,
    path: Path | None,
    linear_outputs: str | None,
    file_params: list[str] | None,
    sets: list[str] | None,
) -> tuple[Any, dict[str, float]]:
    """The free-decay record at ``path`` and the starting parameters of the fit.

    ``--file-params`` maps the name of a scalar stored in the file to a parameter of the
    model (the file's other scalars are not used); ``--set`` overrides come last.
    """
    from bifid.systems import get_system

    system = get_system(model)
    if system.kind != "autonomous":
        raise BifidInputError(
            f"{model!r} is a forced system; mechanistic fits need a Hopf "
            "bifurcation of an autonomous system."
        )
    mapping = _pairs(file_params, "--file-params", "I__alpha=Ia")
    fd, params = None, {}
    if path is None and mapping:
        raise BifidInputError("--file-params needs --free-decay (the file that holds them).")
    if path is not None:
        from bifid.data import load_free_decay

        if not linear_outputs:
            raise BifidInputError(
                "--free-decay needs --linear-outputs: the states its columns record "
                "(e.g. h,alpha for heave and pitch)."
            )
        fd = load_free_decay(path)
        missing = sorted(set(mapping) - set(fd.guesses))
        if missing:
            raise BifidInputError(
                f"{path} stores no scalar named {', '.join(missing)} (it stores "
                f"{', '.join(sorted(fd.guesses)) or 'none'}); fix --file-params."
            )
        for name in mapping.values():
            system.index(name)
        params = {dst: float(fd.guesses[src]) for src, dst in mapping.items()}
    return fd, {**params, **parse_sets(sets)}


@fit_app.command("mechanistic")
def fit_mechanistic_cmd(
    data: DataArg,
    model: Annotated[
        str,
        typer.Option("--model", help="The physical model: a registered system or a system file."),
    ],
    free: Annotated[
        str,
        typer.Option(
            "--free",
            help="Nonlinear parameters of the normal-form and whole-diagram stages, "
            "comma-separated (e.g. ka2,ka3).",
        ),
    ],
    free_decay: Annotated[
        Path | None,
        typer.Option("--free-decay", help="Free-decay record of the linear stage (rig .mat file)."),
    ] = None,
    linear_outputs: Annotated[
        str | None,
        typer.Option(
            "--linear-outputs",
            help="States recorded in the free decay, in its column order (e.g. h,alpha).",
        ),
    ] = None,
    file_params: Annotated[
        list[str] | None,
        typer.Option(
            "--file-params",
            help="FILE_NAME=PARAMETER: a scalar stored in the free-decay file used as the "
            "model's parameter (repeatable or comma-separated, e.g. I__alpha=Ia,c__h=ch).",
        ),
    ] = None,
    linear_free: Annotated[
        str | None,
        typer.Option("--linear-free", help="Parameters of the linear stage (e.g. Ia,ca,ch)."),
    ] = None,
    tie: Annotated[
        list[str] | None,
        typer.Option(
            "--tie", help="DEPENDENT=SOURCE: keep their ratio in the linear stage (e.g. ka=Ia)."
        ),
    ] = None,
    stages: Annotated[
        str,
        typer.Option("--stages", help="'auto' or a subset of linear,normal_form,whole_diagram."),
    ] = "auto",
    outputs: Annotated[
        str | None,
        typer.Option(
            "--outputs", help="Signals whose amplitudes are fitted (default: the first one)."
        ),
    ] = None,
    param: Annotated[str | None, typer.Option("--param", help="Bifurcation parameter.")] = None,
    param_ref: Annotated[
        str,
        typer.Option("--param-ref", help="Reference of mu in the normal-form stage: model | data."),
    ] = "model",
    mesh: Annotated[int, typer.Option("--mesh", help="Collocation points per orbit.")] = 32,
    gradient: Annotated[
        str, typer.Option("--gradient", help="implicit (exact) | fd (finite differences).")
    ] = "implicit",
    max_iter: Annotated[int, typer.Option("--max-iter", help="Iterations per stage.")] = 40,
    decay_start: Annotated[
        str, typer.Option("--decay-start", help="Start of the free decay: 'release' or seconds.")
    ] = "release",
    sets: Annotated[
        list[str] | None,
        typer.Option("--set", help="Override a system parameter, NAME=VALUE (repeatable)."),
    ] = None,
    out: OutOpt = None,
    plot: PlotOpt = None,
    force: ForceOpt = False,
    json_out: JsonOpt = False,
) -> None:
    """Identify a physical model with a Hopf bifurcation in three stages (thesis ch. 4)."""
    with user_errors():
        from bifid.identify import MechanisticModel

        decay, params = _mechanistic_start(model, free_decay, linear_outputs, file_params, sets)
        start = _number_or(decay_start, ("release",), "--decay-start")
        est = MechanisticModel(
            model,
            _names(free, "--free"),
            param=param,
            params=params,
            outputs=_names(outputs, "--outputs") if outputs else None,
            stages=stages.strip().lower()
            if stages.strip().lower() == "auto"
            else _names(stages, "--stages"),
            linear_free=_names(linear_free, "--linear-free") if linear_free else (),
            linear_outputs=_names(linear_outputs, "--linear-outputs") if linear_outputs else None,
            linear_ratios=_pairs(tie, "--tie", "ka=Ia"),
            param_ref=param_ref,
            n_mesh=mesh,
            gradient=gradient,
            max_iter=max_iter,
            decay_start=start,
        )
        run_fit(
            est,
            data,
            out=out,
            plot=plot,
            json_out=json_out,
            force=force,
            command="fit mechanistic",
            fit_kwargs={"free_decay": decay},
            settings={"free_decay": str(free_decay) if free_decay else None},
        )
