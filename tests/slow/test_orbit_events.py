"""Orbit events that take longer to reach (opt-in: ``--runslow``): a branch point of
cycles (AUTO-07p demo pp3) and a branch ending in a homoclinic approach."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from bifid.continuation import continue_from_hopf
from bifid.systems import Parameter, System

pytestmark = pytest.mark.slow


def _fish(x, p):
    # x'' = x - x^2 + x' (mu + x): a Hopf point of (1, 0) at mu = -1 whose orbits grow into
    # the homoclinic loop of the saddle at the origin (Melnikov: mu ≈ -6/7)
    return jnp.stack([x[1], x[0] - x[0] ** 2 + x[1] * (p[0] + x[0])])


def _system(name, field):
    return System(
        name=name,
        states=("x", "y"),
        parameters=(Parameter("mu", 0.0, "nd", ""),),
        field=field,
        default_param="mu",
    )


def test_period_growing_without_bound_ends_as_homoclinic():
    """Check that the orbits of the Hopf point at mu = -1 end as a homoclinic approach
    near mu = -6/7 (first-order Melnikov estimate), with the largest period reported."""
    s = _system("fish", _fish)
    _, (br,) = continue_from_hopf(s, "mu", -1.5, 0.0, x0=np.array([1.0, 0.0]), n_mesh=32)
    assert br.status == "homoclinic" and br.complete
    assert br.params[-1] == pytest.approx(-6 / 7, abs=0.02)
    assert br.meta["max_period"] == pytest.approx(float(np.max(br.data["period"])))
    assert br.meta["max_period"] > 2 * br.data["period"][0]
    assert "period grows without bound" in br.message
    assert not br.special("cycle_fold")
    assert np.all(br.verification["spectral_tail"] <= 1e-9)


def _pp3(u, p):
    # AUTO-07p demo pp3 (predator, prey, superpredator with harvesting p1); the plane
    # u3 = 0 is invariant, and its cycles meet the cycles with u3 > 0 at a branch point
    p1, p2, p3, p4, p5, p6 = p[0], 0.25, 0.5, 4.0, 3.0, 5.0
    return jnp.stack(
        [
            u[0] * (1 - u[0]) - p4 * u[0] * u[1],
            -p2 * u[1] + p4 * u[0] * u[1] - p5 * u[1] * u[2] - p1 * (1 - jnp.exp(-p6 * u[1])),
            -p3 * u[2] + p5 * u[1] * u[2],
        ]
    )


def test_cycle_branch_point_is_not_a_fold_and_the_family_is_kept():
    """Check the cycles of pp3 born at p1 = 0.4596: the branch point at p1 = 0.301234
    (AUTO-07p's value, to its 6 printed digits) is located and verified as a branch point
    (a non-trivial multiplier at +1, the tangent not turning), no cycle fold is reported,
    and every orbit stays in the invariant plane u3 = 0 (no silent change of family)."""
    s = System(
        name="pp3",
        states=("u1", "u2", "u3"),
        parameters=(Parameter("p1", 0.0, "1", ""),),
        field=_pp3,
        default_param="p1",
    )
    _, (br,) = continue_from_hopf(
        s, "p1", 0.800796, 0.3, x0=np.array([1.19897, -0.049742, 0.0]), n_mesh=32
    )
    (bp,) = br.special("branch_point")
    assert bp.param == pytest.approx(0.301234, abs=2e-6)
    assert bp.verification["multiplier_minus_one"] < 1e-4
    assert abs(bp.verification["tangent_param"]) > 1e-3
    assert not br.special("cycle_fold") and not br.candidates
    M = br.meta["n_mesh"]
    assert np.max(np.abs(br.solutions[:, : M * 3].reshape(len(br), M, 3)[:, :, 2])) < 1e-10
