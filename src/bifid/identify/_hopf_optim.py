r"""Optimisation loops shared by the stages of the hybrid Hopf model (pure, jit/vmap-able).

:func:`minimise` runs ``n_adam`` Adam steps (optax, cosine-decayed rate) then ``n_lbfgs``
L-BFGS steps on a scalar loss of a parameter pytree. The L-BFGS here is a deliberately lean
one (two-loop recursion, memory ``m``, backtracking Armijo line search): optax's
``lbfgs`` with its zoom line search is correct but takes about a minute to compile under
``vmap`` on a 2-core machine, which matters more than line-search finesse for these small,
smooth problems.

The loss returns ``(value, aux)``; ``aux`` (e.g. the loss of every orbit) is recorded at every
iteration so that held-out errors can be read along the way and the stopping iteration chosen
by cross-validation. A step with a non-finite loss is rejected, so one bad trial cannot poison
a run inside a ``vmap`` over folds and seeds.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from jax.flatten_util import ravel_pytree

Array = jnp.ndarray


def _adam(vg, theta0, saved0, n, learning_rate, stop_at, mask):
    sched = optax.cosine_decay_schedule(learning_rate, n, alpha=0.05)
    opt = optax.adam(sched)

    def step(carry, k):
        th, st, saved = carry
        (value, aux), grad = vg(th)
        updates, st_new = opt.update(grad * mask, st, th)
        th_new = optax.apply_updates(th, updates)
        ok = jnp.isfinite(value) & jnp.all(jnp.isfinite(th_new))
        th = jnp.where(ok, th_new, th)
        st = jax.tree_util.tree_map(lambda a, b: jnp.where(ok, a, b), st_new, st)
        saved = jnp.where(k + 1 == stop_at, th, saved)
        return (th, st, saved), aux

    (theta, _, saved), hist = jax.lax.scan(
        step, (theta0, opt.init(theta0), saved0), jnp.arange(n)
    )
    return theta, saved, hist


def _two_loop(g, S, Y, rho, gamma):
    """L-BFGS direction :math:`-H g` from the pairs ``S, Y`` (rows; unused rows are zero)."""
    m = S.shape[0]

    def first(q, i):
        a = rho[i] * jnp.dot(S[i], q)
        return q - a * Y[i], a

    q, alphas = jax.lax.scan(first, g, jnp.arange(m - 1, -1, -1))
    alphas = alphas[::-1]
    r = gamma * q

    def second(r, i):
        b = rho[i] * jnp.dot(Y[i], r)
        return r + S[i] * (alphas[i] - b), None

    r, _ = jax.lax.scan(second, r, jnp.arange(m))
    return -r


def _lbfgs(fun, vg, theta0, saved0, n, memory, offset, stop_at, mask, limit,
           max_backtrack=20):
    d = theta0.shape[0]

    vg_raw = vg

    def vg(x):
        (f, aux), g = vg_raw(x)
        return (f, aux), g * mask

    (f0, aux0), g0 = vg(theta0)

    def iterate(carry):
        x, f, g, _, S, Y, rho, gamma, k, saved, npairs, done = carry
        direction = _two_loop(g, S, Y, rho, gamma)
        slope = jnp.dot(direction, g)
        bad = ~(slope < 0) | ~jnp.all(jnp.isfinite(direction))
        direction = jnp.where(bad, -g, direction)
        slope = jnp.where(bad, -jnp.dot(g, g), slope)
        # without curvature pairs the step is a plain gradient step: cap its largest
        # component at 0.1 (parameters are O(1)); otherwise the quasi-Newton step t = 1
        t0 = jnp.where(
            (npairs == 0) | bad, jnp.minimum(1.0, 0.1 / jnp.maximum(jnp.max(jnp.abs(direction)),
                                                                     1e-300)), 1.0
        )

        def cond(c):
            t, ft, j = c
            armijo = ft <= f + 1e-4 * t * slope
            return (j < max_backtrack) & ~(jnp.isfinite(ft) & armijo)

        def body(c):
            t, _, j = c
            t = 0.5 * t
            return t, fun(x + t * direction), j + 1

        # the first trial (t = t0) is the loop's first pass: one traced copy of the loss
        # instead of two (the compile time of these loops is most of a cold fit)
        t, ft, _ = jax.lax.while_loop(
            cond, body, (2.0 * t0, jnp.full_like(f, jnp.inf), jnp.asarray(-1))
        )
        accept = jnp.isfinite(ft) & (ft <= f + 1e-4 * t * slope)
        x_new = jnp.where(accept, x + t * direction, x)
        (f_new, aux_new), g_new = vg(x_new)
        s, y = x_new - x, g_new - g
        sy = jnp.dot(s, y)
        good = accept & (sy > 1e-12 * jnp.dot(y, y) + 1e-300)
        S = jnp.where(good, jnp.roll(S, -1, axis=0).at[-1].set(s), S)
        Y = jnp.where(good, jnp.roll(Y, -1, axis=0).at[-1].set(y), Y)
        rho = jnp.where(good, jnp.roll(rho, -1).at[-1].set(1.0 / jnp.where(good, sy, 1.0)), rho)
        gamma = jnp.where(good, sy / jnp.maximum(jnp.dot(y, y), 1e-300), gamma)
        npairs = npairs + good.astype(npairs.dtype)
        # a failed line search means no descent is possible at this precision: stop there
        done = ~accept | (jnp.max(jnp.abs(g_new)) == 0.0) | (k + 1 >= limit)
        return (x_new, f_new, g_new, aux_new, S, Y, rho, gamma, k, saved, npairs, done)

    def step(carry, _):
        carry = jax.lax.cond(carry[-1], lambda c: c, iterate, carry)
        x, f, g, aux, S, Y, rho, gamma, k, saved, npairs, done = carry
        saved = jnp.where(offset + k + 1 == stop_at, x, saved)
        carry = (x, f, g, aux, S, Y, rho, gamma, k + 1, saved, npairs, done)
        return carry, aux

    init = (
        theta0, f0, g0, aux0,
        jnp.zeros((memory, d)), jnp.zeros((memory, d)), jnp.zeros(memory), jnp.asarray(1.0),
        jnp.asarray(0), saved0, jnp.asarray(0), jnp.asarray(limit) <= 0,
    )
    carry, hist = jax.lax.scan(step, init, None, length=n)
    return carry[0], carry[9], hist


def minimise(
    loss: Callable,
    theta0,
    *,
    n_adam: int,
    n_lbfgs: int,
    learning_rate: float,
    memory_size: int = 10,
    stop_at: Array | int | None = None,
    mask=None,
    lbfgs_limit: Array | int | None = None,
):
    """Minimise ``loss(theta) -> (value, aux)``: Adam then L-BFGS.

    Parameters
    ----------
    loss : callable
        Returns the scalar loss and an auxiliary array recorded each iteration.
    theta0 : pytree
    n_adam, n_lbfgs : int
        Iteration counts (static).
    learning_rate : float
        Peak Adam learning rate.
    memory_size : int
        L-BFGS memory.
    stop_at : int or traced int, optional
        Return the parameters after this many iterations (early stopping chosen at run time
        without recompiling; 0 returns ``theta0``). Default: all iterations.
    mask : pytree like ``theta0`` of 0/1, optional
        Only parameters with mask 1 move (the gradient is multiplied by the mask), so stages
        that train different parts can share one compiled loop.
    lbfgs_limit : int or traced int, optional
        L-BFGS stops after this many iterations (``<= n_lbfgs``; traced, so one compiled
        loop serves different budgets). L-BFGS also stops when a line search fails.

    Returns
    -------
    theta : pytree
        Parameters after ``stop_at`` iterations.
    history : array of shape (n_adam + n_lbfgs, *aux_shape)
        ``aux`` at the point where each iteration starts (Adam) or ends (L-BFGS).
    final : (value, aux) at ``theta``
    """
    flat0, unravel = ravel_pytree(theta0)
    mask_flat = (
        jnp.ones_like(flat0) if mask is None else ravel_pytree(mask)[0].astype(flat0.dtype)
    )
    limit = n_lbfgs if lbfgs_limit is None else lbfgs_limit

    def flat_loss(x):
        return loss(unravel(x))

    vg = jax.value_and_grad(flat_loss, has_aux=True)
    total = n_adam + n_lbfgs
    stop_at = jnp.asarray(total if stop_at is None else stop_at)
    stop_at = jnp.clip(stop_at, 0, total)
    x = flat0
    saved = flat0
    chunks = []
    if n_adam > 0:
        x, saved, hist = _adam(vg, x, saved, n_adam, learning_rate, stop_at, mask_flat)
        chunks.append(hist)
    if n_lbfgs > 0:
        x, saved, hist = _lbfgs(
            lambda z: flat_loss(z)[0], vg, x, saved, n_lbfgs, memory_size, n_adam, stop_at,
            mask_flat, limit,
        )
        chunks.append(hist)
    x = saved
    final = flat_loss(x)
    history = jnp.concatenate(chunks, axis=0) if chunks else final[1][None]
    return unravel(x), history, final
