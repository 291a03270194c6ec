"""``bifid import``: detect the format of measurement files and turn them into a dataset."""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import xarray as xr

from bifid.data._csv import read_csv_dataset
from bifid.data._em_rig import em_dataset
from bifid.data._flutter_rig import flutter_cbc_dataset, open_loop_dataset
from bifid.data._matlab import load_mat
from bifid.data._netcdf import combine_datasets, load_dataset
from bifid.data._validate import parse_json_attr
from bifid.errors import BifidInputError
from bifid.io import check_input_file, jsonable

__all__ = ["FORMATS", "detect_format", "expand_paths", "import_files"]

FORMATS = ("auto", "flutter-cbc", "flutter-openloop", "em-scurve", "em-backbone", "csv", "netcdf")
_SUFFIXES = (".mat", ".csv", ".nc", ".nc4", ".h5")
_HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"


def expand_paths(paths: Sequence[str | os.PathLike[str]]) -> list[Path]:
    """Files given, with each directory replaced by its ``.mat``/``.csv``/``.nc`` files
    (sorted, not recursive)."""
    out: list[Path] = []
    for p in paths:
        p = Path(p)
        if _is_directory(p):
            found = sorted(q for q in p.iterdir() if q.is_file() and q.suffix.lower() in _SUFFIXES)
            if not found:
                raise BifidInputError(f"{p}: directory holds no .mat, .csv or .nc files.")
            out.extend(found)
        else:
            out.append(check_input_file(p))
    if not out:
        raise BifidInputError("no input files given.")
    return out


def _is_directory(path: Path) -> bool:
    try:
        return stat.S_ISDIR(os.stat(path).st_mode)
    except (OSError, ValueError):  # missing, name too long, ...: check_input_file says which
        return False


def _mat_format(path: Path) -> str:
    m = load_mat(path)
    exp = m.get("exp")
    points = getattr(exp, "data", None) if exp is not None else None
    if points is not None and getattr(points, "size", 0) > 0:
        first = points.reshape(-1)[0] if hasattr(points, "reshape") else points
        if hasattr(first, "forcing_freq"):
            raw_name = getattr(exp, "name", "")
            name = raw_name.lower() if isinstance(raw_name, str) else ""
            if "backbone" in name:
                return "em-backbone"
            return "em-scurve"
    if "Wind_sped" in m and "freq_actual" in m and "data" in m:
        return "flutter-cbc"
    if "Speed" in m and "data" in m:
        return "flutter-openloop"
    if "data" in m and "fs" in m and ("k__h" in m or "w_h" in m):
        raise BifidInputError(
            f"{path} is a free-decay record (zero airspeed), not a set of limit cycles; "
            "load it with bifid.data.load_free_decay(path)."
        )
    if "s_U" in m:
        raise BifidInputError(
            f"{path} holds LCO amplitudes extracted by the authors, not time series; load it "
            "with bifid.data.load_ulco_amplitudes(path)."
        )
    raise BifidInputError(
        f"{path}: unrecognised MATLAB file (fields {sorted(m)[:12]}); supported: flutter-rig "
        "CBC files (Wind_sped, freq_actual, data), open-loop runs (Speed, data), "
        "electromagnetic-oscillator CBC structs (exp.data(i).forcing_freq)."
    )


def _csv_format(path: Path) -> str:
    with open(path, "rb") as fh:
        head = fh.read(65536)
    try:
        text = head.decode("utf-8-sig", errors="strict")
    except UnicodeDecodeError:
        text = head.decode("utf-8", errors="replace")
    for line in text.splitlines():
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        cols = [c.strip() for c in s.split(",")]
        if "record" in cols and "time" in cols:
            return "csv"
        try:
            [float(c) for c in cols]
        except ValueError:
            break
        if len(cols) == 3:
            raise BifidInputError(
                f"{path} looks like a headerless amplitude table (speed, heave, pitch), not "
                "time series; load it with bifid.data.load_thesis_curves(path)."
            )
        break
    raise BifidInputError(
        f"{path}: not a recognised CSV file; bifid's CSV schema needs a header row such as "
        "record,param,stable,time,<signals> (see docs/data-formats.md)."
    )


def detect_format(path: str | os.PathLike[str]) -> str:
    """Format of one file, from its content (not its name): one of :data:`FORMATS`.

    Raises
    ------
    BifidInputError
        For unreadable or unsupported files, with a pointer to the right loader when the
        file is a known non-time-series file (free decay, amplitude tables).
    """
    path = check_input_file(path)
    with open(path, "rb") as fh:
        magic = fh.read(128)
    if magic.startswith(_HDF5_MAGIC):
        return "netcdf"
    if magic.startswith(b"MATLAB"):
        return _mat_format(path)
    if path.suffix.lower() == ".mat":
        return _mat_format(path)  # gives the loader's error message
    if b"\x00" in magic:
        raise BifidInputError(f"{path}: unrecognised binary file (not MATLAB v5, not netCDF-4).")
    return _csv_format(path)


def import_files(
    paths: Sequence[str | os.PathLike[str]],
    format: str = "auto",
    settings: Mapping[str, Any] | None = None,
) -> xr.Dataset:
    """Read measurement files into one dataset.

    Parameters
    ----------
    paths
        Files or directories (expanded to their ``.mat``/``.csv``/``.nc`` files).
    format
        One of :data:`FORMATS`; ``"auto"`` detects each file's format from its content.
        All files must share one format (S-curves and backbones of the electromagnetic
        oscillator may be mixed: each file becomes one ``curve``).
    settings
        Merged into the dataset's ``settings`` attribute under ``"import"``.

    Returns
    -------
    xarray.Dataset
        Validated ``"lco"`` or ``"forced"`` dataset (not saved).
    """
    if format not in FORMATS:
        raise BifidInputError(f"unknown format {format!r}; choose one of {', '.join(FORMATS)}.")
    files = expand_paths(paths)
    formats = [detect_format(p) if format == "auto" else format for p in files]
    if format in ("em-scurve", "em-backbone"):
        for p in files:
            found = detect_format(p)
            if found not in ("em-scurve", "em-backbone"):
                raise BifidInputError(f"{p} is not an electromagnetic-oscillator file ({found}).")
    families = {("em" if f.startswith("em-") else f) for f in formats}
    if len(families) > 1:
        listing = ", ".join(f"{p.name}: {f}" for p, f in zip(files, formats, strict=True))
        raise BifidInputError(
            f"input files have different formats ({listing}); import each format separately."
        )
    family = families.pop()
    if family == "flutter-cbc":
        ds = flutter_cbc_dataset(files)
    elif family == "flutter-openloop":
        ds = open_loop_dataset(files)
    elif family == "em":
        ds = em_dataset(files)
    elif family == "csv":
        parts = [read_csv_dataset(p) for p in files]
        ds = parts[0] if len(parts) == 1 else combine_datasets(parts, source=None)
    else:
        parts = [load_dataset(p) for p in files]
        ds = parts[0] if len(parts) == 1 else combine_datasets(parts, source=None)
    if settings:
        merged = parse_json_attr(ds, "settings", "import")
        if not isinstance(merged, dict):
            merged = {"previous": merged}
        merged["import"] = dict(settings)
        merged["import"]["formats"] = sorted(set(formats))
        try:
            ds.attrs["settings"] = json.dumps(jsonable(merged))
        except BifidInputError:
            ds.attrs["settings"] = json.dumps(merged, default=str)
    return ds
