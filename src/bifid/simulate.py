"""Time integration of a :class:`~bifid.systems.System` with diffrax.

One compiled solver per (system, solver settings, output grid length) is cached, so
repeated simulations of the same system do not re-trace.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError, ConvergenceError
from bifid.systems import System

Array = jnp.ndarray


@functools.lru_cache(maxsize=64)
def _solver(rhs: Callable, rtol: float, atol: float, max_steps: int) -> Callable:
    import diffrax  # here: importing it costs 1-2 s that commands without simulation skip

    term = diffrax.ODETerm(lambda t, y, args: rhs(y, t, args))

    @jax.jit
    def solve(x0: Array, ts: Array, p: Array):
        sol = diffrax.diffeqsolve(
            term,
            diffrax.Dopri8(),
            t0=ts[0],
            t1=ts[-1],
            dt0=None,
            y0=x0,
            args=p,
            saveat=diffrax.SaveAt(ts=ts),
            stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
            max_steps=max_steps,
            throw=False,
        )
        return sol.ys, sol.result == diffrax.RESULTS.successful

    return solve


def simulate(
    system: System,
    x0: Array,
    ts: Array,
    p: Array | None = None,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-12,
    max_steps: int = 1_000_000,
) -> np.ndarray:
    """Integrate ``system`` from ``x0`` and return the states at times ``ts``.

    Parameters
    ----------
    system : System
        The system (its full right-hand side, forcing included).
    x0 : array of shape (n_states,)
        Initial state at ``ts[0]``.
    ts : array of shape (n_times,)
        Increasing output times.
    p : array of shape (n_params,), optional
        Parameter vector; defaults to ``system.param_vector()``.
    rtol, atol : float
        Tolerances of the adaptive 8th-order Dormand–Prince solver.

    Returns
    -------
    ndarray of shape (n_times, n_states)

    Raises
    ------
    BifidInputError
        On non-finite or mis-shaped input.
    ConvergenceError
        If the solver fails (step budget, blow-up).
    """
    x0 = jnp.asarray(x0, dtype=jnp.float64)
    ts = jnp.asarray(ts, dtype=jnp.float64)
    if x0.shape != (system.n_states,):
        raise BifidInputError(f"x0 must have shape ({system.n_states},), got {x0.shape}.")
    if ts.ndim != 1 or ts.shape[0] < 2 or not bool(jnp.all(jnp.diff(ts) > 0)):
        raise BifidInputError("ts must be a 1-D increasing array of at least two times.")
    if not (bool(jnp.all(jnp.isfinite(x0))) and bool(jnp.all(jnp.isfinite(ts)))):
        raise BifidInputError("x0 and ts must be finite.")
    p = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    ys, ok = _solver(system.rhs, rtol, atol, max_steps)(x0, ts, p)
    ys = np.asarray(ys)
    if not bool(ok) or not np.all(np.isfinite(ys)):
        raise ConvergenceError(
            f"Integration of {system.name!r} failed (step budget {max_steps} or blow-up); "
            "try a shorter span, looser tolerances or a larger max_steps."
        )
    return ys
