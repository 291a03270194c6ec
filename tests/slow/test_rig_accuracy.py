"""The virtual rig's integration across the flutter diagram, against diffrax.

Run with ``pytest --runslow tests/slow/test_rig_accuracy.py``. Free runs of the flutter rig
at 5 kHz from large pitch amplitudes (the size of the largest LCOs and beyond), for the
default model and variants with other nonlinear stiffness, compared with
:func:`bifid.simulate` (diffrax, adaptive Dopri) at tight tolerances; and a variant so stiff
at large amplitude that one RK4 step per sample is useless, where the error control must
keep the rig on the diffrax solution.
"""

from __future__ import annotations

import numpy as np
import pytest

from bifid.cbc import VirtualRig
from bifid.simulate import simulate
from bifid.systems import Envelope, get_system

pytestmark = pytest.mark.slow

KA2, KA3 = 751.6, 5006.7


def _errors(params: dict, x0: list[float], seconds: float, **rig) -> tuple[float, int]:
    """Largest error of the rig's states relative to each state's range, and the most RK4
    steps an interval needed."""
    s = get_system("flutter")
    m = VirtualRig(
        s, params, sample_rate=5000.0, x0=x0, record_states=True, envelope=Envelope(), **rig
    ).run(seconds)
    ref = np.asarray(
        simulate(s, np.asarray(x0), m.time, s.param_vector(params), rtol=1e-12, atol=1e-14)
    )
    err = np.max(np.abs(m.extra["states"] - ref), axis=0) / np.max(np.abs(ref), axis=0)
    return float(np.max(err)), int(m.extra["rk4_steps_max"])


@pytest.mark.parametrize("U", [15.0, 17.0, 18.5])
@pytest.mark.parametrize(("ka2", "ka3"), [(1.0, 1.0), (0.5, 1.5), (1.5, 0.5), (1.5, 1.5)])
def test_flutter_variants_follow_diffrax(U, ka2, ka3):
    """Check 4 s from a 0.15 rad pitch (beyond the largest LCOs) to 1e-8 of each state's
    range, on one RK4 step per sample (the error control never needs more here)."""
    err, steps = _errors(
        {"U": U, "ka2": ka2 * KA2, "ka3": ka3 * KA3}, [0.02, 0.0, 0.15, 0.0, 0.0, 0.0], 4.0
    )
    assert err < 1e-8
    assert steps == 1


def test_error_control_on_a_stiff_variant():
    """Check a variant with 200 times the cubic pitch stiffness from 0.6 rad (a 370 Hz
    pitch oscillation, 13 samples a period): the rig stays within 2e-3 of diffrax over one
    second (phase drift of ~370 periods), where fixed one-step RK4 is off by tens of %."""
    params = {"U": 17.0, "ka3": 200 * KA3}
    x0 = [0.0, 0.0, 0.6, 0.0, 0.0, 0.0]
    err, steps = _errors(params, x0, 1.0)
    assert err < 2e-3 and steps >= 8
    tight, _ = _errors(params, x0, 1.0, rtol=1e-9)
    assert tight < 1e-5
    fixed, _ = _errors(params, x0, 1.0, rtol=1e9, max_substeps=1)
    assert fixed > 0.1
