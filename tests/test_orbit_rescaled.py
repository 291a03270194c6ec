"""Collocation in a rescaled time: a relaxation oscillation resolved on a mesh far smaller
than the uniform one needs, its period and multiplier against direct simulation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from bifid.continuation import (
    ContinuationOptions,
    continue_from_hopf,
    periodic_orbits,
    resample_orbit,
)
from bifid.errors import BifidInputError
from bifid.signal import spectral_tail
from bifid.systems import get_system

MU = 5.0  # z1'' - (2 mu - z1^2) z1' + z1 = 0: a relaxation oscillation (epsilon = 10)
N_SAMPLES = 4096


def simulated_cycle(mu: float) -> tuple[float, np.ndarray, float]:
    """Period, the cycle sampled at ``N_SAMPLES`` uniform times from an upward zero
    crossing of z1, and ``log`` of its non-trivial multiplier, by direct simulation (SciPy
    DOP853, rtol 1e-13). The multiplier of a planar orbit is ``det Phi(T) = exp(int_0^T
    div f dt)`` (Liouville), integrated along the orbit with it."""

    def f(t, z):
        return [z[1], 2 * mu * z[1] - z[0] ** 2 * z[1] - z[0], 2 * mu - z[0] ** 2]

    z0 = solve_ivp(f, (0, 150), [2.0, 0.0, 0.0], rtol=1e-12, atol=1e-12, method="DOP853").y
    sol = solve_ivp(
        f, (0, 60), z0[:, -1], rtol=1e-13, atol=1e-13, method="DOP853", dense_output=True
    )
    ts = np.linspace(0, 60, 60001)
    z1 = sol.sol(ts)[0]
    up = np.flatnonzero((z1[:-1] < 0) & (z1[1:] >= 0))
    t0, t1 = (brentq(lambda t: sol.sol(t)[0], ts[i], ts[i + 1], xtol=1e-14) for i in up[:2])
    period = t1 - t0
    samples = sol.sol(t0 + period * np.arange(N_SAMPLES) / N_SAMPLES)[:2].T
    log_mult = float(sol.sol(t1)[2] - sol.sol(t0)[2])
    return period, samples, log_mult


@pytest.fixture(scope="module")
def cycle():
    return simulated_cycle(MU)


def test_relaxation_cycle_on_a_rescaled_mesh(cycle):
    period, samples, log_mult = cycle
    M = 256
    # the uniform mesh needs far more points: 256 and 1024 uniform points leave tails of
    # ~3e-2 and ~4e-6 (2048 are needed for 1e-9)
    assert spectral_tail(resample_orbit(samples, M)) > 1e-3
    assert spectral_tail(resample_orbit(samples, 4 * M)) > 1e-7
    s = get_system("vanderpol")
    br = periodic_orbits(
        s,
        "mu",
        samples,
        period,
        p=s.param_vector(mu=MU),
        n_mesh=M,
        options=ContinuationOptions(ds=1e-3, ds_max=1e-2, max_steps=2, rescale=True),
    )
    assert br.params[0] == MU
    assert int(br.data["n_mesh"][0]) == M
    assert br.data["spectral_tail"][0] <= 1e-9
    assert abs(br.data["period"][0] - period) <= 1e-6 * period
    # the non-trivial multiplier (exp(-312): only its logarithm is representable)
    logs = br.data["floquet_log"][0]
    assert abs(np.min(logs) - log_mult) <= 1e-6 * abs(log_mult)
    assert abs(np.max(logs)) <= 1e-8  # the trivial multiplier
    # the orbits leave at uniform times, resolved: peak values as simulated
    Mo = int(br.meta["n_mesh"])
    U = br.solutions[0, : Mo * 2].reshape(Mo, 2)
    assert spectral_tail(U) <= 1e-9
    fine = resample_orbit(U, N_SAMPLES)
    assert np.allclose(fine.max(axis=0), samples.max(axis=0), rtol=1e-6, atol=1e-6)


def test_default_keeps_uniform_meshes_on_a_smooth_branch():
    # the van der Pol cycle up to mu = 1 is resolved on small uniform meshes
    s = get_system("vanderpol")
    assert ContinuationOptions().rescale == "auto"
    _, (br,) = continue_from_hopf(s, "mu", -0.5, 1.0, n_mesh=64)
    assert br.status == "range" and "rescaled" not in br.meta
    assert int(np.max(br.data["n_mesh"])) <= 512
    with pytest.raises(BifidInputError):
        ContinuationOptions(rescale="yes")


def test_default_branch_switches_to_rescaled_time_at_the_mesh_limit():
    """Uniform meshes of up to 256 points do not resolve the van der Pol cycle beyond
    mu ~ 2; by default the branch redistributes its points there and reaches mu = 3,
    its period as simulated."""
    s = get_system("vanderpol")
    _, (br,) = continue_from_hopf(s, "mu", -0.5, 3.0, n_mesh=64, max_mesh=256)
    assert br.status == "range" and br.params[-1] == pytest.approx(3.0, abs=1e-12)
    assert br.meta.get("rescaled") is True
    assert int(np.max(br.data["n_mesh"])) <= 256
    assert np.all(br.data["spectral_tail"] <= 1e-9)
    period, _, _ = simulated_cycle(3.0)
    assert abs(br.data["period"][-1] - period) <= 1e-8 * period
