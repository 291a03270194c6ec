"""The frame every demo runs in: one BLAS thread, the stage cache, the progress bar over
the stages, the ground-truth stage, and the closing lines of the summary (wall time, the
files written)."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bifid.demo._cache import StageCache
from bifid.demo._progress import Stages

__all__ = ["DemoRun", "PointCounter", "run_demo"]


@dataclass
class DemoRun:
    """What the stages of one demo run share.

    Attributes
    ----------
    out : Path
        The demo's output directory.
    cache : StageCache
        Which stages are up to date (:mod:`bifid.demo._cache`).
    bar : Stages
        The progress bar over the stages.
    t_start : float
        ``time.perf_counter()`` when the run began.
    timings : dict
        Seconds spent in each stage (reused stages: the time to check and load them).
    """

    out: Path
    cache: StageCache
    bar: Stages
    t_start: float = field(default_factory=time.perf_counter)
    timings: dict[str, float] = field(default_factory=dict)

    def elapsed(self) -> float:
        """Seconds since the run began."""
        return time.perf_counter() - self.t_start

    def truth(self, key: str, build: Callable[[], object]) -> tuple[dict[str, Any], dict[str, Any]]:
        """The ``truth`` stage: ``build()`` writes ``truth.json``/``truth.npz`` unless they
        are fresh; the loaded facts and arrays (:func:`bifid.demo._truth.load_truth`)."""
        from bifid.demo._truth import load_truth

        self.bar.start("truth", "continuation of the true model")
        self.timings["truth"] = self.cache.ensure(
            "truth", key, ["truth.json", "truth.npz"], lambda: build() and None
        )
        return load_truth(self.out)


class PointCounter:
    """The ``on_point`` callback of a demo's campaign: counts the points it converges and
    notes each on the progress bar as ``describe(point, count)``.

    Made with a campaign file ``path``: a file left there by a campaign with other
    settings is removed (the new campaign starts afresh).
    """

    def __init__(self, path: Path, bar: Stages, describe: Callable[[Any, int], str]) -> None:
        if path.exists():
            path.unlink()
        self.bar = bar
        self.describe = describe
        self.count = 0

    def __call__(self, point: Any) -> None:
        self.count += 1
        self.bar.note(self.describe(point, self.count))


def run_demo(
    out: Path,
    stages: Sequence[str],
    body: Callable[[DemoRun], dict[str, Any]],
    *,
    refresh: bool = False,
    progress: bool = True,
) -> dict[str, Any]:
    """Run ``body`` over the named ``stages`` in ``out``; its summary, with ``wall_time_s``
    and ``files`` (what ``out`` holds) added.

    BLAS runs on one thread throughout: the stages factorise small matrices thousands
    of times, which a thread pool slows down many times on a loaded machine.

    Parameters
    ----------
    out : Path
        Output directory (created if missing; holds the cache manifest).
    stages : sequence of str
        The stage names, in order, for the progress bar.
    body : callable
        ``body(run) -> summary``: runs (or reuses) each stage and writes the report.
    refresh : bool
        Run every stage again, whatever the cache holds.
    progress : bool
        Show the progress bar on stderr.
    """
    from bifid.continuation._blas import one_blas_thread  # bifid.continuation: slow to import

    with one_blas_thread():
        out.mkdir(parents=True, exist_ok=True)
        cache = StageCache(out, refresh=refresh)
        with Stages(stages, enabled=progress) as bar:
            run = DemoRun(out, cache, bar)
            summary = body(run)
            summary["wall_time_s"] = run.elapsed()
            summary["files"] = sorted(p.name for p in out.iterdir() if not p.name.startswith("."))
    return summary
