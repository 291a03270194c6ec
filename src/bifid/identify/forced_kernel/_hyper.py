"""Validation of the hyperparameters of :class:`~bifid.identify.ForcedKernelModel`."""

from __future__ import annotations

import math
from typing import Any

from bifid.errors import BifidInputError

__all__ = ["check_hyperparameters"]


def check_hyperparameters(model: Any) -> None:
    """Raise :class:`~bifid.errors.BifidInputError` for the first invalid hyperparameter of a
    :class:`~bifid.identify.ForcedKernelModel`."""
    fs = model.forcing_scale
    if not (
        fs in ("fit", "auto")
        or (
            isinstance(fs, (int, float))
            and not isinstance(fs, bool)
            and math.isfinite(fs)
            and fs > 0
        )
    ):
        raise BifidInputError(
            f"forcing_scale must be a positive number, 'fit' or 'auto', got {fs!r}."
        )
    w0 = model.linear_frequency
    if w0 is not None and not (isinstance(w0, (int, float)) and math.isfinite(w0) and w0 > 0):
        raise BifidInputError(
            f"linear_frequency must be a positive number [rad/s] or None, got {w0!r}."
        )
    for name, allowed in (
        ("forcing_frequency", ("constant", "inverse")),
        ("selection", ("ml", "loo")),
        ("a_target", ("eq6.19", "phase")),
        ("amplitude_kind", ("max", "harmonic")),
    ):
        if getattr(model, name) not in allowed:
            raise BifidInputError(
                f"{name} must be {' or '.join(map(repr, allowed))}, got {getattr(model, name)!r}."
            )
    for name, basis in (("a_basis", model.a_basis), ("b_basis", model.b_basis)):
        if any(len(m) != 2 or min(m) < 0 for m in basis):
            raise BifidInputError(
                f"{name} must be pairs of non-negative exponents (rho, omega), got {basis}."
            )
    if any(m[0] == 0 for m in model.a_basis):
        raise BifidInputError(
            "a_basis terms must vanish at rho = 0 (a(0, Ω) = 0): every exponent of rho "
            f"must be >= 1, got {model.a_basis}."
        )
    if not (0 <= model.rho_min_fraction < 1) or model.n_pseudo < 0:
        raise BifidInputError("rho_min_fraction must be in [0, 1) and n_pseudo >= 0.")
