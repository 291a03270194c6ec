r"""The Van der Pol oscillator of the thesis, eq. 5.14.

.. math:: \dot z_1 = z_2,\qquad \dot z_2 = 2\mu z_2 - z_1^2 z_2 - z_1 ,

with a supercritical Hopf bifurcation at :math:`\mu = 0`; the cycle's amplitude in ``z1``
grows as :math:`2\sqrt{2\mu}`.

Safety envelope: ``|z1| <= 5``, ``|z2| <= 10``, controller output ``|u| <= 10``: the cycles
for ``mu <= 1`` stay within ``|z1| < 2.9``, ``|z2| < 5.4``, and the controller of a PP-CBC
campaign over them below 6.

CBC settings: phase-plane CBC on ``(z1, z1_dot)`` (the derivative estimated from the samples)
with the control on the ``z2`` equation, ``kp = kd = 1``.
"""

from __future__ import annotations

import jax.numpy as jnp

from bifid.systems._base import Envelope, Parameter, System, state_direction

__all__ = ["system"]

Array = jnp.ndarray
STATES = ("z1", "z2")


def field(x: Array, p: Array) -> Array:
    """Right-hand side of eq. 5.14."""
    mu = p[0]
    return jnp.stack([x[1], 2.0 * mu * x[1] - x[0] ** 2 * x[1] - x[0]])


def system() -> System:
    """The ``vanderpol`` system (module docstring)."""
    return System(
        name="vanderpol",
        states=STATES,
        parameters=(Parameter("mu", 0.5, "nd", "bifurcation parameter"),),
        field=field,
        input_direction=state_direction(STATES, "z2"),  # on the velocity equation
        default_param="mu",
        description="z1' = z2, z2' = 2 mu z2 - z1^2 z2 - z1 (eq. 5.14)",
        envelope=Envelope(states={"z1": (-5.0, 5.0), "z2": (-10.0, 10.0)}, control_max=10.0),
        cbc={
            "sample_rate": 200.0,
            "outputs": ("z1", "z2"),
            "x1": "z1",
            "x2": "z1_dot",
            "kp": 1.0,
            "kd": 1.0,
            "amplitude_range": (0.2, 3.0),
            "n_amplitudes": 12,
            "omega_guess": 1.0,
            "settle_periods": 8.0,
            "measure_periods": 3.0,
        },
    )
