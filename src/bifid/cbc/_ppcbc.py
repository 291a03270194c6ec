"""Phase-plane CBC (PP-CBC) of self-excited systems, thesis §3.3.

The controller ``u = kp (x1* - x1) + kd (x2* - x2)`` acts on a rig through its actuator;
its target is a closed curve in the measured phase plane ``(x1, x2)``, locked to the
response by the measured angle ``φ`` (eqs. 3.13-3.15, 3.20-3.22, 3.27-3.29). A target is
*non-invasive* when the measured curve equals it; the controller then only stabilises, so
the measured orbit is an orbit of the uncontrolled system, stable or not.

Two target families, two ways of solving for non-invasiveness:

- **amplitude scan** (:func:`ppcbc_scan`, §3.3.3.2, as on the flutter rig): at a fixed
  parameter, the target's *shape* (elliptic: centre and aspect ratio ω*; polar: the
  harmonics ``a_j, b_j`` of ``r*(φ)``) is found by Picard iteration from the measured
  response, and the zeros of the control error ``Ξ(A*) = A* - A(A*)`` over the target
  amplitude ``A*`` (elliptic) or mean radius ``a0*`` (polar) are bracketed on a grid and
  refined by an Illinois secant. Each zero is an orbit of the uncontrolled system.
- **continuation** (:func:`ppcbc_continuation`, Example 3.3): the zero problem
  ``G(c*, λ) = c* - Φ(r(φ; c*, λ)) = 0`` (eqs. 3.23-3.24) for the ``2 n_h + 1`` polar
  coefficients plus the pseudo-arclength condition (eq. 3.5) in ``(c*, λ)``, solved by
  Newton with a finite-difference Jacobian updated by Broyden's rule.

Every converged orbit is then labelled stable or unstable by switching the controller off
(:func:`bifid.cbc._stability.switch_off_test`). Orbits that do not converge within their
budget are reported (:class:`~bifid.errors.ConvergenceWarning` and ``failures``) and never
returned as points.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from bifid.cbc._controllers import (
    AbstractTarget,
    EllipticTarget,
    PDController,
    PolarTarget,
    target_to_json,
)
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.cbc._secant import HarmonicSecant
from bifid.cbc._stability import StabilityResult, switch_off_test
from bifid.errors import BifidInputError, ConvergenceError, ConvergenceWarning
from bifid.signal import (
    coefficient_noise,
    estimate_frequency,
    evaluate_series,
    fourier_basis,
    fourier_project,
    periodic_amplitude,
    polar_project,
    uniform_basis,
    whole_periods,
)

__all__ = [
    "LCOPoint",
    "PPCBCFailure",
    "PPCBCOptions",
    "ppcbc_continuation",
    "ppcbc_scan",
    "ppcbc_sweep",
]


@dataclass(frozen=True)
class PPCBCOptions:
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

    def __post_init__(self) -> None:
        if self.target not in ("polar", "elliptic"):
            raise BifidInputError(f"target must be 'polar' or 'elliptic', got {self.target!r}.")
        if int(self.n_harmonics) < 1:
            raise BifidInputError(f"n_harmonics must be >= 1, got {self.n_harmonics!r}.")
        for name in ("settle_periods", "measure_periods", "tol", "fd_step", "watch_periods",
                     "amp_tol", "max_invasiveness"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise BifidInputError(f"{name} must be a positive number, got {v!r}.")
        if self.measure_periods < 1:
            raise BifidInputError("measure_periods must be >= 1 (projections over whole periods).")
        for name in ("picard_max", "secant_max", "newton_max"):
            if int(getattr(self, name)) < 1:
                raise BifidInputError(f"{name} must be a positive integer.")
        self.controller  # noqa: B018 - validates gains, names and filter

    @property
    def controller(self) -> PDController:
        return PDController(self.kp, self.kd, self.x1, self.x2, self.filter_hz)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


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


@dataclass
class PPCBCFailure:
    """A point that did not converge (never recorded as data)."""

    param: float
    reason: str
    data: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"param": self.param, "reason": self.reason, **self.data}


class _Invasive(Exception):
    """A 'converged' point whose control is not small: rejected, reported as a failure."""


# ----------------------------------------------------------------------------- measuring
@dataclass
class _Response:
    m: Measurement
    omega: float
    a0: float  # amplitude measure the zero problem acts on (A or mean radius)
    shape: np.ndarray  # elliptic: [aspect, o1, o2]; polar: [a_1..,b_1..]
    coeffs: np.ndarray | None  # polar coefficients [a0, a.., b..]
    floor: float  # noise floor of a0 (absolute)


class _Family:
    """Target family: how targets are built from (a0, shape) and read from responses."""

    def __init__(self, opts: PPCBCOptions, matrix: np.ndarray | None = None,
                 origin: tuple[float, float] = (0.0, 0.0)):
        self.o = opts
        self.matrix = np.eye(2) if matrix is None else np.asarray(matrix, dtype=float)
        self.inv = np.linalg.inv(self.matrix)
        self.origin = (float(origin[0]), float(origin[1]))

    # target from its unknowns
    def target(self, a0: float, shape: np.ndarray) -> AbstractTarget:
        if self.o.target == "elliptic":
            return EllipticTarget(max(a0, 0.0), float(shape[0]), (float(shape[1]), float(shape[2])))
        coef = np.concatenate([[max(a0, 0.0)], shape])
        T = self.matrix
        return PolarTarget(coefficients=coef, origin=self.origin,
                           transform=((T[0, 0], T[0, 1]), (T[1, 0], T[1, 1])))

    def _from_fit(self, c1: np.ndarray, c2: np.ndarray) -> tuple[float, np.ndarray,
                                                                   np.ndarray | None]:
        """``(a0, shape, polar coefficients)`` of the curve given by the time-domain fits."""
        q = (c1.shape[0] - 1) // 2
        if self.o.target == "elliptic":
            A1 = math.hypot(c1[1], c1[q + 1])
            A2 = math.hypot(c2[1], c2[q + 1])
            # sense of rotation in (x1, x2): sign of the area swept (a1 b2 - b1 a2)
            rot = 1.0 if (c1[1] * c2[q + 1] - c1[q + 1] * c2[1]) >= 0 else -1.0
            aspect = rot * A2 / max(A1, 1e-300)
            return A1, np.array([aspect, c1[0], c2[0]]), None
        grid = uniform_basis(2048, q)  # the fitted curve on 2048 uniform phases
        d1 = grid @ c1 - self.origin[0]
        d2 = grid @ c2 - self.origin[1]
        xi1 = self.inv[0, 0] * d1 + self.inv[0, 1] * d2
        xi2 = self.inv[1, 0] * d1 + self.inv[1, 1] * d2
        coef = polar_project(np.arctan2(xi2, xi1), np.hypot(xi1, xi2), self.o.n_harmonics)
        return float(coef[0]), coef[1:].copy(), coef

    def analyse(self, m: Measurement, omega_hint: float) -> _Response:
        """Measure the response curve in the target's own terms, with its noise floor.

        Both signals are first fitted in *time* by Fourier series at the measured
        frequency (linear in the data, so measurement noise averages out without bias);
        the curve's parameters (elliptic: amplitude, aspect ratio, centre; polar: the
        coefficients of eq. 3.24) are computed from the fitted curve. A radius computed
        sample by sample would be biased upwards by the noise of a derivative estimate.
        With three or more periods the quantities are computed period by period and
        averaged (batch means): the noise floor is 3 standard errors of that mean, which
        also captures the random motion that measurement noise injects through the
        controller, and single-period fits are immune to the phase diffusion of a noisy
        autonomous oscillation.
        """
        x1, x2 = m.signal(self.o.x1), m.signal(self.o.x2)
        om = estimate_frequency(x1, m.sample_rate, method="crossings")
        if not (om > 0 and math.isfinite(om)) or (
                omega_hint > 0 and not 1 / 3 < om / omega_hint < 3):
            # no oscillation, or crossings of measurement noise: a frequency this far from
            # the last one would make the next record absurdly short or long
            om = omega_hint
        if not (om > 0 and math.isfinite(om)):
            raise ConvergenceError("no oscillation found in the measured response.")
        n = whole_periods(x1.shape[0], om, m.sample_rate)
        x1, x2 = x1[-n:], x2[-n:]
        theta = om * np.arange(n) / m.sample_rate
        nfit = max(2 * self.o.n_harmonics, 12) if self.o.target == "polar" else 3
        B = fourier_basis(theta, nfit)  # computed once, its rows reused for every period
        c = fourier_project(np.column_stack([x1, x2]), theta, nfit, basis=B)
        a0, shape, coef = self._from_fit(c[:, 0], c[:, 1])
        resid = x1 - B @ c[:, 0]
        floor = coefficient_noise(resid) * float(np.hypot(*self.inv[:, 0]))
        per = 2.0 * math.pi / om * m.sample_rate
        k_per = round(n / per)
        if k_per >= 3:
            # batch means over single periods: also immune to the slow random walk of the
            # phase of a noisy autonomous oscillation, which smears a fit at one fixed
            # frequency over many periods (and biases its amplitude low)
            vals, coefs = [], []
            for k in range(k_per):
                lo, hi = round(k * per), round((k + 1) * per)
                ck = fourier_project(np.column_stack([x1[lo:hi], x2[lo:hi]]), theta[lo:hi],
                                     nfit, basis=B[lo:hi])
                a0k, shk, cok = self._from_fit(ck[:, 0], ck[:, 1])
                vals.append(np.concatenate([[a0k], shk]))
                coefs.append(cok)
            v = np.asarray(vals)
            mean = v.mean(axis=0)
            a0, shape = float(mean[0]), mean[1:]
            if coef is not None:
                coef = np.mean(np.asarray(coefs), axis=0)
            sd = np.std(v, axis=0, ddof=1) * np.concatenate([[1.0], self._shape_scale(a0, shape)])
            floor = max(floor, 3.0 * float(np.max(sd)) / math.sqrt(k_per))
        # a record that scatters by more than 1 % is not a steady orbit, not noise: cap the
        # floor so that it can never widen a tolerance enough to accept it
        floor = min(floor, 0.01 * abs(a0))
        return _Response(m, om, a0, shape, coef, floor)

    def _shape_scale(self, a0: float, shape: np.ndarray) -> np.ndarray:
        """Weights that express shape changes in units of the amplitude ``a0``."""
        if self.o.target == "elliptic":
            w = max(abs(shape[0]), 1e-12)
            return np.array([a0 / w, 1.0, 1.0 / w])
        return np.ones_like(shape)


def _evaluate(rig: AbstractRig, opts: PPCBCOptions, fam: _Family, target: AbstractTarget,
              omega: float, settle: float | None = None) -> _Response:
    period = 2.0 * math.pi / omega
    rig.set_controller(opts.controller, target)
    rig.run((opts.settle_periods if settle is None else settle) * period)
    m = rig.run(opts.measure_periods * period + 2.0 / rig.sample_rate)
    return fam.analyse(m, omega)


def _bootstrap(rig: AbstractRig, opts: PPCBCOptions, a_start: float, omega_guess: float
               ) -> tuple[float, float, tuple[float, float], tuple[float, float], np.ndarray]:
    """Start an oscillation and measure the curve it draws in the ``(x1, x2)`` plane.

    An elliptic target self-excites the rig from rest (the radial error acts as negative
    damping until ``ρ ≈ A*``): on the protocol's own plane and gains, or, with
    ``bootstrap_gains``, on ``(x1, ẋ1)`` with those gains (needed when the protocol's
    controller cannot start an oscillation, e.g. the heave-pitch controller of flutter).
    The curve measured in ``(x1, x2)`` gives the origin (centre), the aspect ratio with its
    sense of rotation (elliptic target) or the transform ``T`` that maps its
    first-harmonic ellipse to a circle (polar target), and the initial shape harmonics.

    Returns
    -------
    omega, aspect, origin, transform (2x2), shape0
    """
    derivative = opts.x2 == f"{opts.x1}_dot"
    if opts.bootstrap_gains is not None:
        kp, kd = opts.bootstrap_gains
        # its own plane and gains, validated without the protocol's output filter
        boot = PPCBCOptions(**{**opts.to_json(), "target": "elliptic",
                               "x2": f"{opts.x1}_dot", "kp": kp, "kd": kd,
                               "filter_hz": None})
        aspect0 = -omega_guess
    else:  # the protocol's own plane and gains (e.g. (u1, u2) of eq. 3.16)
        boot = PPCBCOptions(**{**opts.to_json(), "target": "elliptic"})
        aspect0 = -omega_guess if derivative else 1.0
    fam = _Family(boot)
    omega = omega_guess
    r = None
    # a target too small against the measurement noise can fail to lock (the angle of a
    # noisy (x1, ẋ1) is noise): try twice and four times the amplitude before giving up;
    # the frame measured there serves the scan's smaller targets as well
    for a_try in (a_start, 2.0 * a_start, 4.0 * a_start):
        shape = np.array([aspect0, 0.0, 0.0])
        for _ in range(4):
            r = _evaluate(rig, boot, fam, fam.target(a_try, shape), omega)
            # learn the ellipse only from a response that is not mostly noise: an aspect
            # ratio measured on noise (a differentiated one, in the (x1, ẋ1) plane) is
            # huge, and the next target would then ask for a huge ẋ1
            if (r.a0 > 1e-3 * a_try and np.all(np.isfinite(r.shape))
                    and 1 / 3 < abs(r.shape[0] / aspect0) < 3):
                omega = r.omega
                shape = r.shape
        if r.a0 > 0.1 * a_try:
            break
    assert r is not None
    if not r.a0 > 0.1 * a_try:
        raise ConvergenceError(
            f"the bootstrap controller did not start an oscillation (amplitude {r.a0:.3g} "
            f"for targets of {a_start:.3g} to {a_try:.3g}); give bootstrap_gains with "
            "kp, kd > 0."
        )
    # the curve in the protocol's own plane
    own = _Family(PPCBCOptions(**{**opts.to_json(), "target": "elliptic"}))
    e = own.analyse(r.m, omega)
    aspect, o1, o2 = (float(v) for v in e.shape)
    if opts.target == "elliptic":
        return omega, aspect, (o1, o2), np.eye(2), e.shape
    # T maps the measured first-harmonic ellipse to a circle of radius |x1's harmonic|
    m = r.m
    x1, x2 = m.signal(opts.x1), m.signal(opts.x2)
    n = whole_periods(x1.shape[0], omega, m.sample_rate)
    th = omega * np.arange(n) / m.sample_rate
    c = fourier_project(np.column_stack([x1[-n:], x2[-n:]]), th, 1)
    T = np.array([[c[1, 0], c[2, 0]], [c[1, 1], c[2, 1]]])
    A1 = math.hypot(c[1, 0], c[2, 0])
    if not (A1 > 0 and abs(np.linalg.det(T)) > 1e-9 * np.max(np.abs(T)) ** 2):
        raise ConvergenceError(
            f"the orbit is degenerate in the ({opts.x1}, {opts.x2}) plane (a line): choose "
            "two signals that are not in phase."
        )
    T = T / A1
    polar = _Family(opts, T, (float(c[0, 0]), float(c[0, 1])))
    pr = polar.analyse(r.m, omega)
    shape0 = pr.shape / max(pr.a0, 1e-300) * a_start  # the measured shape at amplitude A*
    return omega, aspect, (float(c[0, 0]), float(c[0, 1])), T, shape0


# ------------------------------------------------------------------------ amplitude scan
@dataclass
class _Eval:
    a_star: float
    xi: float
    shape: np.ndarray
    resp: _Response
    picard_ok: bool
    n: int


class _Scanner:
    """Picard on the shape for each amplitude, then Ξ(A*) = A* - A(A*)."""

    def __init__(self, rig, opts, fam, omega, shape):
        self.rig, self.o, self.fam = rig, opts, fam
        self.omega = omega
        self.shape = np.asarray(shape, dtype=float)
        self.evals = 0

    def __call__(self, a_star: float, sign_only: bool = False) -> _Eval:
        """Evaluate ``Ξ(A*)`` with the target shape converged by (accelerated) Picard.

        ``sign_only`` (grid points of the scan): stop as soon as the shape error is
        small against ``|Ξ|`` -- the sign of ``Ξ`` is then certain, and only the sign is
        needed to bracket zeros.
        """
        shape = self.shape.copy()
        ok = False
        resp = None
        n0 = self.evals
        polar = self.o.target == "polar"
        acc = HarmonicSecant(self.o.n_harmonics, fixed=(0,)) if polar else None
        for _ in range(self.o.picard_max):
            resp = _evaluate(self.rig, self.o, self.fam, self.fam.target(a_star, shape), self.omega)
            self.evals += 1
            self.omega = resp.omega
            # the shape's control error (target minus response), in units of A*
            err = float(np.max(np.abs(resp.shape - shape)
                               * self.fam._shape_scale(a_star, self.shape)))
            tol = self.o.tol * a_star + resp.floor
            if polar:
                assert acc is not None
                new = acc.step(np.concatenate([[a_star], shape]), resp.coeffs, resp.floor)
                new_shape = new[1:]
            else:
                new_shape = resp.shape
            if err <= tol:
                ok = True
                break
            if sign_only and err < 0.2 * abs(a_star - resp.a0):
                break
            shape = new_shape
        assert resp is not None
        self.shape = shape
        return _Eval(a_star, a_star - resp.a0, shape, resp, ok, self.evals - n0)


def _illinois(f: Callable[[float], _Eval], a: _Eval, b: _Eval, rel_tol: float,
              max_iter: int) -> tuple[_Eval | None, int]:
    """Root of ``Ξ`` between evaluations ``a`` and ``b`` (opposite signs).

    Converged when the error estimate of ``A*`` is below ``rel_tol · A*`` (plus what the
    noise floor of ``Ξ`` allows): the error estimate is the larger of ``|Ξ| / |Ξ'|`` (with
    the secant slope ``Ξ'`` of the bracket) and the next secant step. With a strong
    controller the response follows the target and ``Ξ = A* - A(A*)`` is flat near its
    zero, so a small ``|Ξ|`` alone does not bound the error of ``A*``; with a weak one
    ``Ξ`` is steep and a small error in ``A*`` shows as a large ``|Ξ|``.
    """
    fa, fb = a.xi, b.xi
    best: _Eval | None = None
    best_err = math.inf
    for it in range(max_iter):
        x = (a.a_star * fb - b.a_star * fa) / (fb - fa)
        stagnant = abs(x - b.a_star) <= 1e-9 * abs(x) and it > 0
        c = b if stagnant else f(x)
        if not stagnant:
            if c.xi * fb < 0:
                a, fa = b, fb
            else:
                fa = fa / 2.0
            b, fb = c, c.xi
        slope = abs((b.xi - a.xi) / (b.a_star - a.a_star)) if b.a_star != a.a_star else 0.0
        x_next = (a.a_star * fb - b.a_star * fa) / (fb - fa) if fb != fa else x
        if slope > 0:
            err = max(abs(c.xi) / slope, abs(x_next - c.a_star))
            allowed = rel_tol * c.a_star + c.resp.floor / slope
        else:
            err, allowed = math.inf, 0.0
        if c.picard_ok and err < best_err:
            best, best_err = c, err
        if c.picard_ok and err <= allowed:
            return c, it + 1
        if stagnant:
            break
    if best is not None and best_err <= 3.0 * rel_tol * best.a_star + best.resp.floor:
        return best, max_iter
    return None, max_iter


def ppcbc_scan(
    rig: AbstractRig,
    param: str,
    value: float,
    amplitudes: Sequence[float],
    options: PPCBCOptions | None = None,
    *,
    omega_guess: float = 1.0,
    on_point: Callable[[LCOPoint], None] | None = None,
    on_iteration: Callable[[int], None] | None = None,
    max_points: int | None = None,
) -> tuple[list[LCOPoint], list[PPCBCFailure]]:
    """All LCOs at one parameter value by the amplitude scan (thesis §3.3.3.2).

    Parameters
    ----------
    rig : AbstractRig
    param : str
        Parameter name on the rig (e.g. ``"U"``); set to ``value`` first.
    amplitudes : sequence of float
        Increasing grid of target amplitudes ``A*`` (of ``x1``'s first harmonic for the
        elliptic target, of the mean radius ``a0*`` in the target's coordinates -- close to
        the first-harmonic amplitude of ``x1`` -- for the polar one) on which
        sign changes of ``Ξ`` are looked for. Zeros closer than the grid spacing can be
        missed.
    options : PPCBCOptions
    omega_guess : float
        Rough oscillation frequency [rad/s] to start with.
    on_point : callable, optional
        Called with each converged (and labelled) point as soon as it exists.
    on_iteration : callable, optional
        Called with the number of rig evaluations so far.
    max_points : int, optional
        Stop as soon as this many LCOs are measured, with the rig left holding the last
        one (e.g. to start :func:`ppcbc_continuation` from it).

    Returns
    -------
    points : list of LCOPoint
        In increasing amplitude.
    failures : list of PPCBCFailure
    """
    opts = options or PPCBCOptions()
    grid = np.asarray(amplitudes, dtype=float)
    if grid.ndim != 1 or grid.size < 2 or np.any(np.diff(grid) <= 0) or grid[0] <= 0:
        raise BifidInputError("amplitudes must be an increasing grid of >= 2 positive values.")
    rig.set_parameter(param, value)
    points: list[LCOPoint] = []
    failures: list[PPCBCFailure] = []

    def fail(reason: str, **data: Any) -> None:
        f = PPCBCFailure(value, reason, dict(data))
        warnings.warn(f"PP-CBC at {param}={value:g}: {reason}", ConvergenceWarning,
                      stacklevel=3)
        failures.append(f)

    try:
        omega, aspect, origin, transform, shape0 = _bootstrap(rig, opts, float(grid[0]),
                                                              omega_guess)
    except ConvergenceError as exc:
        fail(f"the controller could not start an oscillation at A*={grid[0]:.4g}: {exc}")
        return points, failures
    if opts.target == "elliptic":
        fam = _Family(opts)
        shape0 = np.array([aspect, origin[0], origin[1]])
    else:
        fam = _Family(opts, transform, origin)
    scan = _Scanner(rig, opts, fam, omega, shape0)
    evals: list[_Eval] = []
    solver: _PolarSolver | None = None
    solver_J: np.ndarray | None = None

    a = float(grid[0])
    try:
        for a in grid:
            e = scan(float(a), sign_only=True)
            evals.append(e)
            if on_iteration is not None:
                on_iteration(scan.evals)
            if len(evals) < 2 or evals[-2].xi * e.xi >= 0:
                continue
            lo, hi = evals[-2], e
            n0 = scan.evals
            if opts.target == "polar":
                # Newton-Broyden on all the target's coefficients at fixed parameter,
                # from the secant estimate of the zero (robust where the shape's
                # Picard iteration converges slowly)
                x0 = (lo.a_star * hi.xi - hi.a_star * lo.xi) / (hi.xi - lo.xi)
                y0 = np.concatenate([[x0], scan.shape, [value]])
                fresh = solver is None or solver_J is None
                if solver is None:
                    solver = _PolarSolver(rig, opts, fam, param, scan.omega, float(x0),
                                          1.0, None)
                if fresh:
                    solver.state["omega"] = scan.omega
                    g0, _ = solver.G(y0)
                    solver_J = solver.jacobian(y0, g0, with_param=False)
                solver.state["omega"] = scan.omega
                br = (lo.a_star, hi.a_star)
                y, resp, J_new, res = solver.correct(y0, None, solver_J, bracket=br)
                if y is None and not fresh:  # a fresh Jacobian at the guess, once
                    solver.state["omega"] = scan.omega
                    g0, _ = solver.G(y0)
                    solver_J = solver.jacobian(y0, g0, with_param=False)
                    y, resp, J_new, res = solver.correct(y0, None, solver_J, bracket=br)
                scan.evals += solver.state["evals"]
                solver.state["evals"] = 0
                if on_iteration is not None:
                    on_iteration(scan.evals)
                if y is None:
                    # Newton cannot start here (e.g. from near a maximum of Ξ, where its
                    # Jacobian is singular in a0*): the bracketing secant on a0* with Picard
                    # on the shape, as for the elliptic target, always can
                    solver.state["omega"] = scan.omega
                    scan.shape = y0[1:-1]
                    root, _ = _illinois(scan, lo, hi, opts.amp_tol, opts.secant_max)
                    if on_iteration is not None:
                        on_iteration(scan.evals)
                    if root is None:
                        fail(f"neither Newton-Broyden on the polar target nor the secant on "
                             f"its amplitude converged in A* = [{lo.a_star:.4g}, "
                             f"{hi.a_star:.4g}]", bracket=[lo.a_star, hi.a_star])
                    else:
                        try:
                            pt = _finish_point(rig, opts, fam, root, value,
                                               scan.evals - n0 + lo.n + hi.n, "scan")
                        except _Invasive as exc:
                            fail(f"{exc} (A* = {root.a_star:.4g})", a_star=root.a_star)
                        else:
                            points.append(pt)
                            if on_point is not None:
                                on_point(pt)
                        scan.shape = root.shape
                        solver_J = None  # the last Jacobian did not help: rebuild next time
                else:
                    solver_J = J_new
                    try:
                        pt = _make_point(rig, opts, fam, fam.target(float(y[0]), y[1:-1]),
                                         resp, value, res, scan.evals - n0 + lo.n + hi.n,
                                         "scan")
                    except _Invasive as exc:
                        fail(f"{exc} (A* = {y[0]:.4g})", a_star=float(y[0]))
                    else:
                        points.append(pt)
                        if on_point is not None:
                            on_point(pt)
                    scan.shape = y[1:-1]
                if (max_points is not None and len(points) >= max_points) or a == grid[-1]:
                    break  # (nothing left to compare with at the last grid point)
                evals[-1] = scan(float(a), sign_only=True)
                continue
            root, _ = _illinois(scan, lo, hi, opts.amp_tol, opts.secant_max)
            if on_iteration is not None:
                on_iteration(scan.evals)
            if root is None:
                fail(f"control error did not converge to zero within {opts.secant_max} "
                     f"secant iterations in A* = [{lo.a_star:.4g}, {hi.a_star:.4g}]",
                     bracket=[lo.a_star, hi.a_star])
            else:
                try:
                    pt = _finish_point(rig, opts, fam, root, value,
                                       scan.evals - n0 + lo.n + hi.n, "scan")
                except _Invasive as exc:
                    fail(f"{exc} (A* = {root.a_star:.4g})", a_star=root.a_star)
                else:
                    points.append(pt)
                    if on_point is not None:
                        on_point(pt)
                scan.shape = root.shape
            if (max_points is not None and len(points) >= max_points) or a == grid[-1]:
                break
            # the rig moved (refinement, stability test): re-settle on this grid point
            evals[-1] = scan(float(a), sign_only=True)
    except ConvergenceError as exc:
        fail(f"the controller did not hold the target near A*={a:.4g}: {exc}")
    return points, failures


def _finish_point(rig: AbstractRig, opts: PPCBCOptions, fam: _Family, root: _Eval,
                  value: float, n_evals: int, branch: str) -> LCOPoint:
    resp = root.resp
    target = fam.target(root.a_star, root.shape)
    return _make_point(rig, opts, fam, target, resp, value, abs(root.xi) / root.a_star,
                       n_evals, branch)


def _make_point(rig, opts, fam, target, resp: _Response, value, residual, n_evals, branch
                ) -> LCOPoint:
    m = resp.m
    om = resp.omega
    n = whole_periods(len(m), om, m.sample_rate)
    m = m.tail(n)
    amps, offs = {}, {}
    for i, name in enumerate(m.output_names):
        a, mean = periodic_amplitude(m.outputs[:, i], om, m.sample_rate,
                                     n_harmonics=max(10, opts.n_harmonics))
        amps[name], offs[name] = a, mean
    x1 = m.signal(opts.x1)
    x2 = m.signal(opts.x2)
    feedback = opts.kp * (x1 - x1.mean()) + opts.kd * (x2 - x2.mean())
    u_rms = float(np.sqrt(np.mean(m.control**2)))
    fb_rms = max(float(np.sqrt(np.mean(feedback**2))), 1e-300)
    inv = u_rms / fb_rms
    theta = om * np.arange(len(m)) / m.sample_rate
    u_fit = evaluate_series(fourier_project(m.control, theta, max(10, opts.n_harmonics)), theta)
    inv_per = float(np.sqrt(np.mean(u_fit**2))) / fb_rms
    trk = float(np.sqrt(np.mean((m.target - x1) ** 2)) / max(np.std(x1), 1e-300))
    pt = LCOPoint(param=value, target=target, measurement=m, frequency=om, amplitude=amps,
                  offset=offs, control_rms=u_rms, invasiveness=inv,
                  invasiveness_periodic=inv_per, tracking_error=trk,
                  residual=float(residual), iterations=int(n_evals), branch=branch,
                  signal=opts.x1)
    if not inv <= opts.max_invasiveness:
        raise _Invasive(f"the converged control is invasive (rms(u)/rms(feedback) = {inv:.2g} "
                        f"> {opts.max_invasiveness:g}): the controller does not hold an orbit "
                        "of the uncontrolled system here")
    if opts.stability:
        res = _stability(rig, opts, fam, target, resp)
        pt.stable, pt.growth = res.stable, res.growth
    return pt


def _stability(rig, opts: PPCBCOptions, fam: _Family, target: AbstractTarget, resp: _Response
               ) -> StabilityResult:
    # nudge inwards: the target scaled by (1 - nudge) about its centre
    if isinstance(target, EllipticTarget):
        nudged: AbstractTarget = EllipticTarget(target.amplitude * (1 - opts.nudge),
                                                target.omega, target.offset)
    else:
        assert isinstance(target, PolarTarget)
        nudged = target.with_coefficients(target.coefficients * (1 - opts.nudge))
    a1 = _first_harmonic_amplitude(resp.m.signal(opts.x1), resp.omega, resp.m.sample_rate)
    res, _ = switch_off_test(rig, opts.x1, a1, resp.omega, controller=opts.controller,
                             nudged_target=nudged, restore_target=target,
                             watch_periods=opts.watch_periods)
    rig.run(opts.settle_periods * 2.0 * math.pi / resp.omega)
    return res


def _first_harmonic_amplitude(x: np.ndarray, omega: float, fs: float) -> float:
    n = whole_periods(x.shape[0], omega, fs)
    c = fourier_project(x[-n:], omega * np.arange(n) / fs, 1)
    return math.hypot(c[1], c[2])


def ppcbc_sweep(
    rig: AbstractRig,
    param: str,
    values: Sequence[float],
    amplitudes: Sequence[float],
    options: PPCBCOptions | None = None,
    *,
    omega_guess: float = 1.0,
    on_point: Callable[[LCOPoint], None] | None = None,
    on_iteration: Callable[[int], None] | None = None,
    skip: Callable[[float], bool] | None = None,
    max_points: int | None = None,
) -> tuple[list[LCOPoint], list[PPCBCFailure]]:
    """:func:`ppcbc_scan` at each parameter value in turn (the wind-tunnel protocol).

    ``skip(value)`` (e.g. for ``--resume``) skips values already measured.
    ``max_points``: stop each scan after that many LCOs (e.g. 2 where a stable and an
    unstable LCO coexist): the grid targets beyond the largest LCO are invasive, and with
    gains tuned for the orbits the rig may not hold them (it trips, a reported failure).
    """
    points: list[LCOPoint] = []
    failures: list[PPCBCFailure] = []
    omega = omega_guess
    for v in values:
        if skip is not None and skip(float(v)):
            continue
        pts, fails = ppcbc_scan(rig, param, float(v), amplitudes, options, omega_guess=omega,
                                on_point=on_point, on_iteration=on_iteration,
                                max_points=max_points)
        if pts:
            omega = pts[-1].frequency
        if not pts and not fails:
            failures.append(PPCBCFailure(float(v), "no zero of the control error on the "
                                         "amplitude grid (no LCO in range?)"))
        points += pts
        failures += fails
    return points, failures


# ------------------------------------------------------------- polar Newton-Broyden solver
class _PolarSolver:
    """Newton–Broyden on the polar zero problem ``G(c*, λ) = c* - Φ(r(φ; c*, λ))``.

    ``y = (c*, λ)``; :meth:`correct` solves ``[G(y); row·(y - y_pred)] = 0`` (``row``
    None: ``λ`` fixed) with a given Jacobian, updated by Broyden's rule in the weighted
    metric ``w``, and a trust region on the steps.
    """

    def __init__(self, rig, opts: PPCBCOptions, fam: _Family, param: str, omega: float,
                 a_ref: float, param_scale: float, on_iteration=None):
        self.rig, self.o, self.fam, self.param = rig, opts, fam, param
        self.nc = 2 * opts.n_harmonics + 1
        self.a_ref, self.param_scale = a_ref, param_scale
        self.w = np.concatenate([np.full(self.nc, 1.0 / a_ref**2), [1.0 / param_scale**2]])
        self.state = {"omega": omega, "evals": 0}
        self.on_iteration = on_iteration

    def G(self, y: np.ndarray) -> tuple[np.ndarray, _Response]:
        nc = self.nc
        if self.rig.get_parameter(self.param) != float(y[-1]):
            self.rig.set_parameter(self.param, float(y[-1]))
        tgt = self.fam.target(float(y[0]), y[1:nc])
        resp = _evaluate(self.rig, self.o, self.fam, tgt, self.state["omega"])
        self.state["omega"] = resp.omega
        self.state["evals"] += 1
        if self.on_iteration is not None:
            self.on_iteration(self.state["evals"])
        return y[:nc] - resp.coeffs, resp

    def jacobian(self, y: np.ndarray, g0: np.ndarray, with_param: bool = True) -> np.ndarray:
        """Finite differences on the rig (``nc`` or ``nc + 1`` evaluations)."""
        nc = self.nc
        J = np.zeros((nc, nc + 1))
        for j in range(nc + 1 if with_param else nc):
            h = self.o.fd_step * (self.a_ref if j < nc else self.param_scale)
            yp = y.copy()
            yp[j] += h
            gp, _ = self.G(yp)
            J[:, j] = (gp - g0) / h
        self.G(y)  # return the rig to the base point
        return J

    def correct(self, y_pred: np.ndarray, row: np.ndarray | None, J: np.ndarray,
                max_step: float = math.inf, bracket: tuple[float, float] | None = None
                ) -> tuple[np.ndarray | None, _Response | None, np.ndarray, float]:
        """Converged when ``max|G| <= tol a0`` and the Newton step (the error estimate of
        ``y``) is below ``amp_tol a0``, each plus what the noise floor of ``G`` allows.
        Steps longer than ``max_step`` (weighted norm) are shortened: far from the
        solution a Broyden Jacobian can point anywhere, and the rig must not be sent
        there. ``bracket`` (amplitude scan): ``a0*`` is kept inside the bracket of the
        zero; a step that hits its end twice gives up at once (the caller falls back to
        the bracketing secant)."""
        o, nc, w = self.o, self.nc, self.w
        y = y_pred.copy()
        g, resp = self.G(y)
        Jk = J.copy()
        hits = 0
        for _ in range(o.newton_max):
            extra = row if row is not None else np.eye(nc + 1)[-1]
            A = np.vstack([Jk, extra[None, :]])
            rhs = np.concatenate([-g, [0.0 if row is None else -(row @ (y - y_pred))]])
            dy = np.linalg.solve(A, rhs)
            noise_step = np.abs(np.linalg.solve(A, np.concatenate([np.full(nc, resp.floor),
                                                                  [0.0]])))
            if (np.max(np.abs(g)) <= o.tol * y[0] + resp.floor
                    and np.max(np.abs(dy[:nc])) <= o.amp_tol * y[0]
                    + np.max(noise_step[:nc])):
                return y, resp, Jk, float(np.max(np.abs(g)) / y[0])
            size = math.sqrt(float(dy @ (w * dy)))
            if size > max_step:
                dy = dy * (max_step / size)
            if bracket is not None:
                lo_b, hi_b = bracket
                a_new = min(max(y[0] + dy[0], lo_b), hi_b)
                if a_new != y[0] + dy[0]:
                    hits += 1
                    if hits >= 2:
                        return None, resp, Jk, float(np.max(np.abs(g)) / y[0])
                    dy = dy * ((a_new - y[0]) / dy[0]) if dy[0] != 0 else dy
            y_new = y + dy
            g_new, resp = self.G(y_new)
            dyw = dy * w  # Broyden: J += (Δg - J Δy) Δyᵀ W / (Δyᵀ W Δy)
            Jk = Jk + np.outer(g_new - g - Jk @ dy, dyw) / (dy @ dyw)
            y, g = y_new, g_new
        return None, resp, Jk, float(np.max(np.abs(g)) / y[0])


# ------------------------------------------------------------------------- continuation
def ppcbc_continuation(
    rig: AbstractRig,
    param: str,
    start: LCOPoint,
    options: PPCBCOptions | None = None,
    *,
    ds: float = 0.5,
    n_points: int = 12,
    direction: int = -1,
    bounds: tuple[float, float] = (-math.inf, math.inf),
    param_scale: float = 1.0,
    second: LCOPoint | None = None,
    on_point: Callable[[LCOPoint], None] | None = None,
    on_iteration: Callable[[int], None] | None = None,
) -> tuple[list[LCOPoint], list[PPCBCFailure]]:
    """Follow a branch of LCOs with a polar target: Newton–Broyden + pseudo-arclength.

    Unknowns ``y = (c*, λ)``: the ``2 n_h + 1`` target coefficients and the parameter.
    Equations (thesis eqs. 3.23, 3.5):

    .. math::

        G(y) = c^* - Φ\\bigl(r(φ; c^*, λ)\\bigr) = 0,\\qquad
        \\hat t^T W (y - y_{pred}) = 0,

    with ``Φ`` the projection of eq. 3.24 of the measured curve, ``\\hat t`` the secant
    direction of the last two points and ``W = diag(1/a_ref², …, 1/λ_ref²)``. The Jacobian
    of ``G`` is built by finite differences on the rig once and then updated by Broyden's
    rank-one rule; it is rebuilt when a corrector fails.

    Parameters
    ----------
    start : LCOPoint
        A converged polar-target point (e.g. from :func:`ppcbc_scan`).
    ds : float
        Arclength step in the weighted norm (a step of ``ds`` moves ``λ`` by about
        ``ds * param_scale`` on a flat branch).
    n_points : int
        Points to return, including ``start``.
    direction : {+1, -1}
        Initial direction of ``λ``.
    bounds : (float, float)
        Stop outside this parameter range.
    param_scale : float
        ``λ_ref``.
    second : LCOPoint, optional
        A second converged point to form the first secant (else a natural-parameter
        step of ``ds * param_scale`` is corrected first).

    Returns
    -------
    points, failures
    """
    opts = options or PPCBCOptions()
    if opts.target != "polar" or not isinstance(start.target, PolarTarget):
        raise BifidInputError("continuation needs the polar target (options.target='polar').")
    fam = _Family(opts, start.target.matrix, start.target.origin)
    nc = 2 * opts.n_harmonics + 1
    a_ref = float(start.target.coefficients[0])
    solver = _PolarSolver(rig, opts, fam, param, start.frequency, a_ref, param_scale,
                          on_iteration)
    w = solver.w
    state = solver.state
    G, jacobian = solver.G, solver.jacobian

    def correct(y_pred, row, J, max_step=math.inf):
        return solver.correct(y_pred, row, J, max_step)

    def y_of(pt: LCOPoint) -> np.ndarray:
        assert isinstance(pt.target, PolarTarget)
        return np.concatenate([pt.target.coefficients, [pt.param]])

    points = [start]
    failures: list[PPCBCFailure] = []
    ys = [y_of(start)]
    g0, _ = G(ys[0])
    J = jacobian(ys[0], g0)

    # second point: given, or a natural-parameter step corrected at fixed λ
    if second is not None:
        ys.append(y_of(second))
        points.append(second)
    else:
        y_pred = ys[0].copy()
        y_pred[-1] += direction * ds * param_scale
        n0 = state["evals"]
        y1, resp, J, res = correct(y_pred, None, J)
        if y1 is None:
            failures.append(PPCBCFailure(float(y_pred[-1]), "Newton did not converge for the "
                                         "second continuation point"))
            warnings.warn(f"PP-CBC continuation: {failures[-1].reason}.", ConvergenceWarning,
                          stacklevel=2)
            return points, failures
        try:
            pt = _make_point(rig, opts, fam, fam.target(float(y1[0]), y1[1:nc]), resp,
                             float(y1[-1]), res, state["evals"] - n0, "continuation")
        except _Invasive as exc:
            failures.append(PPCBCFailure(float(y1[-1]), str(exc)))
            warnings.warn(f"PP-CBC continuation: {exc}.", ConvergenceWarning, stacklevel=2)
            return points, failures
        points.append(pt)
        ys.append(y1)
        if on_point is not None:
            on_point(pt)
    step = ds
    tries = 0
    while len(points) < n_points:
        sec = ys[-1] - ys[-2]
        t = sec / math.sqrt(sec @ (w * sec))
        y_pred = ys[-1] + step * t
        row = w * t
        n0 = state["evals"]
        y_new, resp, J_new, res = correct(y_pred, row, J, max_step=0.5 * step)
        if y_new is None:
            # back to the last point, fresh Jacobian, smaller step
            tries += 1
            g_last, _ = G(ys[-1])
            J = jacobian(ys[-1], g_last)
            if tries > 3:
                failures.append(PPCBCFailure(float(y_pred[-1]), "Newton–Broyden corrector did "
                                             f"not converge in {opts.newton_max} iterations",
                                             {"residual": res}))
                warnings.warn(f"PP-CBC continuation stopped near {param}={y_pred[-1]:.4g}: "
                              f"{failures[-1].reason}.", ConvergenceWarning, stacklevel=2)
                break
            step = step / 2.0
            continue
        tries = 0
        J = J_new
        lam = float(y_new[-1])
        if not (bounds[0] <= lam <= bounds[1]):
            break
        try:
            pt = _make_point(rig, opts, fam, fam.target(float(y_new[0]), y_new[1:nc]), resp,
                             lam, res, state["evals"] - n0, "continuation")
        except _Invasive as exc:
            failures.append(PPCBCFailure(lam, str(exc)))
            warnings.warn(f"PP-CBC continuation stopped: {exc}.", ConvergenceWarning,
                          stacklevel=2)
            break
        points.append(pt)
        ys.append(y_new)
        if on_point is not None:
            on_point(pt)
        # step control: shrink where the branch turns (folds), grow where it is straight
        s_old, s_new = ys[-2] - ys[-3], ys[-1] - ys[-2]
        cosang = float(s_old @ (w * s_new)) / math.sqrt(
            float(s_old @ (w * s_old)) * float(s_new @ (w * s_new)))
        turn = math.degrees(math.acos(max(-1.0, min(1.0, cosang))))
        if turn > 20.0:
            step = max(ds / 16.0, step / 2.0)
        elif turn < 10.0:
            step = min(ds, step * 1.5)
        if state["evals"] - n0 > opts.newton_max // 2:
            g_new, _ = G(ys[-1])  # a hard corrector: refresh the Jacobian here
            J = jacobian(ys[-1], g_new)
    return points, failures
