"""Continuation options and result types (Branch, SpecialPoint)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from bifid.errors import BifidInputError


@dataclass(frozen=True)
class ContinuationOptions:
    """Numbers that steer a pseudo-arclength continuation; checked when built.

    Parameters
    ----------
    ds : float
        Initial arclength step (in the weighted norm of the problem).
    ds_min, ds_max : float
        Bounds of the adaptive step.
    max_steps : int
        Maximum number of accepted points.
    p_min, p_max : float
        Bounds of the continuation parameter; the branch ends exactly on a bound.
    direction : {+1, -1}
        Initial direction of the parameter (where the start does not fix it).
    newton_tol : float
        Convergence tolerance on the Newton update (max-norm).
    newton_max_iter : int
        Newton iterations before a step is rejected and the step halved.
    growth : float
        Step multiplier after an easy corrector (<= 3 iterations).
    detect_folds, detect_bifurcations : bool
        Locate folds (limit points) and flag branch points / bifurcations.
    """

    ds: float = 0.01
    ds_min: float = 1e-7
    ds_max: float = 0.1
    max_steps: int = 400
    p_min: float = -math.inf
    p_max: float = math.inf
    direction: int = 1
    newton_tol: float = 1e-10
    newton_max_iter: int = 10
    growth: float = 1.5
    detect_folds: bool = True
    detect_bifurcations: bool = True

    def __post_init__(self) -> None:
        if not (0 < self.ds_min <= self.ds <= self.ds_max):
            raise BifidInputError(
                "Steps must satisfy 0 < ds_min <= ds <= ds_max; you passed "
                f"ds_min={self.ds_min}, ds={self.ds}, ds_max={self.ds_max}."
            )
        if not self.p_min < self.p_max or math.isnan(self.p_min) or math.isnan(self.p_max):
            raise BifidInputError(
                f"Parameter bounds must be ordered, p_min < p_max; got {self.p_min}, {self.p_max}."
            )
        if self.direction not in (1, -1):
            raise BifidInputError(f"direction must be +1 or -1, got {self.direction!r}.")
        if self.max_steps < 1 or self.newton_max_iter < 1:
            raise BifidInputError("max_steps and newton_max_iter must be positive integers.")
        if not self.growth >= 1.0:
            raise BifidInputError(f"growth must be >= 1, got {self.growth}.")

    def with_(self, **changes: Any) -> ContinuationOptions:
        """A copy with some fields changed (checked again)."""
        return replace(self, **changes)


SpecialKind = Literal[
    "hopf", "fold", "cycle_fold", "period_doubling", "torus", "branch_point", "endpoint"
]


@dataclass
class SpecialPoint:
    """A special point found on a branch.

    Attributes
    ----------
    kind : str
        "hopf", "fold", "cycle_fold", "period_doubling", "torus", "branch_point".
    param : float
        Parameter value at the point.
    index : int
        Index of the branch point just before it.
    interval : (float, float)
        Parameter values of the two branch points that bracket it;
        ``min(interval) <= param <= max(interval)`` up to ``precision``.
    solution : ndarray
        The unknown vector at the point (state / mesh values, without the parameter).
    precision : float
        Estimated accuracy of ``param``.
    status : {"converged", "guess"}
        "converged" when located by an accurate solve, "guess" when only bracketed.
    data : dict
        Extra numbers (``omega``, ``lyapunov``, ``criticality``, ``period``, ``amplitude``...).
    """

    kind: str
    param: float
    index: int
    interval: tuple[float, float]
    solution: np.ndarray
    precision: float = float("nan")
    status: Literal["converged", "guess"] = "guess"
    data: dict[str, Any] = field(default_factory=dict)


@dataclass
class Branch:
    """A continued branch of solutions with its special points.

    Attributes
    ----------
    kind : {"equilibrium", "periodic", "forced", "backbone"}
    system : str
        Registry name of the system.
    param : str
        Name of the continuation parameter.
    params : ndarray of shape (n_points,)
        Parameter value at each point.
    solutions : ndarray of shape (n_points, n_unknowns)
        Unknowns at each point (for orbits: mesh values of shape ``(M, n_states)``
        flattened, then the period when it is unknown).
    stable : ndarray of bool, shape (n_points,)
    special_points : list of SpecialPoint
    data : dict of ndarray
        Per-point quantities, e.g. ``period``, ``amplitude`` (n_points, n_states),
        ``floquet`` (n_points, n_states), ``eigenvalues``, ``phase``, ``omega``, ``forcing``.
    p : ndarray
        Parameter vector of the system (the continuation parameter is overwritten per point).
    status : {"completed", "bounds", "max_steps", "failed"}
        Why the branch ended; "failed" means the last step could not converge.
    message : str
    options : ContinuationOptions
    meta : dict
        How the branch was computed (mesh size, observed state, ...).
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
    options: ContinuationOptions
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        """True unless the continuation stopped on a failure."""
        return self.status != "failed"

    def special(self, kind: str) -> list[SpecialPoint]:
        """Special points of one kind."""
        return [sp for sp in self.special_points if sp.kind == kind]

    def __len__(self) -> int:
        return int(self.params.shape[0])
