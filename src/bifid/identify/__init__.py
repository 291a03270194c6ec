"""Identification of models from bifurcation data (thesis ch. 4–6)."""

from bifid.identify._base import DiagramQuery, Estimator, IdentifiedModel, Orbit
from bifid.identify._intervals import Covariance, conformal_quantile, coverage_test
from bifid.identify._persistence import load
from bifid.identify._records import LCOData, as_lco_data
from bifid.identify.forced_kernel import ForcedKernelModel, GPRegressor, HyperBounds, band_coverage
from bifid.identify.hopf_hybrid import HopfHybridModel
from bifid.identify.mechanistic import LinearPEM, MechanisticModel

__all__ = [
    "Covariance",
    "DiagramQuery",
    "Estimator",
    "ForcedKernelModel",
    "GPRegressor",
    "HopfHybridModel",
    "HyperBounds",
    "IdentifiedModel",
    "LCOData",
    "LinearPEM",
    "MechanisticModel",
    "Orbit",
    "as_lco_data",
    "band_coverage",
    "conformal_quantile",
    "coverage_test",
    "load",
]
