"""Systems stated in a TOML file: the equations as text, parsed with SymPy into a JAX field.

The format (``docs/systems.md``)::

    name = "brusselator"
    kind = "autonomous"            # or "forced": parameters F and Omega are added, the force
    states = ["x", "y"]            # F*cos(Omega*t) enters the equation of `forcing`
    observe = "x"                  # the measured state
    control = "x"                  # the state whose equation the controller's input enters
    # forcing = "x"                # forced systems only
    # default_param = "b"          # the usual bifurcation parameter
    # x0 = [1.0, 1.5]              # a guess of the equilibrium at the nominal parameters
    [parameters]
    a = { value = 1.0, unit = "1", description = "feed rate" }
    b = { value = 1.5 }
    [equations]                    # d(state)/dt
    x = "a - (b + 1)*x + x**2*y"
    y = "b*x - x**2*y"
    [envelope]                     # optional: the rig's safety limits
    x = { min = -10.0, max = 10.0 }
    control = { max = 5.0 }
    [cbc]                          # optional: CBC settings that override the derived ones
    kp = 1.0

The field is :math:`\\dot x_i = f_i(x, p)` with :math:`f_i` the SymPy expression of state
``i``'s equation; Jacobians come from JAX (``jacfwd``) like every system's. Nothing in the file
is executed (:mod:`bifid.systems._expr`). Every mistake is one line naming the file, the key
and, for an equation, the text and the unknown symbol.
"""

from __future__ import annotations

import keyword
import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import jax.numpy as jnp
import sympy

from bifid.errors import BifidInputError
from bifid.systems._base import Envelope, Parameter, System, state_direction
from bifid.systems._expr import RESERVED, evaluate, parse_equation

__all__ = ["system_from_toml"]

_KEYS = (
    "name",
    "kind",
    "description",
    "states",
    "observe",
    "control",
    "forcing",
    "default_param",
    "x0",
    "parameters",
    "equations",
    "envelope",
    "cbc",
)
_FORCING_PARAMETERS = (
    Parameter("F", 0.0, "nd", "forcing amplitude"),
    Parameter("Omega", 1.0, "rad/s", "forcing frequency"),
)


class _Reader:
    """Typed access to the file's keys, every error naming the file and the key."""

    def __init__(self, label: str, data: Mapping[str, Any]) -> None:
        self.label = label
        self.data = data

    def fail(self, key: str, message: str) -> BifidInputError:
        return BifidInputError(f"{self.label}: {key}: {message}")

    def string(self, key: str, default: str | None = None) -> str | None:
        value = self.data.get(key, default)
        if value is not None and not isinstance(value, str):
            raise self.fail(key, f"expected a string, got {value!r}.")
        return value

    def table(self, key: str, required: bool = False) -> Mapping[str, Any]:
        value = self.data.get(key)
        if value is None:
            if required:
                raise self.fail(key, "missing (a table, [" + key + "]).")
            return {}
        if not isinstance(value, dict):
            raise self.fail(key, f"expected a table [{key}], got {value!r}.")
        return value

    def name_of(self, key: str, value: object, kind: str) -> str:
        if not isinstance(value, str) or not value.isidentifier() or keyword.iskeyword(value):
            raise self.fail(
                key,
                f"{kind} names must be identifiers (letters, digits, _; not a Python "
                f"keyword), got {value!r}.",
            )
        if value in RESERVED:
            raise self.fail(
                key,
                f"{value!r} is reserved (the names {', '.join(sorted(RESERVED))}"
                " are functions, constants or time).",
            )
        return value

    def member(self, key: str, names: tuple[str, ...], kind: str, default: str | None) -> str:
        value = self.string(key, default)
        if value is not None and value not in names:
            raise self.fail(key, f"{value!r} is not a {kind} (known: {', '.join(names)}).")
        return value or ""


def _number(reader: _Reader, key: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise reader.fail(key, f"expected a finite number, got {value!r}.")
    return float(value)


def _parameters(reader: _Reader, forced: bool, states: tuple[str, ...]) -> tuple[Parameter, ...]:
    params = []
    for name, spec in reader.table("parameters").items():
        key = f"[parameters] {name}"
        reader.name_of(key, name, "parameter")
        if name in states:
            raise reader.fail(key, f"{name!r} is also a state.")
        if not isinstance(spec, dict):
            spec = {"value": spec}
        unknown = set(spec) - {"value", "unit", "description"}
        if unknown:
            raise reader.fail(
                key, f"unknown key(s) {sorted(unknown)} (known: value, unit, description)."
            )
        if "value" not in spec:
            raise reader.fail(key, "missing 'value'.")
        unit, text = spec.get("unit", "nd"), spec.get("description", "")
        if not isinstance(unit, str) or not isinstance(text, str):
            raise reader.fail(key, "'unit' and 'description' must be strings.")
        params.append(Parameter(name, _number(reader, key, spec["value"]), unit, text))
    names = {p.name for p in params}
    if forced:
        params += [p for p in _FORCING_PARAMETERS if p.name not in names]
    return tuple(params)


def _envelope(reader: _Reader, states: tuple[str, ...]) -> Envelope | None:
    spec = reader.table("envelope")
    if not spec:
        return None
    limits: dict[str, tuple[float, float]] = {}
    control_max = None
    for name, bounds in spec.items():
        key = f"[envelope] {name}"
        allowed = {"max"} if name == "control" else {"min", "max"}
        if name != "control" and name not in states:
            raise reader.fail(key, f"not a state (known: {', '.join(states)}, control).")
        if not isinstance(bounds, dict) or not bounds or set(bounds) - allowed:
            raise reader.fail(
                key, f"expected a table with {' and/or '.join(sorted(allowed))}, got {bounds!r}."
            )
        if name == "control":
            control_max = _number(reader, key, bounds["max"])
        else:
            lo = _number(reader, key, bounds["min"]) if "min" in bounds else -math.inf
            hi = _number(reader, key, bounds["max"]) if "max" in bounds else math.inf
            limits[name] = (lo, hi)
    try:
        return Envelope(states=limits, control_max=control_max)
    except BifidInputError as exc:
        raise reader.fail("[envelope]", str(exc)) from None


def _tuples(value: Any) -> Any:
    """TOML arrays as tuples (CBC settings are hashable), tables as dicts."""
    if isinstance(value, list):
        return tuple(_tuples(v) for v in value)
    if isinstance(value, dict):
        return {k: _tuples(v) for k, v in value.items()}
    return value


def _field(exprs: tuple[sympy.Expr, ...], state_symbols, param_symbols):
    def field(x, p):
        values = {s: x[i] for i, s in enumerate(state_symbols)}
        values.update({s: p[j] for j, s in enumerate(param_symbols)})
        return jnp.stack([jnp.asarray(evaluate(e, values), dtype=x.dtype) for e in exprs])

    return field


def system_from_toml(path: Path, label: str | None = None) -> System:
    """The :class:`~bifid.systems.System` a TOML file states (module docstring).

    Raises
    ------
    BifidInputError
        One line naming the file, the key, and (for an equation) the text and the unknown
        symbol.
    """
    label = label or str(path)
    try:
        data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise BifidInputError(f"{label}: cannot be read ({exc}).") from None
    except tomllib.TOMLDecodeError as exc:
        raise BifidInputError(f"{label}: not valid TOML: {exc}.") from None
    reader = _Reader(label, data)
    unknown = [k for k in data if k not in _KEYS]
    if unknown:
        raise reader.fail(unknown[0], f"unknown key (known: {', '.join(_KEYS)}).")
    name = reader.string("name", Path(path).stem)
    kind = reader.string("kind", "autonomous")
    if kind not in ("autonomous", "forced"):
        raise reader.fail("kind", f"expected 'autonomous' or 'forced', got {kind!r}.")
    raw_states = data.get("states")
    if not isinstance(raw_states, list) or not raw_states:
        raise reader.fail("states", f"expected a list of state names, got {raw_states!r}.")
    states = tuple(reader.name_of("states", s, "state") for s in raw_states)
    if len(set(states)) != len(states):
        raise reader.fail("states", f"duplicated names in {list(states)}.")
    forced = kind == "forced"
    parameters = _parameters(reader, forced, states)
    pnames = tuple(p.name for p in parameters)
    state_symbols = tuple(sympy.Symbol(s, real=True) for s in states)
    param_symbols = tuple(sympy.Symbol(p, real=True) for p in pnames)
    symbols = dict(zip(states + pnames, state_symbols + param_symbols, strict=True))
    equations = reader.table("equations", required=True)
    extra = [k for k in equations if k not in states]
    if extra:
        raise reader.fail(f"[equations] {extra[0]}", f"not a state (states: {', '.join(states)}).")
    missing = [s for s in states if s not in equations]
    if missing:
        raise reader.fail("[equations]", f"no equation for the state {missing[0]!r}.")
    exprs = tuple(
        parse_equation(equations[s], symbols, f"{label}: [equations] {s}") for s in states
    )
    observe = reader.member("observe", states, "state", states[0])
    control = reader.member("control", states, "state", None)
    forcing = reader.member("forcing", states, "state", None)
    if forced and not forcing:
        raise reader.fail(
            "forcing",
            "a forced system needs the state whose equation the force "
            'F*cos(Omega*t) enters, e.g. forcing = "v".',
        )
    if forcing and not forced:
        raise reader.fail("forcing", 'only for kind = "forced".')
    default_param = reader.member(
        "default_param", pnames, "parameter", "Omega" if forced else (pnames[0] if pnames else None)
    )
    x0 = data.get("x0")
    if x0 is not None and (not isinstance(x0, list) or len(x0) != len(states)):
        raise reader.fail(
            "x0",
            f"expected a list of {len(states)} numbers (one per state: "
            f"{', '.join(states)}), got {x0!r}.",
        )
    description = reader.string("description") or "; ".join(
        f"{s}' = {equations[s]}" for s in states
    )
    try:
        return System(
            name=name,
            states=states,
            parameters=parameters,
            field=_field(exprs, state_symbols, param_symbols),
            kind=kind,
            forcing_direction=state_direction(states, forcing) if forcing else None,
            input_direction=state_direction(states, control) if control else None,
            observed=observe,
            default_param=default_param,
            description=description,
            envelope=_envelope(reader, states),
            cbc=_tuples(dict(reader.table("cbc"))),
            source=str(path),
            x0=None if x0 is None else tuple(_number(reader, "x0", v) for v in x0),
        )
    except BifidInputError as exc:
        raise BifidInputError(f"{label}: {exc}") from None
