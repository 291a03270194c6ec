"""CSV schema: reading the documented example, round trips, and clear errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bifid.data import (
    ForcedRecord,
    LCORecord,
    forced_dataset,
    forced_records,
    import_files,
    lco_dataset,
    lco_records,
    read_csv_dataset,
    write_csv,
)
from bifid.errors import BifidInputError

EXAMPLE = """\
# bifid-csv 1
# param_name: U
# units: param=m/s, h=m, alpha=rad, control=V, time=s
# source: flutter rig, run 12
record,param,stable,time,h,alpha,control
a,14.9,1,0.000,0.010,0.020,0.1
a,14.9,1,0.001,0.011,0.019,0.1
a,14.9,1,0.002,0.012,0.018,0.1
b,15.7,0,0.000,-0.005,0.010,0.0
b,15.7,0,0.001,-0.004,0.011,0.0
"""


def _write(tmp_path: Path, text: str, name: str = "d.csv") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_documented_example(tmp_path: Path) -> None:
    ds = read_csv_dataset(_write(tmp_path, EXAMPLE))
    assert ds.attrs["bifid_kind"] == "lco"
    assert [str(s) for s in ds["signal"].values] == ["h", "alpha"]
    np.testing.assert_array_equal(ds["param"].values, [14.9, 15.7])
    np.testing.assert_array_equal(ds["stable"].values, [1, 0])
    np.testing.assert_array_equal(ds["n_samples"].values, [3, 2])
    np.testing.assert_allclose(ds["sample_rate"].values, [1000.0, 1000.0])
    np.testing.assert_allclose(ds["signals"].values[0, :, 0], [0.010, 0.011, 0.012])
    np.testing.assert_allclose(ds["control_rms"].values, [0.1, 0.0])
    assert ds["param"].attrs == {"name": "U", "units": "m/s"}
    assert json.loads(ds.attrs["signal_units"]) == {"h": "m", "alpha": "rad"}
    assert ds.attrs["control_units"] == "V" and ds.attrs["source"] == "flutter rig, run 12"
    assert list(ds["extra_record_id"].values) == ["a", "b"]
    # no target column: NaN target
    assert np.isnan(ds["target"].values).all()


def test_lco_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    recs = [
        LCORecord(
            param=10 + i,
            signals=rng.normal(size=(50 + 7 * i, 2)),
            sample_rate=200.0,
            stable=[True, False, None][i],
            control=rng.normal(size=50 + 7 * i),
            target=rng.normal(size=50 + 7 * i),
            frequency=3.0 + i,
        )
        for i in range(3)
    ]
    ds = lco_dataset(recs, ["h", "alpha"], "U", "m/s", signal_units={"h": "m"})
    back = read_csv_dataset(write_csv(ds, tmp_path / "x.csv"))
    for a, b in zip(lco_records(ds), lco_records(back), strict=True):
        np.testing.assert_array_equal(a.signals, b.signals)  # repr() round-trips floats
        np.testing.assert_array_equal(a.control, b.control)
        np.testing.assert_array_equal(a.target, b.target)
        assert (a.param, a.stable, a.frequency) == (b.param, b.stable, b.frequency)
        assert a.sample_rate == pytest.approx(b.sample_rate, rel=1e-12)
    assert back["param"].attrs == {"name": "U", "units": "m/s"}


def test_forced_round_trip(tmp_path: Path) -> None:
    t = np.arange(400) / 1000.0
    recs = [
        ForcedRecord(
            omega=60.0,
            forcing=0.1 * (i + 1),
            sample_rate=1000.0,
            signals=np.stack([np.cos(60 * t - 0.4 * i), np.sin(60 * t)], axis=1),
            force=np.cos(60 * t),
            curve=i // 2,
        )
        for i in range(4)
    ]
    ds = forced_dataset(recs, ["x1", "x2"], observed="x1", forcing_units="N")
    back = read_csv_dataset(write_csv(ds, tmp_path / "f.csv"))
    assert back.attrs["observed"] == "x1" and back.attrs["forcing_units"] == "N"
    for a, b in zip(forced_records(ds), forced_records(back), strict=True):
        np.testing.assert_array_equal(a.signals, b.signals)
        np.testing.assert_array_equal(a.force, b.force)
        assert (a.omega, a.forcing, a.curve, a.amplitude, a.phase) == (
            b.omega,
            b.forcing,
            b.curve,
            b.amplitude,
            b.phase,
        )


def test_frequency_estimated_when_absent(tmp_path: Path) -> None:
    fs, f = 500.0, 2.5
    t = np.arange(2000) / fs
    rows = "\n".join(f"0,1.0,,{float(ti)!r},{float(np.sin(2 * np.pi * f * ti))!r}" for ti in t)
    ds = import_files([_write(tmp_path, "record,param,stable,time,h\n" + rows + "\n")])
    assert ds["frequency"].values[0] == pytest.approx(2 * np.pi * f, rel=2e-3)
    assert ds["extra_frequency_estimated"].values[0] == 1.0
    assert ds["stable"].values[0] == -1  # empty -> unknown


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "no header row"),
        ("# only a comment\n", "no header row"),
        ("record,param,stable,time,h\n", "no data rows"),
        ("record,stable,time,h\n0,1,0,1\n", "cannot tell the dataset kind"),
        ("record,param,omega,forcing,stable,time,h\n", "cannot be mixed"),
        ("record,param,stable,h\n0,1,1,2\n", "missing column"),
        ("record,param,stable,time\n0,1,1,0\n", "no signal columns"),
        ("record,param,stable,time,h,h\n", "unique"),
        ("record,param,stable,time,h\n0,1,1,0,1\n0,1,1,1\n", "line 3: 4 fields"),
        ("record,param,stable,time,h\n0,1,1,0,abc\n0,1,1,1,2\n", "line 2: column 'h'"),
        ("record,param,stable,time,h\n0,1,1,0,1\n0,2,1,1,2\n", "changes within record"),
        ("record,param,stable,time,h\n0,1,1,0,1\n0,1,1,1,2\n0,1,1,3,2\n", "uniformly"),
        ("record,param,stable,time,h\n0,1,1,0,1\n0,1,1,0,2\n", "increase strictly"),
        ("record,param,stable,time,h\n0,1,1,0,1\n", "at least 2 samples"),
        ("record,param,stable,time,h\n0,1,2,0,1\n0,1,2,1,1\n", "stable must be"),
        ("record,param,stable,time,h\n0,1,1,0,nan\n0,1,1,1,1\n", "line 2: .* finite"),
        ("record,param,stable,time,h\n0,inf,1,0,1\n0,inf,1,1,1\n", "param"),
        ("record,param,stable,time,h\n,1,1,0,1\n", "empty record id"),
        ("record,param,stable,time,force,h\n0,1,1,0,1,1\n", "do not belong"),
        ("# units: h\nrecord,param,stable,time,h\n0,1,1,0,1\n0,1,1,1,1\n", "NAME=UNIT"),
    ],
)
def test_csv_errors(tmp_path: Path, text: str, message: str) -> None:
    with pytest.raises(BifidInputError, match=message):
        read_csv_dataset(_write(tmp_path, text))


def test_csv_binary_and_encoding(tmp_path: Path) -> None:
    p = tmp_path / "bin.csv"
    p.write_bytes(b"record,param\x00\x01\x02")
    with pytest.raises(BifidInputError, match="binary"):
        read_csv_dataset(p)
    p.write_bytes(b"record,param,stable,time,h\n" + b"\xff\xfe,1,1,0,1\n")
    with pytest.raises(BifidInputError, match="UTF-8"):
        read_csv_dataset(p)
    with pytest.raises(BifidInputError, match="does not exist"):
        read_csv_dataset(tmp_path / "missing.csv")
