"""Kernel models of forced systems (thesis ch. 6): accuracy, uncertainty and speed.

Run from the repository root::

    .venv/bin/python benchmarks/bench_forced_kernel.py          # writes BENCHMARKS.md
                                                                # section "forced_kernel"
    .venv/bin/python benchmarks/bench_forced_kernel.py --quick  # shaw_pierre only, prints

Ground truth is the continuation of the true systems (``bifid.continuation.frc``,
``scurve``, ``backbone``: Fourier collocation, 32 mesh points), cached in
``out/bench_cache/forced_kernel/`` (delete it to recompute). Figures go to
``docs/figures/forced_kernel_*.png``.

1. ``shaw_pierre`` as thesis §6.3.1: training points on the FRCs at F = 0.01 and 0.007
   (16 each, spread by arclength over 0.96 ≤ Ω ≤ 1.03, stable and unstable); predicted FRCs
   at F = 0.003, 0.006, 0.009, 0.012 against continuation: peak amplitude, fold
   frequencies, coverage of the 95 % amplitude intervals; backbone over the trained
   amplitude range; time series at untrained points. Speed of fit and of one FRC, against
   scikit-learn's GaussianProcessRegressor fitted to the same a/b samples in the same run
   (its FRC solved by the same fixed-phase Newton sweep in numpy/scipy).
2. ``duffing`` (ζ = 0.01, γ = 0.5, hardening): trained at F = 0.005 and 0.01, FRC predicted
   at F = 0.02 (2×); a sparse-data table like §6.3.2: S-curves at 24, 12, 5 frequencies →
   error on three untrained S-curves, on their folds, on the backbone and on the F = 0.02 FRC.
3. The electromagnetic oscillator (``../shared/data/em_oscillator``): fit on one measured
   S-curve, predict the other; measured backbones beside the model's.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bifid  # noqa: F401
from _report import write_section
from bifid.continuation import ContinuationOptions, backbone, frc, scurve
from bifid.data import ForcedRecord, forced_dataset
from bifid.identify import ForcedKernelModel, band_coverage
from bifid.systems import get_system

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "out" / "bench_cache" / "forced_kernel"
FIGS = ROOT / "docs" / "figures"
DATA = ROOT.parent / "shared" / "data" / "em_oscillator"
N_MESH = 32
LEVEL = 0.95  # intervals of every prediction with a band


# ============================================================================ ground truth


def _key(*parts) -> str:
    return "_".join(f"{p:g}" if isinstance(p, float) else str(p) for p in parts)


def truth_frc(system: str, forcing: float, window: tuple[float, float]) -> dict:
    """True FRC (cached): omega, amplitude, phase, stable, orbits (n, M) of the observed
    state on t_k = 2πk/(MΩ), folds (k, 2)."""
    path = CACHE / f"frc_{_key(system, forcing, *window, N_MESH)}.npz"
    if path.exists():
        return dict(np.load(path))
    s = get_system(system)
    br = frc(
        s,
        forcing,
        window,
        n_mesh=N_MESH,
        options=ContinuationOptions(ds=0.005, ds_min=1e-9, ds_max=0.02, max_steps=20000),
    )
    out = _branch_arrays(s, br)
    _save(path, out)
    return out


def truth_scurve(system: str, omega: float, f_range: tuple[float, float]) -> dict:
    path = CACHE / f"scurve_{_key(system, omega, *f_range, N_MESH)}.npz"
    if path.exists():
        return dict(np.load(path))
    s = get_system(system)
    span = f_range[1] - f_range[0]
    br = scurve(
        s,
        omega,
        f_range,
        n_mesh=N_MESH,
        options=ContinuationOptions(
            ds=span / 200, ds_min=span * 1e-9, ds_max=span / 40, max_steps=20000
        ),
    )
    out = _branch_arrays(s, br)
    out["forcing"] = br.data["forcing"]
    _save(path, out)
    return out


def scurve_forcing_range(omega: float) -> tuple[float, float]:
    """Forcing window of a duffing S-curve through both folds: 1.3 × the upper fold's F.

    First-order averaging of ``q'' + 2ζq' + q + γq³ = F cos Ωt`` (ζ = 0.01, γ = 0.5): the
    lower branch folds where ``A (Ω − 1 − 3γA²/8)`` is largest, at ``F ≈ 2Ω · (2/3)(Ω − 1) A``
    with ``A² = 8(Ω − 1)/(9γ)``.
    """
    if omega <= 1.03:
        return (1e-4, 0.03)
    amp = math.sqrt(8 * (omega - 1) / (9 * 0.5))
    f_fold = 2 * omega * (2 / 3) * (omega - 1) * amp
    return (1e-4, round(max(0.03, 1.3 * f_fold), 4))


def truth_backbone(system: str, a_range: tuple[float, float]) -> dict:
    path = CACHE / f"backbone_{_key(system, *a_range, N_MESH)}.npz"
    if path.exists():
        return dict(np.load(path))
    s = get_system(system)
    span = a_range[1] - a_range[0]
    br = backbone(
        s,
        a_range,
        n_mesh=N_MESH,
        options=ContinuationOptions(
            ds=min(a_range[0], span / 100),
            ds_min=1e-9,
            ds_max=span / 100,
            max_steps=20000,
            detect_folds=False,
        ),
    )
    out = {"amplitude": br.data["observed_amplitude"], "omega": br.data["omega"]}
    _save(path, out)
    return out


def _branch_arrays(s, br) -> dict:
    obs = s.state_index(s.observed)
    orbits = br.solutions[:, : N_MESH * s.n_states].reshape(-1, N_MESH, s.n_states)[:, :, obs]
    folds = np.array([[sp.param, sp.data["amplitude"]] for sp in br.special("fold")])
    return {
        "omega": br.data["omega"],
        "amplitude": br.data["observed_amplitude"],
        "phase": br.data["phase"],
        "stable": br.stable.astype(int),
        "orbits": orbits,
        "folds": folds.reshape(-1, 2),
        "forcing": br.data["forcing"],
    }


def _save(path: Path, arrays: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


# ============================================================================ helpers


def arclength_pick(d: dict, n: int, window: tuple[float, float], xkey: str = "omega"):
    """Indices of n points spread by arclength (scaled axes) over the part in ``window``."""
    m = (d[xkey] >= window[0]) & (d[xkey] <= window[1])
    x, a = d[xkey][m], d["amplitude"][m]
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x) / np.ptp(x), np.diff(a) / np.ptp(a)))])
    idx = np.clip(np.searchsorted(s, np.linspace(0, s[-1], n)), 0, len(x) - 1)
    return np.nonzero(m)[0][np.unique(idx)]


def records_from_truth(d: dict, idx, curve: int) -> list[ForcedRecord]:
    recs = []
    for i in idx:
        om, f = float(d["omega"][i]), float(d["forcing"][i])
        M = d["orbits"].shape[1]
        fs = M * om / (2 * np.pi)
        t = np.arange(M) / fs
        recs.append(
            ForcedRecord(
                omega=om,
                forcing=f,
                signals=d["orbits"][i][:, None],
                sample_rate=fs,
                stable=bool(d["stable"][i]),
                force=f * np.cos(om * t),
                amplitude=float(d["amplitude"][i]),
                phase=float(d["phase"][i]),
                curve=curve,
            )
        )
    return recs


def true_peak(d: dict) -> tuple[float, float]:
    """Peak (Ω, A) of a true FRC: parabola in the phase through the 3 highest points."""
    i = int(np.argmax(d["amplitude"]))
    sl = slice(max(i - 1, 0), i + 2)
    p, a, o = d["phase"][sl], d["amplitude"][sl], d["omega"][sl]
    c = np.polyfit(p, a, 2)
    ps = -c[1] / (2 * c[0])
    return float(np.polyval(np.polyfit(p, o, 2), ps)), float(np.polyval(c, ps))


def predicted(model: ForcedKernelModel, **query):
    """The one branch of ``model.predict_diagram(level=LEVEL, **query)``: the curve with
    its calibrated intervals (extrapolation warnings silenced: the tables say where)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return model.predict_diagram(level=LEVEL, **query).branches[0]


def interval_width(br, key: str) -> np.ndarray:
    """Width of a predicted branch's interval ``key`` (``amplitude``: first column)."""
    lo, hi = (np.asarray(v, float) for v in br.intervals[key])
    return (hi - lo)[:, 0] if lo.ndim == 2 else hi - lo


def frc_errors(model: ForcedKernelModel, d: dict, forcing: float, window, intervals: bool):
    t0 = time.perf_counter()
    if intervals:
        br = predicted(model, forcing=forcing, range=window)
    else:
        br = model.frc(forcing, window)
    dt = time.perf_counter() - t0
    po, pa = true_peak(d)
    (peak,) = br.special("peak")
    mf = np.sort([sp.param for sp in br.special("fold")])
    tf = np.sort(d["folds"][:, 0]) if d["folds"].size else np.zeros(0)
    fold_err = (
        float(np.max(np.abs(mf / tf - 1)))
        if mf.size == tf.size and tf.size
        else (0.0 if mf.size == tf.size else float("inf"))
    )
    row = {
        "F": forcing,
        "peak_true": pa,
        "peak_model": peak.data["amplitude"],
        "peak_err": peak.data["amplitude"] / pa - 1,
        "peak_omega_err": peak.param / po - 1,
        "n_folds_true": int(tf.size),
        "n_folds_model": int(mf.size),
        "fold_err": fold_err,
        "time_s": dt,
    }
    if intervals:
        cov = band_coverage(br, d["omega"], d["amplitude"], d["phase"])
        i = int(np.argmax(br.data["observed_amplitude"]))
        row.update(
            coverage=cov["coverage"],
            band_width_peak=float(interval_width(br, "amplitude")[i]),
            band_failed=br.meta["band"]["failed_fraction"],
        )
    return row, br


def pct(x: float, digits: int = 3) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{100 * x:.{digits}f} %"


# ============================================================================ sklearn baseline


def sklearn_baseline(model: ForcedKernelModel, forcing: float, window, psi_grid):
    """sklearn GPs on the same a/b samples as ``model``; FRC by fixed-phase Newton."""
    from scipy.optimize import fsolve
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel

    xb, yb = model.reduced_.gp_b.x_train_, model.reduced_.gp_b.y_train_
    xa, ya = model.reduced_.gp_a.x_train_, model.reduced_.gp_a.y_train_

    def make():
        k = ConstantKernel(1.0, (1e-6, 1e4)) * RBF([1.0, 0.01], (1e-4, 1e3)) + WhiteKernel(
            1e-6, (1e-14, 1e-1)
        )
        return GaussianProcessRegressor(k, normalize_y=True, n_restarts_optimizer=1, random_state=0)

    t0 = time.perf_counter()
    gb = make().fit(xb, yb)
    ga = make().fit(xa, ya)
    fit_s = time.perf_counter() - t0
    g = forcing * model.forcing_scale_
    oc = model.reduced_.omega_c

    def resid(u, psi):
        r, o = u
        x = np.array([[r, o]])
        a = ga.predict(x)[0]
        b = gb.predict(x)[0] + oc
        return [a + g * math.sin(psi), (b - o) * r + g * math.cos(psi)]

    # start from the kernel model's own FRC at each phase (same grid, same solver budget)
    ref = model.frc(forcing, window)
    lag = np.pi - ref.solutions[:, 1]
    order = np.argsort(lag)
    rho0 = np.interp(np.pi - psi_grid, lag[order], ref.solutions[order, 0])
    om0 = np.interp(np.pi - psi_grid, lag[order], ref.params[order])
    t0 = time.perf_counter()
    sol = [
        fsolve(resid, [r0, o0], args=(p,), xtol=1e-10)
        for p, r0, o0 in zip(psi_grid, rho0, om0, strict=True)
    ]
    frc_s = time.perf_counter() - t0
    sol = np.array(sol)
    return {"fit_s": fit_s, "frc_s": frc_s, "peak": float(sol[:, 0].max()), "sol": sol}


# ============================================================================ experiments


def shaw_pierre(quick: bool) -> tuple[dict, ForcedKernelModel, dict]:
    window = (0.95, 1.05)
    pick = (0.96, 1.03)
    train_f, test_f = (0.01, 0.007), (0.003, 0.006, 0.009, 0.012)
    tr = {f: truth_frc("shaw_pierre", f, window) for f in train_f + test_f}
    recs = []
    for c, f in enumerate(train_f):
        recs += records_from_truth(tr[f], arclength_pick(tr[f], 16, pick), c)
    ds = forced_dataset(recs, ["x1"], observed="x1", system="shaw_pierre", source="bench")
    n_unstable = sum(1 for r in recs if r.stable is False)

    model = ForcedKernelModel(forcing_scale="fit")
    t0 = time.perf_counter()
    model.fit(ds)
    first_fit = time.perf_counter() - t0
    fits = []
    for _ in range(1 if quick else 3):
        t0 = time.perf_counter()
        ForcedKernelModel(forcing_scale="fit").fit(ds)
        fits.append(time.perf_counter() - t0)

    rows, branches = [], {}
    for f in test_f + train_f:
        row, br = frc_errors(model, tr[f], f, window, True)
        row["trained"] = f in train_f
        rows.append(row)
        branches[f] = br
    frc_times = []
    for _ in range(3 if quick else 5):
        t0 = time.perf_counter()
        model.frc(0.009, window)
        frc_times.append(time.perf_counter() - t0)
    band_times = []
    for _ in range(1 if quick else 3):
        t0 = time.perf_counter()
        predicted(model, forcing=0.009, range=window)
        band_times.append(time.perf_counter() - t0)

    # backbone over the trained amplitude range
    r_hi = model.rho_range_[1]
    tb = truth_backbone("shaw_pierre", (0.05, r_hi))
    mb = predicted(model, kind="backbone", range=(0.05, r_hi))
    om_m = np.interp(tb["amplitude"], mb.params, mb.data["omega"])
    bb_err = float(np.max(np.abs(om_m / tb["omega"] - 1)))
    shift = float(np.ptp(tb["omega"]))
    bb_err_shift = float(np.max(np.abs(om_m - tb["omega"])) / shift)
    mb_ext = predicted(model, kind="backbone", range=(0.05, 1.5 * r_hi))
    w = interval_width(mb_ext, "omega")
    inside = mb_ext.params <= r_hi
    widen = float(np.median(w[~inside]) / np.median(w[inside]))

    # time series at untrained points (thesis Fig. 6.4: F = 0.005/0.009 near Ω = 1)
    ts_rows = []
    for f, om in ((0.006, 1.002), (0.009, 1.0), (0.003, 0.99), (0.012, 1.01)):
        d = tr[f]
        i = int(np.argmin(np.abs(d["omega"] - om)))
        om_i, y_true = float(d["omega"][i]), d["orbits"][i]
        t = np.arange(y_true.shape[0]) * 2 * np.pi / om_i / y_true.shape[0]
        fp = min(model.fixed_points(om_i, f), key=lambda p: abs(p["rho"] - d["amplitude"][i]))
        y = model.time_series(t, fp["rho"], fp["psi"], om_i)
        ts_rows.append(
            {
                "F": f,
                "omega": om_i,
                "rms_err": float(np.sqrt(np.mean((y - y_true) ** 2)) / np.sqrt(np.mean(y_true**2))),
            }
        )

    # scikit-learn baseline on the same data, same run
    psi_grid = np.linspace(0.05, np.pi - 0.05, 300)
    sk = sklearn_baseline(model, 0.009, window, psi_grid)
    truth_peak = true_peak(tr[0.009])[1]
    res = {
        "n_train": len(recs),
        "n_unstable": n_unstable,
        "kappa": model.forcing_scale_,
        "kappa_info": model.summary()["parameters"]["forcing_scale_fit"],
        "first_fit_s": first_fit,
        "fit_s": statistics.median(fits),
        "frc_s": statistics.median(frc_times),
        "band_frc_s": statistics.median(band_times),
        "rows": rows,
        "backbone_err": bb_err,
        "backbone_err_shift": bb_err_shift,
        "backbone_widening": widen,
        "ts": ts_rows,
        "sk": {"fit_s": sk["fit_s"], "frc_s": sk["frc_s"], "peak_err": sk["peak"] / truth_peak - 1},
        "losses": model.losses_,
        "truth_peak_009": truth_peak,
    }
    figs = {
        "tr": tr,
        "branches": branches,
        "mb": mb,
        "mb_ext": mb_ext,
        "tb": tb,
        "recs": recs,
        "r_hi": r_hi,
    }
    return res, model, figs


SC_OMEGAS = (0.97, 0.99, 1.0, 1.005, 1.01, 1.02, 1.03)  # as `bifid demo forced`
SC_FORCING = (1e-4, 0.012)


def noisy_scurve_records(
    d: dict,
    om: float,
    idx,
    curve: int,
    sigma: float,
    rng,
    sample_rate: float = 100.0,
    periods: float = 3.0,
):
    """Records as a CBC rig measures them: the true orbit sampled at ``sample_rate`` over
    ``periods`` periods plus white noise σ; amplitude (max of the 5-harmonic Fourier
    series) and phase lag from the least-squares Fourier projection, as ``bifid.cbc`` does."""
    recs = []
    grid = np.linspace(0.0, 2 * np.pi, 2048, endpoint=False)

    def design(theta):
        cols = [np.ones_like(theta)]
        for j in range(1, 6):
            cols += [np.cos(j * theta), np.sin(j * theta)]
        return np.stack(cols, axis=1)

    for i in idx:
        f, orb = float(d["forcing"][i]), d["orbits"][i]
        m = orb.shape[0]
        t = np.arange(int(periods * 2 * np.pi / om * sample_rate)) / sample_rate
        ck = np.fft.rfft(orb) / m
        k = np.arange(1, ck.shape[0] - 1)
        y = ck[0].real + 2 * np.sum(
            (ck[None, k] * np.exp(1j * k[None, :] * om * t[:, None])).real, axis=1
        )
        y = y + rng.normal(0.0, sigma, y.shape)
        coef, *_ = np.linalg.lstsq(design(om * t), y, rcond=None)
        amp = float(np.max(np.abs(design(grid) @ coef)))
        lag = (math.atan2(coef[2], coef[1]) + np.pi / 2) % (2 * np.pi) - np.pi / 2
        recs.append(
            ForcedRecord(
                omega=om,
                forcing=f,
                signals=y[:, None],
                sample_rate=sample_rate,
                stable=bool(d["stable"][i]),
                force=f * np.cos(om * t),
                amplitude=amp,
                phase=lag,
                curve=curve,
            )
        )
    return recs


#: noise seeds of the comparison of the two forcing laws on noisy S-curves
SC_SEEDS = (0, 1, 2, 3, 4)
#: untrained forcing levels of the FRCs predicted from the S-curves
SC_TEST_FORCINGS = (0.003, 0.006, 0.009, 0.012)
SC_WINDOW = (0.95, 1.05)


def scurve_dataset(seed: int, n_per_curve: int = 20, noise: float = 0.01):
    """Noisy S-curves of ``shaw_pierre`` at ``SC_OMEGAS`` (noise ``noise`` times the median
    amplitude, drawn with ``seed``): ``(dataset, records, sigma)``."""
    sc = {om: truth_scurve("shaw_pierre", om, SC_FORCING) for om in SC_OMEGAS}
    sigma = noise * float(np.median(np.concatenate([d["amplitude"] for d in sc.values()])))
    rng = np.random.default_rng(seed)
    recs = []
    for c, om in enumerate(SC_OMEGAS):
        idx = arclength_pick(sc[om], n_per_curve, SC_FORCING, xkey="forcing")
        recs += noisy_scurve_records(sc[om], om, idx, c, sigma, rng)
    ds = forced_dataset(recs, ["x1"], observed="x1", system="shaw_pierre", source="bench")
    return ds, recs, sigma


def scurve_laws() -> list[dict]:
    """Both forcing laws (``forcing_frequency="constant"``: Γ = κF; ``"inverse"``:
    Γ = κFΩ̄/Ω) fitted to the noisy S-curves of each of ``SC_SEEDS``: the FRCs at
    ``SC_TEST_FORCINGS`` with their 95 % bands against the truth."""
    out = []
    for seed in SC_SEEDS:
        ds, _, _ = scurve_dataset(seed)
        for law in ("constant", "inverse"):
            model = ForcedKernelModel(forcing_frequency=law).fit(ds)
            for f in SC_TEST_FORCINGS:
                d = truth_frc("shaw_pierre", f, SC_WINDOW)
                row, _ = frc_errors(model, d, f, SC_WINDOW, True)
                out.append({"seed": seed, "law": law, "kappa": model.forcing_scale_, **row})
    return out


def shaw_pierre_scurves() -> tuple[dict, dict]:
    """The setting of `bifid demo forced`: S-curves at 7 frequencies, measurement noise,
    model with default settings; FRCs at untrained forcing levels, backbone, API timings;
    and the two forcing laws over several noise seeds (:func:`scurve_laws`)."""
    import tempfile

    window = SC_WINDOW
    ds, recs, sigma = scurve_dataset(0)
    timing = {}
    t0 = time.perf_counter()
    model = ForcedKernelModel().fit(ds)
    timing["fit_first"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    model = ForcedKernelModel().fit(ds)
    timing["fit"] = time.perf_counter() - t0
    rows = []
    branches = {}
    for f in SC_TEST_FORCINGS:
        row, br = frc_errors(model, truth_frc("shaw_pierre", f, window), f, window, True)
        rows.append(row)
        branches[f] = br
    t0 = time.perf_counter()
    model.frc(0.009, window)
    timing["frc"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    predicted(model, forcing=0.009, range=window)
    timing["frc_band"] = time.perf_counter() - t0
    r_hi = model.rho_range_[1]
    tb = truth_backbone("shaw_pierre", (0.05, 3.29578))
    for key in ("backbone_band_first", "backbone_band"):
        t0 = time.perf_counter()
        mb = predicted(model, kind="backbone", range=(0.05, r_hi))
        timing[key] = time.perf_counter() - t0
    ok = tb["amplitude"] <= r_hi
    om_m = np.interp(tb["amplitude"][ok], mb.params, mb.data["omega"])
    bb_err = float(np.max(np.abs(om_m / tb["omega"][ok] - 1)))
    for key in ("scurve_band_first", "scurve_band"):
        t0 = time.perf_counter()
        predicted(model, omega=1.0, range=(0.0, 0.012))
        timing[key] = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        model.save(Path(tmp) / "m")
        timing["save"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        ForcedKernelModel.load(Path(tmp) / "m")
        timing["load"] = time.perf_counter() - t0
    res = {
        "n_points": len(recs),
        "n_used": model.n_train_,
        "sigma": sigma,
        "kappa": model.forcing_scale_,
        "rho_max": r_hi,
        "rows": rows,
        "backbone_err": bb_err,
        "timing": timing,
        "notes": list(model.notes_),
        "stability_agreement": model.losses_.get("stability_agreement"),
        "laws": scurve_laws(),
    }
    return res, {"branches": branches, "recs": recs}


def duffing(quick: bool) -> tuple[dict, dict]:
    window = (0.8, 1.5)
    train_f, test_f = (0.005, 0.01), 0.02
    tr = {f: truth_frc("duffing", f, window) for f in (*train_f, test_f)}
    recs = []
    for c, f in enumerate(train_f):
        recs += records_from_truth(tr[f], arclength_pick(tr[f], 16, (0.85, 1.2)), c)
    ds = forced_dataset(recs, ["q"], observed="q", system="duffing", source="bench")
    out: dict = {"frc": {}}
    variants = [("fit", "eq6.19"), ("fit", "phase"), (0.5, "eq6.19"), (1.0, "eq6.19")]
    variants.append(("fit", "eq6.19", "inverse"))  # Γ = κFΩ̄/Ω: the S-curves' law, here
    branches = {}
    for fs, at, *law in variants:
        law = law[0] if law else "constant"
        m = ForcedKernelModel(forcing_scale=fs, a_target=at, forcing_frequency=law).fit(ds)
        row, br = frc_errors(m, tr[test_f], test_f, window, True)
        row["kappa"] = m.forcing_scale_
        out["frc"][f"κ={fs}, a: {at}" + ("" if law == "constant" else f", Γ: {law}")] = row
        if law == "constant":
            branches[(fs, at)] = br
    model = ForcedKernelModel(forcing_scale="fit").fit(ds)
    r_hi = model.rho_range_[1]
    tb = truth_backbone("duffing", (0.02, 2 * r_hi))
    mb = predicted(model, kind="backbone", range=(0.02, 2 * r_hi))
    om_m = np.interp(tb["amplitude"], mb.params, mb.data["omega"])
    inside = tb["amplitude"] <= r_hi
    out["backbone_err_trained"] = float(np.max(np.abs(om_m[inside] / tb["omega"][inside] - 1)))
    out["backbone_err_2x"] = float(np.max(np.abs(om_m / tb["omega"] - 1)))
    # time series at untrained points of the F = 0.02 FRC (stable low branch, near the peak)
    out["ts"] = []
    d = tr[test_f]
    for om in (1.0, 1.15):
        i = int(np.argmin(np.abs(d["omega"] - om) + 1e3 * (d["stable"] == 0)))
        om_i, y_true = float(d["omega"][i]), d["orbits"][i]
        t = np.arange(y_true.shape[0]) * 2 * np.pi / om_i / y_true.shape[0]
        fp = min(
            model.fixed_points(om_i, test_f), key=lambda p, a=d["amplitude"][i]: abs(p["rho"] - a)
        )
        y = model.time_series(t, fp["rho"], fp["psi"], om_i)
        out["ts"].append(
            {
                "F": test_f,
                "omega": om_i,
                "amplitude": float(d["amplitude"][i]),
                "rms_err": float(np.sqrt(np.mean((y - y_true) ** 2)) / np.sqrt(np.mean(y_true**2))),
            }
        )
    figs = {
        "tr": tr,
        "branches": branches,
        "recs": recs,
        "tb": tb,
        "mb": mb,
        "trained_br": predicted(model, forcing=train_f[1], range=window),
    }
    if quick:
        return out, figs

    # sparse S-curve table (§6.3.2). As measured by CBC, every S-curve runs from small
    # forcing through its folds (lower stable, unstable, upper stable branch) up to
    # 1.3 × the forcing of its upper fold (first-order averaging estimate), so the
    # resonant branches are in the data; frequencies span the trained backbone.
    grid = np.linspace(0.95, 1.2, 24)
    val = (1.02, 1.11, 1.17)
    f_ranges = {float(o): scurve_forcing_range(float(o)) for o in (*grid, *val)}
    sc = {o: truth_scurve("duffing", o, fr) for o, fr in f_ranges.items()}
    table = []
    for n_curves, idx in ((24, range(24)), (12, range(0, 24, 2)), (5, (0, 6, 12, 17, 23))):
        recs = []
        for c, i in enumerate(idx):
            o = float(grid[i])
            d = sc[o]
            recs += records_from_truth(d, arclength_pick(d, 12, f_ranges[o], xkey="forcing"), c)
        dsc = forced_dataset(recs, ["q"], observed="q", system="duffing", source="bench")
        t0 = time.perf_counter()
        m = ForcedKernelModel(forcing_scale="fit").fit(dsc)
        fit_s = time.perf_counter() - t0
        errs, ferrs = [], []
        for o in val:
            d = sc[o]
            keep = d["amplitude"] > 0.05 * d["amplitude"].max()
            a, b = m.reduced_dynamics(d["amplitude"][keep], o)
            f_m = np.sqrt(a**2 + (b - o) ** 2 * d["amplitude"][keep] ** 2) / m.forcing_scale_
            errs.append(np.sqrt(np.mean((f_m / d["forcing"][keep] - 1) ** 2)))
            br = m.scurve(o, f_ranges[o])
            mf = np.sort([sp.param for sp in br.special("fold")])
            tf = np.sort(d["folds"][:, 0]) if d["folds"].size else np.zeros(0)
            if tf.size:
                ferrs.append(
                    float(np.max(np.abs(mf / tf - 1))) if mf.size == tf.size else float("inf")
                )
        r_hi = m.rho_range_[1]
        tb2 = truth_backbone("duffing", (0.02, r_hi))
        mb2 = m.backbone((0.02, r_hi))
        bb = float(
            np.max(
                np.abs(
                    np.interp(tb2["amplitude"], mb2.params, mb2.data["omega"]) / tb2["omega"] - 1
                )
            )
        )
        row, _ = frc_errors(m, tr[test_f], test_f, window, 0)
        row_in, _ = frc_errors(m, tr[train_f[1]], train_f[1], window, 0)
        table.append(
            {
                "n_curves": n_curves,
                "n_points": len(recs),
                "kappa": m.forcing_scale_,
                "rho_max": r_hi,
                "scurve_rms": float(np.mean(errs)),
                "fold_err": float(np.max(ferrs)) if ferrs else float("nan"),
                "backbone_err": bb,
                "frc_in_peak_err": row_in["peak_err"],
                "frc_in_fold_err": row_in["fold_err"],
                "frc_peak_err": row["peak_err"],
                "frc_fold_err": row["fold_err"],
                "fit_s": fit_s,
            }
        )
    out["sparse"] = table
    figs["sc"] = sc
    return out, figs


def em_oscillator() -> tuple[dict, dict]:
    from bifid.data import em_dataset

    files = {
        k: DATA / f"{k}.mat" for k in ("scurve_16p5Hz", "scurve_16p6Hz", "backbone_1", "backbone_2")
    }
    if not all(p.exists() for p in files.values()):
        return {"skipped": f"{DATA} not found"}, {}
    ds = {k: em_dataset([p]) for k, p in files.items()}

    def scurve_err(m, d):
        om = float(d["omega"].values[0])
        rho = d["amplitude"].values
        f = d["forcing"].values
        ok = rho > 0.05 * rho.max()
        a, b = m.reduced_dynamics(rho[ok], om)
        f_m = np.sqrt(a**2 + (b - om) ** 2 * rho[ok] ** 2) / m.forcing_scale_
        return (
            float(np.sqrt(np.mean((f_m - f[ok]) ** 2)) / np.sqrt(np.mean(f[ok] ** 2))),
            float(np.median(np.abs(f_m / f[ok] - 1))),
        )

    def bb_err(m, d):
        rho, om = d["amplitude"].values, d["omega"].values
        ok = (rho >= max(m.rho_range_[0], 0.05)) & (rho <= m.rho_range_[1])
        mb = m.backbone((rho[ok].min(), rho[ok].max()))
        om_m = np.interp(rho[ok], mb.params, mb.data["omega"])
        return float(np.max(np.abs(om_m / om[ok] - 1))), float(np.median(np.abs(om_m / om[ok] - 1)))

    b1 = ds["backbone_1"]
    small = b1["amplitude"].values > 0.05 * b1["amplitude"].values.max()
    w0 = float(b1["omega"].values[small][0])
    rows = []
    models = {}
    for train, test in (("scurve_16p5Hz", "scurve_16p6Hz"), ("scurve_16p6Hz", "scurve_16p5Hz")):
        for label, kw in (
            ("κ = 1 (Γ = F, thesis)", {"forcing_scale": 1.0}),
            (
                "κ from ω₀ of the measured backbone",
                {"forcing_scale": "fit", "linear_frequency": w0},
            ),
        ):
            for at in ("eq6.19", "phase"):
                m = ForcedKernelModel(a_target=at, **kw).fit(ds[train])
                rows.append(
                    {
                        "train": train,
                        "test": test,
                        "variant": label,
                        "a_target": at,
                        "kappa": m.forcing_scale_,
                        "train_err": scurve_err(m, ds[train])[0],
                        "test_err": scurve_err(m, ds[test])[0],
                        "test_median": scurve_err(m, ds[test])[1],
                        "bb1": bb_err(m, b1)[0],
                        "bb2": bb_err(m, ds["backbone_2"])[0],
                    }
                )
                models[(train, label, at)] = m
    both = ForcedKernelModel(forcing_scale="fit", a_target="phase").fit(
        [ds["scurve_16p5Hz"], ds["scurve_16p6Hz"]]
    )
    res = {
        "rows": rows,
        "w0_hz": w0 / 2 / np.pi,
        "both": {
            "kappa": both.forcing_scale_,
            "bb1": bb_err(both, b1),
            "bb2": bb_err(both, ds["backbone_2"]),
        },
    }
    figs = {"ds": ds, "models": models, "both": both, "w0": w0}
    return res, figs


# ============================================================================ figures


def figures(sp_figs: dict, du_figs: dict, em_figs: dict) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    FIGS.mkdir(parents=True, exist_ok=True)
    made = []

    def curve(ax, x, y, stable, color, label, lw=1.4):
        st = np.asarray(stable, bool)
        ax.plot(
            np.where(st, x, np.nan), np.where(st, y, np.nan), "-", color=color, lw=lw, label=label
        )
        ax.plot(np.where(~st, x, np.nan), np.where(~st, y, np.nan), "--", color=color, lw=lw)

    # ---- shaw_pierre FRCs
    tr, brs = sp_figs["tr"], sp_figs["branches"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [2, 1]})
    ax = axes[0]
    for k, f in enumerate(sorted(brs)):
        c = f"C{k}"
        d = tr[f]
        ax.plot(
            d["omega"],
            d["amplitude"],
            "-",
            color="0.6",
            lw=3.5,
            alpha=0.6,
            label="true (continuation)" if k == 0 else None,
        )
        br = brs[f]
        curve(ax, br.params, br.data["observed_amplitude"], br.stable, c, f"model F = {f:g}")
        for sp in br.special("fold"):
            ax.plot(sp.param, sp.data["amplitude"], "ks", ms=4)
    om = np.array([r.omega for r in sp_figs["recs"]])
    am = np.array([r.amplitude for r in sp_figs["recs"]])
    st = np.array([bool(r.stable) for r in sp_figs["recs"]])
    ax.plot(om[st], am[st], "ko", ms=4, label="training (stable)")
    ax.plot(om[~st], am[~st], "o", mfc="w", mec="k", ms=5, label="training (unstable)")
    mb = sp_figs["mb"]
    ax.plot(mb.data["omega"], mb.params, "k:", lw=1.2, label="model backbone (eq. 6.21)")
    ax.set(
        xlim=(0.96, 1.03),
        xlabel="Ω [rad/s]",
        ylabel="max |x₁|",
        title="shaw_pierre: trained at F = 0.007, 0.01; predicted at 0.003 … 0.012",
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax = axes[1]
    for k, f in enumerate(sorted(brs)):
        br = brs[f]
        w = interval_width(br, "amplitude")
        ax.semilogy(
            br.data["observed_amplitude"],
            np.maximum(w, 1e-12),
            color=f"C{k}",
            lw=1,
            label=f"F = {f:g}",
        )
    ax.axvline(sp_figs["r_hi"], color="k", lw=0.8, ls=":")
    ax.set(
        xlabel="amplitude ρ",
        ylabel="95 % interval width in amplitude",
        title="95 % interval widths",
    )
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    fig.tight_layout()
    p = FIGS / "forced_kernel_shaw_pierre.png"
    fig.savefig(p, dpi=120)
    plt.close(fig)
    made.append(p.name)

    # ---- duffing: 2× forcing; band width along the curve, trained vs extrapolated
    if du_figs:
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw={"width_ratios": [3, 2]})
        ax = axes[0]
        for k, (_f, d) in enumerate(sorted(du_figs["tr"].items())):
            ax.plot(
                d["omega"],
                d["amplitude"],
                "-",
                color="0.6",
                lw=3.5,
                alpha=0.6,
                label="true" if k == 0 else None,
            )
        br = du_figs["branches"][("fit", "eq6.19")]
        curve(
            ax,
            br.params,
            br.data["observed_amplitude"],
            br.stable,
            "C3",
            "model, F = 0.02 (2× the largest trained)",
        )
        for sp in br.special("fold"):
            ax.plot(sp.param, sp.data["amplitude"], "ks", ms=4)
        om = np.array([r.omega for r in du_figs["recs"]])
        am = np.array([r.amplitude for r in du_figs["recs"]])
        ax.plot(om, am, "ko", ms=4, label="training (F = 0.005, 0.01)")
        tb = du_figs["tb"]
        ax.plot(tb["omega"], tb["amplitude"], "-", color="0.3", lw=1, label="true backbone")
        mb = du_figs["mb"]
        ax.plot(mb.data["omega"], mb.params, "k:", lw=1.2, label="model backbone")
        ax.set(
            xlim=(0.85, 1.25),
            xlabel="Ω [rad/s]",
            ylabel="max |q|",
            title="duffing: prediction at twice the largest trained forcing",
        )
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        ax = axes[1]
        for b_, col, lab in (
            (du_figs["trained_br"], "C0", "F = 0.01 (trained)"),
            (br, "C3", "F = 0.02 (2×)"),
        ):
            w = interval_width(b_, "amplitude")
            ax.semilogy(b_.data["phase"], np.maximum(w, 1e-12), color=col, lw=1.2, label=lab)
        ax.set(
            xlabel="phase lag behind the force [rad]",
            ylabel="95 % interval width in amplitude",
            title="95 % intervals along the FRC",
        )
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
        fig.tight_layout()
        p = FIGS / "forced_kernel_duffing.png"
        fig.savefig(p, dpi=120)
        plt.close(fig)
        made.append(p.name)

    # ---- em oscillator
    if em_figs:
        ds = em_figs["ds"]
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
        ax = axes[0]
        lab = "κ from ω₀ of the measured backbone"
        for train, test in (("scurve_16p5Hz", "scurve_16p6Hz"),):
            m = em_figs["models"][(train, lab, "phase")]
            m1 = em_figs["models"][(train, "κ = 1 (Γ = F, thesis)", "phase")]
            for name, col in ((train, "C0"), (test, "C1")):
                d = ds[name]
                om = float(d["omega"].values[0])
                ax.plot(
                    d["forcing"].values,
                    d["amplitude"].values,
                    "o",
                    color=col,
                    ms=3,
                    label=f"measured {om / 2 / np.pi:.1f} Hz"
                    + (" (training)" if name == train else " (validation)"),
                )
                br = m.scurve(om, (0, 0.6))
                ax.plot(
                    br.params,
                    br.data["observed_amplitude"],
                    "-",
                    color=col,
                    lw=1.3,
                    label=f"model {om / 2 / np.pi:.1f} Hz",
                )
                if name == test:
                    br1 = m1.scurve(om, (0, 0.6))
                    ax.plot(
                        br1.params,
                        br1.data["observed_amplitude"],
                        ":",
                        color=col,
                        lw=1.3,
                        label="model with κ = 1 (Γ = F)",
                    )
        ax.set(
            xlabel="base displacement amplitude F",
            ylabel="max |x|",
            title=f"EM oscillator: trained on one S-curve (κ = {m.forcing_scale_:.3g})",
        )
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        ax = axes[1]
        for name, mk in (("backbone_1", "o"), ("backbone_2", "s")):
            d = ds[name]
            ax.plot(
                d["omega"].values / 2 / np.pi,
                d["amplitude"].values,
                mk,
                color="0.4",
                ms=3,
                mfc="none",
                label=f"measured {name.replace('_', ' ')}",
            )
        for mdl, col, lab2 in (
            (m, "C0", "model, one S-curve + ω₀"),
            (em_figs["both"], "C3", "model, both S-curves, κ fitted"),
        ):
            bb = predicted(mdl, kind="backbone", range=(0.05, mdl.rho_range_[1] * 1.6))
            ax.plot(bb.data["omega"] / 2 / np.pi, bb.params, "-", color=col, lw=1.4, label=lab2)
            ax.fill_betweenx(
                bb.params,
                np.asarray(bb.intervals["omega"][0]) / 2 / np.pi,
                np.asarray(bb.intervals["omega"][1]) / 2 / np.pi,
                color=col,
                alpha=0.25,
            )
        ax.axhline(m.rho_range_[1], color="k", lw=0.8, ls=":")
        ax.text(17.6, m.rho_range_[1] * 1.02, "largest trained amplitude", fontsize=7)
        ax.set(
            xlabel="frequency [Hz]",
            ylabel="max |x|",
            title="backbones: measured (CBC) and predicted (eq. 6.21), 95 % intervals",
        )
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        p = FIGS / "forced_kernel_em.png"
        fig.savefig(p, dpi=120)
        plt.close(fig)
        made.append(p.name)
    return made


# ============================================================================ report


def scurve_laws_lines(rows: list[dict]) -> list[str]:
    """Markdown of :func:`scurve_laws`: per law and noise seed, κ, the band's coverage of
    the true FRC at each untrained forcing and the largest peak error; the means."""
    fs = " / ".join(f"{f:g}" for f in SC_TEST_FORCINGS)
    L = [
        "**The forcing law** (`ForcedKernelModel(forcing_frequency=...)`): the same S-curves "
        f"with the noise drawn from seeds {', '.join(map(str, SC_SEEDS))}; `constant` is "
        "Γ = κF (the default, the thesis), `inverse` Γ = κFΩ̄/Ω (Ω̄ the mean trained "
        "frequency), how the forcing of `ẍ + … = F cos Ωt` reaches the averaged amplitude "
        "equation.\n",
        f"| law | seed | κ | 95 % coverage at F = {fs} | largest peak error |",
        "|---|---|---|---|---|",
    ]
    for law in ("constant", "inverse"):
        for seed in SC_SEEDS:
            part = [r for r in rows if r["law"] == law and r["seed"] == seed]
            cov = " / ".join(pct(r["coverage"], 0) for r in part)
            worst = max((r["peak_err"] for r in part), key=abs)
            L.append(f"| {law} | {seed} | {part[0]['kappa']:.4f} | {cov} | {pct(worst, 2)} |")
    L.append("")
    for law in ("constant", "inverse"):
        part = [r for r in rows if r["law"] == law]
        cov = np.array([r["coverage"] for r in part])
        err = np.abs([r["peak_err"] for r in part])
        width = np.median([r["band_width_peak"] for r in part])
        L.append(
            f"`{law}`: mean coverage {np.mean(cov):.3f} (lowest {np.min(cov):.2f}) over "
            f"{len(part)} FRCs, mean |peak error| {pct(float(np.mean(err)), 2)} (largest "
            f"{pct(float(np.max(err)), 2)}), median 95 % width at the peak {width:.3g}.  "
        )
    L.append("")
    return L


def report(
    sp: dict, du: dict, em: dict, figs: list[str], load: str, sps: dict | None = None
) -> str:
    L = []
    L.append("## forced_kernel — kernel models of forced systems on SSMs (thesis ch. 6)\n")
    L.append(
        "`benchmarks/bench_forced_kernel.py`; ground truth = continuation of the true "
        "system (Fourier collocation, 32 mesh points). Errors are relative. "
        f"Machine load average during the run: {load}.\n"
    )
    L.append(
        f"### shaw_pierre (§6.3.1): {sp['n_train']} training points on the FRCs at "
        f"F = 0.01, 0.007 ({sp['n_unstable']} unstable); fitted κ = {sp['kappa']:.4f} "
        "(expected 1/(2ω₁) = 0.5)\n"
    )
    L.append(
        "| F | trained | peak (true) | peak error | peak Ω error | folds true/model | "
        "max fold-Ω error | 95 % interval coverage | interval width at peak | FRC time |"
    )
    L.append("|---|---|---|---|---|---|---|---|---|---|")
    for r in sp["rows"]:
        L.append(
            f"| {r['F']:g} | {'yes' if r['trained'] else '**no**'} | "
            f"{r['peak_true']:.5f} | {pct(r['peak_err'])} | {pct(r['peak_omega_err'], 4)} "
            f"| {r['n_folds_true']}/{r['n_folds_model']} | {pct(r['fold_err'], 5)} | "
            f"{pct(r['coverage'], 0)} | {r['band_width_peak']:.2e} | {r['time_s']:.2f} s |"
        )
    L.append("")
    L.append(
        f"Tolerances (untrained F): peak within 2 % — max "
        f"{pct(max(abs(r['peak_err']) for r in sp['rows'] if not r['trained']))}; folds "
        f"within 0.1 % — max "
        f"{pct(max(r['fold_err'] for r in sp['rows'] if not r['trained']), 5)}; backbone "
        f"within 1 % over the trained amplitude range — max {pct(sp['backbone_err'], 4)} "
        f"(= {pct(sp['backbone_err_shift'], 2)} of the backbone's frequency shift); "
        f"backbone interval {sp['backbone_widening']:.1f}× wider beyond the trained amplitude "
        "than inside.\n"
    )
    L.append(
        "Time series (observation φ, eq. 6.20) at untrained points, RMS error / RMS: "
        + "; ".join(f"F = {t['F']:g}, Ω = {t['omega']:.4f}: {pct(t['rms_err'])}" for t in sp["ts"])
        + ".\n"
    )
    sk = sp["sk"]
    L.append("Speed (2 cores shared with other jobs; medians):\n")
    L.append(
        "| | bifid (JAX, L-BFGS + marginal likelihood) | scikit-learn GPR (same a/b samples) "
        "| ratio |"
    )
    L.append("|---|---|---|---|")
    L.append(
        f"| fit (a, b, φ; κ) | {sp['fit_s']:.2f} s (first call with "
        f"JIT compile {sp['first_fit_s']:.1f} s) | {sk['fit_s']:.2f} s (a, b only) | "
        f"{sp['fit_s'] / sk['fit_s']:.2f} |"
    )
    L.append(
        f"| one FRC, F = 0.009 | {sp['frc_s']:.2f} s (palc, ~110 points, folds located) | "
        f"{sk['frc_s']:.2f} s (300 fixed-phase fsolve) | {sp['frc_s'] / sk['frc_s']:.2f} |"
    )
    L.append(f"| FRC + {LEVEL:.0%} intervals | {sp['band_frc_s']:.2f} s | – | – |")
    L.append("")
    L.append(
        f"scikit-learn's FRC peak error at F = 0.009 (same a/b samples, zero-mean RBF, "
        f"no basis): {pct(sk['peak_err'])}.\n"
    )
    if sps:
        t = sps["timing"]
        L.append("### shaw_pierre from noisy S-curves (the setting of `bifid demo forced`)\n")
        omegas = ", ".join(f"{o:g}" for o in SC_OMEGAS)
        L.append(
            f"S-curves at Ω = {omegas} over "
            f"0 < F ≤ {SC_FORCING[1]:g} ({sps['n_points']} points by arclength, "
            f"{sps['n_used']} used), sampled at 100 Hz over 3 periods with white noise "
            f"σ = {sps['sigma']:.2g} (1 % of the median amplitude), amplitude and phase "
            "from the 5-harmonic Fourier projection; `ForcedKernelModel()` with default "
            f"settings: κ = {sps['kappa']:.4f}, largest trained amplitude "
            f"{sps['rho_max']:.3f}, stability labels reproduced at "
            f"{pct(sps['stability_agreement'], 1)} of the points.\n"
        )
        L.append(
            "| F | peak (true) | peak error | peak Ω error | folds true/model | "
            "max fold-Ω error | 95 % interval coverage |"
        )
        L.append("|---|---|---|---|---|---|---|")
        for r in sps["rows"]:
            L.append(
                f"| {r['F']:g} | {r['peak_true']:.4f} | {pct(r['peak_err'])} | "
                f"{pct(r['peak_omega_err'], 4)} | {r['n_folds_true']}/{r['n_folds_model']}"
                f" | {pct(r['fold_err'], 4)} | {pct(r['coverage'], 0)} |"
            )
        L.append("")
        L.append(
            f"Backbone over the trained amplitudes: max error {pct(sps['backbone_err'], 4)}. "
            f"Wall times (warm): fit {t['fit']:.2f} s (first call, with JIT compile, "
            f"{t['fit_first']:.1f} s); FRC {t['frc']:.2f} s; FRC + intervals "
            f"{t['frc_band']:.2f} s; backbone + intervals "
            f"{t['backbone_band']:.2f} s (first call {t['backbone_band_first']:.1f} s); "
            f"S-curve + intervals {t['scurve_band']:.2f} s (first call "
            f"{t['scurve_band_first']:.1f} s); save {t['save']:.2f} s; load "
            f"{t['load']:.2f} s.\n"
        )
        L += scurve_laws_lines(sps["laws"])
    if du:
        L.append(
            "### duffing (ζ = 0.01, γ = 0.5): trained at F = 0.005, 0.01 (16 points each), "
            "FRC predicted at F = 0.02\n"
        )
        L.append(
            "| variant | κ | peak error | peak Ω error | max fold-Ω error "
            "| 95 % interval coverage |"
        )
        L.append("|---|---|---|---|---|---|")
        for k, r in du["frc"].items():
            L.append(
                f"| {k} | {r['kappa']:.4f} | {pct(r['peak_err'])} | "
                f"{pct(r['peak_omega_err'], 4)} | {pct(r['fold_err'], 4)} | "
                f"{pct(r['coverage'], 0)} |"
            )
        L.append("")
        L.append(
            f"Backbone (κ fitted): max error {pct(du['backbone_err_trained'], 4)} over the "
            f"trained amplitudes, {pct(du['backbone_err_2x'], 4)} up to twice them. "
            "Time series (φ) at untrained points of the F = 0.02 FRC, RMS error / RMS: "
            + "; ".join(
                f"Ω = {t['omega']:.4f} (amplitude {t['amplitude']:.3f}): {pct(t['rms_err'])}"
                for t in du["ts"]
            )
            + ".\n"
        )
        if "sparse" in du:
            L.append(
                "Sparse data (like §6.3.2): S-curves at N frequencies in [0.95, 1.2], "
                "each measured as CBC does, from small forcing through both folds "
                "(lower stable, unstable and upper stable branch) up to 1.3 × the "
                "forcing of its upper fold, 12 points each by arclength; validated on "
                "untrained S-curves at Ω = 1.02, 1.11, 1.17 and their folds, on the "
                "backbone over the trained amplitudes, and on the FRCs at F = 0.01 and "
                "F = 0.02.\n"
            )
            L.append(
                "| S-curves | points | κ | max trained ρ | S-curve forcing RMS error | "
                "fold (F) error | backbone error | FRC F=0.01 peak / folds | "
                "FRC F=0.02 peak / folds | fit time |"
            )
            L.append("|---|---|---|---|---|---|---|---|---|---|")
            for r in du["sparse"]:
                L.append(
                    f"| {r['n_curves']} | {r['n_points']} | {r['kappa']:.3g} | "
                    f"{r['rho_max']:.3f} | {pct(r['scurve_rms'])} | {pct(r['fold_err'])} | "
                    f"{pct(r['backbone_err'], 4)} | {pct(r['frc_in_peak_err'])} / "
                    f"{pct(r['frc_in_fold_err'], 4)} | {pct(r['frc_peak_err'])} / "
                    f"{pct(r['frc_fold_err'], 4)} | {r['fit_s']:.0f} s |"
                )
            L.append("")
    if em and "rows" in em:
        L.append("### Electromagnetic oscillator (real CBC data, `shared/data/em_oscillator`)\n")
        L.append(
            f"Fit on one measured S-curve, predict the other (error = RMS of the forcing "
            f"misfit at the measured amplitudes / RMS forcing). ω₀ = {em['w0_hz']:.3f} Hz is "
            "the lowest-amplitude point of measured backbone 1.\n"
        )
        L.append(
            "| train → test | κ | a samples | κ value | train error | test error | "
            "backbone 1 max error | backbone 2 max error |"
        )
        L.append("|---|---|---|---|---|---|---|---|")
        for r in em["rows"]:
            L.append(
                f"| {r['train'][7:]} → {r['test'][7:]} | {r['variant']} | {r['a_target']} "
                f"| {r['kappa']:.3g} | {pct(r['train_err'], 2)} | {pct(r['test_err'], 2)} | "
                f"{pct(r['bb1'], 2)} | {pct(r['bb2'], 2)} |"
            )
        b = em["both"]
        L.append("")
        L.append(
            f"Both S-curves, κ fitted by marginal likelihood (κ = {b['kappa']:.3g}): "
            f"backbone error max {pct(b['bb1'][0], 2)} / median {pct(b['bb1'][1], 2)} "
            f"(backbone 1), max {pct(b['bb2'][0], 2)} (backbone 2), over the trained "
            "amplitudes.\n"
        )
    for f in figs:
        L.append(f"![{f}](docs/figures/{f})")
    L.append("")
    L.append(f"Python {platform.python_version()}, numpy {np.__version__}.")
    return "\n".join(L)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument(
        "--quick",
        action="store_true",
        help="shaw_pierre + duffing FRC only; print, do not write BENCHMARKS.md",
    )
    ap.add_argument("--json", type=Path, default=None, help="also write the numbers as JSON")
    args = ap.parse_args()
    warnings.simplefilter("ignore", category=UserWarning)
    load = " / ".join(f"{v:.1f}" for v in os.getloadavg())
    t0 = time.perf_counter()
    sp, _, sp_figs = shaw_pierre(args.quick)
    print(f"shaw_pierre done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    sps, _ = ({}, {}) if args.quick else shaw_pierre_scurves()
    print(f"shaw_pierre S-curves done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    du, du_figs = duffing(args.quick)
    print(f"duffing done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    em, em_figs = ({}, {}) if args.quick else em_oscillator()
    print(f"em done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    made = figures(sp_figs, du_figs, em_figs)
    load = load + " → " + " / ".join(f"{v:.1f}" for v in os.getloadavg())
    md = report(sp, du, em, made, load, sps)
    print(md)
    if args.json is not None:
        args.json.write_text(
            json.dumps(
                {"shaw_pierre": sp, "shaw_pierre_scurves": sps, "duffing": du, "em": em},
                default=float,
                indent=1,
            )
        )
    if not args.quick:
        write_section("forced_kernel", md)


if __name__ == "__main__":
    main()
