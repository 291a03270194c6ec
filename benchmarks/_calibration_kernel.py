"""Kernel-model replications of ``bench_calibration.py`` (its docstring describes the cases):
one fit on fresh noise, the FRC at an untrained forcing level predicted at every level, and
per quantity (both folds' Ω, the peak's Ω and amplitude) the estimate, the truth and the
intervals."""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np

DUFFING = {"c": 0.0015, "k": 0.0005, "w0": 1.0, "kappa": 0.5}
KERNEL_TRAIN_F, KERNEL_PREDICT_F = (0.007, 0.01), 0.0085
# phase lags [rad] along the predicted FRC where its amplitude interval is checked (the
# quantities "amplitude at lag ..."; kept apart from the special points in the report)
BAND_LAGS = (0.4, 0.8, 1.2, 1.57, 1.9, 2.3, 2.7)
BAND_PREFIX = "amplitude at lag "


def duffing_frc(forcing: float, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact FRC (Ω, ρ) of the averaged Duffing oscillator at phases ψ."""
    g = DUFFING["kappa"] * forcing
    rho = g * np.sin(psi) / DUFFING["c"]
    return DUFFING["w0"] + DUFFING["k"] * rho**2 + g * np.cos(psi) / rho, rho


def duffing_truth(forcing: float) -> dict[str, float]:
    """Folds (local extrema of Ω(ψ)) and peak of the exact FRC on a dense ψ grid."""
    om, rho = duffing_frc(forcing, np.linspace(1e-3, np.pi - 1e-3, 400_001))
    d = np.diff(om)
    folds = np.sort(om[np.nonzero(np.sign(d[:-1]) != np.sign(d[1:]))[0] + 1])
    i = int(np.argmax(rho))
    return {"fold_low": folds[0], "fold_high": folds[-1], "peak": om[i], "peak_amp": rho[i]}


def kernel_replication(noise: float, seed: int, levels: Sequence[float]) -> list[dict]:
    """One kernel-model fit on fresh noise; per quantity the estimate, the truth and the
    intervals at every level."""
    from bifid.identify import ForcedKernelModel

    rng = np.random.default_rng(seed)
    psi = np.linspace(0.12, np.pi - 0.12, 16)
    cols = {"omega": [], "forcing": [], "amplitude": [], "phase": []}
    for f in KERNEL_TRAIN_F:
        om, rho = duffing_frc(f, psi)
        cols["omega"].append(om)
        cols["forcing"].append(np.full(psi.size, f))
        cols["amplitude"].append(rho * (1 + noise * rng.standard_normal(psi.size)))
        cols["phase"].append(np.pi - psi + noise * rng.standard_normal(psi.size))

    model = ForcedKernelModel(forcing_scale=DUFFING["kappa"], observation=False, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(**{k: np.concatenate(v) for k, v in cols.items()})
    truth = duffing_truth(KERNEL_PREDICT_F)
    diagrams = {
        lv: model.predict_diagram(kind="frc", forcing=KERNEL_PREDICT_F, range=(0.95, 1.2), level=lv)
        for lv in levels
    }
    return frc_rows(
        truth, diagrams, lambda lag: duffing_frc(KERNEL_PREDICT_F, np.pi - np.asarray(lag))[1]
    )


# Simulated forced systems: the FRCs of the true ODE by continuation (the truth module of
# bench_forced_kernel.py, cached), fitted as `bifid fit forced` fits them.
KERNEL_ODES = {
    "duffing": {
        "observed": "q",
        "window": (0.8, 1.5),
        "pick": (0.85, 1.3),
        "train": (0.01, 0.02),
        "predict": 0.015,
    },
    "shaw_pierre": {
        "observed": "x1",
        "window": (0.95, 1.05),
        "pick": (0.96, 1.03),
        "train": (0.007, 0.01),
        "predict": 0.0085,
    },
}


# `bifid fit forced --selection loo`: on the Duffing ODE at 1 % noise the marginal
# likelihood's length scales let the high fold drift (errors up to 0.018 in Ω on 8 seeds,
# against 0.003 with leave-one-out); the averaged oscillator is fitted with the default
# (marginal likelihood: 16 of 16 fits with both folds at 1 % noise, 14 with loo)
KERNEL_ODE_FIT = {"selection": "loo"}


def ode_truth(system: str) -> dict[str, float]:
    """Folds (located by continuation) and peak of the true FRC at the untrained forcing."""
    from bench_forced_kernel import true_peak, truth_frc

    cfg = KERNEL_ODES[system]
    d = truth_frc(system, cfg["predict"], cfg["window"])
    folds = np.sort(d["folds"][:, 0])
    if folds.size != 2:
        raise RuntimeError(f"the true FRC of {system} has {folds.size} folds in the window")
    om, amp = true_peak(d)
    return {"fold_low": folds[0], "fold_high": folds[1], "peak": om, "peak_amp": amp}


def ode_amplitude_at(system: str):
    """The true FRC's amplitude as a function of the phase lag (cubic spline)."""
    from scipy.interpolate import CubicSpline

    from bench_forced_kernel import truth_frc

    cfg = KERNEL_ODES[system]
    d = truth_frc(system, cfg["predict"], cfg["window"])
    order = np.argsort(d["phase"])
    lag, amp = np.asarray(d["phase"])[order], np.asarray(d["amplitude"])[order]
    keep = np.concatenate([[True], np.diff(lag) > 0])
    return CubicSpline(lag[keep], amp[keep])


def ode_dataset(system: str, noise: float, seed: int):
    """Two FRCs of the true system (16 points each, spread by arclength, stable and
    unstable) with relative amplitude noise and phase noise (radians) of size ``noise``."""
    import dataclasses

    from bench_forced_kernel import arclength_pick, records_from_truth, truth_frc
    from bifid.data import forced_dataset

    cfg = KERNEL_ODES[system]
    rng = np.random.default_rng(seed)
    recs = []
    for c, f in enumerate(cfg["train"]):
        d = truth_frc(system, f, cfg["window"])
        for r in records_from_truth(d, arclength_pick(d, 16, cfg["pick"]), c):
            amp = r.amplitude * (1 + noise * rng.standard_normal())
            recs.append(
                dataclasses.replace(r, amplitude=amp, phase=r.phase + noise * rng.standard_normal())
            )
    obs = cfg["observed"]
    return forced_dataset(recs, [obs], observed=obs, system=system, source="bench_calibration")


def ode_kernel_replication(
    system: str, noise: float, seed: int, levels: Sequence[float]
) -> list[dict]:
    """One kernel-model fit (``bifid fit forced --selection loo``) on fresh noise; per
    quantity the estimate, the truth and the intervals at every level."""
    from bifid.identify import ForcedKernelModel

    model = ForcedKernelModel(seed=seed, **KERNEL_ODE_FIT)
    cfg = KERNEL_ODES[system]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(ode_dataset(system, noise, seed))
        diagrams = {
            lv: model.predict_diagram(
                kind="frc", forcing=cfg["predict"], range=cfg["window"], level=lv
            )
            for lv in levels
        }
    return frc_rows(ode_truth(system), diagrams, ode_amplitude_at(system))


def frc_rows(truth: dict[str, float], diagrams: dict, amplitude_at=None) -> list[dict]:
    """Rows of the FRC's two folds (Ω) and peak (Ω, amplitude), ``diagrams`` by level; with
    ``amplitude_at(lag)`` (the true amplitude at a phase lag) also the predicted amplitude
    and its interval at each of ``BAND_LAGS`` inside the predicted curve."""
    rows = {k: {"quantity": k, "truth": float(v), "intervals": {}} for k, v in truth.items()}
    for lv, d in diagrams.items():
        folds = sorted(d.special("fold"), key=lambda sp: sp.param)
        (peak,) = d.special("peak")
        if len(folds) != 2:
            raise RuntimeError(f"{len(folds)} folds predicted (2 exist)")
        pts = {"fold_low": folds[0], "fold_high": folds[-1], "peak": peak}
        for k, sp in pts.items():
            rows[k]["estimate"] = float(sp.param)
            rows[k]["intervals"][str(lv)] = [float(x) for x in sp.intervals["param"]]
        rows["peak_amp"]["estimate"] = float(np.ravel(peak.data["amplitude"])[0])
        lo, hi = peak.intervals["amplitude"]
        rows["peak_amp"]["intervals"][str(lv)] = [float(lo[0]), float(hi[0])]
        if amplitude_at is not None:
            rows.update(band_rows(d.branches[0], str(lv), amplitude_at, rows))
    from bifid.identify.forced_kernel._uncertainty import (
        BAND_DOF,
        BAND_SCALE,
        ERROR_DOF,
        ERROR_SCALE,
    )

    for k, row in rows.items():  # the shape the intervals were made with (tuning reads it)
        band = k.startswith(BAND_PREFIX)
        row["shape"] = [BAND_SCALE, BAND_DOF] if band else [ERROR_SCALE, ERROR_DOF]
    return list(rows.values())


def band_rows(branch, level: str, amplitude_at, rows: dict) -> dict:
    """The branch's amplitude and its interval at ``level``, interpolated in the phase lag
    at each of ``BAND_LAGS`` the branch covers, as rows (``rows``: those made so far)."""
    lag = np.asarray(branch.data["phase"], dtype=float)
    order = np.argsort(lag)
    lag = lag[order]
    amp = np.asarray(branch.data["amplitude"], dtype=float)[order, 0]
    lo, hi = (np.asarray(v, dtype=float)[order, 0] for v in branch.intervals["amplitude"])
    out = {}
    for at in BAND_LAGS:
        if not lag[0] < at < lag[-1]:
            continue
        key = f"{BAND_PREFIX}{at:g}"
        row = rows.get(key) or {
            "quantity": key,
            "truth": float(amplitude_at(at)),
            "estimate": float(np.interp(at, lag, amp)),
            "intervals": {},
        }
        row["intervals"][level] = [float(np.interp(at, lag, lo)), float(np.interp(at, lag, hi))]
        out[key] = row
    return out


# the shape of the kernel intervals (their scaled Student t) was fitted on three sets of
# seeds, 0.., 100 000.. and 200 000.. (+1000 per case; ``bench_calibration.py
# --tune-kernel``); the reported replications use seeds offset from those
KERNEL_TUNE_OFFSETS = (0, 100_000, 200_000)
KERNEL_SEED_OFFSET = 300_000


def kernel_tuning_report(rows: list[dict], levels: Sequence[float]) -> None:
    """Analysis of the tuning runs of the kernel intervals' shape (the kernel cases on the
    seeds offset by each of ``KERNEL_TUNE_OFFSETS``, ``bench_calibration.py --tune-kernel``):
    prints the maximum-likelihood scaled Student t of the errors over the standard errors
    (``|q̂ - q| / s``, ``s`` read back from the 95 % half widths with the shape in use) and
    its coverage per level, against the shape in use — for the special points
    (``ERROR_SCALE``, ``ERROR_DOF``), and apart for the amplitudes along the FRC
    (``BAND_PREFIX`` quantities; ``BAND_SCALE``, ``BAND_DOF``). The rows must have been made
    with the shapes in use."""
    from bifid.identify.forced_kernel import _uncertainty as u

    ok = [r for r in rows if "failed" not in r]
    band = [r["quantity"].startswith(BAND_PREFIX) for r in ok]
    for name, part, shape in (
        ("special points", [r for r, b in zip(ok, band, strict=True) if not b], u._SPECIAL),
        ("amplitudes along the FRC", [r for r, b in zip(ok, band, strict=True) if b], u._BAND),
    ):
        if part:
            print(f"-- {name}")
            _shape_fit(part, levels, shape)


def _shape_fit(ok: list[dict], levels: Sequence[float], shape: tuple[float, float]) -> None:
    import scipy.optimize
    import scipy.stats

    scale, dof_use = shape
    iv = np.array([r["intervals"]["0.95"] for r in ok])
    made = np.array([r.get("shape", shape) for r in ok], dtype=float)
    se = 0.5 * (iv[:, 1] - iv[:, 0]) / (made[:, 0] * scipy.stats.t.ppf(0.975, made[:, 1]))
    z = np.abs([r["estimate"] - r["truth"] for r in ok]) / se
    z = z[np.isfinite(z)]

    def nll(p: np.ndarray) -> float:
        return -float(np.sum(scipy.stats.t.logpdf(z / np.exp(p[0]), np.exp(p[1])) - p[0]))

    c, dof = np.exp(scipy.optimize.minimize(nll, np.log([0.5, 3.0]), method="Nelder-Mead").x)
    print(f"{len(z)} trials: fitted c = {c:.3f}, dof = {dof:.2f}")
    print(f"in use: c = {scale}, dof = {dof_use}")
    for lv in levels:
        q_use = scale * scipy.stats.t.ppf(0.5 + lv / 2, dof_use)
        q_fit = c * scipy.stats.t.ppf(0.5 + lv / 2, dof)
        print(
            f"level {lv}: coverage {np.mean(z <= q_use):.3f} in use, "
            f"{np.mean(z <= q_fit):.3f} fitted"
        )


def band_lines(table: dict, levels: Sequence[float]) -> list[str]:
    """Markdown lines of the coverage ``table`` of the amplitude intervals along the
    predicted FRCs (the ``BAND_PREFIX`` quantities, not pooled with the special points)."""
    cells = [table["levels"][str(lv)] for lv in levels]
    return [
        f"Along the predicted FRC ({table['n_trials']} trials: the amplitude at phase lags "
        f"{', '.join(f'{x:g}' for x in BAND_LAGS)} rad, where the curve reaches them):",
        "",
        "| nominal | " + " | ".join(f"{lv:.0%}" for lv in levels) + " |",
        "|---" * (len(levels) + 1) + "|",
        "| empirical | " + " | ".join(f"{c['rate']:.3f}" for c in cells) + " |",
        "| binomial p | " + " | ".join(f"{c['p_value']:.2g}" for c in cells) + " |",
        "",
    ]
