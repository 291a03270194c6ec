"""One BLAS thread for continuation runs, fits and predictions.

They factorise small dense matrices (collocation Jacobians of a few hundred unknowns,
Gauss–Newton systems) thousands of times; OpenBLAS's thread pool makes each of them many
times slower on a loaded 2-core machine (threads spinning against JAX's and other
processes'). The limit is set once per run or fit, not per factorisation, and the scan of
the loaded libraries it needs (``threadpoolctl``; tens of milliseconds once numba, SciPy
and matplotlib are loaded) is done once per process.
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


def one_blas_thread(fn: Callable | None = None, *, user_api: str | None = "blas") -> Any:
    """BLAS on one thread: ``with one_blas_thread(): ...``, or ``@one_blas_thread`` on a
    function (for the duration of each call); ``user_api=None`` limits OpenMP too."""
    if fn is None:
        return _controller().limit(limits=1, user_api=user_api)

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with _controller().limit(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper
