"""Measured zero problems and the Broyden corrector that solves them on a rig.

A *measured* zero problem ``G(y) = 0``, ``G: R^{N+1} -> R^N``, is one whose residual is
obtained by holding a rig at ``y`` (a control target and a parameter, forcing amplitude or
frequency) and projecting the measured response on the target's Fourier coefficients
(thesis eqs. 3.4, 3.23). It has no derivative and every evaluation costs rig time, so it
is solved by the continuation driver of :mod:`bifid.continuation` with a quasi-Newton
corrector (:class:`BroydenCorrector`, thesis §3.2.2):

* the Jacobian ``J ≈ G_y`` is bootstrapped by finite differences on the rig (each step
  enlarged until the change of ``G`` stands out of its noise) and then updated by
  Broyden's rank-one rule in the metric ``W`` of the arclength,
  ``J ← J + (ΔG - J Δy) Δyᵀ W / (Δyᵀ W Δy)``, only from changes well above the noise;
* Newton steps on ``[G(y); row · y - c] = 0`` are bounded by a trust region (far from the
  solution a Broyden Jacobian can point anywhere, and the rig must not be sent there); a
  step that raises the residual above its noise triggers one finite-difference refresh;
* acceptance is noise-aware: ``|G_i| <=`` the problem's tolerance plus the noise floor of
  ``G_i`` (3σ), the Newton step (the error estimate of ``y``) below the problem's step
  tolerance plus what the noise floor allows, and the floors themselves small enough
  (while they are not, the record is extended at the same ``y``);
* the tangent is the null vector of ``[J; (W t_prev)ᵀ]``.

The problem (:class:`MeasuredProblem`) says how to hold the rig at ``y`` and what the
tolerances are; everything else is here, written by hand because no library offers a
quasi-Newton solver for noisy residuals that cost seconds of rig time each.
"""

from __future__ import annotations

import abc
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import scipy.linalg

from bifid.cbc._rig import AbstractRig, Measurement
from bifid.continuation import AbstractCorrector, Correction
from bifid.errors import BifidInputError, ConvergenceError

__all__ = [
    "BroydenCorrector",
    "Evaluation",
    "Failure",
    "MeasuredProblem",
    "ProtocolOptions",
    "RigTripped",
    "run",
]


class RigTripped(ConvergenceError):
    """The rig's safety gate fired while a point was being measured (the controller was
    disarmed and the rig brought to rest)."""


def run(rig: AbstractRig, duration: float) -> Measurement:
    """``rig.run(duration)``, with a trip of its safety gate raised as :class:`RigTripped`."""
    try:
        m = rig.run(duration)
    except ConvergenceError as exc:  # a rig that stops itself by raising
        raise RigTripped(str(exc)) from None
    if m.status == "tripped":
        raise RigTripped(m.reason or "the rig's safety gate fired")
    return m


class ProtocolOptions:
    """Base of the options of a CBC protocol (frozen dataclasses): JSON for settings."""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)  # type: ignore[call-overload]

    def check(self, positive: tuple[str, ...], counts: tuple[str, ...]) -> None:
        """Raise :class:`~bifid.errors.BifidInputError` unless the fields ``positive``
        are finite numbers > 0, ``counts`` integers >= 1 and ``n_harmonics`` >= 1."""
        if int(getattr(self, "n_harmonics", 1)) < 1:
            raise BifidInputError(f"n_harmonics must be >= 1, got {self.n_harmonics!r}.")
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise BifidInputError(f"{name} must be a positive number, got {v!r}.")
        for name in counts:
            if int(getattr(self, name)) < 1:
                raise BifidInputError(f"{name} must be a positive integer.")


@dataclass
class Evaluation:
    """One evaluation of a measured zero problem: the rig held at ``y`` and measured.

    Attributes
    ----------
    y : ndarray of shape (N+1,)
    g : ndarray of shape (N,)
        The residual ``G(y)``.
    floor : ndarray of shape (N,)
        Noise floor (3σ) of each component of ``g``.
    info : Any
        What the problem needs to turn the evaluation into a recorded point.
    """

    y: np.ndarray
    g: np.ndarray
    floor: np.ndarray
    info: Any = None

    @property
    def residual(self) -> float:
        return float(np.max(np.abs(self.g))) if self.g.size else 0.0


class MeasuredProblem(abc.ABC):
    """A zero problem whose residual is measured on a rig (see the module docstring).

    Attributes
    ----------
    param_index : int
        Component of ``y`` that is the continuation parameter.
    weights : ndarray of shape (N+1,)
        Diagonal ``W`` of the arclength metric (``1 / scale²`` of each unknown).
    metric : ndarray of shape (N+1,)
        Diagonal of the metric of the corrector's trust region and Broyden updates, and
        of the turning of the branch (default: ``weights``).
    """

    param_index: int = -1
    weights: np.ndarray
    #: finite-difference refreshes of the Jacobian per correction after a step that made
    #: the residual worse, or a stall (a singular estimate is always refreshed, twice)
    refresh_limit: int = 2
    #: a noise-limited point goes through the campaign's retry policy instead of failing
    #: at once (PP-CBC: next to a cycle fold the Jacobian estimate decides, and a fresh
    #: one with raised gains may resolve it)
    retry_noise_limited: bool = False
    jacobian: np.ndarray | None = None  # the corrector's current estimate of G_y
    #: the constraint row of the current correction (``row · y = c``: fixed parameter,
    #: or the arclength), set by the corrector
    constraint: np.ndarray | None = None

    @property
    def metric(self) -> np.ndarray:
        return self.weights

    @abc.abstractmethod
    def evaluate(self, y: np.ndarray) -> Evaluation:
        """Hold the rig at ``y``, let it settle and measure ``G(y)``.

        Raises :class:`RigTripped` when the rig's safety gate fires."""

    @abc.abstractmethod
    def tolerance(self, ev: Evaluation) -> np.ndarray:
        """``|G_i| <= tolerance_i`` (noise floor included) means converged in ``G``."""

    def step_tolerance(self, ev: Evaluation) -> np.ndarray | None:
        """Largest accepted Newton step per unknown (its noise allowance is added), or
        None for no step test."""
        return None

    def begin(self) -> None:  # noqa: B027 - optional hook
        """Called at the start of every correction."""

    def rescale(self, y: np.ndarray) -> None:  # noqa: B027 - optional hook
        """Called with each accepted point: a problem whose scales follow the branch
        updates :attr:`weights` in place here."""

    def transport(self, jacobian: np.ndarray, y_from: np.ndarray, y_to: np.ndarray) -> np.ndarray:
        """The Jacobian estimate made at ``y_from`` carried to ``y_to`` (the start of the
        next correction); unchanged by default. A problem whose unknowns are polar
        coordinates of another (e.g. a force's amplitude and phase) rotates it here."""
        return jacobian

    def stepped(self, ev: Evaluation) -> None:  # noqa: B027 - optional hook
        """Called with the evaluation after each Newton step (not after the evaluations
        of a finite-difference Jacobian)."""

    def settled(self, ev: Evaluation) -> bool:
        """Conditions of convergence besides ``G`` (e.g. the target's other harmonics)."""
        return True

    def precise(self, ev: Evaluation) -> bool:
        """Whether the noise floors of ``ev`` are small enough to verify a point."""
        return True

    def extend(self, ev: Evaluation) -> Evaluation | None:
        """A longer record at the same ``y`` (lower floors), or None when at its limit."""
        return None

    def imprecision(self, ev: Evaluation) -> str:
        """Why ``ev`` cannot be verified (when :meth:`precise` is False after extending)."""
        return "noise floor too high to verify the point"

    @abc.abstractmethod
    def fd_steps(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Initial and largest finite-difference step of each unknown."""


class NoiseLimited(str):
    """A failure reason that a smaller step cannot cure (the noise floor)."""


class BroydenCorrector(AbstractCorrector):
    """Quasi-Newton corrector of a :class:`MeasuredProblem` (see the module docstring).

    Parameters
    ----------
    problem : MeasuredProblem
    max_iter : int
        Newton iterations per correction.
    trust : float
        Trust radius of a Newton step (norm of :attr:`MeasuredProblem.metric`), as a
        multiple of the distance from the prediction to the last accepted point.
    radius : float
        Trust radius where there is no last point (the first correction).
    min_radius : float
        Smallest trust radius (near a fold a prediction that overshoots may need a
        correction longer than the step).
    on_evaluation : callable, optional
        Called with 1 after every rig evaluation (progress).

    Attributes
    ----------
    evaluations : int
        Rig evaluations so far.
    jacobian : ndarray of shape (N, N+1) or None
        The current estimate of ``G_y``.
    box : (int, float, float) or None
        Keep unknown ``i`` in ``[lo, hi]`` (a bracketed zero); a correction that hits the
        box twice gives up.
    last_reason : str
        Why the last correction failed (a :class:`NoiseLimited` reason when a smaller
        step cannot help); ``tripped`` whether the rig's safety gate fired.
    follow_secant : bool
        Give the driver's secant as the tangent (see :meth:`tangent`).
    """

    def __init__(
        self,
        problem: MeasuredProblem,
        *,
        max_iter: int = 12,
        trust: float = 1.0,
        radius: float = math.inf,
        min_radius: float = 0.0,
        on_evaluation=None,
    ) -> None:
        self.problem = problem
        self.max_iter = int(max_iter)
        self.trust = float(trust)
        self.radius = float(radius)
        self.min_radius = float(min_radius)
        self.on_evaluation = on_evaluation
        self.evaluations = 0
        self.jacobian: np.ndarray | None = None
        self.y_accepted: np.ndarray | None = None
        self.box: tuple[int, float, float] | None = None
        self.last: Evaluation | None = None
        self.last_reason = ""
        self.tripped = False
        self.follow_secant = False

    # ------------------------------------------------------------------ evaluations
    def evaluate(self, y: np.ndarray) -> Evaluation:
        ev = self.problem.evaluate(np.asarray(y, dtype=float))
        self.evaluations += 1
        self.last = ev
        if self.on_evaluation is not None:
            self.on_evaluation(1)
        return ev

    def bootstrap(self, ev: Evaluation, columns: list[int] | None = None) -> Evaluation:
        """Finite-difference Jacobian at ``ev.y`` (the given columns, else all); returns a
        fresh evaluation at ``ev.y`` (the rig is left there).

        Each step starts at the problem's initial step and grows (up to its largest)
        until the change of ``G`` is five times its noise floor."""
        y = ev.y
        n = y.shape[0]
        h0, h_max = self.problem.fd_steps(y)
        J = np.zeros((ev.g.shape[0], n)) if self.jacobian is None else self.jacobian.copy()
        for j in range(n) if columns is None else columns:
            h = float(h0[j])
            while True:
                yp = y.copy()
                yp[j] += h
                evp = self.evaluate(yp)
                dg = evp.g - ev.g
                need = 5.0 * float(np.max(np.maximum(ev.floor, evp.floor)))
                size = float(np.linalg.norm(dg))
                if size >= need or h >= h_max[j]:
                    break
                h = min(float(h_max[j]), h * min(10.0, 2.0 * need / max(size, 1e-300)))
            J[:, j] = dg / h
        self.jacobian = J
        return self.evaluate(y)

    # ------------------------------------------------------------------ correction
    def _radius(self, y_pred: np.ndarray) -> float:
        if self.y_accepted is None or self.y_accepted.shape != y_pred.shape:
            return self.radius
        d = y_pred - self.y_accepted
        dist = math.sqrt(float(d @ (self.problem.metric * d)))
        return max(self.trust * dist, self.min_radius) if dist > 0 else self.radius

    def _newton_step(
        self, ev: Evaluation, row: np.ndarray, c: float
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Newton step and its noise allowance, or None when ``[J; row]`` is singular."""
        assert self.jacobian is not None
        A = np.vstack([self.jacobian, row[None, :]])
        with np.errstate(all="ignore"):
            try:
                lu = scipy.linalg.lu_factor(A, check_finite=False)
            except (ValueError, np.linalg.LinAlgError):
                return None
            dy = scipy.linalg.lu_solve(
                lu, np.concatenate([-ev.g, [c - row @ ev.y]]), check_finite=False
            )
            noise = np.abs(
                scipy.linalg.lu_solve(lu, np.concatenate([ev.floor, [0.0]]), check_finite=False)
            )
        if not (np.all(np.isfinite(dy)) and np.all(np.isfinite(noise))):
            return None
        return dy, noise

    def _converged(self, ev: Evaluation, dy: np.ndarray, noise: np.ndarray) -> bool:
        if not (np.all(np.abs(ev.g) <= self.problem.tolerance(ev)) and self.problem.settled(ev)):
            return False
        st = self.problem.step_tolerance(ev)
        return st is None or bool(np.all(np.abs(dy) <= st + noise))

    def correct(self, y_pred: np.ndarray, row: np.ndarray, c: float, args: Any) -> Correction:
        """Solve ``[G(y); row · y - c] = 0`` from ``y_pred`` (module docstring).

        ``info`` of the result: ``evaluation`` (the last :class:`Evaluation`),
        ``evaluations`` (rig evaluations spent), ``reason`` (why it failed; a
        :class:`NoiseLimited` reason when no smaller step can help).
        """
        y_pred = np.asarray(y_pred, dtype=float)
        row = np.asarray(row, dtype=float)
        n0 = self.evaluations
        radius = self._radius(y_pred)
        try:
            r = self._correct(y_pred, row, float(c), radius, n0)
        except ConvergenceError as exc:  # the rig tripped, or lost the oscillation
            tripped = isinstance(exc, RigTripped)
            r = Correction(
                y_pred,
                False,
                0,
                math.inf,
                {
                    "reason": f"the rig tripped: {exc}" if tripped else str(exc),
                    "tripped": tripped,
                    "evaluations": self.evaluations - n0,
                },
            )
        self.last_reason = r.info.get("reason", "")
        self.tripped = bool(r.info.get("tripped", False))
        return r

    def _correct(self, y_pred, row, c, radius, n0) -> Correction:
        """Quasi-Newton iterations with a trust region (module docstring): a step that
        raises the residual above its noise is rejected (its change still updates the
        Jacobian) and the Jacobian refreshed by finite differences at the last point, or,
        after ``problem.refresh_limit`` refreshes, the trust radius halved; a residual
        that has not halved in four iterations also refreshes the Jacobian."""
        w = self.problem.metric
        self.problem.constraint = row
        self.problem.begin()
        if self.jacobian is not None and self.y_accepted is not None:
            if self.y_accepted.shape == y_pred.shape:
                self.jacobian = self.problem.transport(self.jacobian, self.y_accepted, y_pred)
        ev = self.evaluate(y_pred)
        if self.jacobian is None:
            ev = self.bootstrap(ev)
        refreshes, since, res_ref = 0, 0, ev.residual
        hits = 0
        reason = f"no convergence in {self.max_iter} iterations"
        for it in range(self.max_iter + 1):
            step = self._newton_step(ev, row, c)
            stalled = since >= 4 and ev.residual > 0.5 * res_ref
            if step is None or (stalled and refreshes < self.problem.refresh_limit):
                if refreshes >= 2:
                    reason = "singular Jacobian estimate"
                    break
                refreshes, since, res_ref = refreshes + 1, 0, ev.residual
                ev = self.bootstrap(ev)
                continue
            dy, noise = step
            if self._converged(ev, dy, noise):
                self.problem.jacobian = self.jacobian
                while not self.problem.precise(ev):
                    longer = self.problem.extend(ev)
                    if longer is None:
                        break
                    self.evaluations += 1
                    if self.on_evaluation is not None:
                        self.on_evaluation(1)
                    ev = longer
                if not self.problem.precise(ev):
                    return self._result(
                        ev, False, it, n0, NoiseLimited(self.problem.imprecision(ev))
                    )
                # the longer record tells more: its own step (the short record's step is
                # a step on noise), and converged only if it still says so
                dy, noise = self._newton_step(ev, row, c) or (dy, noise)
                if self._converged(ev, dy, noise):
                    return self._result(ev, True, it, n0, "")
            if it == self.max_iter:
                break
            size = math.sqrt(float(dy @ (w * dy)))
            if size > radius:
                dy = dy * (radius / size)
            if self.box is not None:
                i, lo, hi = self.box
                target = min(max(ev.y[i] + dy[i], lo), hi)
                if target != ev.y[i] + dy[i]:
                    hits += 1
                    if hits >= 2:
                        reason = "the zero left its bracket"
                        break
                    dy = dy * ((target - ev.y[i]) / dy[i]) if dy[i] != 0 else dy
            ev_new = self.evaluate(ev.y + dy)
            self.problem.stepped(ev_new)
            since += 1
            self._broyden(ev, ev_new)
            worse = ev_new.residual > max(
                ev.residual, 4.0 * float(np.max(self.problem.tolerance(ev_new)))
            )
            if not worse:
                ev = ev_new
            elif refreshes < self.problem.refresh_limit:
                # the step made it worse: the Jacobian is wrong; refresh it where we were
                refreshes, since, res_ref = refreshes + 1, 0, ev.residual
                ev = self.bootstrap(ev)
            else:
                radius = 0.5 * min(radius, size)
        return self._result(ev, False, self.max_iter, n0, reason)

    def _broyden(self, ev: Evaluation, ev_new: Evaluation) -> None:
        """Rank-one update from a step whose change of ``G`` stands out of the noise."""
        assert self.jacobian is not None
        w = self.problem.metric
        dy = ev_new.y - ev.y
        dyw = dy * w
        den = float(dy @ dyw)
        if den <= 0:
            return
        floor = 3.0 * float(np.max(np.maximum(ev.floor, ev_new.floor)))
        if (
            float(np.linalg.norm(self.jacobian @ dy)) > floor
            or float(np.linalg.norm(ev_new.g - ev.g)) > floor
        ):
            dg = ev_new.g - ev.g
            self.jacobian = self.jacobian + np.outer(dg - self.jacobian @ dy, dyw) / den

    def _result(self, ev: Evaluation, ok: bool, it: int, n0: int, reason: str) -> Correction:
        info = {"evaluation": ev, "evaluations": self.evaluations - n0}
        if reason:
            info["reason"] = reason
        return Correction(ev.y.copy(), ok, int(it), ev.residual, info)

    # ------------------------------------------------------------------ driver hooks
    def tangent(self, y, t_prev, weights, args):
        """Unit tangent (``W`` norm) and the sign of the bordered determinant.

        The null vector of ``[J; (W t_prev)ᵀ]`` while :attr:`follow_secant` is False (at
        the start of a branch, after a finite-difference Jacobian); then ``t_prev`` itself
        (the secant the driver predicts along): a Broyden Jacobian is good enough to
        correct with, not to judge the direction of a step by."""
        t_prev = np.asarray(t_prev, dtype=float)
        w = np.asarray(weights, dtype=float)
        unit = t_prev / math.sqrt(float(t_prev @ (w * t_prev)))
        if self.jacobian is None or self.follow_secant:
            return unit, math.nan
        A = np.vstack([self.jacobian, (w * t_prev)[None, :]])
        rhs = np.zeros(A.shape[0])
        rhs[-1] = 1.0
        with np.errstate(all="ignore"):
            try:
                lu, piv = scipy.linalg.lu_factor(A, check_finite=False)
                t = scipy.linalg.lu_solve((lu, piv), rhs, check_finite=False)
            except (ValueError, np.linalg.LinAlgError):
                return unit, math.nan
        if not np.all(np.isfinite(t)):
            return unit, math.nan
        swaps = np.count_nonzero(piv != np.arange(piv.shape[0]))
        sign = float((-1) ** swaps * np.prod(np.sign(np.diag(lu))))
        return t / math.sqrt(float(t @ (w * t))), sign

    def accept(self, correction: Correction) -> None:
        self.y_accepted = np.asarray(correction.y, dtype=float).copy()

    def state(self) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {"evaluations": np.array(float(self.evaluations))}
        if self.jacobian is not None:
            out["jacobian"] = self.jacobian.copy()
        if self.y_accepted is not None:
            out["y_accepted"] = self.y_accepted.copy()
        return out

    def restore(self, state: dict[str, np.ndarray]) -> None:
        self.jacobian = (
            None if state.get("jacobian") is None else np.array(state["jacobian"], dtype=float)
        )
        self.y_accepted = (
            None if state.get("y_accepted") is None else np.array(state["y_accepted"], dtype=float)
        )
        self.evaluations = int(float(np.asarray(state.get("evaluations", 0.0))))


@dataclass
class Failure:
    """A point a measured campaign could not take, with where and why."""

    where: dict[str, float]
    reason: str
    data: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {**self.where, "reason": str(self.reason), **self.data}
