"""Continuation of the normal-form-like Hopf model against its closed form (thesis eq. 5.3)."""

from __future__ import annotations

import numpy as np
import pytest

from bifid.continuation import ContinuationOptions, continue_from_hopf, equilibria
from bifid.systems import get_system

MU0, A2, OMEGA0 = 0.2, 0.8, 2.0


@pytest.fixture(scope="module")
def subcritical():
    s = get_system("hopf")
    p = s.param_vector(mu0=MU0, a2=A2, omega0=OMEGA0, q5=1.0)
    return continue_from_hopf(s, "mu", -1.0, 1.0, p=p, n_mesh=32)


def test_hopf_point_and_lyapunov_coefficient(subcritical):
    """Check the Hopf point, its frequency and l1 = 2 a2 / omega0 (Kuznetsov normalisation)."""
    eq, _ = subcritical
    (h,) = eq.special("hopf")
    assert h.status == "converged"
    assert abs(h.param - MU0) < 1e-10
    assert abs(h.data["omega"] - OMEGA0) < 1e-10
    assert h.data["lyapunov"] == pytest.approx(2 * A2 / OMEGA0, rel=1e-8)
    assert h.data["criticality"] == "subcritical"
    assert h.bracket[0] <= h.param <= h.bracket[1] or h.bracket[1] <= h.param <= h.bracket[0]


def test_orbit_radius_period_and_fold_match_closed_form(subcritical):
    """Check r(mu), T = 2 pi / omega0 and the cycle fold at mu0 - a2^2/4 to 1e-8."""
    _, (br,) = subcritical
    r = br.data["amplitude"][:, 0]  # max_t |u1| = r on a circle
    mu = br.params
    assert np.max(np.abs(mu - MU0 + A2 * r**2 - r**4)) < 1e-8
    assert np.max(np.abs(br.data["period"] - 2 * np.pi / OMEGA0)) < 1e-8
    (fold,) = br.special("cycle_fold")
    assert abs(fold.param - (MU0 - A2**2 / 4)) < 1e-8
    assert abs(fold.data["amplitude"][0] - np.sqrt(A2 / 2)) < 1e-6
    # stability: unstable between the Hopf point and the fold, stable beyond
    k = fold.index
    assert not br.stable[1 : k + 1].any()
    assert br.stable[k + 2 :].all()
    assert br.status == "range" and br.params[-1] == pytest.approx(1.0, abs=1e-12)


def test_supercritical_case_has_negative_l1_and_stable_orbits():
    """Check the supercritical case (a2 < 0, quintic off): l1 < 0, stable cycles r² = mu."""
    s = get_system("hopf")
    p = s.param_vector(a2=-1.0, q5=0.0, omega0=1.0)
    eq, (br,) = continue_from_hopf(s, "mu", -0.5, 0.5, p=p, n_mesh=16)
    (h,) = eq.special("hopf")
    assert h.data["lyapunov"] == pytest.approx(-2.0, rel=1e-8)
    assert h.data["criticality"] == "supercritical"
    assert br.stable[1:].all()
    assert np.max(np.abs(br.data["amplitude"][:, 0] ** 2 - br.params)) < 1e-9


def test_equilibrium_stability_changes_at_hopf():
    """Check that the origin is stable below mu0 and unstable above."""
    s = get_system("hopf")
    eq = equilibria(
        s,
        "mu",
        p=s.param_vector(mu0=0.1),
        start=-0.5,
        options=ContinuationOptions(ds=0.05, ds_max=0.1, p_min=-0.5, p_max=0.5),
    )
    assert eq.stable[eq.params < 0.1 - 1e-9].all()
    assert not eq.stable[eq.params > 0.1 + 1e-9].any()
