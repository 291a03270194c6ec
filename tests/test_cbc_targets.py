"""Control targets (eqs. 3.3, 3.13, 3.22) and Fourier projections over whole periods."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

from bifid.cbc import EllipticTarget, FourierTarget, PDController, PolarTarget
from bifid.errors import BifidInputError
from bifid.signal import (
    estimate_frequency,
    fourier_project,
    periodic_amplitude,
    polar_project,
    whole_periods,
)


def test_fourier_target_eq_3_3():
    """Check x* = A0/2 + Σ A_j cos jθ + B_j sin jθ and ẋ* = Ω dx*/dθ."""
    t = FourierTarget([0.4, 1.0, 0.1, 0.0, -0.5])
    vec = jnp.asarray(t.vector())
    th, Om = 0.7, 2.0
    r1, r2 = FourierTarget.reference(vec, 0.0, 0.0, th, Om)
    assert float(r1) == pytest.approx(
        0.2 + math.cos(th) + 0.1 * math.cos(2 * th) - 0.5 * math.sin(2 * th)
    )
    assert float(r2) == pytest.approx(
        Om * (-math.sin(th) - 0.2 * math.sin(2 * th) - 1.0 * math.cos(2 * th))
    )


def test_elliptic_target_is_non_invasive_on_its_ellipse():
    """Check a point on the ellipse of eq. 3.13 is its own target, for both rotations."""
    for omega in (2.5, -2.5):  # eq. 3.13 and eq. 3.14 (x2 = dx1/dt)
        t = EllipticTarget(0.3, omega, (0.1, 0.05))
        vec = jnp.asarray(t.vector())
        for phi in np.linspace(0, 2 * np.pi, 9):
            x1 = 0.1 + 0.3 * math.cos(phi)
            x2 = 0.05 + omega * 0.3 * math.sin(phi)
            r1, r2 = EllipticTarget.reference(vec, x1, x2, 0.0, 0.0)
            assert float(r1) == pytest.approx(x1, abs=1e-14)
            assert float(r2) == pytest.approx(x2, abs=1e-14)
        # off the ellipse the target is the radial projection onto it
        r1, r2 = EllipticTarget.reference(vec, 0.1 + 0.6, 0.05, 0.0, 0.0)
        assert (float(r1), float(r2)) == pytest.approx((0.4, 0.05))


def test_polar_target_reproduces_a_polar_curve():
    """Check eq. 3.22 evaluated at a curve's own points returns them (scaled, offset)."""
    rng = np.random.default_rng(0)
    c = np.concatenate([[1.0], 0.05 * rng.normal(size=6)])  # n_h = 3
    t = PolarTarget(c, scale=(0.5, -3.0), origin=(0.2, 0.0))
    vec = jnp.asarray(t.vector())
    for phi in np.linspace(-np.pi, np.pi, 11)[:-1]:
        k = np.arange(1, 4)
        r = c[0] + c[1:4] @ np.cos(k * phi) + c[4:] @ np.sin(k * phi)
        x1, x2 = 0.2 + 0.5 * r * math.cos(phi), -3.0 * r * math.sin(phi)
        r1, r2 = PolarTarget.reference(vec, x1, x2, 0.0, 0.0)
        assert (float(r1), float(r2)) == pytest.approx((x1, x2), abs=1e-13)


def test_polar_target_with_a_general_transform():
    """Check ξ = T⁻¹(x - o): a tilted ellipse x = o + T (cos φ, sin φ) is the circle r* = 1."""
    T = ((0.02, 0.005), (-0.03, 0.07))
    t = PolarTarget(np.array([1.0, 0.0, 0.0]), origin=(0.001, -0.02), transform=T)
    vec = jnp.asarray(t.vector())
    aux = PolarTarget.compile(vec)
    for phi in np.linspace(-3.0, 3.0, 7):
        x = np.array([0.001, -0.02]) + np.asarray(T) @ np.array([math.cos(phi), math.sin(phi)])
        for fn, arg in ((PolarTarget.reference, vec), (PolarTarget.fast_reference, aux)):
            r1, r2 = fn(arg, x[0], x[1], 0.0, 0.0)
            assert (float(r1), float(r2)) == pytest.approx(tuple(x), abs=1e-12)
    _ph, r = t.polar(
        *(np.array([0.001, -0.02])[:, None] + np.asarray(T) @ np.array([[1.0, 0.0], [0.0, 1.0]]))
    )
    np.testing.assert_allclose(r, 1.0)
    with pytest.raises(BifidInputError, match="invertible"):
        PolarTarget([1.0], transform=((1.0, 2.0), (2.0, 4.0)))


def test_target_validation():
    """Check malformed targets and controllers are rejected with a clear message."""
    with pytest.raises(BifidInputError, match="2q\\+1"):
        FourierTarget([1.0, 2.0])
    with pytest.raises(BifidInputError, match="non-zero"):
        EllipticTarget(0.1, 0.0)
    with pytest.raises(BifidInputError, match=">= 0"):
        EllipticTarget(-0.1, 1.0)
    with pytest.raises(BifidInputError, match="scale"):
        PolarTarget([1.0], scale=(1.0, 0.0))
    with pytest.raises(BifidInputError, match="finite"):
        PDController(float("nan"), 1.0, "h", "h_dot")


def test_whole_periods_and_projection_exact():
    """Check the projection over whole periods returns the coefficients of a synthetic signal."""
    fs, om = 1000.0, 7.3
    n = whole_periods(5000, om, fs)
    per = 2 * np.pi / om * fs
    assert abs(n / per - round(n / per)) < 1e-3 and n <= 5000
    t = np.arange(n) / fs
    x = 0.2 + 1.5 * np.cos(om * t) - 0.4 * np.sin(2 * om * t) + 0.1 * np.cos(3 * om * t)
    c = fourier_project(x, om * t, 4)
    np.testing.assert_allclose(c, [0.2, 1.5, 0, 0.1, 0, 0, -0.4, 0, 0], atol=1e-12)
    with pytest.raises(BifidInputError, match="shorter than one period"):
        whole_periods(10, om, fs)


def test_frequency_and_amplitude_with_noise():
    """Check frequency and Fourier-filtered amplitude on a noisy periodic signal."""
    fs, om = 2000.0, 15.3
    t = np.arange(40000) / fs
    clean = 0.03 + np.cos(om * t) + 0.12 * np.cos(2 * om * t + 1.0)
    x = clean + np.random.default_rng(1).normal(0.0, 0.01, t.size)
    assert estimate_frequency(x, fs, method="crossings") == pytest.approx(om, rel=2e-4)
    amp, mean = periodic_amplitude(x, om, fs)
    ref = np.max(np.abs(clean - 0.03))
    assert amp == pytest.approx(ref, rel=2e-3)  # raw max|x| would be ~3 % high
    assert mean == pytest.approx(0.03, abs=1e-3)
    assert np.max(np.abs(x - x.mean())) > 1.02 * ref


def test_polar_projection_eq_3_24():
    """Check Φ(r) of an off-centre circle sampled uniformly in time against quadrature."""
    om, fs = 3.0, 500.0
    t = np.arange(int(2 * np.pi / om * fs) * 3) / fs
    # a circle of radius 1 centred at (0.3, 0): r(φ) from the polar equation
    x1, x2 = 0.3 + np.cos(om * t), np.sin(om * t)
    phi, r = np.arctan2(x2, x1), np.hypot(x1, x2)
    c = polar_project(phi, r, 6)
    g = np.linspace(-np.pi, np.pi, 200001)[:-1]
    rg = 0.3 * np.cos(g) + np.sqrt(1 - (0.3 * np.sin(g)) ** 2)
    ref = (
        [rg.mean()]
        + [2 * np.mean(rg * np.cos(k * g)) for k in range(1, 7)]
        + [2 * np.mean(rg * np.sin(k * g)) for k in range(1, 7)]
    )
    np.testing.assert_allclose(c, ref, atol=2e-4)
