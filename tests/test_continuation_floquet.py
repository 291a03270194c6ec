"""Floquet multipliers for any contraction, against exact values.

The Hopf normal form (``hopf`` system) has circular orbits ``r*`` with the analytic
non-trivial multiplier ``exp(T r g'(r*))``, ``g = mu + a2 r^2 - q5 r^4``; a three-state
system in which that normal form drives a contracting third state has a second exact
multiplier, ``exp(-c int (1 + x0^2) dt)``, far below the smallest double.
"""

from __future__ import annotations

import numpy as np

from bifid.continuation import autonomous_rhs, floquet
from bifid.systems import Parameter, System, get_system

CASES = [
    (-0.05, 0.2, True),
    (-0.1, 1.0, True),
    (0.5, 1.0, False),
    (5.0, 1.0, False),
    (0.03, 0.0198, False),
    (5.0, 0.2, False),
    (100.0, 1.0, False),
    (5.0, 0.1, False),
]


def _hopf_orbit(mu, omega0, inner=False, M=32):
    """A circular orbit of the hopf system and its exact non-trivial log-multiplier."""
    disc = np.sqrt(1.0 + 4.0 * mu)
    r2 = (1.0 - disc) / 2.0 if inner else (1.0 + disc) / 2.0
    tau = 2 * np.pi * np.arange(M) / M
    V = np.sqrt(r2) * np.stack([np.cos(tau), np.sin(tau)], axis=1)
    T = 2 * np.pi / omega0
    return V, T, (2.0 * r2 - 4.0 * r2**2) * T


def test_hopf_orbit_multipliers_match_analytic_values():
    """Check the non-trivial multiplier (log-modulus to 1e-10 relative) from e^3 through
    1e-300 down to e^-2645, where the monodromy matrix itself underflows, the trivial one
    at 1, and the stability labels."""
    s = get_system("hopf")
    orbits = [_hopf_orbit(mu, om, inner) for mu, om, inner in CASES]
    V = np.array([o[0] for o in orbits])
    T = np.array([o[1] for o in orbits])
    expo = np.array([o[2] for o in orbits])
    assert expo.max() > np.log(1e1) and np.any(np.abs(expo / np.log(10) + 300) < 30)
    ps = np.array([np.asarray(s.param_vector(mu=mu, omega0=om)) for mu, om, _ in CASES])
    fl = floquet(autonomous_rhs(s.field), V, T, ps, autonomous=True)
    assert fl.ok.all()
    assert np.allclose(fl.log_max, expo, rtol=1e-10)
    trivial = fl.log_moduli[np.arange(len(CASES)), fl.trivial]
    assert np.all(np.abs(trivial) < 1e-9)
    assert np.array_equal(fl.stable(), (expo < 0).astype(float))


def _coupled_field(x, p):
    import jax.numpy as jnp

    # the hopf normal form in (x0, x1) drives a contracting third state
    r2 = x[0] ** 2 + x[1] ** 2
    g = p[0] + r2 - r2**2
    return jnp.stack(
        [g * x[0] - x[1], g * x[1] + x[0], -p[1] * (1.0 + x[0] ** 2) * x[2] + x[0] * x[1]]
    )


def _coupled_orbit(mu, c, M=64):
    """The orbit (third state from its linear periodic equation, solved spectrally with a
    differentiation matrix built here by FFT) and the exact log-multipliers: the planar
    one and ``-c int (1 + x0^2) dt`` (the system is triangular)."""
    r2 = (1.0 + np.sqrt(1.0 + 4.0 * mu)) / 2.0
    t = 2 * np.pi * np.arange(M) / M
    x0, x1 = np.sqrt(r2) * np.cos(t), np.sqrt(r2) * np.sin(t)
    k = np.fft.fftfreq(M, 1.0 / M)
    k[M // 2] = 0.0
    D = np.real(np.fft.ifft(1j * k[:, None] * np.fft.fft(np.eye(M), axis=0), axis=0))
    z = np.linalg.solve(D + np.diag(c * (1 + x0**2)), x0 * x1)
    V = np.stack([x0, x1, z], axis=1)
    return V, sorted([(2 * r2 - 4 * r2**2) * 2 * np.pi, -c * (1 + r2 / 2) * 2 * np.pi])


def test_three_state_multipliers_match_exact_values():
    """Check both non-trivial log-moduli of a coupled three-state orbit (1e-9 relative),
    from 0.6 down to e^-1382 (a multiplier no double holds)."""
    cases = [(0.5, 0.05), (2.0, 20.0), (0.5, 110.0)]
    system = System(
        name="coupled",
        states=("x0", "x1", "x2"),
        parameters=(Parameter("mu", 0.0, "nd", ""), Parameter("c", 1.0, "nd", "")),
        field=_coupled_field,
        default_param="mu",
    )
    orbits = [_coupled_orbit(mu, c) for mu, c in cases]
    fl = floquet(
        autonomous_rhs(system.field),
        np.array([o[0] for o in orbits]),
        np.full(len(cases), 2 * np.pi),
        np.array(cases, dtype=float),
        autonomous=True,
    )
    for i, (_, exact) in enumerate(orbits):
        _, logm = fl.nontrivial(i)
        assert np.allclose(np.sort(logm), exact, rtol=1e-9)
    assert np.all(fl.stable() == 1.0)


def _oscillator(x, t, p):
    import jax.numpy as jnp

    # a damped oscillator in badly matched units: velocity in units 1e4 times larger
    return jnp.stack([1e4 * x[1], -(p[0] ** 2) * 1e-4 * x[0] - p[1] * x[1]])


def test_monodromy_of_a_badly_scaled_linear_system_matches_expm():
    """Check monodromy matrices (integrated in balanced coordinates and transformed back)
    against ``expm(A T)`` of the linear field, entry by entry relative to each entry's
    scale, and the multipliers against ``exp(T eig(A))``."""
    import scipy.linalg

    from bifid.continuation import monodromy

    ps = np.array([[3.0, 0.1], [20.0, 2.0]])
    T = np.array([1.3, 0.7])
    V = np.zeros((2, 16, 2))
    Phi, ok = monodromy(_oscillator, V, T, ps)
    assert ok.all()
    for i, (w, c) in enumerate(ps):
        A = np.array([[0.0, 1e4], [-(w**2) * 1e-4, -c]])
        exact = scipy.linalg.expm(A * T[i])
        scale = np.outer([1e2, 1e-2], [1e-2, 1e2])  # the sizes of the entries of Phi
        assert np.allclose(Phi[i] / scale, exact / scale, rtol=0, atol=1e-9)
    fl = floquet(_oscillator, V, T, ps, autonomous=False)
    for i, (w, c) in enumerate(ps):
        A = np.array([[0.0, 1e4], [-(w**2) * 1e-4, -c]])
        expected = np.sort(np.real(T[i] * np.linalg.eigvals(A)))
        assert np.allclose(np.sort(fl.log_moduli[i]), expected, rtol=1e-9)
