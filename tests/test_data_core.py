"""Datasets: records, builders, netCDF round trips, append, validation, model files."""

from __future__ import annotations

import errno
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from bifid.data import (
    ForcedRecord,
    LCORecord,
    append_record,
    combine_datasets,
    forced_dataset,
    forced_records,
    lco_dataset,
    lco_records,
    load_dataset,
    save_dataset,
    validate_dataset,
)
from bifid.errors import BifidInputError
from bifid.io import atomic_write_bytes, atomic_write_text, load_model, save_model
from bifid.signal import (
    estimate_frequency,
    fill_gaps,
    first_harmonic,
    periodic_amplitude,
    phase_lag,
)

FS = 1000.0
W = 2 * np.pi * 3.0  # 3 Hz


def _lco(param: float, n: int, amp: float = 1.0, stable: bool | None = True) -> LCORecord:
    t = np.arange(n) / FS
    sig = np.stack([amp * np.sin(W * t), 0.5 * amp * np.cos(W * t + 0.3)], axis=1)
    return LCORecord(
        param=param,
        signals=sig,
        sample_rate=FS,
        stable=stable,
        control=0.1 * np.sin(W * t),
        target=amp * np.sin(W * t),
        frequency=W,
        extra={"err": param / 10, "file": f"run{param}"},
    )


def _forced(omega: float, lag: float, n: int = 2000, curve: int = 0) -> ForcedRecord:
    t = np.arange(n) / FS
    return ForcedRecord(
        omega=omega,
        forcing=0.2,
        signals=np.cos(omega * t - lag)[:, None],
        sample_rate=FS,
        force=0.2 * np.cos(omega * t),
        curve=curve,
    )


def _lco_ds(n_records: int = 3) -> xr.Dataset:
    recs = [
        _lco(10.0 + i, 900 + 50 * i, amp=1.0 + i, stable=[True, False, None][i % 3])
        for i in range(n_records)
    ]
    return lco_dataset(
        recs,
        ["h", "alpha"],
        "U",
        "m/s",
        system="flutter",
        settings={"seed": 1, "arr": np.arange(3)},
        source="unit test",
        signal_units={"h": "m", "alpha": "rad"},
    )


# --------------------------------------------------------------------------- records


def test_record_validation_errors() -> None:
    good = np.zeros((10, 2))
    with pytest.raises(BifidInputError, match="sample_rate"):
        LCORecord(param=1.0, signals=good, sample_rate=0.0)
    with pytest.raises(BifidInputError, match="NaN"):
        LCORecord(param=1.0, signals=np.full((10, 2), np.nan), sample_rate=1.0)
    with pytest.raises(BifidInputError, match="param"):
        LCORecord(param=float("inf"), signals=good, sample_rate=1.0)
    with pytest.raises(BifidInputError, match="control"):
        LCORecord(param=1.0, signals=good, sample_rate=1.0, control=np.zeros(9))
    with pytest.raises(BifidInputError, match="shape"):
        LCORecord(param=1.0, signals=np.zeros((2, 3, 4)), sample_rate=1.0)
    with pytest.raises(BifidInputError, match="stable"):
        LCORecord(param=1.0, signals=good, sample_rate=1.0, stable="yes")  # type: ignore[arg-type]
    with pytest.raises(BifidInputError, match="curve"):
        ForcedRecord(omega=1.0, forcing=1.0, signals=good, sample_rate=1.0, curve=1.5)  # type: ignore[arg-type]
    with pytest.raises(BifidInputError, match="omega"):
        ForcedRecord(omega=-1.0, forcing=1.0, signals=good, sample_rate=1.0)
    # 1-D signals become one column; target may hold NaN (no target)
    r = LCORecord(param=1.0, signals=np.arange(5.0), sample_rate=2.0, target=[np.nan] * 5)
    assert r.signals.shape == (5, 1) and r.n_samples == 5
    np.testing.assert_allclose(r.time, [0, 0.5, 1.0, 1.5, 2.0])


def test_phase_lag_and_first_harmonic_analytic() -> None:
    t = np.arange(1234) / FS  # not a whole number of periods
    for lag in (-1.2, 0.0, 0.4, np.pi / 2, 2.9, 4.0):
        x = 0.7 * np.cos(W * t - lag) + 0.1 * np.cos(3 * W * t) + 0.05
        f = 2.0 * np.cos(W * t)
        expected = (lag + np.pi / 2) % (2 * np.pi) - np.pi / 2
        assert phase_lag(x, f, W, FS) == pytest.approx(expected, abs=1e-9)
        c = first_harmonic(x, W, FS)
        assert abs(c) == pytest.approx(0.7, rel=1e-9)
    assert math.isnan(phase_lag(np.zeros(100), np.cos(W * t[:100]), W, FS))


# --------------------------------------------------------------------------- builders


def test_lco_dataset_schema_and_derived_values() -> None:
    ds = _lco_ds()
    assert ds.attrs["bifid_kind"] == "lco"
    assert dict(ds.sizes) == {"record": 3, "time": 1000, "signal": 2}
    np.testing.assert_array_equal(ds["n_samples"].values, [900, 950, 1000])
    np.testing.assert_array_equal(ds["stable"].values, [1, 0, -1])
    assert ds["stable"].dtype == np.int8
    # NaN padding past n_samples, finite inside
    assert np.isnan(ds["signals"].values[0, 900:]).all()
    assert np.isfinite(ds["signals"].values[0, :900]).all()
    # amplitude = max |x| over the valid samples (independent computation)
    for i, r in enumerate(lco_records(ds)):
        np.testing.assert_allclose(ds["amplitude"].values[i], np.abs(r.signals).max(axis=0))
    # control_rms of 0.1 sin over whole periods of 3 Hz -> 0.1/sqrt(2); 900 samples = 2.7 s
    t = np.arange(1000) / FS
    expected = 0.1 * np.sqrt(np.mean(np.sin(W * t) ** 2))
    np.testing.assert_allclose(ds["control_rms"].values[2], expected)
    assert ds["param"].attrs == {"name": "U", "units": "m/s"}
    assert json.loads(ds.attrs["signal_units"]) == {"h": "m", "alpha": "rad"}
    assert json.loads(ds.attrs["settings"]) == {"seed": 1, "arr": [0, 1, 2]}
    np.testing.assert_allclose(ds["extra_err"].values, [1.0, 1.1, 1.2])


def test_forced_dataset_amplitude_and_phase() -> None:
    recs = [_forced(2 * np.pi * 5, lag) for lag in (0.1, 1.5, 3.0)]
    recs.append(
        ForcedRecord(
            omega=10.0,
            forcing=0.1,
            signals=np.ones((50, 1)),
            sample_rate=FS,
            amplitude=0.25,
            phase=1.0,
            curve=3,
        )
    )
    ds = forced_dataset(recs, ["x"], forcing_units="N")
    np.testing.assert_allclose(ds["phase"].values, [0.1, 1.5, 3.0, 1.0], atol=1e-9)
    # sampled max of cos: within 1 - cos(omega / (2 fs)) = 1.2e-4 of 1
    np.testing.assert_allclose(ds["amplitude"].values[:3], 1.0, atol=1.3e-4)
    assert ds["amplitude"].values[3] == 0.25
    assert np.isnan(ds["force"].values[3]).all()
    assert ds.attrs["observed"] == "x" and ds.attrs["forcing_units"] == "N"
    np.testing.assert_array_equal(ds["curve"].values, [0, 0, 0, 3])
    with pytest.raises(BifidInputError, match="observed"):
        forced_dataset(recs, ["x"], observed="y")


def test_builder_errors() -> None:
    with pytest.raises(BifidInputError, match="no records"):
        lco_dataset([], ["h"])
    with pytest.raises(BifidInputError, match="signal names"):
        lco_dataset([_lco(1.0, 100)], ["h"])
    with pytest.raises(BifidInputError, match="unique"):
        lco_dataset([_lco(1.0, 100)], ["h", "h"])
    with pytest.raises(BifidInputError, match="takes LCORecord"):
        lco_dataset([_forced(1.0, 0.0)], ["x"])
    with pytest.raises(BifidInputError, match="not a signal"):
        lco_dataset([_lco(1.0, 100)], ["h", "a"], signal_units={"q": "m"})


# --------------------------------------------------------------------------- file IO


def test_save_load_round_trip(tmp_path: Path) -> None:
    ds = _lco_ds()
    path = save_dataset(ds, tmp_path / "d.nc")
    back = load_dataset(path)
    for name in (
        "signals",
        "control",
        "target",
        "param",
        "amplitude",
        "frequency",
        "n_samples",
        "stable",
        "sample_rate",
        "control_rms",
        "extra_err",
    ):
        np.testing.assert_array_equal(back[name].values, ds[name].values)
    assert list(back["extra_file"].values) == ["run10.0", "run11.0", "run12.0"]
    assert back.attrs["source"] == "unit test"
    recs = lco_records(back)
    assert [r.stable for r in recs] == [True, False, None]
    assert recs[1].n_samples == 950 and recs[1].extra == {"err": 1.1, "file": "run11.0"}
    np.testing.assert_array_equal(recs[2].signals, lco_records(ds)[2].signals)


def test_forced_round_trip(tmp_path: Path) -> None:
    recs = [_forced(30.0, 0.5, n=300 + i, curve=i % 2) for i in range(4)]
    ds = forced_dataset(recs, ["x"])
    back = load_dataset(save_dataset(ds, tmp_path / "f.nc"))
    out = forced_records(back)
    assert [r.curve for r in out] == [0, 1, 0, 1]
    for a, b in zip(recs, out, strict=True):
        np.testing.assert_array_equal(a.signals, b.signals)
        np.testing.assert_array_equal(a.force, b.force)
        assert b.phase == pytest.approx(0.5, abs=1e-9)


def test_append_record(tmp_path: Path) -> None:
    path = tmp_path / "cbc.nc"
    with pytest.raises(BifidInputError, match="signal_names"):
        append_record(path, _lco(1.0, 100))
    assert not path.exists()
    for i in range(2):
        ds = append_record(
            path,
            _lco(1.0 + i, 100 + 10 * i),
            signal_names=["h", "alpha"],
            param_name="U",
            param_units="m/s",
            settings={"protocol": "ppcbc"},
        )
    np.testing.assert_array_equal(ds["param"].values, [1.0, 2.0])
    ds = load_dataset(path)
    np.testing.assert_array_equal(ds["param"].values, [1.0, 2.0])
    np.testing.assert_array_equal(ds["n_samples"].values, [100, 110])
    assert ds["param"].attrs["name"] == "U"
    assert json.loads(ds.attrs["settings"]) == {"protocol": "ppcbc"}
    before = path.read_bytes()
    with pytest.raises(BifidInputError, match="'lco' records"):
        append_record(path, _forced(1.0, 0.0))
    with pytest.raises(BifidInputError, match="signal_names"):
        append_record(path, _lco(4.0, 100), signal_names=["h", "theta"])
    with pytest.raises(BifidInputError, match="signals"):
        append_record(path, LCORecord(param=1.0, signals=np.zeros((5, 3)), sample_rate=1.0))
    assert path.read_bytes() == before  # refused appends leave the file untouched
    forced_path = tmp_path / "frc.nc"
    append_record(forced_path, _forced(20.0, 0.3), signal_names=["x"], forcing_units="N")
    append_record(forced_path, _forced(21.0, 0.6))
    fds = load_dataset(forced_path)
    np.testing.assert_allclose(fds["phase"].values, [0.3, 0.6], atol=1e-9)
    assert fds.attrs["forcing_units"] == "N"


def test_combine_datasets_offsets_curves() -> None:
    a = forced_dataset([_forced(10.0, 0.1, curve=0), _forced(11.0, 0.1, curve=1)], ["x"])
    b = forced_dataset([_forced(12.0, 0.1, curve=0)], ["x"])
    c = combine_datasets([a, b])
    np.testing.assert_array_equal(c["curve"].values, [0, 1, 2])
    with pytest.raises(BifidInputError, match="cannot combine"):
        combine_datasets([a, _lco_ds()])


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d.attrs.pop("bifid_kind"), "bifid_kind"),
        (lambda d: d.attrs.__setitem__("bifid_kind", "bogus"), "unknown bifid_kind"),
        (lambda d: d["n_samples"].values.__setitem__(0, 5000), "n_samples"),
        (lambda d: d["n_samples"].values.__setitem__(0, 0), "n_samples"),
        (lambda d: d["sample_rate"].values.__setitem__(1, 0.0), "sample_rate"),
        (lambda d: d["sample_rate"].values.__setitem__(1, np.nan), "sample_rate"),
        (lambda d: d["signals"].values.__setitem__((0, 3, 1), np.inf), "signals of record 0"),
        (lambda d: d["param"].values.__setitem__(2, np.nan), "param"),
        (lambda d: d["stable"].values.__setitem__(2, 7), "stable"),
        (lambda d: d.attrs.__setitem__("settings", "{not json"), "settings"),
        (lambda d: d.attrs.__setitem__("signal_units", "[1, 2]"), "signal_units"),
    ],
)
def test_validation_rejects(mutate, message: str) -> None:
    ds = _lco_ds().copy(deep=True)
    mutate(ds)
    with pytest.raises(BifidInputError, match=message):
        validate_dataset(ds)


def test_validation_structure() -> None:
    ds = _lco_ds()
    with pytest.raises(BifidInputError, match="'frequency' is missing"):
        validate_dataset(ds.drop_vars("frequency"))
    with pytest.raises(BifidInputError, match="dims"):
        validate_dataset(ds.assign(amplitude=(("signal", "record"), ds["amplitude"].values.T)))
    with pytest.raises(BifidInputError, match="no records"):
        validate_dataset(ds.isel(record=slice(0, 0)))
    with pytest.raises(BifidInputError, match=r"xarray\.Dataset"):
        validate_dataset({"a": 1})  # type: ignore[arg-type]
    # samples past n_samples are normalised to NaN whatever the file held
    bad = ds.copy(deep=True)
    bad["signals"].values[0, 950:] = 123.0
    assert np.isnan(validate_dataset(bad)["signals"].values[0, 950:]).all()


def test_load_dataset_errors(tmp_path: Path) -> None:
    with pytest.raises(BifidInputError, match="does not exist"):
        load_dataset(tmp_path / "missing.nc")
    (tmp_path / "text.nc").write_text("hello")
    with pytest.raises(BifidInputError, match="not a readable netCDF"):
        load_dataset(tmp_path / "text.nc")
    with pytest.raises(BifidInputError, match="not a file"):
        load_dataset(tmp_path)
    # a valid netCDF file that is not a bifid dataset
    xr.Dataset({"a": ("x", np.arange(3.0))}).to_netcdf(tmp_path / "plain.nc", engine="h5netcdf")
    with pytest.raises(BifidInputError, match="not a bifid dataset"):
        load_dataset(tmp_path / "plain.nc")


# --------------------------------------------------------------------------- atomic writes


def _leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.endswith(".tmp"))


def test_save_dataset_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "d.nc"
    save_dataset(_lco_ds(2), path)
    before = path.read_bytes()

    def disk_full(fd):  # the bytes were handed to the kernel; the disk refuses them
        raise OSError(errno.ENOSPC, "disk full")

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(OSError, match="disk full"):
        save_dataset(_lco_ds(3), path)
    assert path.read_bytes() == before  # old file intact
    assert _leftovers(tmp_path) == []  # no temporary file left
    new = tmp_path / "new.nc"
    with pytest.raises(OSError, match="disk full"):
        save_dataset(_lco_ds(3), new)
    assert not new.exists() and _leftovers(tmp_path) == []


def test_atomic_write_interrupted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "f.txt"
    atomic_write_text(path, "old")

    def interrupted(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        atomic_write_bytes(path, b"new content")
    assert path.read_text() == "old" and _leftovers(tmp_path) == []
    monkeypatch.undo()
    with pytest.raises(BifidInputError, match="does not exist"):
        atomic_write_text(tmp_path / "nodir" / "f.txt", "x")


def test_append_record_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "cbc.nc"
    append_record(path, _lco(1.0, 100), signal_names=["h", "alpha"])
    before = path.read_bytes()

    def boom(fd):  # killed between writing the bytes and syncing them
        raise RuntimeError("killed")

    monkeypatch.setattr(os, "fsync", boom)
    with pytest.raises(RuntimeError):
        append_record(path, _lco(2.0, 100))
    monkeypatch.undo()
    assert path.read_bytes() == before and _leftovers(tmp_path) == []
    assert load_dataset(path).sizes["record"] == 1


# --------------------------------------------------------------------------- model files


def test_model_round_trip(tmp_path: Path) -> None:
    arrays = {
        "w": np.linspace(0, 1, 7),
        "k": np.eye(3),
        "flags": np.array([True, False]),
        "z": np.array([1 + 2j]),
    }
    d = save_model(
        tmp_path / "m",
        "hopf_hybrid",
        {"mu0": np.float64(17.9), "n": 3, "names": ("a", "b"), "bad": float("nan")},
        arrays,
        settings={"data": ["a.nc"]},
    )
    meta, back = load_model(d)
    assert meta["type"] == "hopf_hybrid"
    assert meta["params"]["mu0"] == 17.9 and meta["params"]["names"] == ["a", "b"]
    assert math.isnan(meta["params"]["bad"])
    assert meta["settings"] == {"data": ["a.nc"]}
    assert "numpy" in meta["versions"]
    for k, v in arrays.items():
        np.testing.assert_array_equal(back[k], v)
    with pytest.raises(BifidInputError, match="object"):
        save_model(tmp_path / "m2", "x", {}, {"o": np.array([{"a": 1}], dtype=object)})


def test_pickle_bearing_model_refused(tmp_path: Path) -> None:
    d = save_model(tmp_path / "m", "kernel", {"a": 1}, {"w": np.ones(3)})
    meta = json.loads((d / "model.json").read_text())
    # an npz holding an object array (which np.savez pickles)
    np.savez(d / "arrays.npz", w=np.array([{"evil": 1}, None], dtype=object))
    import hashlib

    meta["arrays"]["sha256"] = hashlib.sha256((d / "arrays.npz").read_bytes()).hexdigest()
    (d / "model.json").write_text(json.dumps(meta))
    with pytest.raises(BifidInputError, match="pickle"):
        load_model(d)
    # a raw pickle in place of the npz
    import pickle

    blob = pickle.dumps({"w": np.ones(3)})
    (d / "arrays.npz").write_bytes(blob)
    meta["arrays"]["sha256"] = hashlib.sha256(blob).hexdigest()
    (d / "model.json").write_text(json.dumps(meta))
    with pytest.raises(BifidInputError, match=r"not an \.npz archive"):
        load_model(d)


def test_model_tampering_and_malformed(tmp_path: Path) -> None:
    d = save_model(tmp_path / "m", "kernel", {"a": 1}, {"w": np.ones(3)})
    np.savez(d / "arrays.npz", w=np.zeros(3))
    with pytest.raises(BifidInputError, match="checksum"):
        load_model(d)
    (d / "model.json").write_text("[1, 2]")
    with pytest.raises(BifidInputError, match="JSON object"):
        load_model(d)
    (d / "model.json").write_text("{broken")
    with pytest.raises(BifidInputError, match="not valid JSON"):
        load_model(d)
    (d / "model.json").write_text(
        json.dumps({"format": "bifid-model", "format_version": 99, "type": "x"})
    )
    with pytest.raises(BifidInputError, match="format_version"):
        load_model(d)
    with pytest.raises(BifidInputError, match="not a directory"):
        load_model(tmp_path / "nothing")


# --------------------------------------------------------------------------- signal helpers


def test_signal_helpers_against_analytic_values() -> None:
    fs = 5000.0
    w = 2 * np.pi * 2.45
    t = np.arange(20000) / fs
    x = 0.03 * np.sin(w * t + 0.2) + 0.01 * np.sin(3 * w * t) + 0.7
    # frequency: spectral peak refined to better than 0.2 % for a 4 s record
    assert estimate_frequency(x, fs) == pytest.approx(w, rel=2e-3)
    # periodic amplitude: max over a fine grid of the exact signal
    theta = np.linspace(0, 2 * np.pi, 100000)
    exact = np.max(np.abs(0.03 * np.sin(theta + 0.2) + 0.01 * np.sin(3 * theta)))
    amp, mean = periodic_amplitude(x, w, fs, n_harmonics=5, trim=False)
    assert amp == pytest.approx(exact, rel=1e-4) and mean == pytest.approx(0.7, abs=1e-9)
    # gap filling: short runs by interpolation, long runs by the Fourier series
    bad = np.zeros(t.shape, bool)
    bad[100:110] = True  # short
    bad[5000:5400] = True  # long (0.08 s)
    bad[:3] = True  # at the start
    corrupted = np.where(bad, 6.2832, x)
    filled, longest = fill_gaps(corrupted, bad, w, fs)
    assert longest == 400
    np.testing.assert_allclose(filled, x, atol=2e-5)
    with pytest.raises(BifidInputError, match="too many"):
        fill_gaps(x, np.ones(t.shape, bool), w, fs)


# --------------------------------------------------------------------------- MAT framing


def test_mat_structure_check_rejects_what_crashes_scipy(tmp_path: Path) -> None:
    """Corrupted element tags made scipy's MAT reader segfault (found by fuzzing);
    bifid checks the element tree first and raises BifidInputError instead."""
    import io

    import scipy.io

    from bifid.data import load_mat

    buf = io.BytesIO()
    scipy.io.savemat(buf, {"a": 1.0})
    good = buf.getvalue()
    # layout: header 0-127 | matrix tag 128 | flags tag 136, flags 144 | dims 152-167 |
    # name (small element) 168 | data tag 176 (miDOUBLE = 9), value 184
    assert good[176] == 9
    cases = {
        "unknown data type 22": good[:176] + bytes([22]) + good[177:],
        "should hold 2 data part": good[:145] + bytes([good[145] | 0x08]) + good[146:],
        "claims": good[:180],
        "no MAT v5 header": good[:126] + b"XX" + good[128:],
        "shorter than the 128-byte header": good[:100],
        "malformed dimensions": good[:152] + bytes([7]) + good[153:],
    }
    for message, blob in cases.items():
        path = tmp_path / "bad.mat"
        path.write_bytes(blob)
        with pytest.raises(BifidInputError, match=message):
            load_mat(path)
    path.write_bytes(good)
    assert load_mat(path)["a"] == 1.0
