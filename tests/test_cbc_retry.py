"""The retry of a failed PP-CBC scan on a system with a model: a controller designed on
the model's cycles (:func:`bifid.cbc.retry_controller`), and a campaign whose default
controller cannot hold a period-doubled LCO that measures it all the same.

Variant ka2 ×1, ka3 ×0.5 of the flutter model: its large LCO loses stability by period
doubling at 15.08 m/s; at 16.05 m/s it is unstable (a multiplier near -1.9), and the
default heave-pitch controller of ``flutter`` loses lock on the way to it.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bifid.cbc import Measurement, VirtualRig, orbit_polar_target, ppcbc_campaign, retry_controller
from bifid.continuation import ContinuationOptions, continue_from_hopf
from bifid.continuation.truth import centred_amplitudes, correct_orbit
from bifid.systems import get_system

pytestmark = pytest.mark.slow  # the model's cycles and the controlled Floquet batches

OVER = {"ka2": 751.6, "ka3": 0.5 * 5006.7}
U = 16.05
WINDOW = (13.12, 18.0)


def _large_orbit(s, p):
    """The large LCO at ``U`` (continuation from the Hopf point, Newton at ``U``)."""
    opts = ContinuationOptions(ds=1e-3, ds_max=0.2, ds_min=1e-9, p_min=8.0, p_max=24.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, (br,) = continue_from_hopf(s, "U", 8.0, 24.0, p=p, n_mesh=48, orbit_options=opts)
    M, n = int(br.meta["n_mesh"]), s.n_states
    amp = 0.5 * np.ptp(br.solutions[:, 0 : M * n : n], axis=1)
    j = int(np.argmin(np.abs(br.params - U) + 10.0 * (amp < 0.02)))
    return correct_orbit(
        s, "U", U, br.solutions[j, : M * n].reshape(M, n), br.data["period"][j], p=p
    )


def _largest_multiplier(s, pv, orbit, period, x1, x2, kp, kd) -> float:
    """The largest non-trivial Floquet multiplier of ``ẋ = f(x) + e u(x)``, ``u = kp (x1*
    - x1) + kd (x2* - x2)`` with the polar target of the orbit (eq. 3.22, written out
    here), from the monodromy matrix integrated by scipy."""
    target = orbit_polar_target(orbit, s, x1, x2, 10, p=pv)
    T = jnp.asarray(target.matrix)
    o = jnp.asarray(target.origin)
    c = jnp.asarray(target.coefficients)
    q = (c.shape[0] - 1) // 2
    k = jnp.arange(1, q + 1)
    p = jnp.asarray(pv)
    e = jnp.asarray(s.input_direction(p))

    def signal(x, fx, name):
        if name.endswith("_dot"):
            return fx[s.state_index(name[:-4])]
        return x[s.state_index(name)]

    def field(x):
        fx = s.field(x, p)
        xs = jnp.stack([signal(x, fx, x1), signal(x, fx, x2)])
        xi = jnp.linalg.solve(T, xs - o)
        phi = jnp.arctan2(xi[1], xi[0])
        r = c[0] + jnp.cos(k * phi) @ c[1 : q + 1] + jnp.sin(k * phi) @ c[q + 1 :]
        ref = o + T @ (r * jnp.stack([jnp.cos(phi), jnp.sin(phi)]))
        return fx + e * (kp * (ref[0] - xs[0]) + kd * (ref[1] - xs[1]))

    f, jac = jax.jit(field), jax.jit(jax.jacfwd(field))
    n = s.n_states

    def var(_t, y):
        x, phi = y[:n], y[n:].reshape(n, n)
        return np.concatenate([np.asarray(f(x)), (np.asarray(jac(x)) @ phi).ravel()])

    y0 = np.concatenate([orbit[0], np.eye(n).ravel()])
    sol = solve_ivp(var, (0.0, period), y0, method="DOP853", rtol=1e-10, atol=1e-12)
    mu = np.linalg.eigvals(sol.y[n:, -1].reshape(n, n))
    trivial = int(np.argmin(np.abs(mu - 1.0)))
    assert abs(mu[trivial] - 1.0) < 1e-3  # the orbit solves the controlled system
    return float(np.max(np.abs(np.delete(mu, trivial))))


def test_designed_controller_holds_the_period_doubled_lco():
    s = get_system("flutter")
    p = s.param_vector(OVER)
    d = retry_controller(s, p, "U", U, WINDOW, "h", "alpha", ("h", "alpha"))
    assert d is not None and d["multiplier"] < 1.0
    orbit, period = _large_orbit(s, p)
    pv = np.asarray(p.at[s.index("U")].set(U))
    free = _largest_multiplier(s, pv, orbit, period, "h", "alpha", 0.0, 0.0)
    held = _largest_multiplier(s, pv, orbit, period, d["x1"], d["x2"], d["kp"], d["kd"])
    assert free > 1.5  # period doubled without control
    assert held < 1.0
    # and the design's own multipliers agree with this independent computation where the
    # design holds all the cycles at U (its orbits at the branch's points around U)
    assert held < d["multiplier"] + 0.3


def test_campaign_measures_the_period_doubled_lco():
    """The default controller loses lock before the large LCO; the retries measure it,
    within 1 % of the model's orbit, and the campaign is complete."""
    s = get_system("flutter")
    p = s.param_vector(OVER)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = ppcbc_campaign("flutter", values=[U], overrides=OVER, seed=1)
    assert r.complete and not r.failures
    orbit, _ = _large_orbit(s, p)
    amp = centred_amplitudes(orbit)  # max |x - x̄|, as measured
    truth = {n: float(amp[s.state_index(n)]) for n in ("h", "alpha")}
    large = max(r.points, key=lambda pt: pt.amplitude["h"])
    for name, a in truth.items():
        assert math.isclose(large.amplitude[name], a, rel_tol=0.01)
    # each record says which controller measured it; the large LCO's is not the default
    ctrl = [json.loads(str(c)) for c in r.dataset["extra_controller"].values]
    assert len(ctrl) == 2 and ctrl[0] != ctrl[1]


class _StrokeLimitedRig(VirtualRig):
    """A virtual ``hopf`` rig with a stroke limit its description does not give (as a
    rig whose gate the model knows nothing of): ``|u1| > 0.7`` brings it to rest."""

    def run(self, duration: float) -> Measurement:
        m = super().run(duration)
        if np.max(np.abs(m.outputs[:, 0])) > 0.7:
            self._trip()
            return replace(m, status="tripped", reason="stroke limit |u1| <= 0.7 reached")
        return m


def test_one_failure_per_lco_of_the_model_with_the_last_reason():
    """Check an LCO that the scan, each retry and the hold from the model's orbit all fail
    to measure is one failure, with the reasons of the last scan and of the hold, not one
    per attempt (``hopf``, q5 = 1, μ = -0.1: r = 0.331 measured; r = 0.945 beyond the
    rig's stroke of 0.7)."""
    mu = -0.1
    d = math.sqrt(1 + 4 * mu)
    r_u, r_s = math.sqrt((1 - d) / 2), math.sqrt((1 + d) / 2)
    rig = _StrokeLimitedRig(get_system("hopf"), {"mu": mu, "q5": 1.0}, sample_rate=100.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = ppcbc_campaign(
            "hopf",
            param="mu",
            values=[mu],
            overrides={"q5": 1.0},
            amplitudes=np.linspace(0.15, 1.05, 7),
            rig=rig,
            options=dict(
                x1="u1",
                x2="u2",
                kp=1.0,
                kd=0.0,
                n_harmonics=3,
                stability=False,
                settle_periods=5.0,
                measure_periods=2.0,
            ),
        )
    assert [p.amplitude["u1"] for p in r.points] == [pytest.approx(r_u, rel=5e-3)]
    assert rig.trips >= 3  # the scan, its retries, the hold
    assert len(r.failures) == 1
    f = r.failures[0].to_json()
    assert f["model"] == pytest.approx(r_s, rel=0.02)
    assert "after a retry" in f["reason"] and "held from the model's orbit" in f["reason"]
