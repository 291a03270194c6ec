"""Reading MATLAB files safely: :func:`load_mat` and the field accessors every rig reader uses.

Files are read with ``scipy.io.loadmat`` (MATLAB v5; no code is executed, MATLAB objects
stay opaque); every missing field, wrong shape or non-finite value raises
:class:`~bifid.errors.BifidInputError` naming the file and the field. The readers of the
thesis's two experiments are :mod:`bifid.data._flutter_rig` and :mod:`bifid.data._em_rig`.
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bifid.data._matcheck import check_mat_v5
from bifid.errors import BifidInputError
from bifid.io import check_input_file

__all__ = ["load_mat"]

MAX_MAT_BYTES = 512 * 1024**2

# ---------------------------------------------------------------------------------------------


def load_mat(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a MATLAB v5 file with ``loadmat(squeeze_me=True, struct_as_record=False)``.

    Raises
    ------
    BifidInputError
        Missing file, v7.3/HDF5 or otherwise unreadable file.
    """
    import scipy.io

    path = check_input_file(path)
    size = path.stat().st_size
    if size > MAX_MAT_BYTES:
        raise BifidInputError(f"{path}: {size / 1e6:.0f} MB is larger than the 512 MB limit.")
    blob = path.read_bytes()
    # scipy's compiled reader can crash the interpreter on corrupted element tags:
    # check the file's structure in Python first
    check_mat_v5(blob, str(path))
    try:
        m = scipy.io.loadmat(io.BytesIO(blob), squeeze_me=True, struct_as_record=False)
    except NotImplementedError:
        raise BifidInputError(
            f"{path}: MATLAB v7.3 (HDF5) files are not supported; re-save with "
            "save(..., '-v7') in MATLAB."
        ) from None
    except MemoryError:
        raise BifidInputError(f"{path}: declares arrays too large to load.") from None
    except Exception as exc:  # scipy raises ValueError, TypeError, OSError, ... on bad files
        msg = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        raise BifidInputError(
            f"{path} is not a readable MATLAB v5 .mat file ({type(exc).__name__}: {msg})."
        ) from None
    if not isinstance(m, dict):
        raise BifidInputError(f"{path}: unexpected content.")
    return {k: v for k, v in m.items() if not k.startswith("__")}


def _need(m: dict[str, Any], key: str, path: Path, what: str) -> Any:
    if key not in m:
        raise BifidInputError(f"{path}: field {key!r} ({what}) is missing.")
    return m[key]


def _scalar(value: Any, name: str, path: Path, *, positive: bool = False) -> float:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise BifidInputError(
            f"{path}: {name} must be a number, found {type(value).__name__}."
        ) from None
    if arr.size != 1:
        raise BifidInputError(f"{path}: {name} must be a scalar, found shape {arr.shape}.")
    v = float(arr.reshape(()))
    if not math.isfinite(v) or (positive and v <= 0):
        raise BifidInputError(
            f"{path}: {name} must be finite{' and > 0' if positive else ''}, found {v!r}."
        )
    return v


def _opt_scalar(m: Any, key: str) -> float | None:
    value = m.get(key) if isinstance(m, dict) else getattr(m, key, None)
    if value is None:
        return None
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    if arr.size != 1 or not np.isfinite(arr).all():
        return None
    return float(arr.reshape(()))


def _matrix(value: Any, name: str, path: Path, min_rows: int, min_cols: int = 2) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise BifidInputError(f"{path}: {name} must be a numeric matrix.") from None
    if arr.ndim != 2 or arr.shape[0] < min_rows or arr.shape[1] < min_cols:
        raise BifidInputError(
            f"{path}: {name} must be a matrix with at least {min_rows} rows (channels) and "
            f"{min_cols} columns (samples), found shape {arr.shape}."
        )
    return arr


def _finite_rows(arr: np.ndarray, rows: Sequence[int], name: str, path: Path) -> None:
    for r in rows:
        bad = ~np.isfinite(arr[r])
        if bad.any():
            raise BifidInputError(
                f"{path}: {name} row {r + 1} has {int(bad.sum())} NaN/inf samples."
            )


def _vector(value: Any, name: str, path: Path, n: int | None = None) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise BifidInputError(f"{path}: {name} must be a numeric vector.") from None
    if n is not None and arr.shape[0] != n:
        raise BifidInputError(f"{path}: {name} must have {n} values, found {arr.shape[0]}.")
    if arr.shape[0] == 0:
        raise BifidInputError(f"{path}: {name} is empty.")
    if not np.all(np.isfinite(arr)):
        raise BifidInputError(f"{path}: {name} contains NaN/inf.")
    return arr


def _struct(value: Any, name: str, path: Path) -> Any:
    if not hasattr(value, "_fieldnames"):
        raise BifidInputError(f"{path}: {name} must be a MATLAB struct.")
    return value


def _experiment_par(exp: Any, path: Path) -> Any:
    """``exp.par`` of a rig file, which must give ``sample_freq``: no rate is assumed."""
    if exp is None or not hasattr(exp, "_fieldnames"):
        raise BifidInputError(
            f"{path}: the experiment struct 'exp' is missing, so the sample rate "
            "(exp.par.sample_freq) is unknown; bifid does not assume one. Export the file "
            "with its exp struct, or write the records as CSV with a time column."
        )
    par = getattr(exp, "par", None)
    if par is None or getattr(par, "sample_freq", None) is None:
        raise BifidInputError(
            f"{path}: exp.par.sample_freq (the sample rate) is missing; bifid does not assume one."
        )
    return par


# ---------------------------------------------------------------------------------------------
# flutter rig: PP-CBC limit cycles (cbc_model1, cbc_model2)
