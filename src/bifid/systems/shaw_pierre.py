r"""The modified Shaw–Pierre two-degree-of-freedom oscillator, thesis §6.3.1 (the authors' code).

.. math::

    \ddot x_1 = -2k x_1 + k x_2 - (c_1+c_2)\dot x_1 + c_2\dot x_2 - \kappa x_1^3
                + F\cos\Omega t,\\
    \ddot x_2 = k x_1 - 2k x_2 + c_2\dot x_1 - (c_1+c_2)\dot x_2 + F\cos\Omega t,

with k = 1, c1 = 0.003, c2 = c1/√3, κ = 0.003; observed coordinate ``x1``. The first mode
(both masses in phase) has natural frequency 1 rad/s. A controller acts on the first mass.

Safety envelope: ``|x1|, |x2| <= 10``, velocities ``<= 15``, controller output ``|u| <= 2``.
At the default ``F = 0.01`` the first mode's resonance (damping ratio 0.0015) peaks near
``|x1| = 3.3``; the controller of an FRC campaign through it stays below 0.66.

CBC settings: ``kp = kd = 1`` on ``x1`` (controlled multipliers <= 0.44). With measurement
noise ``kp = 0, kd = 0.1`` (multipliers <= 0.86): the controller feeds the noise ``ε`` back as a
force whose fundamental has the standard error ``σ_ε |k_p + iΩk_d| sqrt(2/n)`` over ``n``
samples, which the forcing update of eq. 3.6 must tell apart from the small forcing of the
S-curve; lower gains shorten the records that verify a point.
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from bifid.systems._base import Envelope, Parameter, System, state_direction

__all__ = ["system"]

Array = jnp.ndarray
STATES = ("x1", "x1d", "x2", "x2d")


def field(x: Array, p: Array) -> Array:
    """The autonomous part of the two equations (module docstring)."""
    k, c1, c2, kappa = p[0], p[1], p[2], p[3]
    x1, v1, x2, v2 = x[0], x[1], x[2], x[3]
    a1 = -2 * k * x1 + k * x2 - (c1 + c2) * v1 + c2 * v2 - kappa * x1**3
    a2 = k * x1 - 2 * k * x2 + c2 * v1 - (c1 + c2) * v2
    return jnp.stack([v1, a1, v2, a2])


def system() -> System:
    """The ``shaw_pierre`` system (module docstring)."""
    return System(
        name="shaw_pierre",
        states=STATES,
        parameters=(
            Parameter("k", 1.0, "nd", "linear stiffness"),
            Parameter("c1", 0.003, "nd", "linear damping"),
            Parameter("c2", 0.003 / math.sqrt(3.0), "nd", "coupling damping"),
            Parameter("kappa", 0.003, "nd", "cubic stiffness"),
            Parameter("F", 0.01, "nd", "forcing amplitude"),
            Parameter("Omega", 1.0, "rad/s", "forcing frequency"),
        ),
        field=field,
        kind="forced",
        forcing_direction=state_direction(STATES, "x1d", "x2d"),  # on both masses
        input_direction=state_direction(STATES, "x1d"),  # on the first mass
        observed="x1",
        default_param="Omega",
        description="two masses, cubic spring on x1, force F cos(Omega t) on both (§6.3.1)",
        envelope=Envelope(
            states={
                "x1": (-10.0, 10.0),
                "x1d": (-15.0, 15.0),
                "x2": (-10.0, 10.0),
                "x2d": (-15.0, 15.0),
            },
            control_max=2.0,
        ),
        cbc={
            "sample_rate": 100.0,
            "outputs": ("x1", "x2"),
            "signal": "x1",
            "kp": 1.0,
            "kd": 1.0,
            "n_harmonics": 5,
            "settle_periods": 10.0,
            "measure_periods": 3.0,
            "noisy_options": {
                "kp": 0.0,
                "kd": 0.1,
                "settle_periods": 30.0,
                "max_measure_periods": 1000.0,
            },
        },
    )
