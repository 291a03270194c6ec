"""Van der Pol (thesis eq. 5.14): supercritical Hopf at mu = 0; orbits against simulation;
the mesh follows the relaxation oscillations, and an unresolved branch is never complete."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq, minimize_scalar

from bifid.continuation import (
    ContinuationOptions,
    continue_from_hopf,
    correct,
    equilibria,
    fourier_differentiation_matrix,
    orbit_problem,
)
from bifid.systems import get_system


def simulated_orbit(mu: float) -> tuple[float, np.ndarray]:
    """Period and max|z_k| of the attracting cycle by direct simulation (SciPy DOP853,
    rtol 1e-13): settle, then the period from two upward zero crossings of z1 (root
    finding on the dense output) and the maxima by bounded minimisation."""

    def f(t, z):
        return [z[1], 2 * mu * z[1] - z[0] ** 2 * z[1] - z[0]]

    settle = solve_ivp(f, (0, 40 + 30 * mu), [2.0, 0.0], rtol=1e-12, atol=1e-12, method="DOP853")
    z0 = settle.y[:, -1]
    span = 4 * (7 + 3 * mu)
    sol = solve_ivp(f, (0, span), z0, rtol=1e-13, atol=1e-14, method="DOP853", dense_output=True)
    ts = np.linspace(0, span, 200001)
    z1 = sol.sol(ts)[0]
    up = np.flatnonzero((z1[:-1] < 0) & (z1[1:] >= 0))
    crossings = [brentq(lambda t: sol.sol(t)[0], ts[i], ts[i + 1], xtol=1e-14) for i in up[:3]]
    period = crossings[2] - crossings[1]
    amp = []
    for k in range(2):
        zk = np.abs(sol.sol(ts)[k])
        i = int(np.argmax(zk[ts < crossings[1] + period]))
        res = minimize_scalar(
            lambda t, k=k: -abs(sol.sol(t)[k]),
            bounds=(ts[i - 2], ts[i + 2]),
            method="bounded",
            options={"xatol": 1e-12},
        )
        amp.append(-res.fun)
    return period, np.array(amp)


def orbit_at(br, s, mu: float):
    """The branch's orbit corrected at exactly ``mu`` (from the nearest branch point)."""
    M, n = br.meta["n_mesh"], s.n_states
    i = int(np.argmin(np.abs(br.params - mu)))
    y = np.concatenate([br.solutions[i], [br.params[i]]])
    V = y[: M * n].reshape(M, n)
    args = {
        "p": s.param_vector(mu=mu),
        "idx": np.asarray(0),
        "dref": (fourier_differentiation_matrix(M) @ V).ravel(),
    }
    e = np.zeros_like(y)
    e[-1] = 1.0
    y, ok, _, _ = correct(orbit_problem(s.field, M, n), y, e, mu, args, tol=1e-12, max_iter=20)
    assert ok
    return y[M * n], interpolant_max(y[: M * n].reshape(M, n)), int(br.data["n_mesh"][i])


def interpolant_max(V: np.ndarray) -> np.ndarray:
    """max |x_k(tau)| of the trigonometric interpolant of mesh values: a 16x finer grid by
    zero padding, then bounded minimisation of the series around the largest sample."""
    M = V.shape[0]
    c = np.fft.rfft(V, axis=0) / M
    k = np.arange(c.shape[0])
    w = np.where((k == 0) | (k == M // 2), 1.0, 2.0)
    fine = np.fft.irfft(np.fft.rfft(V, axis=0), n=16 * M, axis=0) * 16
    out = []
    for j in range(V.shape[1]):

        def value(tau, j=j):
            return -abs(float(np.sum(w * (c[:, j] * np.exp(1j * k * tau)).real)))

        i = int(np.argmax(np.abs(fine[:, j])))
        h = 2 * np.pi / (16 * M)
        res = minimize_scalar(
            value, bounds=((i - 1) * h, (i + 1) * h), method="bounded", options={"xatol": 1e-14}
        )
        out.append(-res.fun)
    return np.array(out)


def test_exactly_one_hopf_point_from_minus_three_to_five():
    """Check the equilibrium branch over mu in [-3, 5]: one Hopf point, at 0 (1e-10), with
    omega 1 and l1 < 0; the real-eigenvalue collision at mu = 1 is not a Hopf point."""
    s = get_system("vanderpol")
    eq = equilibria(
        s,
        "mu",
        start=-3.0,
        options=ContinuationOptions(ds=0.1, ds_max=0.2, p_min=-3.0, p_max=5.0, max_steps=500),
    )
    (h,) = eq.special("hopf")
    assert abs(h.param) < 1e-10 and h.data["omega"] == pytest.approx(1.0, abs=1e-10)
    assert h.data["lyapunov"] < 0 and h.data["criticality"] == "supercritical"


@pytest.fixture(scope="module")
def vdp():
    s = get_system("vanderpol")
    return s, *continue_from_hopf(s, "mu", -0.5, 1.5, n_mesh=16)


def test_orbit_at_one_matches_simulation_and_mesh_grows(vdp):
    """Check period and amplitudes at mu = 1 and 1.5 against direct simulation (1e-8
    relative), a mesh that grows with mu from 16 points, and resolved, stable orbits."""
    s, _, (br,) = vdp
    assert br.status == "range" and br.params[-1] == pytest.approx(1.5, abs=1e-12)
    meshes = br.data["n_mesh"]
    assert meshes[0] == 16 and meshes[-1] > 16 and np.all(np.diff(meshes[1:]) >= 0)
    assert np.all(br.verification["spectral_tail"] <= 1e-9)
    assert br.stable[1:].all()
    for mu in (1.0, 1.5):
        T, amp, _ = orbit_at(br, s, mu)
        T_sim, amp_sim = simulated_orbit(mu)
        assert T == pytest.approx(T_sim, rel=1e-8)
        assert np.allclose(amp, amp_sim, rtol=1e-8)


def test_planar_branch_has_no_secondary_points(vdp):
    """Check that the planar branch reports no period doubling, torus or candidate of
    either: its one non-trivial multiplier is real and positive (exp of the integrated
    divergence)."""
    _, _, (br,) = vdp
    assert not [sp for sp in br.special_points if sp.kind in ("period_doubling", "torus")]
    assert not [c for c in br.candidates if c.kind in ("period_doubling", "torus")]
    fl = br.data["floquet"][1:]
    nontrivial = np.take_along_axis(fl, np.argmax(np.abs(np.abs(fl) - 1), axis=1)[:, None], axis=1)[
        :, 0
    ]
    assert np.all(nontrivial.real > 0) and np.all(nontrivial.imag == 0)


def test_mesh_limit_ends_the_branch_unresolved():
    """Check that a mesh limit too small for the relaxation oscillations ends the branch
    as "unresolved" (incomplete, with the reason) and that no reported orbit is
    unresolved."""
    s = get_system("vanderpol")
    _, (br,) = continue_from_hopf(s, "mu", -0.5, 3.0, n_mesh=16, max_mesh=32)
    assert br.status == "unresolved" and not br.complete
    assert "collocation points" in br.message and "32" in br.message
    assert br.params[-1] < 3.0
    assert np.all(br.verification["spectral_tail"] <= 1e-9)
