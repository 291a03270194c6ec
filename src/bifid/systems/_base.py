"""System metadata and parameter handling.

A :class:`System` is a pure JAX vector field plus the metadata that the CLI, the
virtual rigs and the identification code need (state names, parameters with units
and nominal values, where a force or a controller enters).

The full right-hand side of a system is

.. math::

    \\dot x = f(x, p) + b(p)\\,\\bigl(F\\cos(\\Omega t) + u(t)\\bigr)

where ``f`` is the autonomous field (:attr:`System.field`), ``b`` the forcing
direction (:attr:`System.forcing_direction`, forced systems only) and ``u`` an
optional control input along :attr:`System.input_direction`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError

Array = jnp.ndarray
FieldFn = Callable[[Array, Array], Array]
DirectionFn = Callable[[Array], Array]


@dataclass(frozen=True)
class Parameter:
    """A named system parameter.

    Parameters
    ----------
    name : str
        Identifier used on the command line (``--set name=value``).
    default : float
        Nominal value.
    unit : str
        Physical unit ("nd" for non-dimensional).
    description : str
        One line saying what the parameter is.
    """

    name: str
    default: float
    unit: str = "nd"
    description: str = ""

    def __post_init__(self) -> None:
        if not math.isfinite(self.default):
            raise BifidInputError(
                f"Parameter {self.name!r} must have a finite default, got {self.default!r}."
            )


@dataclass(frozen=True)
class Envelope:
    """The safety limits of a rig of a system, as a real rig's safety gate holds them.

    Crossing any limit disarms the controller and brings the rig to rest; the point being
    measured is then a failure with the reason recorded.

    Parameters
    ----------
    states : dict of (float, float)
        ``{state: (min, max)}`` limits on states (``-inf`` / ``inf`` for none).
    control_max : float, optional
        Largest magnitude of the controller output (actuator limit).
    """

    states: Mapping[str, tuple[float, float]] = field(default_factory=dict)
    control_max: float | None = None

    def __post_init__(self) -> None:
        for name, (lo, hi) in self.states.items():
            if not (lo < hi) or math.isnan(lo) or math.isnan(hi):
                raise BifidInputError(
                    f"envelope of {name!r} must satisfy min < max, got ({lo!r}, {hi!r})."
                )
        if self.control_max is not None and not self.control_max > 0:
            raise BifidInputError(
                f"envelope control_max must be positive, got {self.control_max!r}."
            )

    def to_json(self) -> dict:
        return {
            "states": {k: list(v) for k, v in self.states.items()},
            "control_max": self.control_max,
        }


@dataclass(frozen=True)
class System:
    """A vector field with its metadata.

    Attributes
    ----------
    name : str
        Registry name.
    states : tuple of str
        State names, in the order of the state vector.
    parameters : tuple of Parameter
        Parameters, in the order of the parameter vector ``p``.
    field : callable ``(x, p) -> dx``
        Autonomous part of the vector field, for one state ``x`` of shape ``(n,)``
        and a parameter vector ``p`` of shape ``(n_params,)``. Pure JAX.
    kind : {"autonomous", "forced"}
        Forced systems are driven by ``F cos(Omega t)`` along ``forcing_direction``
        and must have parameters named ``F`` and ``Omega``.
    forcing_direction : callable ``p -> b`` or None
        State-space direction of the harmonic force (forced systems).
    input_direction : callable ``p -> e`` or None
        State-space direction along which a control input/actuator acts.
    observed : str
        The state whose amplitude a forced response reports, and on which a CBC
        controller acts.
    default_param : str
        The usual bifurcation parameter.
    description : str
        The equations (shown by ``bifid systems``).
    envelope : Envelope, optional
        Safety limits of a rig of this system (CBC disarms beyond them).
    cbc : dict
        CBC settings that override those derived from the linearisation (gains, sample
        rate, measured signals, amplitude grid, ...).
    source : str
        Where the system came from: ``built-in``, a file path, or a package's entry point.
    x0 : tuple of float, optional
        A guess of an equilibrium at the nominal parameters, in state order, for systems whose
        equilibrium is not near the origin (where continuation and CBC start their Newton
        solves otherwise).
    """

    name: str
    states: tuple[str, ...]
    parameters: tuple[Parameter, ...]
    field: FieldFn
    kind: Literal["autonomous", "forced"] = "autonomous"
    forcing_direction: DirectionFn | None = None
    input_direction: DirectionFn | None = None
    observed: str = ""
    default_param: str = ""
    description: str = ""
    envelope: Envelope | None = field(default=None, compare=False)
    cbc: Mapping[str, Any] = field(default_factory=dict, compare=False)
    source: str = field(default="built-in", compare=False)
    x0: tuple[float, ...] | None = field(default=None, compare=False)
    _index: Mapping[str, int] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        names = [p.name for p in self.parameters]
        if len(set(names)) != len(names):
            raise BifidInputError(f"System {self.name!r} has duplicated parameter names: {names}.")
        if len(set(self.states)) != len(self.states):
            raise BifidInputError(f"System {self.name!r} has duplicated state names.")
        if self.kind not in ("autonomous", "forced"):
            raise BifidInputError(f"kind must be 'autonomous' or 'forced', got {self.kind!r}.")
        if self.kind == "forced":
            missing = {"F", "Omega"} - set(names)
            if missing or self.forcing_direction is None:
                raise BifidInputError(
                    f"Forced system {self.name!r} needs parameters 'F' and 'Omega' and a "
                    f"forcing_direction; missing {sorted(missing) or 'forcing_direction'}."
                )
        object.__setattr__(self, "_index", {n: i for i, n in enumerate(names)})
        if not self.observed:
            object.__setattr__(self, "observed", self.states[0])
        if self.observed not in self.states:
            raise BifidInputError(
                f"observed state {self.observed!r} is not a state of {self.name!r} "
                f"(states: {', '.join(self.states)})."
            )
        if self.x0 is not None:
            try:
                guess = tuple(float(v) for v in self.x0)
            except (TypeError, ValueError):
                guess = ()
            if len(guess) != len(self.states) or not all(map(math.isfinite, guess)):
                raise BifidInputError(
                    f"x0 of {self.name!r} must be {len(self.states)} finite numbers "
                    f"({', '.join(self.states)}), got {self.x0!r}."
                )
            object.__setattr__(self, "x0", guess)

    # -- parameters ---------------------------------------------------------------
    @property
    def n_states(self) -> int:
        return len(self.states)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    def index(self, name: str) -> int:
        """Position of parameter ``name`` in the parameter vector.

        Raises
        ------
        BifidInputError
            If the system has no such parameter.
        """
        try:
            return self._index[name]
        except KeyError:
            raise BifidInputError(
                f"System {self.name!r} has no parameter {name!r}; "
                f"known: {', '.join(self.parameter_names)}."
            ) from None

    def state_index(self, name: str) -> int:
        """Position of state ``name`` in the state vector."""
        try:
            return self.states.index(name)
        except ValueError:
            raise BifidInputError(
                f"System {self.name!r} has no state {name!r}; known: {', '.join(self.states)}."
            ) from None

    def param_vector(self, overrides: Mapping[str, float] | None = None, **kw: float) -> Array:
        """Parameter vector with defaults, overridden by ``overrides`` and keywords.

        Raises
        ------
        BifidInputError
            On an unknown name or a value that is not a finite number.
        """
        values = np.array([p.default for p in self.parameters], dtype=np.float64)
        merged = dict(overrides or {})
        merged.update(kw)
        for name, value in merged.items():
            i = self.index(name)
            try:
                v = float(value)
            except (TypeError, ValueError):
                raise BifidInputError(
                    f"Parameter {name!r} must be a number, got {value!r}."
                ) from None
            if not math.isfinite(v):
                raise BifidInputError(f"Parameter {name!r} must be finite, got {value!r}.")
            values[i] = v
        return jnp.asarray(values)

    def param_dict(self, p: Array) -> dict[str, float]:
        """Parameter vector as a ``{name: value}`` dict of Python floats."""
        p = np.asarray(p)
        return {n: float(p[i]) for i, n in enumerate(self.parameter_names)}

    # -- vector field -------------------------------------------------------------
    def rhs(self, x: Array, t: Array, p: Array) -> Array:
        """Full right-hand side ``f(x, p) + b(p) F cos(Omega t)`` for one state."""
        dx = self.field(x, p)
        if self.kind == "forced":
            assert self.forcing_direction is not None
            force = p[self.index("F")] * jnp.cos(p[self.index("Omega")] * t)
            dx = dx + self.forcing_direction(p) * force
        return dx

    def to_json(self) -> dict:
        """The ``bifid systems`` entry of this system."""
        return {
            "name": self.name,
            "kind": self.kind,
            "states": list(self.states),
            "parameters": [
                {"name": p.name, "default": p.default, "unit": p.unit, "description": p.description}
                for p in self.parameters
            ],
            "observed": self.observed,
            "default_param": self.default_param,
            "description": self.description,
            "source": self.source,
            "x0": None if self.x0 is None else list(self.x0),
            "envelope": None if self.envelope is None else self.envelope.to_json(),
        }


def state_direction(states: tuple[str, ...], *names: str) -> DirectionFn:
    """The constant direction ``p -> e`` with ones on the equations of ``names``: where a
    force or a controller enters (``state_direction(("q", "qd"), "qd")`` gives ``[0, 1]``).

    Raises
    ------
    BifidInputError
        If a name is not one of ``states``.
    """
    unknown = [n for n in names if n not in states]
    if unknown:
        raise BifidInputError(f"{unknown[0]!r} is not a state (states: {', '.join(states)}).")
    vector = jnp.array([1.0 if s in names else 0.0 for s in states])

    def direction(p: Array) -> Array:
        return vector

    return direction
