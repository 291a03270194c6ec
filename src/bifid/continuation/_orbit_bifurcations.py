"""Bifurcations of periodic orbits on their own test functions, verified before reported.

Each kind has a test function that vanishes only at the bifurcation, a locator, and a
verifier registered with :mod:`bifid.continuation._verify` (so a point that cannot be
located and verified is a :class:`~bifid.continuation.Candidate`, never a located point):

================  =====================================  ====================================
kind              detected where                         verified by
================  =====================================  ====================================
``cycle_fold``    the parameter component of the         the fold criteria of ``_folds``
                  tangent changes sign (the driver       (on the curve, ``t_lambda = 0``, a
                  locates it)                            null vector, full rank) and a
                                                         non-trivial multiplier at +1
``branch_point``  a real non-trivial multiplier crosses  a non-trivial multiplier at +1
                  +1 where the tangent does not turn,    and ``|t_lambda|`` clearly
                  or ``det [G_y; t^T]`` changes sign;    non-zero (not a fold)
                  located by a secant on ``log|mu|`` or
                  by bisection on the sign
``period_doubling``  a real non-trivial multiplier       a real multiplier at -1 (to
                  crosses -1; located by a secant on     :data:`MULTIPLIER_TOL`) and at
                  ``log|mu|``                            least two non-trivial multipliers
``torus``         a complex pair crosses the unit        a complex pair on the unit circle,
                  circle; located by a secant on         away from ±1, and at least two
                  ``log|mu|``                            non-trivial multipliers
================  =====================================  ====================================

The non-trivial multipliers are those of ``_floquet`` with the trivial one deflated
exactly, so a cycle fold (a second multiplier at +1) is never confused with it. A
planar autonomous system has one non-trivial multiplier, ``exp(int div f dt) > 0``:
no period doubling or torus is looked for there. A branch point is not a fold: its
tangent does not turn, and the fold verifier's rank check rejects a fold located at one.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from bifid.continuation._branch import SpecialPoint
from bifid.continuation._density import integration_samples, time_mean, uniform_samples
from bifid.continuation._floquet import Floquet, autonomous_rhs, collocation_floquet, floquet
from bifid.continuation._folds import verify_fold
from bifid.continuation._mesh import (
    AdaptiveRun,
    Arc,
    Stage,
    bracket_slack,
    residual_check,
    secant_zero,
)
from bifid.continuation._palc import NewtonCorrector
from bifid.continuation._verify import Check, Findings, Verdict, register_verifier
from bifid.systems import System

#: largest distance of the critical multiplier from +1 / -1 / the unit circle at a
#: verified orbit bifurcation
MULTIPLIER_TOL = 1e-6
#: a cycle fold or branch point may show its multiplier at +1 less sharply (a Jordan
#: block splits it by the square root of the location error)
FOLD_MULTIPLIER_TOL = 1e-4
#: a multiplier is complex when its argument exceeds this (radians)
COMPLEX_ARG = 1e-6
#: largest ``sigma_min / sigma_max`` of ``G_y`` at a verified branch point (not of orbits)
BRANCH_RANK_TOL = 1e-7
#: smallest ``|t_lambda|`` at a verified branch point of cycles (a fold has 0)
BRANCH_TANGENT_MIN = 1e-3
#: where the multipliers of autonomous orbits come from, for detection and verification
#: alike: ``"integrated"`` (the variational equation, error-controlled, :func:`floquet`)
#: or ``"collocation"`` (the eigenvalues of the collocation operator,
#: :func:`collocation_floquet`: nothing to compile, for smooth orbits resolved on their mesh)
STABILITY_SOURCES = ("integrated", "collocation")


def collocation_operator(stage: Stage, y: np.ndarray) -> np.ndarray:
    """The mesh block ``D_M (x) I - (T / 2 pi) blockdiag(f_x(v_k))`` of the collocation
    Jacobian at the orbit ``y = [v, T, lambda]`` (:func:`collocation_floquet`)."""
    Mn = len(y) - 2
    _, Gy = NewtonCorrector(stage.problem).evaluate(np.asarray(y), stage.args(y, None))
    return Gy[:Mn, :Mn]


@dataclass
class BracketContext:
    """What locating a special point between two points of an orbit run needs.

    Autonomous orbits have unknowns ``[v (M*n), T, lambda]``; forced responses
    (``forced_rhs`` given) ``[v (M*n), lambda]`` with the period ``2 pi / Omega``, all
    their multipliers non-trivial.
    """

    system: System
    param: str
    p: Any
    idx: int
    run: AdaptiveRun
    stage_of: Callable[[int], Stage]
    floquet: Floquet
    zero: np.ndarray
    forced_rhs: Callable | None = None
    stability: str = "integrated"

    @property
    def n(self) -> int:
        return self.system.n_states

    @property
    def autonomous(self) -> bool:
        return self.forced_rhs is None

    @property
    def n_nontrivial(self) -> int:
        """Non-trivial multipliers of an orbit (the trivial one of autonomous orbits
        excluded)."""
        return self.n - 1 if self.autonomous else self.n

    def lam(self, y: np.ndarray, M: int) -> float:
        """The continuation parameter of ``y`` (mesh ``M``)."""
        return float(y[M * self.n + (1 if self.autonomous else 0)])

    def params_of(self, y: np.ndarray, M: int) -> tuple[np.ndarray, float]:
        """The parameter vector and the period of ``y`` (mesh ``M``)."""
        ps = np.asarray(self.p, dtype=float).copy()
        ps[self.idx] = self.lam(y, M)
        if self.autonomous:
            return ps, float(y[M * self.n])
        return ps, 2.0 * np.pi / float(ps[self.system.index("Omega")])

    def multipliers(self, y: np.ndarray, M: int) -> tuple[np.ndarray, np.ndarray]:
        """Non-trivial multipliers and their log-moduli of the orbit ``y`` (mesh ``M``)."""
        n = self.n
        if self.autonomous and self.stability == "collocation":
            fl = collocation_floquet([collocation_operator(self.stage_of(M), y)], n)
            if not fl.ok[0]:
                raise ArithmeticError("the orbit's collocation multipliers are not resolved")
            return fl.nontrivial(0)
        ps, period = self.params_of(y, M)
        rhs = autonomous_rhs(self.system.field) if self.autonomous else self.forced_rhs
        fl = floquet(
            rhs,
            integration_samples(np.asarray(y[: M * n]).reshape(M, n), M)[None],
            np.array([period]),
            ps[None, :],
            autonomous=self.autonomous,
        )
        if not fl.ok[0]:
            raise ArithmeticError("the Floquet multipliers of the orbit could not be computed")
        return fl.nontrivial(0)

    def step(self, i: int) -> float:
        """Largest change of any unknown between points ``i`` and ``i + 1`` (on the finer
        mesh): the most a fold located between them can lie beyond them."""
        run, n = self.run, self.n
        return bracket_slack(run.ys[i], run.meshes[i], run.ys[i + 1], run.meshes[i + 1], n)

    def arc(self, i: int) -> Arc:
        """The arc between points ``i`` and ``i + 1`` on the finer of their meshes."""
        run = self.run
        M = max(run.meshes[i], run.meshes[i + 1])
        return Arc(
            self.stage_of(M), run.ys[i], run.meshes[i], run.ys[i + 1], run.meshes[i + 1], self.n
        )


def _point_data(ctx: BracketContext, y: np.ndarray, M: int) -> dict[str, Any]:
    n = ctx.n
    V = np.asarray(y[: M * n]).reshape(M, n)
    return {
        "period": ctx.params_of(y, M)[1],
        "amplitude": np.max(np.abs(V), axis=0),
        "amplitude_centred": np.max(np.abs(V - time_mean(V, M)), axis=0),
        "amplitude_states": list(ctx.system.states),
        "n_mesh": int(M),
    }


def _special(ctx, kind, i, y, M, prec) -> SpecialPoint:
    n = ctx.n
    run = ctx.run
    return SpecialPoint(
        kind=kind,
        param=ctx.lam(y, M),
        index=i,
        bracket=(ctx.lam(run.ys[i], run.meshes[i]), ctx.lam(run.ys[i + 1], run.meshes[i + 1])),
        # samples at the uniform times T k / M
        solution=np.concatenate(
            [uniform_samples(np.asarray(y[: M * n]).reshape(M, n), M).ravel(), y[M * n : M * n + 1]]
        ),
        precision=prec,
        data=_point_data(ctx, y, M),
    )


def _context(ctx: BracketContext, y: np.ndarray, M: int) -> dict[str, Any]:
    stage = ctx.stage_of(M)
    return {
        "problem": stage.problem,
        "args": stage.args(y, None),
        "weights": stage.weights,
        "y": y,
        "multipliers": lambda: ctx.multipliers(y, M),
        "n_nontrivial": ctx.n_nontrivial,
    }


# ------------------------------------------------------------------------ verifiers
@register_verifier("cycle_fold")
def verify_cycle_fold(point: SpecialPoint, context: Mapping[str, Any]) -> Verdict:
    """A fold of cycles: the fold criteria of :func:`verify_fold` on the collocation
    problem and a non-trivial multiplier at +1."""
    mults, _ = context["multipliers"]()
    d = float(np.min(np.abs(mults - 1.0))) if mults.size else math.inf
    return verify_fold(point, context) + Verdict(
        (Check.at_most("multiplier_minus_one", d, FOLD_MULTIPLIER_TOL),)
    )


@register_verifier("branch_point")
def verify_branch_point(point: SpecialPoint, context: Mapping[str, Any]) -> Verdict:
    """A branch point. Of periodic orbits (``context["multipliers"]``): on the curve, a
    non-trivial multiplier at +1 and a tangent that does not turn (``|t_lambda|`` clearly
    non-zero: not a fold). Of any other zero problem: on the curve and ``G_y``
    rank-deficient."""
    y = np.asarray(context["y"], dtype=float)
    _, Gy = NewtonCorrector(context["problem"]).evaluate(y, context["args"])
    if not np.all(np.isfinite(Gy)):
        return Verdict((Check.finite("jacobian", math.inf),))
    if "multipliers" not in context:
        s = np.linalg.svd(Gy, compute_uv=False)
        return Verdict(
            (
                residual_check(context),
                Check.at_most("rank_deficiency", float(s[-1] / s[0]), BRANCH_RANK_TOL),
            )
        )
    mults, _ = context["multipliers"]()
    d = float(np.min(np.abs(mults - 1.0))) if mults.size else math.inf
    w = np.asarray(context["weights"], dtype=float)
    t = np.linalg.svd(Gy)[2][-1]
    t = t / math.sqrt(float(t @ (w * t)))
    return Verdict(
        (
            residual_check(context),
            Check.at_most("multiplier_minus_one", d, FOLD_MULTIPLIER_TOL),
            Check.at_least("tangent_param", abs(float(t[-1])), BRANCH_TANGENT_MIN),
        )
    )


def _orbit_checks(context: Mapping[str, Any]) -> list[Check]:
    return [
        residual_check(context),
        Check.at_least("nontrivial_multipliers", float(context["n_nontrivial"]), 2.0),
    ]


@register_verifier("period_doubling")
def verify_period_doubling(point: SpecialPoint, context: Mapping[str, Any]) -> Verdict:
    """A period doubling: a real non-trivial multiplier at -1."""
    mults, _ = context["multipliers"]()
    real = mults[np.abs(np.angle(mults)) >= np.pi - COMPLEX_ARG]
    d = float(np.min(np.abs(real + 1.0))) if real.size else math.inf
    return Verdict(
        (*_orbit_checks(context), Check.at_most("multiplier_plus_one", d, MULTIPLIER_TOL))
    )


@register_verifier("torus")
def verify_torus(point: SpecialPoint, context: Mapping[str, Any]) -> Verdict:
    """A torus (Neimark–Sacker) bifurcation: a complex pair on the unit circle, away
    from ±1."""
    mults, logm = context["multipliers"]()
    ang = np.abs(np.angle(mults))
    cplx = (ang > COMPLEX_ARG) & (ang < np.pi - COMPLEX_ARG)
    if not np.any(cplx):
        return Verdict((*_orbit_checks(context), Check.at_least("complex_pair", 0.0, 1.0)))
    k = np.flatnonzero(cplx)[np.argmin(np.abs(logm[cplx]))]
    return Verdict(
        (
            *_orbit_checks(context),
            Check.at_most("modulus_minus_one", float(np.expm1(logm[k])), MULTIPLIER_TOL),
            Check.at_least("argument", float(ang[k]), 1e-3),
        )
    )


# ------------------------------------------------------------------------ detection
def _counts(mults: np.ndarray, logm: np.ndarray) -> tuple[int, int, int]:
    """Non-trivial multipliers outside the unit circle: (real negative, complex, real
    positive)."""
    ang = np.abs(np.angle(mults))
    out = logm > 0
    neg = out & (ang >= np.pi - COMPLEX_ARG)
    cplx = out & (ang > COMPLEX_ARG) & (ang < np.pi - COMPLEX_ARG)
    pos = out & (ang <= COMPLEX_ARG)
    return int(np.sum(neg)), int(np.sum(cplx)), int(np.sum(pos))


def _nearest(mults: np.ndarray, logm: np.ndarray, target: float) -> float:
    """``log|mu|`` of the multiplier nearest ``target`` (+1 or -1) in its half plane: a
    test function that stays continuous where a complex pair collides on the real axis
    and one of the two real multipliers then moves through ``target``."""
    half = mults.real * target > 0
    if not np.any(half):
        return math.nan
    k = int(np.argmin(np.abs(mults[half] - target)))
    return float(logm[half][k])


def _bp_test(mults: np.ndarray, logm: np.ndarray) -> float:
    return _nearest(mults, logm, 1.0)


def _pd_test(mults: np.ndarray, logm: np.ndarray) -> float:
    return _nearest(mults, logm, -1.0)


def _torus_test(mults: np.ndarray, logm: np.ndarray) -> float:
    ang = np.abs(np.angle(mults))
    cplx = (ang > COMPLEX_ARG) & (ang < np.pi - COMPLEX_ARG)
    return float(logm[cplx][np.argmin(np.abs(logm[cplx]))]) if np.any(cplx) else math.nan


def _secant(ctx: BracketContext, i: int, test: Callable) -> tuple[np.ndarray, int, float] | None:
    """Zero of ``test(multipliers, log_moduli)`` on the arc from point ``i``."""
    arc = ctx.arc(i)

    def g(s):
        y = arc.point(s)
        return (math.nan, None) if y is None else (test(*ctx.multipliers(y, arc.M)), y)

    found = secant_zero(g, 0.0, arc.length)
    return None if found is None else (found[0], arc.M, found[1])


def _bisect_branch_point(ctx: BracketContext, i: int) -> tuple[np.ndarray, int, float] | None:
    """Bisection on the sign of ``det [G_y; t^T]`` on the arc from point ``i``."""
    arc = ctx.arc(i)
    w = arc.stage.weights

    def sign(s):
        y = arc.point(s)
        if y is None:
            return math.nan, None
        return arc.corrector.tangent(y, arc.d, w, arc.args)[1], y

    a, b = 0.0, arc.length
    (sa, _), (sb, yb) = sign(a), sign(b)
    if not sa * sb < 0:
        return None
    for _ in range(60):
        m = 0.5 * (a + b)
        sm, ym = sign(m)
        if not math.isfinite(sm):
            return None
        if sm * sa < 0:
            b, yb = m, ym
        else:
            a, sa = m, sm
        if b - a < 1e-13 * max(1.0, arc.length):
            break
    return yb, arc.M, b - a


def _report(
    findings: Findings,
    ctx: BracketContext,
    kind: str,
    bracket: tuple[float, float],
    i: int,
    found: tuple[np.ndarray, int, float] | None,
    why: str,
    slack: float | None = None,
) -> None:
    """Locate and verify the point of ``kind`` detected between points ``i`` and ``i + 1``
    from ``found = (y, M, precision)``; flag it with ``why`` when it could not be located
    (``found`` None)."""
    if found is None:
        findings.flag(kind, bracket, why)
        return
    y, M, prec = found
    findings.confirm(
        kind,
        bracket,
        lambda: _special(ctx, kind, i, y, M, prec),
        context=_context(ctx, y, M),
        index=i,
        slack=slack,
    )


def find_orbit_special_points(findings: Findings, ctx: BracketContext, params: np.ndarray) -> None:
    """Detect, locate and verify cycle folds, branch points, period doublings and torus
    points along an orbit run; the outcomes go to ``findings``. For forced responses the
    folds are left to the caller (``_forced``: verified as folds of the response)."""
    run = ctx.run
    for i, kind, y_e, prec, M in run.events:
        bracket = (params[i], params[i + 1])
        if kind == "fold" and ctx.autonomous:
            found = None if y_e is None else (y_e, M, prec)
            why = "the parameter turned between these points but the fold could not be located"
            _report(findings, ctx, "cycle_fold", bracket, i, found, why, slack=ctx.step(i))
        elif kind == "branch_point":
            found = _bisect_branch_point(ctx, i)
            why = "det [G_y; t^T] changed sign but the branch point could not be located"
            _report(findings, ctx, "branch_point", bracket, i, found, why)
    fl = ctx.floquet
    valid = fl.ok & ~ctx.zero
    turned = {i for i, kind, *_ in run.events}
    for i in range(len(params) - 1):
        if not (valid[i] and valid[i + 1]):
            continue
        a, b = _counts(*fl.nontrivial(i)), _counts(*fl.nontrivial(i + 1))
        tests = [("branch_point", a[2] != b[2] and i not in turned, _bp_test)]
        if ctx.n_nontrivial >= 2:  # a planar orbit's one is real and positive
            tests += [
                ("period_doubling", a[0] != b[0], _pd_test),
                ("torus", a[1] != b[1], _torus_test),
            ]
        for kind, changed, test in tests:
            if not changed:
                continue
            why = "a multiplier crossed the unit circle here but the crossing could not be located"
            _report(findings, ctx, kind, (params[i], params[i + 1]), i, _secant(ctx, i, test), why)
