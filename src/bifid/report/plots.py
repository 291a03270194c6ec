"""Matplotlib figures of branches: bifurcation diagrams, FRCs, S-curves, backbones.

Stable parts are drawn solid, unstable parts dashed; special points are marked and
labelled, so a figure can be read without the JSON beside it.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from bifid.continuation import Branch

STABLE = dict(color="tab:blue", lw=1.8)
UNSTABLE = dict(color="tab:red", lw=1.5, ls="--")


def _segments(x: np.ndarray, y: np.ndarray, stable: np.ndarray):
    """Split a curve into runs of equal stability (runs share their end points)."""
    start = 0
    for i in range(1, len(x) + 1):
        if i == len(x) or stable[i] != stable[start]:
            stop = min(i + 1, len(x))
            yield x[start:stop], y[start:stop], bool(stable[start])
            start = i


def plot_curve(ax, x, y, stable, label: str | None = None, color: str | None = None) -> None:
    """Plot a curve solid where stable and dashed where unstable."""
    first = {True: True, False: True}
    for xs, ys, st in _segments(np.asarray(x), np.asarray(y), np.asarray(stable)):
        style = dict(STABLE if st else UNSTABLE)
        if color is not None:
            style["color"] = color
        lab = None
        if first[st]:
            lab = f"{label + ' ' if label else ''}{'stable' if st else 'unstable'}"
            first[st] = False
        ax.plot(xs, ys, label=lab, **style)


def _with_hopf_points(eq: Branch, k: int):
    """Equilibrium curve with the located Hopf points inserted, so stability switches there."""
    x, y, st = list(eq.params), list(np.abs(eq.solutions[:, k])), list(eq.stable)
    for sp in sorted(eq.special("hopf"), key=lambda s: -s.index):
        i = sp.index + 1
        x.insert(i, sp.param)
        y.insert(i, abs(float(sp.solution[k])))
        st.insert(i, st[i])  # the next point's stability starts at the Hopf point
    return np.array(x), np.array(y), np.array(st)


def save_figure(fig, path: str | os.PathLike) -> Path:
    """Save atomically (temporary file, then rename) and close the figure."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=path.suffix)
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=130, bbox_inches="tight")
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; give the usual permissions
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
        plt.close(fig)
    return path


def bifurcation_diagram(
    equilibria: Branch | None,
    orbits: Sequence[Branch],
    states: Sequence[str],
    *,
    title: str = "",
    units: dict[str, str] | None = None,
    param_unit: str = "",
):
    """Amplitude ``max_t |x_s(t)|`` of the chosen states along orbit branches.

    Returns
    -------
    matplotlib.figure.Figure
    """
    units = units or {}
    fig, axes = plt.subplots(len(states), 1, figsize=(6.4, 2.8 * len(states)), sharex=True,
                             squeeze=False)
    for ax, state in zip(axes[:, 0], states, strict=True):
        if equilibria is not None:
            k = equilibria.meta["states"].index(state)
            x, y, st = _with_hopf_points(equilibria, k)
            plot_curve(ax, x, y, st, label="equilibria", color="0.35")
        for br in orbits:
            k = br.meta["states"].index(state)
            plot_curve(ax, br.params, br.data["amplitude"][:, k], br.stable, label="orbits")
            for sp in br.special_points:
                if sp.kind == "cycle_fold":
                    ax.plot(sp.param, sp.data["amplitude"][k], "ks", ms=6)
                    ax.annotate(f"fold {sp.param:.4g}", (sp.param, sp.data["amplitude"][k]),
                                textcoords="offset points", xytext=(6, -12), fontsize=8)
        if equilibria is not None:
            for sp in equilibria.special("hopf"):
                ax.plot(sp.param, 0.0, "k^", ms=7)
                ax.annotate(f"Hopf {sp.param:.5g}", (sp.param, 0.0), textcoords="offset points",
                            xytext=(-20, 8), fontsize=8)
        ax.set_ylabel(f"amplitude {state}" + (f" [{units[state]}]" if units.get(state) else ""))
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="best")
    if orbits:
        axes[-1, 0].set_xlabel(f"{orbits[0].param}" + (f" [{param_unit}]" if param_unit else ""))
    if title:
        axes[0, 0].set_title(title)
    fig.tight_layout()
    return fig


def forced_diagram(branches: Sequence[Branch], *, xkey: str, title: str = "",
                   backbone: Branch | None = None):
    """FRC (``xkey="omega"``) or S-curve (``xkey="forcing"``) with folds, optional backbone."""
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for br in branches:
        plot_curve(ax, br.data[xkey], br.data["observed_amplitude"], br.stable)
        for sp in br.special("fold"):
            ax.plot(sp.data[xkey], sp.data["amplitude"], "ks", ms=5)
    if backbone is not None:
        ax.plot(backbone.data["omega"], backbone.data["observed_amplitude"], "k:", lw=1.2,
                label="backbone")
    obs = branches[0].meta["observed"] if branches else (backbone.meta["observed"] if backbone
                                                          else "")
    ax.set_xlabel("forcing frequency Ω [rad/s]" if xkey == "omega" else "forcing amplitude F")
    ax.set_ylabel(f"amplitude max|{obs}|")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    return fig
