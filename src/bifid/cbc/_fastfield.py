"""Checks that a compiled field is the system's field: the rig never silently changes the model.

The rig's numba loop evaluates a field translated from the system's JAX ``field``
(:mod:`bifid.cbc._codegen`). :func:`check_batched` compares the two on the origin and a
few seeded random states of a given size at the rig's parameters, whenever they change;
on any mismatch the rig falls back to its JAX engine.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from bifid.systems import System

__all__ = ["check_batched", "jax_vmap_field", "vmapped_field"]


@functools.lru_cache(maxsize=32)
def vmapped_field(field: Callable) -> Callable:
    """``field(x, p)`` vectorised over states (compiled once per field)."""
    return jax.jit(jax.vmap(field, in_axes=(0, None)))


def jax_vmap_field(system: System) -> Callable:
    """``system.field`` vectorised over states (compiled once per field)."""
    return vmapped_field(system.field)


def _probe_states(scale: np.ndarray) -> np.ndarray:
    """The origin and four seeded random states of size ``scale`` (what checks compare on)."""
    rng = np.random.default_rng(7)
    return np.vstack([np.zeros((1, len(scale))), rng.normal(size=(4, len(scale))) * scale])


def check_batched(
    system: System,
    batch: Callable[[np.ndarray], np.ndarray],
    p: np.ndarray,
    scale: np.ndarray,
    rtol: float = 1e-9,
) -> bool:
    """Does ``batch(xs)`` (a compiled field on each row of ``xs``) agree with
    ``system.field`` at ``p`` to ``rtol`` of the field's size?"""
    xs = _probe_states(scale)
    got = np.asarray(batch(xs))
    ref = np.asarray(vmapped_field(system.field)(jnp.asarray(xs), jnp.asarray(p)))
    finite = np.isfinite(ref)
    return bool(
        np.array_equal(finite, np.isfinite(got))
        and np.all(
            np.abs(got - ref)[finite] <= rtol * (1e-12 + np.max(np.abs(ref[finite]), initial=0.0))
        )
    )
