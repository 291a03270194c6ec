"""CBC of harmonically forced systems, thesis §3.2: S-curves and frequency response curves.

The rig is excited by ``γ cos(θ - ψ)``, ``θ̇ = Ω`` (``Â = γ cos ψ``, ``B̂ = γ sin ψ`` in
the notation of eq. 3.1), and a PD controller (eq. 3.2) on the observed coordinate
``x`` tracks the target of eq. 3.3

.. math:: x^*(θ) = A_0^*/2 + \\sum_{j=1}^q A_j^*\\cos jθ + B_j^*\\sin jθ .

The response's coefficients ``p`` are measured over whole forcing periods after
settling. Non-invasiveness is ``p(p*) = p*`` (eq. 3.4).

**S-curves** (:func:`scurve_cbc`, §3.2.1). The target's fundamental ``(A_1^*, B_1^*)``
is the free variable of the curve (``B_1^* = 0`` fixes the phase origin of the
response); at each point

- the higher harmonics follow the response by Picard iteration (eq. 3.8),
- the fundamental component of the control is moved into the force (eq. 3.6):
  ``Â ← Â + k_p ΔA_1 + Ω k_d ΔB_1``, ``B̂ ← B̂ + k_p ΔB_1 - Ω k_d ΔA_1``
  (``Δ = p* - p``), ``γ = \\sqrt{Â² + B̂²}``,

until the whole control signal vanishes. Successive points are predicted along the
secant in ``(A_1, γ)`` (the arclength condition eq. 3.5 in those coordinates), so the
S-curve is followed round both folds: the response amplitude is monotone along an
S-curve even where ``γ`` folds back.

**FRCs** (:func:`frc_cbc`). At fixed ``γ`` the fundamental can no longer be absorbed into
the force, so ``(A_1^*, B_1^*, Ω)`` are solved by Newton's method (finite-difference
Jacobian updated by Broyden's rule) on ``(A_1^* - A_1, B_1^* - B_1) = 0`` plus the
pseudo-arclength condition, with Picard iteration on the higher harmonics inside each
evaluation; this follows the FRC through its bistable region.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from bifid.cbc._controllers import FourierTarget, PDController
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.cbc._secant import HarmonicSecant
from bifid.cbc._stability import switch_off_test
from bifid.errors import BifidInputError, ConvergenceError, ConvergenceWarning
from bifid.signal import (
    band_noise,
    coefficient_noise,
    evaluate_series,
    fourier_project,
    whole_periods,
)

__all__ = [
    "ForcedCBCOptions",
    "ForcedFailure",
    "ForcedPoint",
    "folds_of",
    "frc_cbc",
    "scurve_cbc",
]


@dataclass(frozen=True)
class ForcedCBCOptions:
    """Numbers that steer forced CBC; checked when built.

    Parameters
    ----------
    signal : str
        Observed (controlled) output; the controller uses it and ``"<signal>_dot"``.
    kp, kd : float
        PD gains (eq. 3.2).
    n_harmonics : int
        ``q`` of the target (eq. 3.3; Example 3.1 uses 5).
    settle_periods, measure_periods : float
        Forcing periods to wait after a change and to record.
    tol : float
        Relative tolerance: ``max |p* - p| <= tol * A_1^*`` (plus the noise floor); on an
        FRC the control's fundamental ``|u_1| <= tol * γ`` (plus its floor).
    picard_max : int
        Iterations (eqs. 3.6 + 3.8) per point.
    ds, ds_max : float
        Arclength step (and its bound) in the normalised ``(A_1 / a_ref, γ / γ_ref)``
        plane (S-curve) or ``(A_1/a_ref, B_1/a_ref, Ω/Ω_ref)`` (FRC).
    max_points : int
    max_turn : float
        Largest angle [deg] between successive secants before the step is halved (resolves
        the folds).
    newton_max : int
        Newton–Broyden iterations per FRC point.
    stability : bool
        Label points by switching the controller off (slow for lightly damped rigs).
    watch_periods : float
    precision : float
        Largest accepted noise floor (3σ, relative): of the forcing update ``|J⁻¹ u_1|``
        (S-curve) or of the control's fundamental ``u_1`` (FRC) against ``γ``, and of the
        response's fundamental against ``A_1^*``. A point whose
        control is "zero within noise" is only as good as that noise floor; while the floor
        is above ``precision`` the record is extended (the rig keeps running, no
        re-settling) up to ``max_measure_periods``, and if it is still above, the point is a
        reported failure -- never recorded. Noise-free the floors are ~1e-8 and this never
        acts.
    max_measure_periods : float
        Longest record (forcing periods) one evaluation may grow to for ``precision``.
    stored_periods : float
        A point keeps (and a dataset stores) the last ``stored_periods`` periods of its
        record; its coefficients and amplitude come from the whole record.
    """

    signal: str = "q"
    kp: float = 0.5
    kd: float = 0.5
    n_harmonics: int = 5
    settle_periods: float = 12.0
    measure_periods: float = 4.0
    tol: float = 1e-4
    picard_max: int = 40
    ds: float = 0.05
    ds_max: float = 0.1
    max_points: int = 200
    newton_max: int = 10
    stability: bool = False
    watch_periods: float = 40.0
    nudge: float = 0.05
    max_turn: float = 12.0
    precision: float = 0.005
    max_measure_periods: float = 400.0
    stored_periods: float = 20.0

    def __post_init__(self) -> None:
        if int(self.n_harmonics) < 1:
            raise BifidInputError(f"n_harmonics must be >= 1, got {self.n_harmonics!r}.")
        for name in ("settle_periods", "measure_periods", "tol", "ds", "ds_max",
                     "watch_periods", "precision", "max_measure_periods",
                     "stored_periods"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise BifidInputError(f"{name} must be a positive number, got {v!r}.")
        if self.max_measure_periods < self.measure_periods:
            raise BifidInputError(
                f"max_measure_periods ({self.max_measure_periods}) must be at least "
                f"measure_periods ({self.measure_periods})."
            )
        if self.ds > self.ds_max:
            raise BifidInputError(f"ds ({self.ds}) must not exceed ds_max ({self.ds_max}).")
        for name in ("picard_max", "max_points", "newton_max"):
            if int(getattr(self, name)) < 1:
                raise BifidInputError(f"{name} must be a positive integer.")
        PDController(self.kp, self.kd, self.signal, f"{self.signal}_dot")

    @property
    def controller(self) -> PDController:
        return PDController(self.kp, self.kd, self.signal, f"{self.signal}_dot")

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class ForcedPoint:
    """A steady forced response measured with a non-invasive controller.

    Attributes
    ----------
    omega, forcing, force_phase : float
        ``Ω`` [rad/s], ``γ`` and ``ψ`` of the excitation ``γ cos(θ - ψ)``.
    target : FourierTarget
    coefficients : ndarray
        Measured response ``p = [A0, A1..Aq, B1..Bq]`` (eq. 3.4 ordering).
    measurement : Measurement
        The record (its last ``stored_periods`` periods when longer).
    amplitude : float
        ``max_t |x(t)|`` of the observed signal (Fourier-filtered).
    phase : float
        Lag of the observed first harmonic behind the force, in ``[-π/2, 3π/2)``.
    stable : bool or None
    control_rms, invasiveness : float
        RMS of ``u``; ``rms(u) / rms(kp x + kd ẋ)``.
    residual : float
        ``max |p* - p| / A_1^*`` at convergence.
    iterations : int
    forcing_floor : float
        Noise floor (3σ) relative to ``γ`` of the last forcing update (S-curves) or of
        the control's fundamental (FRCs): how precisely non-invasiveness was verified
        (0 without noise up to round-off).
    measured_periods : float
        Forcing periods in the record the point was accepted on.
    """

    omega: float
    forcing: float
    force_phase: float
    target: FourierTarget
    coefficients: np.ndarray
    measurement: Measurement | None
    amplitude: float
    phase: float
    stable: bool | None = None
    growth: float = math.nan
    control_rms: float = math.nan
    invasiveness: float = math.nan
    residual: float = math.nan
    iterations: int = 0
    forcing_floor: float = math.nan
    measured_periods: float = math.nan

    def to_json(self) -> dict[str, Any]:
        return {
            "omega": self.omega,
            "forcing": self.forcing,
            "amplitude": self.amplitude,
            "phase": self.phase,
            "stable": self.stable,
            "control_rms": self.control_rms,
            "invasiveness": self.invasiveness,
            "residual": self.residual,
            "iterations": self.iterations,
            "forcing_floor": self.forcing_floor,
            "measured_periods": self.measured_periods,
        }


@dataclass
class ForcedFailure:
    """A point that did not converge (never recorded as data)."""

    omega: float
    forcing: float
    reason: str
    data: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"omega": self.omega, "forcing": self.forcing, "reason": self.reason,
                **self.data}


# ------------------------------------------------------------------------------ helpers
def _to_eq33(c: np.ndarray) -> np.ndarray:
    """``[c0, a.., b..]`` (mean c0) to eq. 3.3's ``[A0, A.., B..]`` (mean A0/2)."""
    p = np.array(c, dtype=float)
    p[0] *= 2.0
    return p


@dataclass
class _Meas:
    p: np.ndarray  # response coefficients, eq. 3.3 ordering
    u: np.ndarray  # control coefficients [c0, a1.., b1..] (a1 cos θ + b1 sin θ ...)
    m: Measurement
    floor: float  # noise floor (3σ) of the response coefficients (white measurement noise)
    ufloor: float  # noise floor (3σ) of the control's fundamental (coloured noise, band)
    periods: float  # forcing periods in the record


def _concat(a: Measurement, b: Measurement) -> Measurement:
    """Two consecutive records of one rig as one (the rig ran on between them)."""
    n_a, n_b = len(a), len(b)
    extra = {}
    for k, v in a.extra.items():
        w = b.extra.get(k)
        if (isinstance(v, np.ndarray) and isinstance(w, np.ndarray)
                and v.shape[:1] == (n_a,) and w.shape[:1] == (n_b,)):
            extra[k] = np.concatenate([v, w])
        else:
            extra[k] = v
    return Measurement(
        time=np.concatenate([a.time, b.time]),
        outputs=np.concatenate([a.outputs, b.outputs]), output_names=a.output_names,
        derivatives=np.concatenate([a.derivatives, b.derivatives]),
        control=np.concatenate([a.control, b.control]),
        target=np.concatenate([a.target, b.target]),
        force=np.concatenate([a.force, b.force]), phase=np.concatenate([a.phase, b.phase]),
        sample_rate=a.sample_rate, saturated=a.saturated + b.saturated, extra=extra,
    )


def _record_periods(rig: AbstractRig, omega: float, periods: float) -> Measurement:
    m = rig.run(periods * 2.0 * math.pi / omega + 2.0 / rig.sample_rate)
    return m.tail(whole_periods(len(m), omega, m.sample_rate))


def _project(opts: ForcedCBCOptions, m: Measurement, omega: float) -> _Meas:
    """Response and control coefficients of a record on the generator phase, with floors.

    The response's floor is :func:`coefficient_noise` (white measurement noise, robust to
    drift). The control carries ``k_d`` times the *differentiated* measurement noise,
    whose total variance says nothing about the noise of its fundamental coefficient:
    its floor is the smaller of :func:`band_noise` (right for coloured stationary noise,
    but a slow transient raises it) and :func:`coefficient_noise` (blind to slow drift,
    but far too high for blue noise), so that neither a transient nor blue noise is
    taken for the noise of the fundamental.
    """
    x = m.signal(opts.signal)
    c = fourier_project(np.column_stack([x, m.control]), m.phase, opts.n_harmonics)
    cx, cu = c[:, 0], c[:, 1]
    floor = coefficient_noise(x - evaluate_series(cx, m.phase))
    eu = m.control - evaluate_series(cu, m.phase)
    ufloor = min(band_noise(eu, omega, m.sample_rate), coefficient_noise(eu))
    periods = len(m) * omega / (2.0 * math.pi * m.sample_rate)
    return _Meas(_to_eq33(cx), cu, m, floor, ufloor, periods)


def _measure(rig: AbstractRig, opts: ForcedCBCOptions, omega: float, settle: float,
             periods: float | None = None) -> _Meas:
    """Settle, record whole periods, project response and control on the generator phase."""
    if settle > 0:
        rig.run(settle * 2.0 * math.pi / omega)
    periods = opts.measure_periods if periods is None else periods
    return _project(opts, _record_periods(rig, omega, periods), omega)


def _extend(rig: AbstractRig, opts: ForcedCBCOptions, omega: float, r: _Meas) -> _Meas:
    """Keep measuring (no change, no settling) to double the record, up to the budget."""
    more = min(r.periods, opts.max_measure_periods - r.periods)
    more = max(1.0, float(math.floor(more + 1e-9)))
    m = _concat(r.m, _record_periods(rig, omega, more))
    return _project(opts, m, omega)


def _lag(p: np.ndarray, psi: float, q: int) -> float:
    """Lag of the response's first harmonic behind the force ``γ cos(θ - ψ)``."""
    phi_x = math.atan2(p[q + 1], p[1])
    lag = phi_x - psi
    return float((lag + math.pi / 2) % (2 * math.pi) - math.pi / 2)


def _point(rig, opts, omega, gamma, psi, pstar, r: _Meas, residual, iterations
           ) -> ForcedPoint:
    q = opts.n_harmonics
    p, m = r.p, r.m
    grid = np.linspace(0.0, 2.0 * np.pi, 2048, endpoint=False)
    c = p.copy()
    c[0] *= 0.5
    amp = float(np.max(np.abs(evaluate_series(c, grid))))
    x = m.signal(opts.signal)
    xd = m.signal(f"{opts.signal}_dot")
    u_rms = float(np.sqrt(np.mean(m.control**2)))
    fb = opts.kp * x + opts.kd * xd
    inv = u_rms / max(float(np.sqrt(np.mean(fb**2))), 1e-300)
    # a long (noise-averaging) record is not stored whole: its last stored_periods
    m = m.tail(whole_periods(len(m), omega, m.sample_rate, max_periods=max(
        1, math.floor(opts.stored_periods + 1e-9))))
    return ForcedPoint(
        omega=omega, forcing=gamma, force_phase=psi, target=FourierTarget(pstar),
        coefficients=p, measurement=m, amplitude=amp, phase=_lag(p, psi, q),
        control_rms=u_rms, invasiveness=inv, residual=residual, iterations=iterations,
    )


def _stability(rig: AbstractRig, opts: ForcedCBCOptions, pt: ForcedPoint) -> None:
    """Switch-off test for a forced response (the force stays on), Fig. 3.18."""
    q = opts.n_harmonics
    nudged = pt.target.coefficients.copy()
    nudged[1:] *= 1.0 - opts.nudge
    a1 = math.hypot(pt.coefficients[1], pt.coefficients[q + 1])
    res, _ = switch_off_test(rig, opts.signal, a1, pt.omega, controller=opts.controller,
                             nudged_target=FourierTarget(nudged), restore_target=pt.target,
                             watch_periods=opts.watch_periods)
    pt.stable, pt.growth = res.stable, res.growth
    rig.run(opts.settle_periods * 2.0 * math.pi / pt.omega)


# ------------------------------------------------------------------------------ S-curve
def _gain(opts: ForcedCBCOptions, omega: float) -> float:
    """``|k_p + i Ω k_d|``: control per unit tracking error at the fundamental."""
    return math.hypot(opts.kp, omega * opts.kd)


class _NoiseLimited(str):
    """A failure reason that a smaller arclength step cannot cure (the noise floor)."""


def _converge_scurve_point(rig, opts, omega, pstar, gamma, psi, on_iteration, settle_first,
                           jac: dict[str, np.ndarray] | None = None
                           ) -> tuple[ForcedPoint | None, np.ndarray, float, float, str]:
    """Iterate eqs. 3.6 and 3.8 with the target fundamental fixed.

    Eq. 3.6 is applied in its measured form: the fundamental of the *recorded* control
    signal is added to the force. With an exact derivative this equals
    ``k_p ΔA_1 + Ω k_d ΔB_1`` (and the sine counterpart); with a derivative estimated from
    samples it stays exact, whereas the formula would leave the estimator's lag in the
    loop as an invasive control.

    Accepted only when the target iteration has converged *and* that is verified to the
    requested precision: the control's fundamental ``u_1`` and the higher-harmonic
    tracking errors are below ``tol`` (relative to ``A_1*``) plus their noise floors
    (3σ), and those floors are themselves small -- the forcing update ``J⁻¹ u_1`` known to
    ``precision · γ``, the response to ``precision · A_1*``. "Zero within noise" with a
    floor as large as ``γ`` would accept any forcing (the stalled points of noisy runs),
    so while a floor is too high the record is extended, and a point whose floors stay
    above the precision within ``max_measure_periods`` is a failure, never a point.
    """
    q = opts.n_harmonics
    fund = [1, q + 1]
    others = [i for i in range(2 * q + 1) if i not in fund]
    f = np.array([gamma * math.cos(psi), gamma * math.sin(psi)])
    ctrl = opts.controller
    K = _gain(opts, omega)
    pstar = pstar.copy()
    err = math.inf
    # Jacobian of the control's fundamental with respect to the force's (cos, sin) parts:
    # -I when force and control enter at the same point (then the update is eq. 3.6);
    # Broyden-corrected otherwise (e.g. a force on both masses of shaw_pierre, or gains so
    # low that the response follows the force rather than the target); ``jac`` carries the
    # corrected J from point to point along a curve
    J = -np.eye(2) if jac is None or "J" not in jac else jac["J"].copy()
    last: tuple[np.ndarray, np.ndarray] | None = None
    harm = HarmonicSecant(q, fixed=(1,))
    a1 = max(math.hypot(pstar[1], pstar[q + 1]), 1e-300)
    periods = float(opts.measure_periods)

    def assess(r: _Meas) -> tuple[bool, bool, np.ndarray, float, float]:
        """(converged within the floors, floors below the precision, u_1, error, floor)."""
        e_h = float(np.max(np.abs((pstar - r.p)[others]))) if others else 0.0
        uf = np.array([r.u[1], r.u[q + 1]])
        # the forcing update and its noise floor, in force units (relative to γ below)
        jinv = float(np.linalg.norm(np.linalg.inv(J), 2))
        g = max(math.hypot(f[0], f[1]), 1e-300)
        f_floor = r.ufloor * jinv / g
        conv = (e_h <= opts.tol * a1 + r.floor
                and np.hypot(*uf) <= opts.tol * K * a1 + r.ufloor)
        precise = f_floor <= opts.precision and r.floor <= opts.precision * a1
        return conv, precise, uf, max(e_h, float(np.hypot(*uf)) / K), f_floor

    for it in range(opts.picard_max):
        gamma, psi = math.hypot(f[0], f[1]), math.atan2(f[1], f[0])
        rig.set_forcing(gamma, omega, psi)
        rig.set_controller(ctrl, FourierTarget(pstar))
        settle = settle_first if it == 0 else opts.settle_periods
        r = _measure(rig, opts, omega, settle, periods)
        if on_iteration is not None:
            on_iteration(1)
        conv, precise, uf, err, f_floor = assess(r)
        # converged as far as this record can tell: make sure it can tell enough
        while conv and not precise and r.periods < 0.99 * opts.max_measure_periods:
            r = _extend(rig, opts, omega, r)
            conv, precise, uf, err, f_floor = assess(r)
        if conv and precise:
            pt = _point(rig, opts, omega, gamma, psi, pstar, r, err / a1, it + 1)
            pt.forcing_floor, pt.measured_periods = f_floor, r.periods
            if jac is not None:
                jac["J"] = J
            return pt, pstar, gamma, psi, ""
        if conv:  # within noise, but the noise is too large to verify the point
            return None, pstar, gamma, psi, _NoiseLimited(
                f"noise floor too high to verify non-invasiveness after {r.periods:.0f} "
                f"periods: forcing update known to {100 * f_floor:.2g} % of γ, response to "
                f"{100 * r.floor / a1:.2g} % of A1* (precision {100 * opts.precision:g} %; "
                "raise max_measure_periods or lower the gains)"
            )
        # the residual left by an update is as small as the record it was measured on
        # could tell: look for it with a record as long
        periods = r.periods
        if last is not None:
            df, du = f - last[0], uf - last[1]
            # Broyden only on changes well above the noise of u_1 (noise would wreck J)
            if df @ df > 0 and np.linalg.norm(J @ df) > 3.0 * r.ufloor:
                J = J + np.outer(du - J @ df, df) / (df @ df)
        last = (f.copy(), uf)
        # eq. 3.6 (measured, quasi-Newton): move the control's fundamental into the force
        f = f - np.linalg.solve(J, uf)
        # eq. 3.8: Picard on the other harmonics (secant-accelerated)
        pstar = harm.step(pstar, r.p, r.floor)
    return None, pstar, gamma, psi, (
        f"target iteration did not converge in {opts.picard_max} iterations "
        f"(control error {err:.2e})"
    )


def folds_of(points: list[ForcedPoint], key: str = "forcing") -> list[dict[str, float]]:
    """Folds of a measured curve: local extrema of ``key`` (``"forcing"`` or ``"omega"``).

    Where the amplitude is monotone along the curve (an S-curve), ``key`` is a smooth
    function of the amplitude with a regular extremum at each fold: a cubic spline
    ``key(A)`` through all points is searched for the extrema between the points that
    bracket a change of direction (on duffing at Ω = 1.05 this locates the lower fold to
    0.1 % where a chord-length spline misses it by 1.8 %). Otherwise (an FRC) the curve is
    parametrised by its cumulative chord length ``s`` in the normalised
    ``(key, amplitude)`` plane and splines ``key(s)``, ``amplitude(s)`` are searched the
    same way. Returns ``[{key: value, "amplitude": value}]``.
    """
    from scipy.interpolate import CubicSpline

    if len(points) < 4:
        return []
    v = np.array([getattr(pt, key) for pt in points], dtype=float)
    a = np.array([pt.amplitude for pt in points], dtype=float)
    if np.all(np.diff(a) > 0) or np.all(np.diff(a) < 0):
        order = np.argsort(a)
        spl = CubicSpline(a[order], v[order])
        out = []
        for i in range(1, len(v) - 1):
            if (v[i] - v[i - 1]) * (v[i + 1] - v[i]) < 0:
                grid = np.linspace(min(a[i - 1], a[i + 1]), max(a[i - 1], a[i + 1]), 4001)
                vals = spl(grid)
                j = int(np.argmax(vals) if v[i] > v[i - 1] else np.argmin(vals))
                out.append({key: float(vals[j]), "amplitude": float(grid[j])})
        return out
    dv = np.diff(v) / max(np.ptp(v), 1e-300)
    da = np.diff(a) / max(np.ptp(a), 1e-300)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(dv, da))])
    keep = np.concatenate([[True], np.diff(s) > 0])
    s, v, a = s[keep], v[keep], a[keep]
    sv, sa = CubicSpline(s, v), CubicSpline(s, a)
    out = []
    for i in range(1, len(v) - 1):
        if (v[i] - v[i - 1]) * (v[i + 1] - v[i]) < 0:
            grid = np.linspace(s[i - 1], s[i + 1], 4001)
            vals = sv(grid)
            j = int(np.argmax(vals) if v[i] > v[i - 1] else np.argmin(vals))
            out.append({key: float(vals[j]), "amplitude": float(sa(grid[j]))})
    return out


def scurve_cbc(
    rig: AbstractRig,
    omega: float,
    forcing_range: tuple[float, float],
    options: ForcedCBCOptions | None = None,
    *,
    amplitude_scale: float | None = None,
    on_point: Callable[[ForcedPoint], None] | None = None,
    on_iteration: Callable[[int], None] | None = None,
    start: ForcedPoint | None = None,
    previous: ForcedPoint | None = None,
    scale_to_range: bool = False,
) -> tuple[list[ForcedPoint], list[ForcedFailure]]:
    """Measure an S-curve at frequency ``omega`` from ``forcing_range[0]`` up (§3.2.1).

    Starts on the low-forcing branch (the response to ``γ = forcing_range[0]``) and
    follows the curve by secant prediction in the normalised ``(A_1, γ)`` plane round its
    folds, until ``γ`` exceeds ``forcing_range[1]`` on a rising part, falls below
    ``forcing_range[0]``, or ``max_points`` is reached.

    Parameters
    ----------
    amplitude_scale : float, optional
        ``a_ref`` of the arclength norm (default: 20 × the first point's amplitude).
    scale_to_range : bool
        Without ``amplitude_scale``, cap ``a_ref`` at ``2 A γ_max / γ`` (twice the linear
        extrapolation of the first point ``(γ, A)`` to the top of the range). A curve
        started high in its range (noisy campaigns start at larger γ, where the forcing
        update can be verified) otherwise takes steps scaled to its larger first
        amplitude and crosses the lower branch in one or two (shaw_pierre with 1 %
        noise: 2 points below the first fold, 7 with the cap). No effect where
        ``γ_max / γ >= 10``. Off by default (``scurve_campaign(scale_to_range=True)``
        passes it on).
    start, previous : ForcedPoint, optional
        Resume from these (the last two recorded points).

    Returns
    -------
    points, failures
    """
    opts = options or ForcedCBCOptions()
    lo, hi = float(forcing_range[0]), float(forcing_range[1])
    if not (0 < lo < hi and math.isfinite(hi)):
        raise BifidInputError(f"forcing range must satisfy 0 < lo < hi, got {forcing_range}.")
    if not (omega > 0 and math.isfinite(omega)):
        raise BifidInputError(f"omega must be a positive frequency, got {omega!r}.")
    q = opts.n_harmonics
    n_c = 2 * q + 1
    points: list[ForcedPoint] = []
    failures: list[ForcedFailure] = []

    def it_cb(k: int) -> None:
        if on_iteration is not None:
            on_iteration(k)

    jac: dict[str, np.ndarray] = {}
    if start is None:
        # bootstrap: hold the observed signal at its measured low-forcing response
        rig.set_forcing(lo, omega, 0.0)
        rig.set_controller(None)
        p0 = _measure(rig, opts, omega, 3 * opts.settle_periods).p
        a1 = math.hypot(p0[1], p0[q + 1])
        pstar = np.zeros(n_c)
        pstar[1] = a1
        # force phase so that the response fundamental is ~ A1 cos θ
        psi = -math.atan2(p0[q + 1], p0[1])
        pt, pstar, gamma, psi, why = _converge_scurve_point(
            rig, opts, omega, pstar, lo, psi, it_cb, opts.settle_periods, jac)
        if pt is None:
            failures.append(ForcedFailure(omega, lo, why))
            warnings.warn(f"S-curve CBC at Ω={omega:g}: first point: {why}.",
                          ConvergenceWarning, stacklevel=2)
            return points, failures
        _record(rig, opts, pt, points, on_point)
        prev = None
    else:
        pt, prev = start, previous
    a_ref = amplitude_scale or 20.0 * max(pt.amplitude, 1e-12)
    if scale_to_range and not amplitude_scale:
        # at most twice the first amplitude's linear extrapolation to the top of the range
        a_ref = min(a_ref, 2.0 * max(pt.amplitude, 1e-12) * hi / max(pt.forcing, 1e-300))
    g_ref = hi
    ds = opts.ds
    cur = pt

    def y_of(x: ForcedPoint) -> np.ndarray:
        return np.array([x.target.coefficients[1] / a_ref, x.forcing / g_ref])

    while len(points) < opts.max_points:
        if prev is None:
            t = np.array([1.0, 0.0])  # first step: along the amplitude
        else:
            sec = y_of(cur) - y_of(prev)
            t = sec / np.linalg.norm(sec)
            if t[0] < 0:  # the response amplitude grows along an S-curve
                t = -t
        y_pred = y_of(cur) + ds * t
        pstar = cur.target.coefficients.copy()
        if prev is not None:
            # linear extrapolation of the higher harmonics along the secant
            frac = ds / max(np.linalg.norm(y_of(cur) - y_of(prev)), 1e-300)
            pstar = pstar + frac * (cur.target.coefficients - prev.target.coefficients)
        pstar[1] = y_pred[0] * a_ref
        pstar[q + 1] = 0.0
        gamma = max(y_pred[1] * g_ref, 0.0)
        try:
            new, _, _, _, why = _converge_scurve_point(rig, opts, omega, pstar, gamma,
                                                       cur.force_phase, it_cb,
                                                       opts.settle_periods, jac)
        except ConvergenceError as exc:
            new, why = None, f"rig failure: {exc}"
        if new is None:
            if ds > opts.ds / 16 and not isinstance(why, _NoiseLimited):
                ds /= 2.0
                continue
            failures.append(ForcedFailure(omega, gamma, why))
            warnings.warn(f"S-curve CBC at Ω={omega:g} stopped near γ={gamma:.4g}: {why}.",
                          ConvergenceWarning, stacklevel=2)
            break
        _record(rig, opts, new, points, on_point)
        # step control: shrink where the curve turns (folds), grow where it is straight
        turn = 0.0
        if prev is not None:
            s_old = y_of(cur) - y_of(prev)
            s_new = y_of(new) - y_of(cur)
            cosang = float(s_old @ s_new / (np.linalg.norm(s_old) * np.linalg.norm(s_new)))
            turn = math.degrees(math.acos(max(-1.0, min(1.0, cosang))))
        prev, cur = cur, new
        if turn > opts.max_turn:
            ds = max(opts.ds / 8, ds * 0.5)
        elif new.iterations <= 6 and turn < opts.max_turn / 2:
            ds = min(opts.ds_max, ds * 1.3)
        if new.forcing > hi and new.forcing > prev.forcing:
            break
        # back below where the curve started (the forcing of the first converged point can
        # be well under ``lo`` -- the response bootstrapped at ``lo`` needs less forcing
        # once the update of eq. 3.6 has converged -- so ``lo`` itself is not the bound)
        if new.forcing < min(lo, points[0].forcing if points else lo) * (1 - 1e-9):
            break
    return points, failures


def _record(rig, opts, pt: ForcedPoint, points: list[ForcedPoint],
            on_point: Callable[[ForcedPoint], None] | None) -> None:
    if opts.stability:
        _stability(rig, opts, pt)
    points.append(pt)
    if on_point is not None:
        on_point(pt)


# ---------------------------------------------------------------------------------- FRC
@dataclass
class _FRCEval:
    """One evaluation of the FRC zero problem: the rig held at target ``y``, measured."""

    y: np.ndarray  # (A_1*, B_1*, Ω)
    pstar: np.ndarray  # the whole target (higher harmonics converged by Picard)
    r: _Meas  # the record the evaluation was measured on
    g: np.ndarray  # control's fundamental (cos, sin) / |k_p + iΩk_d|, in units of x
    gfloor: float  # noise floor (3σ) of g
    e_h: float  # largest tracking error of the higher harmonics
    u: float  # |u_1|: magnitude of the control's fundamental (a force)


def frc_cbc(
    rig: AbstractRig,
    forcing: float,
    omega_range: tuple[float, float],
    options: ForcedCBCOptions | None = None,
    *,
    omega_scale: float | None = None,
    on_point: Callable[[ForcedPoint], None] | None = None,
    on_iteration: Callable[[int], None] | None = None,
    start: ForcedPoint | None = None,
    previous: ForcedPoint | None = None,
) -> tuple[list[ForcedPoint], list[ForcedFailure]]:
    """Measure a frequency response curve at forcing ``γ`` over ``omega_range``.

    ``start`` (and ``previous``, the point before it): continue a curve measured before
    (``--resume``) from its last points instead of from ``omega_range[0]``; the rig is
    brought onto ``start`` (its target held and settled) and the arclength steps go on
    in the direction ``previous → start`` (else towards ``omega_range[1]``).

    Unknowns ``y = (A_1^*, B_1^*, Ω)``; equations ``G(y) = u_1 / |k_p + iΩk_d| = 0`` (the
    control's fundamental, cos and sin parts, in units of the response; the higher
    harmonics converged by Picard, eq. 3.8, inside each evaluation) and the
    pseudo-arclength condition ``t^T W (y - y_pred) = 0`` (``W`` normalises the amplitudes
    by ``a_ref`` = 20 × the first response amplitude and ``Ω`` by ``omega_scale``). Newton
    with a finite-difference Jacobian (3 rig evaluations) updated by Broyden's rule; the
    first point is solved at fixed ``Ω = omega_range[0]``.

    Acceptance (the S-curves' rule, in the FRC's terms). With the higher harmonics
    converged the control is a force ``u_1`` at the forcing frequency: the controlled
    response is the uncontrolled response to the force plus ``u_1`` (exactly so where the
    actuator acts where the force does, as on ``duffing``), so ``|u_1| / γ`` is the
    forcing error of the point. It is accepted when ``|u_1| <= tol · γ + floor`` and the
    higher harmonics' tracking errors ``<= tol · A_1^* + floor``, *and* those noise
    floors (3σ) are small: the control's fundamental known to ``precision · γ``, the
    response to ``precision · A_1^*``. While a floor is too high the record is extended
    (the rig keeps running, no re-settling) up to ``max_measure_periods``; a point that
    still cannot be verified is a failure ("noise floor too high ..."), never recorded,
    and no smaller step is tried for it. (A test on ``|G| <= tol · A_1^*`` would be too
    weak near resonance, where a strong controller makes the response follow the target:
    there ``|u_1| = tol · k A_1^*`` is a forcing error of 0.3 % on duffing at γ = 0.01.)

    With noise: finite-difference steps are enlarged until the change of ``G`` stands out
    of its noise; Broyden updates use only changes well above the noise; Newton steps are
    bounded (trust region ``2 ds``) and a step that raises the residual triggers a
    finite-difference refresh of the Jacobian; where the residual is within a few noise
    floors the records are doubled (Newton steps on noise would only wander).
    """
    opts = options or ForcedCBCOptions()
    w0, w1 = float(omega_range[0]), float(omega_range[1])
    if not (w0 > 0 and w1 > 0 and w0 != w1):
        raise BifidInputError(
            f"omega range must be two distinct positive values, got {omega_range}."
        )
    if not (forcing > 0 and math.isfinite(forcing)):
        raise BifidInputError(f"forcing must be positive, got {forcing!r}.")
    q = opts.n_harmonics
    others = [i for i in range(2 * q + 1) if i not in (1, q + 1)]
    direction = 1.0 if w1 > w0 else -1.0
    om_ref = omega_scale or abs(w1 - w0)
    ctrl = opts.controller
    points: list[ForcedPoint] = []
    failures: list[ForcedFailure] = []
    state: dict[str, Any] = {"pstar": None, "periods": float(opts.measure_periods)}

    def it_cb(k: int) -> None:
        if on_iteration is not None:
            on_iteration(k)

    def eval_of(y: np.ndarray, pstar: np.ndarray, r: _Meas) -> _FRCEval:
        K = _gain(opts, float(y[2]))
        e_h = float(np.max(np.abs((pstar - r.p)[others]))) if others else 0.0
        uf = np.array([r.u[1], r.u[q + 1]])
        return _FRCEval(np.array(y, dtype=float), pstar, r, uf / K, r.ufloor / K, e_h,
                        float(np.hypot(*uf)))

    def evaluate(y: np.ndarray) -> _FRCEval:
        """Hold target ``y`` (Picard on the higher harmonics) and measure."""
        A1, B1, om = float(y[0]), float(y[1]), float(y[2])
        pstar = state["pstar"].copy()
        pstar[1], pstar[q + 1] = A1, B1
        a1 = max(math.hypot(A1, B1), 1e-300)
        rig.set_forcing(forcing, om, 0.0)
        harm = HarmonicSecant(q, fixed=(1,))
        ev = None
        for k in range(opts.picard_max):
            rig.set_controller(ctrl, FourierTarget(pstar))
            r = _measure(rig, opts, om, opts.settle_periods, state["periods"])
            it_cb(1)
            ev = eval_of(y, pstar, r)
            if ev.e_h <= opts.tol * a1 + r.floor or k + 1 == opts.picard_max:
                break
            pstar = harm.step(pstar, r.p, r.floor)
        assert ev is not None
        state["pstar"] = pstar
        return ev

    def assess(ev: _FRCEval) -> tuple[bool, bool, float]:
        """(converged within the floors, floors below the precision, force floor / γ)."""
        a1 = max(math.hypot(ev.y[0], ev.y[1]), 1e-300)
        r = ev.r
        conv = (ev.e_h <= opts.tol * a1 + r.floor
                and ev.u <= opts.tol * forcing + r.ufloor)
        f_floor = r.ufloor / forcing
        precise = f_floor <= opts.precision and r.floor <= opts.precision * a1
        return conv, precise, f_floor

    # start: open-loop response at w0 as the first guess
    rig.set_forcing(forcing, w0, 0.0)
    rig.set_controller(None)
    p0 = _measure(rig, opts, w0, 3 * opts.settle_periods).p
    state["pstar"] = p0.copy()
    a_first = max(math.hypot(p0[1], p0[q + 1]), 1e-12)
    a_ref = 20.0 * a_first
    W = np.array([1.0 / a_ref**2, 1.0 / a_ref**2, 1.0 / om_ref**2])

    def fd_jac(ev0: _FRCEval) -> tuple[np.ndarray, _FRCEval]:
        """Finite-difference ``dG/dy`` at ``ev0.y`` (steps grow until ``ΔG`` beats the
        noise) and a fresh evaluation at ``ev0.y`` (the rig is left there)."""
        y = ev0.y
        J = np.empty((2, 3))
        for j in range(3):
            h = 1e-2 * a_first if j < 2 else 1e-4 * om_ref
            h_max = 0.1 * a_first if j < 2 else 1e-2 * om_ref
            while True:
                yp = y.copy()
                yp[j] += h
                evp = evaluate(yp)
                dg = evp.g - ev0.g
                need = 5.0 * max(ev0.gfloor, evp.gfloor)
                if float(np.linalg.norm(dg)) >= need or h >= h_max:
                    break
                h = min(h_max, h * min(10.0, 2.0 * need / max(float(np.linalg.norm(dg)),
                                                              1e-300)))
            J[:, j] = dg / h
        return J, evaluate(y)

    def newton(y: np.ndarray, row: np.ndarray, c: float, J: np.ndarray, radius: float
               ) -> tuple[_FRCEval | None, np.ndarray, str, int]:
        """Newton–Broyden on ``G = 0`` and ``row · y = c`` from ``y``.

        Steps are bounded by ``radius`` in the ``W`` norm (a trust region: a Broyden
        Jacobian can point anywhere, and the rig must not be sent there); a step that
        raises the residual above its noise triggers one finite-difference refresh of
        ``J`` at the point before it.
        """
        state["periods"] = float(opts.measure_periods)
        ev = evaluate(y)
        why = ""
        refreshed = False
        for it in range(opts.newton_max + 1):
            conv, precise, f_floor = assess(ev)
            # converged as far as this record can tell: make sure it can tell enough
            while conv and not precise and ev.r.periods < 0.99 * opts.max_measure_periods:
                ev = eval_of(ev.y, ev.pstar, _extend(rig, opts, float(ev.y[2]), ev.r))
                conv, precise, f_floor = assess(ev)
            if conv and precise:
                return ev, J, "", it + 1
            a1 = max(math.hypot(ev.y[0], ev.y[1]), 1e-300)
            if conv:
                return None, J, _NoiseLimited(
                    f"noise floor too high to verify non-invasiveness after "
                    f"{ev.r.periods:.0f} periods: control's fundamental known to "
                    f"{100 * f_floor:.2g} % of γ, response to {100 * ev.r.floor / a1:.2g} % "
                    f"of A1* (precision {100 * opts.precision:g} %; raise "
                    "max_measure_periods or lower the gains)"), it + 1
            why = (f"Newton–Broyden did not converge in {opts.newton_max} iterations "
                   f"(control's fundamental {100 * ev.u / forcing:.2g} % of γ, noise floor "
                   f"{100 * ev.r.ufloor / forcing:.2g} %)")
            if it == opts.newton_max:
                break
            # the residual is as small as the record it was measured on could tell: look
            # for the next one with a record as long -- twice as long where the residual
            # is within a few noise floors (Newton steps on noise would only wander)
            state["periods"] = max(state["periods"], ev.r.periods)
            near_noise = 4.0 * (opts.tol * forcing + ev.r.ufloor)
            if ev.u <= near_noise:
                state["periods"] = min(2.0 * state["periods"], opts.max_measure_periods)
            A = np.vstack([J, row[None, :]])
            dy = np.linalg.solve(A, np.concatenate([-ev.g, [c - row @ ev.y]]))
            size = math.sqrt(float(dy @ (W * dy)))
            if size > radius:
                dy *= radius / size
            evn = evaluate(ev.y + dy)
            if (evn.u > max(ev.u, 4.0 * (opts.tol * forcing + evn.r.ufloor))
                    and not refreshed):
                # the step made it worse: J is wrong -- refresh it where we came from
                refreshed = True
                J, ev = fd_jac(ev)
                continue
            # Broyden only on changes well above the noise of G (noise would wreck J)
            if float(np.linalg.norm(J @ dy)) > 3.0 * max(ev.gfloor, evn.gfloor):
                J = J + np.outer(evn.g - ev.g - J @ dy, dy * W) / (dy @ (dy * W))
            ev = evn
        return None, J, why, opts.newton_max

    def fail(omega: float, why: str, where: str) -> None:
        failures.append(ForcedFailure(omega, forcing, why))
        warnings.warn(f"FRC CBC {where} Ω={omega:.4g}: {why}.", ConvergenceWarning,
                      stacklevel=3)

    def record(ev: _FRCEval, iterations: int) -> None:
        a1 = max(math.hypot(ev.y[0], ev.y[1]), 1e-300)
        om = float(ev.y[2])
        pt = _point(rig, opts, om, forcing, 0.0, ev.pstar, ev.r,
                    ev.u / _gain(opts, om) / a1, iterations)
        pt.forcing_floor, pt.measured_periods = ev.r.ufloor / forcing, ev.r.periods
        _record(rig, opts, pt, points, on_point)

    def y_of(pt: ForcedPoint) -> np.ndarray:
        c = np.asarray(pt.target.coefficients, dtype=float)
        if c.shape[0] != 2 * q + 1 or abs(pt.forcing - forcing) > 1e-12 * forcing:
            raise BifidInputError(
                f"cannot continue an FRC from a point with {(c.shape[0] - 1) // 2} "
                f"harmonics at γ = {pt.forcing:g} (this one: {q} harmonics, γ = {forcing:g})."
            )
        return np.array([c[1], c[q + 1], float(pt.omega)])

    t = np.array([0.0, 0.0, direction])
    if start is None:
        y = np.array([p0[1], p0[q + 1], w0])
        J, _ = fd_jac(evaluate(y))
        first, J, why, its = newton(y, np.array([0.0, 0.0, 1.0]), w0, J, 2.0 * opts.ds_max)
        if first is None:
            fail(w0, f"first point: {why}", "at")
            return points, failures
        record(first, its)
        ys = [first.y]
    else:
        # back onto the measured curve: hold the last target, settle, then go on
        state["pstar"] = np.array(start.target.coefficients, dtype=float)
        ys = ([y_of(previous)] if previous is not None else []) + [y_of(start)]
        J, _ = fd_jac(evaluate(ys[-1]))
    ds = opts.ds
    while len(points) < opts.max_points:
        if len(ys) >= 2:
            sec = ys[-1] - ys[-2]
            t = sec / math.sqrt(sec @ (W * sec))
        else:
            t = t / math.sqrt(t @ (W * t))
        y_pred = ys[-1] + ds * t
        row = W * t
        try:
            new, Jn, why, its = newton(y_pred, row, float(row @ y_pred), J, 2.0 * ds)
        except ConvergenceError as exc:
            new, why = None, f"rig failure: {exc}"
        if new is None:
            if ds > opts.ds / 16 and not isinstance(why, _NoiseLimited):
                ds /= 2
                J, _ = fd_jac(evaluate(ys[-1]))
                continue
            fail(float(y_pred[2]), why, "stopped near")
            break
        J = Jn
        record(new, its)
        ys.append(new.y)
        turn = 0.0
        if len(ys) >= 3:
            a_, b_ = ys[-2] - ys[-3], ys[-1] - ys[-2]
            cosang = float(a_ @ (W * b_)) / math.sqrt(float(a_ @ (W * a_)) * float(b_ @ (W * b_)))
            turn = math.degrees(math.acos(max(-1.0, min(1.0, cosang))))
        if turn > opts.max_turn:
            ds = max(opts.ds / 8, ds * 0.5)
        elif turn < opts.max_turn / 2:
            ds = min(opts.ds_max, ds * 1.3)
        om = float(new.y[2])
        if (om - w1) * direction > 0 or (om - w0) * direction < 0:
            break
    return points, failures
