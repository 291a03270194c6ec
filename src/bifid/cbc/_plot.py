"""Figures of measured CBC branches over the continuation ground truth (matplotlib, Agg)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["plot_forced", "plot_lco"]


def _figure(ncols: int):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, ncols, figsize=(5.2 * ncols, 4.0), squeeze=False)
    return fig, axes[0]


def _truth_lines(ax, x: np.ndarray, y: np.ndarray, stable: np.ndarray, label: str) -> None:
    """Continuation branch: solid where stable, dashed where unstable."""
    first = {True: True, False: True}
    for i in range(len(x) - 1):
        s = bool(stable[i] and stable[i + 1])
        ax.plot(
            x[i : i + 2],
            y[i : i + 2],
            "-" if s else "--",
            color="0.35",
            lw=1.4,
            label=(f"{label} ({'stable' if s else 'unstable'})" if first[s] else None),
        )
        first[s] = False


def _points(ax, x, y, stable) -> None:
    x, y = np.asarray(x), np.asarray(y)
    st = np.array([s is True for s in stable])
    un = np.array([s is False for s in stable])
    unk = ~(st | un)
    if st.any():
        ax.plot(x[st], y[st], "o", color="tab:blue", ms=6, label="CBC, stable")
    if un.any():
        ax.plot(x[un], y[un], "o", mfc="white", mec="tab:red", mew=1.6, ms=6, label="CBC, unstable")
    if unk.any():
        ax.plot(x[unk], y[unk], "s", color="0.5", ms=5, label="CBC, stability unknown")


def plot_lco(
    path: str | Path,
    points: Sequence[dict[str, Any]],
    signals: Sequence[str],
    param: str,
    truth: dict[str, Any] | None,
    title: str,
    units: dict[str, str] | None = None,
) -> Path:
    """Amplitude of each signal against the parameter: CBC points over the truth branch.

    ``points``: the ``points`` of a measured diagram's JSON; ``truth``: ``{"param": (n,),
    "amplitude": {signal: (n,)}, "stable": (n,)}`` or None.
    """
    units = units or {}
    fig, axes = _figure(len(signals))
    for ax, s in zip(axes, signals, strict=True):
        if truth is not None and s in truth["amplitude"]:
            _truth_lines(ax, truth["param"], truth["amplitude"][s], truth["stable"], "continuation")
        _points(
            ax,
            [p["param"] for p in points],
            [p["amplitude"][s] for p in points],
            [p["stable"] for p in points],
        )
        ax.set_xlabel(param)
        u = f" [{units[s]}]" if units.get(s) else ""
        ax.set_ylabel(f"amplitude of {s}{u}  (max |x - x̄|)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="best")
    fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=130)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def plot_forced(
    path: str | Path,
    points: Sequence[dict[str, Any]],
    key: str,
    folds: Sequence[dict],
    truth: dict[str, Any] | None,
    title: str,
    signal: str,
) -> Path:
    """Response amplitude against ``key`` ("forcing" or "omega"), CBC over continuation
    (``points`` and ``folds`` of a measured diagram's JSON)."""
    fig, axes = _figure(1)
    ax = axes[0]
    if truth is not None:
        _truth_lines(ax, truth[key], truth["amplitude"], truth["stable"], "continuation")
    _points(
        ax,
        [p[key] for p in points],
        [p["amplitude"] for p in points],
        [p["stable"] for p in points],
    )
    for i, f in enumerate(folds):
        ax.plot(
            f[key],
            f["amplitude"],
            "x",
            color="k",
            ms=9,
            mew=2,
            label="CBC folds" if i == 0 else None,
        )
    ax.set_xlabel("forcing amplitude γ" if key == "forcing" else "forcing frequency Ω [rad/s]")
    ax.set_ylabel(f"amplitude of {signal}  (max |x|)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    ax.set_title(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=130)
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path
