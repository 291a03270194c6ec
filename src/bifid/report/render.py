"""Look at a report as a user would: render it in headless Chromium.

:func:`check_report` opens a *copy* of the page (the report itself is never modified) with
a small script appended that counts the images the browser actually decoded, dumps the
DOM after load and takes a screenshot. A report passes when every ``<img>`` was decoded
with a non-zero size.

Chromium is an optional system dependency (Debian package ``chromium``); without it
:func:`find_chromium` returns ``None`` and callers skip the check.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

from bifid.errors import BifidInputError

__all__ = ["check_report", "find_chromium"]

_PROBE = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; });
  var box = document.createElement('pre');
  box.id = 'bifid-render-probe';
  box.textContent = 'IMAGES ' + imgs.length + ' DECODED ' + ok.length + ' SIZES ' +
    ok.map(function (i) { return i.naturalWidth + 'x' + i.naturalHeight; }).join(',');
  document.body.appendChild(box);
});
</script>"""


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _run(browser: str, args: list[str], timeout: float) -> subprocess.CompletedProcess:
    base = [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            "--disable-dev-shm-usage", "--no-first-run", "--allow-file-access-from-files",
            "--virtual-time-budget=10000"]
    return subprocess.run(base + args, capture_output=True, text=True, timeout=timeout)


def check_report(html_path: str | Path, screenshot: str | Path | None = None, *,
                 width: int = 1200, height: int = 4000, timeout: float = 120.0
                 ) -> dict[str, Any]:
    """Render ``html_path`` headless; count the figures the browser decoded.

    Parameters
    ----------
    html_path : path
        The report.
    screenshot : path, optional
        Where to write a PNG screenshot of the rendered page.

    Returns
    -------
    dict
        ``images`` (``<img>`` elements), ``decoded`` (decoded with a size), ``sizes``,
        ``in_html`` (``<img`` tags in the file), ``ok``, ``screenshot``.

    Raises
    ------
    BifidInputError
        If the file is missing or no Chromium is installed.
    """
    src = Path(html_path)
    if not src.is_file():
        raise BifidInputError(f"{src} is not a file.")
    browser = find_chromium()
    if browser is None:
        raise BifidInputError("no Chromium found: install the Debian package 'chromium'.")
    text = src.read_text(encoding="utf-8")
    in_html = len(re.findall(r"<img\b", text))
    probed = text.replace("</body>", _PROBE + "</body>") if "</body>" in text else text + _PROBE
    with tempfile.TemporaryDirectory(prefix="bifid-render-") as tmp:
        page = Path(tmp) / "page.html"
        page.write_text(probed, encoding="utf-8")
        profile = Path(tmp) / "profile"
        r = _run(browser, [f"--user-data-dir={profile}", "--dump-dom", page.as_uri()], timeout)
        m = re.search(r"IMAGES (\d+) DECODED (\d+) SIZES ([0-9x,]*)", r.stdout)
        shot = None
        if screenshot is not None:
            shot = Path(screenshot).resolve()
            _run(browser, [f"--user-data-dir={profile}", f"--screenshot={shot}",
                           f"--window-size={width},{height}", src.resolve().as_uri()], timeout)
            shot = str(shot) if shot.is_file() else None
    if m is None:
        return {"images": None, "decoded": 0, "sizes": [], "in_html": in_html, "ok": False,
                "screenshot": shot, "stderr": r.stderr[-2000:]}
    images, decoded = int(m.group(1)), int(m.group(2))
    sizes = [s for s in m.group(3).split(",") if s]
    return {"images": images, "decoded": decoded, "sizes": sizes, "in_html": in_html,
            "ok": images == in_html and decoded == images and images > 0,
            "screenshot": shot}
