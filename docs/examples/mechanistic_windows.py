"""Sensitivity of the linear stage to the free-decay window (flutter rig set-up 1, §4.3.1).

Run from the repository root (about 5 min on a loaded 2-core machine; every window length
compiles its own scan):

    .venv/bin/python docs/examples/mechanistic_windows.py

Fits (Ia, ca, ch) with ka tied to Ia on windows starting 0.3 s, at the release (0.56 s),
1 s and 2 s, to the end of the record or over 3 s, and prints them beside Table 4.1.
"""

# bifid-example: slow (eight fits, each window length compiled anew)

from __future__ import annotations

from pathlib import Path

import numpy as np

from bifid.data import load_free_decay
from bifid.identify import LinearPEM
from bifid.identify.mechanistic import release_index

RIG = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "flutter_rig"
fd = load_free_decay(RIG / "free_decay" / "model1_free_decay.mat")
y = np.column_stack([fd.heave, fd.pitch])
fs, g = fd.sample_rate, fd.guesses
start = {
    "U": 0.0,
    "Ia": g["I__alpha"],
    "ca": g["c__alpha"],
    "ch": g["c__h"],
    "ka": g["k__alpha"],
    "kh": g["k__h"],
    "xa": g["x__alpha"],
}
print("| window [s] | Ia | ca | ch | fit h [%] | fit alpha [%] |")
print("|---|---|---|---|---|---|")
print("| Table 4.1 | 0.1724 | 0.5628 | 14.5756 | | |")
for t0 in (0.3, release_index(y) / fs, 1.0, 2.0):
    for dur in (None, 3.0):
        a = round(t0 * fs)
        b = len(y) if dur is None else a + round(dur * fs)
        m = LinearPEM(
            "flutter",
            ("Ia", "ca", "ch"),
            ("h", "alpha"),
            params=start,
            ratios={"ka": "Ia"},
            decimate=10,
        ).fit(y[a:b], fs)
        print(
            f"| {t0:.2f}–{b / fs:.2f} | {m.params_['Ia']:.4f} | {m.params_['ca']:.4f} | "
            f"{m.params_['ch']:.3f} | {m.fit_percent_['h']:.1f} | "
            f"{m.fit_percent_['alpha']:.1f} |",
            flush=True,
        )
