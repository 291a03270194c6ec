"""Records added to a dataset file without rewriting the records it already holds.

:func:`bifid.data.save_dataset` writes files whose ``record`` and ``time`` dimensions can
be extended, with one record per chunk of the sampled signals
(:mod:`bifid.data._growable`). Appending extends the two dimensions and writes (and
compresses) the new records' chunks only: an append costs the new records plus a copy of
the file's bytes, not a rebuild and recompression of the whole dataset (a CBC campaign
that saves after every point would otherwise spend a time quadratic in its number of
points writing its file: 2.4 s of CPU per save of the 14-LCO flutter diagram, 0.2 s to
append its last point).

The file is modified in memory (HDF5 on an in-memory copy of its bytes) and written back
atomically (:func:`bifid.io.atomic_write_bytes`): an interruption at any moment leaves the
previous file, and HDF5 never writes to the destination's file system (see
:mod:`bifid.io`). Files that cannot grow in place -- written by an older version with
fixed dimensions, a record beyond ``keep`` to drop, an extra of another type -- are
rewritten whole through :func:`bifid.data.save_dataset`, with the same result.
"""

from __future__ import annotations

import io
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import xarray as xr

from bifid.data._growable import write_records
from bifid.data._hdf5check import check_self_contained
from bifid.data._iterate import forced_records, lco_records
from bifid.data._netcdf import (
    _RESERVED_ATTRS,
    _builder_kwargs,
    forced_dataset,
    lco_dataset,
    load_dataset,
    save_dataset,
)
from bifid.data._records import ForcedRecord, LCORecord
from bifid.errors import BifidInputError
from bifid.io import atomic_write_bytes, check_input_file

__all__ = ["append_record", "append_records"]


def _kind_of(record: Any) -> str:
    if isinstance(record, LCORecord):
        return "lco"
    if isinstance(record, ForcedRecord):
        return "forced"
    raise BifidInputError(f"append_records takes LCORecord or ForcedRecord, got {type(record)}.")


def _text(value: Any) -> Any:
    return value.decode("utf-8", errors="replace") if isinstance(value, bytes) else value


def _check_given(path: Path, kw: Mapping[str, Any], given: Mapping[str, Any]) -> None:
    """The dataset arguments given for an existing file must agree with it."""
    for key in ("signal_names", "param_name", "observed"):
        if key in given and key in kw:
            value = given[key]
            value = [str(s) for s in value] if key == "signal_names" else str(value)
            if value != kw[key]:
                raise BifidInputError(
                    f"{path} has {key}={kw[key]!r}; cannot append a record with {key}={value!r}."
                )


def _file_kwargs(h: Any) -> dict[str, Any]:
    """Builder arguments of an open HDF5 dataset file (what the records' variables need)."""
    kw: dict[str, Any] = {"signal_names": [str(_text(s)) for s in h["signal"][()]]}
    if _text(h.attrs.get("bifid_kind")) == "lco":
        kw["param_name"] = str(_text(h["param"].attrs.get("name", "param")))
        kw["param_units"] = str(_text(h["param"].attrs.get("units", "")))
    else:
        kw["observed"] = str(_text(h.attrs.get("observed", kw["signal_names"][0])))
        kw["forcing_units"] = str(_text(h["forcing"].attrs.get("units", "")))
    return kw


def append_records(
    path: str | os.PathLike[str],
    records: Sequence[LCORecord | ForcedRecord],
    *,
    keep: int | None = None,
    **dataset_kwargs: Any,
) -> int:
    """Add records to the dataset file at ``path`` (created if missing), atomically.

    The records already in the file are kept as written (module docstring): the cost is
    that of the new records, so a campaign can save after every point.

    Parameters
    ----------
    path
        Dataset file.
    records
        :class:`LCORecord` or :class:`ForcedRecord` values, all of the file's kind (may be
        empty: then only ``attrs`` change).
    keep
        Keep the file's first ``keep`` records and drop the others before appending
        (default: keep all).
    **dataset_kwargs
        Arguments of :func:`lco_dataset` / :func:`forced_dataset` (``signal_names`` is
        required to create the file). For an existing file they must agree with it
        (``signal_names``, ``param_name``, ``observed``), ``attrs`` are set on it and its
        other attributes are kept.

    Returns
    -------
    int
        The number of records in the file.

    Raises
    ------
    BifidInputError
        A record of the other kind, different signal names or count, ``keep`` beyond the
        file's records, a reserved attribute, or a malformed file.
    """
    path = Path(path)
    recs = list(records)
    kinds = {_kind_of(r) for r in recs}
    attrs = dict(dataset_kwargs.get("attrs") or {})
    reserved = sorted(set(attrs) & _RESERVED_ATTRS)
    if reserved:
        raise BifidInputError(f"attribute {reserved[0]!r} is set by the builder.")
    if not path.exists():
        if not recs:
            raise BifidInputError(f"{path} does not exist and no records were given.")
        if "signal_names" not in dataset_kwargs:
            raise BifidInputError(
                f"{path} does not exist yet: pass signal_names=... (and the other dataset "
                "arguments) to create it."
            )
        builder = lco_dataset if kinds == {"lco"} else forced_dataset
        if len(kinds) > 1:
            raise BifidInputError("records of both kinds given; a dataset holds one kind.")
        save_dataset(builder(recs, **dataset_kwargs), path)
        return len(recs)
    path = check_input_file(path, "dataset")
    check_self_contained(path)
    buf = io.BytesIO(path.read_bytes())
    try:
        written = _append_to_image(buf, path, recs, kinds, keep, attrs, dataset_kwargs)
    except BifidInputError:
        raise
    except Exception as exc:  # h5py/h5netcdf raise many types on malformed files
        msg = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise BifidInputError(
            f"{path} is not a dataset records can be appended to ({type(exc).__name__}: {msg})."
        ) from None
    if written is not None:
        atomic_write_bytes(path, buf.getbuffer())
        return written
    return _rewrite(path, recs, keep, attrs, dataset_kwargs)


def _append_to_image(
    buf: io.BytesIO,
    path: Path,
    recs: list[Any],
    kinds: set[str],
    keep: int | None,
    attrs: dict[str, Any],
    given: Mapping[str, Any],
) -> int | None:
    """Append in the in-memory file ``buf``; the number of records, or None when the file
    must be rewritten whole."""
    import h5py

    with h5py.File(buf, "a") as h:
        kind = str(_text(h.attrs.get("bifid_kind")))
        if kinds - {kind}:
            raise BifidInputError(
                f"{path} holds {kind!r} records; cannot append a {type(recs[0]).__name__}."
            )
        if "signal" not in h or "record" not in h:
            return None  # not a dataset: the rewrite says what is wrong
        n_file = int(h["record"].shape[0])
        keep = n_file if keep is None else int(keep)
        if not 0 <= keep <= n_file:
            raise BifidInputError(f"keep={keep}: {path} holds {n_file} records.")
        kw = _file_kwargs(h)
        _check_given(path, kw, given)
        for r in recs:
            if r.signals.shape[1] != len(kw["signal_names"]):
                raise BifidInputError(
                    f"{path} has {len(kw['signal_names'])} signals {kw['signal_names']}; the "
                    f"record has {r.signals.shape[1]}."
                )
        if keep < n_file:
            return None
        new = None
        if recs:
            new = (lco_dataset if kind == "lco" else forced_dataset)(recs, **kw)
        if not write_records(h, new, keep, attrs):
            return None
        return keep + len(recs)


def _rewrite(
    path: Path,
    recs: list[Any],
    keep: int | None,
    attrs: Mapping[str, Any],
    given: Mapping[str, Any],
) -> int:
    """Append by rebuilding the whole dataset (the file cannot grow in place)."""
    old = load_dataset(path)
    kind = old.attrs["bifid_kind"]
    kw = _builder_kwargs(old)
    _check_given(path, kw, given)
    kept = lco_records(old) if kind == "lco" else forced_records(old)
    records = kept[: len(kept) if keep is None else int(keep)] + recs
    if not records:
        raise BifidInputError(f"keep=0 and no records: {path} would hold no records.")
    ds = (lco_dataset if kind == "lco" else forced_dataset)(
        records, **{**kw, "attrs": {**kw["attrs"], **attrs}}
    )
    created = old.attrs.get("created")
    if created:
        ds.attrs["created"] = created
    save_dataset(ds, path)
    return len(records)


def append_record(
    path: str | os.PathLike[str], record: LCORecord | ForcedRecord, **dataset_kwargs: Any
) -> xr.Dataset:
    """Add one record to the dataset file at ``path`` (created if missing), atomically.

    :func:`append_records` with one record (the records already in the file are not
    rewritten), stamping the attribute ``modified``; an interruption leaves the file with
    every earlier point and never a half-written file.

    Parameters
    ----------
    path
        Dataset file.
    record
        :class:`LCORecord` or :class:`ForcedRecord`.
    **dataset_kwargs
        Arguments of :func:`lco_dataset` / :func:`forced_dataset` (``signal_names`` is
        required to create the file). For an existing file they must agree with it
        (``signal_names``, ``param_name``, ``observed``); the file's attributes are kept.

    Returns
    -------
    xarray.Dataset
        The dataset as written (loaded back).

    Raises
    ------
    BifidInputError
        A record of the other kind, different signal names or count, or a malformed file.
    """
    _kind_of(record)
    path = Path(path)
    now = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    if path.exists():
        dataset_kwargs["attrs"] = {**dict(dataset_kwargs.get("attrs") or {}), "modified": now}
    append_records(path, [record], **dataset_kwargs)
    return load_dataset(path)
