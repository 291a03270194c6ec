"""Ground truth for CBC: the uncontrolled system's orbit at exactly the measured parameter.

CBC measures an orbit of the *uncontrolled* system when the control is non-invasive. The
check is Newton's method on the collocation equations of the uncontrolled system
(:func:`bifid.continuation.orbit_problem`) at the measured parameter value, started
from any nearby orbit (a continuation branch point, or the virtual rig's true states):
the corrected orbit does not depend on the start, so it is an independent reference.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError, ConvergenceError
from bifid.signal import fourier_project, max_abs
from bifid.systems import System

__all__ = ["centred_amplitudes", "correct_orbit", "orbit_from_samples"]


def orbit_from_samples(states: np.ndarray, omega: float, sample_rate: float,
                       n_mesh: int = 64, n_harmonics: int = 15) -> np.ndarray:
    """One period of a sampled periodic state trajectory on ``n_mesh`` equispaced points.

    Least-squares Fourier series at ``omega`` of each state over the whole record.
    """
    states = np.asarray(states, dtype=float)
    theta = omega * np.arange(states.shape[0]) / sample_rate
    c = fourier_project(states, theta, n_harmonics)
    tau = 2.0 * np.pi * np.arange(n_mesh) / n_mesh
    k = np.arange(1, n_harmonics + 1)
    B = np.hstack([np.ones((n_mesh, 1)), np.cos(np.outer(tau, k)), np.sin(np.outer(tau, k))])
    return B @ c


def correct_orbit(system: System, param: str, value: float, orbit: np.ndarray, period: float,
                  p: Sequence[float] | None = None, n_mesh: int = 64, tol: float = 1e-11
                  ) -> tuple[np.ndarray, float]:
    """Newton-correct an approximate orbit of the uncontrolled ``system`` at ``param=value``.

    Parameters
    ----------
    orbit : array of shape (M, n)
        Approximate orbit over one period on an equispaced grid.
    period : float
        Approximate period.

    Returns
    -------
    orbit : ndarray of shape (n_mesh, n)
    period : float

    Raises
    ------
    ConvergenceError
        If Newton's method does not converge.
    """
    from bifid.continuation import correct, fourier_differentiation_matrix, orbit_problem

    V = np.asarray(orbit, dtype=float)
    if V.ndim != 2 or V.shape[1] != system.n_states:
        raise BifidInputError(f"orbit must have shape (M, {system.n_states}), got {V.shape}.")
    M0 = V.shape[0]
    c = np.fft.rfft(V, axis=0)
    V = np.fft.irfft(c[: n_mesh // 2 + 1], n=n_mesh, axis=0) * (n_mesh / M0)
    n = system.n_states
    problem = orbit_problem(system.field, n_mesh, n)
    D = fourier_differentiation_matrix(n_mesh)
    pv = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    idx = system.index(param)
    pv = pv.at[idx].set(value)
    args = {"p": pv, "idx": jnp.asarray(idx), "dref": jnp.asarray((D @ V).ravel())}
    y0 = np.concatenate([V.ravel(), [period, value]])
    e = np.zeros_like(y0)
    e[-1] = 1.0
    y, ok, _, res = correct(problem, y0, e, value, args, tol=tol, max_iter=40)
    if not ok:
        raise ConvergenceError(
            f"Newton did not converge on the orbit of {system.name!r} at {param}={value:g} "
            f"(residual {res:.1e})."
        )
    return np.asarray(y[: n_mesh * n]).reshape(n_mesh, n), float(y[n_mesh * n])


def centred_amplitudes(orbit: np.ndarray) -> np.ndarray:
    """``max_t |x_s(t) - x̄_s|`` per state of a periodic orbit on an equispaced mesh."""

    V = np.asarray(orbit, dtype=float)
    return np.atleast_1d(max_abs(V - V.mean(axis=0)))


def forced_orbit_from_samples(states: np.ndarray, phase: np.ndarray, psi: float,
                              n_mesh: int = 64, n_harmonics: int = 15) -> np.ndarray:
    """One forcing period of sampled states on ``τ_k = 2πk/M`` in the *system's* phase.

    The rig's force is ``γ cos(θ - ψ)`` and the system's ``F cos τ``: ``τ = θ - ψ``.
    """
    c = fourier_project(np.asarray(states, dtype=float), np.asarray(phase) - psi, n_harmonics)
    tau = 2.0 * np.pi * np.arange(n_mesh) / n_mesh
    k = np.arange(1, n_harmonics + 1)
    B = np.hstack([np.ones((n_mesh, 1)), np.cos(np.outer(tau, k)), np.sin(np.outer(tau, k))])
    return B @ c


def correct_forced(system: System, omega: float, forcing: float, orbit: np.ndarray,
                   p: Sequence[float] | None = None, n_mesh: int = 64, tol: float = 1e-11
                   ) -> np.ndarray:
    """Newton-correct a forced response of ``system`` at ``(F, Ω) = (forcing, omega)``.

    ``orbit`` (M, n) is a guess on ``τ_k = 2πk/M`` with the force ``F cos τ``.

    Raises
    ------
    ConvergenceError
        If Newton's method does not converge.
    """
    from bifid.continuation import correct, forced_problem

    V = np.asarray(orbit, dtype=float)
    M0 = V.shape[0]
    c = np.fft.rfft(V, axis=0)
    V = np.fft.irfft(c[: n_mesh // 2 + 1], n=n_mesh, axis=0) * (n_mesh / M0)
    n = system.n_states
    problem = forced_problem(system, n_mesh, 1)
    pv = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    iF, iOm = system.index("F"), system.index("Omega")
    pv = pv.at[iOm].set(omega).at[iF].set(forcing)
    args = {"p": pv, "idx": jnp.asarray([iF]),
            "obs": jnp.asarray(system.state_index(system.observed))}
    y0 = np.concatenate([V.ravel(), [forcing]])
    e = np.zeros_like(y0)
    e[-1] = 1.0
    y, ok, _, res = correct(problem, y0, e, forcing, args, tol=tol, max_iter=40)
    if not ok:
        raise ConvergenceError(
            f"Newton did not converge on the forced response of {system.name!r} at "
            f"F={forcing:g}, Omega={omega:g} (residual {res:.1e})."
        )
    return np.asarray(y[: n_mesh * n]).reshape(n_mesh, n)
