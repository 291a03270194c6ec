"""Self-contained HTML reports: figures embedded as base64, tables, settings, versions.

Written by hand (a few dozen lines of templating) because the report is one static page
with no interaction; a templating dependency would add nothing.
"""

from __future__ import annotations

import base64
import html
import json
import platform
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;
margin:2em auto;padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #3465a4;padding-bottom:.2em}h2{margin-top:1.8em;color:#204a87}
table{border-collapse:collapse;margin:1em 0;font-size:.95em}
th,td{border:1px solid #ccc;padding:.3em .7em;text-align:right}
th{background:#eef2f7}td:first-child,th:first-child{text-align:left}
.ok{color:#2e7d32;font-weight:600}.bad{color:#c62828;font-weight:600}
figure{margin:1.2em 0;text-align:center}figure img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.9em;color:#555;margin-top:.3em}
pre{background:#f6f8fa;padding:.8em;overflow-x:auto;font-size:.85em}
.summary{background:#f3f7fb;border-left:4px solid #3465a4;padding:.6em 1em}
"""


@dataclass
class Report:
    """A report under construction: sections of text, tables and figures."""

    title: str
    intro: str = ""
    sections: list[tuple[str, list[str]]] = field(default_factory=list)

    def section(self, heading: str) -> list[str]:
        """Start a section; returns its list of HTML blocks."""
        blocks: list[str] = []
        self.sections.append((heading, blocks))
        return blocks

    @staticmethod
    def text(body: str) -> str:
        return f"<p>{html.escape(body)}</p>"

    @staticmethod
    def figure(path: str | Path, caption: str) -> str:
        """Embed a PNG or SVG figure (base64), so the page stands alone."""
        p = Path(path)
        data = base64.b64encode(p.read_bytes()).decode("ascii")
        mime = "image/svg+xml" if p.suffix.lower() == ".svg" else "image/png"
        return (
            f'<figure><img alt="{html.escape(caption)}" src="data:{mime};base64,{data}">'
            f"<figcaption>{html.escape(caption)}</figcaption></figure>"
        )

    @staticmethod
    def table(
        header: Sequence[str],
        rows: Sequence[Sequence[Any]],
        passed: Sequence[bool | None] | None = None,
    ) -> str:
        """A table; ``passed`` adds a last column marking each row's check."""
        head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
        if passed is not None:
            head += "<th>check</th>"
        body = []
        for i, row in enumerate(rows):
            cells = "".join(f"<td>{html.escape(_fmt(v))}</td>" for v in row)
            if passed is not None:
                ok = passed[i]
                mark = (
                    ""
                    if ok is None
                    else '<span class="ok">pass</span>'
                    if ok
                    else '<span class="bad">fail</span>'
                )
                cells += f"<td>{mark}</td>"
            body.append(f"<tr>{cells}</tr>")
        return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"

    @staticmethod
    def code(obj: Any) -> str:
        text = obj if isinstance(obj, str) else json.dumps(obj, indent=2, default=str)
        return f"<pre>{html.escape(text)}</pre>"

    def render(self, *, settings: Mapping[str, Any], run_time_s: float) -> str:
        """The whole page, with settings, package versions and run time at the end."""
        parts = [f"<h1>{html.escape(self.title)}</h1>"]
        if self.intro:
            parts.append(f'<div class="summary">{html.escape(self.intro)}</div>')
        for heading, blocks in self.sections:
            parts.append(f"<h2>{html.escape(heading)}</h2>")
            parts.extend(blocks)
        parts.append("<h2>Settings, versions, run time</h2>")
        parts.append(
            self.table(
                ["item", "value"],
                [
                    ["run time", f"{run_time_s:.1f} s"],
                    ["created", time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())],
                    *[[k, v] for k, v in versions().items()],
                ],
            )
        )
        parts.append(self.code(dict(settings)))
        return (
            "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>{html.escape(self.title)}</title><style>{_CSS}</style></head>"
            f"<body>{''.join(parts)}</body></html>"
        )


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def versions() -> dict[str, str]:
    """Versions of Python, bifid and the numerical stack."""
    import importlib.metadata as md

    out = {"python": platform.python_version(), "platform": platform.platform()}
    for pkg in (
        "bifid",
        "jax",
        "jaxlib",
        "numpy",
        "scipy",
        "diffrax",
        "equinox",
        "optax",
        "xarray",
        "matplotlib",
    ):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            out[pkg] = "not installed"
    return out
