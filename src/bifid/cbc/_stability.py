"""Stability of measured orbits, and the Floquet multipliers of the *controlled* system.

Two questions, two tools:

1. **Is the measured orbit stable without control?** Answered as an experimentalist does
   (thesis §3.3.3.3, Fig. 3.18): after convergence, nudge the orbit (a slightly larger
   target for a few periods), switch the controller off and watch. If the deviation from
   the converged amplitude decays the orbit is stable; if it grows (the response leaves
   towards the equilibrium or another attractor) it is unstable.
   :func:`switch_off_test`.
2. **Does a controller stabilise an orbit?** The controlled system ``ẋ = f(x) + e u(x)``
   with the non-invasive target expressed as a function of the state is itself a
   System-like vector field (autonomous for PP-CBC); its Floquet multipliers at the
   orbit must lie inside the unit circle, apart from the trivial one (thesis Fig. 3.9,
   eq. 3.26). :func:`controlled_floquet` computes them with
   :func:`bifid.continuation.floquet_multipliers`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np

from bifid.cbc._controllers import AbstractTarget, PDController, PolarTarget
from bifid.cbc._fastfield import jax_vmap_field
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.errors import BifidInputError
from bifid.signal import polar_project
from bifid.systems import System

__all__ = [
    "StabilityResult",
    "controlled_floquet",
    "controlled_rhs",
    "orbit_polar_target",
    "period_amplitudes",
    "switch_off_test",
]


# ------------------------------------------------------------------------ switch-off test
@dataclass
class StabilityResult:
    """Outcome of a switch-off test.

    Attributes
    ----------
    stable : bool or None
        None when the test could not decide (deviation neither grew nor decayed beyond
        noise).
    growth : float
        Estimated growth factor of the amplitude deviation per period (≈ the dominant
        non-trivial Floquet multiplier's modulus).
    deviations : ndarray
        Relative amplitude deviation per period after switch-off.
    """

    stable: bool | None
    growth: float
    deviations: np.ndarray = field(default_factory=lambda: np.zeros(0))


def period_amplitudes(x: np.ndarray, omega: float, sample_rate: float) -> np.ndarray:
    """First-harmonic amplitude of ``x`` over each successive whole period.

    Least-squares fit of ``c + a cos ωt + b sin ωt`` per period (robust to noise).
    """
    x = np.asarray(x, dtype=float)
    per = 2.0 * math.pi / omega * sample_rate
    m = int(x.shape[0] // per)
    out = np.empty(m)
    for j in range(m):
        lo, hi = round(j * per), round((j + 1) * per)
        t = np.arange(hi - lo) / sample_rate
        B = np.stack([np.ones_like(t), np.cos(omega * t), np.sin(omega * t)], axis=1)
        coef, *_ = np.linalg.lstsq(B, x[lo:hi], rcond=None)
        out[j] = math.hypot(coef[1], coef[2])
    return out


def switch_off_test(
    rig: AbstractRig,
    signal: str,
    amplitude: float,
    omega: float,
    *,
    controller: PDController,
    nudged_target: AbstractTarget,
    restore_target: AbstractTarget | None,
    nudge_periods: float = 3.0,
    watch_periods: float = 15.0,
    threshold: float = 1.5,
    escape: float = 0.25,
) -> tuple[StabilityResult, Measurement]:
    """Label an orbit stable/unstable by switching the controller off (Fig. 3.18).

    The controller first tracks ``nudged_target`` (the converged target moved slightly
    off the orbit, e.g. a 5 % smaller amplitude: inwards, towards the equilibrium, so an
    unstable orbit of a subcritical branch falls back instead of escaping) for
    ``nudge_periods``; then it is switched off and ``signal`` is watched for up to
    ``watch_periods``, two periods at a time, stopping early once the deviation exceeds
    ``escape``. With ``d_j`` the deviation of the
    per-period first-harmonic amplitude from ``amplitude`` (the converged orbit's), the
    orbit is

    - unstable if ``|d|`` (mean of the last two periods against the first) grows by more
      than ``threshold``, or the final deviation exceeds ``escape``,
    - stable if it decays by the same factor,
    - undecided otherwise.

    Afterwards the controller is switched back on with ``restore_target`` (when given).

    Returns
    -------
    StabilityResult, Measurement
        The label and the last record after switch-off.
    """
    period = 2.0 * math.pi / omega
    rig.set_controller(controller, nudged_target)
    rig.run(nudge_periods * period)
    rig.set_controller(None)
    # watch period by period; stop as soon as the response has clearly left
    records: list[Measurement] = []
    amps = np.zeros(0)
    chunk = 2
    watched = 0
    while watched < watch_periods:
        k = int(min(chunk, math.ceil(watch_periods - watched)))
        m = rig.run(k * period + 1.0 / rig.sample_rate)
        records.append(m)
        watched += k
        x = np.concatenate([r.signal(signal) for r in records])
        amps = period_amplitudes(x, omega, m.sample_rate)
        if amps.size and abs(amps[-1] - amplitude) > escape * amplitude:
            break
    if restore_target is not None:
        rig.set_controller(controller, restore_target)
    d = (amps - amplitude) / amplitude
    m = records[-1]
    if d.shape[0] < 2:
        return StabilityResult(None, math.nan, d), m
    ad = np.abs(d)
    # growth per period from the first and last deviations (robust to a sign change of d)
    start = float(ad[0])
    end = float(np.mean(ad[-2:])) if ad.shape[0] >= 4 else float(ad[-1])
    span = max(ad.shape[0] - 1.5, 1.0)
    growth = (max(end, 1e-12) / max(start, 1e-12)) ** (1.0 / span)
    if end > escape or end > threshold * start:
        stable: bool | None = False
    elif end < start / threshold:
        stable = True
    else:
        stable = None
    return StabilityResult(stable, growth, d), m


# -------------------------------------------------------------- controlled Floquet analysis
_RHS_CACHE: dict[tuple, Callable] = {}


def _state_signal(system: System, name: str) -> tuple[int, bool]:
    """A controller signal as (state index, is_derivative)."""
    if name in system.states:
        return system.state_index(name), False
    if name.endswith("_dot") and name[:-4] in system.states:
        return system.state_index(name[:-4]), True
    raise BifidInputError(
        f"signal {name!r} is neither a state of {system.name!r} nor '<state>_dot'."
    )


def controlled_rhs(
    system: System, controller: PDController, target: AbstractTarget
) -> tuple[Callable, int]:
    """The closed-loop vector field with continuous (unsampled) control.

    .. math::

        \\dot x = f(x, p) + b(p)\\,γ\\cos(Ωt - ψ) + e(p)\\bigl(k_p(x_1^*-x_1)
                  + k_d(x_2^*-x_2)\\bigr),

    with ``x1, x2`` read from the state (a ``"<state>_dot"`` signal is the component of
    ``f + b γ cos`` along that state). The returned ``rhs(x, t, q)`` takes the augmented
    parameter vector ``q = [p, kp, kd, γ, Ω, ψ, target.vector()]`` (see
    :func:`augmented_params`), so one compiled function serves every gain and target.

    A controller with an output filter (``filter_hz``) adds its state ``u`` as the last
    component of ``x``: ``u̇ = 2π f_c (u_law - u)`` and ``e(p) u`` enters the field.

    Returns
    -------
    rhs : callable
    n_params : int
        Length of ``p`` inside ``q``.
    """
    s1 = _state_signal(system, controller.x1)
    s2 = _state_signal(system, controller.x2)
    wc = None if controller.filter_hz is None else 2.0 * math.pi * controller.filter_hz
    key = (system.name, id(system.field), s1, s2, target.static_key, wc)
    if key not in _RHS_CACHE:
        n_p = len(system.parameters)
        ref = type(target).reference
        bdir = system.forcing_direction or system.input_direction
        edir = system.input_direction
        f = system.field

        def rhs(xa, t, q):
            x = xa if wc is None else xa[:-1]
            p = q[:n_p]
            kp, kd, gamma, Om, psi = q[n_p], q[n_p + 1], q[n_p + 2], q[n_p + 3], q[n_p + 4]
            tv = q[n_p + 5 :]
            force = gamma * jnp.cos(Om * t - psi)
            fx = f(x, p) + bdir(p) * force
            x1 = fx[s1[0]] if s1[1] else x[s1[0]]
            x2 = fx[s2[0]] if s2[1] else x[s2[0]]
            r1, r2 = ref(tv, x1, x2, Om * t, Om)
            u = kp * (r1 - x1) + kd * (r2 - x2)
            if wc is None:
                return fx + edir(p) * u
            return jnp.concatenate([fx + edir(p) * xa[-1], (wc * (u - xa[-1]))[None]])

        _RHS_CACHE[key] = rhs
    return _RHS_CACHE[key], len(system.parameters)


def augmented_params(
    p: np.ndarray,
    controller: PDController,
    target: AbstractTarget,
    forcing: tuple[float, float, float] | None = None,
) -> np.ndarray:
    """``q = [p, kp, kd, γ, Ω, ψ, target.vector()]`` for :func:`controlled_rhs`."""
    g, Om, psi = forcing if forcing is not None else (0.0, 0.0, 0.0)
    return np.concatenate(
        [np.asarray(p, dtype=float), [controller.kp, controller.kd, g, Om, psi], target.vector()]
    )


def orbit_polar_target(
    orbit: np.ndarray,
    system: System,
    x1: str,
    x2: str,
    n_harmonics: int,
    scale: tuple[float, float] | None = None,
    origin: tuple[float, float] | None = None,
    p: np.ndarray | None = None,
    n_fine: int = 4096,
    transform=None,
) -> PolarTarget:
    """The polar target (eq. 3.22) that is non-invasive on a known orbit.

    Parameters
    ----------
    orbit : array of shape (M, n)
        States on ``t_k = T k / M`` (one period).
    x1, x2 : str
        Controller signals (states or ``"<state>_dot"``, the latter from ``system.field``).
    scale, origin, transform : optional
        The target's frame (:class:`~bifid.cbc.PolarTarget`). Without any of them, the
        frame a rig's campaign uses (``TargetFamily.reframed``): centred on the orbit's
        mean, mapping the first-harmonic ellipse of ``(x1, x2)`` to a circle. In a frame
        where the orbit is far from a circle (``(h, ḣ)`` with ``ḣ ~ ω h``), ``n_harmonics``
        terms of ``r*(φ)`` cannot follow it and the target is invasive: the orbit is then
        not a solution of the controlled system (:func:`controlled_floquet` refuses it).
    """
    orbit = np.asarray(orbit, dtype=float)
    M = orbit.shape[0]
    fine = np.fft.irfft(np.fft.rfft(orbit, axis=0), n=n_fine, axis=0) * (n_fine / M)
    pv = np.asarray(system.param_vector() if p is None else p)

    def sig(name):
        i, is_d = _state_signal(system, name)
        if not is_d:
            return fine[:, i]
        fx = np.asarray(jax_vmap_field(system)(jnp.asarray(fine), jnp.asarray(pv)))
        return fx[:, i]

    a, b = sig(x1), sig(x2)
    if scale is None and origin is None and transform is None:
        c = np.fft.rfft(np.column_stack([a, b]), axis=0) / n_fine
        # x ≈ c0 + A cos φ + B sin φ per signal: [A, B] rows map the unit circle onto it
        ellipse = np.array(
            [[2 * c[1, 0].real, -2 * c[1, 0].imag], [2 * c[1, 1].real, -2 * c[1, 1].imag]]
        )
        radius = math.hypot(*ellipse[0])
        if radius > 0 and abs(np.linalg.det(ellipse)) > 1e-9 * np.max(np.abs(ellipse)) ** 2:
            transform = ellipse / radius
        origin = (float(c[0, 0].real), float(c[0, 1].real))
    frame = PolarTarget(
        np.zeros(1),
        scale=(1.0, 1.0) if scale is None else scale,
        origin=(0.0, 0.0) if origin is None else origin,
        transform=transform,
    )
    xi1, xi2 = frame.to_xi(a, b)
    coef = polar_project(np.arctan2(xi2, xi1), np.hypot(xi1, xi2), n_harmonics)
    return frame.with_coefficients(coef)


def controlled_floquet(
    system: System,
    controller: PDController,
    target: AbstractTarget,
    orbit: np.ndarray,
    period: float,
    p: np.ndarray,
    forcing: tuple[float, float, float] | None = None,
) -> tuple[np.ndarray, float]:
    """Floquet multipliers of the controlled system on ``orbit`` (thesis eq. 3.26).

    Parameters
    ----------
    orbit : array of shape (M, n)
        The (non-invasively controlled) orbit on ``t_k = T k / M``; for forced systems
        ``t = 0`` is the phase origin of the force ``γ cos(Ωt - ψ)``.
    period : float
    p : array
        System parameters.
    forcing : (γ, Ω, ψ), optional
        Forced systems: the excitation (the system's own F, Omega are not used).

    Returns
    -------
    multipliers : complex ndarray of shape (n,), by decreasing modulus
        (``n + 1`` with an output filter: its state is part of the closed loop)
    floquet_max : float
        Largest modulus, excluding the trivial multiplier for autonomous systems.
    """
    from bifid.continuation import floquet_multipliers

    rhs, _ = controlled_rhs(system, controller, target)
    q = augmented_params(p, controller, target, forcing)
    orbit = np.asarray(orbit, dtype=float)
    steps = 4
    if controller.filter_hz is not None:  # the filter's output is 0 on a non-invasive orbit
        orbit = np.column_stack([orbit, np.zeros(orbit.shape[0])])
        # a fast filter makes the variational equation stiff: keep 2π f_c h <= 1 for the
        # explicit integrator (powers of two: few distinct compiled step counts)
        need = 2.0 * math.pi * controller.filter_hz * float(period) / orbit.shape[0]
        steps = max(4, 1 << math.ceil(math.log2(max(need, 1.0))))
    mults, _, fmax = floquet_multipliers(
        rhs,
        orbit[None],
        np.array([float(period)]),
        q[None],
        steps_per_mesh=steps,
        autonomous=forcing is None,
    )
    if forcing is None and not invariant(mults[0]):
        raise BifidInputError(
            "the orbit is not a solution of the controlled system (no Floquet multiplier "
            f"within {TRIVIAL_TOL:g} of 1; largest {np.max(np.abs(mults[0])):.3g}): the "
            "target is invasive on it -- build it with orbit_polar_target in the orbit's "
            "own frame (its default) or with more harmonics."
        )
    return mults[0], float(fmax[0])


#: an autonomous orbit of the controlled system has a multiplier this close to 1 (the
#: trivial one; 4e-5 on measured flutter LCOs, 1e-9 on model orbits)
TRIVIAL_TOL = 1e-3


def invariant(multipliers: np.ndarray) -> bool:
    """Whether Floquet multipliers of an autonomous orbit include the trivial one (the
    orbit solves the controlled system: the target is non-invasive on it)."""
    m = np.asarray(multipliers)
    return bool(np.all(np.isfinite(m)) and np.min(np.abs(m - 1.0)) <= TRIVIAL_TOL)
