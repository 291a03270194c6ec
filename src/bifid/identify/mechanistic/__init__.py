"""Mechanistic identification of a physical model with a Hopf bifurcation (thesis ch. 4).

The pipeline, one module per step:

1. :mod:`._linear` — the linear stage (§4.3.1): parameters of the linearisation from a free
   decay by prediction-error identification (:class:`LinearPEM`, :mod:`._linear_pem`);
2. :mod:`._near_hopf` — the normal-form stage (§4.2, §4.3.2): nonlinear parameters from the
   unstable LCOs near the Hopf point through the cubic normal form (:mod:`._normal_form`,
   its dependence on the nonlinear parameters: :mod:`._cubic`);
3. :mod:`._whole_diagram` — the whole-diagram stage (§4.3.3): every measured LCO matched by
   the model's collocation orbits (:mod:`._orbits`), exact implicit gradients;
4. :mod:`._predict` — the fitted model's diagram, orbits and amplitudes;

:class:`MechanisticModel` (:mod:`._model`) runs them as one estimator.
"""

from bifid.identify.mechanistic._branch import model_branch
from bifid.identify.mechanistic._cubic import (
    CubicCoefficient,
    cubic_coefficient_fn,
    hopf_point_regression,
    nonlinear_only,
    quadratic_cubic_structure,
)
from bifid.identify.mechanistic._discrete import expm_taylor, n_squarings_for, state_matrix
from bifid.identify.mechanistic._linear import release_index
from bifid.identify.mechanistic._linear_pem import LinearPEM
from bifid.identify.mechanistic._model import MechanisticModel
from bifid.identify.mechanistic._near_hopf import NearHopfResult, fit_near_hopf
from bifid.identify.mechanistic._normal_form import HopfNormalForm, hopf_normal_form
from bifid.identify.mechanistic._orbits import OrbitSet, max_abs_with_weights
from bifid.identify.mechanistic._whole_diagram import WholeDiagramResult, whole_diagram_update

__all__ = [
    "CubicCoefficient",
    "HopfNormalForm",
    "LinearPEM",
    "MechanisticModel",
    "NearHopfResult",
    "OrbitSet",
    "WholeDiagramResult",
    "cubic_coefficient_fn",
    "expm_taylor",
    "fit_near_hopf",
    "hopf_normal_form",
    "hopf_point_regression",
    "max_abs_with_weights",
    "model_branch",
    "n_squarings_for",
    "nonlinear_only",
    "quadratic_cubic_structure",
    "release_index",
    "state_matrix",
    "whole_diagram_update",
]
