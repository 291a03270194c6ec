r"""The normal-form-like Hopf model of the thesis, eqs. 5.2/5.3.

.. math::

    \dot u_1 = (\mu-\mu_0)u_1 - \omega_0 u_2 + a_2 u_1 r^2 - q_5 u_1 r^4,\qquad
    \dot u_2 = (\mu-\mu_0)u_2 + \omega_0 u_1 + a_2 u_2 r^2 - q_5 u_2 r^4,

with :math:`r^2 = u_1^2+u_2^2`; in polar form :math:`\dot r = (\mu-\mu_0) r + a_2 r^3 - q_5 r^5`,
:math:`\dot\theta = \omega_0`. With ``a2 > 0`` and ``q5 = 1`` the Hopf point at :math:`\mu_0` is
subcritical and the cycles fold at :math:`\mu_0 - a_2^2/4`; ``q5 = 0`` and ``a2 < 0`` give the
supercritical case of §5.4.1.

Safety envelope: ``|u_i| <= 2``, controller output ``|u| <= 2``. The largest stable cycle of
the default parameters over ``mu <= 1`` has radius
:math:`r^2 = (a_2 + \sqrt{a_2^2 + 4\mu})/2 \le 1.62`, ``r <= 1.27``, so the gate only fires on
a response that has left the region the model describes; the controller of a PP-CBC
campaign stays below 0.34.

CBC settings: phase-plane CBC on ``(u1, u2)`` with the control on ``u1``; ``kp = 1`` gives a
radial feedback ``kp (r* - r)/2`` that beats the cycles' instability ``2 r0^2 = 0.2``
(eq. 3.16; controlled Floquet multiplier 0.15).
"""

from __future__ import annotations

import jax.numpy as jnp

from bifid.systems._base import Envelope, Parameter, System, state_direction

__all__ = ["system"]

Array = jnp.ndarray
STATES = ("u1", "u2")


def field(x: Array, p: Array) -> Array:
    """Right-hand side of eq. 5.2 with :math:`\\Omega = \\omega_0`."""
    mu, mu0, a2, omega0, q5 = p[0], p[1], p[2], p[3], p[4]
    r2 = x[0] ** 2 + x[1] ** 2
    g = (mu - mu0) + a2 * r2 - q5 * r2**2
    return jnp.stack([g * x[0] - omega0 * x[1], g * x[1] + omega0 * x[0]])


def system() -> System:
    """The ``hopf`` system (module docstring)."""
    return System(
        name="hopf",
        states=STATES,
        parameters=(
            Parameter("mu", 0.0, "nd", "bifurcation parameter"),
            Parameter("mu0", 0.0, "nd", "Hopf point"),
            Parameter("a2", 1.0, "nd", "cubic coefficient (> 0: subcritical)"),
            Parameter("omega0", 1.0, "rad/s", "angular frequency"),
            Parameter("q5", 1.0, "nd", "quintic coefficient (0 switches the quintic term off)"),
        ),
        field=field,
        input_direction=state_direction(STATES, "u1"),  # the controller pushes on u1
        default_param="mu",
        description="u1' = g u1 - omega0 u2, u2' = g u2 + omega0 u1, "
        "g = (mu - mu0) + a2 r^2 - q5 r^4 (eq. 5.2)",
        envelope=Envelope(states={"u1": (-2.0, 2.0), "u2": (-2.0, 2.0)}, control_max=2.0),
        cbc={
            "sample_rate": 200.0,
            "outputs": ("u1", "u2"),
            "x1": "u1",
            "x2": "u2",
            "kp": 1.0,
            "kd": 0.0,
            "amplitude_range": (0.05, 0.34),
            "n_amplitudes": 8,
            "omega_guess": 1.0,
            "settle_periods": 6.0,
            "measure_periods": 3.0,
        },
    )
