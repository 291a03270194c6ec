"""Branch ends of periodic orbits are events: a Hopf point, a range bound — with the reason
in the branch, and no false cycle fold where a branch ends (the homoclinic end:
``tests/slow/test_orbit_events.py``)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from bifid.continuation import ContinuationOptions, continue_from_hopf, equilibria, hopf_orbits
from bifid.systems import Parameter, System


def _two_hopf(x, p):
    # r' = r (mu (1 - mu) - r^2): Hopf points at mu = 0 and mu = 1, orbits r^2 = mu (1 - mu)
    mu = p[0]
    g = mu * (1 - mu) - x[0] ** 2 - x[1] ** 2
    return jnp.stack([g * x[0] - x[1], g * x[1] + x[0]])


def _system(name, field):
    return System(
        name=name,
        states=("x", "y"),
        parameters=(Parameter("mu", 0.0, "nd", ""),),
        field=field,
        default_param="mu",
    )


def test_branch_shrinking_into_a_hopf_point_ends_there():
    """Check that the orbits born at mu = 0 end at the Hopf point mu = 1 (status "hopf",
    located to 1e-9, a zero-amplitude last orbit) with no cycle fold, radii exact."""
    s = _system("two_hopf", _two_hopf)
    eq = equilibria(
        s, "mu", start=-0.5, options=ContinuationOptions(ds=0.05, ds_max=0.1, p_min=-0.5, p_max=1.5)
    )
    h0 = min(eq.special("hopf"), key=lambda h: h.param)
    br = hopf_orbits(
        s,
        h0,
        n_mesh=16,
        options=ContinuationOptions(ds=1e-3, ds_max=0.1, ds_min=1e-9, p_min=-0.5, p_max=1.5),
    )
    assert br.status == "hopf" and br.complete
    assert br.params[-1] == pytest.approx(1.0, abs=1e-9)
    assert br.meta["end_hopf"]["param"] == pytest.approx(1.0, abs=1e-9)
    assert np.max(br.data["amplitude_centred"][-1]) < 1e-12
    assert not br.special("cycle_fold") and not br.candidates
    mu = br.params[1:-1]
    assert np.allclose(br.data["amplitude"][1:-1, 0], np.sqrt(mu * (1 - mu)), rtol=1e-9)


def test_range_bound_ends_the_branch_exactly():
    """Check a branch cut by the range: status "range", last parameter on the bound."""
    s = _system("two_hopf", _two_hopf)
    _, branches = continue_from_hopf(s, "mu", -0.5, 0.6, n_mesh=16)
    (br,) = [b for b in branches if b.meta["start_param"] < 0.5]
    assert br.status == "range" and br.params[-1] == pytest.approx(0.6, abs=1e-12)
    assert "0.6" in br.message
