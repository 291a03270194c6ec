"""The reference systems of the thesis: ``hopf``, ``vanderpol``, ``flutter``, ``duffing``,
``shaw_pierre``. Each is a pure JAX field plus metadata (see :mod:`bifid.systems._base`)."""

from __future__ import annotations

import math

import jax.numpy as jnp

from bifid.systems._base import Parameter, System, register

Array = jnp.ndarray


# --------------------------------------------------------------------------- hopf
def _hopf_field(x: Array, p: Array) -> Array:
    # eq. 5.2 with Omega = omega0:  u' = (mu - mu0) u - omega0 J u + a2 u r^2 - q5 u r^4
    mu, mu0, a2, omega0, q5 = p[0], p[1], p[2], p[3], p[4]
    r2 = x[0] ** 2 + x[1] ** 2
    g = (mu - mu0) + a2 * r2 - q5 * r2**2
    return jnp.stack([g * x[0] - omega0 * x[1], g * x[1] + omega0 * x[0]])


def hopf() -> System:
    r"""Normal-form-like Hopf model, thesis eq. 5.2/5.3.

    .. math::

        \dot u_1 = (\mu-\mu_0)u_1 - \omega_0 u_2 + a_2 u_1 r^2 - q_5 u_1 r^4,\quad
        \dot u_2 = (\mu-\mu_0)u_2 + \omega_0 u_1 + a_2 u_2 r^2 - q_5 u_2 r^4,

    with :math:`r^2 = u_1^2+u_2^2`; in polar form
    :math:`\dot r = (\mu-\mu_0) r + a_2 r^3 - q_5 r^5`,
    :math:`\dot\theta = \omega_0`. With ``a2 > 0`` and ``q5 = 1`` the Hopf point at
    :math:`\mu_0` is subcritical and the cycles fold at :math:`\mu_0 - a_2^2/4`; set
    ``q5 = 0`` and ``a2 < 0`` for the supercritical case of §5.4.1.
    """
    return System(
        name="hopf",
        states=("u1", "u2"),
        parameters=(
            Parameter("mu", 0.0, "nd", "bifurcation parameter"),
            Parameter("mu0", 0.0, "nd", "Hopf point"),
            Parameter("a2", 1.0, "nd", "cubic coefficient (> 0: subcritical)"),
            Parameter("omega0", 1.0, "rad/s", "angular frequency"),
            Parameter("q5", 1.0, "nd", "quintic coefficient (0 switches the quintic term off)"),
        ),
        field=_hopf_field,
        input_direction=lambda p: jnp.array([1.0, 0.0]),
        default_param="mu",
        description=hopf.__doc__ or "",
    )


# ---------------------------------------------------------------------- vanderpol
def _vdp_field(x: Array, p: Array) -> Array:
    mu = p[0]
    return jnp.stack([x[1], 2.0 * mu * x[1] - x[0] ** 2 * x[1] - x[0]])


def vanderpol() -> System:
    r"""Van der Pol oscillator, thesis eq. 5.14.

    .. math:: \dot z_1 = z_2,\qquad \dot z_2 = 2\mu z_2 - z_1^2 z_2 - z_1 .

    Supercritical Hopf bifurcation at :math:`\mu = 0`.
    """
    return System(
        name="vanderpol",
        states=("z1", "z2"),
        parameters=(Parameter("mu", 0.5, "nd", "bifurcation parameter"),),
        field=_vdp_field,
        input_direction=lambda p: jnp.array([0.0, 1.0]),
        default_param="mu",
        description=vanderpol.__doc__ or "",
    )


# ------------------------------------------------------------------------ flutter
FLUTTER_PARAMETERS = (
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
    """Mass, damping and stiffness matrices ``M, D, K`` of eq. A.2 (with ρ, see :func:`flutter`)."""
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


def _flutter_field(z: Array, p: Array) -> Array:
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


def flutter() -> System:
    r"""Unsteady 2-DOF aerofoil (heave, pitch) with one aerodynamic lag state, thesis App. A.

    .. math:: \mathbf M\ddot{\mathbf x} + \mathbf D\dot{\mathbf x} + \mathbf K\mathbf x
              + \mathbf N(\alpha) = 0,\quad \mathbf x = [h, \alpha, w]^T,
              \quad \mathbf N = [0,\ k_{\alpha2}\alpha^2 + k_{\alpha3}\alpha^3,\ 0]^T,

    with M, D, K of eq. A.2 and the values of Table A.1; states
    ``h, hd, alpha, alphad, w, wd``. **Deviation from the printed thesis:** the entries
    D[0,2] and K[0,2] as printed lack the air density; the authors' code has
    :math:`2\pi\rho U^2 b(c_1c_2+c_3c_4)` and :math:`2\pi\rho U^3 c_2c_4(c_1+c_3)`.
    bifid uses the versions with ρ, which reproduce the thesis's subcritical Hopf
    bifurcation at U ≈ 18.28 m/s. The control input of eq. 3.25 acts on the heave
    velocity equation, ``e_c = [0, 1, 0, 0, 0, 0]``.
    """
    return System(
        name="flutter",
        states=("h", "hd", "alpha", "alphad", "w", "wd"),
        parameters=FLUTTER_PARAMETERS,
        field=_flutter_field,
        input_direction=lambda p: jnp.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0]),
        observed="h",
        default_param="U",
        description=flutter.__doc__ or "",
    )


# ------------------------------------------------------------------------ duffing
def _duffing_field(x: Array, p: Array) -> Array:
    zeta, gamma = p[0], p[1]
    return jnp.stack([x[1], -2.0 * zeta * x[1] - x[0] - gamma * x[0] ** 3])


def duffing() -> System:
    r"""Forced Duffing oscillator.

    .. math:: \ddot q + 2\zeta\dot q + q + \gamma q^3 = F\cos(\Omega t).
    """
    return System(
        name="duffing",
        states=("q", "qd"),
        parameters=(
            Parameter("zeta", 0.01, "nd", "damping ratio"),
            Parameter("gamma", 0.5, "nd", "cubic stiffness"),
            Parameter("F", 0.01, "nd", "forcing amplitude"),
            Parameter("Omega", 1.0, "rad/s", "forcing frequency"),
        ),
        field=_duffing_field,
        kind="forced",
        forcing_direction=lambda p: jnp.array([0.0, 1.0]),
        input_direction=lambda p: jnp.array([0.0, 1.0]),
        observed="q",
        default_param="Omega",
        description=duffing.__doc__ or "",
    )


# -------------------------------------------------------------------- shaw_pierre
def _shaw_pierre_field(x: Array, p: Array) -> Array:
    k, c1, c2, kappa = p[0], p[1], p[2], p[3]
    x1, v1, x2, v2 = x[0], x[1], x[2], x[3]
    a1 = -2 * k * x1 + k * x2 - (c1 + c2) * v1 + c2 * v2 - kappa * x1**3
    a2 = k * x1 - 2 * k * x2 + c2 * v1 - (c1 + c2) * v2
    return jnp.stack([v1, a1, v2, a2])


def shaw_pierre() -> System:
    r"""Modified Shaw–Pierre 2-DOF oscillator, thesis §6.3.1 (the authors' code).

    .. math::

        \ddot x_1 = -2k x_1 + k x_2 - (c_1+c_2)\dot x_1 + c_2\dot x_2 - \kappa x_1^3
                    + F\cos\Omega t,\\
        \ddot x_2 = k x_1 - 2k x_2 + c_2\dot x_1 - (c_1+c_2)\dot x_2 + F\cos\Omega t,

    with k = 1, c1 = 0.003, c2 = c1/√3, κ = 0.003; observed coordinate ``x1``. The
    first mode (both masses in phase) has natural frequency 1 rad/s. A controller acts
    on the first mass.
    """
    return System(
        name="shaw_pierre",
        states=("x1", "x1d", "x2", "x2d"),
        parameters=(
            Parameter("k", 1.0, "nd", "linear stiffness"),
            Parameter("c1", 0.003, "nd", "linear damping"),
            Parameter("c2", 0.003 / math.sqrt(3.0), "nd", "coupling damping"),
            Parameter("kappa", 0.003, "nd", "cubic stiffness"),
            Parameter("F", 0.01, "nd", "forcing amplitude"),
            Parameter("Omega", 1.0, "rad/s", "forcing frequency"),
        ),
        field=_shaw_pierre_field,
        kind="forced",
        forcing_direction=lambda p: jnp.array([0.0, 1.0, 0.0, 1.0]),
        input_direction=lambda p: jnp.array([0.0, 1.0, 0.0, 0.0]),
        observed="x1",
        default_param="Omega",
        description=shaw_pierre.__doc__ or "",
    )


for _factory in (hopf, vanderpol, flutter, duffing, shaw_pierre):
    register(_factory.__name__, _factory)
