"""Reports as a user sees them: a self-contained HTML page rendered by headless Chromium.

The page is built like the demos' reports (``bifid.report.Report``, figures drawn by
``bifid.report.plot_curve`` and written by ``save_figure`` as PNG and SVG, a checks
table, settings) from curves known in closed form, so it takes a second to build. In CI
(``BIFID_REQUIRE_CHROMIUM=1``, set by ``.ci/run`` where Chromium is or can be installed)
the browser tests fail rather than skip without Chromium.
"""

from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.image as mpimg
import matplotlib.pyplot as plt
import numpy as np
import pytest

from bifid.report import Report, check_report, find_chromium, plot_curve, save_figure

_REQUIRED = os.environ.get("BIFID_REQUIRE_CHROMIUM") == "1"


@pytest.fixture
def chromium() -> str:
    path = find_chromium()
    if path is None:
        if _REQUIRED:
            pytest.fail(
                "Chromium is required here (BIFID_REQUIRE_CHROMIUM=1) but missing; "
                "install the Debian package 'chromium'."
            )
        pytest.skip("Chromium not installed (Debian: chromium)")
    return path


def _figures(tmp_path):
    """A subcritical Hopf diagram (r² = μ + r⁴ branches) as PNG, its FRC-like curve as SVG."""
    r = np.linspace(0.0, 1.0, 200)
    mu = r**4 - r**2  # equilibria of dr/dt = r (mu + r^2 - r^4)
    stable = 4 * r**2 > 2  # d/dr (mu + r^2 - r^4) < 0 on the outer branch
    fig, ax = plt.subplots(figsize=(5, 3.5))
    plot_curve(ax, mu, r, stable, label="limit cycles")
    ax.set_xlabel("μ")
    ax.set_ylabel("amplitude")
    png = save_figure(fig, tmp_path / "diagram.png")
    plt.close(fig)
    w = np.linspace(0.8, 1.2, 200)
    amp = 1.0 / np.sqrt((1 - w**2) ** 2 + (0.05 * w) ** 2)
    fig, ax = plt.subplots(figsize=(5, 3.5))
    plot_curve(ax, w, amp, np.ones_like(w, dtype=bool), label="linear FRC")
    svg = save_figure(fig, tmp_path / "frc.svg")
    plt.close(fig)
    return [png, svg]


def _report(tmp_path, extra: str = ""):
    rep = Report("render test", intro="a diagram, an FRC and a checks table")
    sec = rep.section("figures")
    for p in _figures(tmp_path):
        sec.append(rep.figure(p, p.stem))
    sec.append(
        rep.table(
            ["check", "error", "limit"],
            [["Hopf", 0.01, 0.1], ["fold", 0.3, 0.2]],
            passed=[True, False],
        )
    )
    path = tmp_path / "report.html"
    path.write_text(
        rep.render(settings={"seed": 0}, run_time_s=0.1).replace("</body>", extra + "</body>")
    )
    return path


def test_report_is_self_contained(tmp_path):
    """Check figures are embedded (no file references) and settings/versions are listed."""
    text = _report(tmp_path).read_text()
    assert text.count("data:image/png;base64,") == 1
    assert text.count("data:image/svg+xml;base64,") == 1
    assert 'src="diagram.png"' not in text and "jax" in text and "run time" in text


def test_chromium_shows_every_figure(tmp_path, chromium):
    """Check Chromium decodes and displays both figures, the console stays clean, and in
    the screenshot each figure's rectangle holds a drawing (not blank)."""
    path = _report(tmp_path)
    before = path.read_bytes()
    shot = tmp_path / "shot.png"
    res = check_report(path, shot)
    assert res["ok"], res
    assert res["images"] == res["decoded"] == res["shown"] == 2
    assert res["console_errors"] == [] and res["blank_in_screenshot"] == []
    assert path.read_bytes() == before  # the check never modifies the report
    pixels = mpimg.imread(shot)
    assert pixels.shape[1] == 1200 and pixels.shape[0] >= 1000
    assert float(pixels[..., :3].std()) > 0.02  # the page itself is not blank


@pytest.mark.parametrize(
    "damage, what",
    [
        (("base64,iVBOR", "base64,AAAAA"), "broken image"),
        (("<figure>", "<figure style='visibility:hidden'>"), "hidden figure"),
        (("</h1>", "</h1><script>window.notAFunction();</script>"), "script error"),
        (("</h1>", "</h1><script>console.error('bad');</script>"), "console error"),
    ],
)
def test_chromium_notices_a_damaged_report(tmp_path, chromium, damage, what):
    """Check each kind of damage a user would see makes the check fail."""
    path = _report(tmp_path)
    text = path.read_text()
    assert damage[0] in text
    path.write_text(text.replace(damage[0], damage[1], 1))
    res = check_report(path)
    assert not res["ok"], (what, res)
    if what == "broken image":
        assert res["decoded"] == 1 and res["console_errors"] == ["failed to load <img>"]
    elif what == "hidden figure":
        assert res["decoded"] == 2 and res["shown"] == 1
    else:
        assert len(res["console_errors"]) == 1, res


def test_screenshot_notices_a_blank_figure(tmp_path, chromium):
    """Check a figure that decodes but shows nothing (all white) is caught in the shot."""
    fig = plt.figure(figsize=(4, 3))
    blank = save_figure(fig, tmp_path / "blank.png")
    plt.close(fig)
    rep = Report("blank")
    sec = rep.section("figures")
    sec.append(rep.figure(_figures(tmp_path)[0], "drawn"))
    sec.append(rep.figure(blank, "blank"))
    path = tmp_path / "blank.html"
    path.write_text(rep.render(settings={}, run_time_s=0.0))
    res = check_report(path, tmp_path / "shot.png")
    assert res["decoded"] == res["shown"] == 2 and res["blank_in_screenshot"] == [1]
    assert not res["ok"]
