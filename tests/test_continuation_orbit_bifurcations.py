"""Period doubling and torus points of periodic orbits: located on their own test
functions and verified, at the exact parameter values of a system built for the test
(none on a planar system: ``test_continuation_vanderpol``)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from bifid.continuation import ContinuationOptions, periodic_orbits
from bifid.systems import Parameter, System

PD_AT, TORUS_AT, BETA = 0.0, 0.3, 0.37


def _field(z, p):
    """A unit circle (x, y) carrying two transverse planes: (u, v) expressed in a frame
    turning by half a turn per period, with rates (mu, -1) (multipliers -e^{2 pi mu},
    -e^{-2 pi}: period doubling at mu = 0), and (a, b), a focus with rate mu - 0.3 and
    frequency 0.37 (multipliers e^{2 pi (mu - 0.3 ± 0.37 i)}: torus at mu = 0.3)."""
    mu = p[0]
    x, y, u, v, a, b = z
    r2 = x**2 + y**2
    g = 1.0 - r2
    r = jnp.sqrt(r2)
    c, s = x / r, y / r
    s1, s2 = mu, -1.0
    h, d = 0.5 * (s1 + s2), 0.5 * (s1 - s2)
    du = -0.5 * v + (h + d * c) * u + d * s * v
    dv = 0.5 * u + d * s * u + (h - d * c) * v
    return jnp.stack(
        [
            g * x - y,
            g * y + x,
            du,
            dv,
            (mu - TORUS_AT) * a - BETA * b,
            BETA * a + (mu - TORUS_AT) * b,
        ]
    )


def test_period_doubling_and_torus_located_and_verified():
    """Check the period doubling at mu = 0 (a real multiplier at -1) and the torus point
    at mu = 0.3 (a complex pair on the unit circle at angle 2 pi 0.37), both to 1e-9,
    verified, and nothing else."""
    s = System(
        name="pd_torus",
        states=("x", "y", "u", "v", "a", "b"),
        parameters=(Parameter("mu", -0.4, "nd", ""),),
        field=_field,
        default_param="mu",
    )
    M = 16
    t = 2 * np.pi * np.arange(M) / M
    orbit = np.zeros((M, 6))
    orbit[:, 0], orbit[:, 1] = np.cos(t), np.sin(t)
    br = periodic_orbits(
        s,
        "mu",
        orbit,
        2 * np.pi,
        n_mesh=M,
        options=ContinuationOptions(ds=0.05, ds_max=0.1, ds_min=1e-9, p_min=-0.4, p_max=0.6),
    )
    assert br.status == "range"
    (pd,) = br.special("period_doubling")
    (ns,) = br.special("torus")
    assert pd.param == pytest.approx(PD_AT, abs=1e-9)
    assert ns.param == pytest.approx(TORUS_AT, abs=1e-9)
    assert pd.verification["multiplier_plus_one"] < 1e-6
    assert ns.verification["modulus_minus_one"] < 1e-6
    assert ns.verification["argument"] == pytest.approx(
        2 * np.pi * (1 - BETA), abs=1e-6
    ) or ns.verification["argument"] == pytest.approx(2 * np.pi * BETA, abs=1e-6)
    assert not br.special("cycle_fold") and not br.special("branch_point")
    assert not br.candidates
    # stable below the period doubling, unstable beyond
    assert np.all(br.stable[br.params < -1e-6]) and not np.any(br.stable[br.params > 1e-6])
