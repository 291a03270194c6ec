"""Fields prepared for the rig loop: parameter-only work hoisted out of the time step.

The virtual rig evaluates the vector field four times per sample, millions of times per
run. A system's :attr:`~bifid.systems.System.field` recomputes everything from the
parameter vector each call -- for ``flutter`` that includes a 3x3 linear solve, which
XLA on CPU cannot hoist out of a loop (LAPACK custom calls), and which makes the rig ~25x
slower than real-time targets allow. A *prepared field* splits the work:

.. math:: c = \\mathrm{prepare}(p)\\ \\text{(once per block)},\\qquad
          \\dot x = \\mathrm{field}(x, c)\\ \\text{(in the loop)}.

The generic preparation is the identity (``c = p``, ``field = system.field``). Systems
with a faster equivalent register one here; :func:`prepared_field` checks it against
``system.field`` at the rig's parameters (:func:`check_prepared`) and the rig falls back
to the generic path on any mismatch, so a fast path can never silently change the model.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from bifid.systems import System, flutter_matrices

Array = jnp.ndarray

__all__ = ["PreparedField", "check_batched", "check_prepared", "jax_vmap_field",
           "prepared_field"]


@dataclass(frozen=True)
class PreparedField:
    """``field(x, prepare(p)) == system.field(x, p)``; both pure JAX, hashable."""

    name: str
    prepare: Callable[[Array], object]
    field: Callable[[Array, object], Array]


def _identity(p: Array) -> Array:
    return p


# ------------------------------------------------------------------------------ flutter
def _flutter_prepare(p: Array):
    # z' = A z + n(α):  A = [[0, I], [-M⁻¹K, -M⁻¹D]] in the interleaved order
    # (h, ḣ, α, α̇, w, ẇ);  n = -M⁻¹ [0, k_α2 α² + k_α3 α³, 0]  (thesis eq. A.1).
    M, D, K = flutter_matrices(p)
    Mi = jnp.linalg.inv(M)
    pos = jnp.array([0, 2, 4])
    vel = jnp.array([1, 3, 5])
    A = jnp.zeros((6, 6))
    A = A.at[pos, vel].set(1.0)
    A = A.at[jnp.ix_(vel, pos)].set(-Mi @ K)
    A = A.at[jnp.ix_(vel, vel)].set(-Mi @ D)
    col = jnp.zeros(6).at[vel].set(-Mi[:, 1])
    return A, col * p[10], col * p[11]


def _flutter_field(x: Array, c) -> Array:
    A, n2, n3 = c
    a = x[2]
    # elementwise mat-vec: fuses into one kernel (a dot_general per stage is ~3x slower here)
    return jnp.sum(A * x[None, :], axis=1) + (n2 + n3 * a) * (a * a)


_FAST: dict[str, PreparedField] = {
    "flutter": PreparedField("flutter", _flutter_prepare, _flutter_field),
}


def prepared_field(system: System) -> tuple[PreparedField, PreparedField]:
    """``(fast, generic)`` prepared fields of ``system`` (``fast is generic`` if none)."""
    generic = _generic(system)
    return _FAST.get(system.name, generic), generic


def _generic(system: System) -> PreparedField:
    # field(x, c) with c = p is the system's own field: equal (and hashing equal) across
    # get_system calls, so compiled rig loops are reused.
    return PreparedField(system.name, _identity, system.field)


@functools.lru_cache(maxsize=32)
def _discrepancy(field: Callable, prepared: PreparedField) -> Callable:
    """Compiled ``max |prepared(x) - field(x)| / scale`` over a batch of states."""

    def one(x, p, c):
        ref = field(x, p)
        got = prepared.field(x, c)
        return jnp.max(jnp.abs(got - ref)), jnp.max(jnp.abs(ref))

    @jax.jit
    def run(xs, p):
        c = prepared.prepare(p)
        err, size = jax.vmap(one, in_axes=(0, None, None))(xs, p, c)
        return jnp.max(err), jnp.max(size)

    return run


def _probe_states(scale: np.ndarray) -> np.ndarray:
    """The origin and four seeded random states of size ``scale`` (what checks compare on)."""
    rng = np.random.default_rng(7)
    return np.vstack([np.zeros((1, len(scale))), rng.normal(size=(4, len(scale))) * scale])


def check_prepared(
    system: System, prepared: PreparedField, p: Array, scale: np.ndarray, rtol: float = 1e-9
) -> bool:
    """Does ``prepared`` agree with ``system.field`` at ``p`` on a few random states?"""
    xs = _probe_states(scale)
    err, size = _discrepancy(system.field, prepared)(jnp.asarray(xs), jnp.asarray(p))
    return bool(err <= rtol * (1e-12 + float(size)))


@functools.lru_cache(maxsize=32)
def _vmapped(field: Callable) -> Callable:
    return jax.jit(jax.vmap(field, in_axes=(0, None)))


def jax_vmap_field(system: System) -> Callable:
    """``system.field`` vectorised over states (compiled once per field)."""
    return _vmapped(system.field)


def check_batched(
    system: System, batch: Callable[[np.ndarray], np.ndarray], p: np.ndarray,
    scale: np.ndarray, rtol: float = 1e-9,
) -> bool:
    """:func:`check_prepared` for a field outside JAX (e.g. the numba engine's):
    ``batch(xs)`` evaluates it on each row of ``xs``."""
    xs = _probe_states(scale)
    got = np.asarray(batch(xs))
    ref = np.asarray(jax_vmap_field(system)(jnp.asarray(xs), jnp.asarray(p)))
    return bool(np.all(np.isfinite(got))
                and np.max(np.abs(got - ref)) <= rtol * (1e-12 + np.max(np.abs(ref))))
