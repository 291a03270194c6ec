"""Floquet multipliers from the collocation operator (``stability="collocation"``) against
exact values, and the special points they verify.

The ``hopf`` system (eq. 5.2) has circular orbits ``r*`` with the analytic non-trivial
log-multiplier ``T (2 a2 r² - 4 q5 r⁴)``; a three-state system in which that normal form
drives a contracting third state has the second exact log-multiplier
``-c int (1 + x0²) dt`` (the system is triangular).
"""

from __future__ import annotations

import numpy as np
import pytest

from bifid.continuation import ContinuationOptions, hopf_orbits, locate_hopf, periodic_orbits
from bifid.errors import BifidInputError
from bifid.systems import Parameter, System, get_system

MU0, A2, OMEGA0 = 0.2, 0.8, 2.0


def _hopf_branch(stability: str):
    s = get_system("hopf")
    p = s.param_vector(mu0=MU0, a2=A2, omega0=OMEGA0, q5=1.0)
    h = locate_hopf(s, "mu", np.zeros(2), MU0, p)
    opts = ContinuationOptions(ds=1e-3, ds_max=0.05, p_min=-0.5, p_max=1.0, max_steps=400)
    return hopf_orbits(s, h, p=p, n_mesh=16, options=opts, adapt=False, stability=stability)


def test_hopf_branch_multipliers_labels_and_verified_fold():
    """Check the non-trivial log-multiplier of every orbit (1e-8), the labels, and the
    cycle fold at mu0 - a2²/4 verified with a multiplier at +1 from the collocation
    operator."""
    br = _hopf_branch("collocation")
    assert br.meta["stability"] == "collocation"
    r2 = br.data["amplitude"][1:, 0] ** 2
    exact = 2 * np.pi / OMEGA0 * (2 * A2 * r2 - 4 * r2**2)
    logm = br.data["floquet_log"][1:]
    nontrivial = logm[np.arange(len(logm)), np.argmax(np.abs(logm), axis=1)]
    np.testing.assert_allclose(nontrivial, exact, atol=1e-8)
    decided = np.abs(exact) > 1e-6
    assert np.array_equal(br.stable[1:][decided], exact[decided] < 0)
    (fold,) = br.special("cycle_fold")
    assert fold.status == "converged"
    assert abs(fold.param - (MU0 - A2**2 / 4)) < 1e-8
    assert fold.verification["multiplier_minus_one"] < 1e-4
    assert not br.candidates


def test_collocation_and_integrated_branches_agree():
    """Check the same labels, fold and multipliers (1e-8) from both sources, and that an
    unknown source is refused."""
    a, b = _hopf_branch("collocation"), _hopf_branch("integrated")
    assert b.meta["stability"] == "integrated"
    assert np.array_equal(a.stable, b.stable)
    assert a.special("cycle_fold")[0].param == pytest.approx(
        b.special("cycle_fold")[0].param, abs=1e-12
    )
    np.testing.assert_allclose(a.data["floquet_log"][1:], b.data["floquet_log"][1:], atol=1e-8)
    with pytest.raises(BifidInputError, match="stability"):
        _hopf_branch("monodromy")


def _coupled_field(x, p):
    import jax.numpy as jnp

    r2 = x[0] ** 2 + x[1] ** 2
    g = p[0] + r2 - r2**2
    return jnp.stack(
        [g * x[0] - x[1], g * x[1] + x[0], -p[1] * (1.0 + x[0] ** 2) * x[2] + x[0] * x[1]]
    )


def _coupled_branch(c: float):
    system = System(
        name="coupled",
        states=("x0", "x1", "x2"),
        parameters=(Parameter("mu", 0.5, "nd", ""), Parameter("c", c, "nd", "")),
        field=_coupled_field,
        default_param="mu",
    )
    M = 64
    r2 = (1.0 + np.sqrt(3.0)) / 2.0
    t = 2 * np.pi * np.arange(M) / M
    orbit = np.stack([np.sqrt(r2) * np.cos(t), np.sqrt(r2) * np.sin(t), 0 * t], axis=1)
    opts = ContinuationOptions(ds=0.02, ds_max=0.1, p_min=0.4, p_max=1.0, max_steps=40)
    return periodic_orbits(
        system, "mu", orbit, 2 * np.pi, n_mesh=M, options=opts, stability="collocation"
    )


def test_three_state_multipliers_match_exact_values():
    """Check both non-trivial log-moduli of a contracting three-state branch (1e-8
    relative): the planar one and ``-c int (1 + x0²) dt`` down to e^-94."""
    c = 10.0
    br = _coupled_branch(c)
    assert len(br.params) > 3
    r2 = (1.0 + np.sqrt(1.0 + 4.0 * br.params)) / 2.0
    exact = np.sort(
        np.stack([(2 * r2 - 4 * r2**2) * 2 * np.pi, -c * (1 + r2 / 2) * 2 * np.pi], axis=1),
        axis=1,
    )
    logm = br.data["floquet_log"]
    triv = np.argmin(np.abs(logm), axis=1)
    nontrivial = np.sort(
        np.array([np.delete(row, k) for row, k in zip(logm, triv, strict=True)]), axis=1
    )
    np.testing.assert_allclose(nontrivial, exact, rtol=1e-8)
    assert np.all(br.stable)
