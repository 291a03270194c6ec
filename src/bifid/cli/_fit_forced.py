"""``bifid fit forced DATA.nc … --out MODEL`` and the ``forced_kernel`` predictor.

The model is :class:`bifid.identify.forced_kernel.ForcedKernelModel` (thesis ch. 6):
reduced dynamics ``a(ρ, Ω)``, ``b(ρ, Ω)`` on a forced spectral submanifold learned by
Gaussian-process (kernel ridge) regression from forced responses (S-curves, FRCs).

``bifid predict MODEL --frc --forcing F [--omega-range A B]``,
``--scurve --omega W [--forcing-range A B]`` and ``--backbone [--amplitude-range A B]``
return the keys of ``bifid frc`` / ``scurve`` / ``backbone``. ``--set n_samples=N`` adds an
uncertainty band from N posterior samples (``--set band_level=0.9``, ``--set seed=1``).
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
    emit_json,
    fit_app,
    register_predictor,
    user_errors,
)
from bifid.errors import BifidInputError
from bifid.io import run_info

_BAND_KEYS = ("n_samples", "band_level", "seed")


def _forcing_scale(value: str) -> float | str:
    v = value.strip().lower()
    if v in ("fit", "auto"):
        return v
    try:
        f = float(v)
    except ValueError:
        raise BifidInputError(
            f"--forcing-scale must be a positive number, 'fit' or 'auto', got {value!r}."
        ) from None
    if not (math.isfinite(f) and f > 0):
        raise BifidInputError(f"--forcing-scale must be positive and finite, got {value!r}.")
    return f


@fit_app.command("forced")
def fit_forced_cmd(
    data: Annotated[list[Path], typer.Argument(help="Forced datasets (netCDF): S-curves, FRCs.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Model directory to write.")],
    forcing_scale: Annotated[str, typer.Option(
        "--forcing-scale", help="κ in Γ = κF: a number, 'fit' or 'auto' (fit if several Ω).",
    )] = "auto",
    linear_frequency: Annotated[float | None, typer.Option(
        "--linear-frequency", help="Known small-amplitude natural frequency [rad/s] (fixes κ "
        "from one S-curve).",
    )] = None,
    selection: Annotated[str, typer.Option(
        "--selection", help="Hyperparameter criterion: ml (marginal likelihood) | loo.",
    )] = "ml",
    a_target: Annotated[str, typer.Option(
        "--a-target", help="Samples of a: eq6.19 (thesis) | phase (a = −Γ sin ψ).",
    )] = "eq6.19",
    amplitude: Annotated[str, typer.Option(
        "--amplitude", help="ρ: max (max|y|, eq. 6.5) | harmonic (first-harmonic amplitude).",
    )] = "max",
    no_observation: Annotated[bool, typer.Option(
        "--no-observation", help="Do not learn the observation φ from the time series.",
    )] = False,
    restarts: Annotated[int, typer.Option("--restarts", help="Extra L-BFGS starts per GP.")] = 1,
    seed: Annotated[int, typer.Option("--seed")] = 0,
    json_out: Annotated[bool, typer.Option("--json", help="One JSON object on stdout.")] = False,
) -> None:
    """Fit a kernel model of the forced reduced dynamics (thesis ch. 6) to forced datasets."""
    with user_errors():
        from bifid.identify.forced_kernel import ForcedKernelModel

        if not data:
            raise BifidInputError("give at least one forced dataset (netCDF).")
        if restarts < 0:
            raise BifidInputError(f"--restarts must be >= 0, got {restarts}.")
        for p in data:
            if not p.is_file():
                raise BifidInputError(f"dataset {str(p)!r} does not exist.")
        if out.exists() and not out.is_dir():
            raise BifidInputError(f"--out {str(out)!r} exists and is not a directory.")
        model = ForcedKernelModel(
            forcing_scale=_forcing_scale(forcing_scale), linear_frequency=linear_frequency,
            selection=selection, a_target=a_target, observation=not no_observation,
            n_restarts=restarts, seed=seed,
        )
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            model.fit([str(p) for p in data], amplitude_kind=amplitude)
        for w in caught:
            print(f"bifid: warning: {w.message}", file=sys.stderr)
        settings = run_info(
            "fit forced", data=[str(p) for p in data], forcing_scale=forcing_scale,
            linear_frequency=linear_frequency, selection=selection, a_target=a_target,
            amplitude=amplitude, observation=not no_observation, restarts=restarts, seed=seed,
        )
        model.save(out, settings=settings)
        payload = {
            "model": str(out),
            "type": "forced_kernel",
            "parameters": model.parameters(),
            "losses": model.losses_,
            "n_train": model.n_train_,
            "trained_ranges": {"omega": list(model.omega_range_),
                               "amplitude": list(model.rho_range_),
                               "forcing": list(model.forcing_range_)},
            "notes": list(model.notes_),
            "warnings": [str(w.message) for w in caught],
            "settings": settings,
        }
        if json_out:
            emit_json(payload)
        else:
            par = payload["parameters"]
            print(f"forced kernel model → {out}: {model.n_train_} points, κ = "
                  f"{par['forcing_scale']:.6g}, linear frequency "
                  f"{par['linear_frequency'] or float('nan'):.6g} rad/s; forcing misfit "
                  f"{100 * model.losses_['forcing_rel_rms']:.3g} % RMS")
            for n in model.notes_:
                print(f"  note: {n}")


# ---------------------------------------------------------------------------- predictor


def _band_options(sets: dict[str, float]) -> dict[str, Any]:
    unknown = sorted(set(sets) - set(_BAND_KEYS))
    if unknown:
        raise BifidInputError(
            f"a forced_kernel model has no parameter(s) {', '.join(unknown)}; --set accepts "
            f"{', '.join(_BAND_KEYS)} (uncertainty band)."
        )
    n = int(sets.get("n_samples", 0))
    level = float(sets.get("band_level", 0.95))
    if n < 0 or n != sets.get("n_samples", 0):
        raise BifidInputError("--set n_samples=N needs a non-negative integer.")
    if not 0 < level < 1:
        raise BifidInputError(f"--set band_level must be in (0, 1), got {level}.")
    return {"n_samples": n, "band_level": level, "seed": int(sets.get("seed", 0))}


def _mode(options: dict[str, Any]) -> str:
    flags = [k for k in ("frc", "scurve", "backbone") if options.get(k)]
    if len(flags) > 1:
        raise BifidInputError("give only one of --frc, --scurve, --backbone.")
    if flags:
        return flags[0]
    if options.get("forcing") is not None:
        return "frc"
    if options.get("omega") is not None:
        return "scurve"
    if options.get("amplitude_range") is not None:
        return "backbone"
    raise BifidInputError(
        "say what to predict: --frc --forcing F [--omega-range A B], --scurve --omega W "
        "[--forcing-range A B] or --backbone [--amplitude-range A B]."
    )


def predict_forced_kernel(model_dir: Path, options: dict[str, Any]) -> dict[str, Any]:
    """``bifid predict`` handler of ``forced_kernel`` models (keys of frc/scurve/backbone)."""
    from bifid.identify.forced_kernel import ForcedKernelModel

    model = ForcedKernelModel.load(model_dir)
    mode = _mode(options)
    band = _band_options(options.get("sets") or {})
    n_points = int(options.get("n_points") or 100)
    payload: dict[str, Any] = {"model": str(model_dir), "type": "forced_kernel",
                               "observed": "y", "mode": mode}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if mode == "frc":
            if options.get("forcing") is None:
                raise BifidInputError("--frc needs --forcing F.")
            br = model.frc(options["forcing"], options.get("omega_range"), **band)
            payload.update(
                points=[{"omega": br.params[i], "amplitude": br.data["observed_amplitude"][i],
                         "phase": br.data["phase"][i], "stable": bool(br.stable[i])}
                        for i in range(len(br))],
                folds=[{"omega": sp.param, "amplitude": sp.data["amplitude"]}
                       for sp in br.special("fold")],
                peak={"omega": br.meta["peak"]["omega"],
                      "amplitude": br.meta["peak"]["amplitude"]},
            )
            if band["n_samples"]:
                lo, hi = br.data["band_lower"], br.data["band_upper"]
                payload["band"] = {
                    "level": band["band_level"], "n_samples": band["n_samples"],
                    "lower": [{"omega": lo[i, 0], "amplitude": lo[i, 1]} for i in range(len(br))],
                    "upper": [{"omega": hi[i, 0], "amplitude": hi[i, 1]} for i in range(len(br))],
                }
            xkey, title = "omega", f"forced kernel model: FRC, F = {options['forcing']:g}"
        elif mode == "scurve":
            if options.get("omega") is None:
                raise BifidInputError("--scurve needs --omega W.")
            br = model.scurve(options["omega"], options.get("forcing_range"),
                              n_points=max(n_points, 2), **band)
            pts = []
            for i in range(len(br)):
                pt = {"forcing": br.params[i], "amplitude": br.data["observed_amplitude"][i],
                      "phase": br.data["phase"][i], "stable": bool(br.stable[i])}
                if band["n_samples"]:
                    pt["forcing_lower"], pt["forcing_upper"] = br.data["band_forcing"][i]
                pts.append(pt)
            payload.update(points=pts, folds=[{"forcing": sp.param,
                                               "amplitude": sp.data["amplitude"]}
                                              for sp in br.special("fold")])
            xkey, title = "forcing", f"forced kernel model: S-curve, Ω = {options['omega']:g}"
        else:
            br = model.backbone(options.get("amplitude_range"), n_points=max(n_points, 2),
                                **band)
            pts = []
            for i in range(len(br)):
                pt = {"amplitude": br.params[i], "omega": br.data["omega"][i]}
                if band["n_samples"]:
                    pt["omega_lower"], pt["omega_upper"] = br.data["band_omega"][i]
                pts.append(pt)
            payload.update(points=pts, linear_frequency=model.parameters()["linear_frequency"])
            xkey, title = "omega", "forced kernel model: backbone"
    payload["status"] = br.status
    payload["message"] = br.message
    payload["warnings"] = [str(w.message) for w in caught]
    plot = options.get("plot")
    if plot is not None:
        _plot(br, mode, xkey, title, Path(plot))
        payload["plot"] = str(plot)
    return payload


def _plot(br, mode: str, xkey: str, title: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bifid.io import atomic_path

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    amp = br.data["observed_amplitude"]
    if mode == "backbone":
        ax.plot(br.data["omega"], amp, "k-", lw=1.5, label="model backbone")
        if "band_omega" in br.data:
            ax.fill_betweenx(amp, br.data["band_omega"][:, 0], br.data["band_omega"][:, 1],
                             color="C0", alpha=0.3, label="band")
    else:
        x = br.data[xkey]
        st = br.stable
        for mask, style, lab in ((st, "-", "stable"), (~st, "--", "unstable")):
            ax.plot(np.where(mask, x, np.nan), np.where(mask, amp, np.nan), "C0" + style,
                    lw=1.5, label=lab)
        if "band_lower" in br.data:
            poly = np.concatenate([br.data["band_lower"], br.data["band_upper"][::-1]])
            ax.fill(poly[:, 0], poly[:, 1], color="C0", alpha=0.25, lw=0, label="band")
        if "band_forcing" in br.data:
            ax.fill_betweenx(amp, br.data["band_forcing"][:, 0], br.data["band_forcing"][:, 1],
                             color="C0", alpha=0.25, label="band")
        for sp in br.special("fold"):
            ax.plot(sp.data[xkey], sp.data["amplitude"], "ks", ms=5)
    ax.set_xlabel("forcing frequency Ω [rad/s]" if xkey == "omega" else "forcing amplitude F")
    ax.set_ylabel("amplitude ρ = max|y|")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    suffix = path.suffix or ".png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=suffix.lstrip("."), dpi=130)
    plt.close(fig)


register_predictor("forced_kernel", predict_forced_kernel)
