"""The measured zero problem of forced CBC: S-curves and frequency response curves (§3.2).

Unknowns: on an S-curve (fixed ``Ω``) ``y = (A_1^*, ψ, γ)`` — the target's fundamental
``A_1^* cos θ`` (``B_1^* = 0`` fixes the phase origin, §3.2.1), the force's phase and
amplitude, ``γ cos(θ - ψ)``; on an FRC (fixed ``γ``) ``y = (A_1^*, B_1^*, Ω)`` with the
force ``γ cos θ``. Equations

.. math:: G(y) = u_1 / |k_p + iΩk_d| = 0,

the control's fundamental (cos and sin parts, in units of the response), with the higher
harmonics of the target converged by Picard iteration (eq. 3.8, accelerated harmonic by
harmonic) inside each evaluation. With the higher harmonics converged the control is a
force ``u_1`` at the forcing frequency, and ``G = 0`` is eq. 3.4: the response is that of
the uncontrolled system. This one problem gives the S-curve of §3.2.1 (where the thesis
moves the control's fundamental into the force, eq. 3.6, the quasi-Newton corrector does
the same through its Jacobian ``∂u_1/∂(ψ, γ)``, which is well conditioned at the folds of
``γ``) and the FRC. The continuation driver follows an FRC in the arclength of
``W = diag(1/a_ref², 1/a_ref², 1/Ω_ref²)``, an S-curve in (almost only) ``A_1^*/a_ref``,
which grows along it: each point is then solved for the force at its ``A_1^*``, round
the folds of ``γ`` too.

Acceptance. ``|u_1| <= tol · γ +`` its noise floor and the higher harmonics' tracking
errors ``<= tol · A_1^* +`` theirs, *and* those floors (3σ) small: the control's
fundamental known to ``precision · γ``, the response to ``precision · A_1^*``. While a
floor is too high the record is extended (the rig keeps running, no re-settling) up to
``max_measure_periods``; a point that still cannot be verified is a failure, never
recorded. The next evaluations of the point are measured on records as long as the
longest it needed; on an FRC, where a Newton step leaves the residual within a few noise
floors, twice as long (Newton steps on noise would only wander). An S-curve's points are
solved for the force at a fixed ``A_1^*``: their residual is as well determined by
records as long, and doubling them only cost rig time.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bifid.cbc._controllers import FourierTarget
from bifid.cbc._forced_measure import (
    ForcedCBCOptions,
    ForcedPoint,
    Projection,
    extend,
    gain,
    make_forced_point,
    measure,
)
from bifid.cbc._measured import Evaluation, MeasuredProblem
from bifid.cbc._rig import AbstractRig
from bifid.cbc._secant import HarmonicSecant
from bifid.errors import BifidInputError, ConvergenceError

__all__ = ["ForcedProblem"]


class ForcedProblem(MeasuredProblem):
    """The forced-CBC zero problem on a rig (module docstring).

    Parameters
    ----------
    rig : AbstractRig
    opts : ForcedCBCOptions
    kind : {"scurve", "frc"}
        ``λ = γ`` at fixed ``omega``, or ``λ = Ω`` at fixed ``forcing``.
    fixed : float
        The fixed one of ``Ω`` (S-curve) and ``γ`` (FRC).
    a_ref, param_scale : float
        Scales of ``A_1^*, B_1^*`` and of ``λ`` in the arclength metric.
    a_first : float
        Size of the first response (sets the finite-difference steps).
    pstar : ndarray
        The target's coefficients ``[A0, A1..Aq, B1..Bq]`` (its higher harmonics are the
        Picard iterate carried from evaluation to evaluation).
    """

    def __init__(
        self,
        rig: AbstractRig,
        opts: ForcedCBCOptions,
        kind: str,
        fixed: float,
        a_ref: float,
        param_scale: float,
        a_first: float,
        pstar: np.ndarray,
    ) -> None:
        if kind not in ("scurve", "frc"):
            raise BifidInputError(f"forced CBC kind must be 'scurve' or 'frc', got {kind!r}.")
        self.rig, self.opts, self.kind, self.fixed = rig, opts, kind, float(fixed)
        self.q = opts.n_harmonics
        self.param_index = 2
        self.a_ref, self.param_scale, self.a_first = a_ref, param_scale, a_first
        second = a_ref if kind == "frc" else math.pi
        self._metric = np.array([1.0 / a_ref**2, 1.0 / second**2, 1.0 / param_scale**2])
        # S-curves: the arclength is (nearly) the target's amplitude, which grows along
        # the curve (as in §3.2.1, each point is solved for the force at its A_1^*): at the
        # folds of γ -- where a point's γ is only known to the noise floor -- a step then
        # never depends on the noise of γ
        self.weights = self._metric if kind == "frc" else self._metric * np.array([1.0, 1e-4, 1e-4])
        self.pstar = np.array(pstar, dtype=float)
        # S-curves: the corrector solves for the force at a fixed A_1^* (eq. 3.6) with a
        # Jacobian carried from point to point (see transport) that Broyden's updates
        # keep; one finite-difference refresh per point at most (on the long records of
        # noisy points a refresh costs more than the steps it saves)
        self.refresh_limit = 2 if kind == "frc" else 1
        self.periods = float(opts.measure_periods)
        self.jacobian: np.ndarray | None = None  # the corrector's estimate (force floors)
        q = self.q
        self._others = [i for i in range(2 * q + 1) if i not in (1, q + 1)]

    @property
    def metric(self) -> np.ndarray:
        return self._metric

    # ------------------------------------------------------------------ the rig
    def forcing(self, y: np.ndarray) -> tuple[float, float]:
        """``(γ, Ω)`` at ``y``."""
        lam = float(y[2])
        return (lam, self.fixed) if self.kind == "scurve" else (self.fixed, lam)

    def fundamental(self, y: np.ndarray) -> tuple[float, float, float]:
        """``(A_1^*, B_1^*, ψ)`` at ``y``."""
        if self.kind == "scurve":
            return float(y[0]), 0.0, float(y[1])
        return float(y[0]), float(y[1]), 0.0

    def unknowns(self, a1: float, b1: float, lam: float) -> np.ndarray:
        """``y`` of a target fundamental ``(A_1^*, B_1^*)`` at ``λ`` (the force's phase
        chosen to make ``B_1^* = 0`` on an S-curve)."""
        if self.kind == "scurve":
            return np.array([math.hypot(a1, b1), -math.atan2(b1, a1), lam])
        return np.array([a1, b1, lam])

    def begin(self) -> None:
        self.periods = float(self.opts.measure_periods)

    def evaluate(self, y: np.ndarray) -> Evaluation:
        """Hold target ``y`` (Picard on the higher harmonics) and measure."""
        q, o = self.q, self.opts
        gamma, om = self.forcing(y)
        if not (gamma >= 0 and om > 0):
            raise ConvergenceError(
                f"the corrector asked for the forcing γ = {gamma:g}, "
                f"Ω = {om:g} (both must be positive)."
            )
        A1, B1, psi = self.fundamental(y)
        pstar = self.pstar.copy()
        pstar[1], pstar[q + 1] = A1, B1
        a1 = max(math.hypot(A1, B1), 1e-300)
        self.rig.set_forcing(gamma, om, psi)
        harm = HarmonicSecant(q, fixed=(1,))
        ev = None
        for k in range(o.picard_max):
            self.rig.set_controller(o.controller, FourierTarget(pstar))
            r = measure(self.rig, o, om, o.settle_periods, self.periods)
            ev = self._evaluation(y, pstar, r)
            if self._harmonics_error(ev) <= o.tol * a1 + r.floor or k + 1 == o.picard_max:
                break
            pstar = harm.step(pstar, r.p, r.floor)
        assert ev is not None
        self.pstar = pstar
        # the residual is as small as this record could tell: measure the next one as long
        self.periods = max(self.periods, ev.info[1].periods)
        return ev

    def stepped(self, ev: Evaluation) -> None:
        """After a Newton step on an FRC: where the residual is within a few noise floors
        the next records are twice as long (Newton steps on noise would only wander)."""
        if self.kind == "frc" and ev.residual <= 4.0 * float(np.max(self.tolerance(ev))):
            self.periods = min(2.0 * self.periods, self.opts.max_measure_periods)

    def _evaluation(self, y: np.ndarray, pstar: np.ndarray, r: Projection) -> Evaluation:
        q = self.q
        K = gain(self.opts, self.forcing(y)[1])
        g = np.array([r.u[1], r.u[q + 1]]) / K
        return Evaluation(np.array(y, dtype=float), g, np.full(2, r.ufloor / K), (pstar.copy(), r))

    def _harmonics_error(self, ev: Evaluation) -> float:
        pstar, r = ev.info
        return float(np.max(np.abs((pstar - r.p)[self._others]))) if self._others else 0.0

    def _force_map(self, y: np.ndarray) -> np.ndarray:
        """``∂f/∂(ψ, γ)`` of the force's (cos, sin) parts ``f = γ (cos ψ, sin ψ)``."""
        gamma, psi = self.forcing(y)[0], self.fundamental(y)[2]
        c, s = math.cos(psi), math.sin(psi)
        return np.array([[-gamma * s, c], [gamma * c, s]])

    def transport(self, jacobian: np.ndarray, y_from: np.ndarray, y_to: np.ndarray) -> np.ndarray:
        """S-curve: ``∂G/∂(ψ, γ) = (∂G/∂f)(∂f/∂(ψ, γ))`` with ``∂G/∂f`` kept (it changes
        slowly along the curve) and ``∂f/∂(ψ, γ)`` moved to the new force: the force's
        phase turns by up to π along an S-curve, and a Jacobian carried over in
        ``(ψ, γ)`` would be rotated by the step's turn of ``ψ`` (and scaled by that of
        ``γ``)."""
        if self.kind != "scurve" or not (y_from[2] > 0 and y_to[2] > 0):
            return jacobian
        J = np.array(jacobian, dtype=float)
        with np.errstate(all="ignore"):
            try:
                moved = J[:, 1:3] @ np.linalg.solve(self._force_map(y_from), self._force_map(y_to))
            except np.linalg.LinAlgError:
                return jacobian
        if np.all(np.isfinite(moved)):
            J[:, 1:3] = moved
        return J

    # ------------------------------------------------------------------ acceptance
    def tolerance(self, ev: Evaluation) -> np.ndarray:
        """``|u_1| <= tol · γ +`` its floor, on each of the two components of ``G`` (each
        within ``1/√2`` of it, so that the magnitude is)."""
        gamma, om = self.forcing(ev.y)
        K = gain(self.opts, om)
        return np.full(2, (self.opts.tol * gamma + ev.info[1].ufloor) / (K * math.sqrt(2.0)))

    def _a1(self, y: np.ndarray) -> float:
        A1, B1, _ = self.fundamental(y)
        return max(math.hypot(A1, B1), 1e-300)

    def settled(self, ev: Evaluation) -> bool:
        a1 = self._a1(ev.y)
        return self._harmonics_error(ev) <= self.opts.tol * a1 + ev.info[1].floor

    def force_floor(self, ev: Evaluation) -> float:
        """Noise floor of the point's forcing error, relative to ``γ``.

        FRC: the control's fundamental ``u_1`` is a force where the actuator acts where
        the force does, so ``floor(u_1) / γ``. S-curve: the force update that cancels
        ``u_1`` (eq. 3.6, ``J_f⁻¹ u_1`` with ``J_f = ∂u_1/∂f`` from the corrector's
        Jacobian in ``(ψ, γ)``): ``|J_f⁻¹| floor(u_1) / γ``, which also holds where the
        force acts on more than the actuator does (``shaw_pierre``)."""
        r = ev.info[1]
        gamma, om = self.forcing(ev.y)
        scale = 1.0
        J = self.jacobian
        if self.kind == "scurve" and J is not None and gamma > 0:
            psi = self.fundamental(ev.y)[2]
            D = np.array(
                [[-gamma * math.sin(psi), math.cos(psi)], [gamma * math.cos(psi), math.sin(psi)]]
            )
            with np.errstate(all="ignore"):
                try:
                    Jf = gain(self.opts, om) * J[:, 1:3] @ np.linalg.inv(D)
                    scale = float(np.linalg.norm(np.linalg.inv(Jf), 2))
                except np.linalg.LinAlgError:
                    scale = 1.0
            if not (math.isfinite(scale) and scale > 0):
                scale = 1.0
        return scale * r.ufloor / max(gamma, 1e-300)

    def precise(self, ev: Evaluation) -> bool:
        r = ev.info[1]
        return self.force_floor(
            ev
        ) <= self.opts.precision and r.floor <= self.opts.precision * self._a1(ev.y)

    def extend(self, ev: Evaluation) -> Evaluation | None:
        r = ev.info[1]
        if r.periods >= 0.99 * self.opts.max_measure_periods:
            return None
        om = self.forcing(ev.y)[1]
        longer = self._evaluation(ev.y, ev.info[0], extend(self.rig, self.opts, om, r))
        # a record this long was needed to verify a point here: the next ones as long
        self.periods = max(self.periods, longer.info[1].periods)
        return longer

    def imprecision(self, ev: Evaluation) -> str:
        r = ev.info[1]
        a1 = self._a1(ev.y)
        return (
            f"noise floor too high to verify non-invasiveness after {r.periods:.0f} "
            f"periods: forcing error known to {100 * self.force_floor(ev):.2g} % of "
            f"γ, response to {100 * r.floor / a1:.2g} % of A1* (precision "
            f"{100 * self.opts.precision:g} %; raise max_measure_periods or lower the "
            "gains)"
        )

    def fd_steps(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = self.a_first
        if self.kind == "frc":
            return (
                np.array([1e-2 * a, 1e-2 * a, 1e-4 * self.param_scale]),
                np.array([0.1 * a, 0.1 * a, 1e-2 * self.param_scale]),
            )
        return (
            np.array([1e-2 * a, 1e-2, 1e-3 * self.param_scale]),
            np.array([0.1 * a, 0.1, 3e-2 * self.param_scale]),
        )

    # ------------------------------------------------------------------ points
    def point(self, ev: Evaluation, iterations: int) -> ForcedPoint:
        """The recorded point of a converged evaluation."""
        pstar, r = ev.info
        gamma, om = self.forcing(ev.y)
        res = max(self._harmonics_error(ev), float(np.hypot(*ev.g))) / self._a1(ev.y)
        pt = make_forced_point(
            self.rig, self.opts, om, gamma, self.fundamental(ev.y)[2], pstar, r, res, iterations
        )
        pt.forcing_floor = self.force_floor(ev)
        return pt

    def state(self) -> dict[str, Any]:
        return {
            "pstar": self.pstar.tolist(),
            "periods": self.periods,
            "a_ref": self.a_ref,
            "param_scale": self.param_scale,
            "a_first": self.a_first,
        }


def open_loop(rig: AbstractRig, opts: ForcedCBCOptions, gamma: float, omega: float) -> np.ndarray:
    """The response coefficients to ``γ cos Ωt`` with the controller off (a start)."""
    rig.set_forcing(gamma, omega, 0.0)
    rig.set_controller(None)
    return measure(rig, opts, omega, 3 * opts.settle_periods).p
