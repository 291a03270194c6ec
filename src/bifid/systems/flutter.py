r"""The unsteady two-degree-of-freedom aerofoil (heave, pitch) with one aerodynamic lag state,
thesis App. A.

.. math:: \mathbf M\ddot{\mathbf x} + \mathbf D\dot{\mathbf x} + \mathbf K\mathbf x
          + \mathbf N(\alpha) = 0,\quad \mathbf x = [h, \alpha, w]^T,
          \quad \mathbf N = [0,\ k_{\alpha2}\alpha^2 + k_{\alpha3}\alpha^3,\ 0]^T,

with M, D, K of eq. A.2 and the values of Table A.1; states ``h, hd, alpha, alphad, w, wd``.
**Deviation from the printed thesis:** the entries D[0,2] and K[0,2] as printed lack the air
density; the authors' code has :math:`2\pi\rho U^2 b(c_1c_2+c_3c_4)` and
:math:`2\pi\rho U^3 c_2c_4(c_1+c_3)`. bifid uses the versions with ρ, which reproduce the
thesis's subcritical Hopf bifurcation at U ≈ 18.28 m/s. The control input of eq. 3.25 acts on
the heave velocity equation, ``e_c = [0, 1, 0, 0, 0, 0]``, so the controller's output is a
heave acceleration (m/s²).

Safety envelope (the rig of §3.3.3.1): heave ``|h| <= 50 mm`` -- the largest stable LCO of
the operating range is 39 mm at U = 18.3 m/s (42 mm at 19 m/s), and the leaf springs and the
shaker's stroke (158 mm peak to peak) bound the travel; pitch ``|alpha| <= 0.35 rad`` (20°),
three times the largest LCO pitch amplitude of that range (0.12 rad); heave and pitch rates
at most ``2 m/s`` and ``10 rad/s`` (LCOs: 0.58 m/s, 1.5 rad/s); the controller's output at
most ``25 m/s²`` (425 N on the heave mass ``m_T + π ρ b²`` ≈ 17 kg), twice the largest output
the PP-CBC campaigns need (12 m/s², starting an oscillation from rest at U = 18 m/s).

CBC settings: PP-CBC in the plane of the two measured displacements ``(h, alpha)`` (laser and
encoder: no derivative is estimated), polar target with ``n_h = 10``, ``kp = -150, kd = -20``
(every non-trivial controlled Floquet multiplier below 0.48 on both branches for
U = 15-18 m/s; the unstable LCOs have 1.05-1.16 without control). The oscillation is started
from rest by an elliptic ``(h, hd)`` target with ``kp = 50, kd = 40`` (``bootstrap_gains``).
The controller's output passes a 100 Hz first-order low-pass (2.5 Hz LCOs, 1.4° of lag), which
cuts the measurement noise that the gains pass to the shaker. The amplitude grid ends just
above the largest stable LCO (30.5 mm at 17 m/s): targets far outside it are not held. The
``noise_reference`` amplitudes are those of the smallest LCO of the U = 15-17.5 m/s diagram
(unstable, 17.5 m/s): "1 % noise" means 1 % of these.
"""

from __future__ import annotations

import jax.numpy as jnp

from bifid.systems._base import Envelope, Parameter, System, state_direction

__all__ = ["PARAMETERS", "flutter_matrices", "system"]

Array = jnp.ndarray
STATES = ("h", "hd", "alpha", "alphad", "w", "wd")

PARAMETERS = (
    Parameter("U", 15.0, "m/s", "airspeed"),
    Parameter("b", 0.15, "m", "wing semi-chord"),
    Parameter("a", -0.5, "nd", "elastic axis position relative to the semi-chord"),
    Parameter("rho", 1.204, "kg/m^3", "air density"),
    Parameter("mw", 5.3, "kg", "mass of the wing"),
    Parameter("mT", 16.9, "kg", "mass of wing and support"),
    Parameter("Ia", 0.1726, "kg m^2", "wing moment of inertia about the elastic axis"),
    Parameter("ca", 0.5628, "kg m^2/s", "pitch linear damping"),
    Parameter("ch", 15.443, "kg/s", "heave linear damping"),
    Parameter("ka", 54.1162, "N/rad", "pitch linear stiffness"),
    Parameter("ka2", 751.6, "N/rad^2", "pitch quadratic stiffness"),
    Parameter("ka3", 5006.7, "N/rad^3", "pitch cubic stiffness"),
    Parameter("kh", 3529.4, "N/m", "heave linear stiffness"),
    Parameter("xa", 0.234, "nd", "distance between centre of gravity and elastic axis"),
    Parameter("c0", 1.0, "nd", "aeroelastic coefficient"),
    Parameter("c1", 0.1650, "nd", "aeroelastic coefficient"),
    Parameter("c2", 0.0455, "nd", "aeroelastic coefficient"),
    Parameter("c3", 0.335, "nd", "aeroelastic coefficient"),
    Parameter("c4", 0.3, "nd", "aeroelastic coefficient"),
)


def flutter_matrices(p: Array) -> tuple[Array, Array, Array]:
    """Mass, damping and stiffness matrices ``M, D, K`` of eq. A.2 (with ρ, module docstring)."""
    U, b, a, rho, mw, mT, Ia, ca, ch, ka = (p[i] for i in range(10))
    xa, c0, c1, c2, c3, c4 = p[13], p[14], p[15], p[16], p[17], p[18]
    pi = jnp.pi
    chat = c0 - c1 - c3
    s12 = c1 * c2 + c3 * c4
    M = jnp.array(
        [
            [mT + pi * rho * b**2, mw * xa * b - a * pi * rho * b**3, 0.0],
            [mw * xa * b - a * pi * rho * b**3, Ia + pi * (1 / 8 + a**2) * rho * b**4, 0.0],
            [0.0, 0.0, 1.0],
        ]
    )
    D = jnp.array(
        [
            [
                ch + 2 * pi * rho * b * U * chat,
                (1 + chat * (1 - 2 * a)) * pi * rho * b**2 * U,
                2 * pi * rho * U**2 * b * s12,
            ],
            [
                -2 * pi * (a + 0.5) * rho * b**2 * chat * U,
                ca + (0.5 - a) * (1 - chat * (1 + 2 * a)) * pi * rho * b**3 * U,
                -2 * pi * rho * b**2 * U**2 * (a + 0.5) * s12,
            ],
            [-1 / b, a - 0.5, (c2 + c4) * U / b],
        ]
    )
    K = jnp.array(
        [
            [p[12], 2 * pi * rho * b * U**2 * chat, 2 * pi * rho * U**3 * c2 * c4 * (c1 + c3)],
            [
                0.0,
                ka - 2 * pi * (0.5 + a) * rho * chat * b**2 * U**2,
                -2 * pi * rho * b * U**3 * (a + 0.5) * c2 * c4 * (c1 + c3),
            ],
            [0.0, -U / b, c2 * c4 * U**2 / b**2],
        ]
    )
    return M, D, K


def field(z: Array, p: Array) -> Array:
    """First-order form of the equations of motion (module docstring)."""
    M, D, K = flutter_matrices(p)
    q = jnp.stack([z[0], z[2], z[4]])
    qd = jnp.stack([z[1], z[3], z[5]])
    alpha = z[2]
    nonlinear = jnp.stack([0.0 * alpha, p[10] * alpha**2 + p[11] * alpha**3, 0.0 * alpha])
    r = D @ qd + K @ q + nonlinear
    # M is block-diagonal (2x2 structural block, 1 for w): explicit inverse, far cheaper
    # than a batched LAPACK solve inside vmap/jit
    det = M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]
    qdd = -jnp.stack(
        [
            (M[1, 1] * r[0] - M[0, 1] * r[1]) / det,
            (M[0, 0] * r[1] - M[1, 0] * r[0]) / det,
            r[2] / M[2, 2],
        ]
    )
    return jnp.stack([qd[0], qdd[0], qd[1], qdd[1], qd[2], qdd[2]])


def system() -> System:
    """The ``flutter`` system (module docstring)."""
    return System(
        name="flutter",
        states=STATES,
        parameters=PARAMETERS,
        field=field,
        input_direction=state_direction(STATES, "hd"),  # the shaker, eq. 3.25
        observed="h",
        default_param="U",
        description="M x'' + D x' + K x + N(alpha) = 0, x = [h, alpha, w] (App. A, eq. A.2)",
        envelope=Envelope(
            states={
                "h": (-0.05, 0.05),
                "hd": (-2.0, 2.0),
                "alpha": (-0.35, 0.35),
                "alphad": (-10.0, 10.0),
            },
            control_max=25.0,
        ),
        cbc={
            "sample_rate": 5000.0,
            "derivative_cutoff": 25.0,
            "outputs": ("h", "alpha"),
            "x1": "h",
            "x2": "alpha",
            "kp": -150.0,
            "kd": -20.0,
            "bootstrap_gains": (50.0, 40.0),
            "filter_hz": 100.0,
            "amplitude_range": (0.004, 0.032),
            "n_amplitudes": 15,
            "omega_guess": 15.0,
            "settle_periods": 6.0,
            "measure_periods": 4.0,
            "signal_units": {"h": "m", "alpha": "rad"},
            "extra": {"noise_reference": {"h": 0.00743, "alpha": 0.02157}},
        },
    )
