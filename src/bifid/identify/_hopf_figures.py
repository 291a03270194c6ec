"""Figures of a fitted hybrid Hopf model (like thesis Figs. 5.3, 5.5–5.8), matplotlib Agg.

* :func:`diagram_figure` — amplitude of each plane signal against the parameter: stable
  (solid) and unstable (dashed) branches of the primary member, the ensemble band, the Hopf
  point and fold, the training orbits (● stable, ▲ unstable) and optionally a reference.
* :func:`portraits_figure` — measured against predicted phase portraits, one panel per record.
* :func:`series_figure` — measured against predicted time series of one signal.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path) -> None:
    """Save atomically (temporary file + rename) and close."""
    from bifid.io import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=130, bbox_inches="tight", format=path.suffix.lstrip(".") or "png")
    _plt().close(fig)


def _label(model, k: int) -> str:
    name = model.signal_names_[k]
    unit = model.signal_units_.get(name, "")
    return f"max |{name}|" + (f" [{unit}]" if unit else "")


def diagram_figure(
    model,
    data: Any | None = None,
    *,
    param_range: Sequence[float] | None = None,
    reference: Callable[[str], tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
    signals: Sequence[str] | None = None,
    title: str | None = None,
):
    """Bifurcation diagram of ``model`` with its training data.

    Parameters
    ----------
    data : optional
        Records or dataset(s) to overlay (their measured amplitudes).
    reference : callable, optional
        ``signal -> (params, amplitudes, stable)`` of a ground truth, drawn in grey.
    signals : names, optional
        Signals to plot (default: the two plane signals).
    """
    from bifid.identify._hopf_data import as_lco_data
    from bifid.identify._hopf_normal_form import UNSTABLE

    plt = _plt()
    diag = model.predict_diagram(
        tuple(param_range) if param_range is not None else None, n_points=200
    )
    names = list(signals) if signals else [model.signal_names_[i] for i in model.plane_]
    fig, axes = plt.subplots(1, len(names), figsize=(5.2 * len(names), 4.0), squeeze=False)
    orbits = diag["orbits"]
    P = np.array([o["param"] for o in orbits])
    S = np.array([o["stable"] for o in orbits])
    band = diag["band"]
    grid = np.asarray(band["param"])
    meas = None
    if data is not None:
        d = as_lco_data(data)
        from bifid.identify._hopf_prepare import prepare
        from bifid.identify.hopf_hybrid import _measured_amplitude

        prep = prepare(d, model.plane_, model.map_config_.n_harmonics,
                       mu_c=model.mu_c_, mu_s=model.mu_s_, z_scale=model.z_scale_,
                       white=model.white_)
        meas = (
            d.params,
            d.branch,
            np.array([_measured_amplitude(s, w, fs) for s, w, fs in
                      zip(d.signals, prep.omega, d.sample_rates, strict=True)]),
        )
    for ax, name in zip(axes[0], names, strict=True):
        k = model.signal_names_.index(name)
        A = np.array([o["amplitude"][name] for o in orbits])
        for branch in band["branches"].values():
            lo = np.array([np.nan if v is None else v for v in branch[name]["min"]])
            hi = np.array([np.nan if v is None else v for v in branch[name]["max"]])
            ax.fill_between(grid, lo, hi, color="tab:blue", alpha=0.18, lw=0)
        if reference is not None:
            rp, ra, rs = reference(name)
            ax.plot(np.where(rs, rp, np.nan), np.where(rs, ra, np.nan), color="0.45", lw=3,
                    alpha=0.6, label="reference (stable)")
            ax.plot(np.where(~rs, rp, np.nan), np.where(~rs, ra, np.nan), color="0.45", lw=3,
                    alpha=0.6, ls=":", label="reference (unstable)")
        ax.plot(np.where(S, P, np.nan), np.where(S, A, np.nan), color="tab:blue", lw=1.8,
                label="model, stable")
        ax.plot(np.where(~S, P, np.nan), np.where(~S, A, np.nan), color="tab:blue", lw=1.8,
                ls="--", label="model, unstable")
        for h in diag["hopf"]:
            ax.plot([h["param"]], [0.0], "s", color="tab:red", ms=7,
                    label=f"Hopf {h['param']:.4g}")
        for f in diag["cycle_folds"]:
            ax.plot([f["param"]], [f["amplitude"][name]], "D", color="tab:orange", ms=7,
                    label=f"fold {f['param']:.4g}")
        if meas is not None:
            params, branch, amp = meas
            st = branch != UNSTABLE
            ax.plot(params[st], amp[st, k], "o", color="k", ms=6, label="data, stable")
            ax.plot(params[~st], amp[~st, k], "^", color="k", ms=6, mfc="none",
                    label="data, unstable")
        unit = model.param_units_
        ax.set_xlabel(model.param_name_ + (f" [{unit}]" if unit else ""))
        ax.set_ylabel(_label(model, k))
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7, loc="best")
    fig.suptitle(title or "hybrid Hopf model: bifurcation diagram (band: ensemble)")
    fig.tight_layout()
    return fig


def portraits_figure(model, data: Any, *, max_panels: int = 9, title: str | None = None):
    """Measured (grey) and predicted (blue) phase portraits in the plane, one per record."""
    from bifid.identify._hopf_data import as_lco_data
    from bifid.identify._hopf_normal_form import UNSTABLE

    plt = _plt()
    d = as_lco_data(data)
    n = min(d.n_records, max_panels)
    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.2 * rows), squeeze=False)
    i1, i2 = model.plane_
    for ax, i in zip(axes.ravel(), range(n), strict=False):
        sig = d.signals[i]
        branch = "unstable" if d.branch[i] == UNSTABLE else "stable"
        ax.plot(sig[:, i1], sig[:, i2], color="0.6", lw=2.5, alpha=0.7, label="measured")
        try:
            orb = model.predict_orbit(float(d.params[i]), branch)
            z = orb["signals"]
            ax.plot(np.r_[z[:, i1], z[:1, i1]], np.r_[z[:, i2], z[:1, i2]], color="tab:blue",
                    lw=1.3, label="model")
        except Exception as exc:  # the model may lack this cycle: say so in the panel
            ax.text(0.5, 0.5, str(exc)[:60], transform=ax.transAxes, ha="center", fontsize=7)
        ax.set_title(f"{model.param_name_} = {d.params[i]:.4g} ({branch})", fontsize=9)
        ax.set_xlabel(model.signal_names_[i1])
        ax.set_ylabel(model.signal_names_[i2])
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(title or "phase portraits: measured vs hybrid model")
    fig.tight_layout()
    return fig


def series_figure(
    model, data: Any, *, signal: str | None = None, periods: float = 3.0,
    max_panels: int = 9, title: str | None = None,
):
    """Measured (grey) and predicted (blue) time series, phase matched at the first sample."""
    from bifid.identify._hopf_data import as_lco_data
    from bifid.identify._hopf_normal_form import UNSTABLE

    plt = _plt()
    d = as_lco_data(data)
    k = model.signal_names_.index(signal) if signal else model.plane_[0]
    n = min(d.n_records, max_panels)
    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.8 * cols, 2.6 * rows), squeeze=False)
    for ax, i in zip(axes.ravel(), range(n), strict=False):
        sig = d.signals[i]
        fs = d.sample_rates[i]
        branch = "unstable" if d.branch[i] == UNSTABLE else "stable"
        try:
            w = float(model.predict_frequency([d.params[i]], branch)[0])
            m = int(min(len(sig), periods * 2 * np.pi / w * fs))
            t = np.arange(m) / fs
            z = model.predict_time_series(float(d.params[i]), t, branch, initial=sig[0])
            ax.plot(t, sig[:m, k], color="0.6", lw=2.5, alpha=0.7, label="measured")
            ax.plot(t, z[:, k], color="tab:blue", lw=1.2, label="model")
        except Exception as exc:
            ax.text(0.5, 0.5, str(exc)[:60], transform=ax.transAxes, ha="center", fontsize=7)
        ax.set_title(f"{model.param_name_} = {d.params[i]:.4g} ({branch})", fontsize=9)
        ax.set_xlabel("t [s]")
        ax.set_ylabel(model.signal_names_[k])
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(title or "time series: measured vs hybrid model")
    fig.tight_layout()
    return fig
