"""Worked example of docs/data-formats.md: import the real flutter-rig CBC runs and look at them.

Run from the repository root:  .venv/bin/python docs/examples/data_import.py
(needs ../shared/data; writes cbc_model1.nc and data_import_cbc_model1.png into out/, or
into $BIFID_EXAMPLE_OUT when set).
"""

from __future__ import annotations

import os
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from bifid.data import (
    import_files,
    lco_records,
    load_dataset,
    load_thesis_curves,
    save_dataset,
)

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data" / "flutter_rig"


def main() -> None:
    out = Path(os.environ.get("BIFID_EXAMPLE_OUT", ROOT / "out"))
    out.mkdir(exist_ok=True)
    # 1. import (what `bifid import ../shared/data/flutter_rig/cbc_model1 --out ...` does)
    ds = import_files([DATA / "cbc_model1"])
    save_dataset(ds, out / "cbc_model1.nc")
    ds = load_dataset(out / "cbc_model1.nc")

    # 2. look at it: amplitude-speed diagram and one orbit in the (h, alpha) plane
    U = ds["param"].values
    amp = ds["amplitude"].values  # (record, signal): max |h| [m], max |alpha| [rad]
    stable = ds["stable"].values == 1
    fig, axes = plt.subplots(1, 3, figsize=(13, 4), constrained_layout=True)
    curve_u, curve_h, curve_a = load_thesis_curves(
        DATA / "thesis_curves" / "nonlinear_id_Data_8-1.csv"
    )
    for ax, j, label, scale, model in (
        (axes[0], 0, "heave amplitude [mm]", 1e3, curve_h),
        (axes[1], 1, "pitch amplitude [rad]", 1.0, curve_a),
    ):
        ax.plot(curve_u, model * scale, color="0.6", lw=1.5, label="thesis model (ch. 4)")
        ax.plot(U[stable], amp[stable, j] * scale, "o", color="C0", label="stable LCO (CBC)")
        ax.plot(
            U[~stable],
            amp[~stable, j] * scale,
            "o",
            mfc="white",
            color="C3",
            label="unstable LCO (CBC)",
        )
        ax.set_xlabel("wind speed U [m/s]")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].legend(frameon=False)
    for r, color in zip(lco_records(ds)[::4], ("C0", "C3", "C2"), strict=False):
        n = int(2 * 2 * np.pi / r.frequency * r.sample_rate)  # two periods
        axes[2].plot(
            r.signals[:n, 0] * 1e3,
            r.signals[:n, 1],
            color=color,
            lw=1,
            label=f"U = {r.param:g} m/s, {'stable' if r.stable else 'unstable'}",
        )
    axes[2].set_xlabel("heave h [mm]")
    axes[2].set_ylabel("pitch alpha [rad]")
    axes[2].legend(frameon=False, fontsize=8)
    axes[2].grid(alpha=0.3)
    fig.suptitle("Flutter rig, set-up 1: limit cycles measured by PP-CBC (bifid import)")
    path = out / "data_import_cbc_model1.png"
    fig.savefig(path, dpi=110)
    print(f"wrote {out / 'cbc_model1.nc'} and {path}")


if __name__ == "__main__":
    main()
