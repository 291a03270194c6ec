r"""The oscillation speed :math:`\Omega` of the hybrid Hopf model (thesis §5.3.3).

.. math::

    \dot\theta = \Omega(\rho, \theta, \tilde\mu) = \omega_0 + \omega_s\,
        \mathrm{NN}_{\Theta_\Omega}(\rho, \tilde\mu)^{\mathsf T}
        [1, \cos\theta, \dots, \cos n_\Omega\theta, \sin\theta, \dots, \sin n_\Omega\theta]^{\mathsf T}
    \qquad\text{(eq. 5.10)}

(:math:`\omega_s` is a fixed scale, the mean measured frequency, so the network output is
:math:`O(1)`). Training (eq. 5.13) integrates **only the phase equation** on the model cycle of
each orbit, :math:`\rho = \rho_i` fixed, from the phase-matched initial condition of eq. 5.12,
so unstable cycles train without blow-up:

.. math::

    \Xi_\Omega = \frac{1}{\sum_i n_i}\sum_i\sum_j
        \lVert\mathbf U_{12}(\rho_i\cos\theta_i(t_j), \rho_i\sin\theta_i(t_j), \tilde\mu_i)
        - \mathbf z_i(t_j)\rVert^2 .

The initial condition solves :math:`\operatorname{ang}(\mathbf U_{12}(\rho_i e^{i\phi}) - \mathbf c_i)
= \operatorname{ang}(\mathbf z_i(t_1) - \mathbf c_i)` (eq. 5.12) by monotone interpolation on a
fine grid of :math:`\phi` (the same inversion gives the normal-form phase of every sample, used
for the other signals and to initialise :math:`\Omega`: the time along the orbit is linear in
the Fourier coefficients of :math:`1/\Omega(\phi)`,
:math:`t(\phi) = t_0 + \int^{\phi} \mathrm d\phi'/\Omega`, a linear least-squares problem that
gives every orbit's speed profile; the network is first fitted to those profiles, then refined
on :math:`\Xi_\Omega`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from bifid.identify._hopf_map import l2, mlp, mlp_apply, mlp_static, u12
from bifid.identify._hopf_optim import minimise
from bifid.identify._hopf_polar import fourier_design

Array = jnp.ndarray


@dataclass(frozen=True)
class SpeedConfig:
    """Static settings of the speed stage (hashable).

    Attributes
    ----------
    n_harmonics : int
        :math:`n_\\Omega` in eq. 5.10 (0: the speed depends on amplitude and parameter only).
    width, depth : int
        Hidden width and layers of :math:`\\mathrm{NN}_{\\Theta_\\Omega}` (tanh).
    n_fit : int
        Adam iterations fitting the network to the measured speed profiles.
    n_adam : int
        Adam iterations on :math:`\\Xi_\\Omega` (eq. 5.13).
    learning_rate : float
    n_sub : int
        RK4 sub-steps per sample interval.
    map_width, map_depth : int
        Shape of the map network (to evaluate :math:`\\mathbf U_{12}`).
    """

    n_harmonics: int = 0
    width: int = 16
    depth: int = 2
    n_fit: int = 400
    n_adam: int = 200
    learning_rate: float = 3e-3
    n_sub: int = 2
    map_width: int = 16
    map_depth: int = 2


def speed(om, static, rho: Array, theta: Array, mu_t: Array, omega_scale: float, nh: int):
    """:math:`\\Omega(\\rho, \\theta, \\tilde\\mu)` of eq. 5.10 at one point."""
    coef = mlp_apply(om["nn"], static, jnp.stack([rho, mu_t]))
    basis = fourier_design(jnp.atleast_1d(theta), nh)[0]
    return om["w0"] + omega_scale * jnp.dot(coef, basis)


def speed_profile(om, static, rho, mu_t, omega_scale, nh) -> Array:
    """Fourier coefficients of :math:`\\Omega(\\rho, \\cdot, \\tilde\\mu)` (shape ``(2n+1,)``)."""
    coef = mlp_apply(om["nn"], static, jnp.stack([rho, mu_t]))
    return omega_scale * coef + jnp.zeros_like(coef).at[0].set(om["w0"])


def integrate_phase(om, static, rho, mu_t, theta0, h, n_steps, n_sub, omega_scale, nh):
    r"""RK4 on :math:`\dot\theta = \Omega(\rho, \theta, \tilde\mu)`; ``theta`` at ``n_steps`` samples.

    ``h`` is the sample interval; each interval takes ``n_sub`` RK4 steps.
    """

    def f(th):
        return speed(om, static, rho, th, mu_t, omega_scale, nh)

    dt = h / n_sub

    def rk4(th, _):
        k1 = f(th)
        k2 = f(th + 0.5 * dt * k1)
        k3 = f(th + 0.5 * dt * k2)
        k4 = f(th + dt * k3)
        return th + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4), None

    def sample(th, _):
        th_next, _ = jax.lax.scan(rk4, th, None, length=n_sub)
        return th_next, th

    _, thetas = jax.lax.scan(sample, theta0, None, length=n_steps)
    return thetas


# ---------------------------------------------------------------------- phase inversion
def model_angles(map_params, map_static, mu_t, rho, centre, n_grid: int) -> tuple[Array, Array]:
    """Polar angles about ``centre`` of the model cycle at ``n_grid`` normal-form phases."""
    phi = jnp.linspace(0.0, 2 * jnp.pi, n_grid, endpoint=False)
    u = rho * jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=1)
    pts = jax.vmap(lambda ui: u12(map_params, map_static, ui, mu_t))(u)
    d = pts - centre[None, :]
    return phi, jnp.arctan2(d[:, 1], d[:, 0])


def invert_phase(phi_grid: np.ndarray, angles: np.ndarray, beta: np.ndarray):
    """Normal-form phases whose image has polar angle ``beta`` (eq. 5.12), by interpolation.

    Returns
    -------
    phi : ndarray like ``beta``
    monotone : bool
        Whether the model cycle is star-shaped about the centre (the inversion is unique).
    """
    a = np.unwrap(np.asarray(angles))
    sgn = 1.0 if a[-1] >= a[0] else -1.0
    a = sgn * a
    monotone = bool(np.all(np.diff(a) > 0) and (a[-1] - a[0]) < 2 * np.pi)
    a_ext = np.concatenate([a, [a[0] + 2 * np.pi]])
    p_ext = np.concatenate([phi_grid, [2 * np.pi]])
    if not monotone:  # fall back on a monotone envelope to keep a usable answer
        a_ext = np.maximum.accumulate(a_ext)
    b = a[0] + np.mod(sgn * np.asarray(beta) - a[0], 2 * np.pi)
    return np.interp(b, a_ext, p_ext), monotone


def speed_from_phase(t: np.ndarray, phi_unwrapped: np.ndarray, nh: int, n_grid: int = 256):
    r"""Per-orbit speed profile from sample times and unwrapped phases.

    Fits :math:`t = t_0 + d_0\phi + \sum_k (d^c_k \sin k\phi - d^s_k\cos k\phi)/k`, i.e.
    :math:`1/\Omega(\phi) = d_0 + \sum_k d^c_k\cos k\phi + d^s_k\sin k\phi`, then returns the
    Fourier coefficients of :math:`\Omega = 1/(\cdot)` (``(2nh+1,)``), or the mean speed alone
    when the fitted :math:`1/\Omega` is not positive.
    """
    sgn = 1.0 if phi_unwrapped[-1] >= phi_unwrapped[0] else -1.0
    p = sgn * phi_unwrapped
    cols = [np.ones_like(p), p]
    nfit = max(nh, 1) if nh > 0 else 0
    for k in range(1, nfit + 1):
        cols += [np.sin(k * p) / k, -np.cos(k * p) / k]
    X = np.stack(cols, axis=1)
    coef, *_ = np.linalg.lstsq(X, t, rcond=None)
    grid = np.linspace(0, 2 * np.pi, n_grid, endpoint=False)
    s = np.full_like(grid, coef[1])
    for k in range(1, nfit + 1):
        s += coef[2 * k] * np.cos(k * grid) + coef[2 * k + 1] * np.sin(k * grid)
    out = np.zeros(2 * nh + 1)
    if np.all(s > 0):
        om = 1.0 / s
        out[0] = om.mean()
        for k in range(1, nh + 1):
            out[k] = 2 * np.mean(om * np.cos(k * grid))
            out[nh + k] = 2 * np.mean(om * np.sin(k * grid))
    else:
        out[0] = (p[-1] - p[0]) / (t[-1] - t[0])
    return out


# --------------------------------------------------------------------------- training
def init_speed_params(key, config: SpeedConfig, omega0: float):
    import equinox as eqx

    out = 2 * config.n_harmonics + 1
    net = mlp(key, 2, out, config.width, config.depth, 0.0)
    return {"nn": eqx.filter(net, eqx.is_array), "w0": jnp.asarray(omega0)}


@functools.lru_cache(maxsize=16)
def profile_trainer(config: SpeedConfig):
    """Fit of the network to per-orbit speed profiles (targets), with per-orbit losses.

    ``(om, rho, mu_t, target, weights, lam, omega_scale) -> (om, history (n_fit, n))``.
    """
    static = mlp_static(2, 2 * config.n_harmonics + 1, config.width, config.depth)
    nh = config.n_harmonics

    def run(om, rho, mu_t, target, weights, lam, omega_scale):
        def per_orbit(theta):
            pred = jax.vmap(lambda r, m: speed_profile(theta, static, r, m, omega_scale, nh))(
                rho, mu_t
            )
            # relative squared error of the profile (Parseval weights)
            w = jnp.concatenate([jnp.ones(1), 0.5 * jnp.ones(2 * nh)])
            return jnp.sum(w * (pred - target) ** 2, axis=1) / omega_scale**2

        def loss(theta):
            e = per_orbit(theta)
            return jnp.sum(weights * e) / jnp.sum(weights) + lam * l2(theta["nn"]), e

        theta, hist, _ = minimise(
            loss, om, n_adam=config.n_fit, n_lbfgs=0, learning_rate=config.learning_rate * 3
        )
        return theta, hist

    return jax.jit(run)


@functools.lru_cache(maxsize=16)
def series_trainer(config: SpeedConfig, n_steps: int):
    """Refinement on :math:`\\Xi_\\Omega` (eq. 5.13) of one member's speed.

    ``(om, map_params, rho, mu_t, theta0, h, z, mask, lam, omega_scale)
    -> (om, history (n_adam, n), loss)``.
    """
    static = mlp_static(2, 2 * config.n_harmonics + 1, config.width, config.depth)
    map_static = mlp_static(3, 2, config.map_width, config.map_depth)
    nh = config.n_harmonics

    def run(om, map_params, rho, mu_t, theta0, h, z, mask, lam, omega_scale):
        def residuals(theta):
            def one(r, m, th0, hh, zz, mm):
                ths = integrate_phase(theta, static, r, m, th0, hh, n_steps, config.n_sub,
                                      omega_scale, nh)
                u = r * jnp.stack([jnp.cos(ths), jnp.sin(ths)], axis=1)
                pred = jax.vmap(lambda ui: u12(map_params, map_static, ui, m))(u)
                return jnp.sum(mm[:, None] * (pred - zz) ** 2) / jnp.maximum(jnp.sum(mm), 1.0)

            return jax.vmap(one)(rho, mu_t, theta0, h, z, mask)

        def loss(theta):
            e = residuals(theta)
            return jnp.mean(e) + lam * l2(theta["nn"]), e

        theta, hist, (final, _) = minimise(
            loss, om, n_adam=config.n_adam, n_lbfgs=0, learning_rate=config.learning_rate
        )
        return theta, hist, final

    return jax.jit(run)


@functools.lru_cache(maxsize=16)
def period_fn(config: SpeedConfig, n_quad: int = 256):
    r"""Compiled :math:`T = \int_0^{2\pi}\mathrm d\theta/\Omega` and :math:`\min_\theta\Omega`
    for arrays of ``(rho, mu_t)``: ``(om, rho, mu_t, omega_scale) -> (T, min_speed)``."""
    static = mlp_static(2, 2 * config.n_harmonics + 1, config.width, config.depth)
    nh = config.n_harmonics
    grid = jnp.linspace(0.0, 2 * jnp.pi, n_quad, endpoint=False)

    def one(om, r, m, omega_scale):
        prof = speed_profile(om, static, r, m, omega_scale, nh)
        om_vals = fourier_design(grid, nh) @ prof
        return 2 * jnp.pi * jnp.mean(1.0 / om_vals), jnp.min(om_vals)

    return jax.jit(jax.vmap(one, in_axes=(None, 0, 0, None)))


@functools.lru_cache(maxsize=16)
def phase_series_fn(config: SpeedConfig, n_steps: int):
    """Compiled phase integration for one orbit: ``(om, rho, mu_t, theta0, h, omega_scale)``."""
    static = mlp_static(2, 2 * config.n_harmonics + 1, config.width, config.depth)
    nh = config.n_harmonics

    def run(om, rho, mu_t, theta0, h, omega_scale):
        return integrate_phase(om, static, rho, mu_t, theta0, h, n_steps, config.n_sub,
                               omega_scale, nh)

    return jax.jit(run)
