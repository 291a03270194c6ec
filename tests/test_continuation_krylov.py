"""Large collocation systems: preconditioned GMRES in the corrector, SVD-free fold
criteria, and the homoclinic end recognised from the parameter's convergence."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

import bifid.continuation._correctors as correctors
from bifid.continuation import NewtonCorrector, fourier_differentiation_matrix, orbit_problem
from bifid.continuation._folds import _large_fold_measures
from bifid.continuation._krylov import gmres
from bifid.continuation._orbit_branch import (
    homoclinic_convergence,
    homoclinic_settled,
    homoclinic_signature,
)
from bifid.systems import get_system


def test_gmres_with_a_stale_factorisation_solves_to_the_tolerance():
    """Check GMRES preconditioned by the LU of a nearby matrix against a dense solve."""
    rng = np.random.default_rng(0)
    n = 200
    A0 = rng.normal(size=(n, n)) + 3 * np.sqrt(n) * np.eye(n)
    A = A0 + 0.05 * rng.normal(size=(n, n))
    lu = scipy.linalg.lu_factor(A0)
    b = rng.normal(size=n)
    out = gmres(lambda v: A @ v, lambda v: scipy.linalg.lu_solve(lu, v), b, rtol=1e-12, max_iter=50)
    x = np.linalg.solve(A, b)
    assert out.converged and out.iterations < 15
    assert np.max(np.abs(out.x - x)) <= 1e-10 * np.max(np.abs(x))
    # without a preconditioner the Krylov space must grow far more
    slow = gmres(lambda v: A @ v, lambda v: v, b, rtol=1e-12, max_iter=10)
    assert not slow.converged


def _vdp_orbit(M: int, mu: float):
    s = get_system("vanderpol")
    tau = 2 * np.pi * np.arange(M) / M
    V = np.stack([2 * np.cos(tau), -2 * np.sin(tau)], axis=1)
    D = fourier_differentiation_matrix(M)
    args = {"p": s.param_vector(mu=mu), "idx": jnp.asarray(0), "dref": jnp.asarray((D @ V).ravel())}
    return orbit_problem(s.field, M, 2), np.concatenate([V.ravel(), [2 * np.pi, mu]]), args


def test_krylov_corrector_gives_newtons_points_with_fewer_factorisations(monkeypatch):
    """Check the corrector with GMRES against the dense one on van der Pol orbits: the
    same corrected orbits (1e-10) and tangents along three steps of the parameter, with
    the factorisation of the first reused by the later ones."""
    monkeypatch.setattr(correctors, "KRYLOV_MIN_UNKNOWNS", 0)
    problem, y, args = _vdp_orbit(32, 0.5)
    e = np.zeros_like(y)
    e[-1] = 1.0
    dense = NewtonCorrector(problem)
    kry = NewtonCorrector(problem, krylov=True, max_iter=20)
    w = np.ones_like(y)
    for mu in (0.5, 0.55, 0.6):
        a = dense.correct(y, e, mu, args)
        b = kry.correct(y, e, mu, args)
        assert a.converged and b.converged
        assert np.max(np.abs(a.y - b.y)) <= 1e-10 * (1 + np.max(np.abs(a.y)))
        ta, _ = dense.tangent(a.y, e, w, args)
        tb, _ = kry.tangent(b.y, e, w, args)
        assert np.max(np.abs(ta - tb)) <= 1e-8
        y = a.y
    assert kry.stats["krylov_solves"] > 0
    assert kry.stats["factorisations"] < dense.stats["factorisations"]


def test_fold_measures_without_svd_match_the_svd():
    """Check the LU / inverse-iteration fold criteria against dense SVDs, at a fold (a
    null vector of G_u) and at a branch point (G_y rank deficient)."""
    rng = np.random.default_rng(3)
    n = 150
    U, _ = np.linalg.qr(rng.normal(size=(n, n)))
    W, _ = np.linalg.qr(rng.normal(size=(n, n)))
    s = np.logspace(0, -4, n)
    s[-1] = 1e-9
    Gu = U @ np.diag(s) @ W
    for g_lam in (rng.normal(size=n), U[:, 5]):
        Gy = np.insert(Gu, 7, g_lam, axis=1)
        _, s_full, vt = np.linalg.svd(Gy)
        s_u = np.linalg.svd(Gu, compute_uv=False)
        t, null, rank = _large_fold_measures(Gy, 7)
        assert null == pytest.approx(s_u[-1] / max(1.0, s_u[0]), rel=0.05)
        assert rank == pytest.approx(s_full[-1] / s_full[0], rel=0.05)
        assert abs(abs(t @ vt[-1]) - 1.0) <= 1e-8


def test_parameter_converging_geometrically_in_the_period_is_homoclinic():
    """Check the homoclinic test on lambda_h - C exp(-T / tau) (a saddle's homoclinic
    approach) against a fold and a branch that only steepens (power law)."""
    T = np.linspace(2.0, 72.0, 300)
    lam = 0.7 - 0.3 * np.exp(-T / 4.0)
    assert homoclinic_convergence(lam, T)
    assert homoclinic_signature(lam, T)
    # still far from settled: not yet
    assert not homoclinic_convergence(lam[:120], T[:120])
    # a fold: the parameter turns
    fold = 0.7 - 0.01 * (T - 50.0) ** 2
    assert not homoclinic_convergence(fold, T)
    # steepening without geometric convergence
    assert not homoclinic_convergence(0.7 - 1.0 / T**2, T)
    # a branch stuck at rounding after converging: recognised at the end of the run
    stuck_T = np.concatenate([T[:250], np.full(50, T[249]) + np.linspace(0, 1e-6, 50)])
    stuck = np.concatenate([lam[:250], np.full(50, lam[249])])
    assert not homoclinic_convergence(stuck, stuck_T)
    assert homoclinic_convergence(stuck, stuck_T, remaining=1e-5)


def test_parameter_spiralling_into_a_saddle_focus_homoclinic_is_recognised():
    """Check the end of a branch towards a saddle-focus homoclinic orbit (the parameter
    oscillates about its limit with a decaying amplitude: Shilnikov's spiral of cycle
    folds, as in AUTO-07p's ``tor``) against a fold of a short-period branch."""
    T = np.linspace(7.0, 150.0, 600)
    lam = -0.7975 + 0.02 * np.exp(-T / 9.0) * np.cos(2.0 * np.pi * T / 20.0)
    assert not homoclinic_convergence(lam, T)  # not monotone
    assert homoclinic_settled(lam, T, remaining=1e-5)
    assert homoclinic_signature(lam, T, remaining=1e-5)
    # early on (the oscillation still 1e-4 of the range) it is not settled
    assert not homoclinic_signature(lam[:150], T[:150], remaining=1e-5)
    # a period that grew only a few times: no homoclinic approach, however flat
    short = np.linspace(2.0, 9.0, 100)
    assert not homoclinic_settled(np.full(100, 0.15) + 1e-9 * short, short, remaining=1e-5)
