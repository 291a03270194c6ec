"""The PP-CBC amplitude scan at one parameter value (thesis §3.3.3.2, as on the flutter rig).

At a fixed parameter the target's *shape* (elliptic: aspect ratio and centre; polar: the
harmonics of ``r*(φ)``) follows the measured response by Picard iteration (accelerated
harmonic by harmonic, :class:`~bifid.cbc._secant.HarmonicSecant`), and the control error
``Ξ(A*) = A* - A(A*)`` over the target amplitude ``A*`` (elliptic) or mean radius ``a0*``
(polar) is sampled on a grid. Each sign change brackets an orbit of the uncontrolled
system, which is then solved for all the target's unknowns at once by the Broyden
corrector on the PP-CBC zero problem (:class:`~bifid.cbc._ppcbc.PPCBCProblem`, ``λ``
fixed, ``a0*`` kept in the bracket); where that cannot start (e.g. from near a maximum
of ``Ξ``, where the Jacobian is singular in ``a0*``) the bracketing Illinois secant on
``A*`` with Picard on the shape takes over.

Polar targets are re-framed along the grid: once the measured orbit's first harmonic of
``r(φ)`` exceeds 10 % of ``a0`` (the orbit's shape has changed with its amplitude since the
frame was measured), the frame is re-measured on the last response, so the orbits near
the grid point have small harmonics and Picard converges quickly.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bifid.cbc._controllers import PolarTarget
from bifid.cbc._measured import (
    BroydenCorrector,
    Evaluation,
    Failure,
    NoiseLimited,
    RigTripped,
)
from bifid.cbc._ppcbc import (
    FLOOR_SIGMAS,
    Invasive,
    LCOPoint,
    PPCBCOptions,
    PPCBCProblem,
    make_point,
)
from bifid.cbc._ppcbc_family import Response, TargetFamily, bootstrap
from bifid.cbc._rig import AbstractRig
from bifid.cbc._secant import HarmonicSecant
from bifid.errors import BifidInputError, ConvergenceError, ConvergenceWarning

__all__ = ["ScanResult", "hold_orbit", "ppcbc_scan", "scan"]


@dataclass
class _Eval:
    a_star: float
    xi: float
    vec: np.ndarray
    resp: Response
    picard_ok: bool
    n: int


@dataclass
class ScanResult:
    """Outcome of :func:`scan` at one parameter value.

    ``found`` pairs each point with the family (frame) and the converged
    :class:`~bifid.cbc._measured.Evaluation` it was measured in (to continue from it)."""

    points: list[LCOPoint] = field(default_factory=list)
    failures: list[Failure] = field(default_factory=list)
    found: list[tuple[TargetFamily, Evaluation, BroydenCorrector]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    omega: float = math.nan
    evaluations: int = 0


class _Scanner:
    """Picard on the shape for each amplitude, then ``Ξ(A*) = A* - A(A*)``."""

    def __init__(
        self,
        rig: AbstractRig,
        opts: PPCBCOptions,
        family: TargetFamily,
        omega: float,
        vec: np.ndarray,
        on_evaluation=None,
    ) -> None:
        self.rig, self.o, self.family = rig, opts, family
        self.omega = omega
        self.vec = np.asarray(vec, dtype=float)
        self.evals = 0
        self.last: Response | None = None
        self.on_evaluation = on_evaluation

    def reframe(self) -> None:
        """Re-measure the polar frame on the last response when its shape has drifted."""
        r = self.last
        if r is None or not self.family.polar:
            return
        q = self.o.n_harmonics
        if math.hypot(r.vector[1], r.vector[q + 1]) <= 0.1 * abs(r.a0):
            return
        new = self.family.reframed(r.m, r.omega)
        self.vec = self.family.convert(self.vec, new)
        self.family = new

    def __call__(
        self, a_star: float, sign_only: bool = False, shape_tol: float | None = None
    ) -> _Eval:
        """``Ξ(A*)`` with the target shape converged by (accelerated) Picard.

        ``sign_only`` (grid points): stop as soon as the shape error is small against
        ``|Ξ|`` -- only the sign is needed to bracket zeros. ``shape_tol``: relative
        tolerance on the shape's control error (default: the options' ``tol``).
        """
        vec = self.vec.copy()
        vec[0] = a_star
        ok = False
        resp = None
        n0 = self.evals
        fam = self.family
        acc = HarmonicSecant(self.o.n_harmonics, fixed=(0,)) if fam.polar else None
        for _ in range(self.o.picard_max):
            resp = fam.hold(self.rig, fam.target(vec), self.omega)
            self.evals += 1
            if self.on_evaluation is not None:
                self.on_evaluation(1)
            self.omega = resp.omega
            self.last = resp
            # the shape's control error (target minus response), in units of A*
            err = float(np.max(np.abs(resp.vector - vec)[1:] * fam.scales(vec)[1:]))
            rel = self.o.tol if shape_tol is None else shape_tol
            tol = rel * a_star + resp.floor
            new = acc.step(vec, resp.vector, resp.floor) if acc is not None else resp.vector
            if err <= tol:
                ok = True
                break
            if sign_only and err < 0.2 * abs(a_star - resp.a0):
                break
            vec = np.concatenate([[a_star], new[1:]])
        assert resp is not None
        self.vec = vec
        return _Eval(a_star, a_star - resp.a0, vec, resp, ok, self.evals - n0)


def _illinois(
    f: Callable[[float], _Eval],
    a: _Eval,
    b: _Eval,
    rel_tol: float,
    max_iter: int,
    slope_ref: float = math.inf,
    noise_tol: float = math.inf,
) -> _Eval | None:
    """Root of ``Ξ`` between evaluations ``a`` and ``b`` (opposite signs).

    Converged when the error estimate of ``A*`` is below ``rel_tol · A*`` (plus what the
    noise floor of ``Ξ`` allows) and ``|Ξ|`` itself is (a sign change of ``Ξ`` can be a
    jump between attractors, not a zero): the error estimate is the larger of
    ``|Ξ| / |Ξ'|`` and the next secant step, with ``|Ξ'|`` the smaller of the secant
    slope of the bracket and ``slope_ref`` (the slope over the whole first bracket: two
    close iterates give a slope out of the small errors of their ``Ξ``). With a strong
    controller the response follows the target and ``Ξ`` is flat near its zero, so a
    small ``|Ξ|`` alone does not bound the error of ``A*``; nor does a noise floor:
    a root whose standard error (floor / 3 over the slope) is above ``noise_tol · A*``
    is not accepted.
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
        slope = min(slope, slope_ref)
        x_next = (a.a_star * fb - b.a_star * fa) / (fb - fa) if fb != fa else x
        if slope > 0 and c.resp.floor / FLOOR_SIGMAS / slope <= noise_tol * c.a_star:
            err = max(abs(c.xi) / slope, abs(x_next - c.a_star))
            allowed = rel_tol * c.a_star + c.resp.floor / slope
        else:
            err, allowed = math.inf, 0.0
        # Ξ itself small too: where the response jumps from one attractor to another Ξ
        # changes sign without a zero, and the bracket closes on the jump (slope → ∞)
        small = abs(c.xi) <= rel_tol * c.a_star + c.resp.floor
        if c.picard_ok and small and err < best_err:
            best, best_err = c, err
        if c.picard_ok and small and err <= allowed:
            return c
        if stagnant:
            break
    if best is not None and best_err <= 3.0 * rel_tol * best.a_star + best.resp.floor:
        return best
    return None


def _refine(
    rig,
    opts,
    scanner: _Scanner,
    param: str,
    value: float,
    lo: _Eval,
    hi: _Eval,
    corrector: BroydenCorrector | None,
) -> tuple[Evaluation | None, BroydenCorrector]:
    """Solve the zero bracketed by ``lo``, ``hi``: Broyden on all the target's unknowns
    (the last Jacobian reused when the frame is the same, else a fresh one), then the
    Illinois secant on ``A*``."""
    x0 = (lo.a_star * hi.xi - hi.a_star * lo.xi) / (hi.xi - lo.xi)
    vec0 = scanner.vec.copy()
    vec0[0] = x0
    y0 = np.concatenate([vec0, [value]])
    e_p = np.zeros(y0.shape[0])
    e_p[-1] = 1.0
    reuse = (
        corrector is not None
        and corrector.jacobian is not None
        and corrector.problem.family is scanner.family
    )
    for old in (True, False) if reuse else (False,):
        if not old:
            problem = PPCBCProblem(rig, opts, scanner.family, param, scanner.omega, vec0)
            corrector = BroydenCorrector(
                problem, max_iter=opts.newton_max, on_evaluation=scanner.on_evaluation
            )
        assert corrector is not None
        corrector.problem.omega = scanner.omega
        corrector.box = (0, lo.a_star, hi.a_star)
        r = corrector.correct(y0, e_p, value, None)
        corrector.box = None
        scanner.evals += r.info.get("evaluations", 0)
        if r.converged:
            corrector.accept(r)
            return r.info["evaluation"], corrector
        if r.info.get("tripped"):
            raise RigTripped(r.info.get("reason", ""))
    assert corrector is not None
    corrector.jacobian = None  # it did not help: rebuild it next time
    scanner.vec = vec0
    # the error of Ξ is the shape's control error (the tolerance of Picard): below the
    # control error that ``amp_tol`` of A* makes at the bracket's slope (small near a
    # Hopf point, where the response follows the target)
    slope = abs((hi.xi - lo.xi) / (hi.a_star - lo.a_star))
    shape_tol = min(opts.tol, opts.amp_tol * slope)
    root = _illinois(
        lambda x: scanner(x, shape_tol=shape_tol),
        lo,
        hi,
        opts.amp_tol,
        opts.secant_max,
        slope,
        opts.zero_precision,
    )
    if root is None:
        return None, corrector
    y = np.concatenate([root.vec, [value]])
    floor = np.full(root.vec.shape[0], root.resp.floor)
    return Evaluation(y, root.vec - root.resp.vector, floor, root.resp), corrector


def _next_amplitude(
    grid: np.ndarray, k: int, last: _Eval | None, a_max: float = math.inf
) -> float | None:
    """The ``k``-th target amplitude: the grid's, then up to as many more (at least 8)
    with its last spacing while the last control error is negative (the response larger
    than the target: an orbit lies above the grid) and below ``a_max``; None at the end."""
    if k < grid.size:
        return float(grid[k])
    j = k - grid.size + 1
    if j > max(8, grid.size) or last is None or last.xi >= 0:
        return None
    a = float(grid[-1]) + j * float(grid[-1] - grid[-2])
    return a if a < a_max else None


def _no_zero(lo: _Eval, hi: _Eval, corrector: BroydenCorrector | None) -> str:
    """Why no zero of ``Ξ`` was found in the bracket ``[lo, hi]`` (with the corrector's
    last reason when it is the noise)."""
    last = getattr(corrector, "last_reason", None)
    why = f": {last}" if isinstance(last, NoiseLimited) else ""
    return (
        f"the control error did not converge to zero in A* = [{lo.a_star:.4g}, "
        f"{hi.a_star:.4g}] (Broyden on the target, then the secant on A*){why}"
    )


def scan(
    rig: AbstractRig,
    param: str,
    value: float,
    amplitudes: Sequence[float],
    options: PPCBCOptions | None = None,
    *,
    omega_guess: float = 1.0,
    on_point: Callable[[LCOPoint], None] | None = None,
    on_evaluation: Callable[[int], None] | None = None,
    max_points: int | None = None,
    a_max: float = math.inf,
) -> ScanResult:
    """All LCOs at one parameter value by the amplitude scan (module docstring).

    Parameters
    ----------
    rig : AbstractRig
    param : str
        Parameter name on the rig (e.g. ``"U"``); set to ``value`` first.
    amplitudes : sequence of float
        Increasing grid of target amplitudes ``A*`` (of ``x1``'s first harmonic for the
        elliptic target, of the mean radius ``a0*`` in the target's frame -- close to the
        first-harmonic amplitude of ``x1`` -- for the polar one) on which sign changes of
        ``Ξ`` are looked for. Zeros closer than the grid spacing can be missed. Where
        ``Ξ < 0`` at the end of the grid (an orbit lies above it) the grid goes on with
        its last spacing, up to as many more amplitudes (at least 8).
    options : PPCBCOptions
    omega_guess : float
        Rough oscillation frequency [rad/s] to start with.
    on_point : callable, optional
        Called with each converged (and labelled) point as soon as it exists.
    on_evaluation : callable, optional
        Called with the number of new rig evaluations.
    max_points : int, optional
        Stop as soon as this many LCOs are measured, with the rig left holding the last.
    a_max : float, optional
        The grid's extension stops below this target amplitude (e.g. below an LCO
        outside the rig's safety envelope).

    Returns
    -------
    ScanResult
        Points in increasing amplitude, failures (each with its reason), warnings.
    """
    opts = options or PPCBCOptions()
    grid = np.asarray(amplitudes, dtype=float)
    if grid.ndim != 1 or grid.size < 2 or np.any(np.diff(grid) <= 0) or grid[0] <= 0:
        raise BifidInputError("amplitudes must be an increasing grid of >= 2 positive values.")
    rig.set_parameter(param, value)
    out = ScanResult()

    def fail(reason: str, **data) -> None:
        warnings.warn(f"PP-CBC at {param}={value:g}: {reason}", ConvergenceWarning, stacklevel=3)
        out.failures.append(Failure({"param": float(value)}, reason, dict(data)))

    try:
        family, vec0, omega = bootstrap(rig, opts, float(grid[0]), omega_guess)
    except ConvergenceError as exc:
        fail(f"the controller could not start an oscillation at A*={grid[0]:.4g}: {exc}")
        return out
    scanner = _Scanner(rig, opts, family, omega, vec0, on_evaluation)
    corrector: BroydenCorrector | None = None
    prev: _Eval | None = None
    a = float(grid[0])
    k = 0
    try:
        while (nxt := _next_amplitude(grid, k, prev, a_max)) is not None:
            a, k = nxt, k + 1
            scanner.reframe()
            e = scanner(float(a), sign_only=True)
            if prev is None or prev.xi * e.xi >= 0:
                prev = e
                continue
            lo, hi = prev, e
            ev, corrector = _refine(rig, opts, scanner, param, value, lo, hi, corrector)
            if ev is None:
                fail(_no_zero(lo, hi, corrector), bracket=[lo.a_star, hi.a_star])
            else:
                fam = scanner.family
                try:
                    pt = make_point(rig, opts, fam, ev, scanner.evals, "scan")
                except Invasive as exc:
                    fail(f"{exc} (A* = {ev.y[0]:.4g})", lco=float(ev.y[0]))
                else:
                    out.points.append(pt)
                    out.found.append((fam, ev, corrector))
                    if on_point is not None:
                        on_point(pt)
                scanner.vec = fam.convert(ev.y[:-1], scanner.family)
            if (max_points is not None and len(out.points) >= max_points) or (
                k >= grid.size and e.xi > 0
            ):
                break  # (at the end of the grid with Ξ > 0 there is nothing above)
            # the rig moved (refinement, stability test): re-settle on this grid point
            prev = scanner(float(a), sign_only=True)
    except RigTripped as exc:
        # a trip on a requested target is a failure (the targets above it were not
        # scanned); one on the extension past the grid, above the last orbit, is not
        if k > grid.size and out.points:
            out.warnings.append(
                f"PP-CBC at {param}={value:g}: the rig tripped at A* = {a:.4g}, beyond the "
                f"amplitude grid and above the last orbit found ({exc})"
            )
        else:
            where = "above the last orbit found" if out.points else "before any orbit was found"
            fail(
                f"the rig tripped at A* = {a:.4g} of the amplitude grid, {where}; larger "
                f"targets were not scanned: {exc}",
                a_star=a,
            )
    except ConvergenceError as exc:
        fail(f"the controller did not hold the target near A* = {a:.4g}: {exc}", a_star=a)
    out.omega = scanner.omega
    out.evaluations = scanner.evals
    return out


def ppcbc_scan(
    rig: AbstractRig,
    param: str,
    value: float,
    amplitudes: Sequence[float],
    options: PPCBCOptions | None = None,
    **kw: Any,
) -> tuple[list[LCOPoint], list[Failure]]:
    """The LCOs at one parameter value and the failures (:func:`scan`; ``kw``: its
    keyword arguments)."""
    r = scan(rig, param, value, amplitudes, options, **kw)
    return r.points, r.failures


def hold_orbit(
    rig: AbstractRig,
    param: str,
    value: float,
    target: PolarTarget,
    options: PPCBCOptions,
    omega: float,
    on_evaluation: Callable[[int], None] | None = None,
) -> tuple[LCOPoint | None, str]:
    """The LCO near a known orbit, without a scan: the oscillation started at 0.8 times
    the target's mean radius (:func:`~bifid.cbc._ppcbc_family.bootstrap`), then the
    PP-CBC zero problem at ``value`` solved by the Broyden corrector from ``target`` (e.g.
    a model's orbit, :func:`~bifid.cbc.orbit_polar_target`, in its own frame). For LCOs a
    scan cannot reach: the targets between two LCOs, which it must hold on the way, can
    be beyond its controller. Returns ``(point, "")`` or ``(None, reason)``."""
    rig.set_parameter(param, value)
    a0 = float(target.coefficients[0])
    try:
        _, _, omega = bootstrap(rig, options, 0.8 * a0, omega, a_max=a0)
    except ConvergenceError as exc:
        return None, f"the oscillation could not be started near the orbit: {exc}"
    matrix = np.eye(2) if target.transform is None else np.array(target.transform, float)
    family = TargetFamily(options, matrix, target.origin)
    vec = family.unknowns(target)[: family.size]
    problem = PPCBCProblem(rig, options, family, param, omega, vec)
    corrector = BroydenCorrector(problem, max_iter=options.newton_max, on_evaluation=on_evaluation)
    e_p = np.zeros(vec.shape[0] + 1)
    e_p[-1] = 1.0
    r = corrector.correct(np.concatenate([vec, [value]]), e_p, value, None)
    if not r.converged:
        return (
            None,
            f"the control error did not converge from the orbit: {r.info.get('reason', '')}",
        )
    try:
        ev = r.info["evaluation"]
        return make_point(rig, options, family, ev, int(r.info.get("evaluations", 0)), "scan"), ""
    except Invasive as exc:
        return None, str(exc)
