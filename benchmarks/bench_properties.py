#!/usr/bin/env python
"""Benchmark: the property test of bifurcation diagrams on many random variants.

Every built-in system, ``--n`` random parameter variants each (20 by default): the
autonomous ones through :func:`bifid.continuation.bifurcation_diagram` (what ``bifid
continue`` computes), the forced ones through :func:`bifid.continuation.frc`; checked by
every registered property check of ``tests/_properties.py`` against independent
computations written for the test (a dense eigenvalue scan of the equilibria: no false
and no missed Hopf point, fold or real crossing; independent Floquet multipliers of the
orbits and forced responses: stability labels, no false and no missed fold, cycle fold,
period doubling or torus point). ``--orbits`` also continues the orbits of the autonomous
systems and runs the orbit checks (the forced systems always have them). ``--systems``
picks some; the table is rewritten after each system, so a partial run reports what ran.

``--auto`` adds random variants of AUTO-07p demos (``benchmarks/auto_demos``), whose
equilibria are not trivial: folds, several Hopf points, branch points.

Run ``python benchmarks/bench_properties.py`` (or ``make bench``); writes the
"properties" section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests"))

import numpy as np  # noqa: E402

from _properties import (  # noqa: E402
    CHECKS,
    ORBIT_KINDS,
    SAMPLERS,
    Variant,
    autonomous_builtins,
    forced_builtins,
    run_variant,
    variants,
)
from _report import write_section  # noqa: E402
from bench_auto import load_demo  # noqa: E402


def _u(rng: np.random.Generator, value: float, spread: float) -> float:
    return float(value * rng.uniform(1 - spread, 1 + spread))


def _lrz(rng: np.random.Generator) -> Variant:
    sigma, beta, rho = rng.uniform(5.0, 15.0), rng.uniform(1.0, 4.0), 40.0
    x = float(np.sqrt(beta * (rho - 1)))
    return Variant("lrz", "rho", rho, 2.0, {"sigma": sigma, "beta": beta}, (x, x, rho - 1))


#: random variants of AUTO-07p demos (``--auto``)
AUTO_SAMPLERS = {
    "ab": lambda rng: Variant(
        "ab", "Da", 0.0, 0.3, {"B": rng.uniform(8.0, 20.0), "beta": rng.uniform(2.0, 4.0)}
    ),
    "abc": lambda rng: Variant(
        "abc",
        "D",
        0.0,
        0.4,
        {"B": _u(rng, 8.0, 0.1), "beta": _u(rng, 1.55, 0.1), "s": _u(rng, 0.04, 0.5)},
    ),
    "lrz": _lrz,
    "tor": lambda rng: Variant(
        "tor",
        "nu",
        -0.9,
        -0.4,
        {"beta": _u(rng, 0.5, 0.1), "gamma": _u(rng, -0.6, 0.1), "r": _u(rng, 0.6, 0.1)},
    ),
    "plp": lambda rng: Variant(
        "plp",
        "rho",
        2.021628,
        6.0,
        {"alpha": _u(rng, 0.2, 0.05), "kappa": _u(rng, 0.1, 0.05)},
        (45.55974, 177.7987),
    ),
}


def log(msg: str) -> None:
    print(f"[bench_properties {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20, help="variants per system (>= 20 for the table)")
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--orbits", action="store_true", help="continue orbits, run orbit checks")
    ap.add_argument("--auto", action="store_true", help="also variants of AUTO-07p demos")
    ap.add_argument("--systems", nargs="+", help="only these systems (default: all)")
    ap.add_argument("--no-write", action="store_true", help="print, do not write BENCHMARKS.md")
    a = ap.parse_args(argv)
    import bifid  # noqa: F401  (float64)

    names = autonomous_builtins() + forced_builtins()
    if a.auto:
        for name, sampler in AUTO_SAMPLERS.items():
            load_demo(name)
            SAMPLERS[name] = sampler
        names += list(AUTO_SAMPLERS)
    if a.systems:
        names = [n for n in names if n in a.systems]
    rows, failures, md = [], [], ""
    for name in names:
        t0 = time.perf_counter()
        n_hopf = n_fold = n_orbit = n_cand = 0
        bad = 0
        for k, v in enumerate(variants(name, a.n, a.seed)):
            try:
                diagram, fails = run_variant(v, orbits=a.orbits)
            except Exception as exc:  # a variant that fails is a reported failure
                fails, diagram = [f"{type(exc).__name__}: {exc}"], None
            if diagram is not None:
                n_hopf += len(diagram.special("hopf"))
                n_fold += len(diagram.branches[0].special("fold"))
                n_orbit += sum(
                    s.kind in ORBIT_KINDS and s.kind != "fold"
                    for b in diagram.branches
                    if b.kind != "equilibrium"
                    for s in b.special_points
                )
                n_cand += sum(len(b.candidates) for b in diagram.branches)
            bad += bool(fails)
            failures += [f"{v.label}: {f}" for f in fails]
            log(f"{name} {k + 1}/{a.n}: {'ok' if not fails else fails}")
        rows.append((name, a.n, n_hopf, n_fold, n_orbit, n_cand, bad, time.perf_counter() - t0))
        md = render(rows, failures, a)
        if not a.no_write:
            write_section("properties", md)
    print(md)
    return 1 if failures else 0


def render(rows: list[tuple], failures: list[str], a: argparse.Namespace) -> str:
    """The BENCHMARKS.md section for the systems run so far."""
    checks = ", ".join(n for n, (_, orb, _k) in CHECKS.items() if a.orbits or not orb)
    lines = [
        "## Property test of bifurcation diagrams (`bench_properties.py`)",
        "",
        f"Random parameter variants of the built-in systems"
        f"{' and of AUTO-07p demos' if a.auto else ''} (seed {a.seed}), checks: {checks}"
        f"{' (orbits of the autonomous systems included)' if a.orbits else ''};",
        "each against an independent dense scan written for the test (`tests/_properties.py`):",
        "the equilibrium by Newton on a uniform grid of 2001 parameter values and the",
        "eigenvalues of its Jacobian, along each branch up to its first fold (a uniform grid",
        "cannot follow a branch round a fold; there bifid must have located one). Hopf points",
        "and folds: all located points of the variants (also beyond a first fold); failing: a",
        "false or missed point, or a Hopf candidate. Orbits (and the FRCs of the forced",
        "systems, over a range round their resonances): Floquet multipliers by SciPy",
        "(variational equation, DOP853) on twelve orbits spread over each branch and both",
        "neighbours of every located point: stability labels, every change of stability",
        "at a located point, every located point's multiplier at +1, −1 or on the circle.",
        "",
        "| system | variants | Hopf points | folds | orbit bifurcations | candidates "
        "| variants failing | wall [s] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    lines += ["| " + " | ".join(str(v) for v in r[:-1]) + f" | {r[-1]:.0f} |" for r in rows]
    if failures:
        lines += ["", "Failures:"] + [f"- {f}" for f in failures]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
