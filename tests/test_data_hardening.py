"""Property-based hardening of every reader: hostile, malformed and truncated inputs.

Each property feeds generated bad inputs to the readers and requires one of two outcomes:
a valid result, or :class:`BifidInputError` (never another exception type, never a
crash), with the input file unchanged (hash compared before and after). The number of
generated inputs tried is counted per property and printed by the last test (run with
``-s`` to see it, or ``--hypothesis-show-statistics``).
"""

from __future__ import annotations

import collections
import hashlib
import io
import itertools
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import scipy.io
import xarray as xr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bifid.data import (
    KINDS,
    LCORecord,
    detect_format,
    forced_dataset,
    import_files,
    lco_dataset,
    load_dataset,
    load_free_decay,
    load_open_loop,
    load_thesis_curves,
    load_ulco_amplitudes,
    read_csv_dataset,
    read_em_curve,
    read_flutter_cbc,
    save_dataset,
    validate_dataset,
)
from bifid.data import ForcedRecord as FR
from bifid.errors import BifidInputError
from bifid.io import load_model, save_model

TRIED: collections.Counter[str] = collections.Counter()
FOUND: collections.Counter[str] = collections.Counter()  # outcome kinds per property
_ids = itertools.count()

# BIFID_HARDENING_EXAMPLES scales every property (default 50) for long offline fuzzing runs
_N = int(os.environ.get("BIFID_HARDENING_EXAMPLES", "50"))
_CHECKS = [HealthCheck.too_slow, HealthCheck.data_too_large]
FAST = settings(max_examples=_N, deadline=None, suppress_health_check=_CHECKS)
SLOW = settings(max_examples=max(1, _N // 4), deadline=None, suppress_health_check=_CHECKS)
MEDIUM = settings(max_examples=max(1, 4 * _N // 5), deadline=None, suppress_health_check=_CHECKS)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _outcome(prop: str, fn: Any, *args: Any) -> Any:
    """Run a reader; only a result or BifidInputError is acceptable. Count outcomes."""
    TRIED[prop] += 1
    try:
        out = fn(*args)
    except BifidInputError as exc:
        assert str(exc).strip(), "error messages must not be empty"
        FOUND[f"{prop}: BifidInputError"] += 1
        return None
    FOUND[f"{prop}: accepted"] += 1
    return out


@pytest.fixture(scope="module")
def work(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("hostile")


def _valid_lco() -> xr.Dataset:
    t = np.arange(64) / 100.0
    sig = np.stack([np.sin(3 * t), np.cos(3 * t)], 1)
    recs = [
        LCORecord(
            param=1.0 + i,
            signals=sig[: 40 + 8 * i],
            sample_rate=100.0,
            stable=bool(i % 2),
            frequency=3.0,
            control=0.1 * np.ones(40 + 8 * i),
            extra={"e": float(i), "f": "s"},
        )
        for i in range(3)
    ]
    return lco_dataset(recs, ["h", "alpha"], "U", "m/s", source="hardening")


def _valid_forced() -> xr.Dataset:
    t = np.arange(50) / 100.0
    recs = [
        FR(
            omega=6.0,
            forcing=0.1 * (i + 1),
            signals=np.cos(6 * t - i)[:, None],
            sample_rate=100.0,
            force=np.cos(6 * t),
            curve=i,
        )
        for i in range(2)
    ]
    return forced_dataset(recs, ["x"])


@pytest.fixture(scope="module")
def valid_nc(work: Path) -> bytes:
    return save_dataset(_valid_lco(), work / "valid.nc").read_bytes()


# ---------------------------------------------------------------------------------------------
# 1. arbitrary bytes to every reader
# ---------------------------------------------------------------------------------------------

_PREFIXES = [
    b"",
    b"\x89HDF\r\n\x1a\n",
    b"MATLAB 5.0 MAT-file, Platform: GLNXA64" + b" " * 86,
    b"record,param,stable,time,h\n",
    b"\x93NUMPY",
    b"PK\x03\x04",
    b"\x80\x04\x95",
]
_READERS = [
    load_dataset,
    read_flutter_cbc,
    load_free_decay,
    load_open_loop,
    load_ulco_amplitudes,
    read_csv_dataset,
    load_thesis_curves,
    detect_format,
    lambda p: read_em_curve(p),
    lambda p: import_files([p]),
]


@FAST
@given(
    prefix=st.sampled_from(_PREFIXES),
    body=st.binary(max_size=2048),
    suffix=st.sampled_from([".nc", ".mat", ".csv", ".txt", ""]),
)
def test_random_bytes_every_reader(work: Path, prefix: bytes, body: bytes, suffix: str) -> None:
    path = work / f"rand{next(_ids)}{suffix}"
    path.write_bytes(prefix + body)
    before = _sha(path)
    for reader in _READERS:
        _outcome("random bytes x readers", reader, path)
    assert _sha(path) == before


# ---------------------------------------------------------------------------------------------
# 2. truncated / bit-flipped netCDF
# ---------------------------------------------------------------------------------------------


@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")  # h5netcdf __del__
@MEDIUM
@given(data=st.data())
def test_corrupted_netcdf(work: Path, valid_nc: bytes, data: st.DataObject) -> None:
    blob = bytearray(valid_nc)
    if data.draw(st.booleans(), label="truncate"):
        cut = data.draw(st.integers(0, len(blob) - 1), label="cut")
        blob = blob[:cut]
    else:
        for _ in range(data.draw(st.integers(1, 8), label="n_flips")):
            i = data.draw(st.integers(0, len(blob) - 1), label="pos")
            blob[i] = data.draw(st.integers(0, 255), label="byte")
    path = work / f"corrupt{next(_ids)}.nc"
    path.write_bytes(bytes(blob))
    before = _sha(path)
    ds = _outcome("corrupted netCDF", load_dataset, path)
    if ds is not None:
        validate_dataset(ds)  # whatever loads is a valid dataset
    assert _sha(path) == before


# ---------------------------------------------------------------------------------------------
# 3. structurally wrong datasets (in memory, and a few through files)
# ---------------------------------------------------------------------------------------------

_NUMERIC = [
    "n_samples",
    "sample_rate",
    "stable",
    "signals",
    "control",
    "target",
    "control_rms",
    "param",
    "frequency",
    "amplitude",
]
_BAD_VALUES = [np.nan, np.inf, -np.inf, -1.0, 0.0, 1e308, 1e9, 0.5, -7.0]


def _mutate(ds: xr.Dataset, data: st.DataObject) -> tuple[xr.Dataset, bool]:
    """Apply one random mutation; return the dataset and whether it MUST be rejected."""
    ds = ds.copy(deep=True)
    kind = data.draw(
        st.sampled_from(
            [
                "drop_var",
                "bad_value",
                "kind_attr",
                "drop_attr",
                "json_attr",
                "transpose",
                "empty",
                "string_var",
                "n_samples",
                "rename_dim",
            ]
        ),
        label="mutation",
    )
    must_fail = False
    if kind == "drop_var":
        name = data.draw(st.sampled_from([*_NUMERIC, "signal"]), label="var")
        ds = ds.drop_vars(name)
        must_fail = True
    elif kind == "bad_value":
        name = data.draw(st.sampled_from(_NUMERIC), label="var")
        arr = ds[name].values.astype(float)
        idx = tuple(data.draw(st.integers(0, s - 1)) for s in arr.shape)
        value = data.draw(st.sampled_from(_BAD_VALUES), label="value")
        arr[idx] = value
        ds[name] = (ds[name].dims, arr)
        n = int(ds["n_samples"].values[idx[0]]) if name != "n_samples" else None
        inside = name in ("signals", "control") and n is not None and idx[1] < n
        must_fail = (
            not np.isfinite(value)
            and (
                inside
                or name
                in ("sample_rate", "param", "control_rms", "amplitude", "n_samples", "stable")
            )
        ) or (name == "sample_rate" and value <= 0)
    elif kind == "kind_attr":
        value = data.draw(
            st.text(max_size=12)
            | st.sampled_from([np.array([1, 2]), np.array(["lco", "lco"]), 3, 1.5]),
            label="kind",
        )
        ds.attrs["bifid_kind"] = value
        must_fail = not isinstance(value, str) or value not in KINDS or value == "forced"
        if "observed" in ds.attrs and data.draw(st.booleans(), label="observed too"):
            ds.attrs["observed"] = np.array(["x", "y"])
            must_fail = True
    elif kind == "drop_attr":
        ds.attrs.pop("bifid_kind")
        must_fail = True
    elif kind == "json_attr":
        ds.attrs[data.draw(st.sampled_from(["settings", "signal_units"]))] = data.draw(
            st.text(max_size=20), label="json"
        )
    elif kind == "transpose":
        ds["amplitude"] = (("signal", "record"), ds["amplitude"].values.T)
        must_fail = True
    elif kind == "empty":
        ds = ds.isel(record=slice(0, 0))
        must_fail = True
    elif kind == "string_var":
        name = data.draw(st.sampled_from(["param", "sample_rate", "frequency"]), label="var")
        ds[name] = ("record", np.array(["a"] * ds.sizes["record"], dtype=object))
        must_fail = True
    elif kind == "n_samples":
        v = data.draw(st.integers(-3, 200), label="n")
        arr = ds["n_samples"].values.copy()
        arr[0] = v
        ds["n_samples"] = ("record", arr)
        must_fail = v < 1 or v > ds.sizes["time"]
        if not must_fail and v > 40:  # now covers NaN padding of record 0
            must_fail = True
    elif kind == "rename_dim":
        ds = ds.rename_dims({"time": "t"})
        must_fail = True
    return ds, must_fail


@FAST
@given(data=st.data(), forced=st.booleans())
def test_structural_mutations_in_memory(data: st.DataObject, forced: bool) -> None:
    base = _valid_forced() if forced else _valid_lco()
    try:
        ds, must_fail = _mutate(base, data)
    except (KeyError, ValueError, IndexError):
        TRIED["structural (setup not applicable)"] += 1
        return  # the mutation does not apply to this kind (e.g. a variable it lacks)
    out = _outcome("structural mutations (memory)", validate_dataset, ds)
    if must_fail and not forced:
        assert out is None, "a dataset that breaks the schema was accepted"


@SLOW
@given(data=st.data())
def test_structural_mutations_through_files(work: Path, data: st.DataObject) -> None:
    ds, must_fail = _mutate(_valid_lco(), data)
    path = work / f"mut{next(_ids)}.nc"
    try:
        ds.to_netcdf(path, engine="h5netcdf")  # raw write, no validation
    except Exception:
        TRIED["structural (unwritable)"] += 1
        return
    before = _sha(path)
    out = _outcome("structural mutations (files)", load_dataset, path)
    if must_fail:
        assert out is None
    assert _sha(path) == before


# ---------------------------------------------------------------------------------------------
# 4. hostile MATLAB files
# ---------------------------------------------------------------------------------------------

_MAT_VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=5),
    st.just(np.array([])),
    st.just(np.full((5, 4), np.nan)),
    st.just(np.zeros((2, 3, 4))),
    st.just(np.ones(7)),
    st.just(np.full((5, 300), 6.2832)),
    st.just({"a": 1.0}),
)


def _cbc_dict(n: int = 300) -> dict[str, Any]:
    t = np.arange(n) / 5000.0
    w = 2 * np.pi * 2.45
    data = np.stack(
        [
            3.37 + 0.1 * np.sin(w * t),
            3.37 + 0.1 * np.sin(w * t),
            0.01 * np.cos(w * t),
            0.71 + 0.05 * np.sin(w * t + 1),
            np.full(n, 3.37),
        ]
    )
    return {
        "data": data,
        "Wind_sped": 15.0,
        "freq_actual": 2.45,
        "amplitude": 0.1,
        "error1": 0.01,
        "exp": {"par": {"sample_freq": 5000}},
    }


@FAST
@given(data=st.data())
def test_hostile_flutter_mat(work: Path, data: st.DataObject) -> None:
    m = _cbc_dict()
    for _ in range(data.draw(st.integers(1, 3), label="n_mutations")):
        key = data.draw(st.sampled_from(["data", "Wind_sped", "freq_actual", "exp", "amplitude"]))
        if data.draw(st.booleans(), label="delete"):
            m.pop(key, None)
        else:
            m[key] = data.draw(_MAT_VALUES, label="value")
    if "data" in m and isinstance(m["data"], np.ndarray) and m["data"].shape == (5, 300):
        frac = data.draw(st.floats(0, 1), label="wrapped fraction")
        m["data"][3, : int(frac * 300)] = 6.2832
    name = data.draw(st.sampled_from(["CBC_stable_v1.mat", "CBC_v2.mat", "other.mat"]))
    path = work / f"{next(_ids)}_{name}"
    try:
        scipy.io.savemat(path, m)
    except Exception:
        TRIED["flutter mat (unwritable)"] += 1
        return
    before = _sha(path)
    rec = _outcome("hostile flutter MAT", read_flutter_cbc, path)
    if rec is not None:
        assert np.all(np.isfinite(rec.signals)) and rec.sample_rate > 0
        assert np.max(np.abs(rec.signals[:, 1])) < 1.0  # wraps never reach the signals
    _outcome("hostile flutter MAT (import)", lambda p: import_files([p]), path)
    assert _sha(path) == before


@MEDIUM
@given(data=st.data(), compress=st.booleans())
def test_corrupted_mat(work: Path, data: st.DataObject, compress: bool) -> None:
    buf = io.BytesIO()
    scipy.io.savemat(buf, _cbc_dict(), do_compression=compress)
    blob = bytearray(buf.getvalue())
    if data.draw(st.booleans(), label="truncate"):
        blob = blob[: data.draw(st.integers(0, len(blob) - 1), label="cut")]
    else:
        for _ in range(data.draw(st.integers(1, 8), label="n_flips")):
            blob[data.draw(st.integers(0, len(blob) - 1))] = data.draw(st.integers(0, 255))
    path = work / f"CBC_stable_c{next(_ids)}.mat"
    path.write_bytes(bytes(blob))
    before = _sha(path)
    rec = _outcome("corrupted MAT", read_flutter_cbc, path)
    if rec is not None:
        assert np.all(np.isfinite(rec.signals)) and rec.sample_rate > 0
    _outcome("corrupted MAT (detect)", detect_format, path)
    assert _sha(path) == before


def _em_point(n: int = 200, f: float = 16.5) -> dict[str, Any]:
    t = np.arange(n) / 5000.0
    w = 2 * np.pi * f
    coeffs = np.zeros(16)
    coeffs[9] = 0.3
    return {
        "forcing_freq": f,
        "x": 0.2 + 0.3 * np.cos(w * t),
        "base_disp": 0.1 * np.cos(w * t),
        "out": 0.01 * np.cos(w * t),
        "x_target": 0.2 + 0.3 * np.cos(w * t),
        "x_coeffs_ave": coeffs,
        "base_coeffs_ave": coeffs * 0.3,
        "base_amp": 0.09,
    }


@FAST
@given(data=st.data())
def test_hostile_em_mat(work: Path, data: st.DataObject) -> None:
    points = [_em_point() for _ in range(data.draw(st.integers(0, 3), label="n_points"))]
    for p in points:
        for _ in range(data.draw(st.integers(0, 2))):
            key = data.draw(st.sampled_from(sorted(p)))
            if data.draw(st.booleans()):
                p.pop(key)
            else:
                p[key] = data.draw(_MAT_VALUES)
    cells = np.empty(len(points), dtype=object)
    for i, p in enumerate(points):
        cells[i] = p
    exp: dict[str, Any] = {
        "name": data.draw(st.sampled_from(["cbc_backbone", "x", ""])),
        "data": cells,
        "par": {"sample_freq": data.draw(st.sampled_from([5000.0, 0.0, -1.0, np.nan]))},
    }
    path = work / f"em{next(_ids)}.mat"
    try:
        scipy.io.savemat(path, {"exp": exp})
    except Exception:
        TRIED["em mat (unwritable)"] += 1
        return
    before = _sha(path)
    out = _outcome("hostile EM MAT", read_em_curve, path)
    if out is not None:
        recs, _ = out
        assert all(np.isfinite(r.signals).all() and r.omega > 0 for r in recs)
    assert _sha(path) == before


# ---------------------------------------------------------------------------------------------
# 5. hostile CSV
# ---------------------------------------------------------------------------------------------

_COLS = [
    "record",
    "param",
    "stable",
    "time",
    "omega",
    "forcing",
    "h",
    "alpha",
    "control",
    "target",
    "force",
    "curve",
    "frequency",
    "amplitude",
    "phase",
]
_CELLS = st.one_of(
    st.integers(-3, 3).map(str),
    st.floats(allow_nan=True, allow_infinity=True, width=32).map(repr),
    st.sampled_from(["", " ", "nan", "inf", "-inf", "1e400", "0x1p3", '"1"', "a,b", "1;2"]),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=6),
)


@FAST
@given(data=st.data())
def test_hostile_csv(work: Path, data: st.DataObject) -> None:
    header = data.draw(
        st.lists(st.sampled_from(_COLS) | st.text(max_size=4), min_size=0, max_size=9),
        label="header",
    )
    n_rows = data.draw(st.integers(0, 8), label="rows")
    lines = [",".join(header)]
    for _ in range(n_rows):
        width = data.draw(st.integers(0, len(header) + 1))
        lines.append(",".join(data.draw(_CELLS) for _ in range(width)))
    if data.draw(st.booleans(), label="comment"):
        lines.insert(0, "# units: " + data.draw(st.text(max_size=15)))
    path = work / f"h{next(_ids)}.csv"
    path.write_bytes("\n".join(lines).encode("utf-8", errors="surrogatepass"))
    before = _sha(path)
    ds = _outcome("hostile CSV", read_csv_dataset, path)
    if ds is not None:
        validate_dataset(ds)
    _outcome("hostile CSV (import)", lambda p: import_files([p]), path)
    assert _sha(path) == before


def _valid_csv_lines() -> list[str]:
    t = np.arange(12) / 50.0
    lines = ["# units: param=m/s, h=m", "record,param,stable,time,h,alpha,control,target"]
    for r in range(2):
        for k, tk in enumerate(t):
            lines.append(
                f"{r},{14.0 + r},{r % 2},{float(tk)!r},{float(np.sin(3 * tk))!r},"
                f"{float(np.cos(tk))!r},0.1,{'' if k % 3 else 0.5}"
            )
    return lines


def test_valid_csv_base_is_valid(work: Path) -> None:
    path = work / "base.csv"
    path.write_text("\n".join(_valid_csv_lines()) + "\n")
    ds = read_csv_dataset(path)
    assert ds.sizes["record"] == 2 and list(ds["n_samples"].values) == [12, 12]


@FAST
@given(data=st.data())
def test_mutated_valid_csv(work: Path, data: st.DataObject) -> None:
    lines = _valid_csv_lines()
    for _ in range(data.draw(st.integers(1, 3), label="n_mutations")):
        i = data.draw(st.sampled_from(range(len(lines))), label="line")  # uniform
        op = data.draw(
            st.sampled_from(["value", "value", "cell", "drop_cell", "dup", "delete", "truncate"])
        )
        cells = lines[i].split(",")
        if op == "value" and i >= 2 and len(cells) == 8:  # a sample value, finite or not
            cells[data.draw(st.sampled_from([4, 5, 6, 7]))] = repr(data.draw(st.floats()))
            lines[i] = ",".join(cells)
        elif op == "cell":
            cells[data.draw(st.integers(0, len(cells) - 1))] = data.draw(_CELLS)
            lines[i] = ",".join(cells)
        elif op == "drop_cell":
            cells.pop(data.draw(st.integers(0, len(cells) - 1)))
            lines[i] = ",".join(cells)
        elif op == "dup":
            lines.insert(i, lines[i])
        elif op == "delete" and len(lines) > 1:
            lines.pop(i)
        elif op == "truncate":
            lines[i] = lines[i][: data.draw(st.integers(0, len(lines[i])))]
            del lines[i + 1 :]
    path = work / f"m{next(_ids)}.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8", errors="surrogatepass")
    before = _sha(path)
    ds = _outcome("mutated valid CSV", read_csv_dataset, path)
    if ds is not None:
        validate_dataset(ds)
    assert _sha(path) == before


@FAST
@given(
    times=st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=6),
    values=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=6, max_size=6),
)
def test_csv_time_and_values(work: Path, times: list[float], values: list[float]) -> None:
    rows = [f"0,1.0,1,{t!r},{v!r}" for t, v in zip(times, values, strict=False)]
    path = work / f"tv{next(_ids)}.csv"
    path.write_text("record,param,stable,time,h\n" + "\n".join(rows) + "\n")
    ds = _outcome("CSV time/values", read_csv_dataset, path)
    if ds is not None:
        t = np.array(times)
        assert np.all(np.diff(t) > 0) and np.isfinite(values[: len(times)]).all()


# ---------------------------------------------------------------------------------------------
# 6. hostile model files (JSON + npz)
# ---------------------------------------------------------------------------------------------

_JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)


@FAST
@given(data=st.data())
def test_hostile_model_files(work: Path, data: st.DataObject) -> None:
    d = save_model(work / f"model{next(_ids)}", "kernel", {"a": 1.0}, {"w": np.arange(4.0)})
    meta = json.loads((d / "model.json").read_text())
    what = data.draw(
        st.sampled_from(
            ["json_random", "json_field", "json_bytes", "npz_bytes", "npz_object", "delete"]
        ),
        label="what",
    )
    if what == "json_random":
        (d / "model.json").write_text(json.dumps(data.draw(_JSON)))
    elif what == "json_field":
        key = data.draw(st.sampled_from(sorted(meta)))
        meta[key] = data.draw(_JSON)
        (d / "model.json").write_text(json.dumps(meta))
    elif what == "json_bytes":
        (d / "model.json").write_bytes(data.draw(st.binary(max_size=200)))
    elif what == "npz_bytes":
        (d / "arrays.npz").write_bytes(
            data.draw(st.sampled_from(_PREFIXES)) + data.draw(st.binary(max_size=300))
        )
    elif what == "npz_object":
        buf = io.BytesIO()
        np.savez(buf, w=np.array([data.draw(_JSON), None], dtype=object))
        (d / "arrays.npz").write_bytes(buf.getvalue())
        meta["arrays"]["sha256"] = hashlib.sha256(buf.getvalue()).hexdigest()
        (d / "model.json").write_text(json.dumps(meta))
    else:
        os.remove(d / data.draw(st.sampled_from(["model.json", "arrays.npz"])))
    hashes = {p.name: _sha(p) for p in d.iterdir()}
    out = _outcome("hostile model files", load_model, d)
    if what in ("npz_object", "delete", "npz_bytes", "json_bytes"):
        assert out is None  # object arrays (pickle), missing or garbled files: refused
    if out is not None:
        assert out[0]["type"] and isinstance(out[1], dict)
    assert {p.name: _sha(p) for p in d.iterdir()} == hashes


# ---------------------------------------------------------------------------------------------
# report
# ---------------------------------------------------------------------------------------------


def test_zz_report_counts() -> None:
    """Print how many generated bad inputs each property tried (run with -s)."""
    total = sum(TRIED.values())
    print(f"\nhardening: {total} generated inputs tried")
    for k, v in sorted(TRIED.items()):
        print(f"  {k}: {v}")
    for k, v in sorted(FOUND.items()):
        print(f"  outcome {k}: {v}")
    report = os.environ.get("BIFID_HARDENING_REPORT")
    if report:
        Path(report).write_text(json.dumps({"tried": TRIED, "outcomes": FOUND}, indent=1))
    if TRIED and _N >= 50:  # when run alone this test has nothing to report
        assert total >= 1000
