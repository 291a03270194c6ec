"""``bifid demo forced``: CBC S-curves → kernel model → FRCs and backbone vs the truth.

1. **truth** -- FRCs of ``shaw_pierre`` at the test forcing levels and its backbone by
   continuation (``truth.json``/``truth.npz``).
2. **campaign** -- virtual CBC S-curves (thesis §3.2: Picard on the higher harmonics,
   forcing update, arclength round the folds) at a few frequencies, with measurement noise,
   each point written to ``dataset.nc`` as it converges.
3. **model** -- the kernel model of the reduced dynamics on the SSM (thesis ch. 6).
4. **compare** -- predicted FRCs (with 95 % intervals) at the test forcing levels: peak
   amplitude and fold frequencies; the backbone (kept in ``comparison.json`` and
   ``prediction_*.nc``); figures and ``report.html``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bifid.demo._cache import settings_key
from bifid.demo._runner import DemoRun, PointCounter, run_demo
from bifid.errors import ConvergenceError, ConvergenceWarning

__all__ = ["ForcedDemoSettings", "run_forced_demo"]


@dataclass(frozen=True)
class ForcedDemoSettings:
    """What the forced demo does (every field enters the cache keys of its stages)."""

    omegas: tuple[float, ...] = (0.97, 0.98, 0.99, 1.0, 1.005, 1.01)
    forcing_range: tuple[float, float] = (0.001, 0.014)
    test_forcings: tuple[float, ...] = (0.004, 0.008, 0.011)
    omega_range: tuple[float, float] = (0.95, 1.06)
    backbone_range: tuple[float, float] = (0.005, 5.0)
    noise_fraction: float = 0.0
    seed: int = 0
    model: dict[str, Any] = field(default_factory=lambda: {"seed": 0})

    def stage_settings(self) -> dict[str, dict[str, Any]]:
        d = asdict(self)
        return {
            "truth": {
                k: d[k]
                for k in (
                    "test_forcings",
                    "omega_range",
                    "omegas",
                    "forcing_range",
                    "backbone_range",
                )
            },
            "campaign": {k: d[k] for k in ("omegas", "forcing_range", "noise_fraction", "seed")},
            "model": dict(d["model"]),
        }


def run_forced_demo(
    out: Path,
    settings: ForcedDemoSettings | None = None,
    *,
    refresh: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Run (or reuse) the truth, campaign, model and comparison stages of the forced demo
    and write ``out/report.html``; returns the summary (reuse and BLAS threads as in
    :func:`~bifid.demo.run_flutter_demo`)."""
    cfg = settings or ForcedDemoSettings()
    stages = ["truth", "campaign", "model", "compare"]
    return run_demo(out, stages, lambda run: _run(run, cfg), refresh=refresh, progress=progress)


def _run(run: DemoRun, cfg: ForcedDemoSettings) -> dict[str, Any]:
    from bifid.demo._truth import forced_truth

    out, cache, bar, timings = run.out, run.cache, run.bar, run.timings
    st = cfg.stage_settings()
    keys = {"truth": settings_key(st["truth"])}
    keys["campaign"] = settings_key(st["campaign"])
    keys["model"] = settings_key({**st["model"], "campaign": keys["campaign"]})
    keys["compare"] = settings_key(
        {"omega_range": cfg.omega_range, "truth": keys["truth"], "model": keys["model"]}
    )
    truth, tarr = run.truth(
        keys["truth"],
        lambda: forced_truth(
            out,
            cfg.test_forcings,
            cfg.omega_range,
            cfg.backbone_range,
            cfg.omegas,
            (0.0, cfg.forcing_range[1]),
        ),
    )

    bar.start("campaign", "virtual CBC S-curves")

    def campaign() -> dict[str, Any]:
        # noise relative to the smallest response measured (the S-curves' start)
        noise = cfg.noise_fraction * float(np.min(tarr["frc0_amplitude"]))
        n, fails = _campaign(out / "dataset.nc", cfg, noise, bar)
        return {"noise": noise, "n_points": n, "failures": fails}

    timings["campaign"], data = cache.dataset(keys["campaign"], campaign)

    bar.start("model", "fitting the kernel model")
    from bifid.identify.forced_kernel import ForcedKernelModel

    timings["model"], model = cache.model(
        keys["model"], ForcedKernelModel, cfg.model, data, {"demo": "forced", **st["model"]}
    )

    bar.start("compare", "predictions, figures, report")
    from bifid.demo._forced_report import (
        compare,
        load_comparison,
        save_comparison,
        write_report,
    )

    timings["compare"] = cache.ensure(
        "compare",
        keys["compare"],
        ["comparison.json", *cache.info("compare").get("files", [])],
        lambda: save_comparison(out, compare(model, truth, tarr, cfg)),
    )
    result = load_comparison(out)
    info = cache.info("campaign")
    summary = {
        "system": "shaw_pierre",
        "stages_reused": list(cache.reused),
        "campaign": {
            "n_points": int(data.sizes["record"]),
            "n_curves": len(np.unique(data["curve"].values)),
            "omegas": list(cfg.omegas),
            "noise": info.get("noise"),
            "failures": len(info.get("failures", []) or []),
            "seconds": info.get("seconds", math.nan),
        },
        "prediction": result["prediction"],
        "errors": result["errors"],
        "checks": result["checks"],
        "timings_s": timings,
    }
    write_report(
        out,
        summary,
        model,
        data,
        truth,
        tarr,
        result,
        cfg,
        run_time=run.elapsed(),
    )
    return summary


def _campaign(path: Path, cfg: ForcedDemoSettings, noise: float, bar) -> tuple[int, list]:
    """One CBC S-curve per frequency (:func:`bifid.cbc.forced_campaign`), gathered in one
    dataset at ``path`` (the curves numbered in order)."""
    from bifid.cbc import forced_campaign
    from bifid.data import combine_datasets, save_dataset

    on_point = PointCounter(path, bar, lambda pt, n: f"Ω={pt.omega:.4g}: {n} points")

    datasets, failures = [], []
    with warnings.catch_warnings():
        # failures are returned, recorded in the manifest and counted in the report
        warnings.simplefilter("ignore", ConvergenceWarning)
        for k, omega in enumerate(cfg.omegas):
            result = forced_campaign(
                "shaw_pierre",
                "scurve",
                omega=omega,
                span=cfg.forcing_range,
                noise=noise if noise > 0 else None,
                seed=cfg.seed + k,
                on_point=on_point,
            )
            failures += [f.to_json() for f in result.failures]
            if result.dataset is not None:
                datasets.append(result.dataset)
    if on_point.count == 0:
        raise ConvergenceError("the virtual CBC campaign converged no point at all.")
    save_dataset(combine_datasets(datasets), path)
    return on_point.count, failures
