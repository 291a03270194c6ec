"""``bifid demo flutter``: experiment → identification → prediction → comparison.

1. **truth** -- continuation of the flutter model (Appendix A): Hopf point, cycle fold,
   the orbit branch, exact orbits at the test speeds (``truth.json``/``truth.npz``).
2. **campaign** -- a virtual PP-CBC experiment on the flutter rig (5 kHz sampling, zero-order
   hold, measurement noise of 1 % of each channel's typical LCO amplitude): stable and
   unstable LCOs at each wind speed, each written to ``dataset.nc`` as it converges.
3. **model** -- the hybrid normal-form + neural-network model (thesis ch. 5) trained on
   the campaign (``model/``).
4. **compare** -- predicted Hopf and fold speeds, amplitudes and frequencies at *untrained*
   speeds on both branches, and one-period time series, against the truth; figures and
   ``report.html``.

Stages are cached by their settings (:mod:`bifid.demo._cache`).
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bifid.demo._cache import settings_key
from bifid.demo._checks import FLUTTER_CHECKS as CHECKS
from bifid.demo._report_common import check
from bifid.demo._runner import DemoRun, PointCounter, run_demo
from bifid.errors import ConvergenceError, ConvergenceWarning

__all__ = ["FlutterDemoSettings", "run_flutter_demo"]


@dataclass(frozen=True)
class FlutterDemoSettings:
    """What the flutter demo does (every field enters the cache keys of its stages)."""

    speeds: tuple[float, ...] = (15.0, 15.5, 16.0, 16.5, 17.0, 17.5, 17.75)
    noise_fraction: float = 0.01
    sample_rate: float = 5000.0
    seed: int = 0
    truth_range: tuple[float, float] = (14.0, 20.0)
    # untrained test speeds: (U, stable)
    test_points: tuple[tuple[float, bool], ...] = (
        (15.25, True),
        (15.75, True),
        (16.25, True),
        (16.75, True),
        (17.25, True),
        (15.25, False),
        (15.75, False),
        (16.25, False),
        (16.75, False),
        (17.25, False),
    )
    model: dict[str, Any] = field(default_factory=lambda: {"n_ensemble": 3, "seed": 0})
    # level of the model's intervals (Hopf and fold speeds, amplitude band); None: none
    level: float | None = 0.95
    # mechanistic fit (ch. 4): k_a2, k_a3 from a start off by these factors
    mechanistic: bool = True
    mechanistic_start: tuple[float, float] = (1.3, 0.7)

    def stage_settings(self) -> dict[str, dict[str, Any]]:
        d = asdict(self)
        truth = {
            "range": d["truth_range"],
            "tests": d["test_points"],
            "n_mesh": 64,
            "speeds": d["speeds"],
        }
        campaign = {k: d[k] for k in ("speeds", "noise_fraction", "sample_rate", "seed")}
        mech = {"on": d["mechanistic"], "start": d["mechanistic_start"], "free": ["ka2", "ka3"]}
        return {
            "truth": truth,
            "campaign": campaign,
            "model": {**d["model"], "uncertainty": d["level"] is not None},
            "mechanistic": mech,
        }


def run_flutter_demo(
    out: Path,
    settings: FlutterDemoSettings | None = None,
    *,
    refresh: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Run (or reuse) the truth, campaign, model, mechanistic and comparison stages of the
    flutter demo and write ``out/report.html``; returns the summary.

    Stages whose settings did not change are reused (``refresh``: run them all again).
    BLAS runs on one thread throughout: the stages factorise small matrices thousands of
    times, which a thread pool slows down many times on a loaded machine.
    """
    cfg = settings or FlutterDemoSettings()
    mech = ["mechanistic"] if cfg.mechanistic else []
    stages = ["truth", "campaign", "model", *mech, "compare"]
    return run_demo(out, stages, lambda run: _run(run, cfg), refresh=refresh, progress=progress)


def _run(run: DemoRun, cfg: FlutterDemoSettings) -> dict[str, Any]:
    from bifid.demo._truth import flutter_truth

    out, cache, bar, timings = run.out, run.cache, run.bar, run.timings
    st = cfg.stage_settings()
    keys = {"truth": settings_key(st["truth"])}
    # the campaign uses the truth only for its noise levels (branch amplitudes over the range)
    keys["campaign"] = settings_key({**st["campaign"], "truth_range": cfg.truth_range})
    keys["model"] = settings_key({**st["model"], "campaign": keys["campaign"]})
    keys["mechanistic"] = settings_key({**st["mechanistic"], "campaign": keys["campaign"]})

    # 1. ground truth
    truth, tarr = run.truth(
        keys["truth"],
        lambda: flutter_truth(out, cfg.truth_range, cfg.test_points, measured_speeds=cfg.speeds),
    )

    # 2. virtual experiment
    bar.start("campaign", "virtual PP-CBC experiment")

    def campaign() -> dict[str, Any]:
        noise = _noise_levels(tarr, cfg)
        n, fails = _campaign(out / "dataset.nc", cfg, noise, bar)
        return {"noise": noise, "n_points": n, "failures": fails}

    timings["campaign"], data = cache.dataset(keys["campaign"], campaign)

    # 3. identification
    bar.start("model", "training the hybrid model")
    from bifid.identify.hopf_hybrid import HopfHybridModel

    timings["model"], model = cache.model(
        keys["model"],
        HopfHybridModel,
        cfg.model,
        data,
        {"demo": "flutter", **st["model"]},
        fit_options={"uncertainty": st["model"]["uncertainty"]},
    )

    # 3b. mechanistic identification of the same data (thesis ch. 4)
    mech = None
    if cfg.mechanistic:
        from bifid.demo._mechanistic import (
            fit_mechanistic,
            load_mechanistic,
            write_mechanistic_failure,
        )

        bar.start("mechanistic", "whole-diagram update of k_a2, k_a3")

        def mechanistic() -> None:
            try:
                fit_mechanistic(out, data, cfg.mechanistic_start)
            except ConvergenceError as exc:
                # reported in the summary and the report, never hidden; the demo goes on
                write_mechanistic_failure(out, str(exc))

        timings["mechanistic"] = cache.ensure(
            "mechanistic",
            keys["mechanistic"],
            ["mechanistic.json", "mechanistic.npz"],
            mechanistic,
        )
        mech = load_mechanistic(out, truth)

    # 4. comparison, figures, report
    bar.start("compare", "predictions, figures, report")
    t0 = time.perf_counter()
    from bifid.demo._flutter_report import compare, write_report

    errors = compare(model, truth, tarr, cfg.level)
    if mech is not None:
        errors["checks"].update(_mechanistic_checks(mech["summary"]))
    timings["compare"] = time.perf_counter() - t0
    summary = {
        "system": "flutter",
        "stages_reused": list(cache.reused),
        "campaign": _campaign_summary(data, cache.info("campaign")),
        "truth": {
            "hopf_U": truth["hopf"]["U"],
            "fold_U": truth["fold"]["U"] if truth["fold"] else None,
        },
        "prediction": errors["prediction"],
        "errors": errors["errors"],
        "checks": errors["checks"],
        "mechanistic": mech["summary"] if mech else None,
        "timings_s": timings,
    }
    run_time = run.elapsed()
    write_report(out, summary, model, data, truth, tarr, errors, cfg, mech, run_time=run_time)
    return summary


def _mechanistic_checks(ms: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The mechanistic fit's parameters and speeds held to their limits (a failed fit fails)."""
    if ms.get("failed"):
        return {"mechanistic_params": check(math.inf, CHECKS["mechanistic_params_rel"])}
    return {
        "mechanistic_params": check(
            max(ms["param_rel_error"].values()), CHECKS["mechanistic_params_rel"], ""
        ),
        "mechanistic_speeds": check(
            max(ms["hopf_U_error"], ms["fold_U_error"]), CHECKS["mechanistic_U"], "m/s"
        ),
    }


def _noise_levels(tarr: dict[str, np.ndarray], cfg: FlutterDemoSettings) -> dict[str, float]:
    """1 % (``noise_fraction``) of each channel's median LCO amplitude over the speeds."""
    lo, hi = min(cfg.speeds), max(cfg.speeds)
    sel = (tarr["U"] >= lo) & (tarr["U"] <= hi)
    return {k: float(cfg.noise_fraction * np.median(tarr[k][sel])) for k in ("h", "alpha")}


def _campaign(path: Path, cfg: FlutterDemoSettings, noise: dict[str, float], bar) -> tuple:
    """PP-CBC amplitude scans at every speed (:func:`bifid.cbc.ppcbc_campaign`); each point
    written to ``path`` as soon as it converges."""
    from bifid.cbc import ppcbc_campaign

    on_point = PointCounter(
        path,
        bar,
        lambda pt, n: f"U={pt.param:.4g} m/s {'stable' if pt.stable else 'unstable'}: {n} LCOs",
    )

    with warnings.catch_warnings():
        # each failure is also returned, recorded in the manifest and listed in the report
        warnings.simplefilter("ignore", ConvergenceWarning)
        result = ppcbc_campaign(
            "flutter",
            param="U",
            values=cfg.speeds,
            noise=noise,
            seed=cfg.seed,
            rig_options={"sample_rate": cfg.sample_rate},
            out=path,
            on_point=on_point,
        )
    if on_point.count == 0:
        raise ConvergenceError("the virtual PP-CBC campaign converged no LCO at all.")
    return on_point.count, [f.to_json() for f in result.failures]


def _campaign_summary(data, info: dict[str, Any]) -> dict[str, Any]:
    st = np.asarray(data["stable"].values)
    return {
        "n_lcos": int(data.sizes["record"]),
        "n_stable": int(np.sum(st == 1)),
        "n_unstable": int(np.sum(st == 0)),
        "speeds": sorted({round(float(u), 6) for u in data["param"].values}),
        "noise": info.get("noise"),
        "failures": len(info.get("failures", []) or []),
        "failure_reasons": list(info.get("failures", []) or []),
        "seconds": info.get("seconds", math.nan),
    }
