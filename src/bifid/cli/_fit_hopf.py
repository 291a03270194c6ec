"""``bifid fit hopf DATA.nc … --out MODEL`` and the ``hopf_hybrid`` predictor.

The model is :class:`bifid.identify.hopf_hybrid.HopfHybridModel` (thesis ch. 5): a
normal-form-like Hopf model with a learnt coordinate map and oscillation speed, trained on
stable and unstable limit cycles. ``--cv loo`` adds leave-one-orbit-out validation (every
record left out in turn, its amplitudes and frequency predicted by a model trained on the
others). ``bifid predict MODEL --range A B`` returns the keys of ``bifid continue``
(``hopf``, ``cycle_folds``, ``secondary``, ``orbits``) plus ``band`` (the ensemble's spread);
``--set at=U`` adds ``cycles``: one period of every signal on each cycle at ``U`` (phase
portraits, time series); ``--set member=K`` predicts with ensemble member ``K``.
"""

from __future__ import annotations

import math
import os
import sys
import warnings
from pathlib import Path
from typing import Annotated, Any

import typer

from bifid.cli._common import emit_json, fit_app, register_predictor, user_errors
from bifid.errors import BifidInputError
from bifid.io import run_info


def enable_compilation_cache() -> None:
    """Persist compiled XLA programs across runs (``$BIFID_JAX_CACHE`` or
    ``~/.cache/bifid/jax``): the model's training loops take tens of seconds to compile
    and the same shapes recur from one run to the next. Keys include the jaxlib version."""
    import jax

    try:
        current = jax.config.jax_compilation_cache_dir
    except AttributeError:  # pragma: no cover - older config API
        current = None
    if current:
        return
    path = os.environ.get("BIFID_JAX_CACHE") or str(Path.home() / ".cache" / "bifid" / "jax")
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except OSError:
        return
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)


def _number_or(value: str, keyword: str, name: str) -> float | str:
    v = value.strip().lower()
    if v == keyword:
        return v
    try:
        f = float(v)
    except ValueError:
        raise BifidInputError(f"{name} must be '{keyword}' or a number >= 0, got {value!r}.") \
            from None
    if not (math.isfinite(f) and f >= 0):
        raise BifidInputError(f"{name} must be finite and >= 0, got {value!r}.")
    return f


def _stopping(value: str) -> str | int:
    v = value.strip().lower()
    if v in ("cv", "final"):
        return v
    try:
        n = int(v)
    except ValueError:
        raise BifidInputError(
            f"--stopping must be 'cv', 'final' or an iteration count, got {value!r}."
        ) from None
    if n < 0:
        raise BifidInputError(f"--stopping must be >= 0, got {n}.")
    return n


def _harmonics(value: str) -> int | str:
    v = value.strip().lower()
    if v == "auto":
        return v
    try:
        n = int(v)
    except ValueError:
        raise BifidInputError(f"--harmonics must be 'auto' or an int >= 1, got {value!r}.") \
            from None
    if n < 1:
        raise BifidInputError(f"--harmonics must be >= 1, got {n}.")
    return n


@fit_app.command("hopf")
def fit_hopf_cmd(
    data: Annotated[list[Path], typer.Argument(help="LCO datasets (netCDF), stable and unstable.")],
    out: Annotated[Path | None, typer.Option("--out", "-o", help="Model directory to write.")]
    = None,
    criticality: Annotated[str, typer.Option(
        "--criticality", help="auto | subcritical | supercritical.")] = "auto",
    quintic: Annotated[bool | None, typer.Option(
        "--quintic/--no-quintic", help="Quintic term (default: on if subcritical).")] = None,
    plane: Annotated[str | None, typer.Option(
        "--plane", help="Two signals forming the closed orbits, e.g. 'h,alpha'.")] = None,
    harmonics: Annotated[str, typer.Option(
        "--harmonics", help="Polar Fourier harmonics (eq. 5.5): 'auto' or an int.")] = "auto",
    width: Annotated[int, typer.Option("--width", help="Hidden width of the map network.")] = 16,
    depth: Annotated[int, typer.Option("--depth", help="Hidden layers of the map network.")] = 2,
    iterations: Annotated[int, typer.Option(
        "--iterations", help="L-BFGS iterations of the map's second stage.")] = 600,
    adam: Annotated[int, typer.Option("--adam", help="Adam iterations before L-BFGS.")] = 0,
    regularization: Annotated[str, typer.Option(
        "--regularization", help="L2 weight of the map network: 'cv' or a number.")] = "cv",
    stopping: Annotated[str, typer.Option(
        "--stopping", help="'cv' (early stopping by leave-one-out), 'final' or an iteration "
        "count.")] = "cv",
    cv_score: Annotated[str, typer.Option(
        "--cv-score", help="Combine held-out losses by 'median' or 'mean'.")] = "median",
    ensemble: Annotated[int, typer.Option("--ensemble", help="Ensemble members (seeds).")] = 5,
    omega_harmonics: Annotated[int, typer.Option(
        "--omega-harmonics", help="Harmonics of the oscillation speed (eq. 5.10).")] = 6,
    cv: Annotated[str | None, typer.Option(
        "--cv", help="'loo': also run leave-one-orbit-out validation and report it.")] = None,
    plot: Annotated[Path | None, typer.Option(
        "--plot", help="Write the predicted bifurcation diagram with the data (PNG/SVG).")]
    = None,
    seed: Annotated[int, typer.Option("--seed")] = 0,
    quiet: Annotated[bool, typer.Option("--quiet", help="No progress on stderr.")] = False,
    json_out: Annotated[bool, typer.Option("--json", help="One JSON object on stdout.")] = False,
) -> None:
    """Fit a hybrid normal-form + neural-network Hopf model (thesis ch. 5) to limit cycles."""
    with user_errors():
        if out is None and cv is None:
            raise BifidInputError("--out MODEL is required (or --cv loo to only validate).")
        if cv is not None and cv.strip().lower() != "loo":
            raise BifidInputError(f"--cv must be 'loo', got {cv!r}.")
        if criticality not in ("auto", "subcritical", "supercritical"):
            raise BifidInputError(
                f"--criticality must be auto, subcritical or supercritical, got {criticality!r}."
            )
        if ensemble < 1:
            raise BifidInputError(f"--ensemble must be >= 1, got {ensemble}.")
        plane_names = None
        if plane is not None:
            plane_names = tuple(s.strip() for s in plane.split(","))
            if len(plane_names) != 2 or not all(plane_names):
                raise BifidInputError(f"--plane needs two signal names 'a,b', got {plane!r}.")
        enable_compilation_cache()
        from bifid.identify.hopf_hybrid import HopfHybridModel

        model = HopfHybridModel(
            criticality=criticality,
            quintic=quintic,
            plane=plane_names,
            n_harmonics=_harmonics(harmonics),
            width=width,
            depth=depth,
            n_adam=adam,
            n_lbfgs=iterations,
            regularization=_number_or(regularization, "cv", "--regularization"),
            stopping=_stopping(stopping),
            cv_score=cv_score,
            n_ensemble=ensemble,
            omega_harmonics=omega_harmonics,
            seed=seed,
            progress=not quiet,
        )
        paths = [str(p) for p in data]
        source = paths if len(paths) > 1 else paths[0]
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            model.fit(source)
            report = model.cross_validate(source) if cv is not None else None
        for w in caught:
            print(f"bifid: warning: {w.message}", file=sys.stderr)
        settings = run_info("fit hopf", data=paths, hyperparameters=model.get_params())
        payload: dict[str, Any] = {
            "model_type": "hopf_hybrid",
            "parameters": model.parameters(),
            "losses": {
                "map_per_orbit": model.map_losses_["map_per_orbit"],
                "map_final": model.map_losses_["map_final"],
                "speed": model.speed_losses_,
                "cv_score": model.cv_.get("best_score"),
            },
            "hopf": [model.hopf_point()],
            "cycle_folds": [f] if (f := model.cycle_fold()) else [],
            "timings": model.timings_,
            "warnings": [str(w.message) for w in caught],
            "settings": settings,
        }
        if report is not None:
            payload["cv"] = report
        if out is not None:
            model.save(out, settings)
            payload["model"] = str(out)
        if plot is not None:
            from bifid.identify._hopf_figures import diagram_figure, save_figure

            save_figure(diagram_figure(model, source), plot)
            payload["plot"] = str(plot)
        if json_out:
            emit_json(payload)
        else:
            p = payload["parameters"]
            fold = f"{p['fold']:.5g}" if p["fold"] is not None else "none"
            print(
                f"hopf_hybrid: Hopf {p['param_name']} = {p['mu0']:.5g}, fold {fold}, "
                f"a2 = {p['a2']:.4g}, omega0 = {p['omega0']:.4g} rad/s "
                f"({p['n_members']} members, lambda = {p['regularization']:g}, "
                f"{p['n_iterations']} iterations)"
                + (f"; model in {out}" if out is not None else "")
            )
            if report is not None:
                for f_ in report["folds"]:
                    errs = f_.get("amplitude_error")
                    text = ", ".join(f"{k} {100 * v:.2f} %" for k, v in errs.items()) \
                        if errs else f_.get("error", "")
                    print(f"  leave out {f_['param']:.4g} "
                          f"({'stable' if f_['stable'] else 'unstable'}): {text}")


def predict_hopf_hybrid(model_dir: Path, options: dict[str, Any]) -> dict[str, Any]:
    """``bifid predict`` handler: the model's bifurcation diagram in ``bifid continue`` keys."""
    from bifid.identify.hopf_hybrid import HopfHybridModel

    for flag in ("frc", "scurve", "backbone"):
        if options.get(flag):
            raise BifidInputError(
                f"--{flag} does not apply to a hopf_hybrid model (an autonomous Hopf system); "
                "use --range A B."
            )
    model = HopfHybridModel.load(model_dir)
    param = options.get("param")
    if param is not None and param != model.param_name_:
        raise BifidInputError(
            f"This model's bifurcation parameter is {model.param_name_!r}, not {param!r}."
        )
    sets = dict(options.get("sets") or {})
    member = sets.pop("member", None)
    at = sets.pop("at", None)
    if sets:
        raise BifidInputError(
            f"Unknown --set names for a hopf_hybrid model: {sorted(sets)}; only 'member' "
            "(ensemble member) and 'at' (parameter value of the cycles to return)."
        )
    if member is not None and not (0 <= int(member) < model.n_members_):
        raise BifidInputError(f"member must be in 0..{model.n_members_ - 1}, got {member}.")
    prange = options.get("range")
    diagram = model.predict_diagram(
        tuple(prange) if prange is not None else None,
        n_points=int(options.get("n_points") or 100),
        member=None if member is None else int(member),
    )
    payload = {"param": model.param_name_, **diagram}
    if at is not None:
        payload["cycles"] = _cycles_at(model, float(at), None if member is None else int(member))
    if options.get("plot") is not None:
        from bifid.identify._hopf_figures import diagram_figure, save_figure

        save_figure(diagram_figure(model, None, param_range=prange), options["plot"])
        payload["plot"] = str(options["plot"])
    return payload


def _cycles_at(model, param: float, member: int | None, n_points: int = 128) -> list[dict]:
    """One period of every signal (phase portrait / time series) of each cycle at ``param``:
    ``[{param, branch, period, t, signals: {name: [...]}}]`` (stable first; empty where the
    model has no cycle)."""
    out = []
    for branch in ("stable", "unstable"):
        try:
            orb = model.predict_orbit(param, branch, n_points=n_points, member=member)
        except BifidInputError:
            continue
        out.append({
            "param": param,
            "branch": branch,
            "period": float(orb["period"]),
            "t": orb["t"].tolist(),
            "signals": {k: orb["signals"][:, j].tolist()
                        for j, k in enumerate(model.signal_names_)},
        })
    return out


register_predictor("hopf_hybrid", predict_hopf_hybrid)
