"""PP-CBC campaigns on a system with a model: the LCOs a scan asks for are the model's
cycles at each value; those outside the rig's safety envelope are refused up front, and
what is left unmeasured is one failure per LCO, with its reason.

``hopf`` with q5 = 1 (polar form ṙ = (μ - μ0) r + r³ - r⁵): at μ the LCOs have
r² = (1 ± sqrt(1 + 4μ))/2, the smaller unstable.
"""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest

from bifid.cbc import ppcbc_campaign
from bifid.systems import Envelope


def test_lco_outside_the_envelope_is_refused_not_tripped():
    """Check a scan whose model has an LCO outside the rig's safety envelope measures the
    LCO inside it and records the other as refused up front, with the reason (one
    failure, not a trip) (``hopf``, q5 = 1, μ = -0.1: r = 0.331 unstable, 0.945
    stable; envelope |u_i| <= 0.8)."""
    mu = -0.1
    d = math.sqrt(1 + 4 * mu)
    r_u, r_s = math.sqrt((1 - d) / 2), math.sqrt((1 + d) / 2)
    env = Envelope(states={"u1": (-0.8, 0.8), "u2": (-0.8, 0.8)}, control_max=2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = ppcbc_campaign(
            "hopf",
            param="mu",
            values=[mu],
            overrides={"q5": 1.0},
            amplitudes=np.linspace(0.15, 1.05, 7),
            rig_options={"sample_rate": 100.0, "envelope": env},
            options=dict(
                x1="u1",
                x2="u2",
                kp=1.0,
                kd=0.0,
                n_harmonics=3,
                stability=False,
                settle_periods=5.0,
                measure_periods=2.0,
            ),
        )
    assert [p.amplitude["u1"] for p in r.points] == [pytest.approx(r_u, rel=5e-3)]
    assert len(r.failures) == 1
    f = r.failures[0].to_json()
    assert "outside the rig's safety envelope" in f["reason"]
    assert f["lco"] == pytest.approx(r_s, rel=0.02)
    # the scan stops below the refused LCO: a trip on the way there (the transient to a
    # target between the LCOs) is no failure of an LCO the campaign asks for
    assert "tripped" not in json.dumps([x.to_json() for x in r.failures])
    assert r.diagram.to_json()["complete"] is False
