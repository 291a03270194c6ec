"""Van der Pol (thesis eq. 5.14): supercritical Hopf at mu = 0; amplitude vs simulation."""

from __future__ import annotations

import numpy as np
import pytest

from bifid.continuation import continue_from_hopf
from bifid.simulate import simulate
from bifid.systems import get_system


@pytest.fixture(scope="module")
def vdp():
    s = get_system("vanderpol")
    return s, *continue_from_hopf(s, "mu", -0.5, 0.5, n_mesh=96)


def test_supercritical_hopf_at_zero(vdp):
    """Check the Hopf point at mu = 0 (to 1e-10) and its criticality."""
    _, eq, _ = vdp
    (h,) = eq.special("hopf")
    assert abs(h.param) < 1e-10
    assert abs(h.data["omega"] - 1.0) < 1e-10
    assert h.data["lyapunov"] < 0 and h.data["criticality"] == "supercritical"


def test_amplitude_at_half_matches_long_simulation(vdp):
    """Check max|z| of the orbit at mu = 0.5 against a long direct simulation (1e-6 rel)."""
    s, _, (br,) = vdp
    assert br.params[-1] == pytest.approx(0.5, abs=1e-12)
    amp = br.data["amplitude"][-1]
    T = br.data["period"][-1]
    # 60 periods to settle on the attracting cycle, then 2 periods sampled finely
    ts = np.concatenate([np.linspace(0.0, 60 * T, 3000, endpoint=False),
                         np.linspace(60 * T, 62 * T, 20001)])
    ys = simulate(s, np.array([0.5, 0.0]), ts, s.param_vector(mu=0.5))
    tail = ys[ts >= 60 * T]
    sim_amp = np.max(np.abs(tail), axis=0)
    assert np.allclose(sim_amp, amp, rtol=1e-5)
    for k in range(2):
        i = np.argmax(np.abs(tail[:, k]))
        y0, y1, y2 = np.abs(tail[i - 1 : i + 2, k])
        peak = y1 + (y0 - y2) ** 2 / (8 * (2 * y1 - y0 - y2))  # parabola through the peak
        assert peak == pytest.approx(amp[k], rel=1e-6)
    assert br.stable[1:].all()
