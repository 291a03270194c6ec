"""PP-CBC target families: targets from their unknowns, and responses read in their terms.

A PP-CBC target is a closed curve in the measured phase plane ``(x1, x2)`` (thesis §3.3):

- **elliptic** (eqs. 3.13, 3.28-3.29): unknowns ``c* = [A*, ω*, o1*, o2*]`` (amplitude,
  signed aspect ratio, centre);
- **polar** (eqs. 3.20-3.22): in the frame ``ξ = T⁻¹ (x - o)``, ``r*(φ) = a0* + Σ a_j*
  cos jφ + b_j* sin jφ``; unknowns ``c* = [a0*, a_1*..a_nh*, b_1*..b_nh*]``. ``T`` maps the
  first-harmonic ellipse of a measured orbit to a circle, so that ``r(φ)`` of orbits near
  it has small harmonics (:meth:`TargetFamily.reframed`).

:meth:`TargetFamily.analyse` reads a measured response in the same terms (``Φ`` of eqs.
3.23-3.24), so that ``c* - Φ(response)`` is the residual of the PP-CBC zero problem.
:meth:`TargetFamily.hold` holds a target and measures; :func:`bootstrap` starts an
oscillation from rest and measures the frame of the orbit it draws.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from bifid.cbc._controllers import AbstractTarget, EllipticTarget, PolarTarget
from bifid.cbc._measured import run
from bifid.cbc._ppcbc import PPCBCOptions
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.errors import ConvergenceError
from bifid.signal import (
    coefficient_noise,
    estimate_frequency,
    fourier_basis,
    fourier_project,
    fourier_project_batch,
    fourier_project_segments,
    polar_project,
    uniform_basis,
    whole_periods,
)

__all__ = ["Response", "TargetFamily", "bootstrap"]

# points of a fitted curve read in polar terms (spectrally accurate: see _from_fit)
_CURVE_POINTS = 256


@dataclass
class Response:
    """A measured response read in a family's terms.

    ``vector`` is ``[a0, shape...]`` (the family's unknowns, measured); ``floor`` the noise
    floor (3σ) of ``a0`` in amplitude units."""

    m: Measurement
    omega: float
    vector: np.ndarray
    floor: float

    @property
    def a0(self) -> float:
        return float(self.vector[0])

    @property
    def shape(self) -> np.ndarray:
        return self.vector[1:]


class TargetFamily:
    """Elliptic or polar targets in a fixed frame (``T``, ``o``); see the module docstring."""

    def __init__(
        self,
        opts: PPCBCOptions,
        matrix: np.ndarray | None = None,
        origin: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self.o = opts
        self.matrix = np.eye(2) if matrix is None else np.asarray(matrix, dtype=float)
        self.inv = np.linalg.inv(self.matrix)
        self.origin = (float(origin[0]), float(origin[1]))

    @property
    def polar(self) -> bool:
        return self.o.target == "polar"

    @property
    def size(self) -> int:
        """Number of unknowns of a target."""
        return 2 * self.o.n_harmonics + 1 if self.polar else 4

    def frame(self) -> list[float]:
        """``[T11, T12, T21, T22, o1, o2]`` (to store and rebuild the family)."""
        return [*self.matrix.ravel().tolist(), *self.origin]

    @classmethod
    def from_frame(cls, opts: PPCBCOptions, frame) -> TargetFamily:
        f = [float(v) for v in frame]
        return cls(opts, np.array(f[:4]).reshape(2, 2), (f[4], f[5]))

    def with_options(self, opts: PPCBCOptions) -> TargetFamily:
        return TargetFamily(opts, self.matrix, self.origin)

    # ------------------------------------------------------------------ targets
    def target(self, vec: np.ndarray) -> AbstractTarget:
        """The target with unknowns ``vec``."""
        vec = np.asarray(vec, dtype=float)
        if not self.polar:
            return EllipticTarget(
                max(float(vec[0]), 0.0), float(vec[1]), (float(vec[2]), float(vec[3]))
            )
        coef = np.concatenate([[max(float(vec[0]), 0.0)], vec[1:]])
        T = self.matrix
        return PolarTarget(
            coefficients=coef,
            origin=self.origin,
            transform=((T[0, 0], T[0, 1]), (T[1, 0], T[1, 1])),
        )

    def unknowns(self, target: AbstractTarget) -> np.ndarray:
        """Inverse of :meth:`target`."""
        if isinstance(target, EllipticTarget):
            return np.array([target.amplitude, target.omega, *target.offset], dtype=float)
        assert isinstance(target, PolarTarget)
        return np.array(target.coefficients, dtype=float)

    def scales(self, vec: np.ndarray) -> np.ndarray:
        """Factors that express each unknown's error in units of the amplitude ``a0``."""
        if self.polar:
            return np.ones(self.size)
        w = max(abs(float(vec[1])), 1e-12)
        return np.array([1.0, float(vec[0]) / w, 1.0, 1.0])

    def nudged(self, target: AbstractTarget, nudge: float) -> AbstractTarget:
        """The target scaled by ``1 - nudge`` about its centre (stability test)."""
        if isinstance(target, EllipticTarget):
            return EllipticTarget(target.amplitude * (1 - nudge), target.omega, target.offset)
        assert isinstance(target, PolarTarget)
        return target.with_coefficients(target.coefficients * (1 - nudge))

    # ------------------------------------------------------------------ responses
    def _from_fit(self, c1: np.ndarray, c2: np.ndarray) -> np.ndarray:
        """The family's unknowns of the curves given by time-domain Fourier fits.

        ``c1``, ``c2`` of shape ``(p, 2q+1)``: ``p`` fits (e.g. one per period), read at once;
        returns shape ``(p, size)``.

        Polar: ``r(φ)`` is projected over the fitted curve sampled uniformly in its own
        phase ``θ``, with the exact ``dφ/dθ = (ξ1 ξ2' - ξ2 ξ1') / r²`` of the series as the
        quadrature weight: the integrand is smooth and periodic in ``θ``, so the rule is
        spectrally accurate on a short grid (eq. 3.24)."""
        q = (c1.shape[1] - 1) // 2
        if not self.polar:
            A1 = np.hypot(c1[:, 1], c1[:, q + 1])
            A2 = np.hypot(c2[:, 1], c2[:, q + 1])
            # sense of rotation in (x1, x2): sign of the area swept (a1 b2 - b1 a2)
            rot = np.where(c1[:, 1] * c2[:, q + 1] - c1[:, q + 1] * c2[:, 1] >= 0, 1.0, -1.0)
            return np.column_stack([A1, rot * A2 / np.maximum(A1, 1e-300), c1[:, 0], c2[:, 0]])
        grid = uniform_basis(_CURVE_POINTS, q)
        j = np.arange(1, q + 1, dtype=float)
        x = [c @ grid.T - o for c, o in zip((c1, c2), self.origin, strict=True)]
        dx = [
            np.concatenate([np.zeros((c.shape[0], 1)), j * c[:, q + 1 :], -j * c[:, 1 : q + 1]], 1)
            @ grid.T
            for c in (c1, c2)
        ]
        (a, b), (c, d) = self.inv
        xi1, xi2 = a * x[0] + b * x[1], c * x[0] + d * x[1]
        dxi1, dxi2 = a * dx[0] + b * dx[1], c * dx[0] + d * dx[1]
        r2 = np.maximum(xi1**2 + xi2**2, 1e-300)
        dphi = (xi1 * dxi2 - xi2 * dxi1) / r2
        phi = np.arctan2(xi2, xi1)
        B = fourier_basis(phi.ravel(), self.o.n_harmonics).reshape(*phi.shape, -1)
        return fourier_project_batch(np.sqrt(r2), B, weights=np.abs(dphi))

    def _polar_of(self, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
        d1, d2 = x1 - self.origin[0], x2 - self.origin[1]
        xi1 = self.inv[0, 0] * d1 + self.inv[0, 1] * d2
        xi2 = self.inv[1, 0] * d1 + self.inv[1, 1] * d2
        return polar_project(np.arctan2(xi2, xi1), np.hypot(xi1, xi2), self.o.n_harmonics)

    def analyse(self, m: Measurement, omega_hint: float) -> Response:
        """Measure the response curve in the target's own terms, with its noise floor.

        Both signals are first fitted in *time* by Fourier series at the measured
        frequency (linear in the data, so measurement noise averages out without bias);
        the curve's unknowns are computed from the fitted curve (a radius computed sample
        by sample would be biased upwards by the noise of a derivative estimate). With
        three or more periods they are computed period by period and averaged (batch
        means): the noise floor is 3 standard errors of that mean, which also captures
        the random motion that measurement noise injects through the controller, and
        single-period fits are immune to the phase diffusion of a noisy oscillation.
        """
        x1, x2 = m.signal(self.o.x1), m.signal(self.o.x2)
        om = estimate_frequency(x1, m.sample_rate, method="crossings")
        if not (om > 0 and math.isfinite(om)) or (
            omega_hint > 0 and not 1 / 3 < om / omega_hint < 3
        ):
            # no oscillation, or crossings of measurement noise: a frequency this far from
            # the last one would make the next record absurdly short or long
            om = omega_hint
        if not (om > 0 and math.isfinite(om)):
            raise ConvergenceError("no oscillation found in the measured response.")
        n = whole_periods(x1.shape[0], om, m.sample_rate)
        x1, x2 = x1[-n:], x2[-n:]
        theta = om * np.arange(n) / m.sample_rate
        nfit = max(2 * self.o.n_harmonics, 12) if self.polar else 3
        per = 2.0 * math.pi / om * m.sample_rate
        k_per = round(n / per)
        if k_per < 3:
            B = fourier_basis(theta, nfit)
            c = fourier_project(np.column_stack([x1, x2]), theta, nfit, basis=B)
            vec = self._from_fit(c[None, :, 0], c[None, :, 1])[0]
            floor = coefficient_noise(x1 - B @ c[:, 0]) * float(np.hypot(*self.inv[:, 0]))
        else:
            edges = [min(round(k * per), n) for k in range(k_per + 1)]
            ck, resid = fourier_project_segments(np.column_stack([x1, x2]), theta, edges, nfit)
            v = self._from_fit(ck[..., 0], ck[..., 1])
            vec = v.mean(axis=0)
            sd = np.std(v, axis=0, ddof=1) * self.scales(vec)
            floor = coefficient_noise(resid[:, 0]) * float(np.hypot(*self.inv[:, 0]))
            floor = max(floor, 3.0 * float(np.max(sd)) / math.sqrt(k_per))
        # a record that scatters by more than 1 % is not a steady orbit, not noise: cap the
        # floor so that it can never widen a tolerance enough to accept it
        floor = min(floor, 0.01 * abs(float(vec[0])))
        return Response(m, om, vec, floor)

    def hold(
        self, rig: AbstractRig, target: AbstractTarget, omega: float, settle: float | None = None
    ) -> Response:
        """Switch the controller on with ``target``, settle and measure (whole periods).

        Raises :class:`~bifid.cbc._measured.RigTripped` when the rig's safety gate fires,
        :class:`~bifid.errors.ConvergenceError` when a polar target's response does not go
        round the target's centre (the controller lost lock)."""
        period = 2.0 * math.pi / omega
        rig.set_controller(self.o.controller, target)
        run(rig, (self.o.settle_periods if settle is None else settle) * period)
        m = run(rig, self.o.measure_periods * period + 2.0 / rig.sample_rate)
        r = self.analyse(m, omega)
        if self.polar:
            self._check_lock(r)
        return r

    def _check_lock(self, r: Response) -> None:
        """Raise :class:`~bifid.errors.ConvergenceError` unless the response goes round
        the target's centre: its angle ``φ`` turns once per period (at least half as many
        turns as periods) and ``r(φ)`` is positive (a mean radius larger than the size of
        its harmonics). A response that wanders between orbits (the controller lost lock)
        gives a curve that does not enclose the centre, whose fit in ``φ`` is
        ill-conditioned: a target built from it would be absurd."""
        x1, x2 = r.m.signal(self.o.x1), r.m.signal(self.o.x2)
        d1, d2 = x1 - self.origin[0], x2 - self.origin[1]
        phi = np.unwrap(
            np.arctan2(
                self.inv[1, 0] * d1 + self.inv[1, 1] * d2,
                self.inv[0, 0] * d1 + self.inv[0, 1] * d2,
            )
        )
        turns = abs(float(phi[-1] - phi[0])) / (2.0 * math.pi) if phi.size else 0.0
        periods = r.omega * x1.shape[0] / r.m.sample_rate / (2.0 * math.pi)
        size = float(np.linalg.norm(r.shape))
        if not (np.all(np.isfinite(r.vector)) and size < r.a0 and turns >= 0.5 * periods):
            raise ConvergenceError(
                "the controller lost lock: the response does not go round the target's "
                f"centre ({turns:.1f} turns in {periods:.1f} periods, mean radius "
                f"{r.a0:.3g}, harmonics {size:.3g})"
            )

    # ------------------------------------------------------------------ frames
    def reframed(self, m: Measurement, omega: float) -> TargetFamily:
        """The family in the frame of the orbit recorded in ``m`` (polar targets): ``T``
        maps its first-harmonic ellipse in ``(x1, x2)`` to a circle of the radius of
        ``x1``'s first harmonic, ``o`` is its centre.

        Raises
        ------
        ConvergenceError
            If the orbit is a line in the ``(x1, x2)`` plane.
        """
        x1, x2 = m.signal(self.o.x1), m.signal(self.o.x2)
        n = whole_periods(x1.shape[0], omega, m.sample_rate)
        th = omega * np.arange(n) / m.sample_rate
        c = fourier_project(np.column_stack([x1[-n:], x2[-n:]]), th, 1)
        T = np.array([[c[1, 0], c[2, 0]], [c[1, 1], c[2, 1]]])
        A1 = math.hypot(c[1, 0], c[2, 0])
        if not (A1 > 0 and abs(np.linalg.det(T)) > 1e-9 * np.max(np.abs(T)) ** 2):
            raise ConvergenceError(
                f"the orbit is degenerate in the ({self.o.x1}, {self.o.x2}) plane (a line): "
                "choose two signals that are not in phase."
            )
        return TargetFamily(self.o, T / A1, (float(c[0, 0]), float(c[0, 1])))

    def convert(self, vec: np.ndarray, other: TargetFamily) -> np.ndarray:
        """The unknowns in ``other``'s frame of the target ``vec`` of this family (the same
        curve, up to the truncation of its Fourier series)."""
        if not self.polar:
            return np.asarray(vec, dtype=float).copy()
        phi = np.linspace(0.0, 2.0 * np.pi, 2048, endpoint=False)
        basis = uniform_basis(2048, self.o.n_harmonics)
        r = basis @ np.asarray(vec, dtype=float)
        xi1, xi2 = r * np.cos(phi), r * np.sin(phi)
        x1 = self.origin[0] + self.matrix[0, 0] * xi1 + self.matrix[0, 1] * xi2
        x2 = self.origin[1] + self.matrix[1, 0] * xi1 + self.matrix[1, 1] * xi2
        return other._polar_of(x1, x2)


def bootstrap(
    rig: AbstractRig,
    opts: PPCBCOptions,
    a_start: float,
    omega_guess: float,
    a_max: float | None = None,
) -> tuple[TargetFamily, np.ndarray, float]:
    """Start an oscillation from rest and measure the curve it draws in ``(x1, x2)``.

    An elliptic target self-excites the rig (the radial error acts as negative damping
    until ``ρ ≈ A*``): on the protocol's own plane and gains, or, with
    ``bootstrap_gains``, on ``(x1, ẋ1)`` with those gains (needed when the protocol's
    controller cannot start an oscillation, e.g. the heave-pitch controller of flutter).
    Targets above ``a_max`` are not tried (a rig's safety envelope).

    Returns
    -------
    family : TargetFamily
        In the frame of the measured orbit (polar targets).
    vector : ndarray
        The target's unknowns that describe the measured curve scaled to ``a_start``.
    omega : float
        The measured frequency.
    """
    derivative = opts.x2 == f"{opts.x1}_dot"
    if opts.bootstrap_gains is not None:
        kp, kd = opts.bootstrap_gains
        # its own plane and gains, validated without the protocol's output filter
        boot = replace(opts, target="elliptic", x2=f"{opts.x1}_dot", kp=kp, kd=kd, filter_hz=None)
        aspect0 = -omega_guess
    else:  # the protocol's own plane and gains (e.g. (u1, u2) of eq. 3.16)
        boot = replace(opts, target="elliptic")
        aspect0 = -omega_guess if derivative else 1.0
    fam = TargetFamily(boot)
    omega = omega_guess
    # the first ellipse is centred on the rest position (a derivative's centre is 0)
    centre = (opts.centre[0], 0.0 if boot.x2 != opts.x2 else opts.centre[1])
    r = None
    a_try = a_start
    # a target too small against the measurement noise can fail to lock (the angle of a
    # noisy (x1, ẋ1) is noise): try twice and four times the amplitude (up to a_max)
    tries = [a for a in (a_start, 2.0 * a_start, 4.0 * a_start) if a_max is None or a <= a_max]
    tries = tries or [a_start]
    k, rested = 0, False
    while k < len(tries):
        a_try, k = tries[k], k + 1
        vec = np.array([a_try, aspect0, centre[0], centre[1]])
        for _ in range(4):
            r = fam.hold(rig, fam.target(vec), omega)
            # learn the ellipse only from a response that is not mostly noise
            if (
                r.a0 > 1e-3 * a_try
                and np.all(np.isfinite(r.vector))
                and 1 / 3 < abs(r.vector[1] / aspect0) < 3
            ):
                omega = r.omega
                vec = np.concatenate([[a_try], r.vector[1:]])
        off = abs(float(np.mean(r.m.signal(boot.x1))) - centre[0])
        # the rig rests, or oscillates, away from the centre: about another equilibrium
        # (e.g. a buckled state of a structure, or the buckled pitch of a flutter
        # variant with a soft cubic stiffness), where the last orbit or a transient left
        # it. A rig that can be brought to rest at its rest position (as its safety gate
        # does) starts again from there, once
        if (r.a0 <= 0.1 * a_try or off > 0.5 * a_try) and not rested and rig.rest():
            rested, k = True, k - 1
            continue
        if r.a0 > 0.1 * a_try:
            break
        # else: outside the ellipse the radial error damps, so once more with an ellipse
        # round the centre that encloses the rig (inside, the radial error self-excites)
        big = 1.5 * off
        if k == len(tries) == 3 and off > a_try and (a_max is None or big <= a_max):
            tries.append(big)
    assert r is not None
    if not r.a0 > 0.1 * a_try:
        raise ConvergenceError(
            f"the bootstrap controller did not start an oscillation (amplitude {r.a0:.3g} "
            f"for targets of {a_start:.3g} to {a_try:.3g}); give bootstrap_gains with "
            "kp, kd > 0."
        )
    own = TargetFamily(replace(opts, target="elliptic"))
    e = own.analyse(r.m, omega)
    if opts.target == "elliptic":
        vec = e.vector.copy()
        vec[0] = a_start
        return TargetFamily(opts), vec, omega
    family = TargetFamily(opts).reframed(r.m, omega)
    pr = family.analyse(r.m, omega)
    vec = pr.vector / max(pr.a0, 1e-300) * a_start  # the measured shape at amplitude A*
    return family, vec, omega
