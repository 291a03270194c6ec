"""Calibration of bifid's intervals: nominal vs empirical coverage over seeded replications.

Each replication draws fresh measurement noise on a diagram with known truth, fits the
model, predicts with ``level`` and records, for every quantity, the estimate, the truth and
the delta-method standard deviation (intervals at 50/80/90/95/99 % follow from Student's t
with the fit's residual degrees of freedom). Reported per method: empirical coverage pooled
over its cases and quantities, a two-sided exact binomial test at the 1 % level, median
interval width next to median absolute error, and a reliability figure
(``docs/figures/calibration_<method>.png``).

Mechanistic method: the ``hopf`` system (eq. 5.2, cycles of radius
``r² = (a2 ± sqrt(a2² + 4 q5 (mu − mu0)))/(2 q5)``), free ``mu0, a2, q5``; eight measured
LCOs (four unstable, four stable, at the same places relative to the fold) with Gaussian
amplitude noise of a stated fraction of the largest amplitude; quantities: Hopf point
``mu0``, cycle-fold speed ``mu0 − a2²/(4 q5)`` and cycle-fold amplitude
``sqrt(a2/(2 q5))``. Cases: ``a2 = 1`` and ``a2 = 0.8`` at 1 % noise, ``a2 = 1`` at 0.5 %
and 2 %.

Kernel method (forced systems, thesis ch. 6): the first-order averaged hardening Duffing
oscillator, ``a(ρ) = −cρ``, ``b(ρ) = ω₀ + kρ²``, ``Γ = κF`` (c = 0.0015, k = 0.0005,
ω₀ = 1, κ = 0.5, known), whose FRC is explicit in the phase ψ: ``ρ = Γ sin ψ / c``,
``Ω = b(ρ) + Γ cos ψ / ρ``. Training: two FRCs (F = 0.007, 0.01, 16 points each) with
relative amplitude noise and phase noise (radians) of the stated size; prediction: the FRC
at the untrained F = 0.0085 with ``predict_diagram(level=...)`` (posterior samples and the
leave-one-out jackknife, ``docs/uncertainty.md``); quantities: both folds' Ω, the peak's Ω
and amplitude. Cases: 1 % noise, and 0.5 % and 2 %.

Hybrid method (thesis ch. 5): the same ``hopf`` system (``omega0 = 1``, ``q5 = 1``) and the
mechanistic cases, but the hybrid model learns it from eight measured cycles (time series:
the exact circles, 20 s at 10 Hz, a random phase, Gaussian noise of the stated fraction of
the largest radius on every sample of both signals), with fixed hyperparameters
(``HYBRID_FIT``) and ``fit(..., uncertainty=True)``; a fresh noise draw and a fresh training
seed per replication; quantities: Hopf point ``mu0`` and frequency ``omega0``, cycle-fold
speed and amplitude of ``u1``.

Run: ``cd benchmarks && ../.venv/bin/python bench_calibration.py [--reps N | --quick]
[--method mechanistic|kernel|hybrid]``
(``N`` replications of each 1 % case, ``N/2`` of the others; default 40, ``--quick`` 4;
``--resume``: kernel replications already in ``results/`` are read back, not rerun).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import write_section

ROOT = Path(__file__).resolve().parents[1]
FIG = ROOT / "docs" / "figures"
RESULTS = ROOT / "benchmarks" / "results"
LEVELS = (0.5, 0.8, 0.9, 0.95, 0.99)

MU = np.array([-0.2, -0.12, -0.05, -0.02, -0.22, -0.15, -0.05, 0.05])
STABLE = np.array([0, 0, 0, 0, 1, 1, 1, 1])


def log(msg: str) -> None:
    print(f"[bench_calibration] {msg}", file=sys.stderr, flush=True)


def radius(mu, stable, a2, q5=1.0, mu0=0.0):
    s = np.sqrt(a2**2 + 4 * q5 * (np.asarray(mu) - mu0))
    return np.sqrt((a2 + np.where(stable, s, -s)) / (2 * q5))


# --------------------------------------------------------------------- mechanistic
def mechanistic_replication(a2: float, noise: float, seed: int) -> list[dict]:
    """One fit of the ``hopf`` model on fresh noise; per quantity (estimate, truth, std, dof)."""
    from bifid.identify import LCOData, MechanisticModel

    mu = MU * a2**2  # the same places relative to the fold at -a2²/4
    clean = radius(mu, STABLE == 1, a2)
    rng = np.random.default_rng(seed)
    amp = clean + noise * np.max(clean) * rng.standard_normal(MU.size)
    data = LCOData.from_amplitudes(mu, amp[:, None], STABLE, ("u1",), param_name="mu")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = MechanisticModel("hopf", ("mu0", "a2", "q5"), stages=("whole_diagram",), n_mesh=16).fit(
            data
        )
        d = m.predict_diagram(range=(-0.35, 0.05), level=0.95, n_points=20)
    cov = m.covariance()
    from scipy.stats import t as student

    z = student.ppf(0.975, cov.dof)
    (hopf,) = d.special("hopf")
    (fold,) = d.special("cycle_fold")
    truth = {"hopf": 0.0, "fold": -(a2**2) / 4, "fold_amplitude": math.sqrt(a2 / 2)}
    est = {
        "hopf": (hopf.param, hopf.intervals["param"]),
        "fold": (fold.param, fold.intervals["param"]),
        "fold_amplitude": (
            float(fold.data["amplitude"][0]),
            [fold.intervals["amplitude"][0][0], fold.intervals["amplitude"][1][0]],
        ),
    }
    return [
        {
            "quantity": k,
            "estimate": v,
            "truth": truth[k],
            "std": (iv[1] - iv[0]) / (2 * z),
            "dof": cov.dof,
        }
        for k, (v, iv) in est.items()
    ]


# -------------------------------------------------------------------------- hybrid
HYBRID_FIT = dict(
    n_harmonics=4,
    regularization=1e-5,
    stopping="final",
    n_lbfgs=400,
    n_ensemble=3,
    omega_harmonics=2,
    omega_regularization=1e-4,
)
HYBRID_RATE, HYBRID_DURATION = 10.0, 20.0  # samples per second, seconds per record
# the calibration factor of the hybrid intervals was measured on the seeds 0..17 (+1000 per
# case); the reported replications use seeds offset from those
HYBRID_SEED_OFFSET = 100_000


def hybrid_records(a2: float, noise: float, seed: int) -> list[tuple]:
    """Eight measured cycles of the ``hopf`` system (eq. 5.2, ``omega0 = 1``, ``q5 = 1``,
    ``mu0 = 0``) at the mechanistic case's places: circles of the exact radius, a random
    phase, 20 s at 10 Hz (about three periods), Gaussian noise of ``noise`` times the
    largest radius on every sample of both signals."""
    rng = np.random.default_rng(seed)
    mu = MU * a2**2
    r = radius(mu, STABLE == 1, a2)
    t = np.arange(round(HYBRID_RATE * HYBRID_DURATION)) / HYBRID_RATE
    out = []
    for m, rr, st in zip(mu, r, STABLE, strict=True):
        phase = t + rng.uniform(0, 2 * np.pi)
        z = rr * np.stack([np.cos(phase), np.sin(phase)], axis=1)
        z += noise * np.max(r) * rng.standard_normal(z.shape)
        out.append((float(m), z, HYBRID_RATE, bool(st)))
    return out


def hybrid_replication(a2: float, noise: float, seed: int) -> list[dict]:
    """One hybrid fit (with its jackknife) on fresh noise and a fresh training seed; per
    quantity the estimate, the truth and the intervals at every level."""
    from bifid.identify import HopfHybridModel

    seed += HYBRID_SEED_OFFSET
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = HopfHybridModel(seed=seed, **HYBRID_FIT).fit(
            hybrid_records(a2, noise, seed), signal_names=("u1", "u2"), uncertainty=True
        )
        diagrams = {
            lv: m.predict_diagram(range=(-0.35, 0.05), n_points=20, level=lv) for lv in LEVELS
        }
    truth = {
        "hopf": 0.0,
        "hopf_omega": 1.0,
        "fold": -(a2**2) / 4,
        "fold_amplitude": math.sqrt(a2 / 2),
    }
    rows = {k: {"quantity": k, "truth": v, "intervals": {}} for k, v in truth.items()}
    for lv, d in diagrams.items():
        (hopf,) = d.special("hopf")
        (fold,) = d.special("cycle_fold")
        pts = {
            "hopf": (hopf.param, hopf.intervals["param"]),
            "hopf_omega": (hopf.data["omega"], hopf.intervals["omega"]),
            "fold": (fold.param, fold.intervals["param"]),
            "fold_amplitude": (
                float(fold.data["amplitude"][0]),
                [fold.intervals["amplitude"][0][0], fold.intervals["amplitude"][1][0]],
            ),
        }
        for k, (v, iv) in pts.items():
            rows[k]["estimate"] = float(v)
            rows[k]["intervals"][str(lv)] = [float(x) for x in iv]
    return list(rows.values())


# -------------------------------------------------------------------------- kernel
DUFFING = {"c": 0.0015, "k": 0.0005, "w0": 1.0, "kappa": 0.5}
KERNEL_TRAIN_F, KERNEL_PREDICT_F = (0.007, 0.01), 0.0085


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


def kernel_replication(noise: float, seed: int) -> list[dict]:
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

    model = ForcedKernelModel(
        forcing_scale=DUFFING["kappa"], selection="loo", observation=False, seed=seed
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(**{k: np.concatenate(v) for k, v in cols.items()})
    truth = duffing_truth(KERNEL_PREDICT_F)
    rows = {k: {"quantity": k, "truth": float(v), "intervals": {}} for k, v in truth.items()}
    for lv in LEVELS:
        d = model.predict_diagram(kind="frc", forcing=KERNEL_PREDICT_F, range=(0.95, 1.2), level=lv)
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
    return list(rows.values())


KERNEL_CASES = (
    ("averaged Duffing, 1 % noise", 0.01, 1.0),
    ("averaged Duffing, 0.5 % noise", 0.005, 0.5),
    ("averaged Duffing, 2 % noise", 0.02, 0.5),
)


MECHANISTIC_CASES = (
    ("a2 = 1, 1 % noise", 1.0, 0.01, 1.0),
    ("a2 = 0.8, 1 % noise", 0.8, 0.01, 1.0),
    ("a2 = 1, 0.5 % noise", 1.0, 0.005, 0.5),
    ("a2 = 1, 2 % noise", 1.0, 0.02, 0.5),
)


HYBRID_CASES = MECHANISTIC_CASES


def run_hybrid(reps: int) -> dict:
    cases = [(name, frac, (a2, noise)) for name, a2, noise, frac in HYBRID_CASES]
    return run_cases(hybrid_replication, cases, reps, "calibration_hybrid_rows.json")


def run_mechanistic(reps: int) -> dict:
    cases = [(name, frac, (a2, noise)) for name, a2, noise, frac in MECHANISTIC_CASES]
    return run_cases(mechanistic_replication, cases, reps, "calibration_rows.json")


def run_kernel(reps: int, resume: bool = False) -> dict:
    """Every kernel case's replications; with ``resume`` the seeds already in the rows file
    are read back (the replications are deterministic in their seed) and only new ones run."""
    cases = [(name, frac, (noise,)) for name, noise, frac in KERNEL_CASES]
    path = RESULTS / "calibration_kernel_rows.json"
    done: dict[int, list[dict]] = {}
    if resume and path.exists():
        for r in json.loads(path.read_text()):
            done.setdefault(r["seed"], []).append(r)

    def replicate(noise: float, seed: int) -> list[dict]:
        if seed not in done:
            return kernel_replication(noise, seed)
        if "failed" in done[seed][0]:
            raise RuntimeError(f"(earlier run) {done[seed][0]['failed']}")
        return [
            {k: v for k, v in r.items() if k not in ("case", "seed", "noise")} for r in done[seed]
        ]

    run = run_cases(replicate, cases, reps, path.name)
    if resume and (RESULTS / "calibration.json").exists():  # wall time of every run
        previous = json.loads((RESULTS / "calibration.json").read_text()).get("kernel", {})
        run["time_s"] += previous.get("time_s", 0.0)
    return run


def run_cases(replicate, cases: list, reps: int, rows_file: str) -> dict:
    """``replicate(*args, seed)`` over every case's seeds; a failed fit is a row too."""
    rows = []
    t0 = time.perf_counter()
    for c, (name, frac, case_args) in enumerate(cases):
        n = max(2, round(reps * frac))
        for r in range(n):
            seed = 1000 * c + r
            try:
                out = replicate(*case_args, seed)
            except Exception as exc:  # a failed fit is counted, not hidden
                rows.append({"case": name, "seed": seed, "failed": repr(exc)})
                log(f"{name} seed {seed}: failed ({exc!r})")
                continue
            rows += [{"case": name, "seed": seed, "noise": case_args[-1], **q} for q in out]
        log(f"{name}: {n} replications, {time.perf_counter() - t0:.0f} s so far")
        RESULTS.mkdir(parents=True, exist_ok=True)
        (RESULTS / rows_file).write_text(json.dumps(rows))
    return {"rows": rows, "time_s": time.perf_counter() - t0}


# ----------------------------------------------------------------------- analysis
def coverage_table(rows: list[dict]) -> dict:
    """Coverage per level (pooled and per case) with the binomial test."""
    from scipy.stats import t as student

    from bifid.identify import coverage_test

    ok = [r for r in rows if "failed" not in r]
    err = np.array([abs(r["estimate"] - r["truth"]) for r in ok])

    def hits_widths(lv: float) -> tuple[np.ndarray, np.ndarray]:
        """Whether each interval at ``lv`` held the truth, and its width: given intervals
        (``intervals`` by level), else Student-t ones from ``std`` and ``dof``."""
        if ok and "intervals" in ok[0]:
            iv = np.array([r["intervals"][str(lv)] for r in ok])
            truth = np.array([r["truth"] for r in ok])
            return (iv[:, 0] <= truth) & (truth <= iv[:, 1]), iv[:, 1] - iv[:, 0]
        half = student.ppf(0.5 + lv / 2, [r["dof"] for r in ok]) * np.array([r["std"] for r in ok])
        return err <= half, 2 * half

    out = {
        "n_trials": len(ok),
        "n_failed": len({(r["case"], r["seed"]) for r in rows if "failed" in r}),
        "levels": {},
    }
    for lv in LEVELS:
        hits = hits_widths(lv)[0]
        out["levels"][str(lv)] = coverage_test(hits, lv)
        out["levels"][str(lv)]["by_case"] = {
            c: float(np.mean(hits[[r["case"] == c for r in ok]]))
            for c in dict.fromkeys(r["case"] for r in ok)
        }
    hits95, width95 = hits_widths(0.95)
    out["width_vs_error"] = {}
    for key in dict.fromkeys((r["case"], r["quantity"]) for r in ok):
        sel = np.array([(r["case"], r["quantity"]) == key for r in ok])
        out["width_vs_error"][" / ".join(key)] = {
            "median_width_95": float(np.nanmedian(width95[sel])),
            "median_abs_error": float(np.median(err[sel])),
            "coverage_95": float(np.mean(hits95[sel])),
            "n": int(sel.sum()),
        }
    return out


def reliability_figure(method: str, table: dict, path: Path) -> None:
    import matplotlib.figure

    fig = matplotlib.figure.Figure(figsize=(4.2, 4.0), layout="constrained")
    ax = fig.add_subplot()
    nominal = np.array(LEVELS)
    rates = np.array([table["levels"][str(lv)]["rate"] for lv in LEVELS])
    ci = np.array([table["levels"][str(lv)]["rate_ci"] for lv in LEVELS])
    ax.plot([0.4, 1.0], [0.4, 1.0], color="0.6", lw=1, label="ideal")
    ax.errorbar(
        nominal,
        rates,
        yerr=[rates - ci[:, 0], ci[:, 1] - rates],
        fmt="o-",
        capsize=3,
        label=f"{method} (99 % CI, n = {table['n_trials']})",
    )
    ax.set_xlabel("nominal level")
    ax.set_ylabel("empirical coverage")
    ax.set_xlim(0.45, 1.0)
    ax.set_ylim(0.4, 1.01)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"Calibration: {method}", fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def markdown(method: str, table: dict, run: dict, reps: int) -> list[str]:
    md = [
        f"### {method}",
        "",
        f"{table['n_trials']} interval trials ({table['n_failed']} failed fits), "
        f"{reps} replications per 1 % case; {run['time_s'] / 60:.1f} min wall "
        f"(load average at the end {os.getloadavg()[0]:.1f}).",
        "",
        "| nominal | empirical (pooled) | 99 % CI of the rate | binomial p | rejected at 1 % |",
        "|---|---|---|---|---|",
    ]
    for lv in LEVELS:
        r = table["levels"][str(lv)]
        md.append(
            f"| {lv:.0%} | {r['rate']:.3f} ({r['covered']}/{r['n']}) | "
            f"{r['rate_ci'][0]:.3f}–{r['rate_ci'][1]:.3f} | {r['p_value']:.3g} | "
            f"{'yes' if r['rejected'] else 'no'} |"
        )
    md += [
        "",
        "| case / quantity | n | coverage at 95 % | median 95 % width | median error |",
        "|---|---|---|---|---|",
    ]
    for k, v in table["width_vs_error"].items():
        md.append(
            f"| {k} | {v['n']} | {v['coverage_95']:.2f} | {v['median_width_95']:.3g} | "
            f"{v['median_abs_error']:.3g} |"
        )
    return md


def save_results(method: str, table: dict, run: dict) -> None:
    """Merge one method's table and rows into ``results/calibration.json``."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / "calibration.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    results[method] = {"table": table, **run}
    path.write_text(json.dumps(results, indent=1))


def write_report(
    method: str, run: dict, reps: int, section: str, intro: list[str], title: str, extra=()
) -> None:
    """Coverage table, reliability figure, results file and the BENCHMARKS.md section of one
    method's run (``intro`` lines before the table, ``extra`` lines after it)."""
    table = coverage_table(run["rows"])
    figure = f"calibration_{method}.png"
    reliability_figure(method, table, FIG / figure)
    save_results(method, table, run)
    md = [*intro, "", *markdown(title, table, run, reps), "", *extra]
    md += [f"![reliability](docs/figures/{figure})"]
    write_section(section, "\n".join(md))
    log(f"{method} done in {run['time_s'] / 60:.1f} min")


def report_mechanistic(reps: int) -> None:
    intro = [
        "## Calibration of intervals",
        "",
        "Nominal vs empirical coverage over seeded replications with known truth "
        "(`benchmarks/bench_calibration.py`; method and cases in its docstring and in "
        "`docs/uncertainty.md`).",
        "",
        "Scope: the `hopf` system (eq. 5.2) with free `mu0, a2, q5`; the flutter model's "
        "whole-diagram fits take minutes each and are not part of this benchmark.",
    ]
    title = "Mechanistic (delta method on the Gauss–Newton covariance)"
    write_report("mechanistic", run_mechanistic(reps), reps, "calibration", intro, title)


def undefined_intervals(rows: list[dict], level: float = 0.95) -> int:
    """Trials whose interval at ``level`` is undefined (NaN)."""
    return sum(
        not np.all(np.isfinite(r["intervals"][str(level)])) for r in rows if "failed" not in r
    )


def report_kernel(reps: int, resume: bool = False) -> None:
    run = run_kernel(reps, resume)
    intro = [
        "## Calibration of intervals: kernel model of forced systems",
        "",
        "FRC folds and peak of the averaged Duffing oscillator at an untrained forcing level "
        "(`benchmarks/bench_calibration.py`, cases in its docstring; method in "
        "`docs/uncertainty.md`). Scope: the averaged (reduced) oscillator, whose FRC is "
        "exact in closed form; the Duffing ODE and Shaw–Pierre are not part of this benchmark.",
    ]
    extra = [
        f"Undefined intervals (no posterior sample has the fold or peak: `null`), counted "
        f"as not covering: {undefined_intervals(run['rows'])} of "
        f"{coverage_table(run['rows'])['n_trials']} at 95 %. "
        "A failed fit is one whose mean FRC at the untrained forcing does not have the two "
        "folds of the true one (spurious folds where the GP of `a` follows the noise).",
        "",
    ]
    title = "Kernel (posterior samples and leave-one-out jackknife)"
    write_report("kernel", run, reps, "calibration-kernel", intro, title, extra)


def report_hybrid(reps: int) -> None:
    intro = [
        "## Calibration of intervals: hybrid model",
        "",
        "Hopf point (speed and frequency) and cycle fold (speed and amplitude) of the `hopf` "
        "system (eq. 5.2) learnt by the hybrid model from eight simulated cycles with noise "
        "on every sample; a fresh noise draw and a fresh training seed per replication "
        "(`benchmarks/bench_calibration.py --method hybrid`, cases in its docstring; method "
        "in `docs/uncertainty.md`). Fixed hyperparameters (`"
        + ", ".join(f"{k}={v}" for k, v in HYBRID_FIT.items())
        + "`) keep a replication under a minute. The intervals' calibration factor "
        "c = 0.85 was read off a first run on other seeds (0–17 per case); these "
        f"replications use seeds offset by {HYBRID_SEED_OFFSET}.",
    ]
    title = "Hybrid (jackknife over orbits and ensemble over seeds)"
    write_report("hybrid", run_hybrid(reps), reps, "calibration-hybrid", intro, title)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=40, help="replications of each 1 %% case")
    ap.add_argument("--quick", action="store_true", help="4 replications per 1 %% case")
    ap.add_argument(
        "--method",
        choices=("all", "mechanistic", "kernel", "hybrid"),
        default="all",
        help="which method",
    )
    ap.add_argument(
        "--resume",
        action="store_true",
        help="kernel: read back the replications already in results/ and run only new seeds",
    )
    args = ap.parse_args()
    if args.quick:
        args.reps = 4
    if args.method in ("all", "mechanistic"):
        report_mechanistic(args.reps)
    if args.method in ("all", "kernel"):
        report_kernel(args.reps, args.resume)
    if args.method in ("all", "hybrid"):
        report_hybrid(args.reps)


if __name__ == "__main__":
    main()
