"""The system registry and the reference systems' metadata and equations."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

from bifid.errors import BifidInputError
from bifid.systems import Parameter, System, get_system, list_systems, register


def test_reference_systems_registered_with_thesis_values():
    """Check names, states and Table A.1 / §6.3.1 nominal values."""
    assert {"hopf", "vanderpol", "flutter", "duffing", "shaw_pierre"} <= set(list_systems())
    f = get_system("flutter")
    d = f.param_dict(f.param_vector())
    assert d["ka2"] == 751.6 and d["ka3"] == 5006.7 and d["rho"] == 1.204 and d["xa"] == 0.234
    sp = get_system("shaw_pierre")
    assert sp.param_dict(sp.param_vector())["c2"] == pytest.approx(0.003 / math.sqrt(3))
    assert sp.observed == "x1" and sp.kind == "forced"


def test_duffing_and_shaw_pierre_equations():
    """Check the right-hand sides against the equations written out by hand."""
    d = get_system("duffing")
    x, t = jnp.array([0.3, -0.2]), 0.7
    p = d.param_vector(F=0.05, Omega=1.2)
    expected = [-0.2, -2 * 0.01 * -0.2 - 0.3 - 0.5 * 0.3**3 + 0.05 * np.cos(1.2 * 0.7)]
    assert np.allclose(d.rhs(x, t, p), expected, atol=1e-15)
    s = get_system("shaw_pierre")
    x = jnp.array([0.1, 0.2, -0.3, 0.4])
    p = s.param_vector(F=0.01, Omega=1.0)
    c1, c2, k, kap = 0.003, 0.003 / math.sqrt(3), 1.0, 0.003
    f = 0.01 * np.cos(0.5)
    a1 = -2 * k * 0.1 + k * -0.3 - (c1 + c2) * 0.2 + c2 * 0.4 - kap * 0.1**3 + f
    a2 = k * 0.1 - 2 * k * -0.3 + c2 * 0.2 - (c1 + c2) * 0.4 + f
    assert np.allclose(s.rhs(x, 0.5, p), [0.2, a1, 0.4, a2], atol=1e-15)


def test_param_vector_rejects_unknown_and_non_finite_values():
    """Check clear errors for unknown names, NaN/inf and non-numbers."""
    s = get_system("hopf")
    with pytest.raises(BifidInputError, match="no parameter 'nope'"):
        s.param_vector(nope=1.0)
    with pytest.raises(BifidInputError, match="finite"):
        s.param_vector(mu=float("nan"))
    with pytest.raises(BifidInputError, match="finite"):
        s.param_vector({"mu": float("inf")})
    with pytest.raises(BifidInputError, match="number"):
        s.param_vector(mu="abc")
    with pytest.raises(BifidInputError, match="Unknown system"):
        get_system("not-a-system")


def test_user_system_registration():
    """Check that a user-registered system is found by name, with the field it was given
    (Hopf normal form: eigenvalues lam +- i at the origin, by the JAX Jacobian)."""
    import jax

    def field(x, p):  # Hopf normal form with l1 < 0 written by a user
        r2 = x[0] ** 2 + x[1] ** 2
        return jnp.stack([p[0] * x[0] - x[1] - x[0] * r2, x[0] + p[0] * x[1] - x[1] * r2])

    register(
        "user_hopf",
        System(
            name="user_hopf",
            states=("a", "b"),
            parameters=(Parameter("lam", 0.0, "nd", "parameter"),),
            field=field,
            default_param="lam",
        ),
        overwrite=True,
    )
    with pytest.raises(BifidInputError, match="already registered"):
        register("user_hopf", get_system("hopf"))
    s = get_system("user_hopf")
    assert "user_hopf" in list_systems() and s.default_param == "lam"
    jac = np.asarray(jax.jacfwd(s.field)(jnp.zeros(2), s.param_vector(lam=-0.2)))
    np.testing.assert_allclose(
        sorted(np.linalg.eigvals(jac), key=np.imag), [-0.2 - 1j, -0.2 + 1j], atol=1e-15
    )


def test_forced_system_needs_forcing_parameters():
    """Check that a forced System without F/Omega is refused when built."""
    with pytest.raises(BifidInputError, match="needs parameters 'F' and 'Omega'"):
        System(
            name="bad",
            states=("q",),
            parameters=(Parameter("k", 1.0),),
            field=lambda x, p: -x,
            kind="forced",
            forcing_direction=lambda p: jnp.ones(1),
        )


def test_each_built_in_has_one_home_with_envelope_and_cbc_settings():
    """Check every built-in carries its envelope and CBC settings, naming its own states."""
    from bifid.systems import BUILT_IN, Envelope

    assert set(BUILT_IN) == {"hopf", "vanderpol", "flutter", "duffing", "shaw_pierre"}
    for name in BUILT_IN:
        s = get_system(name)
        assert s is get_system(name) and s.source == "built-in"
        assert isinstance(s.envelope, Envelope) and s.envelope.control_max > 0
        assert set(s.envelope.states) <= set(s.states)
        signals = [s.cbc.get(k) for k in ("x1", "x2", "signal")] + list(s.cbc["outputs"])
        for signal in filter(None, signals):
            assert signal.removesuffix("_dot") in s.states, (name, signal)
        assert s.cbc["sample_rate"] > 0 and s.cbc["kp"] is not None


def test_hopf_envelope_holds_the_stable_cycles_it_documents():
    """Check the largest stable cycle for mu <= 1, r^2 = (a2 + sqrt(a2^2 + 4 mu))/2, lies
    inside the hopf envelope (and is a zero of the radial equation of eq. 5.3)."""
    s = get_system("hopf")
    mu, a2 = 1.0, 1.0
    r = math.sqrt((a2 + math.sqrt(a2**2 + 4 * mu)) / 2)
    x = jnp.array([r, 0.0])
    dx = s.field(x, s.param_vector(mu=mu))
    assert float(dx[0]) == pytest.approx(0.0, abs=1e-12)  # on the cycle: no radial motion
    lo, hi = s.envelope.states["u1"]
    assert lo < -r and r < hi


def test_registered_system_source_is_the_registering_file():
    """Check that a system registered from code records that file as its source."""
    register(
        "user_decay",
        System(
            name="user_decay",
            states=("q",),
            parameters=(Parameter("k", 1.0),),
            field=lambda x, p: -x,
        ),
        overwrite=True,
    )
    assert get_system("user_decay").source == __file__
