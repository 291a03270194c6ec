"""Render report(s) in headless Chromium and check that every figure shows.

Usage: ``python scripts/check_report.py DIR/report.html [...] [--screenshot FILE.png]``.
Prints one JSON object per report; exit status 1 if any figure failed to render, 2 when
no Chromium is installed.
"""

from __future__ import annotations

import argparse
import json
import sys

from bifid.report.render import check_report, find_chromium


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("reports", nargs="+")
    ap.add_argument("--screenshot", default=None, help="PNG of the (first) rendered page")
    args = ap.parse_args()
    if find_chromium() is None:
        print("no Chromium: install the Debian package 'chromium'", file=sys.stderr)
        return 2
    ok = True
    for i, path in enumerate(args.reports):
        res = check_report(path, args.screenshot if i == 0 else None)
        print(json.dumps({"report": path, **res}))
        ok &= bool(res["ok"])
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
