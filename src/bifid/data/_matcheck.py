"""Structural check of MATLAB v5 files before ``scipy.io.loadmat`` sees them.

scipy's compiled MAT reader trusts the element tags it reads: a corrupted data-type code
makes it crash the interpreter (segmentation fault, found by ``tests/test_data_hardening``
fuzzing bit-flipped files). This module walks the file's element tree in pure Python —
tags, sizes, nesting, compression — and rejects anything malformed with
:class:`~bifid.errors.BifidInputError`, so only well-framed files reach scipy.

MAT v5 layout (MathWorks, "MAT-File Format", ch. 1): a 128-byte header (text, subsystem
offset, version 0x0100, endian indicator ``IM``/``MI``), then data elements. Each element
has an 8-byte tag (data type, byte count) or a 4-byte "small element" tag (byte count ≤ 4
in the upper 16 bits); ``miMATRIX`` (14) elements contain further elements (array flags,
dimensions, name, data, or cells / fields); ``miCOMPRESSED`` (15) elements hold one
zlib-compressed element.
"""

from __future__ import annotations

import struct
import zlib

from bifid.errors import BifidInputError

__all__ = ["check_mat_v5"]

MI_INT32, MI_UINT32, MI_MATRIX, MI_COMPRESSED = 5, 6, 14, 15
# miINT8..miUINT64 (1-13 without the reserved 8, 10, 11), miMATRIX, miCOMPRESSED, miUTF8-32
VALID_TYPES = frozenset({1, 2, 3, 4, 5, 6, 7, 9, 12, 13, 14, 15, 16, 17, 18})
VALID_CLASSES = frozenset(range(1, 18))  # mxCELL_CLASS (1) .. mxOPAQUE_CLASS (17)
MAX_DEPTH = 32
MAX_DECOMPRESSED = 1024**3  # bytes per compressed element


def _fail(where: str, msg: str) -> None:
    raise BifidInputError(f"{where} is not a valid MATLAB v5 file: {msg}")


def check_mat_v5(blob: bytes, where: str = "file") -> None:
    """Raise :class:`BifidInputError` unless ``blob`` is a well-formed MAT v5 file."""
    if len(blob) < 128:
        _fail(where, f"{len(blob)} bytes is shorter than the 128-byte header")
    endian = blob[126:128]
    if endian == b"IM":
        e = "<"
    elif endian == b"MI":
        e = ">"
    else:
        _fail(where, "no MAT v5 header (MATLAB v4 files are not supported)")
    (version,) = struct.unpack(e + "H", blob[124:126])
    if version == 0x0200:
        raise BifidInputError(
            f"{where}: MATLAB v7.3 (HDF5) files are not supported; re-save "
            "with save(..., '-v7') in MATLAB."
        )
    if version != 0x0100:
        _fail(where, f"unknown version 0x{version:04x}")
    _walk(blob, 128, len(blob), e, where, depth=0, top=True)


_ITEMSIZE = {1: 1, 2: 1, 3: 2, 4: 2, 5: 4, 6: 4, 7: 4, 9: 8, 12: 8, 13: 8, 16: 1, 17: 2, 18: 4}
_NUMERIC_DATA = frozenset({1, 2, 3, 4, 5, 6, 7, 9, 12, 13})


def _elements(
    buf: bytes, pos: int, end: int, e: str, where: str, top: bool
) -> list[tuple[int, int, int]]:
    """Parse a sequence of data elements: ``[(type, content_start, nbytes), ...]``."""
    out = []
    while pos < end:
        if end - pos < 8:
            if top or any(buf[pos:end]):  # trailing zero padding inside a matrix is allowed
                _fail(where, f"truncated element tag at byte {pos}")
            break
        a, b = struct.unpack(e + "II", buf[pos : pos + 8])
        if a >> 16:  # small data element: type in the low, byte count in the high half
            mtype, nbytes, cstart, size = a & 0xFFFF, a >> 16, pos + 4, 8
            if nbytes > 4:
                _fail(where, f"small element with {nbytes} bytes at byte {pos}")
        else:
            mtype, nbytes, cstart = a, b, pos + 8
            if cstart + nbytes > end:
                _fail(
                    where,
                    f"element at byte {pos} claims {nbytes} bytes, "
                    f"only {end - cstart} remain (truncated file?)",
                )
            size = min(8 + nbytes + (0 if top else (-nbytes) % 8), end - pos)
        if mtype not in VALID_TYPES:
            _fail(where, f"unknown data type {mtype} at byte {pos}")
        out.append((mtype, cstart, nbytes))
        pos += size
    return out


def _walk(buf: bytes, pos: int, end: int, e: str, where: str, depth: int, top: bool) -> None:
    if depth > MAX_DEPTH:
        _fail(where, f"elements nested more than {MAX_DEPTH} deep")
    for mtype, cstart, nbytes in _elements(buf, pos, end, e, where, top):
        if mtype == MI_COMPRESSED:
            if not top:
                _fail(where, f"compressed element nested in a matrix at byte {cstart}")
            _check_compressed(buf[cstart : cstart + nbytes], e, where, depth)
        elif mtype == MI_MATRIX:
            _check_matrix(buf, cstart, cstart + nbytes, e, where, depth)
        elif top:
            _fail(where, f"top-level element of type {mtype} at byte {cstart} (expected a matrix)")


def _check_compressed(data: bytes, e: str, where: str, depth: int) -> None:
    d = zlib.decompressobj()
    try:
        inner = d.decompress(data, MAX_DECOMPRESSED)
    except zlib.error as exc:
        _fail(where, f"corrupted compressed element ({exc})")
    if d.unconsumed_tail:
        _fail(where, f"a compressed element expands to more than {MAX_DECOMPRESSED} bytes")
    _walk(inner, 0, len(inner), e, where, depth + 1, top=True)


def _int32(buf: bytes, cstart: int, nbytes: int, e: str) -> tuple[int, ...]:
    return struct.unpack(e + f"{nbytes // 4}i", buf[cstart : cstart + nbytes // 4 * 4])


def _check_matrix(buf: bytes, start: int, end: int, e: str, where: str, depth: int) -> None:
    """One ``miMATRIX``: flags, dimensions, name, then the parts its class requires."""
    if start == end:
        return  # empty matrix (e.g. an empty cell)
    if depth > MAX_DEPTH:
        _fail(where, f"elements nested more than {MAX_DEPTH} deep")
    els = _elements(buf, start, end, e, where, top=False)
    bad = f"matrix at byte {start}"
    if not els or els[0][0] != MI_UINT32 or els[0][2] != 8:
        _fail(where, f"{bad} does not start with array flags")
    flags = struct.unpack(e + "I", buf[els[0][1] : els[0][1] + 4])[0]
    mclass, is_complex = flags & 0xFF, bool(flags & 0x800)
    if mclass not in VALID_CLASSES:
        _fail(where, f"unknown array class {mclass} at byte {start}")
    if mclass == 17:  # opaque (classdef) object: names, then matrices
        for mtype, cstart, nbytes in els[1:]:
            if mtype == MI_MATRIX:
                _check_matrix(buf, cstart, cstart + nbytes, e, where, depth + 1)
        return
    if len(els) < 3 or els[1][0] != MI_INT32 or els[1][2] % 4 or els[1][2] < 8:
        _fail(where, f"{bad} has malformed dimensions")
    dims = _int32(buf, els[1][1], els[1][2], e)
    if any(d < 0 for d in dims):
        _fail(where, f"{bad} has a negative dimension {dims}")
    n = 1
    for d in dims:
        n *= d
    rest = els[3:]  # after flags, dims, name
    if 6 <= mclass <= 15 or mclass == 4:  # numeric or char: real (and imaginary) parts
        if len(rest) != 1 + is_complex:
            _fail(where, f"{bad} should hold {1 + is_complex} data part(s), has {len(rest)}")
        for mtype, _, nbytes in rest:
            if mtype not in _ITEMSIZE or mtype == MI_MATRIX:
                _fail(where, f"{bad} has data of type {mtype}")
            if mtype not in (16, 17, 18) and nbytes != n * _ITEMSIZE[mtype]:
                _fail(where, f"{bad}: {nbytes} data bytes for {n} values of type {mtype}")
        return
    if mclass == 5:  # sparse: ir, jc, pr (, pi)
        if len(rest) != 3 + is_complex or any(t not in _NUMERIC_DATA for t, _, _ in rest):
            _fail(where, f"{bad}: malformed sparse matrix")
        return
    if mclass in (2, 3):  # struct / object: [class name,] field-name length, names, values
        if mclass == 3:
            if not rest or rest[0][0] != 1:
                _fail(where, f"{bad}: object without a class name")
            rest = rest[1:]
        if len(rest) < 2 or rest[0][0] != MI_INT32 or rest[0][2] != 4 or rest[1][0] != 1:
            _fail(where, f"{bad}: malformed struct field names")
        (name_len,) = _int32(buf, rest[0][1], 4, e)
        if name_len <= 0 or rest[1][2] % name_len:
            _fail(where, f"{bad}: malformed struct field names")
        n_fields = rest[1][2] // name_len
        rest = rest[2:]
        if len(rest) != n_fields * n:
            _fail(where, f"{bad}: {len(rest)} field values for {n_fields} fields x {n}")
    elif mclass == 1 and len(rest) != n:  # cell
        _fail(where, f"{bad}: {len(rest)} cells for dimensions {dims}")
    for mtype, cstart, nbytes in rest:  # cells, field values, function handles
        if mtype != MI_MATRIX:
            _fail(where, f"{bad}: element of type {mtype} where a matrix was expected")
        _check_matrix(buf, cstart, cstart + nbytes, e, where, depth + 1)
