r"""The sampled linear model of :class:`~bifid.identify.mechanistic.LinearPEM` (thesis eqs.
4.7–4.8): the state matrix of a system's linearisation, its exact discretisation
:math:`A_d = e^{A T_s}` and the output sequence :math:`C A_d^k z_0`, with the jitted weighted
output-error residual and Jacobian of one model structure.

The matrix exponential is a fixed-order Taylor polynomial with scaling and squaring
(:func:`expm_taylor`) rather than ``jax.scipy.linalg.expm``: its unrolled graph compiles and
differentiates much faster than the branchy Padé approximant, at the same accuracy for the
norms it is used with (:func:`n_squarings_for`).
"""

from __future__ import annotations

import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bifid.systems import System

Array = jnp.ndarray

__all__ = [
    "discrete_outputs",
    "expm_taylor",
    "jacobian_and_field",
    "n_squarings_for",
    "output_error_kernels",
    "state_matrix",
]


def state_matrix(system: System, p: Array, x_eq: Array | None = None) -> Array:
    """Continuous-time state matrix :math:`A = \\partial f/\\partial x` at ``x_eq`` (eq. 4.8).

    Parameters
    ----------
    system : System
    p : array of shape (n_params,)
    x_eq : array of shape (n_states,), optional
        Equilibrium; zeros by default.

    Returns
    -------
    jax array of shape (n_states, n_states)
    """
    x = jnp.zeros(system.n_states) if x_eq is None else jnp.asarray(x_eq, dtype=jnp.float64)
    return jacobian_and_field(system.field)[0](x, jnp.asarray(p, dtype=jnp.float64))


@functools.lru_cache(maxsize=64)
def jacobian_and_field(field: Any) -> tuple[Any, Any]:
    """Jitted ``(df/dx, f)`` of a field (compiled once per field)."""
    return jax.jit(jax.jacfwd(field)), jax.jit(field)


def expm_taylor(M: Array, n_squarings: int, order: int = 18) -> Array:
    """Matrix exponential by scaling and squaring with a Taylor polynomial.

    :math:`e^{M} = (T_K(M/2^s))^{2^s}` with :math:`T_K` the degree-``order`` Taylor
    polynomial (Horner form). With :math:`\\|M/2^s\\|_1 \\le 1/2` the truncation error is below
    :math:`2^{-19}/19! \\approx 10^{-23}`. A fixed, unrolled graph: it compiles (and
    differentiates) far faster than ``jax.scipy.linalg.expm``'s branchy Padé.
    """
    n = M.shape[0]
    X = M / (2.0**n_squarings)
    eye = jnp.eye(n, dtype=M.dtype)
    E = eye
    for k in range(order, 0, -1):
        E = eye + (X @ E) / k
    for _ in range(n_squarings):
        E = E @ E
    return E


def n_squarings_for(M: np.ndarray) -> int:
    """Number of squarings ``s`` so that ``||M / 2^s||_1 <= 1/4`` (margin for parameter changes)."""
    norm = float(np.linalg.norm(np.asarray(M), 1))
    return max(0, math.ceil(math.log2(max(norm, 1e-300) / 0.25)))


def discrete_outputs(A_d: Array, C: Array, z0: Array, n_samples: int) -> Array:
    """Outputs :math:`C A_d^k z_0`, ``k = 0 .. n_samples-1`` (eq. 4.7), ``(n_samples, n_out)``."""

    def step(z, _):
        return A_d @ z, C @ z

    _, ys = jax.lax.scan(step, z0, None, length=n_samples)
    return ys


@functools.lru_cache(maxsize=32)
def output_error_kernels(
    field: Any,
    n_states: int,
    out_idx: tuple[int, ...],
    free_idx: tuple[int, ...],
    log_mask: tuple[bool, ...],
    ratio_pairs: tuple[tuple[int, int], ...],
    z0_idx: tuple[int, ...],
    fit_offset: bool,
    n_sq: int,
):
    """Jitted residual/Jacobian of the weighted output error for one model structure."""
    n_free = len(free_idx)
    n_z0 = len(z0_idx)
    n_out = len(out_idx)
    C = jnp.zeros((n_out, n_states)).at[jnp.arange(n_out), jnp.asarray(out_idx)].set(1.0)
    free_arr = jnp.asarray(free_idx, dtype=jnp.int32)
    logm = jnp.asarray(log_mask)

    def unpack(theta, p_base, z_base, ratio_base):
        phi = theta[:n_free]
        values = jnp.where(logm, jnp.exp(phi), phi)
        p = p_base.at[free_arr].set(values) if n_free else p_base
        for k, (dep, src) in enumerate(ratio_pairs):
            p = p.at[dep].set(ratio_base[k] * p[src])
        z0 = z_base
        if n_z0:
            z0 = z0.at[jnp.asarray(z0_idx)].set(theta[n_free : n_free + n_z0])
        off = theta[n_free + n_z0 :] if fit_offset else jnp.zeros(n_out)
        return p, z0, off

    def predict(theta, p_base, z_base, ratio_base, x_eq, dt, n_samples):
        p, z0, off = unpack(theta, p_base, z_base, ratio_base)
        A = jax.jacfwd(field)(x_eq, p)
        A_d = expm_taylor(A * dt, n_sq)
        return discrete_outputs(A_d, C, z0, n_samples) + off

    @functools.partial(jax.jit, static_argnums=(6,))
    def residual(theta, p_base, z_base, ratio_base, x_eq, dt, n_samples, y, w):
        return ((y - predict(theta, p_base, z_base, ratio_base, x_eq, dt, n_samples)) * w).ravel()

    jac = jax.jit(jax.jacfwd(residual), static_argnums=(6,))
    pred = jax.jit(predict, static_argnums=(6,))
    return residual, jac, pred, C
