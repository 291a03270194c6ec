"""Phase-plane CBC (PP-CBC) of self-excited systems, thesis §3.3: options, the measured
zero problem, and the limit cycles it records.

The controller ``u = kp (x1* - x1) + kd (x2* - x2)`` acts on a rig through its actuator;
its target is a closed curve in the measured phase plane ``(x1, x2)``, locked to the
response by the measured angle ``φ`` (eqs. 3.13-3.15, 3.20-3.22, 3.27-3.29; the target
families are in :mod:`bifid.cbc._ppcbc_family`). A target is *non-invasive* when the
measured curve equals it; the controller then only stabilises, so the measured orbit is
an orbit of the uncontrolled system, stable or not.

The zero problem (:class:`PPCBCProblem`, eqs. 3.23-3.24, Example 3.3) has the target's
unknowns ``c*`` and the parameter ``λ`` as unknowns,

.. math:: G(c^*, λ) = c^* - Φ\bigl(\text{response to } c^* \text{ at } λ\bigr) = 0,

with ``Φ`` the measured curve read in the target's terms. It is solved by the Broyden
corrector of :mod:`bifid.cbc._measured`: at fixed ``λ`` after an amplitude scan
(:mod:`bifid.cbc._ppcbc_scan`, §3.3.3.2), and along a branch by the continuation driver
(:mod:`bifid.cbc._campaign`). Every converged orbit is then labelled stable or unstable by
switching the controller off (:func:`bifid.cbc._stability.switch_off_test`). A converged
point whose control is not small is rejected (:class:`Invasive`) and never recorded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from bifid.cbc._controllers import AbstractTarget, PDController, target_to_json
from bifid.cbc._measured import Evaluation, MeasuredProblem, ProtocolOptions, run
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.cbc._stability import switch_off_test
from bifid.errors import BifidInputError
from bifid.signal import (
    coefficient_noise,
    evaluate_series,
    fourier_project,
    periodic_amplitude,
    whole_periods,
)

if TYPE_CHECKING:
    from bifid.cbc._ppcbc_family import Response, TargetFamily

__all__ = ["Invasive", "LCOPoint", "PPCBCOptions", "PPCBCProblem", "make_point"]


#: a measured noise floor is this many standard deviations of the noise
FLOOR_SIGMAS = 3.0


@dataclass(frozen=True)
class PPCBCOptions(ProtocolOptions):
    """Numbers that steer PP-CBC; checked when built.

    Parameters
    ----------
    x1, x2 : str
        The phase-plane signals (e.g. ``"h"`` and ``"h_dot"``); ``x1`` is also the
        signal whose amplitude the scan zeroes.
    kp, kd : float
        Controller gains (:class:`~bifid.cbc.PDController`).
    target : {"polar", "elliptic"}
        Target family.
    n_harmonics : int
        ``n_h`` of the polar target (eq. 3.22).
    settle_periods, measure_periods : float
        Periods to wait after a target change, and to record for the projections.
    tol : float
        Relative tolerance on the control error (``|Ξ| / A*`` for the scan, the
        max-norm of ``G`` over ``a0*`` for continuation) *and* on the last secant/Newton
        step (the error estimate of the target); the measurement-noise floor of the
        projections is added automatically.
    amp_tol : float
        Relative accuracy of a zero ``A*`` of the scan's control error (estimated from
        the residual over the slope of ``Ξ`` and the last secant step).
    max_invasiveness : float
        A converged point whose control is larger than this fraction of the feedback
        (``rms(u) / rms(kp x1 + kd x2)``) is rejected as invasive (controller lost).
    picard_max : int
        Picard iterations on the target shape per amplitude.
    secant_max : int
        Secant iterations per zero of ``Ξ``.
    newton_max : int
        Newton/Broyden iterations per continuation point.
    fd_step : float
        Finite-difference step of the Jacobian, relative to ``a0*``.
    stability : bool
        Label orbits by the switch-off test.
    nudge, watch_periods : float
        Relative target nudge before switch-off and the longest watch.
    bootstrap_gains : (float, float), optional
        ``(kp, kd)`` of an elliptic ``(x1, ẋ1)`` target that starts the oscillation from
        rest (default: the protocol's own plane and gains).
    filter_hz : float, optional
        Cut-off of the controller's output low-pass (:class:`~bifid.cbc.PDController`):
        keeps the gains from passing broadband measurement noise to the actuator.
    max_turn : float
        Continuation: largest angle [deg] between successive secants before the next
        step is halved (resolves the cycle folds).
    precision : float
        Largest noise floor of a converged point relative to ``a0*``: while it is larger,
        the record at the converged target is doubled (up to ``max_extension`` times the
        measured periods) and the point checked again. Near a Hopf point the response
        follows the target closely, so a control error within the floor moves the
        measured amplitude by several times the floor.
    max_extension : float
        Longest record of a converged point, in multiples of ``measure_periods``.
    zero_precision : float
        Largest standard error of the converged ``a0*`` relative to ``a0*``: the noise of
        ``G`` carried through the Jacobian (``[G_y; e_λ]⁻¹``, eq. 3.24 at fixed ``λ``).
        Near a Hopf point the response follows the target, ``G`` is flat in ``a0*`` and
        a floor far below ``precision`` still moves the zero by percent: while this is
        larger the record is extended as for ``precision``; a point still above it at
        the longest record is a failure (noise-limited), in the amplitude scan's secant
        too (its floor over its slope).
    centre : (float, float)
        Where the bootstrap's first target is centred in ``(x1, x2)``: the rig's rest
        position (the system's equilibrium).
    """

    x1: str = "h"
    x2: str = "h_dot"
    kp: float = 50.0
    kd: float = 40.0
    target: str = "polar"
    n_harmonics: int = 10
    settle_periods: float = 10.0
    measure_periods: float = 5.0
    tol: float = 1e-4
    amp_tol: float = 1e-3
    max_invasiveness: float = 0.05
    picard_max: int = 12
    secant_max: int = 25
    newton_max: int = 12
    fd_step: float = 0.01
    stability: bool = True
    nudge: float = 0.05
    watch_periods: float = 20.0
    bootstrap_gains: tuple[float, float] | None = None
    filter_hz: float | None = None
    max_turn: float = 20.0
    precision: float = 2e-4
    max_extension: float = 8.0
    zero_precision: float = 4e-3
    centre: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if self.target not in ("polar", "elliptic"):
            raise BifidInputError(f"target must be 'polar' or 'elliptic', got {self.target!r}.")
        self.check(
            (
                "settle_periods",
                "measure_periods",
                "tol",
                "fd_step",
                "watch_periods",
                "amp_tol",
                "max_invasiveness",
                "precision",
                "max_extension",
                "zero_precision",
            ),
            ("picard_max", "secant_max", "newton_max"),
        )
        if self.measure_periods < 1:
            raise BifidInputError("measure_periods must be >= 1 (projections over whole periods).")
        self.controller  # noqa: B018 - validates gains, names and filter

    @property
    def controller(self) -> PDController:
        return PDController(self.kp, self.kd, self.x1, self.x2, self.filter_hz)


@dataclass
class LCOPoint:
    """A limit cycle measured by PP-CBC with a non-invasive controller.

    Attributes
    ----------
    param : float
        Value of the bifurcation parameter.
    target : AbstractTarget
        The converged (non-invasive) target.
    measurement : Measurement
        The record over whole periods with the converged controller on.
    frequency : float
        [rad/s].
    amplitude, offset : dict
        ``max_t |x(t) - x̄|`` (Fourier-filtered) and ``x̄`` per output.
    stable : bool or None
        From the switch-off test (None: not tested or undecided).
    growth : float
        Per-period growth factor of a perturbation after switch-off.
    control_rms : float
        RMS of the control signal.
    invasiveness : float
        ``rms(u) / rms(kp (x1 - x̄1) + kd (x2 - x̄2))``: the control relative to what the
        same gains would apply if the target were the centre.
    invasiveness_periodic : float
        The same with ``u`` replaced by its periodic part (mean and ``max(10, n_h)``
        harmonics of ``ω`` fitted over the record): measurement noise that the controller
        passes on (``kp ε1 + kd ε2``, zero-mean and broadband) is left out, the
        deterministic control that would bias the orbit is kept.
    tracking_error : float
        ``rms(x1* - x1) / rms(x1 - x̄1)``.
    residual : float
        Final relative control error (``|Ξ|/A*`` or ``max|G|/a0*``).
    iterations : int
        Rig evaluations (settle + measure) spent on this point.
    branch : str
        "scan" or "continuation".
    signal : str
        The controller's first signal ``x1`` (whose target ``measurement.target`` is).
    """

    param: float
    target: AbstractTarget
    measurement: Measurement
    frequency: float
    amplitude: dict[str, float]
    offset: dict[str, float]
    stable: bool | None = None
    growth: float = math.nan
    control_rms: float = math.nan
    invasiveness: float = math.nan
    invasiveness_periodic: float = math.nan
    tracking_error: float = math.nan
    residual: float = math.nan
    iterations: int = 0
    branch: str = "scan"
    signal: str = ""

    def to_json(self, param_name: str = "param") -> dict[str, Any]:
        return {
            param_name: self.param,
            "param": self.param,
            "amplitude": dict(self.amplitude),
            "offset": dict(self.offset),
            "frequency": self.frequency,
            "stable": self.stable,
            "growth": self.growth,
            "control_rms": self.control_rms,
            "invasiveness": self.invasiveness,
            "invasiveness_periodic": self.invasiveness_periodic,
            "tracking_error": self.tracking_error,
            "residual": self.residual,
            "iterations": self.iterations,
            "target": target_to_json(self.target),
        }


#: largest half-frequency content of an accepted point, of its fundamental (period-one
#: records measured here show at most 0.014 %, period-doubled ones 1.2–9 %)
SUBHARMONIC_MAX = 0.01


def subharmonic(x: np.ndarray, omega: float, sample_rate: float) -> float:
    """Half-frequency content of a record, relative to its fundamental: the amplitudes at
    ``ω/2`` and ``3ω/2`` of a least-squares fit (with the mean and ``ω``) over the whole
    double periods of the record, less what its noise explains (a 3σ floor per
    coefficient); 0 for a record shorter than two periods. A period-doubled orbit has it;
    a period-one orbit with measurement noise or a decaying transient (energy near ``ω``)
    does not."""
    x = np.asarray(x, dtype=float)
    double = 2.0 * 2.0 * math.pi / omega * sample_rate  # samples of two periods
    n = round(math.floor(x.shape[0] / double) * double)
    if n < 2:
        return 0.0
    x = x[-n:]  # whole double periods: the half-frequency terms are orthogonal to the rest
    th = omega * np.arange(n) / sample_rate
    B = np.column_stack(
        [np.ones(n)] + [f(k * th) for k in (0.5, 1.0, 1.5) for f in (np.cos, np.sin)]
    )
    c, *_ = np.linalg.lstsq(B, x, rcond=None)
    floor = coefficient_noise(x - B @ c)
    half = math.hypot(c[1], c[2]) + math.hypot(c[5], c[6])
    return max(half - 2.0 * floor, 0.0) / max(math.hypot(c[3], c[4]), 1e-300)


class Invasive(Exception):
    """A 'converged' point whose control is not small: rejected, reported as a failure."""


class PPCBCProblem(MeasuredProblem):
    """The PP-CBC zero problem ``G(c*, λ) = c* - Φ(response)`` on a rig (module docstring).

    Unknowns ``y = [c*, λ]``; the arclength metric ``W = diag(1/a_ref², …, 1/λ_ref²)``
    (each target unknown expressed in amplitude units first).

    Parameters
    ----------
    rig : AbstractRig
    opts : PPCBCOptions
    family : TargetFamily
    param : str
        The rig parameter ``λ`` (e.g. ``"U"``).
    omega : float
        Frequency estimate [rad/s]; updated by every evaluation.
    vec_ref : ndarray
        A target near the branch (sets ``a_ref`` and the unit conversions).
    param_scale : float
        ``λ_ref``.
    """

    retry_noise_limited = True

    def __init__(
        self,
        rig: AbstractRig,
        opts: PPCBCOptions,
        family: TargetFamily,
        param: str,
        omega: float,
        vec_ref: np.ndarray,
        param_scale: float = 1.0,
    ) -> None:
        self.rig, self.opts, self.family, self.param = rig, opts, family, param
        self.omega = float(omega)
        self.n = family.size
        self.param_index = self.n
        self.vec_ref = np.array(vec_ref, dtype=float)
        self.vec_start = self.vec_ref.copy()
        self.a_ref = max(abs(float(vec_ref[0])), 1e-300)
        self.param_scale = float(param_scale)
        self._scales = family.scales(np.asarray(vec_ref, dtype=float))
        self.weights = np.concatenate(
            [(self._scales / self.a_ref) ** 2, [1.0 / self.param_scale**2]]
        )
        self._metric = self.weights.copy()

    @property
    def metric(self) -> np.ndarray:
        return self._metric

    def rescale(self, y: np.ndarray) -> None:
        """The corrector's scales follow the branch (its trust region and finite
        differences in proportion to the current LCO, small or large); the arclength
        keeps the scale of the branch's start."""
        self.vec_ref = np.array(y[: self.n], dtype=float)
        self.a_ref = max(abs(float(y[0])), 1e-300)
        self._scales = self.family.scales(self.vec_ref)
        self._metric[: self.n] = (self._scales / self.a_ref) ** 2

    def evaluate(self, y: np.ndarray) -> Evaluation:
        lam = float(y[-1])
        if self.rig.get_parameter(self.param) != lam:
            self.rig.set_parameter(self.param, lam)
        resp = self.family.hold(self.rig, self.family.target(y[: self.n]), self.omega)
        self.omega = resp.omega
        floor = np.full(self.n, resp.floor) / self._scales
        return Evaluation(np.array(y, dtype=float), y[: self.n] - resp.vector, floor, resp)

    def tolerance(self, ev: Evaluation) -> np.ndarray:
        return (self.opts.tol * abs(float(ev.y[0])) + ev.info.floor) / self._scales

    def step_tolerance(self, ev: Evaluation) -> np.ndarray:
        return np.concatenate([self.opts.amp_tol * abs(float(ev.y[0])) / self._scales, [math.inf]])

    def _periods(self, resp: Response) -> float:
        return len(resp.m) * resp.omega / (2.0 * math.pi * resp.m.sample_rate)

    def zero_errors(self, ev: Evaluation) -> tuple[float, float]:
        """Standard errors of the zero's ``a0*`` and ``λ``, relative to ``a0*`` and to
        ``max(|λ|, s_λ)`` (``s_λ`` the parameter's scale): the noise of ``G`` (its floors)
        carried through the corrector's Jacobian bordered by its constraint row
        (:attr:`~bifid.cbc._measured.MeasuredProblem.constraint`; fixed ``λ``, whose
        error is then 0, without one); zeros without a Jacobian.

        At fixed ``λ`` the error of ``a0*`` grows without bound at a cycle fold (``G_y``
        at fixed ``λ`` is singular there); the arclength row keeps the bordered system
        regular through the fold, where the point's error lies along the normal to the
        branch, mostly in ``λ``."""
        J = self.jacobian
        if J is None or J.shape != (self.n, self.n + 1):
            return 0.0, 0.0
        row = self.constraint
        if row is None or row.shape != (self.n + 1,):
            row = np.zeros(self.n + 1)
            row[-1] = 1.0
        with np.errstate(all="ignore"):
            try:
                inv = np.linalg.solve(np.vstack([J, row[None, :]]), np.eye(self.n + 1)[:, : self.n])
            except np.linalg.LinAlgError:
                return math.inf, math.inf
        # (the components' noises independent)
        s_a, s_p = (float(np.linalg.norm(inv[i] * ev.floor)) / FLOOR_SIGMAS for i in (0, -1))
        e_a = s_a / max(abs(float(ev.y[0])), 1e-300)
        e_p = s_p / max(abs(float(ev.y[-1])), self.param_scale)
        return tuple(e if math.isfinite(e) else math.inf for e in (e_a, e_p))

    def zero_noise(self, ev: Evaluation) -> float:
        """The zero's relative standard error, ``hypot`` of :meth:`zero_errors`."""
        return math.hypot(*self.zero_errors(ev))

    def precise(self, ev: Evaluation) -> bool:
        """The floor is below ``precision`` (of ``a0*``) and the zero's noise below
        ``zero_precision`` (:meth:`zero_noise`); at the longest record the floor passes,
        the zero's noise must (else the point is noise-limited)."""
        resp: Response = ev.info
        longest = self.opts.max_extension * self.opts.measure_periods
        zero_ok = self.zero_noise(ev) <= self.opts.zero_precision
        if self._periods(resp) >= longest - 0.5:
            return zero_ok
        return zero_ok and resp.floor <= self.opts.precision * abs(float(ev.y[0]))

    def imprecision(self, ev: Evaluation) -> str:
        e_a, e_p = self.zero_errors(ev)
        return (
            f"the zero has a standard error of {100 * self.zero_noise(ev):.2g} % (a0* "
            f"{100 * e_a:.2g} %, {self.param} {100 * e_p:.2g} %; noise carried through the "
            f"Jacobian; limit {100 * self.opts.zero_precision:g} "
            f"%) at the longest record ({self.opts.max_extension:g} x measure_periods): the "
            "control error is too flat in the target's amplitude here (near a Hopf point) "
            "for the measurement noise"
        )

    def extend(self, ev: Evaluation) -> Evaluation | None:
        """Twice as long a record at the same target (the rig is already there)."""
        resp: Response = ev.info
        periods = self._periods(resp)
        longest = self.opts.max_extension * self.opts.measure_periods
        if periods >= longest - 0.5:
            return None
        n_periods = min(2.0 * round(periods), longest)
        m = run(self.rig, n_periods * 2.0 * math.pi / resp.omega + 2.0 / self.rig.sample_rate)
        new = self.family.analyse(m, resp.omega)
        self.omega = new.omega
        floor = np.full(self.n, new.floor) / self._scales
        return Evaluation(ev.y.copy(), ev.y[: self.n] - new.vector, floor, new)

    def fd_steps(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = np.concatenate(
            [self.opts.fd_step * self.a_ref / self._scales, [self.opts.fd_step * self.param_scale]]
        )
        return h, 10.0 * h

    def state(self) -> dict[str, Any]:
        """What rebuilding this problem needs (besides the options): ``vec_ref`` sets the
        arclength's scales, ``vec_now`` the corrector's (:meth:`rescale`)."""
        return {
            "omega": self.omega,
            "frame": self.family.frame(),
            "vec_ref": self.vec_start.tolist(),
            "vec_now": self.vec_ref.tolist(),
            "param_scale": self.param_scale,
        }


def make_point(
    rig: AbstractRig,
    opts: PPCBCOptions,
    family: TargetFamily,
    ev: Evaluation,
    evaluations: int,
    branch: str,
) -> LCOPoint:
    """An :class:`LCOPoint` of a converged evaluation (labelled by the switch-off test).

    Raises
    ------
    Invasive
        If the converged control is larger than ``max_invasiveness`` of the feedback.
    """
    resp: Response = ev.info
    target = family.target(ev.y[: family.size])
    value = float(ev.y[-1])
    om = resp.omega
    amps, offs = {}, {}
    for i, name in enumerate(resp.m.output_names):
        a, mean = periodic_amplitude(
            resp.m.outputs[:, i], om, resp.m.sample_rate, n_harmonics=max(10, opts.n_harmonics)
        )
        amps[name], offs[name] = a, mean
    m = resp.m.tail(whole_periods(len(resp.m), om, resp.m.sample_rate))
    x1, x2 = m.signal(opts.x1), m.signal(opts.x2)
    feedback = opts.kp * (x1 - x1.mean()) + opts.kd * (x2 - x2.mean())
    u_rms = float(np.sqrt(np.mean(m.control**2)))
    fb_rms = max(float(np.sqrt(np.mean(feedback**2))), 1e-300)
    inv = u_rms / fb_rms
    theta = om * np.arange(len(m)) / m.sample_rate
    u_fit = evaluate_series(fourier_project(m.control, theta, max(10, opts.n_harmonics)), theta)
    inv_per = float(np.sqrt(np.mean(u_fit**2))) / fb_rms
    trk = float(np.sqrt(np.mean((m.target - x1) ** 2)) / max(np.std(x1), 1e-300))
    pt = LCOPoint(
        param=value,
        target=target,
        measurement=m,
        frequency=om,
        amplitude=amps,
        offset=offs,
        control_rms=u_rms,
        invasiveness=inv,
        invasiveness_periodic=inv_per,
        tracking_error=trk,
        residual=ev.residual / max(abs(float(ev.y[0])), 1e-300),
        iterations=int(evaluations),
        branch=branch,
        signal=opts.x1,
    )
    if not inv <= opts.max_invasiveness:
        raise Invasive(
            f"the converged control is invasive (rms(u)/rms(feedback) = {inv:.2g} "
            f"> {opts.max_invasiveness:g}): the controller does not hold an orbit "
            "of the uncontrolled system here"
        )
    sub = subharmonic(resp.m.signal(opts.x1), om, resp.m.sample_rate)
    if sub > SUBHARMONIC_MAX:
        raise Invasive(
            "the response is not periodic at the target's period: its half-frequency "
            f"content is {100 * sub:.2g} % of its fundamental (a period-doubled orbit: "
            "the controller does not stabilise the orbit's period-doubling mode)"
        )
    if opts.stability:
        a1 = _first_harmonic_amplitude(m.signal(opts.x1), om, m.sample_rate)
        res, _ = switch_off_test(
            rig,
            opts.x1,
            a1,
            om,
            controller=opts.controller,
            nudged_target=family.nudged(target, opts.nudge),
            restore_target=target,
            watch_periods=opts.watch_periods,
        )
        rig.run(opts.settle_periods * 2.0 * math.pi / om)
        pt.stable, pt.growth = res.stable, res.growth
    return pt


def _first_harmonic_amplitude(x: np.ndarray, omega: float, fs: float) -> float:
    n = whole_periods(x.shape[0], omega, fs)
    c = fourier_project(x[-n:], omega * np.arange(n) / fs, 1)
    return math.hypot(c[1], c[2])
