"""Result types of continuation and of everything that answers the same questions:
:class:`SpecialPoint`, :class:`Candidate`, :class:`Branch`.

A branch is a sequence of verified points with per-point quantities in ``data``, the
checks that verified each point in ``verification``, optional uncertainty bands in
``intervals``, its located special points, and why it ended (``status``, one of
:data:`END_REASONS`). Branches are gathered into a :class:`~bifid.continuation.Diagram`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from bifid.continuation._options import ContinuationOptions

#: Why a branch ended. The first four are natural ends (the branch is complete); the
#: others mean it was cut short and make the result incomplete.
END_REASONS = (
    "range",  # reached a bound of the requested range
    "hopf",  # an orbit branch shrank into an equilibrium at a Hopf point
    "homoclinic",  # the period grew without bound
    "completed",  # a stopping condition of the driver was met (e.g. a closed curve)
    "steps",  # the step budget ran out
    "failed",  # a step could not be corrected even with the smallest step
    "unresolved",  # the mesh limit was reached with an unresolved spectrum
    "interrupted",  # stopped by the user
)
INCOMPLETE = frozenset({"steps", "failed", "unresolved", "interrupted"})

SpecialKind = Literal[
    "hopf",
    "fold",
    "cycle_fold",
    "period_doubling",
    "torus",
    "branch_point",
    "peak",
]


@dataclass
class SpecialPoint:
    """A located and verified special point of a branch.

    Attributes
    ----------
    kind : str
        One of ``hopf``, ``fold``, ``cycle_fold``, ``period_doubling``, ``torus``,
        ``branch_point``, ``peak``.
    param : float
        Parameter value at the point.
    index : int
        Index of the branch point just before it.
    bracket : (float, float)
        Parameter values of the two branch points that bracket it;
        ``min(bracket) <= param <= max(bracket)`` up to ``precision``.
    solution : ndarray
        The unknown vector at the point (state / mesh values, without the parameter).
    precision : float
        Estimated accuracy of ``param``.
    status : {"converged", "guess"}
        ``converged`` when located by an accurate solve and verified. Only converged
        points are reported as located; others belong in ``Diagram.candidates``.
    data : dict
        Extra numbers (``omega``, ``lyapunov``, ``criticality``, ``period``,
        ``amplitude``...).
    verification : dict
        What was checked at the point and the residual of each check (e.g.
        ``{"residual": 1e-13, "real_part": 2e-14}``).
    intervals : dict of (float, float)
        Confidence intervals of a predicted point at the diagram's ``level``, keyed by
        the quantity (``param``, ``amplitude``, ...).
    """

    kind: str
    param: float
    index: int
    bracket: tuple[float, float]
    solution: np.ndarray
    precision: float = float("nan")
    status: Literal["converged", "guess"] = "guess"
    data: dict[str, Any] = field(default_factory=dict)
    verification: dict[str, Any] = field(default_factory=dict)
    intervals: dict[str, tuple[float, float]] = field(default_factory=dict)


@dataclass
class Candidate:
    """A possible special point that could not be located and verified.

    Never reported as a located point: it is listed apart, with the bracket where a test
    function changed and why it was not confirmed.
    """

    kind: str
    bracket: tuple[float, float]
    reason: str
    branch: int = 0


@dataclass
class Branch:
    """A continued (or measured, or predicted) branch with its special points.

    Attributes
    ----------
    kind : {"equilibrium", "periodic", "forced", "backbone", "measured"}
    system : str
        Name of the system (or model) the branch belongs to.
    param : str
        Name of the continuation parameter.
    params : ndarray of shape (n_points,)
        Parameter value at each point.
    solutions : ndarray of shape (n_points, n_unknowns)
        Unknowns at each point (for orbits: mesh values of shape ``(M, n_states)``
        flattened, then the period); may have zero columns for measured or predicted
        branches.
    stable : ndarray of bool, shape (n_points,)
    special_points : list of SpecialPoint
    data : dict of ndarray
        Per-point quantities, e.g. ``period``, ``amplitude`` (n_points, n_signals) =
        max_t|x_s(t)|, ``floquet`` (n_points, n_states), ``phase``, ``omega``, ``forcing``.
    p : ndarray
        Parameter vector of the system (the continuation parameter is overwritten per point).
    status : str
        Why the branch ended, one of :data:`END_REASONS`.
    message : str
        The reason in words.
    options : ContinuationOptions, optional
    meta : dict
        How the branch was computed (mesh size, observed state, ...).
    signals : tuple of str
        Names of the columns of ``data["amplitude"]`` when it is two-dimensional.
    verification : dict of ndarray
        Per-point checks (e.g. ``residual``, ``spectral_tail``), each of shape (n_points,).
    intervals : dict of (ndarray, ndarray)
        Lower and upper bands of per-point quantities at the diagram's ``level``, keyed
        like ``data`` (e.g. ``amplitude``).
    candidates : list of Candidate
        Possible special points on this branch that could not be located and verified.
    """

    kind: str
    system: str
    param: str
    params: np.ndarray
    solutions: np.ndarray
    stable: np.ndarray
    special_points: list[SpecialPoint]
    data: dict[str, np.ndarray]
    p: np.ndarray
    status: str
    message: str
    options: ContinuationOptions | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    signals: tuple[str, ...] = ()
    verification: dict[str, np.ndarray] = field(default_factory=dict)
    intervals: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    candidates: list[Candidate] = field(default_factory=list)

    @property
    def complete(self) -> bool:
        """False when the branch was cut short (step budget, failure, unresolved mesh)."""
        return self.status not in INCOMPLETE

    def special(self, kind: str) -> list[SpecialPoint]:
        """Located special points of one kind."""
        return [sp for sp in self.special_points if sp.kind == kind]

    def __len__(self) -> int:
        return int(np.asarray(self.params).shape[0])
