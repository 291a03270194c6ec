#!/usr/bin/env python
"""Run every ``benchmarks/bench_*.py`` script, one after another, each in its own process.

Each script writes its own section of BENCHMARKS.md. Scripts run sequentially (the
machines are small and timings must not compete with each other); a failing script
does not stop the others. Exit status is non-zero if any script failed.

Usage: ``python benchmarks/run_all.py [-k NAME ...] [-- ARGS...]`` — ``-k`` keeps only
scripts whose name contains one of the given substrings; arguments after ``--`` are
passed to every script.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def discover(keep: list[str] | None = None) -> list[Path]:
    """The benchmark scripts, sorted by name, optionally filtered by substrings."""
    scripts = sorted(HERE.glob("bench_*.py"))
    if keep:
        scripts = [s for s in scripts if any(k in s.stem for k in keep)]
    return scripts


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    extra: list[str] = []
    if "--" in argv:
        i = argv.index("--")
        argv, extra = argv[:i], argv[i + 1 :]
    ap = argparse.ArgumentParser(description="Run all bifid benchmarks.")
    ap.add_argument(
        "-k",
        action="append",
        dest="keep",
        metavar="NAME",
        help="only scripts whose name contains NAME (repeatable)",
    )
    a = ap.parse_args(argv)
    scripts = discover(a.keep)
    if not scripts:
        print("run_all: no benchmark scripts found", file=sys.stderr)
        return 1
    results: list[tuple[str, int, float]] = []
    for script in scripts:
        print(f"run_all: {script.name} ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        try:
            rc = subprocess.call([sys.executable, str(script), *extra], cwd=HERE.parent)
        except OSError as exc:
            print(f"run_all: could not start {script.name}: {exc}", file=sys.stderr)
            rc = 127
        dt = time.perf_counter() - t0
        results.append((script.name, rc, dt))
        state = "ok" if rc == 0 else f"FAILED (exit {rc})"
        print(f"run_all: {script.name} {state} in {dt:.0f} s", file=sys.stderr, flush=True)
    failed = [r for r in results if r[1] != 0]
    print("\nrun_all summary:", file=sys.stderr)
    for name, rc, dt in results:
        print(f"  {'ok    ' if rc == 0 else 'FAILED'} {name} ({dt:.0f} s)", file=sys.stderr)
    if failed:
        print(
            f"run_all: {len(failed)} of {len(results)} benchmarks failed: "
            + ", ".join(name for name, _, _ in failed),
            file=sys.stderr,
        )
        return 1
    print(f"run_all: all {len(results)} benchmarks passed", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
