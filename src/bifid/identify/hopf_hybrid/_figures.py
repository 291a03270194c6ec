"""Figures of a fitted hybrid model against its data (like thesis Figs. 5.5–5.8).

* :func:`portraits_figure` — measured against predicted phase portraits, one panel per record;
* :func:`series_figure` — measured against predicted time series of one signal.

Bifurcation diagrams are drawn by :func:`bifid.report.plot_diagram` from
``model.predict_diagram()``. Figures are built with matplotlib's object-oriented API (no
pyplot state, no backend change) and saved with :func:`bifid.report.save_figure`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bifid.errors import BifidError
from bifid.identify._records import as_lco_data

__all__ = ["portraits_figure", "series_figure"]


def _grid(n: int, width: float, height: float):
    from matplotlib.figure import Figure

    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    fig = Figure(figsize=(width * cols, height * rows))
    return fig, fig.subplots(rows, cols, squeeze=False)


def _finish(fig: Any, axes: Any, n: int, title: str) -> Any:
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def portraits_figure(
    model: Any, data: Any, *, max_panels: int = 9, title: str | None = None
) -> Any:
    """Measured (grey) and predicted (blue) phase portraits in the plane, one per record."""
    d = as_lco_data(data)
    n = min(len(d), max_panels)
    fig, axes = _grid(n, 3.6, 3.2)
    i1, i2 = model.state_.plane
    names = model.state_.signal_names
    for ax, i in zip(axes.ravel(), range(n), strict=False):
        sig = d.signals[i]
        stable = bool(d.stable[i] != 0)
        ax.plot(sig[:, i1], sig[:, i2], color="0.6", lw=2.5, alpha=0.7, label="measured")
        try:
            z = model.predict_orbit(float(d.param[i]), stable=stable).signals
            ax.plot(
                np.r_[z[:, i1], z[:1, i1]],
                np.r_[z[:, i2], z[:1, i2]],
                color="tab:blue",
                lw=1.3,
                label="model",
            )
        except BifidError as exc:  # the model may lack this cycle: say so in the panel
            ax.text(0.5, 0.5, str(exc)[:60], transform=ax.transAxes, ha="center", fontsize=7)
        ax.set_title(
            f"{d.param_name} = {d.param[i]:.4g} ({'stable' if stable else 'unstable'})", fontsize=9
        )
        ax.set_xlabel(names[i1])
        ax.set_ylabel(names[i2])
        ax.grid(alpha=0.3)
    return _finish(fig, axes, n, title or "phase portraits: measured vs hybrid model")


def series_figure(
    model: Any,
    data: Any,
    *,
    signal: str | None = None,
    periods: float = 3.0,
    max_panels: int = 9,
    title: str | None = None,
) -> Any:
    """Measured (grey) and predicted (blue) time series, phase matched at the first sample."""
    d = as_lco_data(data)
    names = model.state_.signal_names
    k = names.index(signal) if signal else model.state_.plane[0]
    n = min(len(d), max_panels)
    fig, axes = _grid(n, 3.8, 2.6)
    for ax, i in zip(axes.ravel(), range(n), strict=False):
        sig, fs = d.signals[i], d.sample_rate[i]
        stable = bool(d.stable[i] != 0)
        try:
            w = float(model.predict_frequency([d.param[i]], stable=stable)[0])
            m = int(min(len(sig), periods * 2 * np.pi / w * fs))
            t = np.arange(m) / fs
            z = model.predict_time_series(float(d.param[i]), t, stable=stable, initial=sig[0])
            ax.plot(t, sig[:m, k], color="0.6", lw=2.5, alpha=0.7, label="measured")
            ax.plot(t, z[:, k], color="tab:blue", lw=1.2, label="model")
        except BifidError as exc:
            ax.text(0.5, 0.5, str(exc)[:60], transform=ax.transAxes, ha="center", fontsize=7)
        ax.set_title(
            f"{d.param_name} = {d.param[i]:.4g} ({'stable' if stable else 'unstable'})", fontsize=9
        )
        ax.set_xlabel("t [s]")
        ax.set_ylabel(names[k])
        ax.grid(alpha=0.3)
    return _finish(fig, axes, n, title or "time series: measured vs hybrid model")
