"""Records appended to a dataset file: the file equals the dataset built from all records,
the records already written are not rewritten, and files of other layouts still append.

A CBC campaign saves its file after every point (:func:`bifid.data.append_records`); these
checks hold the appended file to the dataset that :func:`bifid.data.lco_dataset` /
:func:`bifid.data.forced_dataset` build from the same records, written whole.
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest

from bifid.data import (
    ForcedRecord,
    LCORecord,
    append_records,
    forced_dataset,
    lco_dataset,
    load_dataset,
    save_dataset,
)
from bifid.errors import BifidInputError

KW = dict(signal_names=["h", "alpha"], param_name="U", param_units="m/s")


def _lco(i: int, n: int, extra: dict) -> LCORecord:
    rng = np.random.default_rng(i)
    return LCORecord(
        param=10.0 + i,
        signals=rng.standard_normal((n, 2)),
        sample_rate=100.0,
        stable=bool(i % 2),
        control=rng.standard_normal(n),
        target=rng.standard_normal(n) if i % 3 else None,
        frequency=2.0 + 0.1 * i,
        extra=extra,
    )


def _same(path: Path, expected, tmp_path: Path) -> None:
    """The file at ``path`` loads as ``expected`` written whole: same sizes, variables,
    values (bit for bit), attributes of the variables and of the dataset."""
    ref = tmp_path / "whole.nc"
    save_dataset(expected, ref)
    a, b = load_dataset(path), load_dataset(ref)
    assert dict(a.sizes) == dict(b.sizes)
    assert set(a.variables) == set(b.variables)
    for v in b.variables:
        x, y = a[v].values, b[v].values
        assert x.dtype.kind == y.dtype.kind, v
        if x.dtype.kind == "f":
            np.testing.assert_array_equal(x, y, err_msg=v)
        else:
            assert np.array_equal(x, y), v
        assert a[v].attrs == b[v].attrs, v
    for k in set(a.attrs) | set(b.attrs):
        if k not in ("created", "modified"):
            assert a.attrs.get(k) == b.attrs.get(k), k


def test_appended_records_equal_the_whole_dataset(tmp_path: Path) -> None:
    """Check records of growing and shrinking lengths, string and numeric extras and an
    extra that later records lack, appended one at a time, and a state attribute that
    changes at every append (as a campaign's checkpoint does)."""
    lengths = [120, 40, 3000, 9000, 15]
    recs = [
        _lco(i, n, {"iterations": i, "note": f"p{i}", **({"first": 1.5} if i == 0 else {})})
        for i, n in enumerate(lengths)
    ]
    path = tmp_path / "c.nc"
    for i, r in enumerate(recs):
        assert append_records(path, [r], attrs={"state": f"s{i}"}, **KW) == i + 1
        if i in (3, 4):  # after the longest record (time grew), then a short one
            _same(path, lco_dataset(recs[: i + 1], **KW, attrs={"state": f"s{i}"}), tmp_path)
    assert append_records(path, [], attrs={"state": "done"}) == len(recs)
    assert load_dataset(path).attrs["state"] == "done"
    # drop the last two and append another: as if built from the three kept and the new one
    new = _lco(7, 500, {"iterations": 7, "note": "p7"})
    assert append_records(path, [new], keep=3, attrs={"state": "k"}) == 4
    _same(path, lco_dataset([*recs[:3], new], **KW, attrs={"state": "k"}), tmp_path)
    with pytest.raises(BifidInputError, match="keep"):
        append_records(path, [new], keep=9)


def test_forced_records_append(tmp_path: Path) -> None:
    """Check a forced dataset (force series, curves, phases from the force) appends as it
    is built whole."""
    recs = [
        ForcedRecord(
            omega=1.0 + 0.1 * i,
            forcing=0.5,
            signals=np.sin((1.0 + 0.1 * i) * np.arange(n)[:, None] / 50.0 - 0.3),
            sample_rate=50.0,
            force=np.sin((1.0 + 0.1 * i) * np.arange(n) / 50.0),
            curve=i % 2,
            extra={"q": float(i)},
        )
        for i, n in enumerate([400, 1500, 700])
    ]
    path = tmp_path / "f.nc"
    for r in recs:
        append_records(path, [r], signal_names=["x"], forcing_units="N")
    _same(path, forced_dataset(recs, signal_names=["x"], forcing_units="N"), tmp_path)


def test_written_records_are_not_rewritten(tmp_path: Path) -> None:
    """Check an append leaves the stored samples of earlier records as they are on disk: a
    value planted in record 0's padding (which a rebuilt dataset would reset to NaN)
    survives the append."""
    path = tmp_path / "c.nc"
    recs = [_lco(0, 50, {}), _lco(1, 200, {})]
    save_dataset(lco_dataset(recs, **KW), path)
    with h5py.File(path, "r+") as h:
        h["signals"][0, 100, 0] = 123.0  # beyond record 0's 50 samples
    append_records(path, [_lco(2, 300, {})])
    with h5py.File(path, "r") as h:
        assert h["signals"][0, 100, 0] == 123.0
        assert h["signals"].shape == (3, 300, 2)
    assert np.isnan(load_dataset(path)["signals"].values[0, 100, 0])  # readers see padding


def test_file_of_fixed_dimensions_appends(tmp_path: Path) -> None:
    """Check a file written with fixed netCDF dimensions (by xarray directly, as earlier
    versions did) takes appended records, with the same result."""
    path = tmp_path / "old.nc"
    recs = [_lco(i, 80 + 40 * i, {"iterations": i}) for i in range(3)]
    lco_dataset(recs[:2], **KW).to_netcdf(path, engine="h5netcdf")
    append_records(path, [recs[2]])
    _same(path, lco_dataset(recs, **KW), tmp_path)
    append_records(path, [recs[0]])  # now of the extendable layout
    _same(path, lco_dataset([*recs, recs[0]], **KW), tmp_path)
