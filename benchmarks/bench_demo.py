#!/usr/bin/env python
"""The demos end to end: wall time per stage, the cached second run, the checks.

Runs ``bifid demo flutter`` and ``bifid demo forced`` into fresh temporary directories (each
in its own process, as a user would), then once more to time the cached re-run, renders
each report in headless Chromium when installed, and writes the "demo" section of
BENCHMARKS.md. Usage: ``python benchmarks/bench_demo.py [--only flutter|forced]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import write_section

BIFID = Path(sys.executable).with_name("bifid")
RESULTS = Path(__file__).resolve().parent / "results" / "demo.json"


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def run_demo(which: str, out: Path) -> tuple[float, float, dict]:
    """Wall and CPU seconds (all threads of the demo's process) and the summary."""
    t0, c0 = time.perf_counter(), _children_cpu()
    r = subprocess.run(
        [str(BIFID), "demo", which, "--out", str(out), "--resume", "--json", "--quiet"],
        capture_output=True,
        text=True,
    )
    wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
    if r.returncode != 0:
        raise SystemExit(f"bifid demo {which} failed ({r.returncode}): {r.stderr[-2000:]}")
    return wall, cpu, json.loads(r.stdout)["summary"]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", choices=["flutter", "forced"], default=None)
    args = ap.parse_args()
    from bifid.report.render import check_report, find_chromium

    lines = [
        "## demo — `bifid demo flutter|forced` end to end",
        "",
        "Fresh output directory, each demo in its own process (JIT compilation included; "
        "the persistent compilation cache may be warm), then a second run in the same "
        "directory (every stage reused from the cache). Limit: 10 min on 2 cores. Wall "
        "times per stage; CPU = user + system time of the demo's process (all threads), "
        "less inflated than wall time when other jobs share the cores (load average in "
        "the last column).",
        "",
        "| demo | first run [s] | CPU [s] | truth | campaign | model | mechanistic | "
        "compare + report | second run [s] | CPU [s] | ratio | checks passed | "
        "Chromium: figures shown | load |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    # rows of a demo not run this time (--only) are kept from the last run that measured it
    rows = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    for which in [args.only] if args.only else ["flutter", "forced"]:
        with tempfile.TemporaryDirectory(prefix=f"bifid-demo-{which}-") as tmp:
            out = Path(tmp)
            load0 = os.getloadavg()[0]
            wall1, cpu1, s1 = run_demo(which, out)
            wall2, cpu2, _s2 = run_demo(which, out)
            load = f"{load0:.1f}–{os.getloadavg()[0]:.1f}"
            t = s1["timings_s"]
            chk = s1["checks"]
            shown = "not installed"
            if find_chromium() is not None:
                res = check_report(out / "report.html")
                shown = f"{res['decoded']}/{res['in_html']}"
            row = (
                f"| {which} | {wall1:.0f} | {cpu1:.0f} | {t['truth']:.0f} | "
                f"{t['campaign']:.0f} | {t['model']:.0f} | {t.get('mechanistic', 0):.0f} | "
                f"{t['compare']:.0f} | {wall2:.1f} | {cpu2:.1f} | "
                f"{wall1 / wall2:.0f}× | {sum(c['passed'] for c in chk.values())}/{len(chk)} | "
                f"{shown} | {load} |"
            )
            detail = f"**{which}** errors: " + ", ".join(
                f"{k} = {v['value']:.4g} (limit {v['limit']:g})" for k, v in chk.items()
            )
            stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
            rows[which] = {"row": row, "detail": detail, "run": stamp}
            print(row, flush=True)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(rows, indent=1) + "\n")
    names = [w for w in ("flutter", "forced") if w in rows]
    lines += [rows[w]["row"] for w in names]
    details = [f"{rows[w]['detail']} (run {rows[w]['run']})" for w in names]
    write_section("demo", "\n".join([*lines, "", *details]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
