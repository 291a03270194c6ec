"""Virtual rig: integration accuracy and error control, persistence, sampling, noise, saturation,
the safety gate, the generated loop against the JAX engine, errors."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bifid.cbc import EllipticTarget, FourierTarget, PDController, PolarTarget, VirtualRig
from bifid.errors import BifidInputError
from bifid.simulate import simulate
from bifid.systems import Envelope, Parameter, System, get_system

HOPF = {"mu": -0.1, "q5": 0.0}


@pytest.fixture(scope="module")
def hopf():
    return get_system("hopf")


def test_free_run_matches_diffrax(hopf):
    """Check that the rig's sampled RK4 equals bifid.simulate (Dopri8) without control."""
    rig = VirtualRig(hopf, HOPF, sample_rate=200.0, x0=[0.25, 0.0], record_states=True)
    m = rig.run(6.0)
    ref = simulate(hopf, np.array([0.25, 0.0]), m.time, hopf.param_vector(HOPF))
    assert m.outputs.shape == (1200, 2)
    np.testing.assert_allclose(m.outputs, ref, atol=1e-9)
    np.testing.assert_allclose(m.extra["states"], ref, atol=1e-9)


def test_state_persists_between_runs(hopf):
    """Check that two runs continue each other exactly (no reset), clock included."""
    a = VirtualRig(hopf, HOPF, sample_rate=200.0, x0=[0.2, 0.1])
    b = VirtualRig(hopf, HOPF, sample_rate=200.0, x0=[0.2, 0.1])
    m1, m2 = a.run(1.5), a.run(2.5)
    m = b.run(4.0)
    np.testing.assert_allclose(np.vstack([m1.outputs, m2.outputs]), m.outputs, atol=1e-14)
    np.testing.assert_allclose(np.concatenate([m1.time, m2.time]), m.time, atol=1e-12)
    assert a.time == pytest.approx(4.0)


def test_zero_order_hold_control(hopf):
    """Check the sampled controller against an independent ZOH integration (scipy).

    u_k = kp (x* - u1_k) + kd (0 - u2_k) is computed from the samples and held over each
    interval; integrating the same piecewise-constant input with solve_ivp must agree.
    """
    from scipy.integrate import solve_ivp

    fs, kp, kd, xstar = 50.0, 0.8, 0.3, 0.1
    # a constant target: elliptic with zero amplitude centred at (xstar, 0)
    rig = VirtualRig(hopf, HOPF, sample_rate=fs, x0=[0.3, 0.0], derivative="state")
    rig.set_controller(PDController(kp, kd, "u1", "u2"), EllipticTarget(0.0, 1.0, (xstar, 0.0)))
    m = rig.run(4.0)
    x = np.array([0.3, 0.0])
    for k in range(m.time.shape[0]):
        u = kp * (xstar - x[0]) + kd * (0.0 - x[1])
        assert m.control[k] == pytest.approx(u, abs=1e-7)

        def f(t, y, u=u):  # eq. 3.16 with mu = -0.1 (numpy, independent of bifid)
            g = -0.1 + y[0] ** 2 + y[1] ** 2
            return np.array([g * y[0] - y[1] + u, g * y[1] + y[0]])

        x = solve_ivp(f, (0, 1 / fs), x, rtol=1e-11, atol=1e-13).y[:, -1]


def test_noise_is_seeded_and_has_the_requested_level(hopf):
    """Check noise std per channel, reproducibility for a seed, difference across seeds."""
    kw = dict(sample_rate=200.0, x0=[0.2, 0.0], record_states=True)
    a = VirtualRig(hopf, HOPF, noise={"u1": 1e-3}, seed=3, **kw).run(20.0)
    b = VirtualRig(hopf, HOPF, noise={"u1": 1e-3}, seed=3, **kw).run(20.0)
    c = VirtualRig(hopf, HOPF, noise={"u1": 1e-3}, seed=4, **kw).run(20.0)
    err = a.outputs - a.extra["states"]
    assert np.std(err[:, 0]) == pytest.approx(1e-3, rel=0.05)
    assert np.max(np.abs(err[:, 1])) == 0.0
    np.testing.assert_array_equal(a.outputs, b.outputs)
    assert not np.allclose(a.outputs, c.outputs)


def test_seed_restarts_the_noise_stream(hopf):
    """Check rig.seed(s) makes the next run's noise that of a fresh rig seeded with s."""
    kw = dict(sample_rate=100.0, x0=[0.2, 0.0], record_states=True, noise=1e-3)
    rig = VirtualRig(hopf, HOPF, seed=1, **kw)
    rig.run(1.0)
    rig.seed(5)
    m = rig.run(2.0)
    fresh = VirtualRig(hopf, HOPF, seed=5, **kw).run(2.0)
    np.testing.assert_allclose(
        m.outputs - m.extra["states"], fresh.outputs - fresh.extra["states"], rtol=0, atol=1e-15
    )
    assert rig.describe()["seed"] == 5


def test_saturation_limits_the_control(hopf):
    """Check |u| <= saturation and that saturated samples are counted."""
    rig = VirtualRig(hopf, HOPF, sample_rate=100.0, x0=[0.3, 0.0], saturation=0.01)
    rig.set_controller(PDController(1.0, 0.0, "u1", "u2"), EllipticTarget(0.0, 1.0))
    m = rig.run(2.0)
    assert np.max(np.abs(m.control)) <= 0.01 + 1e-15
    assert m.saturated > 0


def test_derivative_estimate_from_samples(hopf):
    """Check the filtered difference tracks the true derivative with a small lag."""
    rig = VirtualRig(
        hopf,
        {"mu": 0.0, "q5": 0.0, "a2": 0.0},
        sample_rate=1000.0,
        x0=[0.5, 0.0],
        derivative_cutoff=50.0,
    )
    m = rig.run(8.0)
    tail = slice(2000, None)
    true = -0.5 * np.sin(m.time[tail])  # u1 = 0.5 cos t on the neutral centre
    est = m.signal("u1_dot")[tail]
    # first-order filter: gain ~1, phase lag ~ ω/ωc = 1/(2π·50) rad
    assert np.max(np.abs(est - true)) < 0.5 * (1.0 / (2 * math.pi * 50) + 2e-3)


def test_forcing_phase_and_generator(hopf):
    """Check force = γ cos(θ - ψ) with θ continuous across a change of frequency."""
    duff = get_system("duffing")
    rig = VirtualRig(duff, sample_rate=100.0)
    rig.set_forcing(0.02, 1.0, phase=0.3)
    m1 = rig.run(3.0)
    np.testing.assert_allclose(m1.force, 0.02 * np.cos(m1.phase - 0.3), atol=1e-15)
    rig.set_forcing(0.02, 2.0, phase=0.3)
    m2 = rig.run(1.0)
    assert m2.phase[0] == pytest.approx((m1.phase[-1] + 1.0 / 100.0) % (2 * math.pi), abs=1e-9)
    np.testing.assert_allclose(np.diff(m2.phase), 2.0 / 100.0, atol=1e-12)


def test_fourier_target_tracks_a_harmonic_reference():
    """Check the rig's target signal is x*(θ) of eq. 3.3 and the controller follows it."""
    duff = get_system("duffing")
    rig = VirtualRig(duff, sample_rate=100.0, derivative="state", envelope=Envelope())
    rig.set_forcing(0.0, 1.2)
    c = np.array([0.0, 0.1, 0.0, 0.0, 0.05])  # A0, A1, A2, B1, B2
    rig.set_controller(PDController(20.0, 6.0, "q", "q_dot"), FourierTarget(c))
    m = rig.run(30.0)
    th = m.phase
    np.testing.assert_allclose(m.target, 0.1 * np.cos(th) + 0.05 * np.sin(2 * th), atol=1e-12)
    tail = slice(-500, None)
    assert np.max(np.abs(m.outputs[tail, 0] - m.target[tail])) < 0.03


# -- error control and the safety gate ------------------------------------------------------
def _system(name, states, params, field, **kw):
    return System(
        name=name,
        states=states,
        parameters=tuple(Parameter(n, v) for n, v in params),
        field=field,
        default_param=params[0][0],
        **kw,
    )


def _oscillator_field(x, p):
    return jnp.stack([x[1], -(p[0] ** 2) * x[0]])


@pytest.mark.parametrize("engine", ["numba", "jax"])
def test_error_control_keeps_a_fast_oscillator_accurate(engine):
    """Check a 150 Hz oscillator sampled at 1 kHz (one RK4 step per sample is far off)
    against its exact solution q0 cos(ωt): the error estimate raises the steps per sample."""
    w = 2 * math.pi * 150.0
    osc = _system("fast_oscillator", ("q", "v"), [("w", w)], _oscillator_field)
    kw = dict(sample_rate=1000.0, x0=[0.01, 0.0], record_states=True, engine=engine)
    m = VirtualRig(osc, **kw).run(1.0)
    exact = 0.01 * np.cos(w * m.time)
    assert np.max(np.abs(m.outputs[:, 0] - exact)) < 1e-6
    assert 4 <= m.extra["rk4_steps_max"] <= 256
    fixed = VirtualRig(osc, rtol=1e3, max_substeps=1, **kw).run(1.0)  # plain RK4, 1 step
    assert np.max(np.abs(fixed.outputs[:, 0] - exact)) > 1e-3


def test_blow_up_trips_the_rig_and_the_state_stays_finite():
    """Check x' = x² from x(0) = 1 (infinite at t = 1): the gate trips just before t = 1,
    every returned sample and the rig's state are finite, the rig is usable again."""
    s = _system(
        "blow_up",
        ("x",),
        [("a", 1.0)],
        lambda x, p: p[0] * x**2,
        input_direction=lambda p: jnp.ones(1),
    )
    rig = VirtualRig(s, sample_rate=100.0, x0=[1.0], envelope=Envelope())
    rig.set_controller(PDController(0.0, 0.0, "x", "x_dot"), EllipticTarget(0.0, 1.0))
    m = rig.run(3.0)
    assert m.status == "tripped" and "safety gate tripped" in m.reason
    assert 0.9 < m.time[-1] < 1.0
    assert np.all(np.isfinite(m.outputs)) and np.all(np.isfinite(rig.state))
    # the samples before the trip follow the exact solution 1 / (1 - t)
    early = m.time < 0.9
    np.testing.assert_allclose(m.outputs[early, 0], 1.0 / (1.0 - m.time[early]), rtol=1e-6)
    assert rig.trips == 1 and rig.controller == (None, None)
    assert rig.time == pytest.approx(len(m) / 100.0)


@pytest.mark.parametrize("engine", ["numba", "jax"])
def test_envelope_trip_brings_the_rig_to_rest(hopf, engine):
    """Check the first sample whose true state leaves the envelope ends the run: the growing
    cycle of an unstable Hopf origin crosses |u1| = 0.5 at the sample found in a free run."""
    kw = dict(sample_rate=100.0, x0=[0.05, 0.0], engine=engine)
    free = VirtualRig(hopf, {"mu": 0.1}, envelope=Envelope(), record_states=True, **kw)
    xs = free.run(20.0).extra["states"]
    first_out = int(np.argmax(np.abs(xs[:, 0]) > 0.5))
    assert first_out > 0
    env = Envelope(states={"u1": (-0.5, 0.5)})
    rig = VirtualRig(hopf, {"mu": 0.1}, envelope=env, **kw)
    rig.set_forcing(0.0, 1.0)
    m = rig.run(20.0)
    assert m.status == "tripped" and "u1" in m.reason and "envelope" in m.reason
    assert len(m) == first_out
    np.testing.assert_allclose(rig.state, 0.0, atol=1e-12)  # at rest: the origin
    assert rig.forcing is None and rig.controller == (None, None)
    assert np.max(np.abs(rig.run(1.0).outputs)) < 1e-12


@pytest.mark.parametrize("engine", ["numba", "jax"])
def test_actuator_limit_trips(hopf, engine):
    """Check a controller output beyond the envelope's control_max trips at once
    (u = kp (A - 0) = 0.5 at rest, limit 0.3), below it nothing happens."""
    target = EllipticTarget(0.5, 1.0)
    for limit, status in ((0.3, "tripped"), (0.6, "ok")):
        rig = VirtualRig(
            hopf, HOPF, sample_rate=100.0, engine=engine, envelope=Envelope(control_max=limit)
        )
        rig.set_controller(PDController(1.0, 0.0, "u1", "u2"), target)
        m = rig.run(1.0)
        assert m.status == status
        if status == "tripped":
            assert len(m) == 0 and "actuator limit" in m.reason
    assert len(m) == 100


def _brusselator(x, p):
    a, b = p[0], p[1]
    return jnp.stack([a - (b + 1) * x[0] + x[0] ** 2 * x[1], b * x[0] - x[0] ** 2 * x[1]])


def test_rest_is_the_equilibrium_nearest_the_initial_state():
    """Check a trip leaves a system whose equilibrium is not the origin at that equilibrium
    ((a, b/a) for the Brusselator)."""
    s = _system("brusselator_rest", ("x", "y"), [("a", 1.0), ("b", 1.5)], _brusselator)
    rig = VirtualRig(
        s, sample_rate=100.0, x0=[1.2, 1.4], envelope=Envelope(states={"x": (0.0, 1.1)})
    )
    m = rig.run(1.0)
    assert m.status == "tripped" and len(m) == 0
    np.testing.assert_allclose(rig.state, [1.0, 1.5], atol=1e-10)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"noise": {"nope": 1.0}}, "not outputs"),
        ({"noise": -1.0}, ">= 0"),
        ({"outputs": ("u3",)}, "no state"),
        ({"derivative": "magic"}, "derivative"),
        ({"sample_rate": 0.0}, "sample_rate"),
        ({"x0": [1.0]}, "x0"),
        ({"substeps": 4, "max_substeps": 2}, "max_substeps"),
        ({"rtol": 0.0}, "rtol"),
        ({"engine": "fortran"}, "engine"),
        ({"envelope": {"u1": (0, 1)}}, "Envelope"),
    ],
)
def test_bad_rig_settings(hopf, kwargs, match):
    """Check invalid rig settings raise BifidInputError saying what is wrong."""
    with pytest.raises(BifidInputError, match=match):
        VirtualRig(hopf, HOPF, **kwargs)


def test_bad_controller_and_runs(hopf):
    """Check unknown signals, missing targets and bad durations are rejected."""
    rig = VirtualRig(hopf, HOPF)
    with pytest.raises(BifidInputError, match="cannot use"):
        rig.set_controller(PDController(1, 1, "u1", "h_dot"), EllipticTarget(0.1, 1.0))
    with pytest.raises(BifidInputError, match="needs a target"):
        rig.set_controller(PDController(1, 1, "u1", "u2"), None)
    with pytest.raises(BifidInputError, match="duration"):
        rig.run(-1.0)
    with pytest.raises(BifidInputError, match="frequency"):
        rig.set_forcing(0.1)


# -- the generated numba loop against the JAX engine ----------------------------------------
def _engine_pair(
    system, params, *, x0, noise, outputs=None, derivative="samples", substeps=1, sample_rate=5000.0
):
    rigs = [
        VirtualRig(
            system,
            params,
            x0=x0,
            noise=noise,
            seed=11,
            engine=eng,
            outputs=outputs,
            derivative=derivative,
            substeps=substeps,
            record_states=True,
            envelope=Envelope(),
            sample_rate=sample_rate,
        )
        for eng in ("numba", "jax")
    ]
    assert [r.engine for r in rigs] == ["numba", "jax"]
    return rigs


def _assert_same(m_a, m_b, scale):
    for field in ("outputs", "derivatives", "control", "force"):
        a, b = getattr(m_a, field), getattr(m_b, field)
        assert np.allclose(a, b, rtol=0, atol=1e-10 * scale), field
    assert np.allclose(m_a.extra["states"], m_b.extra["states"], rtol=0, atol=1e-10 * scale)
    assert np.array_equal(np.isnan(m_a.target), np.isnan(m_b.target))
    ok = ~np.isnan(m_a.target)
    assert np.allclose(m_a.target[ok], m_b.target[ok], rtol=0, atol=1e-10 * scale)


def test_engines_agree_flutter_polar_target_with_noise():
    rigs = _engine_pair(
        get_system("flutter"),
        {"U": 16.0},
        x0=[0.01, 0, 0.02, 0, 0, 0],
        noise={"h": 1e-4, "alpha": 3e-4},
        outputs=("h", "alpha"),
    )
    coef = np.zeros(11)
    coef[0], coef[2], coef[7] = 0.02, 1e-3, -5e-4
    target = PolarTarget(
        coefficients=coef, transform=((1.0, 0.2), (0.5, 3.4)), origin=(1e-3, -2e-3)
    )
    ms = []
    for rig in rigs:
        rig.set_controller(PDController(-150.0, -20.0, "h", "alpha"), target)
        first = rig.run(0.3)
        rig.set_parameter("U", 16.5)  # parameter change between runs, state kept
        ms.append((first, rig.run(0.7)))
    _assert_same(ms[0][0], ms[1][0], 0.05)
    _assert_same(ms[0][1], ms[1][1], 0.05)
    assert np.std(ms[0][1].control) > 0.1  # the controller really acted


@pytest.mark.parametrize("derivative", ["samples", "state"])
def test_engines_agree_forced_fourier_target(derivative):
    for name, params, x0, out in [
        ("duffing", {"F": 0.02}, [0.1, 0.0], "q"),
        ("shaw_pierre", {"F": 0.01}, [0.1, 0.0, 0.05, 0.0], "x1"),
    ]:
        rigs = _engine_pair(
            get_system(name),
            params,
            x0=x0,
            noise=1e-3,
            outputs=(out,),
            derivative=derivative,
            substeps=2,
        )
        target = FourierTarget(coefficients=[0.01, 0.3, 0.02, -0.1, 0.01])
        ms = []
        for rig in rigs:
            rig.set_forcing(0.02, 1.05, phase=0.3)
            rig.set_controller(PDController(1.0, 0.5, out, out + "_dot"), target)
            ms.append(rig.run(3.0))
        _assert_same(ms[0], ms[1], 1.0)
        assert np.std(ms[0].force) > 0.01


def test_engines_agree_hopf_vanderpol_elliptic_target():
    for name, params, x0, sig in [
        ("hopf", {"mu": -0.1}, [0.3, 0.0], ("u1", "u2")),
        ("vanderpol", {"mu": 0.2}, [0.5, 0.0], ("z1", "z1_dot")),
    ]:
        rigs = _engine_pair(get_system(name), params, x0=x0, noise=2e-3)
        target = EllipticTarget(
            amplitude=0.4, omega=1.0 if name == "hopf" else -1.0, offset=(0.01, 0.0)
        )
        ms = []
        for rig in rigs:
            rig.run(0.5)  # free run, then controlled
            rig.set_controller(PDController(2.0, 1.0, *sig), target)
            ms.append(rig.run(2.0))
        _assert_same(ms[0], ms[1], 1.0)


def _many_operations(x, p):
    """A field using what users write: where, tanh, clip, a static loop, a state-dependent
    cond, a parameter matrix inverted by LAPACK, matrix products, a reduction."""
    stiff = jnp.linalg.inv(jnp.array([[p[0], 0.2], [0.1, p[1]]]))
    spring = stiff @ x[:2]
    soft = jnp.where(x[0] > 0, jnp.tanh(x[0]), 0.5 * x[0])
    poly = jax.lax.fori_loop(0, 3, lambda i, acc: acc * x[1] + 0.1, 1.0)
    damp = jax.lax.cond(x[1] > 0, lambda v: 0.2 * v, lambda v: 0.3 * v, x[1])
    return jnp.stack(
        [x[1], -spring[0] - soft - damp - 0.01 * poly + jnp.clip(x[0], -0.1, 0.1) * jnp.sum(x**2)]
    )


def test_generated_loop_handles_user_fields_and_agrees_with_jax():
    """Check a user field with many kinds of operations runs on the generated numba loop
    and gives the JAX engine's samples."""
    s = _system(
        "many_operations",
        ("q", "v"),
        [("k1", 2.0), ("k2", 3.0)],
        _many_operations,
        input_direction=lambda p: jnp.array([0.0, 1.0]),
    )
    rigs = _engine_pair(s, {"k1": 2.5}, x0=[0.3, -0.2], noise=1e-3, sample_rate=500.0)
    ms = []
    for rig in rigs:
        rig.set_controller(PDController(0.5, 0.2, "q", "v"), EllipticTarget(0.2, 1.3))
        ms.append(rig.run(4.0))
        rig.set_parameter("k2", 2.0)
        ms.append(rig.run(1.0))
    _assert_same(ms[0], ms[2], 1.0)
    _assert_same(ms[1], ms[3], 1.0)


def test_untranslatable_fields_fall_back_to_the_jax_engine():
    """Check a field whose loop length depends on the state runs on the JAX engine (with a
    warning saying why), and engine='numba' refuses it."""

    def field(x, p):
        halve = jax.lax.while_loop(lambda v: jnp.abs(v) > p[0], lambda v: 0.5 * v, x[0])
        return jnp.stack([x[1], -x[0] - 0.1 * x[1] + 0.0 * halve])

    s = _system("state_while", ("q", "v"), [("tol", 0.1)], field)
    with pytest.warns(UserWarning, match="JAX engine"):
        rig = VirtualRig(s, x0=[0.2, 0.0], sample_rate=100.0)
    assert rig.engine == "jax"
    m = rig.run(1.0)
    assert m.status == "ok" and np.all(np.isfinite(m.outputs))
    with pytest.raises(BifidInputError, match="numba"):
        VirtualRig(s, engine="numba")


def test_user_system_equals_the_builtin_it_copies():
    """Check a user-registered copy of a built-in system runs the same generated loop."""
    h = get_system("hopf")
    user = System(
        name="my_hopf_copy",
        states=h.states,
        parameters=h.parameters,
        field=lambda x, p: h.field(x, p),
        input_direction=h.input_direction,
        default_param="mu",
    )
    rig_u = VirtualRig(user, {"mu": -0.1}, x0=[0.3, 0.0])
    rig_h = VirtualRig(h, {"mu": -0.1}, x0=[0.3, 0.0])
    assert rig_u.engine == rig_h.engine == "numba"
    np.testing.assert_array_equal(rig_u.run(1.0).outputs, rig_h.run(1.0).outputs)


def test_generated_loop_reaches_its_speed_target():
    """The flutter rig with the PP-CBC controller in the loop runs hundreds of times real
    time (BENCHMARKS.md measures it properly); here a loose floor of 60x, so that a
    regression to the JAX engine's speed fails even on a loaded 2-core machine."""
    import time

    rig = VirtualRig(
        get_system("flutter"),
        {"U": 16.0},
        x0=[0.01, 0, 0.02, 0, 0, 0],
        noise={"h": 1e-4, "alpha": 3e-4},
        envelope=Envelope(),
    )
    coef = np.zeros(21)
    coef[0] = 0.02
    rig.set_controller(
        PDController(-150.0, -20.0, "h", "alpha"), PolarTarget(coefficients=coef, scale=(1.0, 3.4))
    )
    rig.run(0.1)
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        rig.run(10.0)
        times.append(time.perf_counter() - t0)
    assert 10.0 / min(times) > 60.0


@pytest.mark.parametrize("engine", ["numba", "jax"])
def test_controller_output_filter(engine):
    """The applied control is the first-order low-pass of the PD law evaluated on the
    recorded measurements, u_k = u_{k-1} + a (law_k - u_{k-1}), a = 1 - exp(-2π f_c/f_s);
    on white measurement noise it keeps the variance fraction a / (2 - a)."""
    s = get_system("hopf")
    fs, fc = 200.0, 5.0
    rig = VirtualRig(
        s, {"mu": -0.1, "q5": 0.0}, sample_rate=fs, x0=[0.3, 0.0], noise=0.01, seed=4, engine=engine
    )
    target = EllipticTarget(0.3, 1.0)
    ctrl = PDController(1.0, 0.5, "u1", "u2", filter_hz=fc)
    rig.set_controller(ctrl, target)
    m = rig.run(60.0)
    y1, y2 = m.outputs[:, 0], m.outputs[:, 1]
    r1, r2 = (np.asarray(v) for v in EllipticTarget.reference(target.vector(), y1, y2, 0, 0))
    law = 1.0 * (r1 - y1) + 0.5 * (r2 - y2)
    a = 1.0 - math.exp(-2 * math.pi * fc / fs)
    assert ctrl.filter_coefficient(fs) == pytest.approx(a)
    u = m.control
    assert np.allclose(u[1:], u[:-1] + a * (law[1:] - u[:-1]), rtol=0, atol=1e-12)
    # noise part of the law (its high-pass residual) is attenuated as predicted
    noise_law = law - np.convolve(law, np.ones(41) / 41, mode="same")
    noise_u = u - np.convolve(u, np.ones(41) / 41, mode="same")
    ratio = np.std(noise_u[100:-100]) / np.std(noise_law[100:-100])
    assert ratio == pytest.approx(math.sqrt(a / (2 - a)), rel=0.2)
    with pytest.raises(BifidInputError, match="filter_hz"):
        PDController(1.0, 0.0, "u1", "u2", filter_hz=-1.0)
