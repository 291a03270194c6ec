"""Comparison with the truth, figures and ``report.html`` of the flutter demo."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from bifid.demo._checks import FLUTTER_CHECKS as CHECKS
from bifid.demo._report_common import check, finish_report
from bifid.errors import BifidError
from bifid.report.plots import STABLE, UNSTABLE, save_figure
from bifid.signal import aligned_orbit_error

__all__ = ["compare", "write_report"]

SIGNALS = ("h", "alpha")
UNITS = {"h": "m", "alpha": "rad"}


def _diagram_range(truth: dict[str, Any]) -> tuple[float, float]:
    """Speeds of the predicted diagram: below the true cycle fold to above the Hopf point."""
    return (
        float(truth["fold"]["U"]) - 0.6 if truth["fold"] else 14.0,
        float(truth["hopf"]["U"]) + 0.4,
    )


def _intervals(diagram: dict[str, Any], truth: dict[str, Any]) -> list[dict[str, Any]]:
    """The predicted Hopf and fold speeds with their intervals, against the truth."""
    rows = []
    for name, key, true in (
        ("Hopf speed", "hopf", truth["hopf"]["U"]),
        ("cycle-fold speed", "cycle_folds", truth["fold"]["U"] if truth["fold"] else None),
    ):
        points = diagram.get(key) or []
        interval = points[0].get("param_interval") if points else None
        if interval is None or true is None:
            continue
        lo, hi = (float(v) for v in interval)
        rows.append(
            {
                "quantity": name,
                "model": float(points[0]["param"]),
                "interval": [lo, hi],
                "truth": float(true),
                "covered": bool(lo <= true <= hi),
            }
        )
    return rows


def compare(
    model, truth: dict[str, Any], tarr: dict[str, np.ndarray], level: float | None = None
) -> dict[str, Any]:
    """Model predictions against the truth: special points (with their intervals at
    ``level``), amplitudes, frequencies, series; ``diagram`` is the predicted diagram's
    JSON."""

    hopf = model.hopf_point()
    fold = model.cycle_fold()
    diagram = model.predict_diagram(range=_diagram_range(truth), n_points=160, level=level)
    diagram = diagram.to_json()
    pred = {
        "hopf_U": hopf["param"],
        "hopf_omega": hopf["omega"],
        "criticality": hopf["criticality"],
        "fold_U": fold["param"] if fold else None,
        "level": level,
        "intervals": _intervals(diagram, truth) if level is not None else [],
    }
    err: dict[str, Any] = {
        "hopf_U": abs(hopf["param"] - truth["hopf"]["U"]),
        "hopf_omega_rel": abs(hopf["omega"] / truth["hopf"]["omega"] - 1),
        "fold_U": (abs(fold["param"] - truth["fold"]["U"]) if fold and truth["fold"] else math.nan),
    }
    rows = []
    for i, tp in enumerate(truth["test_points"]):
        branch = "stable" if tp["stable"] else "unstable"
        row = {
            "U": tp["U"],
            "branch": branch,
            "truth": {s: tp[s] for s in SIGNALS},
            "truth_omega": tp["omega"],
        }
        try:
            orb = model.predict_orbit(tp["U"], stable=tp["stable"], n_points=256)
            amp = model.predict_amplitude([tp["U"]], stable=tp["stable"])[0]
            names = list(orb.signal_names)
            row["model"] = {s: float(amp[names.index(s)]) for s in SIGNALS}
            row["model_omega"] = 2 * math.pi / orb.period
            row["amplitude_rel"] = max(abs(row["model"][s] / tp[s] - 1) for s in SIGNALS)
            row["frequency_rel"] = abs(row["model_omega"] / tp["omega"] - 1)
            z = np.column_stack([orb.signal(s) for s in SIGNALS])
            row["series_rel"] = aligned_orbit_error(z, tarr["test_orbits"][i])
        except BifidError as exc:  # the model has no such cycle: a failed prediction
            row.update(
                model=None,
                amplitude_rel=math.inf,
                frequency_rel=math.inf,
                series_rel=math.inf,
                note=str(exc),
            )
        rows.append(row)
    for key in ("amplitude_rel", "frequency_rel", "series_rel"):
        err[f"{key}_max"] = max(r[key] for r in rows)
        err[f"{key}_median"] = float(np.median([r[key] for r in rows]))
    checks = {
        "hopf_U": check(err["hopf_U"], CHECKS["hopf_U"], "m/s"),
        "fold_U": check(err["fold_U"], CHECKS["fold_U"], "m/s"),
        "amplitude_rel": check(err["amplitude_rel_max"], CHECKS["amplitude_rel"], ""),
        "frequency_rel": check(err["frequency_rel_max"], CHECKS["frequency_rel"], ""),
        "series_rel": check(err["series_rel_max"], CHECKS["series_rel"], ""),
    }
    return {
        "prediction": pred,
        "errors": err,
        "checks": checks,
        "test_rows": rows,
        "diagram": diagram,
    }


# ------------------------------------------------------------------------------- figures
def diagram_figure(pred: dict[str, Any], data, truth, tarr, path: Path, mech=None) -> Path:
    """Amplitude–speed diagram: truth branch, measured LCOs, the model's branch ``pred``
    (the predicted diagram's JSON) with its amplitude band and the intervals of its Hopf
    and fold speeds (shaded spans) where it has them."""
    fig = Figure(figsize=(11, 4.2))
    axes = fig.subplots(1, 2)
    sel = tarr["stable"].astype(bool)
    for ax, s in zip(axes, SIGNALS, strict=True):
        for st, style in ((True, STABLE), (False, UNSTABLE)):
            m = sel == st
            ax.plot(
                tarr["U"][m],
                tarr[s][m],
                color="k",
                lw=1.2,
                ls=style.get("ls", "-"),
                label=f"truth {'stable' if st else 'unstable'}",
            )
        u = np.array([o["param"] for o in pred["orbits"]])
        a = np.array([o["amplitude"][s] for o in pred["orbits"]])
        stab = np.array([o["stable"] for o in pred["orbits"]])
        for st, color, ls in ((True, "tab:blue", "-"), (False, "tab:red", "--")):
            m = stab == st
            ax.plot(
                u[m],
                a[m],
                color=color,
                ls=ls,
                lw=2,
                alpha=0.85,
                label=f"model {'stable' if st else 'unstable'}",
            )
        _interval_band(ax, pred, s, u, stab)
        if mech is not None and mech["branch"] is not None:
            b = mech["branch"]
            for st, ls in ((True, "-"), (False, "--")):
                m = b["stable"].astype(bool) == st
                ax.plot(
                    np.where(m, b["U"], np.nan),
                    b[s],
                    color="tab:green",
                    ls=ls,
                    lw=1.4,
                    alpha=0.9,
                    label="mechanistic fit" if st else None,
                )
        U = data["param"].values
        amp = (
            data[f"extra_amp_{s}"].values
            if f"extra_amp_{s}" in data
            else data["amplitude"].sel(signal=s).values
        )
        lab = data["stable"].values
        for code, style in (
            (1, {"color": "tab:blue", "mec": "k", "label": "measured (stable)"}),
            (0, {"mfc": "white", "mec": "tab:red", "mew": 1.8, "label": "measured (unstable)"}),
        ):
            ax.plot(U[lab == code], amp[lab == code], "o", ms=7, **style)
        ax.plot(truth["hopf"]["U"], 0, "k^", ms=8)
        ax.plot(
            pred["hopf"][0]["param"] if pred["hopf"] else np.nan,
            0,
            "^",
            color="tab:orange",
            ms=8,
            label="Hopf: model",
        )
        ax.set_xlabel("wind speed U [m/s]")
        ax.set_ylabel(f"amplitude max|{s}| [{UNITS[s]}]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[0].set_title("heave")
    axes[1].set_title("pitch")
    level = pred.get("level")
    band = f"shaded: {level:.0%} intervals" if level else "no intervals"
    fig.suptitle(f"flutter: measured LCOs (virtual PP-CBC), hybrid model ({band}), truth")
    fig.tight_layout()
    return save_figure(fig, path)


def _interval_band(ax, pred: dict[str, Any], s: str, u: np.ndarray, stab: np.ndarray) -> None:
    """The amplitude band of each predicted branch and the Hopf / fold speed intervals."""
    band = np.array(
        [(o.get("amplitude_interval") or {}).get(s, (np.nan, np.nan)) for o in pred["orbits"]],
        dtype=float,
    ).reshape(-1, 2)
    for st, color in ((True, "tab:blue"), (False, "tab:red")):
        m = stab == st
        if np.any(np.isfinite(band[m])):
            ax.fill_between(u[m], band[m, 0], band[m, 1], color=color, alpha=0.18, lw=0)
    for key, color in (("hopf", "tab:orange"), ("cycle_folds", "tab:purple")):
        for point in pred.get(key) or []:
            if point.get("param_interval"):
                ax.axvspan(*point["param_interval"], color=color, alpha=0.12, lw=0)


def portraits_figure(model, data, path: Path, n_panels: int = 3) -> Path:
    """Measured orbits (samples) beside the model's cycles at the measured speeds."""
    from bifid.data import lco_records

    recs = lco_records(data)
    speeds = sorted({round(float(r.param), 6) for r in recs})
    pick = [speeds[i] for i in np.unique(np.linspace(0, len(speeds) - 1, n_panels).astype(int))]
    fig = Figure(figsize=(4.2 * len(pick), 3.9))
    axes = fig.subplots(1, len(pick), squeeze=False)
    for ax, U in zip(axes[0], pick, strict=True):
        for r in recs:
            if abs(r.param - U) > 1e-6:
                continue
            st = bool(r.stable)
            n = min(len(r.signals), int(3 * 2 * np.pi / max(r.frequency, 1e-9) * r.sample_rate))
            ax.plot(
                r.signals[:n, 0],
                r.signals[:n, 1],
                ".",
                ms=1.2,
                color="tab:blue" if st else "tab:red",
                alpha=0.35,
            )
            try:
                orb = model.predict_orbit(U, stable=st)
                h, a = orb.signal("h"), orb.signal("alpha")
                ax.plot(np.r_[h, h[0]], np.r_[a, a[0]], color="k", lw=1.4, ls="-" if st else "--")
            except BifidError:
                pass
        ax.set_title(f"U = {U:.4g} m/s")
        ax.set_xlabel("h [m]")
        ax.set_ylabel("α [rad]")
        ax.grid(alpha=0.3)
    fig.suptitle("phase portraits: measured samples (blue stable, red unstable), model (black)")
    fig.tight_layout()
    return save_figure(fig, path)


def series_figure(model, truth, tarr, rows, path: Path) -> Path:
    """One period at untrained speeds, model against truth (phase-aligned)."""
    mid = sorted({r["U"] for r in rows})
    U = mid[len(mid) // 2]
    fig = Figure(figsize=(11, 5.6))
    axes = fig.subplots(2, 2, sharex=True)
    for j, branch in enumerate(("stable", "unstable")):
        i = next((k for k, r in enumerate(rows) if r["U"] == U and r["branch"] == branch), None)
        if i is None or rows[i].get("model") is None:
            continue
        orb = model.predict_orbit(U, stable=branch == "stable", n_points=256)
        names = list(orb.signal_names)
        z = orb.signals
        tz = tarr["test_orbits"][i]
        n = z.shape[0]
        c = np.fft.rfft(tz, axis=0)
        tzr = np.fft.irfft(c[: min(c.shape[0], n // 2 + 1)], n=n, axis=0) * (n / tz.shape[0])
        best = np.argmax([np.dot(np.roll(tzr[:, 0], s), z[:, names.index("h")]) for s in range(n)])
        tzr = np.roll(tzr, best, axis=0)
        phase = np.linspace(0, 1, n, endpoint=False)
        for k, s in enumerate(SIGNALS):
            ax = axes[k, j]
            ax.plot(phase, tzr[:, k], "k", lw=2, label="truth")
            ax.plot(phase, z[:, names.index(s)], "--", color="tab:orange", lw=1.6, label="model")
            ax.set_ylabel(f"{s} [{UNITS[s]}]")
            ax.grid(alpha=0.3)
            if k == 0:
                ax.set_title(
                    f"{branch} LCO at untrained U = {U:.4g} m/s (error {rows[i]['series_rel']:.1%})"
                )
        axes[1, j].set_xlabel("t / T")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


# ------------------------------------------------------------------------------- report
def write_report(
    out: Path, summary, model, data, truth, tarr, errors, cfg, mech=None, *, run_time: float
) -> Path:
    """Figures (PNG) and the self-contained ``report.html``."""
    from dataclasses import asdict

    from bifid.report.html import Report

    figs = {
        "diagram": diagram_figure(errors["diagram"], data, truth, tarr, out / "diagram.png", mech),
        "portraits": portraits_figure(model, data, out / "portraits.png"),
        "series": series_figure(model, truth, tarr, errors["test_rows"], out / "series.png"),
    }
    c = summary["campaign"]
    p = errors["prediction"]
    rep = Report(
        "bifid demo: flutter rig — experiment, identification, prediction",
        intro=(
            f"A virtual PP-CBC experiment on the flutter rig ({cfg.sample_rate:.0f} Hz, "
            f"noise {cfg.noise_fraction:.0%} of each channel's amplitude) measured "
            f"{c['n_lcos']} limit cycles ({c['n_stable']} stable, {c['n_unstable']} "
            f"unstable). The hybrid normal-form + neural-network model trained on them "
            f"predicts the Hopf point at U = {p['hopf_U']:.3f} m/s (truth "
            f"{truth['hopf']['U']:.3f}) and the fold of cycles at U = "
            f"{_num(p['fold_U'])} m/s (truth {_num(truth['fold']['U'])}). "
            f"{sum(v['passed'] for v in errors['checks'].values())} of "
            f"{len(errors['checks'])} checks pass."
        ),
    )
    _prediction_section(rep, figs, errors)
    _experiment_section(rep, figs, data, truth, summary)
    if mech is not None:
        _mechanistic_section(rep, mech, cfg, truth)
    return finish_report(rep, out, model, summary, {"demo": "flutter", **asdict(cfg)}, run_time)


def _prediction_section(rep, figs, errors) -> None:
    """Checks against the truth, the diagram, and the errors at every test point."""
    sec = rep.section("Prediction against the truth")
    labels = {
        "hopf_U": "Hopf speed error",
        "fold_U": "fold speed error",
        "amplitude_rel": "amplitude error at untrained speeds (max)",
        "frequency_rel": "frequency error at untrained speeds (max)",
        "series_rel": "one-period time-series RMS error (max)",
        "mechanistic_params": "mechanistic fit: k_a2, k_a3 relative error (max)",
        "mechanistic_speeds": "mechanistic fit: Hopf and fold speed error (max)",
    }
    chk = errors["checks"]
    sec.append(
        rep.table(
            ["quantity", "value", "limit"],
            [
                [labels[k], _fmtv(v["value"], v["unit"]), _fmtv(v["limit"], v["unit"])]
                for k, v in chk.items()
            ],
            passed=[v["passed"] for v in chk.values()],
        )
    )
    level = errors["prediction"].get("level")
    intervals = errors["prediction"].get("intervals") or []
    if intervals:
        sec.append(
            rep.text(
                f"Intervals at {level:.0%} (bootstrap of the records' noise and the "
                "ensemble over training seeds; see the uncertainty guide). At this level one "
                "interval in twenty misses the truth by design."
            )
        )
        sec.append(
            rep.table(
                ["quantity", "model [m/s]", f"{level:.0%} interval [m/s]", "truth [m/s]"],
                [
                    [
                        r["quantity"],
                        f"{r['model']:.3f}",
                        f"{r['interval'][0]:.3f} – {r['interval'][1]:.3f}",
                        f"{r['truth']:.3f}",
                    ]
                    for r in intervals
                ],
                passed=[r["covered"] for r in intervals],
            )
        )
    shaded = (
        f"shaded: {level:.0%} intervals of amplitude and of the Hopf (orange) and fold "
        "(purple) speeds"
        if level
        else "no intervals"
    )
    sec.append(
        rep.figure(
            figs["diagram"],
            "Bifurcation diagram: truth (black), measured LCOs "
            f"(dots), hybrid model (blue/red; {shaded}), "
            "mechanistic fit (green).",
        )
    )
    sec.append(rep.text("Per test point (untrained speeds, both branches):"))
    sec.append(
        rep.table(
            [
                "U [m/s]",
                "branch",
                "truth h",
                "model h",
                "truth α",
                "model α",
                "amp. err",
                "freq. err",
                "series err",
            ],
            [
                [
                    r["U"],
                    r["branch"],
                    r["truth"]["h"],
                    (r["model"] or {}).get("h", "—"),
                    r["truth"]["alpha"],
                    (r["model"] or {}).get("alpha", "—"),
                    _pct(r["amplitude_rel"]),
                    _pct(r["frequency_rel"]),
                    _pct(r["series_rel"]),
                ]
                for r in errors["test_rows"]
            ],
        )
    )


def _experiment_section(rep, figs, data, truth, summary) -> None:
    """Portraits, series, and the measured LCOs with the failed attempts."""
    sec = rep.section("Phase portraits and time series")
    sec.append(rep.figure(figs["portraits"], "Measured orbits and the model's cycles."))
    sec.append(rep.figure(figs["series"], "One period at an untrained speed, both branches."))
    sec = rep.section("The virtual experiment")
    sec.append(
        rep.table(
            [
                "U [m/s]",
                "label (switch-off)",
                "label (truth)",
                "h amplitude [m]",
                "error vs truth",
                "invasiveness: control / feedback RMS",
            ],
            _campaign_rows(data, truth),
        )
    )
    fails = summary["campaign"].get("failure_reasons") or []
    sec.append(
        rep.text(
            f"{len(fails)} attempted points did not converge and were not recorded"
            + (":" if fails else ".")
        )
    )
    if fails:
        sec.append(
            rep.table(
                ["U [m/s]", "reason"], [[f.get("param", "?"), f.get("reason", "")] for f in fails]
            )
        )


def _mechanistic_section(rep, mech, cfg, truth) -> None:
    """The whole-diagram update of the same data, or why it failed."""
    if mech["summary"].get("failed"):
        sec = rep.section("Mechanistic identification of the same data (thesis ch. 4)")
        sec.append(
            rep.text(
                "The whole-diagram update of k_a2, k_a3 did not converge: "
                + mech["summary"]["failed"]
            )
        )
    else:
        ms = mech["summary"]
        sec = rep.section("Mechanistic identification of the same data (thesis ch. 4)")
        sec.append(
            rep.text(
                "The physical flutter model with its linear parameters known and the nonlinear "
                "stiffness coefficients started off by "
                f"{cfg.mechanistic_start[0]:g}x and {cfg.mechanistic_start[1]:g}x, updated so that "
                "its continued LCO branch matches every measured LCO (collocation, exact "
                f"gradients, Levenberg-Marquardt): {ms['iterations']} iterations, "
                f"{ms['fit_seconds']:.0f} s, RMS heave misfit {1e3 * ms['rms_start_m']:.3f} -> "
                f"{1e3 * ms['rms_m']:.3f} mm."
            )
        )
        sec.append(
            rep.table(
                ["parameter", "start", "fitted", "true", "error"],
                [
                    [
                        k,
                        ms["start"][k],
                        ms["fitted"][k],
                        ms["true"][k],
                        _pct(ms["param_rel_error"][k]),
                    ]
                    for k in ms["fitted"]
                ]
                + [
                    [
                        "Hopf speed [m/s]",
                        "",
                        ms["hopf_U"],
                        truth["hopf"]["U"],
                        f"{ms['hopf_U_error']:.4f} m/s",
                    ],
                    [
                        "fold speed [m/s]",
                        "",
                        ms["fold_U"],
                        truth["fold"]["U"] if truth["fold"] else "",
                        f"{ms['fold_U_error']:.4f} m/s",
                    ],
                ],
            )
        )


def _campaign_rows(data, truth) -> list[list[Any]]:
    """Each measured LCO against the exact LCOs at its speed: label and amplitude error.

    The measured amplitude is the Fourier-filtered one the rig reports (``extra_amp_h``;
    the raw ``max|h|`` of a noisy record is biased up by the noise).
    """
    rows = []
    key = "extra_amp_h" if "extra_amp_h" in data else "amplitude"
    h = data[key].values if key != "amplitude" else data["amplitude"].sel(signal="h").values
    for k in range(data.sizes["record"]):
        U = float(data["param"].values[k])
        lab = int(data["stable"].values[k])
        cands = [
            (abs(h[k] - m["h"]), m["stable"], m["h"])
            for m in truth.get("measured_speeds", [])
            if abs(m["U"] - U) < 1e-9
        ]
        _, tst, ta = min(cands) if cands else (None, None, math.nan)
        inv = (
            float(data["extra_invasiveness"].values[k])
            if "extra_invasiveness" in data
            else math.nan
        )
        rows.append(
            [
                U,
                {1: "stable", 0: "unstable"}.get(lab, "?"),
                "—" if tst is None else ("stable" if tst else "unstable"),
                float(h[k]),
                _pct(abs(h[k] / ta - 1)) if np.isfinite(ta) else "—",
                _pct(inv),
            ]
        )
    return rows


def _pct(v: float) -> str:
    return "—" if not np.isfinite(v) else f"{100 * v:.2f} %"


def _num(v) -> str:
    return "none" if v is None or not np.isfinite(v) else f"{v:.3f}"


def _fmtv(v: float, unit: str) -> str:
    if unit:
        return f"{v:.4g} {unit}"
    return _pct(v)
