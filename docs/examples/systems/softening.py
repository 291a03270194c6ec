"""A forced softening oscillator: the cubic term lowers the stiffness as the amplitude grows,
so the resonance peak bends to lower frequencies."""

import jax.numpy as jnp

from bifid.systems import Envelope, Parameter, System, register


def field(s, p):
    omega0, zeta, beta = p[0], p[1], p[2]
    x, v = s[0], s[1]
    return jnp.stack([v, -2 * zeta * omega0 * v - omega0**2 * x + beta * x**3])


def on_velocity(p):
    return jnp.array([0.0, 1.0])


register(
    "softening",
    System(
        name="softening",
        states=("x", "v"),
        parameters=(
            Parameter("omega0", 1.0, "rad/s", "natural frequency"),
            Parameter("zeta", 0.01, "1", "damping ratio"),
            Parameter("beta", 0.5, "1/(m^2 s^2)", "softening cubic stiffness"),
            Parameter("F", 0.01, "m/s^2", "forcing amplitude"),
            Parameter("Omega", 1.0, "rad/s", "forcing frequency"),
        ),
        field=field,
        kind="forced",
        forcing_direction=on_velocity,  # F cos(Omega t) enters the velocity equation
        input_direction=on_velocity,  # and so does the controller
        observed="x",
        default_param="Omega",
        envelope=Envelope(states={"x": (-1.2, 1.2)}, control_max=0.5),
    ),
)
