"""Forced CBC benchmark: S-curves and FRCs with and without measurement noise.

Run from the repository root or the benchmarks directory::

    .venv/bin/python benchmarks/bench_cbc_forced.py           # writes BENCHMARKS.md "cbc_forced"
    .venv/bin/python benchmarks/bench_cbc_forced.py --quick   # 1 % noise, one seed, prints only

For ``duffing`` at Ω = 1.05 and ``shaw_pierre`` at Ω = 1.005 (both S-curves have two
folds and an unstable middle branch), :func:`bifid.cbc.forced_campaign` measures the
S-curve on the virtual rig (100 Hz) noise-free and with white measurement noise of
σ = 0.3 % and 1 % of the largest response amplitude of the observed signal in the
forcing range (from continuation), two seeds each. Every accepted point is compared with

- the uncontrolled response at the *same* forcing, Newton-corrected (Fourier collocation)
  from the rig's true states (:func:`bifid.continuation.truth.correct_forced`) -- points where the
  S-curve is steep (``|dlnA/dlnγ| > 2``, next to the folds) are listed apart: there a
  forcing error δ becomes an amplitude error ``|dlnA/dlnγ| δ`` (infinite at the fold,
  where Newton at fixed γ is singular and may jump to the other branch);
- the continuation curve (dense, ``ds_max = 0.01``): the normalised distance
  ``min sqrt((Δγ/γ)² + (ΔA/A)²)`` to its polyline, for every point;

and the folds (extrema of γ along the measured curve, :func:`bifid.cbc.folds_of`) with the
continuation folds. Noisy runs start higher (γ ≥ 0.005 / 0.0075) than noise-free ones: a
point is accepted only when its forcing update is verified to ``precision`` = 0.5 % of γ
(3σ), and the noise of that update, ``σ |k_p + iΩk_d| sqrt(2/n)``, does not shrink with γ.

FRCs (:func:`bifid.cbc.frc_cbc`, Newton–Broyden + pseudo-arclength in (A1*, B1*, Ω)):
``duffing`` at γ = 0.01, Ω ∈ [0.95, 1.10] and ``shaw_pierre`` at γ = 0.01,
Ω ∈ [0.98, 1.03] (both fold twice), same noise levels and seeds, same gains. Every point
is compared with the uncontrolled response Newton-corrected at its own (γ, Ω) (apart
where ``|dlnA/dlnγ| > 2`` at that Ω, i.e. next to the folds) and with the dense
continuation FRC (distance normalised by the ranges of Ω and A in the window, as in
``tests/slow/test_cbc_accuracy.py``); folds against the continuation folds, also as a
fraction of the width of the bistable range.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bifid  # noqa: F401
from _report import write_section
from bifid.cbc import ForcedCBCOptions, defaults_for, folds_of, forced_campaign, frc_cbc
from bifid.continuation import ContinuationOptions, frc, scurve
from bifid.continuation.truth import correct_forced, orbit_from_samples
from bifid.errors import ConvergenceError
from bifid.signal import max_abs
from bifid.systems import get_system

CASES = {
    "duffing": {"omega": 1.05, "range": (0.002, 0.03), "noisy_lo": 0.005},
    "shaw_pierre": {"omega": 1.005, "range": (0.001, 0.02), "noisy_lo": 0.0075},
}
STEEP = 2.0  # |dlnA/dlnγ| of the continuation curve above this: "steep" (near a fold)


def reference(name: str) -> dict:
    """Dense continuation S-curve: polyline (γ, A), folds, largest amplitude in range."""
    c = CASES[name]
    s = get_system(name)
    lo, hi = c["range"]
    br = scurve(
        s,
        c["omega"],
        (lo * 0.5, hi * 1.2),
        n_mesh=32,
        options=ContinuationOptions(ds=0.005, ds_min=1e-9, ds_max=0.01, max_steps=20000),
    )
    f = np.asarray(br.data["forcing"])
    a = np.asarray(br.data["observed_amplitude"])
    folds = sorted(sp.param for sp in br.special("fold"))
    return {"f": f, "a": a, "folds": folds, "a_max": float(a[f <= hi].max())}


def distance_to_curve(ref: dict, forcing: float, amplitude: float) -> float:
    """Normalised distance of ``(γ, A)`` to the continuation polyline."""
    t = np.linspace(0.0, 1.0, 21)[:, None]
    fd = (ref["f"][:-1] + t * np.diff(ref["f"])).ravel()
    ad = (ref["a"][:-1] + t * np.diff(ref["a"])).ravel()
    return float(np.min(np.hypot((fd - forcing) / forcing, (ad - amplitude) / amplitude)))


def log_slope(ref: dict, forcing: float, amplitude: float) -> float:
    """``dlnA/dlnγ`` of the continuation curve at its point nearest to ``(γ, A)``."""
    f, a = ref["f"], ref["a"]
    k = int(np.argmin(np.hypot((f - forcing) / forcing, (a - amplitude) / amplitude)))
    k = min(max(k, 1), len(f) - 2)
    df = math.log(f[k + 1]) - math.log(f[k - 1])
    return math.inf if df == 0 else (math.log(a[k + 1]) - math.log(a[k - 1])) / df


def truth_errors(name: str, pts: list, distance, slope) -> tuple[list, list, list, int]:
    """Per point: the distance to the continuation curve (``distance(p)``) and the
    amplitude error against the uncontrolled response Newton-corrected at the point's
    (γ, Ω), split by ``|slope(s, p, Vc, obs)| > STEEP`` (next to a fold, where that
    comparison is ill-conditioned). Returns ``(err_far, err_near, dist, n_newton_fail)``."""
    s = get_system(name)
    obs = s.state_index(defaults_for(name).signal)
    err_far, err_near, dist, n_newton_fail = [], [], [], 0
    for p in pts:
        dist.append(distance(p))
        m = p.measurement
        V = orbit_from_samples(m.extra["states"], m.phase - p.force_phase, m.sample_rate, n_mesh=32)
        try:
            Vc = correct_forced(s, p.omega, p.forcing, V, n_mesh=32)
        except ConvergenceError:
            n_newton_fail += 1
            continue
        e = abs(p.amplitude / float(max_abs(Vc[:, obs])) - 1.0)
        steep = abs(slope(s, p, Vc, obs)) > STEEP
        (err_near if steep else err_far).append(e)
    return err_far, err_near, dist, n_newton_fail


def evaluate(name: str, pts: list, ref: dict) -> dict:
    err_far, err_near, dist, n_newton_fail = truth_errors(
        name,
        pts,
        lambda p: distance_to_curve(ref, p.forcing, p.amplitude),
        lambda s, p, Vc, obs: log_slope(ref, p.forcing, p.amplitude),
    )
    got = sorted(f["forcing"] for f in folds_of(pts))
    fold_err = (
        [g / r - 1.0 for g, r in zip(got, ref["folds"], strict=True)]
        if len(got) == len(ref["folds"])
        else None
    )
    middle = 0
    if len(got) == 2:
        fl = folds_of(pts)
        lo_a, hi_a = sorted(f["amplitude"] for f in fl)
        middle = sum(lo_a < p.amplitude < hi_a for p in pts)
    return {
        "n": len(pts),
        "middle": middle,
        "err_far": max(err_far, default=float("nan")),
        "err_near": max(err_near, default=float("nan")),
        "n_near": len(err_near),
        "newton_fail": n_newton_fail,
        "dist": max(dist, default=float("nan")),
        "folds": got,
        "fold_err": fold_err,
        "floor": max((p.forcing_floor for p in pts), default=float("nan")),
        "periods": statistics.median([p.measured_periods for p in pts]) if pts else 0,
        "max_periods": max((p.measured_periods for p in pts), default=0),
    }


def run(name: str, fraction: float, seed: int, ref: dict) -> dict:
    c = CASES[name]
    sig = defaults_for(name).signal
    lo = c["range"][0] if fraction == 0 else c["noisy_lo"]
    sigma = fraction * ref["a_max"]
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = forced_campaign(
            name,
            "scurve",
            omega=c["omega"],
            span=(lo, c["range"][1]),
            noise={sig: sigma} if sigma > 0 else None,
            seed=seed,
            rig_options={"record_states": True},
        )
        pts, fails = r.points, r.failures
    wall = time.perf_counter() - t0
    out = evaluate(name, pts, ref)
    out.update(
        system=name,
        fraction=fraction,
        sigma=sigma,
        seed=seed,
        lo=lo,
        wall=wall,
        failures=[getattr(f, "reason", f) for f in fails],
    )
    return out


def warmup(name: str) -> float:
    """First rig run of a fresh process (the rig engine's compile time)."""
    rig = defaults_for(name).rig(get_system(name), record_states=True)
    t0 = time.perf_counter()
    rig.set_forcing(0.01, CASES[name]["omega"], 0.0)
    rig.run(1.0)
    return time.perf_counter() - t0


def _pct(x: float, digits: int = 2) -> str:
    return "–" if not np.isfinite(x) else f"{100 * x:.{digits}f} %"


def _cells(r: dict, fold_digits: int) -> tuple[str, str, str]:
    """The noise, folds and failures cells that both tables share."""
    noise = "0" if r["fraction"] == 0 else f"{r['fraction']:.1%} ({r['sigma']:.2g})"
    if r["fold_err"] is None:
        folds = f"{len(r['folds'])} found"
    else:
        folds = ", ".join(
            f"{g:.5f} ({e:+.{fold_digits}%})"
            for g, e in zip(r["folds"], r["fold_err"], strict=True)
        )
    fails = str(len(r["failures"]))
    if r["failures"]:
        fails += ": " + str(r["failures"][0])[:90].replace("|", "/")
    return noise, folds, fails


def table(rows: list[dict]) -> str:
    head = (
        "| system | noise σ | seed | γ from | points (middle) | max amp. err, same γ "
        "| steep (n) | max dist. to curve | folds: CBC (err) | failures "
        "| max forcing floor | periods median / max | wall |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for r in rows:
        noise, folds, fails = _cells(r, 2)
        lines.append(
            f"| {r['system']} | {noise} | {r['seed']} | {r['lo']:g} | {r['n']} ({r['middle']}) "
            f"| {_pct(r['err_far'])} | {_pct(r['err_near'])} ({r['n_near']}) "
            f"| {_pct(r['dist'])} | {folds} | {fails} | {_pct(r['floor'])} "
            f"| {r['periods']:.0f} / {r['max_periods']:.0f} | {r['wall']:.1f} s |"
        )
    return head + "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------- FRCs
FRC_CASES = {
    "duffing": {"forcing": 0.01, "range": (0.95, 1.10)},
    "shaw_pierre": {"forcing": 0.01, "range": (0.98, 1.03)},
}


def frc_reference(name: str) -> dict:
    """Dense continuation FRC: polyline (Ω, A), folds, ranges and largest amplitude."""
    c = FRC_CASES[name]
    w0, w1 = c["range"]
    br = frc(
        get_system(name),
        c["forcing"],
        (w0 - 0.02, w1 + 0.02),
        n_mesh=32,
        options=ContinuationOptions(ds=0.005, ds_min=1e-9, ds_max=0.01, max_steps=20000),
    )
    w = np.asarray(br.params)
    a = np.asarray(br.data["observed_amplitude"])
    inside = (w >= w0) & (w <= w1)
    return {
        "w": w,
        "a": a,
        "folds": sorted(sp.param for sp in br.special("fold")),
        "a_max": float(a[inside].max()),
        "w_ptp": w1 - w0,
        "a_ptp": float(np.ptp(a[inside])),
    }


def frc_distance(ref: dict, omega: float, amplitude: float) -> float:
    """Distance of ``(Ω, A)`` to the continuation polyline, normalised by the ranges."""
    t = np.linspace(0.0, 1.0, 41)[:, None]
    wd = (ref["w"][:-1] + t * np.diff(ref["w"])).ravel()
    ad = (ref["a"][:-1] + t * np.diff(ref["a"])).ravel()
    return float(np.min(np.hypot((wd - omega) / ref["w_ptp"], (ad - amplitude) / ref["a_ptp"])))


def gamma_sensitivity(s, p, Vc, obs: int, rel: float = 2e-3) -> float:
    """``dlnA/dlnγ`` of the uncontrolled response at the point's Ω (inf if Newton fails)."""
    a = []
    for f in (1.0 + rel, 1.0 - rel):
        try:
            a.append(
                float(max_abs(correct_forced(s, p.omega, p.forcing * f, Vc, n_mesh=32)[:, obs]))
            )
        except ConvergenceError:
            return math.inf
    return (math.log(a[0]) - math.log(a[1])) / (math.log(1.0 + rel) - math.log(1.0 - rel))


def frc_evaluate(name: str, pts: list, ref: dict) -> dict:
    err_far, err_near, dist, n_newton_fail = truth_errors(
        name, pts, lambda p: frc_distance(ref, p.omega, p.amplitude), gamma_sensitivity
    )
    got = sorted(f["omega"] for f in folds_of(pts, "omega"))
    ok = len(got) == len(ref["folds"]) == 2
    width = ref["folds"][1] - ref["folds"][0] if len(ref["folds"]) == 2 else math.nan
    return {
        "n": len(pts),
        "err_far": max(err_far, default=float("nan")),
        "err_near": max(err_near, default=float("nan")),
        "n_near": len(err_near),
        "newton_fail": n_newton_fail,
        "dist": max(dist, default=float("nan")),
        "folds": got,
        "fold_err": ([g / r - 1.0 for g, r in zip(got, ref["folds"], strict=True)] if ok else None),
        "fold_width": (
            max(abs(g - r) for g, r in zip(got, ref["folds"], strict=True)) / width
            if ok
            else float("nan")
        ),
        "floor": max((p.forcing_floor for p in pts), default=float("nan")),
        "periods": statistics.median([p.measured_periods for p in pts]) if pts else 0,
        "max_periods": max((p.measured_periods for p in pts), default=0),
    }


def frc_run(name: str, fraction: float, seed: int, ref: dict) -> dict:
    c = FRC_CASES[name]
    d = defaults_for(name)
    s = get_system(name)
    sigma = fraction * ref["a_max"]
    rig = d.rig(s, noise={d.signal: sigma} if sigma > 0 else None, seed=seed, record_states=True)
    kw = dict(
        signal=d.signal,
        kp=d.kp,
        kd=d.kd,
        n_harmonics=d.n_harmonics,
        settle_periods=d.settle_periods,
        measure_periods=d.measure_periods,
    )
    if sigma > 0:
        kw.update(d.noisy_options)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pts, fails = frc_cbc(rig, c["forcing"], c["range"], ForcedCBCOptions(**kw))
    wall = time.perf_counter() - t0
    out = frc_evaluate(name, pts, ref)
    out.update(
        system=name,
        fraction=fraction,
        sigma=sigma,
        seed=seed,
        wall=wall,
        failures=[f.reason for f in fails],
    )
    return out


def frc_table(rows: list[dict]) -> str:
    head = (
        "| system | noise σ | seed | points | max amp. err, same (γ, Ω) | steep (n) "
        "| max dist. to curve | folds: CBC (err; / width) | failures "
        "| max control floor | periods median / max | wall |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for r in rows:
        noise, folds, fails = _cells(r, 4)
        if r["fold_err"] is not None:
            folds += f"; {r['fold_width']:.1%}"
        lines.append(
            f"| {r['system']} | {noise} | {r['seed']} | {r['n']} | {_pct(r['err_far'])} "
            f"| {_pct(r['err_near'])} ({r['n_near']}) | {_pct(r['dist'])} | {folds} "
            f"| {fails} | {_pct(r['floor'])} | {r['periods']:.0f} / {r['max_periods']:.0f} "
            f"| {r['wall']:.1f} s |"
        )
    return head + "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 %% noise, one seed; print only")
    ap.add_argument(
        "--only",
        choices=("scurve", "frc"),
        default=None,
        help="run one protocol only (prints, does not write BENCHMARKS.md)",
    )
    ap.add_argument("--system", choices=tuple(CASES), default=None, help="one system only")
    ap.add_argument("--noise", type=float, default=None, help="one noise fraction only")
    ap.add_argument("--seed", type=int, nargs="+", default=None, help="these seeds only")
    args = ap.parse_args()
    fractions = (0.01,) if args.quick else (0.0, 0.003, 0.01)
    seeds = (1,) if args.quick else (1, 2)
    if args.noise is not None:
        fractions = (args.noise,)
    if args.seed is not None:
        seeds = tuple(args.seed)
    names = (args.system,) if args.system else tuple(CASES)
    partial = args.quick or args.only or args.system or args.noise is not None or args.seed
    rows, refs, compile_s = [], {}, {}
    if args.only != "frc":
        for name in names:
            refs[name] = reference(name)
            compile_s[name] = warmup(name)
            for frac in fractions:
                for seed in seeds if frac > 0 else (0,):
                    r = run(name, frac, seed, refs[name])
                    rows.append(r)
                    print(table([r]).splitlines()[-1], file=sys.stderr, flush=True)
    frc_rows, frc_refs = [], {}
    if args.only != "scurve":
        for name in names:
            frc_refs[name] = frc_reference(name)
            for frac in fractions:
                for seed in seeds if frac > 0 else (0,):
                    r = frc_run(name, frac, seed, frc_refs[name])
                    frc_rows.append(r)
                    print(frc_table([r]).splitlines()[-1], file=sys.stderr, flush=True)
    ref_lines = "\n".join(
        f"- `{n}`: continuation folds γ = {', '.join(f'{f:.7f}' for f in refs[n]['folds'])}; "
        f"largest amplitude in range {refs[n]['a_max']:.4f} (σ = 1 % of it: "
        f"{0.01 * refs[n]['a_max']:.4g}); rig warm-up (engine compile) {compile_s[n]:.2f} s"
        for n in refs
    )
    frc_ref_lines = "\n".join(
        f"- `{n}`, γ = {FRC_CASES[n]['forcing']:g}, Ω ∈ {list(FRC_CASES[n]['range'])}: "
        f"continuation folds Ω = {', '.join(f'{f:.7f}' for f in frc_refs[n]['folds'])}; "
        f"largest amplitude in range {frc_refs[n]['a_max']:.4f} (σ = 1 % of it: "
        f"{0.01 * frc_refs[n]['a_max']:.4g})"
        for n in frc_refs
    )
    md = f"""## cbc_forced: forced CBC (S-curves, FRCs) with measurement noise

### S-curves

`forced_campaign(..., "scurve")` on the virtual rig (100 Hz, derivative from samples,
white measurement noise on the observed signal, σ relative to its largest response
amplitude in the forcing range). The S-curve is the measured zero problem in
`(A1*, ψ, γ)` continued in the target's amplitude (each point solved for the force).
Gains: noise-free `kp = kd = 0.5` (duffing) / `1` (shaw_pierre); noisy
(`defaults_for(...).noisy_options`) `kp = kd = 0.1` (duffing) / `kp = 0, kd = 0.1`
(shaw_pierre). A point is accepted only when its forcing update is verified to 0.5 % of γ
and its response to 0.5 % of A₁* (3σ noise floors; the record is extended up to
`max_measure_periods` = 400 / 1000 periods for that), otherwise it is a failure.

{table(rows) if rows else "(not run)"}
Columns: *max amp. err, same γ* -- against the uncontrolled response Newton-corrected at
the point's own γ, points where the S-curve's slope `|dlnA/dlnγ| <= 2`; *steep (n)* -- the
same for the points next to the folds (`|dlnA/dlnγ| > 2`: a forcing error δ shows as an
amplitude error `|dlnA/dlnγ| δ` there; Newton at fixed γ fails at the fold itself and such
points are not counted); *max dist. to curve* -- normalised distance
`min √((Δγ/γ)² + (ΔA/A)²)` to the dense continuation curve, all points; *forcing floor* --
3σ noise floor of the last forcing update relative to γ; *periods* -- forcing periods of
the record each point was accepted on. Limits: amplitudes within 1 %, folds within 2 %.

{ref_lines}

### Frequency response curves

`frc_cbc` (Broyden corrector on the target's fundamental `(A1*, B1*)`, pseudo-arclength
in `(A1*, B1*, Ω)`) on the same rigs, gains and noise levels, Ω upwards through the
bistable range. A point is accepted only when the control's fundamental `u1` is below
`tol · γ` plus its noise floor and that floor is below 0.5 % of γ (the control is then a
force within 0.5 % of γ: the point is the uncontrolled response to a forcing within
that of γ), the response known to 0.5 % of A₁*; records are extended up to
`max_measure_periods` for that, otherwise the point is a failure.

{frc_table(frc_rows) if frc_rows else "(not run)"}
Columns: *max amp. err, same (γ, Ω)* -- against the uncontrolled response Newton-corrected
at the point's own (γ, Ω), points where `|dlnA/dlnγ| <= 2` at that Ω; *steep (n)* -- the
points next to the folds (`|dlnA/dlnγ| > 2`; Newton at fixed (γ, Ω) fails at the fold
itself, such points are not counted); *max dist. to curve* -- distance to the dense
continuation FRC, Ω and A normalised by their ranges in the window; *folds* -- the
turning points of Ω along the measured curve that reverse it by more than three times its
local scatter (`folds_of`), relative error in Ω and the largest error as a fraction of
the width of the bistable range;
*control floor* -- 3σ noise floor of `|u1|` relative to γ. Limits: amplitudes
within 1 %, folds within 2 %.

{frc_ref_lines}

Reproduce: `.venv/bin/python benchmarks/bench_cbc_forced.py` (wall times: shared 2-core
machine; `--only frc|scurve` runs one part and prints only).
"""
    if partial:
        print(md)
    else:
        write_section("cbc_forced", md)
        print(md)


if __name__ == "__main__":
    main()
