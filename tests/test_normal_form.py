"""Cubic normal form at a Hopf point from JAX derivatives (thesis §4.2, eq. 4.10)."""

from __future__ import annotations

import numpy as np
import pytest

from bifid.errors import BifidInputError
from bifid.identify.mechanistic import (
    hopf_normal_form,
    hopf_point_regression,
    quadratic_cubic_structure,
)


@pytest.fixture(scope="module")
def flutter_nf():
    return hopf_normal_form("flutter", "U", guess=18.0)


def test_hopf_system_coefficients_are_analytic() -> None:
    # z' = (mu - mu0 + i w0) z + a2 z|z|^2 with z = u1 + i u2; <q,q> = 1 gives c1 = 2 a2
    nf = hopf_normal_form(
        "hopf", "mu", p={"mu0": 0.3, "a2": -0.7, "q5": 0.0, "omega0": 2.0}, guess=0.2
    )
    assert nf.param_value == pytest.approx(0.3, abs=1e-12)
    assert nf.omega == pytest.approx(2.0, rel=1e-12)
    assert nf.alpha1 == pytest.approx(1.0, rel=1e-12)
    assert nf.c1.real == pytest.approx(-1.4, rel=1e-10)
    assert nf.c1.imag == pytest.approx(0.0, abs=1e-10)
    assert nf.l1 == pytest.approx(-0.7, rel=1e-10)  # Re c1 / omega
    assert nf.criticality == "supercritical"
    # r^2 = (mu - mu0) / (-a2): exact for this system
    assert nf.amplitude(0.4, "u1") == pytest.approx(np.sqrt(0.1 / 0.7), rel=1e-10)
    assert np.isnan(nf.amplitude(0.2, "u1"))


def test_vanderpol_amplitude_leading_order() -> None:
    # x'' - (2 mu - x^2) x' + x = 0: averaging gives A = 2 sqrt(2 mu) at leading order
    nf = hopf_normal_form("vanderpol", "mu", guess=0.1)
    assert nf.param_value == pytest.approx(0.0, abs=1e-12)
    assert nf.omega == pytest.approx(1.0, rel=1e-12)
    for mu in (1e-4, 1e-2):
        assert nf.amplitude(mu, "z1") == pytest.approx(2 * np.sqrt(2 * mu), rel=1e-10)


def test_flutter_matches_thesis_eq_4_10(flutter_nf) -> None:
    nf = flutter_nf
    assert nf.param_value == pytest.approx(18.2748, abs=1e-3)
    assert nf.omega == pytest.approx(15.496, abs=1e-2)
    assert nf.criticality == "subcritical"
    a1_tau, _ = nf.tau_coefficients()
    # eq. 4.10: dR/dtau = 8.8e-3 mu R + (-4.5e-5 ka3 + 8.4e-7 ka2^2) R^3 (tau = omega t, |q| = 1)
    assert a1_tau == pytest.approx(8.8e-3, rel=0.02)
    s = quadratic_cubic_structure("flutter", nf, "ka2", "ka3")
    assert s["c3_tau"] == pytest.approx(-4.5e-5, rel=0.02)
    assert s["c22_tau"] == pytest.approx(8.4e-7, rel=0.02)
    # the structure is exact: every other quadratic term vanishes to round-off
    assert s["max_rel_residual"] < 1e-12
    assert s["max_rel_gradient_error"] < 1e-10
    for term in ("1", "k2", "k2*k3", "k3^2"):
        assert abs(s["fit_relative"][term]) < 1e-11
    assert s["alpha2"] == pytest.approx(s["c3"] * 5006.7 + s["c22"] * 751.6**2, rel=1e-12)


def test_flutter_l1_agrees_with_continuation(flutter_nf) -> None:
    from bifid.continuation import locate_hopf
    from bifid.systems import get_system

    sys_ = get_system("flutter")
    sp = locate_hopf(sys_, "U", np.zeros(6), 18.0, sys_.param_vector())
    assert flutter_nf.l1 == pytest.approx(sp.data["lyapunov"], rel=1e-9)
    assert flutter_nf.param_value == pytest.approx(sp.param, abs=1e-10)


def test_flutter_amplitude_error_shrinks_like_sqrt_mu(flutter_nf) -> None:
    """Normal-form pitch amplitude vs collocation: relative error ~ sqrt(U_H - U)."""
    from bifid.continuation import correct, fourier_differentiation_matrix, orbit_problem
    from bifid.signal import max_abs
    from bifid.systems import get_system

    sys_ = get_system("flutter")
    nf = flutter_nf
    M, n = 32, 6
    prob = orbit_problem(sys_.field, M, n)
    D = fourier_differentiation_matrix(M)
    eps = np.array([0.01, 0.02, 0.04, 0.08, 0.16])
    errs, ferrs = [], []
    for e in eps:
        U = nf.param_value - e
        V, T = nf.initial_orbit(U, M)
        y0 = np.concatenate([V.ravel(), [T, U]])
        row = np.zeros_like(y0)
        row[-1] = 1.0
        args = {"p": nf.p, "idx": np.asarray(sys_.index("U")), "dref": (D @ V).ravel()}
        y, ok, _, _ = correct(prob, y0, row, U, args, tol=1e-12, max_iter=30)
        assert ok
        Vs = y[: M * n].reshape(M, n)
        amp = max_abs(Vs[:, 2])
        assert amp > 0.3 * nf.amplitude(U, "alpha")  # a cycle, not the equilibrium
        errs.append(abs(nf.amplitude(U, "alpha") / amp - 1))
        ferrs.append(abs(nf.frequency(U) - 2 * np.pi / y[M * n]))
    slope = np.polyfit(np.log(eps), np.log(errs), 1)[0]
    assert 0.35 < slope < 0.65, (slope, errs)
    assert errs[0] < 0.02
    # the first-order frequency correction is second-order accurate
    fslope = np.polyfit(np.log(eps), np.log(ferrs), 1)[0]
    assert fslope > 1.5, (fslope, ferrs)


def test_hopf_point_regression_exact_and_errors() -> None:
    U = np.array([14.9, 15.7, 16.4, 17.2])
    amp = np.sqrt(2e-4 * (17.92 - U))
    f = 2.52 + 0.03 * (U - 17.92)
    r = hopf_point_regression(U, amp, f)
    assert r["param"] == pytest.approx(17.92, abs=1e-10)
    assert r["frequency"] == pytest.approx(2.52, abs=1e-10)
    assert r["r2"] == pytest.approx(1.0)
    with pytest.raises(BifidInputError):
        hopf_point_regression([1.0], [1.0])
    with pytest.raises(BifidInputError):
        hopf_point_regression([1.0, 1.0], [1.0, 2.0])


def test_structure_rejects_linear_parameters(flutter_nf) -> None:
    with pytest.raises(BifidInputError, match="linearisation"):
        quadratic_cubic_structure("flutter", flutter_nf, "ka", "ka3")
