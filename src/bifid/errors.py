"""Exception and warning classes.

User errors (bad names, bad values, unreadable files) are :class:`BifidInputError`;
numerical failures are :class:`ConvergenceError`. The CLI turns both into a one-line
message on stderr and a non-zero exit, never a traceback.
"""

from __future__ import annotations


class BifidError(Exception):
    """Base class of every error bifid raises on purpose."""


class BifidInputError(BifidError, ValueError):
    """Bad input: unknown name, invalid value, malformed file."""


class ConvergenceError(BifidError, RuntimeError):
    """A Newton solve, an iteration or an integration did not converge."""


class NotFittedError(BifidError, ValueError, AttributeError):
    """A model was used before ``fit``."""


class ConvergenceWarning(UserWarning):
    """A computation finished but its accuracy is doubtful."""


class ResolutionWarning(UserWarning):
    """A collocation mesh is too coarse for the solution (slow Fourier decay)."""
