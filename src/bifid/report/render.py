"""Look at a report as a user would: render it in headless Chromium.

:func:`check_report` opens a *copy* of the page (the report itself is never modified) with
two small scripts added: one at the top that records every console error, uncaught
exception and resource that failed to load, and one run at ``load`` that lists each
``<img>`` -- decoded or not, its natural size, where it sits on the page and whether it
is displayed. With a screenshot requested, the page is shot at its full height and every
figure's rectangle in the PNG is checked to hold a picture (not a blank area). A report
passes when every ``<img>`` was decoded with a non-zero size, is displayed, shows in the
screenshot, and the console stayed free of errors.

Chromium is an optional system dependency (Debian package ``chromium``); without it
:func:`find_chromium` returns ``None`` and callers skip the check.
"""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any

from bifid.errors import BifidInputError

__all__ = ["check_report", "find_chromium"]

# first in <head>: records errors from the moment the page starts to parse
_CAPTURE = """<script>
window.__bifidErrors = [];
(function () {
  var push = function (m) { window.__bifidErrors.push(String(m).slice(0, 300)); };
  var err = console.error;
  console.error = function () {
    push('console.error: ' + Array.prototype.join.call(arguments, ' '));
    return err.apply(console, arguments);
  };
  window.addEventListener('error', function (ev) {
    var t = ev.target;
    if (t && t !== window && t.tagName) {
      push('failed to load <' + t.tagName.toLowerCase() + '>');
    } else {
      push(ev.message || 'uncaught error');
    }
  }, true);
  window.addEventListener('unhandledrejection', function (ev) {
    push('unhandled rejection: ' + ev.reason);
  });
})();
</script>"""

_PROBE = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images).map(function (i) {
    var r = i.getBoundingClientRect(), s = window.getComputedStyle(i);
    return {decoded: i.complete && i.naturalWidth > 0, natural: [i.naturalWidth,
            i.naturalHeight], rect: [r.left + window.scrollX, r.top + window.scrollY,
            r.width, r.height], shown: s.display !== 'none' && s.visibility !== 'hidden'
            && parseFloat(s.opacity) > 0 && r.width > 0 && r.height > 0};
  });
  var box = document.createElement('pre');
  box.id = 'bifid-render-probe';
  box.textContent = 'BIFID-PROBE ' + JSON.stringify({images: imgs, errors:
    window.__bifidErrors || [], height: document.documentElement.scrollHeight});
  document.body.appendChild(box);
});
</script>"""

_MAX_SHOT_HEIGHT = 16384  # px; a figure below this is reported as not in the screenshot


def find_chromium() -> str | None:
    """Path of a Chromium/Chrome executable, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    return None


def _run(browser: str, args: list[str], timeout: float) -> subprocess.CompletedProcess:
    base = [
        browser,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--hide-scrollbars",
        "--disable-dev-shm-usage",
        "--no-first-run",
        "--allow-file-access-from-files",
        "--virtual-time-budget=10000",
    ]
    return subprocess.run(base + args, capture_output=True, text=True, timeout=timeout)


def _instrumented(text: str) -> str:
    """The page with the error recorder first in ``<head>`` and the probe at the end."""
    m = re.search(r"<head[^>]*>", text, flags=re.IGNORECASE)
    text = (text[: m.end()] + _CAPTURE + text[m.end() :]) if m else _CAPTURE + text
    return text.replace("</body>", _PROBE + "</body>") if "</body>" in text else text + _PROBE


def _blank_figures(shot: Path, rects: list[list[float]]) -> list[int]:
    """Indices of the figures whose rectangle in the screenshot is blank or cut off."""
    import matplotlib.image as mpimg
    import numpy as np

    pixels = np.asarray(mpimg.imread(shot))[..., :3]
    blank = []
    for k, (x, y, w, h) in enumerate(rects):
        x0, y0 = int(x) + 2, int(y) + 2
        x1, y1 = int(x + w) - 2, int(y + h) - 2
        if x1 > pixels.shape[1] or y1 > pixels.shape[0] or x1 <= x0 or y1 <= y0:
            blank.append(k)
            continue
        region = pixels[y0:y1, x0:x1]
        # a drawn figure has lines and text: its pixels vary; a blank box does not
        if float(region.std()) < 0.01:
            blank.append(k)
    return blank


def check_report(
    html_path: str | Path,
    screenshot: str | Path | None = None,
    *,
    width: int = 1200,
    height: int = 4000,
    timeout: float = 120.0,
) -> dict[str, Any]:
    """Render ``html_path`` headless; check every figure shows and the console is clean.

    Parameters
    ----------
    html_path : path
        The report.
    screenshot : path, optional
        Where to write a PNG screenshot of the whole rendered page; every figure's
        rectangle in it is then checked to hold a picture.
    width, height : int
        Browser window size in pixels (the screenshot takes the page's full height).

    Returns
    -------
    dict
        ``images`` (``<img>`` elements), ``decoded`` (decoded with a size), ``shown``
        (displayed with a size on the page), ``sizes``, ``in_html`` (``<img`` tags in the
        file), ``console_errors`` (console errors, uncaught exceptions, failed loads),
        ``blank_in_screenshot`` (figures blank or cut off in the screenshot), ``ok``,
        ``screenshot``.

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
    window = f"--window-size={width},{height}"
    with tempfile.TemporaryDirectory(prefix="bifid-render-") as tmp:
        page = Path(tmp) / "page.html"
        page.write_text(_instrumented(text), encoding="utf-8")
        profile = f"--user-data-dir={Path(tmp) / 'profile'}"
        r = _run(browser, [profile, window, "--dump-dom", page.as_uri()], timeout)
        m = re.search(r"BIFID-PROBE (\{.*?\})</pre>", r.stdout, flags=re.DOTALL)
        if m is None:
            return {
                "images": None,
                "decoded": 0,
                "shown": 0,
                "sizes": [],
                "in_html": in_html,
                "console_errors": [],
                "blank_in_screenshot": [],
                "ok": False,
                "screenshot": None,
                "stderr": r.stderr[-2000:],
            }
        probe = json.loads(html.unescape(m.group(1)))
        imgs = probe["images"]
        shot, blank = None, []
        if screenshot is not None:
            shot_path = Path(screenshot).resolve()
            full = min(max(int(probe["height"]), height), _MAX_SHOT_HEIGHT)
            _run(
                browser,
                [
                    profile,
                    f"--screenshot={shot_path}",
                    f"--window-size={width},{full}",
                    src.resolve().as_uri(),
                ],
                timeout,
            )
            if shot_path.is_file():
                shot = str(shot_path)
                blank = _blank_figures(shot_path, [i["rect"] for i in imgs])
            else:
                blank = list(range(len(imgs)))
    decoded = sum(bool(i["decoded"]) for i in imgs)
    shown = sum(bool(i["decoded"] and i["shown"]) for i in imgs)
    errors = [str(e) for e in probe["errors"]]
    return {
        "images": len(imgs),
        "decoded": decoded,
        "shown": shown,
        "sizes": [f"{i['natural'][0]}x{i['natural'][1]}" for i in imgs if i["decoded"]],
        "in_html": in_html,
        "console_errors": errors,
        "blank_in_screenshot": blank,
        "ok": (
            len(imgs) == in_html
            and decoded == shown == len(imgs)
            and len(imgs) > 0
            and not errors
            and not blank
            and (screenshot is None or shot is not None)
        ),
        "screenshot": shot,
    }
