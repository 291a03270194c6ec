"""Long accuracy runs of periodic orbits and forced responses (opt-in: ``--runslow``).

* van der Pol, mu from -3 to 5: one Hopf point; periods and amplitudes at mu = 1, 2, 3, 5
  against direct simulation, with the mesh used (up to 2048 points);
* the ``hopf`` branch from mu = -1 to 100: stability labels of orbits whose multipliers
  reach e^-2645;
* lightly damped (zeta = 0.001) hardening and softening Duffing FRCs over ranges with the
  3:1 and 5:1 superharmonic resonances: every resonance peak of a dense shooting sweep
  present on the FRC, every located FRC peak a true periodic response;
* both ``shaw_pierre`` backbones against the undamped nonlinear normal modes.
"""

from __future__ import annotations

import functools
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve

from bifid.continuation import backbone, continue_from_hopf, frc
from bifid.systems import get_system

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from test_continuation_vanderpol import interpolant_max, orbit_at, simulated_orbit

pytestmark = pytest.mark.slow


def test_vanderpol_orbits_to_mu_five_match_simulation():
    """Check the branch from the Hopf point to mu = 5 (range end) and the orbits at
    mu = 1, 2, 3, 5 against direct simulation: periods and amplitudes to 1e-8."""
    s = get_system("vanderpol")
    eq, (br,) = continue_from_hopf(s, "mu", -3.0, 5.0, n_mesh=64)
    (h,) = eq.special("hopf")
    assert abs(h.param) < 1e-10
    assert br.status == "range" and br.params[-1] == pytest.approx(5.0, abs=1e-12)
    assert np.all(br.verification["spectral_tail"] <= 1e-9)
    for mu in (1.0, 2.0, 3.0, 5.0):
        T, amp, mesh = orbit_at(br, s, mu)
        T_sim, amp_sim = simulated_orbit(mu)
        assert T == pytest.approx(T_sim, rel=1e-8), (mu, mesh)
        assert np.allclose(amp, amp_sim, rtol=1e-8), (mu, mesh)


def test_hopf_branch_to_mu_hundred_is_labelled_right():
    """Check every orbit of the hopf branch from mu = -1 to 100 against its analytic
    multiplier (labels, and log|mu| to 1e-9) down to e^-2645."""
    s = get_system("hopf")
    _, (br,) = continue_from_hopf(s, "mu", -1.0, 100.0, n_mesh=16)
    assert br.status == "range" and br.params[-1] == pytest.approx(100.0)
    (fold,) = br.special("cycle_fold")
    assert fold.param == pytest.approx(-0.25, abs=1e-8)
    r2 = br.data["amplitude"][:, 0] ** 2
    expo = (2 * r2 - 4 * r2**2) * 2 * np.pi
    assert expo.min() < -2600
    assert np.array_equal(br.stable[1:], expo[1:] < 0)
    logm = br.data["floquet_log"][1:]
    far = np.take_along_axis(logm, np.argmax(np.abs(logm), axis=1)[:, None], axis=1)[:, 0]
    assert np.allclose(far, expo[1:], rtol=1e-9, atol=1e-8)


def _duffing_rhs(zeta, gamma, F, Om):
    def rhs(t, z):
        q, v = z[0], z[1]
        J = np.array([[0.0, 1.0], [-1.0 - 3 * gamma * q**2, -2 * zeta]])
        dz = [v, -2 * zeta * v - q - gamma * q**3 + F * np.cos(Om * t)]
        return np.concatenate([dz, (J @ z[2:].reshape(2, 2)).ravel()])

    return rhs


def _shoot(zeta, gamma, F, Om, z0):
    """Periodic response by Newton on the period map (exact Jacobian from the variational
    equation); its amplitude max|q| from the dense output (4000 samples, refined)."""
    T = 2 * np.pi / Om
    rhs = _duffing_rhs(zeta, gamma, F, Om)
    z = np.asarray(z0, dtype=float)
    for _ in range(30):
        sol = solve_ivp(
            rhs,
            (0, T),
            np.concatenate([z, np.eye(2).ravel()]),
            rtol=1e-10,
            atol=1e-12,
            method="DOP853",
        )
        r = sol.y[:2, -1] - z
        if np.max(np.abs(r)) < 1e-10:
            break
        z = z - np.linalg.solve(sol.y[2:, -1].reshape(2, 2) - np.eye(2), r)
    else:
        return None, None
    sol = solve_ivp(
        lambda t, y: rhs(t, np.concatenate([y, np.zeros(4)]))[:2],
        (0, T),
        z,
        rtol=1e-12,
        atol=1e-14,
        method="DOP853",
        dense_output=True,
    )
    ts = np.linspace(0, T, 4001)
    q = np.abs(sol.sol(ts)[0])
    i = int(np.argmax(q))
    fine = np.linspace(ts[max(i - 1, 0)], ts[min(i + 1, 4000)], 201)
    return z, float(np.max(np.abs(sol.sol(fine)[0])))


@functools.lru_cache(maxsize=1)
def _period_map():
    """Jitted ``(z0, (zeta, gamma, F, Omega)) -> samples of [z, vec Phi]`` over one forcing
    period (diffrax Dopri8, rtol 1e-11; 1024 equispaced samples and the end point)."""
    import diffrax

    def rhs(t, z, a):
        zeta, gamma, F, Om = a
        q, v = z[0], z[1]
        J = jnp.array([[0.0, 1.0], [-1.0 - 3 * gamma * q**2, -2 * zeta]])
        dz = jnp.stack([v, -2 * zeta * v - q - gamma * q**3 + F * jnp.cos(Om * t)])
        return jnp.concatenate([dz, (J @ z[2:].reshape(2, 2)).ravel()])

    def run(z0, a):
        T = 2 * jnp.pi / a[3]
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(rhs),
            diffrax.Dopri8(),
            0.0,
            T,
            None,
            jnp.concatenate([z0, jnp.eye(2).ravel()]),
            args=a,
            stepsize_controller=diffrax.PIDController(rtol=1e-11, atol=1e-13),
            saveat=diffrax.SaveAt(ts=jnp.linspace(0.0, T, 1025)),
            max_steps=20_000,
            throw=False,
        )
        return sol.ys

    return jax.jit(run)


def _sweep(zeta, gamma, F, omegas):
    """Natural-parameter shooting sweep (Newton on the period map, exact Jacobian from the
    variational equation, each frequency from the last one's response); amplitudes max|q|
    of the trigonometric interpolant of 1024 samples of one period (NaN where Newton
    failed)."""
    period_map = _period_map()
    z = np.array([F / (1 - omegas[0] ** 2), 0.0])
    amps = []
    for Om in omegas:
        a = jnp.array([zeta, gamma, F, Om])
        zk, amp = z.copy(), np.nan
        for _ in range(30):
            ys = np.asarray(period_map(jnp.asarray(zk), a))
            if not np.all(np.isfinite(ys)):
                break
            r = ys[-1, :2] - zk
            if np.max(np.abs(r)) < 1e-11:
                z, amp = zk, float(interpolant_max(ys[:-1, :1])[0])
                break
            zk = zk - np.linalg.solve(ys[-1, 2:].reshape(2, 2) - np.eye(2), r)
        amps.append(amp)
    return np.array(amps)


@pytest.mark.parametrize("gamma", [1.0, -1.0])
def test_duffing_superharmonic_peaks_match_dense_shooting(gamma):
    """Check an FRC (zeta = 0.001, F = 0.1, Omega 0.18-0.45: 5:1 and 3:1 resonances)
    against dense shooting sweeps up and down (step 1e-3, a jitted diffrax period map):
    every local maximum of the
    sweeps lies below the FRC's amplitude within two grid steps, and every located FRC
    peak is a periodic response of that amplitude (shooting from it, 1e-8)."""
    zeta, F = 0.001, 0.1
    s = get_system("duffing")
    br = frc(s, F, (0.18, 0.45), p=s.param_vector(zeta=zeta, gamma=gamma))
    assert br.status == "range"
    omegas = np.arange(0.18, 0.45 + 1e-12, 1e-3)
    W = np.concatenate([br.params, [sp.param for sp in br.special("peak")]])
    A = np.concatenate(
        [br.data["observed_amplitude"], [sp.data["amplitude"] for sp in br.special("peak")]]
    )
    n_peaks = 0
    for grid, amps in (
        (omegas, _sweep(zeta, gamma, F, omegas)),
        (omegas[::-1], _sweep(zeta, gamma, F, omegas[::-1])),
    ):
        for i in range(1, len(grid) - 1):
            if amps[i] > amps[i - 1] and amps[i] >= amps[i + 1]:
                near = np.abs(W - grid[i]) <= 2e-3
                assert np.any(near) and A[near].max() >= amps[i] - 1e-8, grid[i]
                n_peaks += 1
    assert n_peaks >= 2
    peaks = br.special("peak")
    assert any(abs(sp.param - 1 / 3) < 0.02 for sp in peaks)  # 3:1
    assert any(abs(sp.param - 1 / 5) < 0.01 for sp in peaks)  # 5:1
    for sp in peaks:
        M = sp.data["n_mesh"]
        V = np.asarray(sp.solution[: M * 2]).reshape(M, 2)
        _, a = _shoot(zeta, gamma, F, sp.param, V[0])
        assert a == pytest.approx(sp.data["amplitude"], rel=1e-8)


def _nnm(A, mode, guess):
    kappa = 0.003

    def f(t, z):
        x1, v1, x2, v2 = z
        return [v1, -2 * x1 + x2 - kappa * x1**3, v2, x1 - 2 * x2]

    def half(u):
        sol = solve_ivp(f, (0, u[1]), [A, 0, u[0], 0], rtol=1e-12, atol=1e-14, method="DOP853")
        return [sol.y[1, -1], sol.y[3, -1]]

    u = fsolve(half, guess, xtol=1e-13)
    return np.pi / u[1], u


@pytest.mark.parametrize("mode", [0, 1])
def test_shaw_pierre_backbones_match_undamped_normal_modes(mode):
    """Check the backbone of each mode (amplitudes 0.01-2, exactly) against the undamped
    nonlinear normal mode by shooting (frequency to 5e-8 relative; damping 0.003 moves it
    by ~1e-8) and that it follows the requested mode."""
    br = backbone(get_system("shaw_pierre"), (0.01, 2.0), mode=mode)
    A, W = br.data["observed_amplitude"], br.data["omega"]
    assert br.status == "range"
    assert A[0] == pytest.approx(0.01, rel=1e-10) and A[-1] == pytest.approx(2.0, rel=1e-10)
    assert np.all(br.data["mode_share"] > 0.99)
    guess = [A[0] * (1 if mode == 0 else -1), np.pi / (1.0 if mode == 0 else np.sqrt(3))]
    for a, w in zip(A, W, strict=True):
        wn, guess = _nnm(a, mode, guess)
        assert w == pytest.approx(wn, rel=5e-8)
