"""Controller gains that stabilise (Floquet multipliers of the controlled system) and the
switch-off stability test (Fig. 3.18)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bifid.cbc import (
    EllipticTarget,
    PDController,
    VirtualRig,
    controlled_floquet,
    defaults_for,
    orbit_polar_target,
    switch_off_test,
)
from bifid.errors import BifidInputError
from bifid.systems import get_system

R0 = math.sqrt(0.1)


@pytest.fixture(scope="module")
def hopf_orbit():
    s = get_system("hopf")
    p = np.asarray(s.param_vector(mu=-0.1, q5=0.0))
    tau = 2 * np.pi * np.arange(32) / 32
    return s, p, np.stack([R0 * np.cos(tau), R0 * np.sin(tau)], axis=1)


def test_hopf_gains_stabilise_the_unstable_lco(hopf_orbit):
    """Check the default and the thesis's gains stabilise the LCO of eq. 3.16 (Fig. 3.9).

    Uncontrolled: non-trivial multiplier exp(2π · 2 r0²) = exp(0.4π) ≈ 3.51. Controlled:
    the radial dynamics gain -kp/2, so |μ| = exp(2π (0.2 - kp/2)).
    """
    s, p, V = hopf_orbit
    target = EllipticTarget(R0, 1.0)
    mu, fmax = controlled_floquet(s, PDController(0.0, 0.0, "u1", "u2"), target, V, 2 * np.pi, p)
    assert fmax == pytest.approx(math.exp(0.4 * math.pi), rel=1e-3)
    d = defaults_for("hopf")
    mu, fmax = controlled_floquet(s, PDController(d.kp, d.kd, "u1", "u2"), target, V, 2 * np.pi, p)
    assert np.min(np.abs(mu - 1.0)) < 1e-6  # the trivial multiplier
    assert fmax == pytest.approx(math.exp(2 * math.pi * (0.2 - d.kp / 2)), rel=1e-3)
    _, fmax_thesis = controlled_floquet(
        s, PDController(0.5, -0.5, "u1", "u2"), target, V, 2 * np.pi, p
    )
    assert fmax_thesis < 1.0


def test_switch_off_labels():
    """Check the switch-off test: unstable LCO of eq. 3.16 leaves, the stable one stays."""
    s = get_system("hopf")
    c = PDController(1.0, 0.0, "u1", "u2")
    r_u = math.sqrt((1 - math.sqrt(1 - 0.4)) / 2)  # q5 = 1, mu = -0.1
    r_s = math.sqrt((1 + math.sqrt(1 - 0.4)) / 2)
    for r, expected in ((r_u, False), (r_s, True)):
        rig = VirtualRig(s, {"mu": -0.1, "q5": 1.0}, sample_rate=100.0)
        t = EllipticTarget(r, 1.0)
        rig.set_controller(c, t)
        rig.run(40.0)
        res, _ = switch_off_test(
            rig,
            "u1",
            r,
            1.0,
            controller=c,
            nudged_target=EllipticTarget(0.95 * r, 1.0),
            restore_target=t,
        )
        assert res.stable is expected
        assert (res.growth > 1.0) is (not expected)


def test_output_filter_enters_the_controlled_floquet_multipliers():
    """With an output low-pass the closed loop has one more state (the filter's): one more
    multiplier, ≈ exp(-2π f_c T), and the others tend to the unfiltered ones as f_c → ∞
    (the filter's effect is O(ω/ω_c))."""
    s = get_system("hopf")
    r = math.sqrt((1 - math.sqrt(1 - 0.4)) / 2)  # the unstable LCO, q5 = 1, mu = -0.1
    p = np.asarray(s.param_vector(mu=-0.1, q5=1.0))
    tau = 2 * np.pi * np.arange(64) / 64
    V = np.stack([r * np.cos(tau), r * np.sin(tau)], axis=1)
    target = EllipticTarget(r, 1.0)
    mu0, f0 = controlled_floquet(s, PDController(1.0, 0.0, "u1", "u2"), target, V, 2 * np.pi, p)
    errs = []
    for fc in (1.0, 10.0, 100.0):
        mu, fmax = controlled_floquet(
            s, PDController(1.0, 0.0, "u1", "u2", fc), target, V, 2 * np.pi, p
        )
        assert mu.shape == (3,) and mu0.shape == (2,)
        assert np.min(np.abs(mu - 1.0)) < 1e-6  # trivial multiplier kept
        assert np.min(np.abs(mu)) < 1e-6  # the filter's own mode, exp(-2π f_c 2π)
        errs.append(abs(fmax / f0 - 1))
    assert errs[0] > 0.1  # a 1 Hz filter on a 0.16 Hz orbit changes the loop
    assert errs[1] < errs[0] / 5 and errs[2] < errs[1] / 5 and errs[2] < 5e-3


def test_polar_target_of_an_orbit_is_non_invasive_in_a_stretched_plane():
    """Check the polar target of a known orbit in the (u1, u1') plane with omega0 = 10,
    where the orbit is an ellipse of aspect 10 (u1' = -10 u2): in the orbit's own frame
    (the default) the orbit still solves the controlled system (trivial multiplier 1) and
    the radial feedback gives the closed form exp((0.2 - kp/2) T) with T = 2π/ω0 (eq.
    3.16: radial rate 0.2 without control, ``kp`` acting on u1 only: -kp/2 on average); in
    the unscaled frame ten harmonics of r*(φ) cannot follow the ellipse, the target is
    invasive, and the computation is refused instead of returning multipliers of a
    curve that is not an orbit."""
    s = get_system("hopf")
    p = np.asarray(s.param_vector(mu=-0.1, q5=0.0, omega0=10.0))
    tau = 2 * np.pi * np.arange(64) / 64
    V = np.stack([R0 * np.cos(tau), R0 * np.sin(tau)], axis=1)
    T = 2 * np.pi / 10.0
    kp = 1.0
    c = PDController(kp, 0.0, "u1", "u1_dot")
    target = orbit_polar_target(V, s, "u1", "u1_dot", 10, p=p)
    mu, fmax = controlled_floquet(s, c, target, V, T, p)
    assert np.min(np.abs(mu - 1.0)) < 1e-8
    assert fmax == pytest.approx(math.exp((0.2 - kp / 2) * T), rel=1e-3)
    stretched = orbit_polar_target(V, s, "u1", "u1_dot", 10, p=p, scale=(1.0, 1.0))
    with pytest.raises(BifidInputError, match="not a solution of the controlled system"):
        controlled_floquet(s, c, stretched, V, T, p)
