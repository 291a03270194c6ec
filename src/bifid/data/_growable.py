"""The file layout that lets a dataset grow by records without rewriting the others.

A dataset file's variables along ``record`` are chunked with unlimited HDF5 extents (one
record per chunk of a sampled signal), while its netCDF dimensions ``record`` and ``time``
are *fixed* ones whose dimension scales may still be extended: readers see an ordinary
netCDF-4 file with fixed dimensions. (Unlimited netCDF dimensions would do the same, but
h5netcdf sizes an unlimited dimension by visiting every variable along it, for every
variable it opens: a dataset with them loads 5-7 times slower.)

:func:`growable_image` turns the in-memory image written by xarray with unlimited
dimensions into this layout; :func:`write_records` appends records to an open file of it.
Written with h5py by hand: neither xarray nor h5netcdf appends to a fixed dimension.
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping
from typing import Any

import numpy as np
import xarray as xr

from bifid.data._validate import EXTRA_PREFIX
from bifid.io import jsonable

__all__ = ["GROWING", "growable_image", "write_records"]

GROWING = ("record", "time")  # the dimensions a file can grow along
_MAX_EXTENT = 2**40  # the largest extent of a growing dimension's scale
_NOT_A_VARIABLE = "This is a netCDF dimension but not a netCDF variable."


def _scale_name(h: Any, dim: str, size: int) -> str:
    """The dimension scale's NAME as netCDF-4 writes it (with the length when the
    dimension has no coordinate variable)."""
    name = h[dim].attrs["NAME"]
    name = name.decode("ascii") if isinstance(name, bytes) else str(name)
    return f"{_NOT_A_VARIABLE}{size:10}" if name.startswith(_NOT_A_VARIABLE) else name


def _fixed_scale(h: Any, dim: str) -> None:
    """Replace the unlimited scale of ``dim`` by a fixed-size one that can be extended."""
    old = h[dim]
    refs = [(h[ref], int(axis)) for ref, axis in old.attrs.get("REFERENCE_LIST", [])]
    keep = [
        (k, old.attrs[k], old.attrs.get_id(k).dtype)
        for k in old.attrs
        if k not in ("CLASS", "NAME", "REFERENCE_LIST")
    ]
    name = _scale_name(h, dim, old.shape[0])
    data = old[()] if not name.startswith(_NOT_A_VARIABLE) else None
    shape, dtype, chunks, fill = old.shape, old.dtype, old.chunks, old.fillvalue
    for var, axis in refs:
        var.dims[axis].detach_scale(old)
    del h[dim]
    new = h.create_dataset(
        dim,
        shape=shape,
        dtype=dtype,
        maxshape=(_MAX_EXTENT,),
        chunks=chunks,
        data=data,
        fillvalue=fill,
    )
    new.make_scale(name)
    for k, value, kind in keep:
        new.attrs.create(k, value, dtype=kind)
    for var, axis in refs:
        var.dims[axis].attach_scale(new)


def growable_image(image: bytes | memoryview) -> bytes:
    """The netCDF-4 image ``image`` (written with ``record`` and ``time`` unlimited) with
    fixed dimensions that :func:`write_records` can extend."""
    import h5py

    buf = io.BytesIO(image)
    with h5py.File(buf, "a") as h:
        for dim in GROWING:
            if dim in h and h[dim].maxshape == (None,):
                _fixed_scale(h, dim)
    return buf.getvalue()


def _along(h: Any, dim: str) -> dict[str, int]:
    """``{variable: axis}`` of the variables along ``dim``, its scale included (empty if
    the file cannot grow along ``dim``)."""
    scale = h.get(dim)
    if scale is None or (scale.maxshape[0] is not None and scale.maxshape[0] < _MAX_EXTENT):
        return {}
    out = {dim: 0}
    for ref, axis in scale.attrs.get("REFERENCE_LIST", []):
        out[h[ref].name.lstrip("/")] = int(axis)
    return out


def _is_text(dtype: np.dtype) -> bool:
    import h5py

    return dtype.kind in "SU" or h5py.check_string_dtype(dtype) is not None


def _fits(dset: Any, var: xr.Variable, records: dict[str, int], times: dict[str, int]) -> bool:
    """The file's variable ``dset`` takes the records of ``var``: same dimensions, same
    kind of values, extendable along them."""
    n = dset.name.lstrip("/")
    if records.get(n) != var.dims.index("record") or dset.ndim != var.ndim:
        return False
    if "time" in var.dims and times.get(n) != var.dims.index("time"):
        return False
    if n not in GROWING and any(dset.maxshape[a] is not None for a in _axes_of(n, records, times)):
        return False
    text = _is_text(dset.dtype)
    return text == (var.dtype.kind in "OSU") and (text or dset.dtype.kind == var.dtype.kind)


def _axes_of(n: str, records: dict[str, int], times: dict[str, int]) -> list[int]:
    return [records[n]] + ([times[n]] if n in times else [])


def write_records(h: Any, new: xr.Dataset | None, start: int, attrs: Mapping[str, Any]) -> bool:
    """Write the records of ``new`` (a dataset of the file's kind) from record ``start`` of
    the open file ``h`` and set ``attrs``; False, with nothing written, when the file does
    not take them (not of this module's layout, a variable missing or of another type)."""
    if new is not None:
        records, times = _along(h, "record"), _along(h, "time")
        data = {str(n): v for n, v in new.variables.items() if "record" in v.dims}
        found = {n: h[n] for n in records}
        if not times or any(
            n not in found or not _fits(found[n], var, records, times) for n, var in data.items()
        ):
            return False
        m = new.sizes["record"]
        for n, axis in records.items():
            found[n].resize(start + m, axis=axis)
        if new.sizes["time"] > h["time"].shape[0]:
            for n, axis in times.items():
                h[n].resize(new.sizes["time"], axis=axis)
            name = _scale_name(h, "time", new.sizes["time"])
            h["time"].attrs.modify("NAME", np.bytes_(name.encode("ascii")))
        for n, var in data.items():
            key = tuple(
                slice(start, start + m) if d == "record" else slice(0, size)
                for d, size in zip(var.dims, var.shape, strict=True)
            )
            found[n][key] = np.arange(start, start + m) if n == "record" else var.values
        for n, dset in found.items():  # an extra the new records lack: empty, as stored
            if n.startswith(EXTRA_PREFIX) and n not in data:
                text = _is_text(dset.dtype)
                dset[start : start + m] = np.array([""] * m, dtype=object) if text else np.nan
    for k, v in attrs.items():  # as the builders store them
        h.attrs[str(k)] = v if isinstance(v, (str, int, float)) else json.dumps(jsonable(v))
    return True
