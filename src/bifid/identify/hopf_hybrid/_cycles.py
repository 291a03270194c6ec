r"""The limit cycles of a fitted hybrid model (eq. 5.3 through the learnt maps).

Every function takes the fitted :class:`~._state.HybridState` and an ensemble member ``s``.
The cycles are the roots of :math:`\dot\rho/\rho = 0` (:mod:`._normal_form`), mapped to the
measured signals by :math:`\mathbf U_{12}` and the regression of the other signals, and
traversed at the learnt speed :math:`\dot\theta = \Omega` (eq. 5.10).
"""

from __future__ import annotations

import math
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError, ConvergenceError
from bifid.identify.hopf_hybrid._normal_form import growth_derivative, raw_a2
from bifid.identify.hopf_hybrid._speed import invert_phase, speed_on_grid_fn
from bifid.identify.hopf_hybrid._state import (
    HybridState,
    member,
    plane_angles,
    u12_batch,
    u12_cycles,
)

__all__ = [
    "amplitudes",
    "branch_samples",
    "cycle",
    "cycle_fold",
    "cycle_points",
    "cycle_radii",
    "hopf_point",
    "period",
    "radius2",
    "time_series",
]

N_CYCLE = 512  # phases per predicted cycle (amplitudes = max over them)


def radius2(state: HybridState, s: int, mu_t: float, root: float) -> float | None:
    """:math:`\\rho^2` of the cycle on ``root`` (+1 outer, -1 inner) at ``mu_t`` (None: none)."""
    mu0, a2 = state.mu0_t(s), state.a2(s)
    if state.q5:
        disc = a2**2 + 4 * (mu_t - mu0)
        if disc < 0:
            return None
        r2 = 0.5 * (a2 + root * math.sqrt(disc))
    else:
        r2 = -(mu_t - mu0) / a2
    return r2 if r2 > 0 else None


def speed_grid(state: HybridState, s: int, rho: np.ndarray, mu_t: np.ndarray) -> np.ndarray:
    """:math:`\\Omega` on 512 uniform phases for each ``(rho, mu_t)``, shape ``(n, 512)``."""
    return np.asarray(
        speed_on_grid_fn(state.speed_config)(
            member(state.speed_params, s),
            jnp.asarray(rho, dtype=float),
            jnp.asarray(mu_t, dtype=float),
            jnp.asarray(state.omega_scale),
        )
    )


def period(state: HybridState, s: int, rho: Any, mu_t: Any) -> np.ndarray:
    """:math:`T = \\int_0^{2\\pi} \\mathrm d\\theta/\\Omega` (NaN where :math:`\\Omega \\le 0`)."""
    v = speed_grid(state, s, np.atleast_1d(rho), np.atleast_1d(mu_t))
    with np.errstate(divide="ignore"):
        T = 2 * np.pi * np.mean(1.0 / v, axis=1)
    return np.where(np.min(v, axis=1) > 0, T, np.nan)


def cycle_points(
    state: HybridState, s: int, mu_t: float, rho: float, phi: np.ndarray
) -> np.ndarray:
    """All signals (data units) at normal-form phases ``phi`` of the cycle ``rho``."""
    u = rho * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    plane = u12_batch(member(state.map_params, s), state.map_config, u, mu_t)
    out = np.zeros((len(phi), len(state.signal_names)))
    out[:, list(state.plane)] = plane @ np.linalg.inv(state.white)
    if state.others:
        x = np.column_stack([u, np.full(len(phi), mu_t)])
        out[:, list(state.others)] = state.observation[s].predict(x)
    return out * state.z_scale[None, :]


def amplitudes(state: HybridState, s: int, mu_t: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """``max_t |z_k|`` of every signal on the cycles ``(mu_t, rho)``, shape (n, m)."""
    mu_t, rho = np.atleast_1d(np.asarray(mu_t, float)), np.atleast_1d(np.asarray(rho, float))
    phi = np.linspace(0, 2 * np.pi, N_CYCLE, endpoint=False)
    out = np.zeros((len(rho), len(state.signal_names)))
    if not len(rho):
        return out
    unit = np.stack([np.cos(phi), np.sin(phi)], axis=1)
    # padded to a power of two: one compiled program serves many branch lengths
    n = len(rho)
    pad = max(8, 1 << (n - 1).bit_length()) - n
    r_pad, m_pad = np.pad(rho, (0, pad), mode="edge"), np.pad(mu_t, (0, pad), mode="edge")
    mp = member(state.map_params, s)
    plane = u12_cycles(mp, state.map_config, r_pad[:, None, None] * unit, m_pad)[:n]
    scale = state.z_scale[list(state.plane)]
    out[:, list(state.plane)] = np.max(np.abs(plane @ np.linalg.inv(state.white)), axis=1) * scale
    for j, (m, r) in enumerate(zip(mu_t, rho, strict=True)) if state.others else ():
        x = np.column_stack([r * unit, np.full(len(phi), m)])
        z = state.observation[s].predict(x) * state.z_scale[list(state.others)]
        out[j, list(state.others)] = np.max(np.abs(z), axis=0)
    return out


def cycle_radii(state: HybridState, s: int, mu_t: np.ndarray, stable: np.ndarray) -> np.ndarray:
    r"""Radii :math:`\rho` of the cycles of the given stability at ``mu_t`` (NaN: none)."""
    mu_t, stable = np.asarray(mu_t, dtype=float), np.asarray(stable, dtype=bool)
    mu0, a2, q5 = state.mu0_t(s), state.a2(s), state.q5
    rho2 = np.full(mu_t.shape, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        for root in (1.0, -1.0) if q5 else (1.0,):
            r2 = 0.5 * (a2 + root * np.sqrt(a2**2 + 4 * (mu_t - mu0))) if q5 else -(mu_t - mu0) / a2
            ok = (r2 > 0) & ((growth_derivative(r2, mu_t, mu0, a2, q5) < 0) == stable)
            rho2 = np.where(np.isnan(rho2) & ok, r2, rho2)
    return np.sqrt(rho2)


def hopf_point(state: HybridState, s: int) -> dict[str, Any]:
    """The Hopf point of member ``s``: ``param``, ``omega`` (rad/s, :math:`2\\pi/T` at
    :math:`\\rho \\to 0`), ``lyapunov`` (:math:`a_2` in raw units: its sign gives the
    criticality), ``criticality``, and ``state`` (the signals at the equilibrium)."""
    mu0_t = state.mu0_t(s)
    T = period(state, s, 0.0, mu0_t)[0]
    a2 = raw_a2(state.a2(s), state.mu_s, state.q5)
    return {
        "param": float(state.raw(mu0_t)),
        "omega": 2 * math.pi / T,
        "lyapunov": a2,
        "criticality": "subcritical" if a2 > 0 else "supercritical",
        "state": cycle_points(state, s, mu0_t, 0.0, np.zeros(1))[0],
    }


def cycle_fold(state: HybridState, s: int) -> dict[str, Any] | None:
    """The fold of cycles :math:`\\mu_0 - a_2^2/4` of member ``s`` (None if it has none)."""
    a2 = state.a2(s)
    if not state.q5 or a2 <= 0:
        return None
    mu_t = state.mu0_t(s) - a2**2 / 4
    rho = math.sqrt(a2 / 2)
    return {
        "param": float(state.raw(mu_t)),
        "period": float(period(state, s, rho, mu_t)[0]),
        "amplitude": amplitudes(state, s, np.array([mu_t]), np.array([rho]))[0],
        "rho": rho,
    }


def branch_samples(
    state: HybridState, s: int, lo_t: float, hi_t: float, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points ``(mu_t, rho, d rho_dot / d rho)`` along the cycle branch within ``[lo, hi]``.

    The branch is the graph :math:`\\tilde\\mu(\\rho) = \\tilde\\mu_0 - a_2\\rho^2 +
    q_5\\rho^4`, sampled uniformly in :math:`\\rho` so the fold is passed smoothly.
    """
    mu0, a2, q5 = state.mu0_t(s), state.a2(s), state.q5
    # largest radius with mu(rho) <= hi (the outer branch rises with rho beyond the fold)
    if q5:
        disc = a2**2 + 4 * (hi_t - mu0)
        r2_hi = (a2 + math.sqrt(disc)) / 2 if disc >= 0 else 0.0
    else:
        r2_hi = max(-(hi_t - mu0) / a2, 0.0)
    rho = np.linspace(0.0, math.sqrt(max(r2_hi, 0.0)), n)[1:]
    mu = mu0 - a2 * rho**2 + q5 * rho**4
    keep = (mu >= lo_t - 1e-12) & (mu <= hi_t + 1e-12)
    rho, mu = rho[keep], mu[keep]
    return mu, rho, growth_derivative(rho**2, mu, mu0, a2, q5)


def cycle(state: HybridState, s: int, param: float, stable: bool) -> tuple[float, float]:
    """``(mu_t, rho)`` of the stable or unstable cycle at ``param``.

    Raises
    ------
    BifidInputError
        Where member ``s`` has no such cycle.
    """
    if not math.isfinite(float(param)):
        raise BifidInputError(f"param must be finite, got {param!r}.")
    mu_t = float(state.mu_t(param))
    for root in (1.0, -1.0) if state.q5 else (1.0,):
        r2 = radius2(state, s, mu_t, root)
        if r2 is not None and (
            growth_derivative(r2, mu_t, state.mu0_t(s), state.a2(s), state.q5) < 0
        ) == bool(stable):
            return mu_t, math.sqrt(r2)
    fold = cycle_fold(state, s)
    raise BifidInputError(
        f"The model has no {'stable' if stable else 'unstable'} limit cycle at "
        f"{state.param_name}={param:g} (Hopf point {hopf_point(state, s)['param']:.4g}"
        + (f", fold {fold['param']:.4g}" if fold else "")
        + ")."
    )


def _phase_of_time(
    state: HybridState, s: int, mu_t: float, rho: float, times: np.ndarray, theta0: float
) -> np.ndarray:
    """:math:`\\theta(t)` of the phase equation, exactly by inverting
    :math:`t(\\theta) = \\int \\mathrm d\\theta/\\Omega` on a fine grid (no ODE solve)."""
    speed = speed_grid(state, s, np.array([rho]), np.array([mu_t]))[0]
    if np.any(speed <= 0):
        raise ConvergenceError(
            "The learnt oscillation speed vanishes on this cycle; the model cannot produce a "
            "time series here."
        )
    grid = np.linspace(0, 2 * np.pi, len(speed) + 1)
    inv = 1.0 / np.concatenate([speed, speed[:1]])
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(grid))])
    T = cum[-1]
    tau = np.interp(np.mod(theta0, 2 * np.pi), grid, cum) + (np.asarray(times) - times[0])
    k = np.floor(tau / T)
    return np.interp(tau - k * T, cum, grid) + 2 * np.pi * k


def time_series(
    state: HybridState,
    s: int,
    mu_t: float,
    rho: float,
    times: np.ndarray,
    initial: np.ndarray | None = None,
    initial_phase: float = 0.0,
) -> np.ndarray:
    """Every signal on the cycle ``(mu_t, rho)`` at ``times``, shape ``(len(times), m)``.

    ``initial`` (a measured sample at ``times[0]``) fixes the initial phase by its polar
    angle in the plane (eq. 5.12); otherwise ``initial_phase`` (normal-form phase) does.
    """
    th0 = float(initial_phase)
    if initial is not None:
        z0 = np.asarray(initial, dtype=float) / state.z_scale
        ring = np.linspace(0, 2 * np.pi, 256, endpoint=False)
        centre = np.mean(
            u12_batch(
                member(state.map_params, s),
                state.map_config,
                rho * np.stack([np.cos(ring), np.sin(ring)], 1),
                mu_t,
            ),
            0,
        )
        phi, ang = plane_angles(member(state.map_params, s), state.map_config, mu_t, rho, centre)
        d = z0[list(state.plane)] @ state.white - centre
        th0 = float(invert_phase(phi, ang, np.array([math.atan2(d[1], d[0])]))[0][0])
    return cycle_points(state, s, mu_t, rho, _phase_of_time(state, s, mu_t, rho, times, th0))
