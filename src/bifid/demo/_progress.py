"""Stage progress of the demos on stderr (rich): which stage runs, what it just did."""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence

__all__ = ["Stages"]


class Stages:
    """A progress bar over named stages, with a one-line note of the latest event."""

    def __init__(self, names: Sequence[str], enabled: bool = True) -> None:
        self.names = list(names)
        self.enabled = enabled
        self._progress = None
        self._task = None
        self._current: str | None = None
        self._t0 = time.perf_counter()

    def __enter__(self) -> Stages:
        if self.enabled:
            from rich.console import Console
            from rich.progress import (
                BarColumn,
                MofNCompleteColumn,
                Progress,
                TextColumn,
                TimeElapsedColumn,
            )

            self._progress = Progress(
                TextColumn("[bold]{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                TextColumn("{task.fields[note]}"),
                console=Console(file=sys.stderr),
                transient=False,
            )
            self._progress.start()
            self._task = self._progress.add_task("demo", total=len(self.names), note="")
        return self

    def start(self, name: str, description: str) -> None:
        """Mark the previous stage done and start ``name``."""
        if self._current is not None:
            self._advance()
        self._current = name
        if self._progress is not None:
            self._progress.update(self._task, description=f"{name}: {description}", note="")

    def note(self, text: str) -> None:
        if self._progress is not None:
            self._progress.update(self._task, note=text)

    def _advance(self) -> None:
        if self._progress is not None:
            self._progress.advance(self._task)

    def __exit__(self, *exc: object) -> None:
        if self._current is not None and exc[0] is None:
            self._advance()
        if self._progress is not None:
            self._progress.update(self._task, description="done", note="")
            self._progress.stop()
