#!/usr/bin/env python
"""Benchmark: periodic orbits and forced responses — mesh adaptation, Floquet, resonances.

Tasks (each timed as a user runs it, through the public API; wall and CPU time, medians
of ``--repeats`` warm runs after one warm-up run, which also gives the compile time):

* **Adaptation cost** — the van der Pol orbit branch from the Hopf point at mu = 0 to
  ``MU_END`` (relaxation oscillations: the mesh grows from 64 to 512 points), adaptive
  against a fixed mesh of 512 points (the mesh the adaptive run ends on), in the same
  run; accuracy of the period at ``MU_END`` against a direct simulation (SciPy DOP853).
* **Narrow resonance** — ``frc duffing --forcing 0.1 --omega-range 0.25 0.45 --set
  zeta=0.002 --set gamma=1``: the 3:1 superharmonic peak (0.1830 at 0.3373) located.
* **Floquet** — the ``hopf`` branch from mu = -1 to 100: labels against the analytic
  multipliers (the largest ``e^-2645``).
* **Backbones** — both modes of ``shaw_pierre`` over amplitudes 0.01–2 against the
  undamped nonlinear normal modes by SciPy shooting.

Run ``python benchmarks/bench_orbits.py`` (or ``make bench``); writes the "orbits"
section of BENCHMARKS.md. ``--sections adaptation --no-write`` runs one part and prints.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq, fsolve

import bifid  # noqa: F401  (enables float64)
from _report import write_section
from bifid.continuation import backbone, continue_from_hopf, frc
from bifid.systems import get_system

MU_END = 2.0


def log(msg: str) -> None:
    print(f"[bench_orbits {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def timed(fn: Callable, repeats: int):
    """(result, compile_s, wall medians, cpu medians): one warm-up, then ``repeats``."""
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    first = time.perf_counter() - t0
    walls, cpus = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    wall = statistics.median(walls)
    return out, max(first - wall, 0.0), wall, statistics.median(cpus)


def vdp_period(mu: float) -> float:
    def f(t, z):
        return [z[1], 2 * mu * z[1] - z[0] ** 2 * z[1] - z[0]]

    z0 = solve_ivp(f, (0, 200), [2.0, 0.0], rtol=1e-12, atol=1e-12, method="DOP853").y[:, -1]
    sol = solve_ivp(f, (0, 60), z0, rtol=1e-13, atol=1e-14, method="DOP853", dense_output=True)
    ts = np.linspace(0, 60, 60001)
    z = sol.sol(ts)[0]
    up = np.flatnonzero((z[:-1] < 0) & (z[1:] >= 0))[:3]
    t = [brentq(lambda s: sol.sol(s)[0], ts[i], ts[i + 1], xtol=1e-14) for i in up]
    return t[2] - t[1]


def adaptation(repeats: int) -> list[str]:
    s = get_system("vanderpol")
    rows = [
        f"| run | end | orbits | meshes used | period error at μ = {MU_END:g} | "
        "compile [s] | wall [s] | CPU [s] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    T_ref = vdp_period(MU_END)
    results = {}
    for name, kw in (
        ("adaptive 64 → 512", {"n_mesh": 64, "max_mesh": 512}),
        ("fixed 512", {"n_mesh": 512, "max_mesh": 512}),
    ):
        log(f"vanderpol {name}")
        (_, (br,)), comp, wall, cpu = timed(
            lambda kw=kw: continue_from_hopf(s, "mu", -0.5, MU_END, **kw), repeats
        )
        used, counts = np.unique(br.data["n_mesh"], return_counts=True)
        meshes = ", ".join(f"{m}×{c}" for m, c in zip(used, counts, strict=True))
        err = abs(br.data["period"][-1] - T_ref) / T_ref
        results[name] = wall
        rows.append(
            f"| {name} | {br.status} at {br.params[-1]:g} | {len(br)} | {meshes} | "
            f"{err:.1e} | {comp:.1f} | {wall:.1f} | {cpu:.1f} |"
        )
    ratio = results["adaptive 64 → 512"] / results["fixed 512"]
    rows.append("")
    rows.append(f"Adaptive / fixed fine mesh (wall, median): **{ratio:.2f}**.")
    return rows


def resonance(repeats: int) -> list[str]:
    s = get_system("duffing")
    p = s.param_vector(zeta=0.002, gamma=1.0)
    log("duffing 3:1 resonance")
    br, comp, wall, cpu = timed(lambda: frc(s, 0.1, (0.25, 0.45), p=p), repeats)
    peaks = sorted(br.special("peak"), key=lambda sp: -sp.data["amplitude"])
    top = peaks[0]
    return [
        f"`frc duffing --forcing 0.1 --omega-range 0.25 0.45 --set zeta=0.002 --set "
        f"gamma=1`: {len(br)} points, peak {top.data['amplitude']:.6f} at Ω = "
        f"{top.param:.6f} (expected 0.1830 at 0.3373), {len(peaks)} located peaks; "
        f"compile {comp:.1f} s, wall {wall:.1f} s, CPU {cpu:.1f} s."
    ]


def floquet_labels(repeats: int) -> list[str]:
    s = get_system("hopf")
    log("hopf -1..100")
    (_, (br,)), comp, wall, cpu = timed(
        lambda: continue_from_hopf(s, "mu", -1.0, 100.0, n_mesh=16), repeats
    )
    r2 = br.data["amplitude"][:, 0] ** 2
    expo = (2 * r2 - 4 * r2**2) * 2 * np.pi
    truth = expo < 0
    wrong = int(np.sum(br.stable[1:] != truth[1:]))
    logm = br.data["floquet_log"][1:]
    far = np.take_along_axis(logm, np.argmax(np.abs(logm), axis=1)[:, None], axis=1)[:, 0]
    err = float(np.max(np.abs(far - expo[1:]) / np.maximum(1.0, np.abs(expo[1:]))))
    return [
        f"`hopf` branch, μ from −1 to 100: {len(br)} orbits, largest non-trivial "
        f"multiplier from e^{expo[1:].max():.2f} down to e^{expo.min():.0f}; wrong "
        f"stability labels: **{wrong}**; worst relative error of log|μ|: {err:.1e}; "
        f"compile {comp:.1f} s, wall {wall:.1f} s, CPU {cpu:.1f} s."
    ]


def nnm_frequency(A: float, mode: int, guess):
    kappa = 0.003

    def f(t, z):
        x1, v1, x2, v2 = z
        return [v1, -2 * x1 + x2 - kappa * x1**3, v2, x1 - 2 * x2]

    def half(u):
        s = solve_ivp(f, (0, u[1]), [A, 0, u[0], 0], rtol=1e-12, atol=1e-14, method="DOP853")
        return [s.y[1, -1], s.y[3, -1]]

    u = fsolve(half, guess, xtol=1e-13)
    return np.pi / u[1], u


def backbones(repeats: int) -> list[str]:
    s = get_system("shaw_pierre")
    rows = [
        "| mode | points | amplitude range | Ω range | max rel. error vs undamped NNM | "
        "min mode share | wall [s] |",
        "|---|---|---|---|---|---|---|",
    ]
    for mode in (0, 1):
        log(f"shaw_pierre backbone mode {mode}")
        br, _, wall, _ = timed(lambda mode=mode: backbone(s, (0.01, 2.0), mode=mode), repeats)
        A, W = br.data["observed_amplitude"], br.data["omega"]
        w0 = 1.0 if mode == 0 else np.sqrt(3.0)
        guess = [A[0] * (1 if mode == 0 else -1), np.pi / w0]
        err = 0.0
        warnings.simplefilter("ignore", RuntimeWarning)  # fsolve's progress notes
        for a, w in zip(A, W, strict=True):
            wn, guess = nnm_frequency(a, mode, guess)
            err = max(err, abs(w - wn) / wn)
        rows.append(
            f"| {mode} | {len(br)} | {A.min():.6g}–{A.max():.6g} | {W.min():.6f}–"
            f"{W.max():.6f} | {err:.1e} | {br.data['mode_share'].min():.6f} | "
            f"{wall:.1f} |"
        )
    return rows


SECTIONS = {
    "adaptation": (
        f"### Cost of mesh adaptation (van der Pol, μ from the Hopf point to {MU_END:g})",
        adaptation,
    ),
    "resonance": ("### A narrow superharmonic resonance", resonance),
    "floquet": ("### Floquet multipliers of strongly contracting orbits", floquet_labels),
    "backbones": ("### Backbones of both shaw_pierre modes", backbones),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument(
        "--sections",
        nargs="*",
        default=list(SECTIONS),
        choices=list(SECTIONS),
        help="run these sections only (with --no-write)",
    )
    ap.add_argument("--no-write", action="store_true", help="print, do not write BENCHMARKS.md")
    args = ap.parse_args()
    md = ["## orbits — mesh adaptation, Floquet multipliers, resonances, backbones"]
    for name in args.sections:
        md += ["", SECTIONS[name][0], ""]
        md += SECTIONS[name][1](args.repeats)
    md += ["", f"Reproduce: `python benchmarks/bench_orbits.py --repeats {args.repeats}`."]
    text = "\n".join(md)
    if not args.no_write and args.sections == list(SECTIONS):
        write_section("orbits", text)
    print(text)


if __name__ == "__main__":
    main()
