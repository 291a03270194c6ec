"""Numerical continuation: equilibria, periodic orbits, forced responses.

Problem / algorithm / options are kept apart: a :class:`~bifid.systems.System` is the
problem, the drivers below pick the zero problem (equilibria, Fourier collocation of
orbits or forced responses), :func:`palc` is the algorithm, and
:class:`ContinuationOptions` holds the numbers. Every driver returns a :class:`Branch`
carrying its special points.
"""

from bifid.continuation._backbone import backbone
from bifid.continuation._bifurcation import bifurcation_diagram, continue_from_hopf
from bifid.continuation._branch import END_REASONS, Branch, Candidate, SpecialPoint
from bifid.continuation._collocation import (
    hopf_orbits,
    orbit_problem,
    periodic_orbits,
    resample_orbit,
)
from bifid.continuation._diagram import Diagram
from bifid.continuation._equilibria import equilibria, equilibrium_problem
from bifid.continuation._floquet import autonomous_rhs, floquet, floquet_multipliers, monodromy
from bifid.continuation._forced import forced_problem, frc, scurve
from bifid.continuation._fourier import fourier_differentiation_matrix, fourier_grid
from bifid.continuation._hopf import (
    critical_pair,
    first_lyapunov_coefficient,
    locate_hopf,
    multilinear_forms,
)
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._palc import (
    AbstractCorrector,
    Continuation,
    ContinuationState,
    Correction,
    NewtonCorrector,
    PalcResult,
    Step,
    ZeroProblem,
    correct,
    palc,
    tangent_at,
)
from bifid.continuation._verify import (
    VERIFIERS,
    Check,
    Findings,
    Verdict,
    confirm,
    register_verifier,
)

__all__ = [
    "END_REASONS",
    "VERIFIERS",
    "AbstractCorrector",
    "Branch",
    "Candidate",
    "Check",
    "Continuation",
    "ContinuationOptions",
    "ContinuationState",
    "Correction",
    "Diagram",
    "Findings",
    "NewtonCorrector",
    "PalcResult",
    "SpecialPoint",
    "Step",
    "Verdict",
    "ZeroProblem",
    "autonomous_rhs",
    "backbone",
    "bifurcation_diagram",
    "confirm",
    "continue_from_hopf",
    "correct",
    "critical_pair",
    "equilibria",
    "equilibrium_problem",
    "first_lyapunov_coefficient",
    "floquet",
    "floquet_multipliers",
    "forced_problem",
    "fourier_differentiation_matrix",
    "fourier_grid",
    "frc",
    "hopf_orbits",
    "locate_hopf",
    "monodromy",
    "multilinear_forms",
    "orbit_problem",
    "palc",
    "periodic_orbits",
    "register_verifier",
    "resample_orbit",
    "scurve",
    "tangent_at",
]
