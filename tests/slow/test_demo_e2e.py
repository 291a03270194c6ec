"""The whole demos, as ``make demo`` runs them (``pytest --runslow tests/slow``).

Each runs experiment → model → prediction → report in a temporary directory, asserts the
report's checks, that a second run reuses every stage, and that Chromium shows every figure.
"""

from __future__ import annotations

import json
import time

import pytest

from bifid.cli import main
from bifid.report.render import check_report, find_chromium

pytestmark = pytest.mark.slow


def _run(which, out, capsys):
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(["demo", which, "--out", str(out), "--resume", "--json", "--quiet"])
    assert e.value.code == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("which", ["flutter", "forced"])
def test_demo_end_to_end(which, tmp_path, capsys):
    """Check the demo's checks pass, it finishes in 10 min, and a re-run reuses everything."""
    t0 = time.perf_counter()
    first = _run(which, tmp_path, capsys)["summary"]
    wall = time.perf_counter() - t0
    assert wall < 600, wall
    failed = {k: v for k, v in first["checks"].items() if not v["passed"]}
    assert not failed, failed
    for name in ("report.html", "dataset.nc", "model", "summary.json"):
        assert (tmp_path / name).exists(), name
    t0 = time.perf_counter()
    second = _run(which, tmp_path, capsys)["summary"]
    assert set(second["stages_reused"]) >= {"truth", "campaign", "model"}
    assert time.perf_counter() - t0 < wall / 3
    for k, v in first["errors"].items():
        assert second["errors"][k] == pytest.approx(v, rel=1e-6, abs=1e-12), k
    if find_chromium() is not None:
        res = check_report(tmp_path / "report.html")
        assert res["ok"], res
