"""Validation of the hyperparameters of :class:`~bifid.identify.HopfHybridModel`."""

from __future__ import annotations

import math
from typing import Any

from bifid.errors import BifidInputError

__all__ = ["check_hyperparameters"]


def check_hyperparameters(model: Any) -> None:
    """Raise :class:`~bifid.errors.BifidInputError` for the first invalid hyperparameter of a
    :class:`~bifid.identify.HopfHybridModel` (name, expected form and the value given)."""

    def need(cond: bool, name: str, what: str) -> None:
        if not cond:
            raise BifidInputError(
                f"The {name!r} parameter of HopfHybridModel must be "
                f"{what}; got {getattr(model, name)!r}."
            )

    def count(name: str, low: int) -> None:
        v = getattr(model, name)
        need(
            isinstance(v, int) and not isinstance(v, bool) and v >= low,
            name,
            f"an int >= {low}",
        )

    need(
        model.criticality in ("auto", "subcritical", "supercritical"),
        "criticality",
        "'auto', 'subcritical' or 'supercritical'",
    )
    need(model.quintic in (None, True, False), "quintic", "True, False or None")
    need(
        model.n_harmonics == "auto"
        or (isinstance(model.n_harmonics, int) and model.n_harmonics >= 1),
        "n_harmonics",
        "'auto' or an int >= 1",
    )
    need(
        model.n_points == "auto" or (isinstance(model.n_points, int) and model.n_points >= 16),
        "n_points",
        "'auto' or an int >= 16",
    )
    for name in ("width", "depth", "n_ensemble", "omega_width", "omega_depth"):
        count(name, 1)
    count("omega_samples", 32)
    for name in (
        "n_linear",
        "n_adam",
        "n_lbfgs",
        "omega_harmonics",
        "omega_fit_iterations",
        "omega_iterations",
        "seed",
    ):
        count(name, 0)
    need(model.n_adam + model.n_lbfgs >= 1, "n_adam", "> 0 when n_lbfgs is 0")
    for name in ("learning_rate", "omega_learning_rate", "omega_periods"):
        v = getattr(model, name)
        need(
            isinstance(v, (int, float)) and math.isfinite(v) and v > 0,
            name,
            "a positive number",
        )
    for name in ("regularization", "omega_regularization"):
        v = getattr(model, name)
        need(
            v == "cv" or (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0),
            name,
            "'cv' or a number >= 0",
        )
    for name in ("regularization_grid", "omega_regularization_grid"):
        v = getattr(model, name)
        need(
            len(v) >= 1 and all(math.isfinite(float(x)) and float(x) >= 0 for x in v),
            name,
            "a non-empty sequence of numbers >= 0",
        )
    need(model.omega_form in ("log", "additive"), "omega_form", "'log' or 'additive'")
    need(model.cv_score in ("mean", "median"), "cv_score", "'mean' or 'median'")
    need(
        model.stopping in ("cv", "final")
        or (
            isinstance(model.stopping, int)
            and not isinstance(model.stopping, bool)
            and model.stopping >= 0
        ),
        "stopping",
        "'cv', 'final' or an iteration count >= 0",
    )
