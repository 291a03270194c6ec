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
from bifid.cbc._fourier import (
    HarmonicSecant,
    coefficient_noise,
    estimate_frequency,
    fourier_project,
    periodic_amplitude,
    polar_project,
    whole_periods,
)
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.cbc._stability import StabilityResult, switch_off_test
from bifid.errors import BifidInputError, ConvergenceError, ConvergenceWarning

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
    picard_max: int = 12
    secant_max: int = 25
    newton_max: int = 12
    fd_step: float = 0.01
    stability: bool = True
    nudge: float = 0.05
    watch_periods: float = 20.0

    def __post_init__(self) -> None:
        if self.target not in ("polar", "elliptic"):
            raise BifidInputError(f"target must be 'polar' or 'elliptic', got {self.target!r}.")
        if int(self.n_harmonics) < 1:
            raise BifidInputError(f"n_harmonics must be >= 1, got {self.n_harmonics!r}.")
        for name in ("settle_periods", "measure_periods", "tol", "fd_step", "watch_periods"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise BifidInputError(f"{name} must be a positive number, got {v!r}.")
        if self.measure_periods < 1:
            raise BifidInputError("measure_periods must be >= 1 (projections over whole periods).")
        for name in ("picard_max", "secant_max", "newton_max"):
            if int(getattr(self, name)) < 1:
                raise BifidInputError(f"{name} must be a positive integer.")
        PDController(self.kp, self.kd, self.x1, self.x2)  # validates gains and names

    @property
    def controller(self) -> PDController:
        return PDController(self.kp, self.kd, self.x1, self.x2)

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

    def __init__(self, opts: PPCBCOptions, scale: tuple[float, float], origin: tuple[float, float]):
        self.o = opts
        self.scale = scale
        self.origin = origin

    # target from its unknowns
    def target(self, a0: float, shape: np.ndarray) -> AbstractTarget:
        if self.o.target == "elliptic":
            return EllipticTarget(max(a0, 0.0), float(shape[0]), (float(shape[1]), float(shape[2])))
        coef = np.concatenate([[max(a0, 0.0)], shape])
        return PolarTarget(coefficients=coef, scale=self.scale, origin=self.origin)

    def analyse(self, m: Measurement, omega_hint: float) -> _Response:
        x1, x2 = m.signal(self.o.x1), m.signal(self.o.x2)
        om = estimate_frequency(x1, m.sample_rate)
        if not (om > 0 and math.isfinite(om)):
            om = omega_hint
        if not (om > 0 and math.isfinite(om)):
            raise ConvergenceError("no oscillation found in the measured response.")
        n = whole_periods(x1.shape[0], om, m.sample_rate)
        x1, x2 = x1[-n:], x2[-n:]
        theta = om * np.arange(n) / m.sample_rate
        c1 = fourier_project(x1, theta, 1)
        c2 = fourier_project(x2, theta, 1)
        resid = x1 - (c1[0] + c1[1] * np.cos(theta) + c1[2] * np.sin(theta))
        A1 = math.hypot(c1[1], c1[2])
        if self.o.target == "elliptic":
            A2 = math.hypot(c2[1], c2[2])
            # sense of rotation in (x1, x2): sign of the area swept (a1 b2 - b1 a2)
            rot = 1.0 if (c1[1] * c2[2] - c1[2] * c2[1]) >= 0 else -1.0
            aspect = rot * A2 / max(A1, 1e-300)
            floor = coefficient_noise(resid)
            return _Response(m, om, A1, np.array([aspect, c1[0], c2[0]]), None, floor)
        xi1 = (x1 - self.origin[0]) / self.scale[0]
        xi2 = (x2 - self.origin[1]) / self.scale[1]
        phi = np.arctan2(xi2, xi1)
        coef = polar_project(phi, np.hypot(xi1, xi2), self.o.n_harmonics)
        floor = coefficient_noise(resid) / abs(self.scale[0])
        return _Response(m, om, float(coef[0]), coef[1:].copy(), coef, floor)


def _evaluate(rig: AbstractRig, opts: PPCBCOptions, fam: _Family, target: AbstractTarget,
              omega: float, settle: float | None = None) -> _Response:
    period = 2.0 * math.pi / omega
    rig.set_controller(opts.controller, target)
    rig.run((opts.settle_periods if settle is None else settle) * period)
    m = rig.run(opts.measure_periods * period + 2.0 / rig.sample_rate)
    return fam.analyse(m, omega)


def _bootstrap(rig: AbstractRig, opts: PPCBCOptions, a_start: float, omega_guess: float
               ) -> tuple[float, float, tuple[float, float], tuple[float, float]]:
    """Engage an elliptic target to start an oscillation; return (ω, aspect, origin, scale)."""
    derivative = opts.x2 == f"{opts.x1}_dot"
    aspect = -omega_guess if derivative else 1.0
    fam = _Family(PPCBCOptions(**{**opts.to_json(), "target": "elliptic"}), (1.0, 1.0), (0.0, 0.0))
    shape = np.array([aspect, 0.0, 0.0])
    omega = omega_guess
    for _ in range(4):
        r = _evaluate(rig, fam.o, fam, fam.target(a_start, shape), omega)
        omega = r.omega
        shape = r.shape
    aspect, o1, o2 = (float(v) for v in shape)
    return omega, aspect, (o1, o2), (1.0, aspect)


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

    def __call__(self, a_star: float) -> _Eval:
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
            err = float(np.max(np.abs(resp.shape - shape) * self._shape_weights(a_star)))
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
            shape = new_shape
        assert resp is not None
        self.shape = shape
        return _Eval(a_star, a_star - resp.a0, shape, resp, ok, self.evals - n0)

    def _shape_weights(self, a_star: float) -> np.ndarray:
        if self.o.target == "elliptic":
            # aspect ratio changes matter through ω A*; centre offsets directly
            return np.array([a_star / max(abs(self.shape[0]), 1e-12) * 1.0, 1.0, 1.0 / max(
                abs(self.shape[0]), 1e-12)])
        return np.ones_like(self.shape)


def _illinois(f: Callable[[float], _Eval], a: _Eval, b: _Eval, tol_fn, rel_tol: float,
              max_iter: int) -> tuple[_Eval | None, int]:
    """Root of ``Ξ`` between evaluations ``a`` and ``b`` (opposite signs).

    Converged when ``|Ξ|`` is within tolerance *and* the next secant step is below
    ``rel_tol · A*`` (or the step that the noise floor of ``Ξ`` allows): with a strong
    controller the response follows the target, ``Ξ = A* - A(A*)`` is flat near its zero
    and a small ``|Ξ|`` alone does not bound the error of ``A*``.
    """
    fa, fb = a.xi, b.xi
    for it in range(max_iter):
        x = (a.a_star * fb - b.a_star * fa) / (fb - fa)
        c = f(x)
        if c.xi * fb < 0:
            a, fa = b, fb
        else:
            fa = fa / 2.0
        b, fb = c, c.xi
        slope = abs((b.xi - a.xi) / (b.a_star - a.a_star)) if b.a_star != a.a_star else 0.0
        x_next = (a.a_star * fb - b.a_star * fa) / (fb - fa) if fb != fa else x
        step_tol = rel_tol * c.a_star + (c.resp.floor / slope if slope > 0 else 0.0)
        if abs(c.xi) <= tol_fn(c) and c.picard_ok and abs(x_next - c.a_star) <= step_tol:
            return c, it + 1
        if abs(b.a_star - a.a_star) < 1e-12 * max(abs(b.a_star), 1e-300):
            break
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
) -> tuple[list[LCOPoint], list[PPCBCFailure]]:
    """All LCOs at one parameter value by the amplitude scan (thesis §3.3.3.2).

    Parameters
    ----------
    rig : AbstractRig
    param : str
        Parameter name on the rig (e.g. ``"U"``); set to ``value`` first.
    amplitudes : sequence of float
        Increasing grid of target amplitudes ``A*`` (of ``x1``'s first harmonic for the
        elliptic target, of the mean scaled radius ``a0*`` for the polar one) on which
        sign changes of ``Ξ`` are looked for. Zeros closer than the grid spacing can be
        missed.
    options : PPCBCOptions
    omega_guess : float
        Rough oscillation frequency [rad/s] to start with.
    on_point : callable, optional
        Called with each converged (and labelled) point as soon as it exists.
    on_iteration : callable, optional
        Called with the number of rig evaluations so far.

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
        omega, aspect, origin, scale = _bootstrap(rig, opts, float(grid[0]), omega_guess)
    except ConvergenceError as exc:
        fail(f"the controller could not start an oscillation at A*={grid[0]:.4g}: {exc}")
        return points, failures
    if opts.target == "elliptic":
        fam = _Family(opts, (1.0, 1.0), (0.0, 0.0))
        shape0 = np.array([aspect, origin[0], origin[1]])
    else:
        fam = _Family(opts, scale, origin)
        shape0 = np.zeros(2 * opts.n_harmonics)
    scan = _Scanner(rig, opts, fam, omega, shape0)
    evals: list[_Eval] = []

    def tol_fn(e: _Eval) -> float:
        return opts.tol * e.a_star + e.resp.floor

    a = float(grid[0])
    try:
        for a in grid:
            e = scan(float(a))
            evals.append(e)
            if on_iteration is not None:
                on_iteration(scan.evals)
            if len(evals) < 2 or evals[-2].xi * e.xi >= 0:
                continue
            lo, hi = evals[-2], e
            n0 = scan.evals
            root, _ = _illinois(scan, lo, hi, tol_fn, opts.tol, opts.secant_max)
            if on_iteration is not None:
                on_iteration(scan.evals)
            if root is None:
                fail(f"control error did not converge to zero within {opts.secant_max} "
                     f"secant iterations in A* = [{lo.a_star:.4g}, {hi.a_star:.4g}]",
                     bracket=[lo.a_star, hi.a_star])
            else:
                pt = _finish_point(rig, opts, fam, root, value, scan.evals - n0 + lo.n + hi.n,
                                   "scan")
                points.append(pt)
                if on_point is not None:
                    on_point(pt)
                scan.shape = root.shape
            # the rig moved (refinement, stability test): re-settle on this grid point
            evals[-1] = scan(float(a))
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
    inv = u_rms / max(float(np.sqrt(np.mean(feedback**2))), 1e-300)
    trk = float(np.sqrt(np.mean((m.target - x1) ** 2)) / max(np.std(x1), 1e-300))
    pt = LCOPoint(param=value, target=target, measurement=m, frequency=om, amplitude=amps,
                  offset=offs, control_rms=u_rms, invasiveness=inv, tracking_error=trk,
                  residual=float(residual), iterations=int(n_evals), branch=branch,
                  signal=opts.x1)
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
) -> tuple[list[LCOPoint], list[PPCBCFailure]]:
    """:func:`ppcbc_scan` at each parameter value in turn (the wind-tunnel protocol).

    ``skip(value)`` (e.g. for ``--resume``) skips values already measured.
    """
    points: list[LCOPoint] = []
    failures: list[PPCBCFailure] = []
    omega = omega_guess
    for v in values:
        if skip is not None and skip(float(v)):
            continue
        pts, fails = ppcbc_scan(rig, param, float(v), amplitudes, options, omega_guess=omega,
                                on_point=on_point, on_iteration=on_iteration)
        if pts:
            omega = pts[-1].frequency
        if not pts and not fails:
            failures.append(PPCBCFailure(float(v), "no zero of the control error on the "
                                         "amplitude grid (no LCO in range?)"))
        points += pts
        failures += fails
    return points, failures


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
    fam = _Family(opts, start.target.scale, start.target.origin)
    nc = 2 * opts.n_harmonics + 1
    a_ref = float(start.target.coefficients[0])
    w = np.concatenate([np.full(nc, 1.0 / a_ref**2), [1.0 / param_scale**2]])
    state = {"omega": start.frequency, "evals": 0}

    def G(y: np.ndarray) -> tuple[np.ndarray, _Response]:
        rig.set_parameter(param, float(y[-1]))
        tgt = fam.target(float(y[0]), y[1:nc])
        resp = _evaluate(rig, opts, fam, tgt, state["omega"])
        state["omega"] = resp.omega
        state["evals"] += 1
        if on_iteration is not None:
            on_iteration(state["evals"])
        return y[:nc] - resp.coeffs, resp

    def jacobian(y: np.ndarray, g0: np.ndarray) -> np.ndarray:
        J = np.empty((nc, nc + 1))
        for j in range(nc + 1):
            h = opts.fd_step * (a_ref if j < nc else param_scale)
            yp = y.copy()
            yp[j] += h
            gp, _ = G(yp)
            J[:, j] = (gp - g0) / h
        G(y)  # return the rig to the base point
        return J

    def y_of(pt: LCOPoint) -> np.ndarray:
        assert isinstance(pt.target, PolarTarget)
        return np.concatenate([pt.target.coefficients, [pt.param]])

    points = [start]
    failures: list[PPCBCFailure] = []
    ys = [y_of(start)]
    g0, _ = G(ys[0])
    J = jacobian(ys[0], g0)

    def correct(y_pred: np.ndarray, row: np.ndarray | None, J: np.ndarray,
                max_step: float = math.inf
                ) -> tuple[np.ndarray | None, _Response | None, np.ndarray, float]:
        """Broyden–Newton on [G; row.(y - y_pred)] (row None: fixed parameter).

        Steps longer than ``max_step`` (weighted norm) are shortened: far from the
        solution a Broyden Jacobian can point anywhere, and the rig must not be sent
        there.
        """
        y = y_pred.copy()
        g, resp = G(y)
        Jk = J.copy()
        for _ in range(opts.newton_max):
            extra = (row if row is not None else np.eye(nc + 1)[-1])
            A = np.vstack([Jk, extra[None, :]])
            rhs = np.concatenate([-g, [0.0 if row is None else -(row @ (y - y_pred))]])
            dy = np.linalg.solve(A, rhs)
            # converged: small residual and a Newton step (= the error estimate of y) small
            # against the tolerance and against what the noise floor of G allows
            noise_step = np.abs(np.linalg.solve(A, np.concatenate([np.full(nc, resp.floor),
                                                                  [0.0]])))
            if (np.max(np.abs(g)) <= opts.tol * y[0] + resp.floor
                    and np.max(np.abs(dy[:nc])) <= opts.tol * y[0] + np.max(noise_step[:nc])):
                return y, resp, Jk, float(np.max(np.abs(g)) / y[0])
            size = math.sqrt(float(dy @ (w * dy)))
            if size > max_step:
                dy = dy * (max_step / size)
            y_new = y + dy
            g_new, resp = G(y_new)
            # Broyden: J += (Δg - J Δy) Δyᵀ / (Δyᵀ Δy) in the weighted metric
            dyw = dy * w
            Jk = Jk + np.outer(g_new - g - Jk @ dy, dyw) / (dy @ dyw)
            y, g = y_new, g_new
        return None, resp, Jk, float(np.max(np.abs(g)) / y[0])

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
        pt = _make_point(rig, opts, fam, fam.target(float(y1[0]), y1[1:nc]), resp,
                         float(y1[-1]), res, state["evals"] - n0, "continuation")
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
        pt = _make_point(rig, opts, fam, fam.target(float(y_new[0]), y_new[1:nc]), resp, lam,
                         res, state["evals"] - n0, "continuation")
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
