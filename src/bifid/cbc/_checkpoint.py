"""A campaign's file: its measured records and the state that continues it.

The dataset of a campaign (:mod:`bifid.data`, netCDF) holds the recorded points and, in
the attribute ``cbc_campaign``, the campaign's *checkpoint*: where it is (which task,
which branch), the continuation driver's state (last points, tangent, step, direction),
the Broyden corrector's Jacobian, the controller gains and the problem's own state, the
rig's state where the rig can save it, the failures with their reasons, and a digest of
the settings that define the campaign. Every record also carries the checkpoint taken
when it was recorded (``extra["cbc_state"]``).

Every checkpoint replaces the file atomically, so an interruption — SIGINT or SIGKILL —
leaves the last checkpoint, never a torn file; the temporary files of a killed write are
removed when the campaign resumes. A checkpoint costs what its new records cost (and a
copy of the file's bytes): the records already in the file are neither rebuilt nor
recompressed (:func:`bifid.data.append_records`), the new ones are added and the state
replaced.
Numbers are stored as JSON, whose float representation round-trips exactly, so a resumed
campaign continues from bit-identical numbers.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bifid.data import (
    append_records,
    forced_dataset,
    forced_records,
    lco_dataset,
    lco_records,
    load_dataset,
    save_dataset,
)
from bifid.errors import BifidInputError

__all__ = ["CampaignFile", "digest", "from_json", "settings_difference", "to_json"]

#: the settings whose difference makes a file another campaign (in the order they are named)
IDENTITY = (
    "system",
    "protocol",
    "parameters",
    "param",
    "fixed",
    "range",
    "values",
    "continuation",
    "amplitudes",
    "options",
    "rig",
    "seed",
    "ds",
    "param_scale",
)


def to_json(value: Any) -> Any:
    """Plain JSON values: arrays as (nested) lists, NaN/inf as strings (exact round trip)."""
    if isinstance(value, Mapping):
        return {str(k): to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return {"__array__": to_json(value.tolist()), "shape": list(value.shape)}
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        f = float(value)
        return f if math.isfinite(f) else {"__float__": repr(f)}
    return value


def from_json(value: Any) -> Any:
    """Inverse of :func:`to_json`."""
    if isinstance(value, dict):
        if "__array__" in value:
            arr = np.array(from_json(value["__array__"]), dtype=float)
            return arr.reshape(value["shape"])
        if "__float__" in value:
            return float(value["__float__"])
        return {k: from_json(v) for k, v in value.items()}
    if isinstance(value, list):
        return [from_json(v) for v in value]
    return value


def digest(identity: Mapping[str, Any]) -> str:
    """SHA-256 of the canonical JSON of a campaign's identity."""
    text = json.dumps(to_json(dict(identity)), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def settings_difference(old: Mapping[str, Any], new: Mapping[str, Any]) -> str:
    """One line naming the first identity setting in which two campaigns differ ('' if none)."""
    protocol = old.get("protocol")
    names = {
        "fixed": {"scurve": "omega", "frc": "forcing"}.get(str(protocol), "fixed"),
        "range": {"scurve": "forcing range", "frc": "omega range"}.get(str(protocol), "range"),
    }
    for key in IDENTITY:
        a, b = to_json(old.get(key)), to_json(new.get(key))
        if a == b:
            continue
        name = names.get(key, key)
        if isinstance(a, dict) and isinstance(b, dict):
            for k in sorted(set(a) | set(b)):
                if a.get(k) != b.get(k):
                    return f"{name}.{k} is {_short(a.get(k))} in the file, {_short(b.get(k))} now"
        return f"{name} is {_short(a)} in the file, {_short(b)} now"
    return ""


def _short(v: Any) -> str:
    text = json.dumps(v)
    return text if len(text) <= 60 else text[:57] + "..."


class CampaignFile:
    """The dataset file of a campaign (see the module docstring).

    Parameters
    ----------
    path : path
    kind : {"lco", "forced"}
    dataset_kwargs : dict
        Arguments of :func:`bifid.data.lco_dataset` / :func:`bifid.data.forced_dataset`.
    """

    def __init__(self, path: str | Path, kind: str, dataset_kwargs: Mapping[str, Any]) -> None:
        self.path = Path(path)
        self.kind = kind
        self.kw = dict(dataset_kwargs)
        # the records in the file, in order, each with the state it was written with
        self._written: list[tuple[Any, Any]] = []

    def clean(self) -> list[Path]:
        """Remove the temporary files that a killed write left beside the file."""
        removed = []
        parent = self.path.parent if str(self.path.parent) else Path(".")
        for tmp in parent.glob(f".{self.path.name}.*.tmp"):
            with contextlib.suppress(OSError):
                tmp.unlink()
                removed.append(tmp)
        return removed

    def read(self) -> tuple[list[Any], dict[str, Any], Any]:
        """``(records, checkpoint, dataset)`` of an existing campaign file.

        Raises
        ------
        BifidInputError
            If the file is not a dataset of this kind written by a campaign.
        """
        ds = load_dataset(self.path)
        if ds.attrs.get("bifid_kind") != self.kind:
            raise BifidInputError(
                f"--resume: {self.path} holds {ds.attrs.get('bifid_kind')!r} records; this "
                f"campaign writes {self.kind!r} records."
            )
        text = ds.attrs.get("cbc_campaign")
        if not text:
            raise BifidInputError(
                f"--resume: {self.path} has no campaign state (it was not written by a "
                "CBC campaign of this version); start a new file."
            )
        try:
            checkpoint = from_json(json.loads(text))
        except (TypeError, ValueError):
            raise BifidInputError(
                f"--resume: {self.path} has a malformed campaign state."
            ) from None
        records = lco_records(ds) if self.kind == "lco" else forced_records(ds)
        self._written = [(r, r.extra.get("cbc_state")) for r in records]
        if int(checkpoint.get("n_records", 0)) > len(records) and records:
            # records were removed after the last checkpoint: continue from the state the
            # last remaining record carries
            try:
                checkpoint = from_json(json.loads(str(records[-1].extra["cbc_state"])))
            except (KeyError, TypeError, ValueError):
                raise BifidInputError(
                    f"--resume: {self.path} has fewer records than its campaign state and "
                    "its last record carries no state; start a new file."
                ) from None
        return records, checkpoint, ds

    def _on_file(self, records: Sequence[Any]) -> int:
        """How many of ``records`` lead the file as they are (the same objects, unchanged)."""
        n = 0
        for rec, (done, state) in zip(records, self._written, strict=False):
            if rec is not done or rec.extra.get("cbc_state") != state:
                break
            n += 1
        return n

    def write(self, records: Sequence[Any], checkpoint: Mapping[str, Any]) -> None:
        """Write the records and the checkpoint, atomically (nothing without a record).

        The records already in the file stay as written; the file's records after them
        (recorded after the checkpoint a campaign resumed from) are dropped.
        """
        if not records:
            return
        attrs = dict(self.kw.get("attrs") or {})
        attrs["cbc_campaign"] = json.dumps(to_json(dict(checkpoint)))
        kept = self._on_file(records) if self.path.exists() else 0
        if kept:
            append_records(self.path, records[kept:], keep=kept, attrs=attrs)
        else:
            builder = lco_dataset if self.kind == "lco" else forced_dataset
            save_dataset(builder(list(records), **{**self.kw, "attrs": attrs}), self.path)
        self._written = [(r, r.extra.get("cbc_state")) for r in records]
