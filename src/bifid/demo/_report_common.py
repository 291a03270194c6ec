"""Pieces both demo reports share: a check against a limit, the closing model section."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bifid.errors import BifidError

__all__ = ["check", "finish_report"]


def check(value: float, limit: float, unit: str = "") -> dict[str, Any]:
    """A number held to a limit (non-finite values fail)."""
    return {
        "value": float(value),
        "limit": limit,
        "unit": unit,
        "passed": bool(np.isfinite(value) and value <= limit),
    }


def finish_report(
    rep, out: Path, model, summary: dict[str, Any], settings: dict[str, Any], run_time: float
) -> Path:
    """Append the model's parameters and timings, render, write ``out/report.html``."""
    from bifid.io import atomic_write_text

    sec = rep.section("Model")
    try:
        params = model.summary()["parameters"]
    except BifidError:
        params = {}
    sec.append(
        rep.code(
            {
                "parameters": params,
                "timings_s": summary["timings_s"],
                "stages reused from cache": summary["stages_reused"],
            }
        )
    )
    atomic_write_text(out / "report.html", rep.render(settings=settings, run_time_s=run_time))
    return out / "report.html"
