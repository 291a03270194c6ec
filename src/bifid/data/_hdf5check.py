"""Refuse HDF5 (netCDF-4) files that take data from outside themselves.

HDF5 lets a dataset keep its bytes in other files (*external storage*), assemble itself
from datasets of other files (*virtual datasets*), and lets a group link to objects in
other files (*external links*). A reader following them reads whatever those paths hold
on the reader's machine -- a dataset that copies the bytes of some local file into a
measurement. bifid writes none of these, so :func:`check_self_contained` walks every link
and object of a file with h5py before xarray opens it and refuses the file if it finds one.

Written by hand: neither h5netcdf nor xarray has an option to refuse them.
"""

from __future__ import annotations

import os
from pathlib import Path

from bifid.errors import BifidInputError

__all__ = ["check_self_contained"]

MAX_OBJECTS = 100_000  # a dataset file has a few dozen; more is refused, not walked


def _problems(root) -> list[str]:
    import h5py

    found: list[str] = []
    seen: set[int] = set()
    stack = [("", root)]
    n_objects = 0
    while stack and not found:
        prefix, group = stack.pop()
        for name in group:
            n_objects += 1
            if n_objects > MAX_OBJECTS:
                return [f"more than {MAX_OBJECTS} objects"]
            where = f"{prefix}/{name}"
            link = group.get(name, getlink=True)
            if isinstance(link, h5py.ExternalLink):
                found.append(f"{where} is an external link to {link.filename!r}")
                continue
            if isinstance(link, h5py.SoftLink):
                continue  # a name for an object inside the file, visited where it lives
            if not isinstance(link, h5py.HardLink):
                found.append(f"{where} is a {type(link).__name__}")
                continue
            obj = group[name]
            if isinstance(obj, h5py.Dataset):
                if obj.external:
                    files = sorted({str(e[0]) for e in obj.external})
                    found.append(f"{where} stores its data in external file(s) {files}")
                elif obj.is_virtual:
                    files = sorted({str(s.file_name) for s in obj.virtual_sources()})
                    found.append(f"{where} is a virtual dataset reading {files}")
            elif isinstance(obj, h5py.Group):
                address = h5py.h5o.get_info(obj.id).addr
                if address not in seen:
                    seen.add(address)
                    stack.append((where, obj))
    return found


def check_self_contained(path: str | os.PathLike[str], where: str | None = None) -> None:
    """Refuse an HDF5 file with external storage, virtual datasets or external links.

    Parameters
    ----------
    path
        An HDF5 / netCDF-4 file.
    where
        How to name the file in messages (default: ``path``).

    Raises
    ------
    BifidInputError
        If the file is not readable HDF5 or takes data from outside itself.
    """
    import h5py

    where = where or str(path)
    try:
        fh = h5py.File(Path(path), "r")
    except Exception as exc:  # h5py raises OSError, ValueError, ... on malformed files
        msg = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise BifidInputError(
            f"{where} is not a readable netCDF-4 (HDF5) file ({type(exc).__name__}: {msg})."
        ) from None
    try:
        with fh:
            found = _problems(fh)
    except BifidInputError:
        raise
    except Exception as exc:  # a damaged object table
        raise BifidInputError(
            f"{where}: its HDF5 structure cannot be read ({type(exc).__name__}: {str(exc)[:200]})."
        ) from None
    if found:
        raise BifidInputError(
            f"{where} takes data from outside itself ({'; '.join(found[:3])}); bifid reads "
            "only self-contained files. Re-save the data as a plain netCDF-4 file."
        )
