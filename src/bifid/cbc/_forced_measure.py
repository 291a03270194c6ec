"""Forced CBC measurements, thesis §3.2: options, the measured point, projections.

The rig is excited by ``γ cos(θ - ψ)``, ``θ̇ = Ω`` (``Â = γ cos ψ``, ``B̂ = γ sin ψ`` in
the notation of eq. 3.1), and a PD controller (eq. 3.2) on the observed coordinate
``x`` tracks the target of eq. 3.3

.. math:: x^*(θ) = A_0^*/2 + \\sum_{j=1}^q A_j^*\\cos jθ + B_j^*\\sin jθ .

The response's coefficients ``p`` and the control's are measured over whole forcing
periods after settling, with their noise floors (:func:`project`); non-invasiveness is
``p(p*) = p*`` (eq. 3.4). The zero problem of S-curves and FRCs is in
:mod:`bifid.cbc._forced`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.interpolate import CubicSpline

from bifid.cbc._controllers import FourierTarget, PDController
from bifid.cbc._measured import ProtocolOptions, run
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.cbc._stability import switch_off_test
from bifid.errors import BifidInputError
from bifid.signal import (
    band_noise,
    coefficient_noise,
    evaluate_series,
    fourier_project,
    whole_periods,
)

__all__ = [
    "ForcedCBCOptions",
    "ForcedPoint",
    "Projection",
    "fold_points",
    "folds_of",
    "gain",
    "make_forced_point",
    "measure",
    "project",
    "turning_points",
]


@dataclass(frozen=True)
class ForcedCBCOptions(ProtocolOptions):
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
    max_turn: float = 12.0
    newton_max: int = 10
    stability: bool = False
    nudge: float = 0.05
    watch_periods: float = 40.0
    precision: float = 0.005
    max_measure_periods: float = 400.0
    stored_periods: float = 20.0

    def __post_init__(self) -> None:
        self.check(
            (
                "settle_periods",
                "measure_periods",
                "tol",
                "ds",
                "ds_max",
                "watch_periods",
                "precision",
                "max_measure_periods",
                "stored_periods",
            ),
            ("picard_max", "max_points", "newton_max"),
        )
        if self.max_measure_periods < self.measure_periods:
            raise BifidInputError(
                f"max_measure_periods ({self.max_measure_periods}) must be at least "
                f"measure_periods ({self.measure_periods})."
            )
        if self.ds > self.ds_max:
            raise BifidInputError(f"ds ({self.ds}) must not exceed ds_max ({self.ds_max}).")
        PDController(self.kp, self.kd, self.signal, f"{self.signal}_dot")

    @property
    def controller(self) -> PDController:
        return PDController(self.kp, self.kd, self.signal, f"{self.signal}_dot")


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


# ------------------------------------------------------------------------------ helpers
def _to_eq33(c: np.ndarray) -> np.ndarray:
    """``[c0, a.., b..]`` (mean c0) to eq. 3.3's ``[A0, A.., B..]`` (mean A0/2)."""
    p = np.array(c, dtype=float)
    p[0] *= 2.0
    return p


@dataclass
class Projection:
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
        if (
            isinstance(v, np.ndarray)
            and isinstance(w, np.ndarray)
            and v.shape[:1] == (n_a,)
            and w.shape[:1] == (n_b,)
        ):
            extra[k] = np.concatenate([v, w])
        else:
            extra[k] = v
    return Measurement(
        time=np.concatenate([a.time, b.time]),
        outputs=np.concatenate([a.outputs, b.outputs]),
        output_names=a.output_names,
        derivatives=np.concatenate([a.derivatives, b.derivatives]),
        control=np.concatenate([a.control, b.control]),
        target=np.concatenate([a.target, b.target]),
        force=np.concatenate([a.force, b.force]),
        phase=np.concatenate([a.phase, b.phase]),
        sample_rate=a.sample_rate,
        saturated=a.saturated + b.saturated,
        extra=extra,
    )


def _record_periods(rig: AbstractRig, omega: float, periods: float) -> Measurement:
    m = run(rig, periods * 2.0 * math.pi / omega + 2.0 / rig.sample_rate)
    return m.tail(whole_periods(len(m), omega, m.sample_rate))


def project(opts: ForcedCBCOptions, m: Measurement, omega: float) -> Projection:
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
    return Projection(_to_eq33(cx), cu, m, floor, ufloor, periods)


def measure(
    rig: AbstractRig,
    opts: ForcedCBCOptions,
    omega: float,
    settle: float,
    periods: float | None = None,
) -> Projection:
    """Settle, record whole periods, project response and control on the generator phase."""
    if settle > 0:
        run(rig, settle * 2.0 * math.pi / omega)
    periods = opts.measure_periods if periods is None else periods
    return project(opts, _record_periods(rig, omega, periods), omega)


def extend(rig: AbstractRig, opts: ForcedCBCOptions, omega: float, r: Projection) -> Projection:
    """Keep measuring (no change, no settling) to double the record, up to the budget."""
    more = min(r.periods, opts.max_measure_periods - r.periods)
    more = max(1.0, float(math.floor(more + 1e-9)))
    m = _concat(r.m, _record_periods(rig, omega, more))
    return project(opts, m, omega)


def _lag(p: np.ndarray, psi: float, q: int) -> float:
    """Lag of the response's first harmonic behind the force ``γ cos(θ - ψ)``."""
    phi_x = math.atan2(p[q + 1], p[1])
    lag = phi_x - psi
    return float((lag + math.pi / 2) % (2 * math.pi) - math.pi / 2)


def make_forced_point(
    rig: AbstractRig,
    opts: ForcedCBCOptions,
    omega: float,
    gamma: float,
    psi: float,
    pstar: np.ndarray,
    r: Projection,
    residual: float,
    iterations: int,
) -> ForcedPoint:
    """A :class:`ForcedPoint` of a converged projection (labelled by the switch-off test
    when ``opts.stability``)."""
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
    m = m.tail(
        whole_periods(
            len(m), omega, m.sample_rate, max_periods=max(1, math.floor(opts.stored_periods + 1e-9))
        )
    )
    pt = ForcedPoint(
        omega=omega,
        forcing=gamma,
        force_phase=psi,
        target=FourierTarget(pstar),
        coefficients=p,
        measurement=m,
        amplitude=amp,
        phase=_lag(p, psi, q),
        control_rms=u_rms,
        invasiveness=inv,
        residual=residual,
        iterations=iterations,
        forcing_floor=r.ufloor / max(gamma, 1e-300),
        measured_periods=r.periods,
    )
    if opts.stability:
        _stability(rig, opts, pt)
    return pt


def _stability(rig: AbstractRig, opts: ForcedCBCOptions, pt: ForcedPoint) -> None:
    """Switch-off test for a forced response (the force stays on), Fig. 3.18."""
    q = opts.n_harmonics
    nudged = pt.target.coefficients.copy()
    nudged[1:] *= 1.0 - opts.nudge
    a1 = math.hypot(pt.coefficients[1], pt.coefficients[q + 1])
    res, _ = switch_off_test(
        rig,
        opts.signal,
        a1,
        pt.omega,
        controller=opts.controller,
        nudged_target=FourierTarget(nudged),
        restore_target=pt.target,
        watch_periods=opts.watch_periods,
    )
    pt.stable, pt.growth = res.stable, res.growth
    run(rig, opts.settle_periods * 2.0 * math.pi / pt.omega)


def gain(opts: ForcedCBCOptions, omega: float) -> float:
    """``|k_p + i Ω k_d|``: control per unit tracking error at the fundamental."""
    return math.hypot(opts.kp, omega * opts.kd)


def folds_of(points: list[ForcedPoint], key: str = "forcing") -> list[dict[str, float]]:
    """Folds of a measured forced curve (:func:`fold_points` of ``key`` against the
    amplitude): ``[{key: value, "amplitude": value}]``."""
    v = np.array([getattr(pt, key) for pt in points], dtype=float)
    a = np.array([pt.amplitude for pt in points], dtype=float)
    return [{key: f, "amplitude": amp} for f, amp, _ in fold_points(v, a)]


def turning_points(v: np.ndarray) -> list[int]:
    """Indices of the robust local extrema of a measured sequence ``v`` (the folds of a
    curve measured point by point): the sign changes of ``Δv`` that survive the removal
    of noise.

    Near a fold the curve is tangent to the direction of ``v``, the steps in ``v`` between
    points are small and a noisy point can reverse ``Δv`` twice (a spurious pair of
    extrema). The scatter of ``v`` is estimated locally from third differences (blind to
    the quadratic shape of a fold: ``σ̂ = median|Δ³v| / (0.6745 √20)``, seven points
    round the pair); a pair of neighbouring extrema whose excursion is within ``3σ̂`` is
    removed (the smallest first, until none is), and so is an extremum within ``3σ̂`` of
    an end of the curve. What remains reverses ``v`` by more than its noise.
    """
    v = np.asarray(v, dtype=float)
    n = v.shape[0]
    if n < 3:
        return []
    d = np.diff(v)
    ext = [i for i in range(1, n - 1) if d[i - 1] * d[i] < 0]
    d3 = np.abs(np.diff(v, 3)) if n >= 4 else np.zeros(0)

    def floor(i: int, j: int) -> float:
        w = d3[max(min(i, j) - 3, 0) : min(max(i, j) + 1, d3.shape[0])]
        return 3.0 * float(np.median(w)) / (0.6745 * math.sqrt(20.0)) if w.size >= 3 else 0.0

    while ext:
        nodes = [0, *ext, n - 1]
        worst, pick = 1.0, None
        for k in range(len(nodes) - 1):
            i, j = nodes[k], nodes[k + 1]
            if k == 0 and len(nodes) == 2:
                continue
            lim = floor(i, j)
            if lim > 0 and abs(v[j] - v[i]) < worst * lim:
                worst, pick = abs(v[j] - v[i]) / lim, (i, j)
        if pick is None:
            break
        ext = [e for e in ext if e not in pick]
    return ext


def fold_points(v: np.ndarray, a: np.ndarray) -> list[tuple[float, float, int]]:
    """Folds of a measured curve ``(v_i, a_i)`` in the order measured: the robust local
    extrema of the parameter ``v`` (:func:`turning_points`), as ``(v, amplitude, i)``
    with ``i`` the point before the fold.

    Where the amplitude is monotone along the curve (an S-curve), ``v`` is a smooth
    function of the amplitude with a regular extremum at each fold: a cubic spline
    ``v(a)`` through all points is searched for the extrema between the points that
    bracket a change of direction (on duffing at Ω = 1.05 this locates the lower fold to
    0.1 % where a chord-length spline misses it by 1.8 %). Otherwise (an FRC, a branch of
    limit cycles round a cycle fold) the curve is parametrised by its cumulative chord
    length ``s`` in the normalised ``(v, a)`` plane and splines ``v(s)``, ``a(s)`` are
    searched the same way.
    """
    v, a = np.asarray(v, dtype=float), np.asarray(a, dtype=float)
    if v.shape[0] < 4:
        return []
    out = []
    if np.all(np.diff(a) > 0) or np.all(np.diff(a) < 0):
        order = np.argsort(a)
        spl = CubicSpline(a[order], v[order])
        for i in turning_points(v):
            grid = np.linspace(min(a[i - 1], a[i + 1]), max(a[i - 1], a[i + 1]), 4001)
            vals = spl(grid)
            j = int(np.argmax(vals) if v[i] > v[i - 1] else np.argmin(vals))
            before = i - 1 if (grid[j] - a[i]) * (a[i] - a[i - 1]) < 0 else i
            out.append((float(vals[j]), float(grid[j]), before))
        return out
    dv = np.diff(v) / max(np.ptp(v), 1e-300)
    da = np.diff(a) / max(np.ptp(a), 1e-300)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(dv, da))])
    idx = np.flatnonzero(np.concatenate([[True], np.diff(s) > 0]))
    s, v, a = s[idx], v[idx], a[idx]
    sv, sa = CubicSpline(s, v), CubicSpline(s, a)
    for i in turning_points(v):
        grid = np.linspace(s[i - 1], s[i + 1], 4001)
        vals = sv(grid)
        j = int(np.argmax(vals) if v[i] > v[i - 1] else np.argmin(vals))
        before = int(idx[i - 1] if grid[j] < s[i] else idx[i])
        out.append((float(vals[j]), float(sa(grid[j])), before))
    return out
