"""CBC benchmark: PP-CBC diagrams of the flutter model and its variants, through the CLI.

Run from the repository root::

    .venv/bin/python benchmarks/bench_cbc.py                  # writes BENCHMARKS.md "cbc"
    .venv/bin/python benchmarks/bench_cbc.py --only diagram   # one part, printed only

Measures, as a user would (``bifid cbc ...`` in a fresh process, compilation and start-up
included; CPU time of the process beside the wall time):

1. **diagram** -- ``bifid cbc flutter --protocol ppcbc --values 15,15.5,...,17.5,17.9``:
   both LCOs at every speed (14), noise-free and with measurement noise of 1 % of the
   smallest LCO's amplitude (``--noise-fraction 0.01``), and the same campaign by the
   library (:func:`bifid.cbc.ppcbc_campaign`) in this process: first call (numba cache and
   JIT) and a second one;
2. **continuation** -- ``--continuation N --range 17.5 LOW`` from the LCOs at 17.5 m/s round
   the cycle fold, for the default model and three variants of the pitch stiffness;
3. **variants** -- ``--set ka2=… --set ka3=…`` (0.5-1.5 × the defaults, one with period
   doubling of the large LCO inside the range) × 6 speeds in each bistable range, up to
   where an LCO reaches 80 % of the rig's safety envelope; every LCO of the model at
   each speed counted once (``--variant 1.25,0.75`` runs one variant, printed only).

Every measured LCO is compared with the model's orbit Newton-corrected at the measured
speed (Fourier collocation from the nearest orbit of the continued branch,
:func:`bifid.cbc._truth.lco_truth`); amplitudes are ``max |x - x̄|``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _report import write_section

ROOT = Path(__file__).resolve().parents[1]
BIFID = str(ROOT / ".venv" / "bin" / "bifid")
SPEEDS = (15.0, 15.5, 16.0, 16.5, 17.0, 17.5, 17.9)
KA2, KA3 = 751.6, 5006.7
# (ka2, ka3) factors: bistable ranges from `bifid continue flutter --set ... --param U`
VARIANTS = ((1.0, 0.5), (1.25, 0.75), (0.75, 0.5), (0.75, 0.75), (1.0, 1.25), (1.25, 1.0))
PD_VARIANT = (1.0, 0.5)  # the large LCO loses stability by period doubling at U ≈ 15.1


def cli(args: list[str], env: dict[str, str] | None = None) -> tuple[dict, float, float, int]:
    """``bifid cbc ARGS --json`` (``env``: extra environment variables): (JSON, wall s,
    CPU s of the process, exit code)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run(
        [BIFID, "cbc", *args, "--json", "--quiet"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, **(env or {})},
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    out = (
        json.loads(r.stdout)
        if r.stdout.strip().startswith("{")
        else {"points": [], "failures": [{"reason": r.stderr.strip()[-300:]}], "complete": False}
    )
    return out, wall, cpu, r.returncode


def compare(points: list[dict], overrides: dict[str, float], lo: float, hi: float) -> dict:
    """Add ``truth_amplitude``, ``relative_error``, ``truth_stable`` to each point; return
    the continued branch (``param``, ``amplitude``, ``stable``)."""
    from bifid.cbc._truth import lco_truth
    from bifid.systems import get_system

    s = get_system("flutter")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return lco_truth(s, s.param_vector(overrides), "U", lo, hi, points, ["h", "alpha"], "h")


def curve_distance(points: list[dict], curve: dict | None) -> float:
    """Largest distance of a point to the continued branch, relative to the point's
    amplitude: ``min sqrt((ΔU/U)² + (Δh/h)²)`` over the branch densified as a polyline (the
    measure that holds at a fold, where the orbit at a fixed U is ill-conditioned)."""
    if curve is None or not points:
        return float("nan")
    u, h = np.asarray(curve["param"]), np.asarray(curve["amplitude"]["h"])
    t = np.linspace(0.0, 1.0, 41)[:, None]
    ud, hd = (u[:-1] + t * np.diff(u)).ravel(), (h[:-1] + t * np.diff(h)).ravel()
    return max(
        float(
            np.min(
                np.hypot(
                    (ud - p["param"]) / p["param"], (hd - p["amplitude"]["h"]) / p["amplitude"]["h"]
                )
            )
        )
        for p in points
    )


def _err(p: dict) -> float:
    e = p.get("relative_error")
    return max(abs(v) for v in e.values()) if e else float("nan")


def _max_err(points: list[dict]) -> str:
    """The largest error of the points in %, and how many have no truth (the model's
    orbit could not be corrected at their speed, e.g. at a cycle fold)."""
    errs = [_err(p) for p in points]
    ok = [e for e in errs if np.isfinite(e)]
    text = f"{100 * max(ok):.2f} %" if ok else "–"
    return text + (f" ({len(errs) - len(ok)} without truth)" if len(ok) < len(errs) else "")


def table(points: list[dict]) -> list[str]:
    rows = [
        "| U [m/s] | label | h [mm] | h truth | err h | α [rad] | α truth | err α |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for p in sorted(points, key=lambda q: (q["param"], q["amplitude"]["h"])):
        t = p.get("truth_amplitude", {})
        e = p.get("relative_error", {})
        lab = {True: "stable", False: "unstable"}.get(p["stable"], "?")
        rows.append(
            f"| {p['param']:.3f} | {lab} | {1e3 * p['amplitude']['h']:.4f} | "
            f"{1e3 * t.get('h', np.nan):.4f} | {100 * e.get('h', np.nan):+.2f} % | "
            f"{p['amplitude']['alpha']:.5f} | {t.get('alpha', np.nan):.5f} | "
            f"{100 * e.get('alpha', np.nan):+.2f} % |"
        )
    return rows


# ------------------------------------------------------------------------------ diagram
def diagram(tmp: Path) -> list[str]:
    md = ["### The PP-CBC diagram at U = 15, 15.5, …, 17.5 and 17.9 m/s (14 LCOs)", ""]
    values = ",".join(f"{u:g}" for u in SPEEDS)
    runs = {}
    # the last run as on a fresh machine: the numba loop and every XLA program compiled
    empty = {"BIFID_CACHE_DIR": str(tmp / "cache"), "BIFID_JAX_CACHE": str(tmp / "jax")}
    noisy = ["--noise-fraction", "0.01"]
    for label, extra, env in (
        ("noise-free", [], None),
        ("1 % noise", noisy, None),
        ("1 % noise, empty caches", noisy, empty),
    ):
        out = tmp / f"diagram_{len(runs)}.nc"
        cmd = [
            "flutter",
            "--protocol",
            "ppcbc",
            "--values",
            values,
            "--seed",
            "1",
            "--no-truth",
            "--out",
            str(out),
            *extra,
        ]
        d, wall, cpu, rc = cli(cmd, env)
        compare(d["points"], {}, min(SPEEDS), max(SPEEDS))
        runs[label] = (d, wall, cpu, rc, cmd)
        print(
            f"diagram {label}: {len(d['points'])} LCOs, {wall:.1f} s wall, {cpu:.1f} s CPU, "
            f"max error {100 * max(map(_err, d['points']), default=np.nan):.3f} %",
            flush=True,
        )
    lib = library()
    md += [
        "Defaults of `flutter` only (polar target n_h = 10 in the (h, α) plane, "
        "kp = −150, kd = −20, 100 Hz output filter, the amplitude scan of its "
        "settings, grid continued above where Ξ < 0); 1 % noise means σ of 1 % of the "
        "smallest LCO's amplitude per channel (σ_h = 74 µm, σ_α = 0.22 mrad), records of "
        "8 periods. Truth: the model's orbit Newton-corrected at the measured U.",
        "",
        "| run | LCOs | failures | max error | wall | CPU | wall / library 2nd call |",
        "|---|---|---|---|---|---|---|",
    ]
    base = lib["second call"]["wall"]
    for label, (d, wall, cpu, rc, _) in runs.items():
        md.append(
            f"| CLI, {label} (exit {rc}) | {len(d['points'])} / 14 | "
            f"{len(d.get('failures', []))} | "
            f"{100 * max(map(_err, d['points']), default=np.nan):.3f} % | "
            f"**{wall:.1f} s** | {cpu:.1f} s | {wall / base:.2f} |"
        )
    for label, r in lib.items():
        md.append(
            f"| library `ppcbc_campaign`, 1 % noise, {label} | {r['n']} / 14 | "
            f"{r['failures']} | – | {r['wall']:.1f} s | {r['cpu']:.1f} s | "
            f"{r['wall'] / base:.2f} |"
        )
    md += [
        "",
        f"Machine load average when the diagram runs ended: {_load()}.",
    ]
    md += [
        "",
        "CLI wall and CPU include the interpreter, imports and compilation (the numba "
        "loop and XLA programs from their on-disk caches, which the first run fills; "
        "with empty caches, as the first run on a new machine, every one is compiled); "
        "the library's first call includes the rig's compilation in this process, its "
        "second call does not.",
        "",
        "Commands: `" + "bifid cbc " + " ".join(runs["1 % noise"][4]) + "` (and without "
        "`--noise-fraction`).",
        "",
        "**1 % noise:**",
        "",
        *table(runs["1 % noise"][0]["points"]),
        "",
        "**Noise-free:**",
        "",
        *table(runs["noise-free"][0]["points"]),
        "",
    ]
    return md


def _load() -> str:
    return " / ".join(f"{v:.1f}" for v in os.getloadavg()) + " (1/5/15 min, 2 cores)"


def library() -> dict[str, dict]:
    """The same campaign (1 % noise) in this process, twice."""
    from bifid.cbc import ppcbc_campaign

    out = {}
    for label in ("library, first call", "library, second call"):
        t0, c0 = time.perf_counter(), time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = ppcbc_campaign("flutter", param="U", values=SPEEDS, noise_fraction=0.01, seed=1)
        out[label.split(", ")[1]] = {
            "wall": time.perf_counter() - t0,
            "cpu": time.process_time() - c0,
            "n": len(r.points),
            "failures": len(r.failures),
        }
    return out


# ------------------------------------------------------------------------- continuation
def _sets(f2: float, f3: float) -> list[str]:
    return (
        []
        if (f2, f3) == (1.0, 1.0)
        else ["--set", f"ka2={KA2 * f2:.10g}", "--set", f"ka3={KA3 * f3:.10g}"]
    )


def _gap(points: list[dict]) -> float:
    """Largest step between consecutive measured points along the branch, relative to the
    branch's extent in (U, h) normalised by their ranges. The other LCOs of the first
    scan (recorded before the followed branch) are left out: the branch comes back to
    them at its end."""
    start = points[0]["param"] if points else None
    points = [p for i, p in enumerate(points) if i == 0 or p["param"] != start or i > 2]
    u = np.array([p["param"] for p in points])
    h = np.array([p["amplitude"]["h"] for p in points])
    if len(u) < 3:
        return np.inf
    du, dh = np.diff(u) / max(np.ptp(u), 1e-12), np.diff(h) / max(np.ptp(h), 1e-12)
    return float(np.max(np.hypot(du, dh)))


#: (ka2, ka3) factors: (START, LOW) of ``--range``. LOW just below the cycle fold. START
#: 17.5 m/s, where both LCOs exist and the large one is stable; not for (1.25, 0.75): its
#: large LCO is stable only from the fold (12.85) to U ≈ 14.9 (a Floquet multiplier
#: leaves the unit circle there; 3.0 at 17.5), and swings in pitch towards a saddle
#: equilibrium at α = -0.090 behind which lies a buckled pitch equilibrium
#: (α = -0.160): at 17.5 neither the scan nor a controller designed on the model holds it,
#: and a transient near it drops the rig into the buckled state. 14.5 m/s has both LCOs,
#: the large one stable, as 17.5 has for the others.
CONTINUATION_RANGES = {
    (1.0, 1.0): (17.5, 14.0),
    (1.0, 1.25): (17.5, 16.0),
    (0.75, 0.75): (17.5, 16.8),
    (1.25, 0.75): (14.5, 12.0),
}


def continuation(tmp: Path) -> list[str]:
    md = [
        "### `--continuation`: both LCO branches round the cycle fold",
        "",
        "`bifid cbc flutter --protocol ppcbc --continuation 40 --range START LOW "
        "--noise-fraction 0.01 [--set ka2=… --set ka3=…]`: the scan at START, then "
        "each LCO found there followed by continuation of the measured zero problem "
        "towards LOW (below the cycle fold) and back. START is 17.5 m/s except for "
        "(1.25, 0.75), whose large LCO is stable only between its cycle fold and "
        "U ≈ 14.9 m/s (beyond, it swings towards a saddle equilibrium of pitch that "
        "guards a buckled one): 14.5 m/s.",
        "",
        "| ka2, ka3 (× default) | START, LOW | points | unstable / stable | cycle fold: CBC | "
        "largest step (of the branch) | max error, same U | max distance | failures | wall |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (f2, f3), (start, low) in CONTINUATION_RANGES.items():
        out = tmp / f"cont_{f2}_{f3}.nc"
        cmd = [
            "flutter",
            "--protocol",
            "ppcbc",
            "--continuation",
            "40",
            "--range",
            f"{start:g}",
            f"{low:g}",
            "--noise-fraction",
            "0.01",
            "--seed",
            "1",
            "--no-truth",
            "--out",
            str(out),
            *_sets(f2, f3),
        ]
        d, wall, _cpu, _rc = cli(cmd)
        over = {} if (f2, f3) == (1.0, 1.0) else {"ka2": KA2 * f2, "ka3": KA3 * f3}
        curve = compare(d["points"], over, low, start)
        cont = d["points"]
        n_u = sum(p["stable"] is False for p in cont)
        n_s = sum(p["stable"] is True for p in cont)
        folds = ", ".join(f"{f['param']:.3f}" for f in d.get("cycle_folds", [])) or "–"
        fold_u = [f["param"] for f in d.get("cycle_folds", [])]
        # away from the cycle fold (0.1 m/s), where an orbit at a fixed U is well defined
        away = [p for p in cont if all(abs(p["param"] - u) > 0.1 for u in fold_u)]
        md.append(
            f"| {f2:g}, {f3:g} | {start:g}, {low:g} | {len(cont)} | {n_u} / {n_s} | {folds} | "
            f"{_gap(cont):.3f} | {100 * max(map(_err, away), default=np.nan):.2f} % "
            f"({len(away)}) | {100 * curve_distance(cont, curve):.2f} % | "
            f"{len(d.get('failures', []))} | {wall:.0f} s |"
        )
        print(md[-1], flush=True)
    md += [
        "",
        "Max error, same U: against the orbit Newton-corrected at the point's U, the points "
        "more than 0.1 m/s from the cycle fold; max distance: to the continued branch, "
        "`min √((ΔU/U)² + (Δh/h)²)`, every point. "
        "Largest step: the longest chord between consecutive points in the (U, h) "
        "plane with both normalised by the branch's extent (no gap at the fold: the "
        "steps there are among the shortest).",
        "",
    ]
    return md


# ----------------------------------------------------------------------------- variants
#: the speeds of a variant stop where one of its LCOs reaches this fraction of a limit of
#: the rig's safety envelope (the controlled transients on the way need the rest)
ENVELOPE_FRACTION = 0.8
#: a measured point is an LCO of the model at its speed when their heave amplitudes agree
MATCH_TOL = 0.05


def bistable(f2: float, f3: float) -> dict:
    """A variant's continued cycles: ``lo`` (cycle fold), ``hopf``, ``secondary`` points,
    ``hi`` (the Hopf speed, or lower: the speed where an LCO's peak of a state first
    reaches :data:`ENVELOPE_FRACTION` of the envelope) and ``limit`` (which state)."""
    from bifid.continuation import ContinuationOptions, continue_from_hopf
    from bifid.systems import get_system

    s = get_system("flutter")
    p = s.param_vector({"ka2": KA2 * f2, "ka3": KA3 * f3})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _eq, brs = continue_from_hopf(
            s,
            "U",
            10.0,
            22.0,
            p=p,
            n_mesh=48,
            orbit_options=(
                ContinuationOptions(
                    ds=1e-3, ds_max=0.3, ds_min=1e-9, p_min=8.0, p_max=22.0, max_steps=400
                )
            ),
        )
    br = brs[0]
    lo, hopf = float(np.min(br.params)), float(br.params[0])
    hi, limit = hopf, None
    m, n = int(br.meta.get("n_mesh", 48)), s.n_states
    for i in range(len(br)):
        orbit = br.solutions[i, : m * n].reshape(m, n)
        for name, (a, b) in s.envelope.states.items():
            peak = np.abs(orbit[:, s.state_index(name)]).max()
            if peak >= ENVELOPE_FRACTION * min(-a, b) and float(br.params[i]) < hi:
                hi, limit = float(br.params[i]), name
    return {
        "lo": lo,
        "hopf": hopf,
        "hi": hi,
        "limit": limit,
        "secondary": [(sp.kind, sp.param) for sp in br.special_points if sp.kind != "cycle_fold"],
    }


def requested(f2: float, f3: float, value: float, window: tuple[float, float]) -> list[float]:
    """Heave amplitudes (``max |h - h̄|``) of the variant's LCOs at ``value``: every
    crossing of its branch, Newton-corrected there -- the LCOs a scan there asks for."""
    from bifid.cbc._derive import cycles_at
    from bifid.continuation.truth import centred_amplitudes
    from bifid.systems import get_system

    s = get_system("flutter")
    p = s.param_vector({"ka2": KA2 * f2, "ka3": KA3 * f3})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cycles = cycles_at(s, p, "U", value, window)
    return sorted(float(centred_amplitudes(c[1])[s.state_index("h")]) for c in cycles)


def _concerns(f: dict, a: float) -> bool:
    """Whether a failure (its JSON) can be about the LCO of heave amplitude ``a``."""
    if "bracket" in f:
        lo, hi = sorted(float(v) for v in f["bracket"])
        return (1 - MATCH_TOL) * lo <= a <= (1 + MATCH_TOL) * hi
    if "lco" in f:
        return abs(a / float(f["lco"]) - 1) <= MATCH_TOL
    if "a_star" in f:
        return a >= (1 - MATCH_TOL) * float(f["a_star"])
    return True


def tally(points: list[dict], failures: list[dict], wanted: dict[float, list[float]]):
    """Per requested LCO (``wanted``: speed -> heave amplitudes of the model's LCOs):
    measured or not. Points of the same LCO count once, points of no requested LCO not
    at all. Returns ``(measured, missing)``, ``missing`` as ``(speed, amplitude, reason)``
    with the last failure at that speed that can be about it."""
    measured, missing = 0, []
    for v, amps in wanted.items():
        here = [p["amplitude"]["h"] for p in points if abs(p["param"] - v) <= 1e-3]
        hit = set()
        for h in here:
            k = min(range(len(amps)), key=lambda i: abs(h / amps[i] - 1), default=None)
            if k is not None and abs(h / amps[k] - 1) <= MATCH_TOL:
                hit.add(k)
        measured += len(hit)
        fails = [f for f in failures if abs(float(f.get("param", np.inf)) - v) <= 1e-3]
        for k, a in enumerate(amps):
            if k not in hit:
                why = [f for f in fails if _concerns(f, a)] or fails
                missing.append((v, a, str(why[-1]["reason"]) if why else "no failure recorded"))
    return measured, missing


def variants(tmp: Path, keep: Path | None = None, only: tuple | None = None) -> list[str]:
    md = [
        "### Flutter variants: other pitch stiffness, 6 speeds in each bistable range",
        "",
        "`bifid cbc flutter --protocol ppcbc --values V1,…,V6 --set ka2=… --set ka3=…` "
        "with every setting derived for the variant (the amplitude grid and noise "
        "reference from its continued cycles) except the gains and rig of `flutter`; "
        "the speeds span the bistable range (cycle fold to Hopf point, 5 % in from each "
        "end) where every LCO of the variant lies inside "
        f"{100 * ENVELOPE_FRACTION:.0f} % of the rig's safety envelope (heave 50 mm, "
        "pitch 0.35 rad, rates 2 m/s and 10 rad/s): a larger LCO, or the controlled "
        "transients that reach it, would trip a real rig's safety gate (the campaign "
        "refuses an LCO of the model outside the envelope, with that reason). Requested: "
        "every LCO of the variant at each speed (its continued branch's crossings); a "
        "point counts for the LCO whose heave amplitude it matches within 5 %, each LCO once.",
        "",
        "| ka2, ka3 (× default) | bistable range [m/s] | envelope | speeds [m/s] | "
        "secondary | measured | failures | max error | max error, unstable | wall |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    total, measured = 0, 0
    for f2, f3 in VARIANTS:
        if only is not None and (f2, f3) != only:
            continue
        b = bistable(f2, f3)
        lo, hi = b["lo"], b["hi"]
        w = hi - lo
        values = [float(f"{v:.4f}") for v in np.linspace(lo + 0.05 * w, hi - 0.05 * w, 6)]
        wanted = {v: requested(f2, f3, v, (lo, b["hopf"])) for v in values}
        out = (keep or tmp) / f"var_{f2}_{f3}.nc"
        cmd = [
            "flutter",
            "--protocol",
            "ppcbc",
            "--values",
            ",".join(f"{v:.4f}" for v in values),
            "--seed",
            "1",
            "--no-truth",
            "--out",
            str(out),
            *_sets(f2, f3),
        ]
        d, wall, _cpu, _rc = cli(cmd)
        compare(d["points"], {"ka2": KA2 * f2, "ka3": KA3 * f3}, lo, b["hopf"])
        if keep is not None:
            (keep / f"var_{f2}_{f3}.json").write_text(json.dumps(d, indent=1, default=str))
        got, missing = tally(d["points"], d.get("failures", []), wanted)
        n_req = sum(map(len, wanted.values()))
        total += n_req
        measured += got
        unstable = [
            p for p in d["points"] if p.get("truth_stable") is False or p["stable"] is False
        ]
        sec = ", ".join(f"{k} {u:.2f}" for k, u in b["secondary"]) or "–"
        env = "–" if b["limit"] is None else f"{b['limit']} above {hi:.2f}"
        md.append(
            f"| {f2:g}, {f3:g} | {lo:.2f} – {b['hopf']:.2f} | {env} | "
            f"{values[0]:.2f} – {values[-1]:.2f} | {sec} | {got} / {n_req} | "
            f"{len(d.get('failures', []))} | {_max_err(d['points'])} | "
            f"{_max_err(unstable)} | {wall:.0f} s |"
        )
        for v, a, why in missing:
            md.append(
                f"|  | not measured: U = {v:g}, h = {1e3 * a:.1f} mm | {why[:160]} | | | | | | | |"
            )
        print("\n".join(md[-1 - len(missing) :]), flush=True)
    md += [
        "",
        f"**{measured} of {total} requested LCOs measured "
        f"({100 * measured / max(total, 1):.0f} %)**; the others are listed with the last "
        "failure recorded at their speed that can be about them. Failures: the campaign's "
        "count (one per LCO it did not measure).",
        "",
    ]
    return md


def _with_part(part: list[str]) -> str:
    """The "cbc" section of BENCHMARKS.md with one part (its ``### `` subsection) replaced
    by ``part``, the other parts as they were."""
    start, end = "<!-- cbc:start -->", "<!-- cbc:end -->"
    text = (ROOT / "BENCHMARKS.md").read_text()
    if start not in text or end not in text:
        return "\n".join(part)
    body = text.split(start, 1)[1].split(end, 1)[0].strip().splitlines()
    body = [line for line in body if not line.startswith("_Run ")]
    cut = [i for i, line in enumerate(body) if line.startswith("### ")] + [len(body)]
    head, parts = body[: cut[0]], [body[a:b] for a, b in itertools.pairwise(cut)]
    title = part[0].split(":")[0].split(" at ")[0]
    parts = [part if p[0].split(":")[0].split(" at ")[0] == title else p for p in parts]
    if not any(p is part for p in parts):
        parts.append(part)
    return "\n".join([*head, *(line for p in parts for line in p)])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", choices=("diagram", "continuation", "variants"))
    ap.add_argument(
        "--print-only", action="store_true", help="print the tables, leave BENCHMARKS.md"
    )
    ap.add_argument("--keep", help="variants: keep each campaign's file and JSON in this folder")
    ap.add_argument(
        "--variant",
        help="variants: only this one, 'F2,F3' (factors of ka2, ka3); printed only",
    )
    args = ap.parse_args()
    only = None if args.variant is None else tuple(float(v) for v in args.variant.split(","))
    load = "{:.1f} / {:.1f} / {:.1f}".format(*os.getloadavg())
    keep = None if args.keep is None else Path(args.keep).resolve()
    parts = {
        "diagram": diagram,
        "continuation": continuation,
        "variants": lambda tmp: variants(tmp, keep, only),
    }
    md = [
        "## cbc — PP-CBC campaigns on the flutter model (virtual rig, 5 kHz)",
        "",
        "`benchmarks/bench_cbc.py`: every campaign through the CLI in a fresh process. "
        f"Machine load average at the start: {load} (1/5/15 min, 2 cores shared).",
        "",
    ]
    with tempfile.TemporaryDirectory() as d:
        for name, fn in parts.items():
            if args.only in (None, name):
                md += fn(Path(d))
                stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
                md += [f"_This part ran until {stamp}; load average then {_load()}._", ""]
                if args.only is None and name != "variants":
                    # what is measured so far, should a later part not finish
                    note = "_The later parts of this benchmark did not finish in this run._"
                    write_section("cbc", "\n".join([*md, "", note]))
    print("\n".join(md))
    if args.print_only or only is not None:
        return
    if args.only is None:
        write_section("cbc", "\n".join(md))
    else:  # this part replaced, the others kept (each part says when it ran)
        write_section("cbc", _with_part(md[4:]))


if __name__ == "__main__":
    main()
