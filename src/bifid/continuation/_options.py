"""Continuation options: the numbers that steer a predictor–corrector run."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Literal

from bifid.errors import BifidInputError

#: default of :attr:`ContinuationOptions.rescale`
RESCALE_DEFAULT: bool | Literal["auto"] = "auto"


@dataclass(frozen=True)
class ContinuationOptions:
    """Numbers that steer a pseudo-arclength continuation; checked when built.

    Parameters
    ----------
    ds : float
        Initial arclength step (in the weighted norm of the problem).
    ds_min, ds_max : float
        Bounds of the adaptive step.
    dp_max : float
        Largest change of the parameter in one step (default: no limit). With it a
        branch can take long steps where it changes mostly in its states (an orbit
        branch that is nearly vertical) and still resolve the parameter range.
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
    rescale : bool or "auto"
        Periodic orbits: collocate in a rescaled time whose mesh density follows the
        orbit's arclength (``bifid.continuation._density``), so that orbits with fast
        phases (relaxation oscillations) are resolved on far fewer points. True: every
        mesh is rescaled; False: the uniform mesh in time throughout; "auto" (default):
        uniform meshes while they are cheap, a rescaled one once the uniform mesh would
        have to grow beyond ``_mesh.AUTO_RESCALE_UNKNOWNS`` unknowns (or beyond
        ``max_mesh``), so smooth branches cost what they cost on uniform meshes.
    """

    ds: float = 0.01
    ds_min: float = 1e-7
    ds_max: float = 0.1
    dp_max: float = math.inf
    max_steps: int = 400
    p_min: float = -math.inf
    p_max: float = math.inf
    direction: int = 1
    newton_tol: float = 1e-10
    newton_max_iter: int = 10
    growth: float = 1.5
    detect_folds: bool = True
    detect_bifurcations: bool = True
    rescale: bool | Literal["auto"] = RESCALE_DEFAULT

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
        if not self.dp_max > 0:
            raise BifidInputError(f"dp_max must be positive, got {self.dp_max!r}.")
        if self.direction not in (1, -1):
            raise BifidInputError(f"direction must be +1 or -1, got {self.direction!r}.")
        if self.max_steps < 1 or self.newton_max_iter < 1:
            raise BifidInputError("max_steps and newton_max_iter must be positive integers.")
        if not (isinstance(self.rescale, bool) or self.rescale == "auto"):
            raise BifidInputError(f"rescale must be True, False or 'auto'; got {self.rescale!r}.")
        if not self.growth >= 1.0:
            raise BifidInputError(f"growth must be >= 1, got {self.growth}.")

    def with_(self, **changes: Any) -> ContinuationOptions:
        """A copy with some fields changed (checked again)."""
        return replace(self, **changes)
