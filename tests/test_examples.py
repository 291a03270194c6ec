"""Check that every script in ``docs/examples`` runs as the docs say (exit status 0).

Scripts run in a fresh process from a temporary directory, with ``BIFID_EXAMPLE_OUT``
pointing there so that figures and files they write never touch the repository. A script
whose first lines contain ``# bifid-example: slow`` runs only with ``--runslow``.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "docs" / "examples").rglob("*.py"))


def _is_slow(path: Path) -> bool:
    return any("bifid-example: slow" in line for line in path.read_text().splitlines()[:30])


@pytest.mark.parametrize(
    "script",
    [
        pytest.param(
            p,
            id=p.relative_to(ROOT / "docs" / "examples").as_posix(),
            marks=[pytest.mark.slow] if _is_slow(p) else [],
        )
        for p in EXAMPLES
    ],
)
def test_example_runs(script: Path, tmp_path: Path, shared_data: Path) -> None:
    """Check that the example exits with status 0 and writes nothing into the repository."""
    env = {**os.environ, "BIFID_EXAMPLE_OUT": str(tmp_path), "MPLBACKEND": "Agg"}
    before = {p: p.stat().st_mtime for p in (ROOT / "docs").rglob("*") if p.is_file()}
    r = subprocess.run(
        [sys.executable, str(script)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    changed = [p for p, t in before.items() if p.exists() and p.stat().st_mtime != t]
    assert not changed, f"the example wrote into the repository: {changed}"
