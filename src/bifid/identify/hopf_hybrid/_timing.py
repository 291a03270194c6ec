"""How the hybrid model's training runs: compiled once, timed, on one BLAS thread, with
progress on stderr — kept apart from what it computes.

:class:`StageTimer` runs a jitted training function ahead-of-time compiled
(``fn.lower(*args).compile()``) so that compile time and run time are measured apart; the
executables are kept in a bounded cache keyed on the function (itself cached per static
configuration) and the shapes of its arguments, so cross-validation folds and ensemble
members reuse one executable.
"""

from __future__ import annotations

import contextlib
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from typing import Any

import jax
import numpy as np
from rich.console import Console
from rich.progress import Progress

__all__ = ["StageTimer", "progress_bar"]

_MAX_EXECUTABLES = 32
_EXECUTABLES: OrderedDict = OrderedDict()  # (fn, tree structure, shapes) -> executable


class StageTimer:
    """Wall-clock per training stage, compilation apart; ``times`` by stage name."""

    def __init__(self) -> None:
        self.times: dict[str, float] = {}

    def add(self, name: str, seconds: float) -> None:
        self.times[name] = self.times.get(name, 0.0) + seconds

    def run(self, name: str, fn: Callable, *args: Any) -> Any:
        """``fn(*args)`` from a cached ahead-of-time executable; times recorded under
        ``compile_<name>`` and ``name``."""
        t0 = time.perf_counter()
        leaves, tdef = jax.tree_util.tree_flatten(args)
        key = (fn, tdef, tuple((np.shape(x), np.asarray(x).dtype.str) for x in leaves))
        cache = _EXECUTABLES
        compiled = cache.get(key)
        if compiled is None:
            compiled = fn.lower(*args).compile()
            cache[key] = compiled
            while len(cache) > _MAX_EXECUTABLES:
                cache.popitem(last=False)
        else:
            cache.move_to_end(key)
        t1 = time.perf_counter()
        out = jax.block_until_ready(compiled(*args))
        self.add(f"compile_{name}", t1 - t0)
        self.add(name, time.perf_counter() - t1)
        return out


@contextlib.contextmanager
def progress_bar(enabled: bool, total: int, name: str) -> Iterator[Callable[[str], None]]:
    """A progress bar on stderr; yields ``tick(message)`` (a no-op when disabled)."""
    if not enabled:
        yield lambda message: None
        return
    with Progress(console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(name, total=total)
        yield lambda message: bar.update(task, advance=1, description=message)
