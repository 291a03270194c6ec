"""Verify before report: the one way a special point of a branch is reported.

Every special point goes through the same three stages:

1. **detect** — a test function of the branch changes sign between two consecutive
   points; the two parameter values are the *bracket* of a candidate;
2. **locate** — the candidate is located accurately (Newton on a defining system, a
   secant search on the test function, ...);
3. **verify** — the located point is checked by an independent criterion with stated
   tolerances (a Hopf point: a complex pair on the imaginary axis with ``omega`` clearly
   positive; a fold: the parameter component of the tangent vanishes and the Jacobian
   has a null vector; ...).

:func:`confirm` runs stages 2 and 3 and returns either a
``SpecialPoint(status="converged", verification={...})`` — the checks and their values
recorded beside the point — or a :class:`~bifid.continuation.Candidate` with its bracket
and the reason it was not confirmed. A candidate is never put in the lists of located
points; :class:`Findings` keeps the two apart for a branch.

Adding a new kind
-----------------
1. Write a verifier ``(point, context) -> Verdict`` that recomputes what characterises
   the kind *independently of how the point was located* and returns one
   :class:`Check` per criterion, each with its tolerance (``Check.at_most`` /
   ``Check.at_least``), and register it once::

       @register_verifier("period_doubling")
       def _verify_pd(point, context):
           mu = context["multipliers"](point)          # recomputed at the point
           d = float(np.min(np.abs(mu + 1.0)))
           return Verdict((Check.at_most("multiplier_minus_one", d, 1e-6),))

2. Where the test function changes sign, call
   ``confirm("period_doubling", bracket, locate, context=..., index=i)`` with a locator
   ``() -> SpecialPoint`` (raising :class:`~bifid.errors.ConvergenceError`, or returning
   ``None``, when it cannot locate), and add the result to the branch's
   :class:`Findings`. A kind that is detected but cannot be located yet is recorded with
   :meth:`Findings.flag` (a candidate with its reason).

Besides the kind's own checks, :func:`confirm` checks for every kind that the located
parameter is finite and lies in the bracket (widened by ``slack``), that ``precision`` is
finite, and that no number in ``point.data`` is infinite. At a fold (the kinds in
:data:`EXTREMAL_KINDS`) the parameter is extremal along the branch, so it lies *beyond*
both bracketing points, by up to the distance between them: pass that distance as
``slack`` (the default for these kinds is a loose ``1e-3 max(1, |param|)``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bifid.continuation._branch import Candidate, SpecialPoint
from bifid.errors import BifidError, BifidInputError

#: Exceptions a locator may raise that mean "could not be located" (numerical trouble is
#: turned into a candidate with its reason, never into a traceback).
LOCATION_ERRORS = (BifidError, np.linalg.LinAlgError, ArithmeticError, ValueError)


@dataclass(frozen=True)
class Check:
    """One verification criterion: a measured ``value`` against a tolerance.

    Attributes
    ----------
    name : str
        What was checked (the key under which ``value`` is recorded).
    value : float
        The measured quantity (a residual, a distance, a real part, ...).
    tol : float
        The tolerance.
    passed : bool
    bound : {"max", "min", "finite"}
        ``max``: passes when ``|value| <= tol``; ``min``: passes when ``value >= tol``;
        ``finite``: passes when ``value`` is finite (``tol`` unused).
    """

    name: str
    value: float
    tol: float
    passed: bool
    bound: str = "max"

    @classmethod
    def at_most(cls, name: str, value: float, tol: float) -> Check:
        """Passes when ``|value| <= tol`` (a residual, a distance, a real part)."""
        v = float(value)
        return cls(name, v, float(tol), bool(math.isfinite(v) and abs(v) <= tol), "max")

    @classmethod
    def at_least(cls, name: str, value: float, tol: float) -> Check:
        """Passes when ``value >= tol`` (a frequency clearly positive, a rank margin)."""
        v = float(value)
        return cls(name, v, float(tol), bool(math.isfinite(v) and v >= tol), "min")

    @classmethod
    def finite(cls, name: str, value: float) -> Check:
        """Passes when ``value`` is finite (no overflow, no division by zero)."""
        v = float(value)
        return cls(name, v, math.inf, bool(math.isfinite(v)), "finite")

    def describe(self) -> str:
        if self.bound == "finite":
            return f"{self.name} = {self.value:.3g} (required finite)"
        rel = "<=" if self.bound == "max" else ">="
        shown = f"|{self.name}|" if self.bound == "max" else self.name
        return f"{shown} = {self.value:.3g} (required {rel} {self.tol:.3g})"


@dataclass(frozen=True)
class Verdict:
    """The checks of one located point; it is verified when every check passes."""

    checks: tuple[Check, ...] = ()

    @property
    def ok(self) -> bool:
        return all(c.passed for c in self.checks)

    @property
    def reason(self) -> str:
        """The failed checks, in words."""
        return "; ".join(c.describe() for c in self.checks if not c.passed)

    def __add__(self, other: Verdict) -> Verdict:
        return Verdict(self.checks + other.checks)

    def record(self) -> dict[str, Any]:
        """``{name: value, ..., "tolerance": {name: tol}}``: the point's ``verification``."""
        out: dict[str, Any] = {c.name: c.value for c in self.checks}
        out["tolerance"] = {c.name: c.tol for c in self.checks}
        return out


#: kinds at which the continuation parameter is extremal along the branch (folds)
EXTREMAL_KINDS = frozenset({"fold", "cycle_fold"})

Verifier = Callable[[SpecialPoint, Mapping[str, Any]], Verdict]
#: The verifier of each kind of special point (one per kind).
VERIFIERS: dict[str, Verifier] = {}


def register_verifier(kind: str) -> Callable[[Verifier], Verifier]:
    """Register the verifier of ``kind`` (decorator); a kind has exactly one."""

    def deco(fn: Verifier) -> Verifier:
        if kind in VERIFIERS and VERIFIERS[kind] is not fn:
            raise BifidInputError(f"a verifier for special points of kind {kind!r} exists.")
        VERIFIERS[kind] = fn
        return fn

    return deco


def _generic_checks(point: SpecialPoint, bracket: tuple[float, float], slack: float) -> Verdict:
    lo, hi = min(bracket), max(bracket)
    p = float(point.param)
    tol = slack + 1e-9 * max(1.0, abs(lo), abs(hi))
    outside = max(lo - p, p - hi, 0.0) if math.isfinite(p) else math.inf
    checks = [Check.at_most("outside_bracket", outside, tol)]
    if not math.isfinite(float(point.precision)):
        checks.append(Check.finite("precision", float(point.precision)))
    for k, v in point.data.items():
        if isinstance(v, (float, np.floating)) and math.isinf(float(v)):
            checks.append(Check.finite(k, float(v)))
    return Verdict(tuple(checks))


def confirm(
    kind: str,
    bracket: tuple[float, float],
    locate: Callable[[], SpecialPoint | None],
    *,
    context: Mapping[str, Any] | None = None,
    index: int = 0,
    branch: int = 0,
    slack: float | None = None,
) -> SpecialPoint | Candidate:
    """Locate and verify a candidate special point.

    Parameters
    ----------
    kind : str
        Kind of the point; must have a registered verifier (:data:`VERIFIERS`).
    bracket : (float, float)
        Parameter values of the two branch points between which a test function changed.
    locate : callable ``() -> SpecialPoint or None``
        Locates the point; may raise (:data:`LOCATION_ERRORS`) or return None.
    context : mapping, optional
        What the verifier needs to recompute its criterion (the field, the parameter
        vector, a multiplier routine, ...).
    index : int
        Index of the branch point just before the bracket.
    branch : int
        Index of the branch in its diagram (recorded on a candidate).
    slack : float, optional
        How far beyond the bracket the located parameter may lie (default: the width of
        the bracket; for a fold, :data:`EXTREMAL_KINDS`, ``1e-3 max(1, |param|)`` — pass
        the distance between the two points, the most the arc can overshoot them).

    Returns
    -------
    SpecialPoint or Candidate
        The verified point (``status="converged"``, ``verification`` filled in,
        ``index`` and ``bracket`` set), or a candidate with the reason.
    """
    verifier = VERIFIERS.get(kind)
    if verifier is None:
        raise BifidInputError(f"no verifier is registered for special points of kind {kind!r}.")
    bracket = (float(bracket[0]), float(bracket[1]))
    if slack is None:
        slack = abs(bracket[1] - bracket[0])
        if kind in EXTREMAL_KINDS:
            slack = max(slack, 1e-3 * max(1.0, abs(bracket[0]), abs(bracket[1])))
    try:
        point = locate()
    except LOCATION_ERRORS as exc:
        return Candidate(kind, bracket, f"could not be located: {_one_line(exc)}", branch)
    if point is None:
        return Candidate(kind, bracket, "could not be located", branch)
    try:
        verdict = _generic_checks(point, bracket, slack) + verifier(point, context or {})
    except LOCATION_ERRORS as exc:
        return Candidate(kind, bracket, f"could not be verified: {_one_line(exc)}", branch)
    if not verdict.ok:
        return Candidate(
            kind,
            bracket,
            f"located at {point.param:.10g} but not verified: {verdict.reason}",
            branch,
        )
    point.status = "converged"
    point.index = int(index)
    point.bracket = bracket
    point.verification = {**point.verification, **verdict.record()}
    return point


def _same_point(a: SpecialPoint, b: SpecialPoint) -> bool:
    if a.kind != b.kind or abs(a.param - b.param) > 1e-9 * max(1.0, abs(a.param)):
        return False
    sa, sb = np.ravel(a.solution), np.ravel(b.solution)
    return sa.shape == sb.shape and bool(
        np.max(np.abs(sa - sb), initial=0.0) <= 1e-7 * (1.0 + np.max(np.abs(sa), initial=0.0))
    )


def _neighbours(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Two brackets of a branch that share an end point or overlap."""
    tol = 1e-12 * max(1.0, *map(abs, (*a, *b)))
    return min(a) <= max(b) + tol and min(b) <= max(a) + tol


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


@dataclass
class Findings:
    """The special points and candidates of one branch, kept apart."""

    points: list[SpecialPoint] = field(default_factory=list)
    candidates: list[Candidate] = field(default_factory=list)
    branch: int = 0

    def add(self, result: SpecialPoint | Candidate) -> SpecialPoint | Candidate:
        """Add the outcome of :func:`confirm` to the right list.

        A point located a second time from another bracket becomes a candidate (its own
        crossing was not located), except a fold (:data:`EXTREMAL_KINDS`) seen again from a
        neighbouring bracket: at a fold that lies on a point of the branch, the tangent's
        parameter component is zero to rounding there and may change sign in both
        intervals that share the point — one fold, reported once (the first result is
        returned)."""
        if isinstance(result, SpecialPoint) and not (
            result.status == "converged" and result.verification
        ):
            raise BifidInputError(  # only confirm() makes a located point
                f"a {result.kind} point must be verified by confirm() before it is reported."
            )
        if isinstance(result, SpecialPoint):
            twin = next((q for q in self.points if _same_point(q, result)), None)
            if twin is None:
                self.points.append(result)
                return result
            if result.kind in EXTREMAL_KINDS and _neighbours(twin.bracket, result.bracket):
                return twin
            result = Candidate(
                result.kind,
                result.bracket,
                f"Newton converged to the point already located at {twin.param:.10g}",
                self.branch,
            )
        self.candidates.append(result)
        return result

    def flag(self, kind: str, bracket: tuple[float, float], reason: str) -> None:
        """Record a detected point that is not located (a candidate with its reason)."""
        self.candidates.append(
            Candidate(kind, (float(bracket[0]), float(bracket[1])), reason, self.branch)
        )

    def confirm(
        self,
        kind: str,
        bracket: tuple[float, float],
        locate: Callable[[], SpecialPoint | None],
        **kw: Any,
    ) -> SpecialPoint | Candidate:
        """:func:`confirm` on this branch, the outcome added; returns it."""
        return self.add(confirm(kind, bracket, locate, branch=self.branch, **kw))

    def sorted_points(self) -> list[SpecialPoint]:
        """Located points in branch order."""
        return sorted(self.points, key=lambda sp: (sp.index, sp.param))
