"""Stage cache of the demos: a second run reuses what the first one produced.

Each stage (campaign, model, ground truth, ...) is keyed by the SHA-256 of its settings
*and the keys of the stages it consumes*, so changing the noise level re-runs the campaign
and, through the chained key, the model fitted to it -- but not the ground truth. The
manifest ``DIR/cache.json`` is written atomically after each stage, so an interrupted
demo loses only the stage it was in.

Written by hand: the cache is a dictionary in a JSON file; joblib.Memory would hash the
arguments (datasets, models) instead of the settings and pickles its results, which bifid
never does.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

from bifid.data import load_dataset
from bifid.io import atomic_write_text, jsonable

MANIFEST = "cache.json"

__all__ = ["MANIFEST", "StageCache", "settings_key"]


def settings_key(settings: Mapping[str, Any]) -> str:
    """A short stable hash of JSON-able settings (key order does not matter)."""
    text = json.dumps(jsonable(dict(settings)), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class StageCache:
    """Which stages of a demo directory are up to date.

    Parameters
    ----------
    directory : Path
        The demo's output directory (holds the manifest).
    refresh : bool
        Ignore what is there: every stage runs again.
    """

    def __init__(self, directory: Path, refresh: bool = False) -> None:
        self.directory = Path(directory)
        self.refresh = refresh
        self.path = self.directory / MANIFEST
        self.entries: dict[str, dict[str, Any]] = {}
        if self.path.is_file():
            try:
                loaded = json.loads(self.path.read_text())
                if isinstance(loaded, dict):
                    self.entries = {k: v for k, v in loaded.items() if isinstance(v, dict)}
            except (OSError, ValueError):
                self.entries = {}  # a damaged manifest only costs a re-run
        self.reused: list[str] = []

    def fresh(self, stage: str, key: str, files: Iterable[str | Path]) -> bool:
        """True if ``stage`` was completed with ``key`` and all its files still exist."""
        if self.refresh:
            return False
        entry = self.entries.get(stage)
        ok = (
            entry is not None
            and entry.get("key") == key
            and all((self.directory / f).exists() for f in files)
        )
        if ok:
            self.reused.append(stage)
        return ok

    def done(self, stage: str, key: str, seconds: float, **info: Any) -> None:
        """Record that ``stage`` finished with ``key`` (manifest rewritten atomically)."""
        self.entries[stage] = {
            "key": key,
            "seconds": float(seconds),
            "finished": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            **jsonable(info),
        }
        atomic_write_text(self.path, json.dumps(self.entries, indent=2, sort_keys=True))

    def ensure(
        self,
        stage: str,
        key: str,
        files: Iterable[str | Path],
        build: Callable[[], Mapping[str, Any] | None],
    ) -> float:
        """Run ``build`` unless ``stage`` is fresh; record it; return the seconds spent.

        ``build`` writes the stage's ``files`` and may return facts to keep in the manifest.
        """
        t0 = time.perf_counter()
        if not self.fresh(stage, key, list(files)):
            info = build() or {}
            self.done(stage, key, time.perf_counter() - t0, **info)
        return time.perf_counter() - t0

    def info(self, stage: str) -> dict[str, Any]:
        """What was recorded with ``stage`` (empty if nothing)."""
        return dict(self.entries.get(stage, {}))

    def dataset(self, key: str, measure: Callable[[], Mapping[str, Any]]) -> tuple[float, Any]:
        """The ``campaign`` stage: ``measure()`` writes ``dataset.nc`` unless it is fresh;
        the seconds spent and the loaded dataset."""
        seconds = self.ensure("campaign", key, ["dataset.nc"], measure)
        return seconds, load_dataset(self.directory / "dataset.nc")

    def model(
        self,
        key: str,
        estimator: type,
        hyper: Mapping[str, Any],
        data: Any,
        settings: dict,
        fit_options: Mapping[str, Any] | None = None,
    ) -> tuple[float, Any]:
        """The ``model`` stage: ``estimator(**hyper).fit(data, **fit_options)`` saved in
        ``model/`` unless it is fresh; the seconds spent and the loaded model. A saved model
        fitted with ``uncertainty=True`` that has no calibrated intervals when loaded (saved
        by a version whose intervals this one does not read) is fitted again."""

        def fit() -> None:
            model = estimator(**hyper).fit(data, **dict(fit_options or {}))
            model.save(self.directory / "model", settings=settings)

        seconds = self.ensure("model", key, ["model/model.json"], fit)
        model = estimator.load(self.directory / "model")
        if dict(fit_options or {}).get("uncertainty") and not getattr(model, "calibrated", True):
            t0 = time.perf_counter()
            fit()
            self.done("model", key, time.perf_counter() - t0)
            self.reused = [s for s in self.reused if s != "model"]
            return seconds + time.perf_counter() - t0, estimator.load(self.directory / "model")
        return seconds, model
