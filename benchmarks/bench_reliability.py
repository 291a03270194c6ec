#!/usr/bin/env python
"""Reliability: the CLI fuzz and fault-injection tests, counted.

Runs ``tests/test_cli_fuzz.py`` with more generated cases than the default suite
(``--examples`` per property, five properties) and ``tests/test_faults.py``, each in its own
pytest process, and writes the outcome counts -- cases tried, exit codes per command,
fault cases passed / skipped / failed -- into ``docs/reliability.md`` (between its
markers) and the "reliability" section of BENCHMARKS.md.

Usage: ``python benchmarks/bench_reliability.py [--examples N]`` (default 100).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DOC = ROOT / "docs" / "reliability.md"
START, END = "<!-- reliability:counts:start -->", "<!-- reliability:counts:end -->"
sys.path.insert(0, str(HERE))
from _report import write_section  # noqa: E402


def _pytest(test: str, env: dict[str, str]) -> tuple[dict[str, int], float, str]:
    """Run one test module; the pass/fail/skip counts from its closing line."""
    t0 = time.perf_counter()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            str(ROOT / "tests" / test),
        ],
        capture_output=True,
        text=True,
        env={**os.environ, **env},
        cwd=ROOT,
    )
    seconds = time.perf_counter() - t0
    last = (r.stdout.strip().splitlines() or [""])[-1]
    counts = {
        k: int(n) for n, k in re.findall(r"(\d+) (passed|failed|skipped|xfailed|error)", last)
    }
    return counts, seconds, last


def _fuzz_table(report: dict) -> tuple[str, int]:
    by_cmd: dict[str, collections.Counter[int]] = collections.defaultdict(collections.Counter)
    for key, n in report["outcomes"].items():
        cmd, _, code = key.rpartition(": exit ")
        by_cmd[cmd][int(code)] += n
    codes = (0, 2, 3, 4, 130)
    lines = [
        "| command | cases | " + " | ".join(f"exit {c}" for c in codes) + " |",
        "|---|---:|" + "---:|" * len(codes),
    ]
    for cmd in sorted(by_cmd):
        c = by_cmd[cmd]
        lines.append(
            f"| `{cmd}` | {sum(c.values())} | " + " | ".join(str(c.get(k, 0)) for k in codes) + " |"
        )
    total = collections.Counter()
    for c in by_cmd.values():
        total.update(c)
    lines.append(
        f"| **all** | **{sum(total.values())}** | "
        + " | ".join(f"**{total.get(k, 0)}**" for k in codes)
        + " |"
    )
    return "\n".join(lines), sum(total.values())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=100, help="cases per fuzz property")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        report_path = Path(tmp) / "fuzz.json"
        fuzz, fuzz_s, fuzz_line = _pytest(
            "test_cli_fuzz.py",
            {"BIFID_FUZZ_EXAMPLES": str(args.examples), "BIFID_FUZZ_REPORT": str(report_path)},
        )
        report = (
            json.loads(report_path.read_text())
            if report_path.exists()
            else {"outcomes": {}, "budget_s": float("nan")}
        )
    faults, faults_s, faults_line = _pytest("test_faults.py", {})
    table, n_cases = _fuzz_table(report)
    when = time.strftime("%Y-%m-%d", time.gmtime())
    body = (
        f"Measured {when} by `make bench` (`benchmarks/bench_reliability.py --examples "
        f"{args.examples}`).\n\n"
        f"**CLI fuzz** (`tests/test_cli_fuzz.py`): {n_cases} generated hostile command lines "
        f"in {fuzz_s:.0f} s; every property held in {fuzz.get('passed', 0)} of "
        f"{sum(fuzz.values())} tests (pytest: `{fuzz_line}`). Cases still computing after "
        f"{report['budget_s']:g} s were interrupted as Ctrl-C would, and counted under exit "
        "130.\n\n" + table + "\n\n"
        f"**Fault injection** (`tests/test_faults.py`): {faults.get('passed', 0)} cases passed, "
        f"{faults.get('failed', 0)} failed, {faults.get('skipped', 0)} skipped, "
        f"{faults.get('xfailed', 0)} known to fail, in {faults_s:.0f} s "
        f"(pytest: `{faults_line}`).\n"
    )
    text = DOC.read_text()
    if START in text and END in text:
        head, rest = text.split(START, 1)
        text = head + START + "\n" + body + END + rest.split(END, 1)[1]
        DOC.write_text(text)
    write_section("reliability", "## reliability — CLI fuzz and fault injection\n\n" + body)
    print(body)
    return 0 if not fuzz.get("failed") and not faults.get("failed") else 1


if __name__ == "__main__":
    sys.exit(main())
