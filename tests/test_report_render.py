"""Reports as a user sees them: self-contained HTML rendered by headless Chromium."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pytest

from bifid.report.html import Report
from bifid.report.render import check_report, find_chromium


def _report(tmp_path, n_png: int = 2, svg: bool = True):
    rep = Report("render test", intro="two figures and a table")
    sec = rep.section("figures")
    for k in range(n_png):
        fig, ax = plt.subplots(figsize=(3 + k, 2))
        ax.plot([0, 1], [0, k + 1])
        fig.savefig(tmp_path / f"f{k}.png")
        plt.close(fig)
        sec.append(rep.figure(tmp_path / f"f{k}.png", f"figure {k}"))
    if svg:
        fig, ax = plt.subplots()
        ax.plot([0, 1], [1, 0])
        fig.savefig(tmp_path / "v.svg")
        plt.close(fig)
        sec.append(rep.figure(tmp_path / "v.svg", "vector"))
    sec.append(rep.table(["a", "b"], [[1, 2.5]], passed=[True]))
    path = tmp_path / "report.html"
    path.write_text(rep.render(settings={"x": 1}, run_time_s=0.1))
    return path


def test_report_is_self_contained(tmp_path):
    """Check figures are embedded (no file references) and settings/versions are listed."""
    path = _report(tmp_path)
    text = path.read_text()
    assert text.count("data:image/png;base64,") == 2
    assert text.count("data:image/svg+xml;base64,") == 1
    assert 'src="f0.png"' not in text and "jax" in text and "run time" in text


@pytest.mark.skipif(find_chromium() is None, reason="Chromium not installed (Debian: chromium)")
def test_chromium_decodes_every_figure(tmp_path):
    """Check headless Chromium decodes all embedded figures, and notices a broken one."""
    path = _report(tmp_path)
    before = path.read_bytes()
    res = check_report(path, tmp_path / "shot.png")
    assert res["ok"], res
    assert res["images"] == res["decoded"] == 3
    assert (tmp_path / "shot.png").stat().st_size > 10_000
    assert path.read_bytes() == before  # the check never modifies the report
    broken = tmp_path / "broken.html"
    broken.write_text(before.decode().replace("base64,iVBOR", "base64,AAAAA", 1))
    res = check_report(broken)
    assert not res["ok"] and res["decoded"] == 2
