r"""The oscillation speed :math:`\Omega` of the hybrid Hopf model (thesis §5.3.3).

.. math::

    \dot\theta = \Omega(\rho, \theta, \tilde\mu),\qquad
    \Omega = \omega_s\, e^{g}\ \text{(log form, default)}\quad\text{or}\quad
    \Omega = \omega_s\, g\ \text{(eq. 5.10 as printed)},

    g(\theta) = \mathbf c(\rho, \tilde\mu)^{\mathsf T}
        [1, \cos\theta, \dots, \cos n_\Omega\theta, \sin\theta, \dots, \sin n_\Omega\theta],
    \qquad \mathbf c = w_0\mathbf e_0 + W_{\rm lin}[\rho, \tilde\mu]^{\mathsf T}
        + \mathrm{NN}_{\Theta_\Omega}(\rho, \tilde\mu),

with :math:`\omega_s` the mean measured frequency. Training (eq. 5.13) integrates **only the
phase equation** on the model cycle of each orbit, :math:`\rho = \rho_i` fixed, from the
phase-matched initial condition of eq. 5.12, so unstable cycles train without blow-up:

.. math::

    \Xi_\Omega = \frac{1}{m_s}\sum_i \frac{1}{n_i}\sum_j
        \lVert\mathbf U_{12}(\rho_i\cos\theta_i(t_j), \rho_i\sin\theta_i(t_j), \tilde\mu_i)
        - \mathbf z_i(t_j)\rVert^2 .

The initial phase solves eq. 5.12, :math:`\operatorname{ang}(\mathbf U_{12}(\rho_i e^{i\phi})
- \mathbf c_i) = \operatorname{ang}(\mathbf z_i(t_1) - \mathbf c_i)`, by monotone interpolation
on a fine grid of :math:`\phi`; the same inversion gives the normal-form phase of every sample.
Those phases give each orbit's speed profile (:func:`speed_from_phase`); the linear part and
the network are fitted to the profiles first, then refined on :math:`\Xi_\Omega` by L-BFGS.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from bifid.identify.hopf_hybrid._map import l2, mlp, mlp_apply, mlp_static, u12
from bifid.identify.hopf_hybrid._optim import minimise
from bifid.identify.hopf_hybrid._polar import fourier_design

__all__ = [
    "SpeedConfig",
    "init_speed_params",
    "invert_phase",
    "profile_trainer",
    "series_trainer",
    "speed_from_phase",
    "speed_on_grid_fn",
]

Array = jnp.ndarray


@dataclass(frozen=True)
class SpeedConfig:
    r"""Static settings of the speed stage (hashable).

    Attributes
    ----------
    n_harmonics : int
        :math:`n_\\Omega` in eq. 5.10 (0: the speed depends on amplitude and parameter only).
    width, depth : int
        Hidden width and layers of :math:`\\mathrm{NN}_{\\Theta_\\Omega}` (tanh).
    n_fit : int
        Adam iterations fitting the network to the measured speed profiles.
    n_refine : int
        L-BFGS iterations on :math:`\\Xi_\\Omega` (eq. 5.13) from the profile fit (a descent
        method: it can only improve on its start).
    learning_rate : float
    n_sub : int
        RK4 sub-steps per sample interval.
    form : {"log", "additive"}
        ``"additive"``: eq. 5.10 as printed, :math:`\Omega = \omega_s(c_0 + \mathbf c^{\mathsf T}
        \mathbf b(\theta))`; ``"log"``: :math:`\Omega = \omega_s\exp(c_0 + \mathbf c^{\mathsf T}
        \mathbf b(\theta))`, positive by construction (a speed that changes sign would put an
        equilibrium on the cycle); identical when ``n_harmonics = 0`` up to reparametrisation.
    map_width, map_depth : int
        Shape of the map network (to evaluate :math:`\\mathbf U_{12}`).
    """

    n_harmonics: int = 0
    width: int = 16
    depth: int = 2
    n_fit: int = 400
    n_refine: int = 100
    learning_rate: float = 3e-3
    n_sub: int = 2
    form: str = "log"
    map_width: int = 16
    map_depth: int = 2


def log_speed_coefficients(om, static, rho: Array, mu_t: Array, config: SpeedConfig) -> Array:
    r"""Coefficients :math:`\mathbf c` of :math:`g(\theta) = \mathbf c^{\mathsf T}[1, \cos\theta,
    \dots, \sin n\theta]` such that :math:`\Omega = \omega_s g` (additive form) or
    :math:`\Omega = \omega_s e^{g}` (log form):
    :math:`\mathbf c = w_0\mathbf e_0 + W_{\rm lin}[\rho, \tilde\mu]^{\mathsf T}
    + \mathrm{NN}_{\Theta_\Omega}(\rho, \tilde\mu)` — an unregularised linear part (fitted
    first, as :math:`T_L` is for the map) plus the network correction."""
    x = jnp.stack([rho, mu_t])
    coef = mlp_apply(om["nn"], static, x) + om["lin"] @ x
    return coef.at[0].add(om["w0"])


def speed_from_coefficients(coef: Array, theta: Array, omega_scale, form: str) -> Array:
    r""":math:`\Omega` at phases ``theta`` from the coefficients of
    :func:`log_speed_coefficients`."""
    g = fourier_design(jnp.atleast_1d(theta), (coef.shape[0] - 1) // 2) @ coef
    return omega_scale * (jnp.exp(g) if form == "log" else g)


def integrate_phase(om, static, rho, mu_t, theta0, h, n_steps, omega_scale, config):
    r"""RK4 on :math:`\dot\theta = \Omega(\rho, \theta, \tilde\mu)`; ``theta`` at the samples.

    ``h`` is the sample interval; each interval takes ``config.n_sub`` RK4 steps.
    """
    coef = log_speed_coefficients(om, static, rho, mu_t, config)
    n_sub = config.n_sub

    def f(th):
        return speed_from_coefficients(coef, th, omega_scale, config.form)[0]

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


def speed_from_phase(
    t: np.ndarray,
    phi_unwrapped: np.ndarray,
    omega: float,
    grid: np.ndarray,
    n_time_harmonics: int = 40,
) -> np.ndarray:
    r"""An orbit's speed profile :math:`\Omega(\phi)` on ``grid`` from its phase trajectory.

    On a limit cycle of period :math:`T = 2\pi/\omega` the phase minus its mean advance is
    periodic in time, so

    .. math::

        \phi(t) = \phi_0 + \omega t + \sum_{k=1}^{K} c_k\cos k\omega t + d_k\sin k\omega t

    is a linear least-squares fit (noise averages out; any record length), and
    :math:`\Omega = \dot\phi` follows analytically at every sample. The samples
    :math:`(\phi(t_j) \bmod 2\pi, \Omega_j)` are interpolated periodically onto ``grid``.
    The measured ``omega`` (from whole revolutions in the plane) fixes the period.
    """
    sgn = 1.0 if phi_unwrapped[-1] >= phi_unwrapped[0] else -1.0
    p = sgn * np.asarray(phi_unwrapped)
    t = np.asarray(t) - t[0]
    K = int(max(0, min(n_time_harmonics, (len(p) - 4) // 6)))
    wt = omega * t
    cols = [np.ones_like(t), t]
    for k in range(1, K + 1):
        cols += [np.cos(k * wt), np.sin(k * wt)]
    X = np.stack(cols, axis=1)
    coef, *_ = np.linalg.lstsq(X, p, rcond=None)
    dphi = np.full_like(t, coef[1])
    for k in range(1, K + 1):
        dphi += k * omega * (-coef[2 * k] * np.sin(k * wt) + coef[2 * k + 1] * np.cos(k * wt))
    dphi = np.maximum(dphi, 0.02 * abs(coef[1]))
    phase = np.mod(X @ coef, 2 * np.pi)
    order = np.argsort(phase)
    return np.interp(grid, phase[order], dphi[order], period=2 * np.pi)


# --------------------------------------------------------------------------- training
def init_speed_params(key, config: SpeedConfig, rho=None, mu_t=None, targets=None, weights=None):
    """Initial speed parameters: network with a zero output layer; ``w0`` and the linear part
    by weighted least squares of the per-orbit ``targets`` on ``[1, rho, mu_t]`` (zero when no
    targets are given)."""
    out = 2 * config.n_harmonics + 1
    net = mlp(key, 2, out, config.width, config.depth, 0.0)
    w0, lin = 0.0, np.zeros((out, 2))
    if targets is not None:
        w = np.ones(len(rho)) if weights is None else np.asarray(weights, dtype=float)
        X = np.stack([np.ones_like(rho), rho, mu_t], axis=1) * np.sqrt(w)[:, None]
        coef, *_ = np.linalg.lstsq(X, np.asarray(targets) * np.sqrt(w)[:, None], rcond=1e-10)
        lin = coef[1:].T.copy()  # (out, 2) slopes
        w0 = float(coef[0, 0])
        bias = coef[0].copy()  # intercepts of the harmonics: the network's output bias
        bias[0] = 0.0
        net = eqx.tree_at(lambda m: m.layers[-1].bias, net, jnp.asarray(bias))
    return {"nn": eqx.filter(net, eqx.is_array), "w0": jnp.asarray(w0), "lin": jnp.asarray(lin)}


@functools.lru_cache(maxsize=16)
def profile_trainer(config: SpeedConfig):
    """Fit of the network to per-orbit speed profiles (targets), with per-orbit losses.

    ``(om, rho, mu_t, target, weights, lam) -> (om, history (n_fit, n))``; ``target`` holds the
    per-orbit coefficients of :math:`g` (see :func:`log_speed_coefficients`).
    """
    static = mlp_static(2, 2 * config.n_harmonics + 1, config.width, config.depth)
    nh = config.n_harmonics

    def run(om, rho, mu_t, target, weights, lam):
        w = jnp.concatenate([jnp.ones(1), 0.5 * jnp.ones(2 * nh)])
        mean = jnp.sum(weights[:, None] * target, axis=0) / jnp.sum(weights)
        var = jnp.sum(weights * jnp.sum(w * (target - mean) ** 2, axis=1)) / jnp.sum(weights)
        scale = jnp.maximum(var, 1e-10)

        def per_orbit(theta):
            pred = jax.vmap(lambda r, m: log_speed_coefficients(theta, static, r, m, config))(
                rho, mu_t
            )
            # squared L2 distance of the profiles (Parseval weights), relative to their spread
            return jnp.sum(w * (pred - target) ** 2, axis=1) / scale

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
    -> (om, residuals at the start (n,), residuals at the end (n,))``.
    """
    static = mlp_static(2, 2 * config.n_harmonics + 1, config.width, config.depth)
    map_static = mlp_static(3, 2, config.map_width, config.map_depth)

    def run(om, map_params, rho, mu_t, theta0, h, z, mask, lam, omega_scale):
        def residuals(theta):
            def one(r, m, th0, hh, zz, mm):
                ths = integrate_phase(theta, static, r, m, th0, hh, n_steps, omega_scale, config)
                u = r * jnp.stack([jnp.cos(ths), jnp.sin(ths)], axis=1)
                pred = jax.vmap(lambda ui: u12(map_params, map_static, ui, m))(u)
                return jnp.sum(mm[:, None] * (pred - zz) ** 2) / jnp.maximum(jnp.sum(mm), 1.0)

            return jax.vmap(one)(rho, mu_t, theta0, h, z, mask)

        start = residuals(om)
        scale = jnp.maximum(jnp.mean(start), 1e-12)

        def loss(theta):
            # relative to the start, so that lam means what it meant in the profile fit
            e = residuals(theta)
            return jnp.mean(e) / scale + lam * l2(theta["nn"]), e

        theta, _, (_, end) = minimise(
            loss, om, n_adam=0, n_lbfgs=config.n_refine, learning_rate=config.learning_rate
        )
        return theta, start, end  # `end`: the per-orbit residuals at `theta`

    return jax.jit(run)


@functools.lru_cache(maxsize=16)
def speed_on_grid_fn(config: SpeedConfig, n_grid: int = 512):
    r"""Compiled :math:`\Omega(\rho_k, \theta_j, \tilde\mu_k)` on a uniform grid of phases
    for arrays ``rho``, ``mu_t``: ``(om, rho, mu_t, omega_scale) -> (n, n_grid)``."""
    static = mlp_static(2, 2 * config.n_harmonics + 1, config.width, config.depth)
    grid = jnp.linspace(0.0, 2 * jnp.pi, n_grid, endpoint=False)

    def one(om, r, m, omega_scale):
        coef = log_speed_coefficients(om, static, r, m, config)
        return speed_from_coefficients(coef, grid, omega_scale, config.form)

    return jax.jit(jax.vmap(one, in_axes=(None, 0, 0, None)))
