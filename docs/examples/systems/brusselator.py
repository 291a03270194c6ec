"""The Brusselator, a two-state chemical oscillator: a Hopf bifurcation at b = 1 + a^2 away
from the origin (the equilibrium is x = a, y = b/a)."""

import jax.numpy as jnp

from bifid.systems import Envelope, Parameter, System, register


def field(s, p):
    a, b = p[0], p[1]
    x, y = s[0], s[1]
    return jnp.stack([a - (b + 1) * x + x**2 * y, b * x - x**2 * y])


register(
    "brusselator",
    System(
        name="brusselator",
        states=("x", "y"),
        parameters=(
            Parameter("a", 1.0, "1", "feed rate"),
            Parameter("b", 1.5, "1", "conversion rate"),
        ),
        field=field,
        input_direction=lambda p: jnp.array([1.0, 0.0]),  # the controller acts on x
        observed="x",
        default_param="b",
        x0=(1.0, 1.5),  # the equilibrium (a, b/a) at the nominal parameters
        envelope=Envelope(states={"x": (-1.0, 10.0), "y": (-1.0, 10.0)}, control_max=5.0),
        cbc={"outputs": ("x", "y")},  # the rig records both concentrations
    ),
)
