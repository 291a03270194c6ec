r"""The forced Duffing oscillator.

.. math:: \ddot q + 2\zeta\dot q + q + \gamma q^3 = F\cos(\Omega t),

states ``q, qd``; a hardening oscillator for ``gamma > 0``. The force and the controller both
act on the velocity equation.

Safety envelope: ``|q| <= 2``, ``|qd| <= 4``, controller output ``|u| <= 1``. At the default
``F = 0.01`` the largest response (the resonance peak, ``F/(2 zeta) = 0.5`` linear, bent to
``Omega`` ≈ 1.04 by the cubic term) stays below ``|q| = 0.5`` (``|q| = 1.5``,
``|qd| = 1.9`` at ``F = 0.04``); the controller of an S-curve or FRC campaign stays below 0.16.

CBC settings: ``kp = kd = 0.5`` on ``q`` (controlled Floquet multipliers 0.21 on the three
branches; the middle one is a saddle with multiplier up to 1.11 without control). With
measurement noise ``kp = kd = 0.1`` (multipliers <= 0.70): the controller feeds the noise
back as a force, and lower gains let the forcing update tell the fundamental from it.
"""

from __future__ import annotations

import jax.numpy as jnp

from bifid.systems._base import Envelope, Parameter, System, state_direction

__all__ = ["system"]

Array = jnp.ndarray
STATES = ("q", "qd")


def field(x: Array, p: Array) -> Array:
    """The autonomous part: ``(qd, -2 zeta qd - q - gamma q^3)``."""
    zeta, gamma = p[0], p[1]
    return jnp.stack([x[1], -2.0 * zeta * x[1] - x[0] - gamma * x[0] ** 3])


def system() -> System:
    """The ``duffing`` system (module docstring)."""
    return System(
        name="duffing",
        states=STATES,
        parameters=(
            Parameter("zeta", 0.01, "nd", "damping ratio"),
            Parameter("gamma", 0.5, "nd", "cubic stiffness"),
            Parameter("F", 0.01, "nd", "forcing amplitude"),
            Parameter("Omega", 1.0, "rad/s", "forcing frequency"),
        ),
        field=field,
        kind="forced",
        forcing_direction=state_direction(STATES, "qd"),
        input_direction=state_direction(STATES, "qd"),
        observed="q",
        default_param="Omega",
        description="q'' + 2 zeta q' + q + gamma q^3 = F cos(Omega t)",
        envelope=Envelope(states={"q": (-2.0, 2.0), "qd": (-4.0, 4.0)}, control_max=1.0),
        cbc={
            "sample_rate": 100.0,
            "outputs": ("q",),
            "signal": "q",
            "kp": 0.5,
            "kd": 0.5,
            "n_harmonics": 5,
            "settle_periods": 8.0,
            "measure_periods": 3.0,
            "noisy_options": {"kp": 0.1, "kd": 0.1, "settle_periods": 20.0},
        },
    )
