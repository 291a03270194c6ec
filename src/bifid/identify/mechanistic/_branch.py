"""The model's periodic-orbit branch born at its Hopf point, and its Hopf summary."""

from __future__ import annotations

import math
import warnings
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.continuation import Branch, ContinuationOptions, hopf_orbits, locate_hopf
from bifid.identify.mechanistic._normal_form import HopfNormalForm
from bifid.systems import System

TWO_PI = 2.0 * math.pi

__all__ = ["data_range", "hopf_summary", "model_branch", "orbit_options"]


def orbit_options(lo: float, hi: float, max_steps: int) -> ContinuationOptions:
    """Continuation options of the orbit branches of a mechanistic model in ``[lo, hi]``."""
    return ContinuationOptions(
        ds=1e-3, ds_max=0.25, ds_min=1e-9, p_min=lo, p_max=hi, max_steps=max_steps
    )


def data_range(param: np.ndarray) -> tuple[float, float]:
    """Parameter window of the branch used to match measured LCOs at ``param``."""
    lo, hi = float(np.min(param)), float(np.max(param))
    span = max(hi - lo, 1e-3 * max(abs(hi), 1.0))
    # generous below: a start model may fold well below the measured range
    return lo - 3.0 * span, hi + 0.5 * span


def model_branch(
    system: System,
    p: np.ndarray,
    param: str,
    *,
    n_mesh: int = 32,
    guess: float | None = None,
    param_range: tuple[float, float] = (-math.inf, math.inf),
    max_steps: int = 400,
) -> Branch:
    """The model's periodic-orbit branch from its Hopf point (:func:`hopf_orbits`).

    The Hopf point is located by :func:`bifid.continuation.locate_hopf` from ``guess``
    (default: the current parameter value), so no equilibrium continuation is needed. The
    mesh stays at ``n_mesh`` (the resolution the identification works at).
    """
    idx = system.index(param)
    lam0 = float(p[idx]) if guess is None else float(guess)
    sp = locate_hopf(system, param, np.zeros(system.n_states), lam0, jnp.asarray(p))
    lo, hi = param_range
    opts = orbit_options(min(lo, sp.param - 1e-6), max(hi, sp.param + 1e-6), max_steps)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return hopf_orbits(
            system,
            sp,
            p=jnp.asarray(p),
            n_mesh=n_mesh,
            options=opts,
            adapt=False,
            resolution_tol=0.5,
        )


def hopf_summary(nf: HopfNormalForm) -> dict[str, Any]:
    """The Hopf point of a normal form as reported by ``summary()``."""
    return {
        "param": nf.param_value,
        "omega": nf.omega,
        "frequency_hz": nf.omega / TWO_PI,
        "lyapunov": nf.l1,
        "criticality": nf.criticality,
        "alpha1": nf.alpha1,
        "alpha2": nf.alpha2,
    }
