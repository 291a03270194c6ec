"""PP-CBC round a cycle fold: the noise of the measured zero problem in the bordered
system, the noise reference of relative measurement noise, and the rig's rest."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bifid.cbc import (
    EllipticTarget,
    PDController,
    PPCBCOptions,
    PPCBCProblem,
    VirtualRig,
    defaults_for,
)
from bifid.systems import get_system


class _Family:
    """The two things the problem's error estimate asks of a target family: its number
    of unknowns and their scales (ones: a polar target's)."""

    size = 3
    polar = True

    def scales(self, vec):
        return np.ones(3)


class _Ev:
    y = np.array([0.5, 0.0, 0.0, -0.2])  # a0* = 0.5, μ = -0.2
    floor = np.full(3, 3e-3)


def _problem() -> PPCBCProblem:
    rig = VirtualRig(get_system("hopf"), {"q5": 1.0, "mu": -0.2}, sample_rate=100.0)
    opts = PPCBCOptions(x1="u1", x2="u2", kp=1.0, kd=0.0, n_harmonics=1)
    return PPCBCProblem(rig, opts, _Family(), "mu", 1.0, np.array([0.5, 0.0, 0.0]), 0.1)


def test_zero_noise_is_finite_at_a_fold_with_the_arclength_row():
    """Check the zero's standard errors against the bordered system solved by hand.

    Regular point, fixed μ, ``G_y = [I | 0]``: ``δa0 = δG_0``, so the relative error of
    ``a0*`` is ``σ / a0* = σ / 0.5``. Fold, ``G_y = [[0,0,0,1],[0,1,0,0],[0,0,1,0]]``
    (``a0*`` does not change ``G``, μ does): at fixed μ the bordered system is singular
    (unbounded error); with the arclength row along the tangent (``a0*``) it gives
    ``δa0 = 0`` and ``δμ = δG_0``, a parameter error ``σ / max(|μ|, scale) = σ / 0.2``,
    i.e. 0.5 / 0.2 times the regular point's."""
    prob = _problem()
    prob.jacobian = np.hstack([np.eye(3), np.zeros((3, 1))])
    prob.constraint = None  # fixed μ
    regular, e_p = prob.zero_errors(_Ev)
    assert regular > 0 and e_p == 0.0
    prob.jacobian = np.array([[0.0, 0.0, 0.0, 1.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    e_a, _ = prob.zero_errors(_Ev)
    assert not e_a < 1e3
    prob.constraint = np.array([1.0, 0.0, 0.0, 0.0])  # the tangent at the fold
    e_a, e_p = prob.zero_errors(_Ev)
    assert e_a == pytest.approx(0.0, abs=1e-12)
    assert e_p == pytest.approx(regular * 0.5 / 0.2, rel=1e-9)
    assert prob.zero_noise(_Ev) == pytest.approx(math.hypot(e_a, e_p))


def test_noise_reference_is_the_smallest_lco_of_the_range():
    """Check relative noise refers to the smallest LCO inside the range, not to the
    vanishing cycles next to the Hopf point (μ = 0) that the padded window of the
    model's cycles reaches: on the q5 = 1 normal form over μ in [-0.2, -0.01] it is the
    unstable LCO at μ = -0.01, r² = (1 - sqrt(1 - 0.04)) / 2."""
    d = defaults_for(
        "hopf", {"q5": 1.0}, param="mu", param_range=(-0.2, -0.01), noise_reference=True
    )
    r = math.sqrt((1 - math.sqrt(1 - 0.04)) / 2)
    assert d.noise_reference["u1"] == pytest.approx(r, rel=0.02)


def test_rest_disarms_and_brings_the_rig_to_rest():
    """Check ``rest()`` of a virtual rig: controller off, the state at the rest
    equilibrium (the origin of the normal form), no trip counted; the next run stays
    there."""
    s = get_system("hopf")
    rig = VirtualRig(s, {"q5": 1.0, "mu": -0.2}, sample_rate=100.0)
    rig.set_controller(PDController(1.0, 0.0, "u1", "u2"), EllipticTarget(0.5, 1.0))
    rig.run(20.0)  # the controller draws an orbit of radius about 0.5
    assert np.max(np.abs(rig.state)) > 0.3
    assert rig.rest() is True
    assert rig.controller == (None, None) and rig.trips == 0
    np.testing.assert_allclose(rig.state, 0.0, atol=1e-12)
