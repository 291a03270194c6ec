"""Floquet multipliers from the monodromy matrix of the variational equation.

For a periodic orbit ``x_s(t)`` of period ``T`` (thesis eq. 3.26)

.. math:: \\dot\\Phi = \\partial_x f(x_s(t), t, p)\\,\\Phi,\\qquad \\Phi(0) = I,

and the multipliers are the eigenvalues of ``Phi(T)``. The orbit is evaluated from the
trigonometric interpolant of its collocation values, and the variational equation is
integrated with diffrax's 8th-order Dormand–Prince (fixed step); all points of a
branch are done in one ``vmap``-ed, compiled call.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from bifid.signal import fourier_coefficients

Array = jnp.ndarray


@functools.lru_cache(maxsize=32)
def _monodromy_fn(rhs: Callable, n_harm: int, n_steps: int) -> Callable:
    k = jnp.arange(1, n_harm + 1, dtype=jnp.float64)

    def one(a0, a, b, T, p):
        n = a0.shape[0]

        def x_of(t):
            tau = 2.0 * jnp.pi * t / T
            return a0 + jnp.cos(k * tau) @ a + jnp.sin(k * tau) @ b

        def vf(t, phi, args):
            J = jax.jacfwd(rhs, argnums=0)(x_of(t), t, p)
            return J @ phi

        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(vf),
            diffrax.Dopri8(),
            t0=0.0,
            t1=T,
            dt0=T / n_steps,
            y0=jnp.eye(n),
            stepsize_controller=diffrax.ConstantStepSize(),
            max_steps=n_steps + 2,
            throw=False,
        )
        return sol.ys[-1], sol.result == diffrax.RESULTS.successful

    return jax.jit(jax.vmap(one))


@functools.lru_cache(maxsize=64)
def autonomous_rhs(field: Callable) -> Callable:
    """``(x, t, p) -> field(x, p)``, one stable object per field (keeps jit caches warm)."""

    def rhs(x, t, p):
        return field(x, p)

    return rhs


def monodromy(
    rhs: Callable,
    orbits: np.ndarray,
    periods: np.ndarray,
    ps: np.ndarray,
    *,
    steps_per_mesh: int = 4,
) -> tuple[np.ndarray, np.ndarray]:
    """Monodromy matrices of a batch of orbits.

    Parameters
    ----------
    rhs : callable ``(x, t, p) -> dx``
        Right-hand side (time enters for forced systems; the orbit starts at t = 0).
    orbits : array of shape (n_orbits, M, n)
        Collocation values on ``t_k = T k / M``.
    periods : array of shape (n_orbits,)
    ps : array of shape (n_orbits, n_params)
    steps_per_mesh : int
        Fixed 8th-order Dormand–Prince steps per collocation interval (4 gives
        multipliers accurate to ~1e-10 for the reference systems; the variational
        equation is linear, so a fixed step is as safe as an adaptive one and vectorises
        without divergent while-loops).

    Returns
    -------
    Phi : array of shape (n_orbits, n, n)
    ok : bool array of shape (n_orbits,)
    """
    orbits = np.asarray(orbits, dtype=float)
    a0, a, b = fourier_coefficients(np.moveaxis(orbits, 1, 0))  # (n_orb, n), (K, n_orb, n)
    a = np.moveaxis(a, 0, 1)
    b = np.moveaxis(b, 0, 1)
    fn = _monodromy_fn(rhs, a.shape[1], steps_per_mesh * orbits.shape[1])
    # pad the batch to a power of two (>= 8) by repeating the last orbit, so branches of
    # different lengths reuse a handful of compiled shapes instead of one each
    n_orb = orbits.shape[0]
    size = max(8, 1 << max(n_orb - 1, 0).bit_length())
    idx = np.minimum(np.arange(size), max(n_orb - 1, 0))
    periods = np.asarray(periods, dtype=float)
    ps = np.asarray(ps, dtype=float)
    Phi, ok = fn(jnp.asarray(a0[idx]), jnp.asarray(a[idx]), jnp.asarray(b[idx]),
                 jnp.asarray(periods[idx]), jnp.asarray(ps[idx]))
    return np.asarray(Phi)[:n_orb], np.asarray(ok)[:n_orb]


def floquet_multipliers(
    rhs: Callable,
    orbits: np.ndarray,
    periods: np.ndarray,
    ps: np.ndarray,
    *,
    autonomous: bool,
    steps_per_mesh: int = 4,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Floquet multipliers, stability and the largest non-trivial modulus.

    For autonomous orbits the trivial multiplier (closest to 1) is excluded from the
    stability decision. ``steps_per_mesh``: see :func:`monodromy` (raise it for stiff
    right-hand sides).

    Returns
    -------
    multipliers : complex array of shape (n_orbits, n), sorted by decreasing modulus
    stable : bool array of shape (n_orbits,)
    floquet_max : array of shape (n_orbits,)
        Largest modulus among the non-trivial multipliers.
    """
    Phi, ok = monodromy(rhs, orbits, periods, ps, steps_per_mesh=steps_per_mesh)
    mults = np.linalg.eigvals(Phi)
    order = np.argsort(-np.abs(mults), axis=1)
    mults = np.take_along_axis(mults, order, axis=1)
    fmax = np.empty(mults.shape[0])
    for i, m in enumerate(mults):
        if autonomous:
            j = int(np.argmin(np.abs(m - 1.0)))
            m = np.delete(m, j)
        fmax[i] = np.max(np.abs(m)) if m.size else 0.0
    fmax[~ok] = np.nan
    stable = fmax < 1.0
    return mults, stable, fmax
