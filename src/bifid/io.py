"""Safe file output and model files.

Every file bifid writes goes through :func:`atomic_path`: the content is written to a
temporary file in the destination's directory and moved over the destination with
:func:`os.replace` only once it is complete, so an interrupted run never leaves a
half-written file (the old file, if any, stays intact).

:func:`atomic_write_netcdf` serialises a dataset in memory before anything touches the
disk: HDF5 writing straight to a file system that fills up crashes the interpreter when the
library later closes the half-written file, while Python's own write raises a clean
:class:`OSError` (``ENOSPC``) that leaves the destination intact.

:func:`check_input_file` and :func:`check_output_path` name what is wrong with a path
(missing, too long, not a regular file, parent missing, not writable) before a command
spends any time computing.

Models are directories holding ``model.json`` (type, hyperparameters, fitted scalar
parameters, settings, versions) and ``arrays.npz`` (numeric arrays only). Nothing is ever
pickled, and :func:`load_model` refuses any file that would need unpickling
(``np.load(..., allow_pickle=False)``).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import json
import math
import os
import platform
import stat
import sys
import tempfile
import time
import zipfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from bifid.errors import BifidInputError

MODEL_JSON = "model.json"
MODEL_ARRAYS = "arrays.npz"
MODEL_FORMAT = "bifid-model"
MODEL_FORMAT_VERSION = 1
_MAX_JSON_BYTES = 64 * 1024 * 1024
_TMP_STEM = 64  # characters of the destination's name kept in a temporary file's name
_MIN_FREE_BYTES = 64 * 1024  # an output directory with less free space is refused early
_ENVIRONMENT_ERRNOS = {
    errno.EROFS,
    errno.EACCES,
    errno.EPERM,
    errno.ENOSPC,
    errno.EDQUOT,
    errno.EIO,
}

__all__ = [
    "MODEL_ARRAYS",
    "MODEL_JSON",
    "atomic_path",
    "atomic_write_bytes",
    "atomic_write_netcdf",
    "atomic_write_text",
    "check_input_file",
    "check_output_path",
    "jsonable",
    "load_model",
    "run_info",
    "save_model",
    "versions",
]


# ---------------------------------------------------------------------------------------------
# atomic writes
# ---------------------------------------------------------------------------------------------


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; move it over ``path`` if the block succeeds.

    The temporary file lives in the same directory (so :func:`os.replace` is an atomic
    rename on POSIX and Windows). If the block raises, the temporary file is deleted and
    ``path`` is left exactly as it was.

    Raises
    ------
    BifidInputError
        If the destination directory does not exist or ``path`` is a directory.
    """
    dest = Path(path)
    parent = dest.parent if str(dest.parent) else Path(".")
    if not parent.is_dir():
        raise BifidInputError(
            f"cannot write {str(dest)!r}: directory {str(parent)!r} does not exist; "
            "create it first."
        )
    if dest.is_dir():
        raise BifidInputError(f"cannot write {str(dest)!r}: it is a directory; give a file name.")
    # a short prefix: the temporary name must fit the file system's name limit whenever
    # the destination's name does
    fd, tmp_name = tempfile.mkstemp(prefix=f".{dest.name[:_TMP_STEM]}.", suffix=".tmp", dir=parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        # keep the permissions a freshly created file would get (mkstemp uses 0o600)
        umask = os.umask(0)
        os.umask(umask)
        with contextlib.suppress(OSError):
            os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, dest)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def _fsync_write(path: Path, data: bytes) -> None:
    with open(path, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file + :func:`os.replace`)."""
    with atomic_path(path) as tmp:
        _fsync_write(tmp, bytes(data))


def atomic_write_text(path: str | os.PathLike[str], text: str, encoding: str = "utf-8") -> None:
    """Write ``text`` to ``path`` atomically (temporary file + :func:`os.replace`)."""
    atomic_write_bytes(path, text.encode(encoding))


def atomic_write_netcdf(obj: Any, path: str | os.PathLike[str], **to_netcdf: Any) -> None:
    """Write an xarray ``Dataset`` or ``DataTree`` to ``path`` as netCDF-4, atomically.

    The file is built in memory (``obj.to_netcdf(engine="h5netcdf")`` without a path) and
    written with :func:`atomic_write_bytes`: HDF5 never writes to the destination's file
    system, so a full disk or a quota gives an :class:`OSError` (``ENOSPC``/``EDQUOT``),
    not an HDF5 crash, and the previous file stays as it was.

    Parameters
    ----------
    obj
        Anything with xarray's ``to_netcdf`` method.
    path
        Destination file.
    **to_netcdf
        Passed on to ``to_netcdf`` (``encoding=...``).
    """
    blob = obj.to_netcdf(None, engine="h5netcdf", **to_netcdf)
    atomic_write_bytes(path, bytes(blob))


# ---------------------------------------------------------------------------------------------
# path checks
# ---------------------------------------------------------------------------------------------

_FILE_KINDS = (
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def _short(path: str | os.PathLike[str], limit: int = 120) -> str:
    """``path`` for a message: long paths keep their start and end only."""
    text = os.fspath(path)
    if len(text) <= limit:
        return text
    return f"{text[: limit // 2]}…{text[-(limit // 3) :]} ({len(text)} characters)"


def _kind_of_special(mode: int) -> str:
    return next((name for test, name in _FILE_KINDS if test(mode)), "not a regular file")


def _name_limits(directory: Path) -> tuple[int, int]:
    """The file system's limits on one name and on a whole path (bytes)."""
    try:
        return (os.pathconf(directory, "PC_NAME_MAX"), os.pathconf(directory, "PC_PATH_MAX"))
    except (OSError, ValueError, AttributeError):  # not POSIX, or the directory is missing
        return 255, 4096


def _is_dir(path: Path) -> bool:
    try:
        return stat.S_ISDIR(os.stat(path).st_mode)
    except (OSError, ValueError):  # missing, too long, an embedded NUL
        return False


def _check_name_lengths(path: Path, what: str) -> None:
    anchor = next((p for p in path.absolute().parents if _is_dir(p)), Path("/"))
    name_max, path_max = _name_limits(anchor)
    too_long = [part for part in path.parts if len(os.fsencode(part)) > name_max]
    if too_long:
        raise BifidInputError(
            f"{what} {_short(path)}: a name in it is {len(os.fsencode(too_long[0]))} bytes "
            f"long; the file system allows {name_max}. Choose a shorter name."
        )
    if len(os.fsencode(os.fspath(path.absolute()))) >= path_max:
        raise BifidInputError(
            f"{what} {_short(path)}: the path is longer than the file system's limit of "
            f"{path_max} bytes. Choose a shorter path."
        )


def check_input_file(path: str | os.PathLike[str], what: str = "input") -> Path:
    """Check that ``path`` names an existing regular file (symbolic links followed).

    Run before a file is opened: a FIFO would block the reader forever and a device such
    as ``/dev/zero`` never ends.

    Returns
    -------
    Path
        ``path``, an existing regular file.

    Raises
    ------
    BifidInputError
        If the path is too long, missing, a directory, or not a regular file (FIFO,
        device, socket); the message names which.
    """
    path = Path(path)
    _check_name_lengths(path, what)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise BifidInputError(f"{what} {_short(path)} does not exist.") from None
    except NotADirectoryError:
        raise BifidInputError(
            f"{what} {_short(path)}: a component of the path is not a directory."
        ) from None
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            raise BifidInputError(f"{what} {_short(path)}: file name too long.") from None
        raise
    if stat.S_ISDIR(mode):
        raise BifidInputError(f"{what} {_short(path)} is a directory, not a file.")
    if not stat.S_ISREG(mode):
        raise BifidInputError(
            f"{what} {_short(path)} is {_kind_of_special(mode)}, not a regular file; "
            "give a file on disk."
        )
    return path


def check_output_path(
    path: str | os.PathLike[str], what: str = "output", *, directory: bool = False
) -> Path:
    """Check, before any computation, that ``path`` can be written.

    Checks the length of every name against the file system's limit, that the parent
    directory exists, that an existing ``path`` is of the expected kind (a regular file,
    or a directory when ``directory``), and that the parent is writable with some free
    space left (a temporary file is created and removed there).

    Returns
    -------
    Path
        ``path``, writable.

    Raises
    ------
    BifidInputError
        What the command line can fix: a name too long, a missing parent, an existing path
        of the wrong kind.
    OSError
        What the environment must fix, with its ``errno``: ``EROFS`` (read-only file
        system), ``EACCES`` / ``EPERM`` (permission), ``ENOSPC`` (no space left).
    """
    path = Path(path)
    _check_name_lengths(path, what)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        reason = "is not a directory" if parent.exists() else "does not exist"
        raise BifidInputError(
            f"{what} {_short(path)}: directory {_short(parent)} {reason}; create it first."
        )
    if path.exists() or path.is_symlink():
        mode = os.stat(path).st_mode if path.exists() else 0
        if directory and not stat.S_ISDIR(mode):
            raise BifidInputError(f"{what} {_short(path)} exists and is not a directory.")
        if not directory and stat.S_ISDIR(mode):
            raise BifidInputError(f"{what} {_short(path)} is a directory; give a file name.")
        if not directory and not stat.S_ISREG(mode):
            raise BifidInputError(
                f"{what} {_short(path)} is {_kind_of_special(mode)}; bifid writes only "
                "regular files."
            )
    probe_dir = path if directory and path.is_dir() else parent
    try:
        fd, probe = tempfile.mkstemp(prefix=".bifid-probe-", dir=probe_dir)
    except OSError as exc:
        if exc.errno in _ENVIRONMENT_ERRNOS:  # read-only, permission, no space: exit 4
            raise OSError(exc.errno, exc.strerror, os.fspath(probe_dir)) from None
        raise BifidInputError(
            f"{what} {_short(path)}: cannot create a file in {_short(probe_dir)} ({exc.strerror})."
        ) from None
    os.close(fd)
    os.unlink(probe)
    free = math.inf
    with contextlib.suppress(OSError, AttributeError):  # statvfs is POSIX only
        vfs = os.statvfs(probe_dir)
        free = vfs.f_bavail * vfs.f_frsize
    if free < _MIN_FREE_BYTES:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), os.fspath(probe_dir))
    return path


# ---------------------------------------------------------------------------------------------
# JSON helpers
# ---------------------------------------------------------------------------------------------


def jsonable(obj: Any) -> Any:
    """Convert numpy/JAX scalars and arrays, tuples, paths to plain JSON values.

    Non-finite floats are kept (Python's :mod:`json` writes ``NaN``/``Infinity`` and reads
    them back), so a model round-trips exactly.
    """
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (str, type(None))):
        return obj
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj)
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if hasattr(obj, "__array__"):
        arr = np.asarray(obj)
        if arr.dtype.kind in "biuf":
            return jsonable(arr.tolist())
    raise BifidInputError(
        f"cannot store a value of type {type(obj).__name__} in JSON; "
        "use numbers, strings, lists and dicts (put arrays in `arrays`)."
    )


def versions() -> dict[str, str]:
    """Versions of bifid and the numerical stack, recorded in every model and dataset."""
    from bifid import __version__

    out = {"bifid": __version__, "python": platform.python_version(), "numpy": np.__version__}
    for mod in ("jax", "scipy", "xarray"):
        with contextlib.suppress(Exception):
            out[mod] = __import__(mod).__version__
    return out


# ---------------------------------------------------------------------------------------------
# model files
# ---------------------------------------------------------------------------------------------


def _check_arrays(arrays: Mapping[str, Any]) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for name, value in arrays.items():
        if not isinstance(name, str) or not name or "/" in name:
            raise BifidInputError(
                f"array names must be non-empty strings without '/', got {name!r}."
            )
        arr = np.asarray(value)
        if arr.dtype.kind not in "biufc":
            raise BifidInputError(
                f"array {name!r} has dtype {arr.dtype}; only numeric/bool arrays can be saved "
                "(object arrays would need pickle, which bifid never uses)."
            )
        out[name] = np.ascontiguousarray(arr)
    return out


def save_model(
    directory: str | os.PathLike[str],
    model_type: str,
    params: Mapping[str, Any],
    arrays: Mapping[str, Any] | None = None,
    settings: Mapping[str, Any] | None = None,
) -> Path:
    """Save a model as ``directory/model.json`` + ``directory/arrays.npz``.

    Both files are written atomically, arrays first; ``model.json`` records the SHA-256 of
    ``arrays.npz`` so a pair left inconsistent by an interruption is detected on load.

    Parameters
    ----------
    directory
        Created if missing (its parent must exist).
    model_type
        The name ``bifid predict`` dispatches on (e.g. ``"hopf_hybrid"``).
    params
        Hyperparameters and fitted scalars; JSON-able (numpy scalars/arrays are converted).
    arrays
        Numeric arrays (no object dtype), stored with :func:`numpy.savez`.
    settings
        Everything that generated the model (data files, options, seeds).

    Returns
    -------
    Path
        The model directory.
    """
    if not isinstance(model_type, str) or not model_type.strip():
        raise BifidInputError(f"model_type must be a non-empty string, got {model_type!r}.")
    if not isinstance(params, Mapping):
        raise BifidInputError(f"params must be a dict, got {type(params).__name__}.")
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise BifidInputError(f"model path {str(directory)!r} exists and is not a directory.")
    if not directory.parent.is_dir():
        raise BifidInputError(
            f"cannot create model directory {str(directory)!r}: its parent does not exist."
        )
    arrs = _check_arrays(arrays or {})
    meta = {
        "format": MODEL_FORMAT,
        "format_version": MODEL_FORMAT_VERSION,
        "type": model_type,
        "params": jsonable(dict(params)),
        "settings": jsonable(dict(settings or {})),
        "versions": versions(),
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    buf = io.BytesIO()
    np.savez(buf, **arrs)
    blob = buf.getvalue()
    meta["arrays"] = {
        "file": MODEL_ARRAYS,
        "sha256": hashlib.sha256(blob).hexdigest(),
        "names": sorted(arrs),
    }
    text = json.dumps(meta, indent=2, sort_keys=False)
    directory.mkdir(exist_ok=True)
    atomic_write_bytes(directory / MODEL_ARRAYS, blob)
    atomic_write_text(directory / MODEL_JSON, text + "\n")
    return directory


def _read_npz_safely(blob: bytes, where: str) -> dict[str, np.ndarray]:
    if not zipfile.is_zipfile(io.BytesIO(blob)):
        raise BifidInputError(
            f"{where} is not an .npz archive (a zip of .npy arrays); it may be a pickle or a "
            "corrupted file. bifid refuses to load it."
        )
    out: dict[str, np.ndarray] = {}
    try:
        with np.load(io.BytesIO(blob), allow_pickle=False) as npz:
            for name in npz.files:
                arr = npz[name]
                if not isinstance(arr, np.ndarray):  # a member that is not a .npy file
                    raise BifidInputError(
                        f"{where}: member {name!r} is not a .npy array; an .npz archive holds "
                        "only .npy arrays."
                    )
                if arr.dtype.kind not in "biufc":
                    raise BifidInputError(
                        f"{where}: array {name!r} has dtype {arr.dtype}; only numeric arrays are "
                        "accepted."
                    )
                out[name] = arr
    except BifidInputError:
        raise
    except ValueError as exc:
        if "pickle" in str(exc).lower():
            raise BifidInputError(
                f"{where} contains pickled (object) data; bifid never unpickles files because "
                "that can execute code. Re-save the model with numeric arrays only."
            ) from None
        raise BifidInputError(f"{where} is not a valid .npz archive: {exc}") from None
    except Exception as exc:  # zipfile.BadZipFile, OSError, EOFError, ...
        raise BifidInputError(f"{where} is not a valid .npz archive: {exc}") from None
    return out


def load_model(directory: str | os.PathLike[str]) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Load a model directory written by :func:`save_model`.

    Returns
    -------
    meta : dict
        The content of ``model.json`` (keys ``type``, ``params``, ``settings``, ``versions``...).
    arrays : dict of ndarray
        The arrays of ``arrays.npz``.

    Raises
    ------
    BifidInputError
        Missing or malformed files, a checksum mismatch, or any pickled content.
    """
    directory = Path(directory)
    _check_name_lengths(directory, "model")
    if not directory.is_dir():
        raise BifidInputError(
            f"model {str(directory)!r} is not a directory; a bifid model is a directory holding "
            f"{MODEL_JSON} and {MODEL_ARRAYS}."
        )
    jpath = directory / MODEL_JSON
    if not jpath.is_file():
        raise BifidInputError(f"model {str(directory)!r} has no {MODEL_JSON}.")
    try:
        raw = jpath.read_bytes()
        if len(raw) > _MAX_JSON_BYTES:
            raise BifidInputError(f"{jpath} is larger than {_MAX_JSON_BYTES} bytes.")
        meta = json.loads(raw.decode("utf-8"))
    except BifidInputError:
        raise
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise BifidInputError(f"{jpath} is not valid JSON: {exc}") from None
    if not isinstance(meta, dict):
        raise BifidInputError(f"{jpath} must hold a JSON object, got {type(meta).__name__}.")
    if meta.get("format") != MODEL_FORMAT:
        raise BifidInputError(
            f"{jpath} is not a bifid model file (format={meta.get('format')!r}, "
            f"expected {MODEL_FORMAT!r})."
        )
    fv = meta.get("format_version")
    if not isinstance(fv, int) or isinstance(fv, bool) or fv > MODEL_FORMAT_VERSION or fv < 1:
        raise BifidInputError(
            f"{jpath}: unsupported format_version {fv!r} (this bifid reads up to "
            f"{MODEL_FORMAT_VERSION}); upgrade bifid."
        )
    if not isinstance(meta.get("type"), str) or not meta["type"]:
        raise BifidInputError(f"{jpath}: missing model 'type'.")
    for key in ("params", "settings"):
        if not isinstance(meta.get(key, {}), dict):
            raise BifidInputError(f"{jpath}: {key!r} must be a JSON object.")
    meta.setdefault("params", {})
    meta.setdefault("settings", {})
    ainfo = meta.get("arrays")
    if not isinstance(ainfo, dict) or ainfo.get("file") != MODEL_ARRAYS:
        raise BifidInputError(f"{jpath}: missing or malformed 'arrays' entry.")
    apath = directory / MODEL_ARRAYS
    if not apath.is_file():
        raise BifidInputError(f"model {str(directory)!r} has no {MODEL_ARRAYS}.")
    blob = apath.read_bytes()
    arrays = _read_npz_safely(blob, str(apath))
    digest = hashlib.sha256(blob).hexdigest()
    if ainfo.get("sha256") != digest:
        raise BifidInputError(
            f"{apath} does not match {MODEL_JSON} (checksum mismatch): the model was modified "
            "or a save was interrupted. Re-run the fit."
        )
    return meta, arrays


def finite_or_none(x: float) -> float | None:
    """``x`` as a float, or ``None`` when it is not finite (JSON has no NaN)."""
    x = float(x)
    return x if math.isfinite(x) else None


def run_info(command: str, **settings: Any) -> dict[str, Any]:
    """Provenance recorded with every output: the command, bifid's version, the time, the
    command line and working directory, and the ``settings`` that produced it."""
    return {
        "command": command,
        "bifid_version": versions()["bifid"],
        "time": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "argv": sys.argv[1:],
        "cwd": os.getcwd(),
        **settings,
    }
