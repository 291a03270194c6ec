"""A diagram saved to netCDF loads back with its branches, intervals and options."""

from __future__ import annotations

import math

import numpy as np

from bifid.continuation import Branch, ContinuationOptions, Diagram, SpecialPoint


def test_diagram_round_trips_with_default_options_and_intervals(tmp_path):
    """Check a predicted FRC-like diagram (options with infinite default bounds, intervals
    on the branch and on a special point) against the one written."""
    om = np.linspace(0.9, 1.1, 7)
    amp = 1.0 / (0.01 + (om - 1.0) ** 2)
    br = Branch(
        kind="forced",
        system="toy",
        param="Omega",
        params=om,
        solutions=amp[:, None],
        stable=np.ones(7, bool),
        special_points=[
            SpecialPoint(
                kind="peak",
                param=1.0,
                index=3,
                bracket=(0.95, 1.05),
                solution=np.array([100.0, 1.0]),
                data={"amplitude": 100.0},
                intervals={"param": (0.99, 1.01)},
            )
        ],
        data={"omega": om, "amplitude": amp[:, None]},
        p=np.array([1.0, 0.01]),
        status="completed",
        message="",
        options=ContinuationOptions(ds=0.02, p_max=1.1),
        intervals={"amplitude": (0.9 * amp[:, None], 1.1 * amp[:, None])},
    )
    d = Diagram(kind="frc", system="toy", param="Omega", branches=[br], level=0.95)
    d.save(tmp_path / "d.nc")
    back = Diagram.load(tmp_path / "d.nc")
    (b,) = back.branches
    assert back.level == 0.95 and back.kind == "frc"
    assert np.array_equal(b.params, om) and np.array_equal(np.ravel(b.data["amplitude"]), amp)
    lo, hi = b.intervals["amplitude"]
    assert np.allclose(np.ravel(lo), 0.9 * amp) and np.allclose(np.ravel(hi), 1.1 * amp)
    (sp,) = b.special("peak")
    assert sp.param == 1.0 and tuple(np.ravel(sp.intervals["param"])) == (0.99, 1.01)
    assert b.options.ds == 0.02 and b.options.p_max == 1.1
    assert b.options.p_min == -math.inf and b.options.dp_max == math.inf
