"""bifid: identify ODE models of nonlinear systems from their bifurcation diagrams.

Importing bifid switches JAX to 64-bit floats: every numerical routine here assumes it.
"""

import jax

jax.config.update("jax_enable_x64", True)

from bifid.errors import (  # noqa: E402
    BifidError,
    BifidInputError,
    ConvergenceError,
    ConvergenceWarning,
    NotFittedError,
    ResolutionWarning,
)
from bifid.systems import Parameter, System, get_system, list_systems, register  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "BifidError",
    "BifidInputError",
    "ConvergenceError",
    "ConvergenceWarning",
    "NotFittedError",
    "Parameter",
    "ResolutionWarning",
    "System",
    "__version__",
    "get_system",
    "list_systems",
    "register",
]
