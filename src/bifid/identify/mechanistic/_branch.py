"""The model's periodic-orbit branch born at its Hopf point, and its Hopf summary."""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.continuation import Branch, ContinuationOptions, hopf_orbits, locate_hopf
from bifid.errors import ConvergenceWarning
from bifid.identify.mechanistic._normal_form import HopfNormalForm
from bifid.systems import System

TWO_PI = 2.0 * math.pi

__all__ = [
    "INTERNAL_STABILITY",
    "collapse_index",
    "data_branch",
    "data_range",
    "hopf_summary",
    "model_branch",
    "orbit_options",
]

#: where the multipliers of the identification's own branches come from (never shown to a
#: user; see :func:`model_branch`)
INTERNAL_STABILITY = "collocation"


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


def data_branch(
    system: System, p: np.ndarray, param: str, measured: np.ndarray, *, n_mesh: int, guess: float
) -> Branch:
    """The identification's own orbit branch over the window of the measured LCOs at
    ``measured`` (:func:`data_range`; multipliers from :data:`INTERNAL_STABILITY`)."""
    return model_branch(
        system,
        p,
        param,
        n_mesh=n_mesh,
        guess=guess,
        param_range=data_range(measured),
        stability=INTERNAL_STABILITY,
    )


def collapse_index(branch: Branch, n_states: int) -> int | None:
    """Index of the first orbit of ``branch`` that has collapsed onto the equilibrium.

    A constant solves the collocation equations at any parameter and period, so a
    continuation step that overshoots a cycle fold can land on it; the branch then runs on
    along the equilibrium. An orbit is collapsed when its size ``max_s ptp_t x_s(t)`` is
    below ``1e-3`` of the largest size before it (None: no collapse).
    """
    M = int(branch.meta.get("n_mesh", 0))
    sols = np.asarray(branch.solutions)
    if M <= 0 or sols.shape[0] < 2:
        return None
    size = np.ptp(sols[:, : M * n_states].reshape(-1, M, n_states), axis=1).max(axis=1)
    peak = np.maximum.accumulate(size)
    bad = np.flatnonzero((size[1:] < 1e-3 * peak[:-1]) & (peak[:-1] > 0))
    return int(bad[0]) + 1 if bad.size else None


def model_branch(
    system: System,
    p: np.ndarray,
    param: str,
    *,
    n_mesh: int = 32,
    guess: float | None = None,
    param_range: tuple[float, float] = (-math.inf, math.inf),
    max_steps: int = 400,
    stability: str = "integrated",
) -> Branch:
    """The model's periodic-orbit branch from its Hopf point (:func:`hopf_orbits`).

    The Hopf point is located by :func:`bifid.continuation.locate_hopf` from ``guess``
    (default: the current parameter value), so no equilibrium continuation is needed. The
    mesh stays at ``n_mesh`` (the resolution the identification works at). A branch whose
    orbits collapse onto the equilibrium (a step past a cycle fold, :func:`collapse_index`)
    is continued again with at most 0.4 times the step; if it still collapses it is returned
    with a :class:`~bifid.errors.ConvergenceWarning` (its orbits up to the collapse are
    valid).

    ``stability`` is passed to :func:`hopf_orbits`: the identification's own branches
    (matching measured LCOs, the data homotopy, the stage summaries, the covariance) use
    ``"collocation"`` — multipliers from the collocation operator, nothing to compile —
    and every branch a user is shown keeps the default ``"integrated"``. The special
    points are verified before they are reported with either.
    """
    idx = system.index(param)
    lam0 = float(p[idx]) if guess is None else float(guess)
    sp = locate_hopf(system, param, np.zeros(system.n_states), lam0, jnp.asarray(p))
    lo, hi = param_range
    opts = orbit_options(min(lo, sp.param - 1e-6), max(hi, sp.param + 1e-6), max_steps)
    for _ in range(2):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            branch = hopf_orbits(
                system,
                sp,
                p=jnp.asarray(p),
                n_mesh=n_mesh,
                options=opts,
                adapt=False,
                resolution_tol=0.5,
                stability=stability,
            )
        k = collapse_index(branch, system.n_states)
        if k is None:
            return branch
        opts = dataclasses.replace(opts, ds_max=opts.ds_max / 2.5, max_steps=3 * max_steps)
    warnings.warn(
        f"the periodic orbits born at the Hopf point ({param} = {sp.param:.6g}) collapse onto "
        f"the equilibrium at {param} = {float(branch.params[k]):.6g}; the branch is valid "
        "only before that point.",
        ConvergenceWarning,
        stacklevel=2,
    )
    return branch


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
