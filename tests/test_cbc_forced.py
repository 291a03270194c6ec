"""CBC of forced systems (§3.2): the duffing S-curve at Ω = 1.05 round both folds.

The reference is independent of CBC: every measured point is compared with the
uncontrolled system's periodic response at exactly the measured forcing, found by
Newton's method on the Fourier collocation equations started from the rig's true
states; the folds are compared with numerical continuation
(``bifid scurve duffing --omega 1.05 --forcing-range 0.002 0.04``: F = 0.0215934 and
0.0109005, recomputed in ``tests/slow/test_cbc_accuracy.py``).
"""

from __future__ import annotations

import numpy as np
import pytest

from bifid.cbc import VirtualRig
from bifid.cbc._forced import ForcedCBCOptions, folds_of, scurve_cbc
from bifid.cbc._truth import correct_forced, forced_orbit_from_samples
from bifid.continuation import max_abs
from bifid.systems import get_system

FOLDS_CONTINUATION = (0.0215934, 0.0109005)


@pytest.fixture(scope="module")
def duffing_scurve():
    s = get_system("duffing")
    rig = VirtualRig(s, sample_rate=50.0, record_states=True)
    opts = ForcedCBCOptions(signal="q", kp=0.5, kd=0.5, n_harmonics=3, settle_periods=6,
                            measure_periods=2, ds=0.1, ds_max=0.15, stability=False)
    pts, fails = scurve_cbc(rig, 1.05, (0.008, 0.026), opts)
    return s, pts, fails


def test_scurve_goes_round_both_folds(duffing_scurve):
    """Check the S-curve is followed from the lower to the upper branch with 2 folds."""
    _, pts, fails = duffing_scurve
    assert not fails
    amps = np.array([p.amplitude for p in pts])
    assert np.all(np.diff(amps) > 0)  # amplitude grows along an S-curve
    assert pts[0].forcing < 0.011 and pts[-1].forcing > 0.026
    folds = folds_of(pts)
    assert len(folds) == 2
    for f, ref in zip(folds, FOLDS_CONTINUATION, strict=True):
        assert f["forcing"] == pytest.approx(ref, rel=0.02)
    middle = [p for p in pts if folds[0]["amplitude"] < p.amplitude < folds[1]["amplitude"]]
    assert len(middle) >= 5  # the unstable middle branch is measured


def test_points_are_responses_of_the_uncontrolled_system(duffing_scurve):
    """Check amplitudes within 1 % of the uncontrolled response at the same forcing.

    Each point's true states are Newton-corrected (forced collocation) at its own
    (γ, Ω); the control is non-invasive, so the correction must barely move them.
    """
    s, pts, _ = duffing_scurve
    worst = 0.0
    for p in pts:
        m = p.measurement
        V = forced_orbit_from_samples(m.extra["states"], m.phase, p.force_phase, n_mesh=32)
        Vc = correct_forced(s, p.omega, p.forcing, V, n_mesh=32)
        a_true = float(max_abs(Vc[:, 0]))
        worst = max(worst, abs(p.amplitude / a_true - 1.0))
        assert p.invasiveness < 2e-3
    assert worst < 0.01


def test_force_update_matches_eq_3_6_with_exact_derivative():
    """Check one force update equals eq. 3.6 when the derivative comes from the state."""
    from bifid.cbc import FourierTarget
    from bifid.cbc._forced import _measure

    s = get_system("duffing")
    rig = VirtualRig(s, sample_rate=100.0, derivative="state")
    opts = ForcedCBCOptions(signal="q", kp=0.5, kd=0.5, n_harmonics=3)
    q, Om = 3, 1.05
    rig.set_forcing(0.01, Om, 0.0)
    pstar = np.array([0.0, 0.1, 0.0, 0.0, 0.02, 0.0, 0.0])
    rig.set_controller(opts.controller, FourierTarget(pstar))
    r = _measure(rig, opts, Om, 30)
    d = pstar - r.p
    A_hat = opts.kp * d[1] + Om * opts.kd * d[q + 1]  # eq. 3.6, cos part of u
    B_hat = opts.kp * d[q + 1] - Om * opts.kd * d[1]  # sin part
    assert r.u[1] == pytest.approx(A_hat, rel=1e-3, abs=1e-9)
    assert r.u[q + 1] == pytest.approx(B_hat, rel=1e-3, abs=1e-9)
