"""One BLAS thread for the estimators' fits and predictions.

The fits factorise small dense matrices (collocation Jacobians of a few hundred unknowns,
Gauss–Newton systems) thousands of times; OpenBLAS's thread pool makes each of them many
times slower on a loaded 2-core machine (threads spinning against JAX's and other
processes'). The limit is set once per call of a fit, not per factorisation, and the
scan of the loaded libraries it needs is done once per process.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

from threadpoolctl import ThreadpoolController

__all__ = ["one_blas_thread"]


@functools.cache
def _controller() -> ThreadpoolController:
    return ThreadpoolController()


def one_blas_thread(fn: Callable | None = None) -> Any:
    """BLAS on one thread: ``with one_blas_thread(): ...``, or ``@one_blas_thread`` on a
    function (for the duration of each call)."""
    if fn is None:
        return _controller().limit(limits=1, user_api="blas")

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with _controller().limit(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper
