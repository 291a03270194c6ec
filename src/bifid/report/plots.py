"""Figures of diagrams: one function draws any :class:`~bifid.continuation.Diagram`.

:func:`plot_diagram` draws one or several diagrams on the same axes — continuation,
measurement and prediction of the same question overlay, so they can be compared by eye:
stable parts solid, unstable parts dashed, measured points as markers, bands where a branch
carries intervals, special points marked and labelled (with their intervals as error bars),
so a figure can be read without the JSON beside it.

Figures are built with matplotlib's object-oriented API (:class:`matplotlib.figure.Figure`)
and never touch pyplot's global state or the backend, so they work the same in scripts,
servers and interactive sessions.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from bifid.continuation import Branch, Diagram
from bifid.errors import BifidInputError
from bifid.io import atomic_path

__all__ = ["STABLE", "UNSTABLE", "plot_curve", "plot_diagram", "save_figure"]

STABLE = {"lw": 1.8}
UNSTABLE = {"lw": 1.5, "ls": "--"}
_COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:pink")
_MARKERS = {
    "hopf": "^",
    "cycle_fold": "s",
    "fold": "s",
    "peak": "D",
    "period_doubling": "v",
    "torus": "o",
    "branch_point": "x",
}


def _segments(x: np.ndarray, y: np.ndarray, stable: np.ndarray):
    """Split a curve into runs of equal stability (runs share their end points)."""
    start = 0
    for i in range(1, len(x) + 1):
        if i == len(x) or stable[i] != stable[start]:
            stop = min(i + 1, len(x))
            yield x[start:stop], y[start:stop], bool(stable[start])
            start = i


def plot_curve(
    ax: Any, x: Any, y: Any, stable: Any, *, label: str | None = None, color: str | None = None
) -> None:
    """Plot a curve solid where stable and dashed where unstable (one legend entry each)."""
    first = {True: True, False: True}
    for xs, ys, st in _segments(np.asarray(x), np.asarray(y), np.asarray(stable)):
        lab = None
        if first[st]:
            lab = f"{label + ' ' if label else ''}{'stable' if st else 'unstable'}"
            first[st] = False
        ax.plot(xs, ys, label=lab, color=color, **(STABLE if st else UNSTABLE))


def save_figure(fig: Figure, path: str | os.PathLike[str]) -> Path:
    """Save a figure atomically (the format from the suffix: png, svg, pdf, ...).

    Raises
    ------
    BifidInputError
        If matplotlib cannot write the suffix's format.
    """
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in fig.canvas.get_supported_filetypes():
        known = ", ".join(sorted(fig.canvas.get_supported_filetypes()))
        raise BifidInputError(f"cannot write a figure as {path.name!r}; use one of: {known}.")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=fmt, dpi=130, bbox_inches="tight")
    return path


def _amplitude(b: Branch, signal: str | None) -> tuple[np.ndarray, int | None]:
    """The branch's amplitude column for ``signal`` (or its scalar amplitude)."""
    key = "observed_amplitude" if "observed_amplitude" in b.data else "amplitude"
    amp = np.asarray(b.data.get(key, np.full(len(b), np.nan)), dtype=float)
    if amp.ndim == 1:
        return amp, None
    k = b.signals.index(signal) if signal in b.signals else 0
    return amp[:, k], k


def _x(d: Diagram, b: Branch) -> np.ndarray:
    if d.kind == "backbone":
        return np.asarray(b.data["omega"], dtype=float)
    return np.asarray(b.params, dtype=float)


def _equilibrium_curve(b: Branch, signal: str | None) -> tuple[np.ndarray, ...]:
    """``|x_s|`` along an equilibrium branch with its Hopf points inserted, so that the
    drawn stability changes exactly there."""
    k = b.signals.index(signal) if signal in b.signals else 0
    sol = np.asarray(b.solutions, dtype=float)
    x, y, st = list(b.params), list(np.abs(sol[:, k])), list(np.asarray(b.stable, bool))
    for sp in sorted(b.special("hopf"), key=lambda s: -s.index):
        i = sp.index + 1
        if 0 < i < len(x):
            x.insert(i, sp.param)
            y.insert(i, abs(float(np.asarray(sp.solution)[k])))
            st.insert(i, st[i])  # the next point's stability starts at the Hopf point
    return np.array(x), np.array(y), np.array(st)


def _draw_branch(
    ax: Any, d: Diagram, b: Branch, signal: str | None, color: str, label: str
) -> None:
    x = _x(d, b)
    stable = np.asarray(b.stable)
    known = stable.dtype == bool or not np.any(np.isnan(stable.astype(float)))
    if b.kind == "equilibrium":
        plot_curve(
            ax, *_equilibrium_curve(b, signal), color="0.4", label=f"{label} equilibria".strip()
        )
        return
    y, k = _amplitude(b, signal)
    if d.source == "measurement":
        st = stable.astype(float) if known else np.full(len(b), np.nan)
        for value, marker, what in ((1.0, "o", "stable"), (0.0, "x", "unstable")):
            sel = st == value
            if np.any(sel):
                ax.plot(
                    x[sel],
                    y[sel],
                    marker,
                    color=color,
                    ls="none",
                    ms=5,
                    label=f"{label} {what}".strip(),
                )
        if np.any(np.isnan(st)):
            sel = np.isnan(st)
            ax.plot(
                x[sel],
                y[sel],
                "+",
                color=color,
                ls="none",
                ms=6,
                label=f"{label} (stability unknown)".strip(),
            )
    else:
        plot_curve(
            ax,
            x,
            y,
            stable.astype(bool) if known else np.ones(len(b), bool),
            label=label,
            color=color,
        )
    key = "observed_amplitude" if "observed_amplitude" in b.intervals else "amplitude"
    if key in b.intervals:
        lo, hi = (np.asarray(v, dtype=float) for v in b.intervals[key])
        if lo.ndim > 1:
            lo, hi = lo[:, k or 0], hi[:, k or 0]
        level = f" {100 * d.level:g} %" if d.level else ""
        ax.fill_between(
            x, lo, hi, color=color, alpha=0.18, lw=0, label=f"{label}{level} band".strip()
        )


def _draw_special(ax: Any, d: Diagram, b: Branch, signal: str | None, color: str) -> None:
    for sp in b.special_points:
        marker = _MARKERS.get(sp.kind, "o")
        if sp.kind == "hopf" or (sp.kind == "fold" and b.kind == "equilibrium"):
            yv = (
                abs(float(np.asarray(sp.solution)[b.signals.index(signal)]))
                if signal in b.signals
                else 0.0
            )
        else:
            amp = np.asarray(sp.data.get("amplitude", np.nan), dtype=float)
            k = b.signals.index(signal) if (amp.ndim and signal in b.signals) else 0
            yv = float(amp[k]) if amp.ndim else float(amp)
        xv = float(sp.data.get("omega", sp.param)) if d.kind == "backbone" else sp.param
        xerr = None
        if "param" in sp.intervals:
            lo, hi = sp.intervals["param"]
            xerr = [[max(xv - lo, 0.0)], [max(hi - xv, 0.0)]]
        yerr = None
        if "amplitude" in sp.intervals:
            lo_a, hi_a = (np.atleast_1d(np.asarray(v, float)) for v in sp.intervals["amplitude"])
            k = b.signals.index(signal) if (lo_a.size > 1 and signal in b.signals) else 0
            yerr = [[max(yv - lo_a[k], 0.0)], [max(hi_a[k] - yv, 0.0)]]
        ax.errorbar(
            [xv],
            [yv],
            xerr=xerr,
            yerr=yerr,
            fmt=marker,
            color="k",
            mfc=color,
            ms=7,
            capsize=3,
            zorder=5,
        )
        name = sp.kind.replace("_", " ")
        ax.annotate(
            f"{name} {sp.param:.5g}",
            (xv, yv),
            textcoords="offset points",
            xytext=(6, 6),
            fontsize=8,
        )


def plot_diagram(
    *diagrams: Diagram,
    labels: Sequence[str] | None = None,
    signals: Sequence[str] | None = None,
    title: str = "",
    units: dict[str, str] | None = None,
) -> Figure:
    """Draw one or several diagrams of the same question on shared axes.

    Parameters
    ----------
    *diagrams : Diagram
        E.g. the continuation of the true system, a CBC measurement and a model's
        prediction; they must be of the same ``kind``.
    labels : sequence of str, optional
        Legend label per diagram (default: each diagram's ``source``).
    signals : sequence of str, optional
        Signals to draw, one panel each (bifurcation diagrams; default: up to two of the
        first diagram's signals, displacements before velocities). FRCs, S-curves and
        backbones draw their observed amplitude in one panel.
    title : str
    units : dict of str, optional
        Units by name (parameter and signals), added to the axis labels; defaults to the
        first diagram's ``units``.

    Returns
    -------
    matplotlib.figure.Figure
    """
    if not diagrams:
        raise BifidInputError("plot_diagram needs at least one diagram.")
    kinds = {d.kind for d in diagrams}
    if len(kinds) > 1:
        raise BifidInputError(f"cannot overlay diagrams of different kinds: {sorted(kinds)}.")
    kind = diagrams[0].kind
    labels = list(labels) if labels is not None else [d.source for d in diagrams]
    units = dict(units if units is not None else diagrams[0].units)
    if kind == "bifurcation":
        panels = list(signals) if signals else _default_signals(diagrams[0])
    else:
        panels = [None]
    fig = Figure(figsize=(6.6, 3.0 * len(panels) + 0.6))
    axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
    for ax, signal in zip(axes, panels, strict=True):
        for j, (d, lab) in enumerate(zip(diagrams, labels, strict=True)):
            color = _COLORS[j % len(_COLORS)]
            for b in d.branches:
                _draw_branch(ax, d, b, signal, color, lab)
                _draw_special(ax, d, b, signal, color)
        observed = signal or diagrams[0].branches[0].meta.get("observed", "")
        what = f"amplitude {observed}".strip()
        unit = units.get(observed, "")
        ax.set_ylabel(what + (f" [{unit}]" if unit else ""))
        ax.grid(alpha=0.3)
    handles, _ = axes[0].get_legend_handles_labels()
    if handles:
        axes[0].legend(fontsize=8, loc="best")
    xname = {
        "frc": "forcing frequency Ω",
        "scurve": "forcing amplitude F",
        "backbone": "frequency Ω",
    }.get(kind, diagrams[0].param)
    xunit = units.get(diagrams[0].param, "rad/s" if kind in ("frc", "backbone") else "")
    axes[-1].set_xlabel(xname + (f" [{xunit}]" if xunit else ""))
    if title:
        axes[0].set_title(title)
    fig.tight_layout()
    return fig


def _default_signals(d: Diagram) -> list[str]:
    names: list[str] = []
    for b in d.branches:
        names += [s for s in b.signals if s not in names]
    displacements = [s for s in names if not (s.endswith("d") or s.endswith("_dot"))]
    return (displacements or names)[:2] or [""]


def bifurcation_diagram(
    equilibria: Branch | None,
    orbits: Sequence[Branch],
    states: Sequence[str],
    *,
    title: str = "",
    units: dict[str, str] | None = None,
    param_unit: str = "",
) -> Figure:
    """Equilibria and orbit branches as a figure (:func:`plot_diagram` of their diagram)."""
    branches = ([equilibria] if equilibria is not None else []) + list(orbits)
    d = Diagram(
        kind="bifurcation", system=branches[0].system, param=branches[0].param, branches=branches
    )
    u = dict(units or {})
    if param_unit:
        u[branches[0].param] = param_unit
    return plot_diagram(d, labels=[""], signals=list(states), title=title, units=u)


def forced_diagram(
    branches: Sequence[Branch], *, xkey: str, title: str = "", backbone: Branch | None = None
) -> Figure:
    """An FRC (``xkey="omega"``) or S-curve (``xkey="forcing"``), or a backbone."""
    kind = "backbone" if not branches else ("frc" if xkey == "omega" else "scurve")
    brs = list(branches) if branches else [backbone]
    d = Diagram(kind=kind, system=brs[0].system, param=brs[0].param, branches=brs)
    return plot_diagram(d, labels=[""], title=title)
