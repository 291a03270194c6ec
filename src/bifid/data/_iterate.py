"""Records of a dataset: each stored orbit back as an :class:`~bifid.data.LCORecord` or
:class:`~bifid.data.ForcedRecord`, trimmed to its ``n_samples``."""

from __future__ import annotations

from typing import Any

import numpy as np
import xarray as xr

from bifid.data._records import ForcedRecord, LCORecord
from bifid.data._validate import EXTRA_PREFIX
from bifid.errors import BifidInputError

__all__ = ["forced_records", "lco_records"]


def _record_extras(ds: xr.Dataset, i: int) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name in ds.data_vars:
        name = str(name)
        if not name.startswith(EXTRA_PREFIX):
            continue
        v = ds[name].values[i]
        if isinstance(v, (bytes, np.bytes_)):
            v = v.decode("utf-8", errors="replace")
        if isinstance(v, str):
            if v:
                out[name[len(EXTRA_PREFIX) :]] = str(v)
        elif np.isfinite(v):
            out[name[len(EXTRA_PREFIX) :]] = float(v)
    return out


def _check_kind(ds: xr.Dataset, kind: str) -> None:
    found = ds.attrs.get("bifid_kind") if isinstance(ds, xr.Dataset) else None
    if found != kind:
        raise BifidInputError(f"expected a {kind!r} dataset, got bifid_kind={found!r}.")


def lco_records(ds: xr.Dataset) -> list[LCORecord]:
    """The records of an ``"lco"`` dataset, each trimmed to its ``n_samples``."""
    _check_kind(ds, "lco")
    out = []
    for i in range(ds.sizes["record"]):
        n = int(ds["n_samples"].values[i])
        target = ds["target"].values[i, :n]
        s = int(ds["stable"].values[i])
        out.append(
            LCORecord(
                param=float(ds["param"].values[i]),
                signals=ds["signals"].values[i, :n, :],
                sample_rate=float(ds["sample_rate"].values[i]),
                stable=None if s < 0 else bool(s),
                control=ds["control"].values[i, :n],
                target=None if np.all(np.isnan(target)) else target,
                frequency=float(ds["frequency"].values[i]),
                extra=_record_extras(ds, i),
            )
        )
    return out


def forced_records(ds: xr.Dataset) -> list[ForcedRecord]:
    """The records of a ``"forced"`` dataset, each trimmed to its ``n_samples``."""
    _check_kind(ds, "forced")
    out = []
    for i in range(ds.sizes["record"]):
        n = int(ds["n_samples"].values[i])
        target = ds["target"].values[i, :n]
        force = ds["force"].values[i, :n]
        s = int(ds["stable"].values[i])
        phase = float(ds["phase"].values[i])
        out.append(
            ForcedRecord(
                omega=float(ds["omega"].values[i]),
                forcing=float(ds["forcing"].values[i]),
                signals=ds["signals"].values[i, :n, :],
                sample_rate=float(ds["sample_rate"].values[i]),
                stable=None if s < 0 else bool(s),
                force=None if np.all(np.isnan(force)) else force,
                control=ds["control"].values[i, :n],
                target=None if np.all(np.isnan(target)) else target,
                amplitude=float(ds["amplitude"].values[i]),
                phase=phase,
                curve=int(ds["curve"].values[i]),
                extra=_record_extras(ds, i),
            )
        )
    return out
