"""The user guide builds (strict: no broken links, no page left out of the navigation)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_mkdocs_build_strict(tmp_path):
    """Check that `mkdocs build --strict` succeeds and renders every page of the nav."""
    pytest.importorskip("mkdocs")
    r = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    import yaml

    nav = yaml.safe_load((ROOT / "mkdocs.yml").read_text())["nav"]

    def flatten(items):
        for item in items:
            value = next(iter(item.values()))
            yield from flatten(value) if isinstance(value, list) else [value]

    pages = list(flatten(nav))
    assert any(p.startswith("api/") for p in pages)
    for page in pages:
        html = tmp_path / (page[:-3] + "/index.html" if page != "index.md" else "index.html")
        assert html.exists(), page
        assert html.stat().st_size > 2000
