r"""Optimisation loops shared by the stages of the hybrid Hopf model (pure, jit/vmap-able).

:func:`minimise` runs ``n_adam`` Adam steps (:func:`optax.adam`, cosine-decayed rate) then
``n_lbfgs`` L-BFGS steps (:func:`optax.lbfgs` with a backtracking Armijo line search: its
default zoom line search is more thorough but several times slower to compile, which
dominates a fit of these small, smooth problems) on a scalar loss of a parameter pytree.

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

    (theta, _, saved), hist = jax.lax.scan(step, (theta0, opt.init(theta0), saved0), jnp.arange(n))
    return theta, saved, hist


def _lbfgs(fun, vg, theta0, saved0, n, memory, offset, stop_at, mask, limit, max_backtrack=20):
    """``n`` steps of :func:`optax.lbfgs` (backtracking Armijo line search), masked,
    stopping early (the remaining steps repeat the last point) at the traced ``limit``, when
    a line search finds no decrease, or at a zero gradient."""
    opt = optax.lbfgs(
        memory_size=memory,
        linesearch=optax.scale_by_backtracking_linesearch(max_backtracking_steps=max_backtrack),
    )

    def masked(x):
        (f, aux), g = vg(x)
        return (f, aux), g * mask

    (f0, aux0), g0 = masked(theta0)

    def iterate(carry):
        x, f, g, aux, state, k, saved, done = carry
        updates, new_state = opt.update(g, state, x, value=f, grad=g, value_fn=fun)
        x_new = optax.apply_updates(x, updates * mask)
        (f_new, aux_new), g_new = masked(x_new)
        accept = jnp.isfinite(f_new) & (f_new <= f) & jnp.all(jnp.isfinite(x_new))

        def pick(a, b):
            return jnp.where(accept, a, b)

        x, f, g = pick(x_new, x), pick(f_new, f), pick(g_new, g)
        aux = jax.tree_util.tree_map(pick, aux_new, aux)
        state = jax.tree_util.tree_map(pick, new_state, state)
        # no decrease at this precision, a stationary point or the budget: stop there
        done = ~accept | (jnp.max(jnp.abs(g)) == 0.0) | (k + 1 >= limit)
        return x, f, g, aux, state, k, saved, done

    def step(carry, _):
        carry = jax.lax.cond(carry[-1], lambda c: c, iterate, carry)
        x, f, g, aux, state, k, saved, done = carry
        saved = jnp.where(offset + k + 1 == stop_at, x, saved)
        return (x, f, g, aux, state, k + 1, saved, done), aux

    init = (theta0, f0, g0, aux0, opt.init(theta0), jnp.asarray(0), saved0, jnp.asarray(limit) <= 0)
    carry, hist = jax.lax.scan(step, init, None, length=n)
    return carry[0], carry[6], hist


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
    mask_flat = jnp.ones_like(flat0) if mask is None else ravel_pytree(mask)[0].astype(flat0.dtype)
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
            lambda z: flat_loss(z)[0],
            vg,
            x,
            saved,
            n_lbfgs,
            memory_size,
            n_adam,
            stop_at,
            mask_flat,
            limit,
        )
        chunks.append(hist)
    x = saved
    final = flat_loss(x)
    history = jnp.concatenate(chunks, axis=0) if chunks else final[1][None]
    return unravel(x), history, final
