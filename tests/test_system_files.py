"""Systems from files (.py, .toml) and installed packages' entry points: the same field from
either form, analytic bifurcation points of the loaded fields, and one clear line for every
malformed file."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bifid.errors import BifidInputError
from bifid.systems import get_system, list_systems, system_entries, systems_in_file

EXAMPLES = Path(__file__).resolve().parents[1] / "docs" / "examples" / "systems"
BRUSSELATOR_TOML = """\
name = "brusselator"
states = ["x", "y"]
control = "x"
[parameters]
a = { value = 1.0 }
b = { value = 1.5 }
[equations]
x = "a - (b + 1)*x + x**2*y"
y = "b*x - x**2*y"
"""


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


@pytest.mark.parametrize("name", ["brusselator", "softening"])
def test_py_and_toml_give_the_same_system_to_round_off(name):
    """Check field, full right-hand side, Jacobian and metadata of the two forms agree."""
    py, toml = get_system(EXAMPLES / f"{name}.py"), get_system(EXAMPLES / f"{name}.toml")
    assert py.source == str((EXAMPLES / f"{name}.py").resolve())
    assert toml.source == str((EXAMPLES / f"{name}.toml").resolve())
    for attr in (
        "name",
        "states",
        "parameters",
        "kind",
        "observed",
        "default_param",
        "envelope",
        "x0",
    ):
        assert getattr(py, attr) == getattr(toml, attr), attr
    rng = np.random.default_rng(1)
    xs = jnp.asarray(rng.normal(size=(64, py.n_states)))
    p = py.param_vector(
        dict(zip(py.parameter_names, rng.uniform(0.5, 2.0, len(py.parameters)), strict=True))
    )
    t = 0.37
    rhs_py = jax.jit(jax.vmap(lambda x: py.rhs(x, t, p)))(xs)
    rhs_toml = jax.jit(jax.vmap(lambda x: toml.rhs(x, t, p)))(xs)
    np.testing.assert_allclose(rhs_toml, rhs_py, rtol=1e-14, atol=1e-14)
    jac_py = jax.jit(jax.vmap(jax.jacfwd(py.field), (0, None)))(xs, p)
    jac_toml = jax.jit(jax.vmap(jax.jacfwd(toml.field), (0, None)))(xs, p)
    np.testing.assert_allclose(jac_toml, jac_py, rtol=1e-14, atol=1e-14)
    np.testing.assert_array_equal(py.input_direction(p), toml.input_direction(p))
    if py.kind == "forced":
        np.testing.assert_array_equal(py.forcing_direction(p), toml.forcing_direction(p))


def test_toml_field_matches_the_equations_written_out():
    """Check the Brusselator's right-hand side by hand, and its Hopf point b = 1 + a^2 away
    from the origin (equilibrium (a, b/a), eigenvalues +-i a) through the JAX Jacobian."""
    s = get_system(EXAMPLES / "brusselator.toml")
    a, b, x, y = 1.3, 2.1, 0.7, -0.4
    expected = [a - (b + 1) * x + x**2 * y, b * x - x**2 * y]
    np.testing.assert_allclose(
        s.field(jnp.array([x, y]), s.param_vector(a=a, b=b)), expected, rtol=1e-15
    )
    b_hopf = 1 + a**2
    p, eq = s.param_vector(a=a, b=b_hopf), jnp.array([a, b_hopf / a])
    np.testing.assert_allclose(s.field(eq, p), 0.0, atol=1e-15)
    eigenvalues = np.linalg.eigvals(np.asarray(jax.jacfwd(s.field)(eq, p)))
    np.testing.assert_allclose(sorted(eigenvalues.imag), [-a, a], rtol=1e-14)
    np.testing.assert_allclose(eigenvalues.real, 0.0, atol=1e-14)


def test_forced_toml_adds_forcing_parameters_and_direction(tmp_path):
    """Check that a forced .toml without F, Omega gets both, the force on the `forcing` state."""
    path = _write(
        tmp_path,
        "osc.toml",
        """\
        kind = "forced"
        states = ["q", "v"]
        forcing = "v"
        [parameters]
        k = 2.0
        [equations]
        q = "v"
        v = "-k*q - 0.1*v"
        """,
    )
    s = get_system(path)
    assert s.name == "osc" and s.parameter_names == ("k", "F", "Omega")
    assert s.default_param == "Omega" and s.input_direction is None
    p = s.param_vector(F=0.3, Omega=2.0)
    x = jnp.array([0.5, -0.2])
    expected = [-0.2, -2.0 * 0.5 + 0.02 + 0.3 * math.cos(2.0 * 0.8)]
    np.testing.assert_allclose(s.rhs(x, 0.8, p), expected, rtol=1e-15)


def test_toml_envelope_and_cbc_overrides(tmp_path):
    """Check [envelope] limits (one-sided ones too) and [cbc] arrays read as tuples."""
    path = _write(
        tmp_path,
        "b.toml",
        BRUSSELATOR_TOML
        + """\
        [envelope]
        x = { max = 8.0 }
        y = { min = -1.0, max = 9.0 }
        control = { max = 2.5 }
        [cbc]
        kp = 0.5
        amplitude_range = [0.1, 0.8]
        """,
    )
    s = get_system(path)
    assert s.envelope.states == {"x": (-math.inf, 8.0), "y": (-1.0, 9.0)}
    assert s.envelope.control_max == 2.5
    assert s.cbc == {"kp": 0.5, "amplitude_range": (0.1, 0.8)}


@pytest.mark.parametrize(
    ("replace", "by", "expect"),
    [
        (
            'y = "b*x - x**2*y"',
            'y = "b*x - x**2*z"',
            "[equations] y = 'b*x - x**2*z': unknown symbol 'z'",
        ),
        ('y = "b*x - x**2*y"', 'y = "b*x - bessel(x)"', "unknown function 'bessel'"),
        ('y = "b*x - x**2*y"', "y = \"__import__('os').getcwd()\"", "unknown function"),
        ('y = "b*x - x**2*y"', 'y = "x.__class__"', "not arithmetic"),
        ('y = "b*x - x**2*y"', 'y = "b*x - x**2*y*t"', "unknown symbol 't'"),
        ('y = "b*x - x**2*y"', 'y = "b*x -* x"', "[equations] y = 'b*x -* x': syntax error"),
        ('y = "b*x - x**2*y"', "y = \"b*x - 's'\"", "a str constant"),
        ('y = "b*x - x**2*y"', "y = 3", "expected the equation as a non-empty string"),
        ('y = "b*x - x**2*y"', 'z = "x"', "[equations] z: not a state"),
        ('y = "b*x - x**2*y"', "", "[equations]: no equation for the state 'y'"),
        ("b = { value = 1.5 }", 'b = { value = "high" }', "[parameters] b: expected a finite"),
        ("b = { value = 1.5 }", "b = { valu = 1.5 }", "[parameters] b: unknown key(s) ['valu']"),
        ("b = { value = 1.5 }", "exp = 1.5", "[parameters] exp: 'exp' is reserved"),
        ("b = { value = 1.5 }", "lambda = 1.5", "[parameters] lambda: parameter names must"),
        ('name = "brusselator"', 'name = "b"\nkind = "chaotic"', "kind: expected 'autonomous'"),
        ('name = "brusselator"', 'nme = "b"', "nme: unknown key"),
        ('name = "brusselator"', 'name = "b"\nkind = "forced"', "forcing: a forced system needs"),
        ('control = "x"', 'control = "w"', "control: 'w' is not a state"),
        ('y = "b*x - x**2*y"', 'y = "x"\n[envelope]\nq = { max = 1.0 }', "[envelope] q: not a"),
        ('states = ["x", "y"]', 'states = ["x", "x"]', "states: duplicated names"),
        ('control = "x"', 'control = "x"\nx0 = [1.0]', "x0: expected a list of 2 numbers"),
        ('control = "x"', 'control = "x"\nx0 = [1.0, "a"]', "x0: expected a finite number"),
        ('name = "brusselator"', 'name = "b" = 1', "not valid TOML"),
    ],
)
def test_malformed_toml_gives_one_line_naming_file_key_and_symbol(tmp_path, replace, by, expect):
    """Check each mistake gives one BifidInputError line naming the file and the key."""
    assert replace in BRUSSELATOR_TOML
    path = _write(tmp_path, "bad.toml", BRUSSELATOR_TOML.replace(replace, by))
    with pytest.raises(BifidInputError) as info:
        get_system(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path) + ": ")
    assert expect in message


def test_python_file_with_several_systems_and_errors(tmp_path):
    """Check `file.py:name`, the error for an ambiguous file, and one line with a line number
    for a failing module."""
    body = """\
        import jax.numpy as jnp
        from bifid.systems import Parameter, System, register

        def make(name, k):
            return System(name=name, states=("q",), parameters=(Parameter("k", k),),
                          field=lambda x, p: -p[0] * x)

        register("slow", make("slow", 0.5))
        register("fast", lambda: make("fast", 5.0))
        """
    path = _write(tmp_path, "two.py", body)
    assert sorted(systems_in_file(path)) == ["fast", "slow"]
    fast = get_system(f"{path}:fast")
    assert fast.param_vector()[0] == 5.0 and fast.source == str(path.resolve())
    with pytest.raises(BifidInputError, match=r"defines several systems.*two\.py:NAME"):
        get_system(path)
    with pytest.raises(BifidInputError, match="defines no system 'medium'"):
        get_system(f"{path}:medium")
    broken = _write(tmp_path, "broken.py", textwrap.dedent(body) + "\n1 / 0\n")
    with pytest.raises(BifidInputError, match=r"broken.py: line 11: ZeroDivisionError"):
        get_system(broken)
    empty = _write(tmp_path, "empty.py", "x = 1\n")
    with pytest.raises(BifidInputError, match="registers no system"):
        get_system(empty)
    with pytest.raises(BifidInputError, match="no such system file"):
        get_system(tmp_path / "missing.toml")
    with pytest.raises(BifidInputError, match=r"must end in \.py or \.toml"):
        get_system(_write(tmp_path, "model.txt", ""))
    assert "fast" not in list_systems()  # a file's systems stay out of the named registry


def test_entry_point_systems_listed_with_their_package(tmp_path, monkeypatch):
    """Check that an installed package's entry point is found by name, with its source, and
    that a broken one is one clear line."""
    (tmp_path / "bifidplug.py").write_text(
        textwrap.dedent("""\
        from bifid.systems import Parameter, System

        def decay():
            return System(name="plug_decay", states=("q",),
                          parameters=(Parameter("k", 2.0),), field=lambda x, p: -p[0] * x)

        def broken():
            raise RuntimeError("no licence")
        """)
    )
    dist = tmp_path / "bifidplug-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: bifidplug\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(
        "[bifid.systems]\nplug_decay = bifidplug:decay\nplug_broken = bifidplug:broken\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    sources = {e.name: e.source for e in system_entries()}
    assert sources["plug_decay"] == "bifidplug:plug_decay" and sources["hopf"] == "built-in"
    s = get_system("plug_decay")
    assert s.source == "bifidplug:plug_decay"
    assert float(s.field(jnp.array([3.0]), s.param_vector())[0]) == -6.0
    with pytest.raises(BifidInputError, match=r"bifidplug:plug_broken.*RuntimeError: no licence"):
        get_system("plug_broken")


def test_every_allowed_function_evaluates_like_sympy(tmp_path):
    """Check a field using every function, pi, ^ and division against SymPy's own numbers."""
    import sympy

    text = (
        "sqrt(x) + log(x) - exp(-x) + sin(x)*cos(pi*x) + tan(x) + asin(x) + acos(x) + "
        "atan(x) + atan2(x, k) + sinh(x) + cosh(x)^2 + tanh(x)/3 + abs(-x)*sign(x)"
    )
    path = _write(
        tmp_path,
        "f.toml",
        f"""\
        states = ["x"]
        [parameters]
        k = 2.5
        [equations]
        x = "{text}"
        """,
    )
    s = get_system(path)
    x, k = sympy.symbols("x k")
    reference = sympy.sympify(text.replace("^", "**").replace("abs", "Abs"))
    for value in (0.1, 0.45, 0.9):
        expected = float(reference.subs({x: value, k: 2.5}).evalf(30))
        got = float(s.field(jnp.array([value]), s.param_vector())[0])
        assert got == pytest.approx(expected, rel=1e-14)
