"""Hostile inputs to every command that reads files: ``fit``, ``predict``, ``cbc --resume``.

Generated bad datasets and model directories (random bytes, truncated or mislabelled
netCDF, empty or NaN-laden datasets, pickle-bearing arrays, garbled or hostile
``model.json``) must give exit status 2 or 3 with one line on stderr, nothing on stdout,
no traceback -- and the input files must be byte-for-byte unchanged.
"""

from __future__ import annotations

import hashlib
import io
import json
import pickle
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from bifid.cli import main
from bifid.data import (
    ForcedRecord,
    LCORecord,
    forced_dataset,
    lco_dataset,
    load_dataset,
    save_dataset,
)

N_TRIED: dict[str, int] = {}
_SETTINGS = settings(
    max_examples=25,
    deadline=None,
    suppress_health_check=[
        HealthCheck.function_scoped_fixture,
        HealthCheck.too_slow,
        HealthCheck.filter_too_much,
    ],
)


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    capsys.readouterr()
    try:
        main(argv)
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def _refused(code: int, out: str, err: str) -> None:
    assert code in (2, 3), (code, out, err)
    assert out.strip() == "" or ("complete" in out and '"complete": false' in out), out
    assert "Traceback" not in err
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("bifid: error")]
    assert len(lines) == 1, err


def _digest(paths: list[Path]) -> dict[Path, str]:
    out = {}
    for p in paths:
        files = sorted(p.rglob("*")) if p.is_dir() else [p]
        out[p] = hashlib.sha256(b"".join(f.read_bytes() for f in files if f.is_file())).hexdigest()
    return out


def _lco(n_records: int, bad: str | None) -> object:
    t = np.arange(200) / 100.0
    recs = [
        LCORecord(
            param=15.0 + 0.5 * k,
            signals=np.column_stack([0.01 * np.sin(15 * t), 0.05 * np.cos(15 * t)]),
            sample_rate=100.0,
            stable=bool(k % 2),
            frequency=15.0,
        )
        for k in range(n_records)
    ]
    ds = lco_dataset(recs, ["h", "alpha"], "U", "m/s", "flutter", {}, "test")
    if bad == "nan_signals":
        ds["signals"][:] = np.nan
    elif bad == "nan_param":
        ds["param"][:] = np.nan
    elif bad == "inf_rate":
        ds["sample_rate"][:] = np.inf
    elif bad == "drop_signals":
        ds = ds.drop_vars("signals")
    elif bad == "wrong_kind":
        ds.attrs["bifid_kind"] = "banana"
    return ds


def _forced(n: int) -> object:
    t = np.arange(300) / 50.0
    recs = [
        ForcedRecord(
            omega=1.0 + 0.01 * k,
            forcing=0.01,
            signals=np.column_stack([0.1 * np.sin(t), 0.1 * np.cos(t)]),
            sample_rate=50.0,
            stable=True,
            force=0.01 * np.cos(t),
        )
        for k in range(n)
    ]
    return forced_dataset(recs, ["x1", "x2"], "x1", "shaw_pierre", {}, "test")


@pytest.fixture(scope="module")
def valid_nc(tmp_path_factory) -> bytes:
    p = tmp_path_factory.mktemp("v") / "v.nc"
    save_dataset(_lco(3, None), p)
    return p.read_bytes()


def _bad_dataset(tmp: Path, data: st.DataObject, valid_nc: bytes) -> Path:
    kind = data.draw(
        st.sampled_from(
            [
                "bytes",
                "truncated",
                "flipped",
                "empty_file",
                "json",
                "zero_records",
                "nan_signals",
                "nan_param",
                "inf_rate",
                "drop_signals",
                "wrong_kind",
                "forced_for_lco",
                "directory",
                "missing",
            ]
        ),
        label="dataset",
    )
    N_TRIED[f"dataset:{kind}"] = N_TRIED.get(f"dataset:{kind}", 0) + 1
    p = tmp / f"bad_{kind}.nc"
    if kind == "bytes":
        p.write_bytes(data.draw(st.binary(max_size=512)))
    elif kind == "truncated":
        p.write_bytes(valid_nc[: data.draw(st.integers(0, len(valid_nc) - 1))])
    elif kind == "flipped":
        b = bytearray(valid_nc)
        for _ in range(data.draw(st.integers(1, 64))):
            i = data.draw(st.integers(0, len(b) - 1))
            b[i] ^= 0xFF
        p.write_bytes(bytes(b))
        try:  # flips inside the numbers can leave a valid dataset: not a bad input then
            load_dataset(p)
        except Exception:
            pass
        else:
            assume(False)
    elif kind == "empty_file":
        p.write_bytes(b"")
    elif kind == "json":
        p.write_text(json.dumps({"records": []}))
    elif kind == "directory":
        p.mkdir()
    elif kind == "missing":
        pass
    elif kind == "zero_records":
        try:
            save_dataset(_lco(0, None), p)
        except Exception:  # the writer itself refuses: hand-craft via xarray instead
            _lco(1, None).isel(record=slice(0, 0)).to_netcdf(p, engine="h5netcdf")
    elif kind == "forced_for_lco":
        _forced(3).to_netcdf(p, engine="h5netcdf")
    else:
        _lco(3, kind).to_netcdf(p, engine="h5netcdf")
    return p


def _bad_model(tmp: Path, data: st.DataObject) -> Path:
    kind = data.draw(
        st.sampled_from(
            [
                "no_dir",
                "empty_dir",
                "json_garbage",
                "json_list",
                "unknown_type",
                "pickle_npz",
                "npz_garbage",
                "huge_numbers",
                "missing_arrays",
                "file_not_dir",
            ]
        ),
        label="model",
    )
    N_TRIED[f"model:{kind}"] = N_TRIED.get(f"model:{kind}", 0) + 1
    d = tmp / f"model_{kind}"
    if kind == "no_dir":
        return d
    if kind == "file_not_dir":
        d.write_text("x")
        return d
    d.mkdir()
    mtype = data.draw(st.sampled_from(["hopf_hybrid", "forced_kernel", "mechanistic"]))
    meta = {
        "format": "bifid-model",
        "format_version": 1,
        "type": mtype,
        "params": {},
        "settings": {},
    }
    if kind == "json_garbage":
        (d / "model.json").write_bytes(data.draw(st.binary(max_size=200)))
    elif kind == "json_list":
        (d / "model.json").write_text("[1, 2, 3]")
    elif kind == "unknown_type":
        (d / "model.json").write_text(json.dumps({**meta, "type": "rm -rf /"}))
    elif kind == "huge_numbers":
        (d / "model.json").write_text(json.dumps({**meta, "params": {"a": 1e308 * 10}}))
    elif kind in ("pickle_npz", "npz_garbage", "missing_arrays"):
        (d / "model.json").write_text(json.dumps(meta))
        if kind == "pickle_npz":
            # an object array is stored with pickle: np.load(allow_pickle=False) must refuse
            buf = io.BytesIO()
            np.savez(buf, evil=np.array([{"x": 1}], dtype=object))
            (d / "arrays.npz").write_bytes(buf.getvalue())
        elif kind == "npz_garbage":
            buf = io.BytesIO()
            with zipfile.ZipFile(buf, "w") as z:
                z.writestr("evil.pkl", pickle.dumps({"x": 1}))
            (d / "arrays.npz").write_bytes(buf.getvalue())
    return d


@_SETTINGS
@given(data=st.data())
def test_fit_refuses_hostile_datasets(
    tmp_path: Path, valid_nc: bytes, capsys: pytest.CaptureFixture[str], data: st.DataObject
) -> None:
    """``bifid fit hopf|forced|mechanistic BAD --out M``: one-line error, input unchanged."""
    tmp_path = Path(tempfile.mkdtemp(dir=tmp_path))  # fresh per generated example
    bad = _bad_dataset(tmp_path, data, valid_nc)
    which = data.draw(st.sampled_from(["hopf", "forced", "mechanistic"]), label="fit")
    out = tmp_path / f"m_{which}"
    argv = ["fit", which, str(bad), "--out", str(out)]
    if which == "mechanistic":
        argv += ["--model", "flutter", "--free", "ka2,ka3"]
    if data.draw(st.booleans(), label="json"):
        argv.append("--json")
    before = _digest([bad]) if bad.exists() else {}
    N_TRIED["fit argv"] = N_TRIED.get("fit argv", 0) + 1
    code, o, e = run(argv, capsys)
    _refused(code, o, e)
    assert (_digest([bad]) if bad.exists() else {}) == before
    assert not (out / "model.json").exists()


@_SETTINGS
@given(data=st.data())
def test_predict_refuses_hostile_models(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], data: st.DataObject
) -> None:
    """``bifid predict BAD ...``: refused (pickle-bearing arrays included), input unchanged."""
    tmp_path = Path(tempfile.mkdtemp(dir=tmp_path))
    model = _bad_model(tmp_path, data)
    opts = data.draw(
        st.sampled_from(
            [
                [],
                ["--frc", "--forcing", "0.01"],
                ["--backbone"],
                ["--range", "14", "18"],
                ["--scurve", "--omega", "1"],
            ]
        )
    )
    before = _digest([model]) if model.exists() else {}
    N_TRIED["predict argv"] = N_TRIED.get("predict argv", 0) + 1
    code, o, e = run(["predict", str(model), *opts, "--json"], capsys)
    _refused(code, o, e)
    assert (_digest([model]) if model.exists() else {}) == before


@_SETTINGS
@given(data=st.data())
def test_cbc_resume_refuses_hostile_datasets(
    tmp_path: Path, valid_nc: bytes, capsys: pytest.CaptureFixture[str], data: st.DataObject
) -> None:
    """``bifid cbc ... --resume --out BAD``: refused before any experiment, file unchanged."""
    tmp_path = Path(tempfile.mkdtemp(dir=tmp_path))
    bad = _bad_dataset(tmp_path, data, valid_nc)
    if bad.name == "bad_forced_for_lco.nc" or not bad.exists():
        return  # a valid forced dataset / nothing to resume: covered elsewhere
    before = _digest([bad])
    N_TRIED["cbc argv"] = N_TRIED.get("cbc argv", 0) + 1
    code, o, e = run(
        [
            "cbc",
            "hopf",
            "--protocol",
            "ppcbc",
            "--values",
            "-0.1",
            "--resume",
            "--out",
            str(bad),
            "--quiet",
        ],
        capsys,
    )
    _refused(code, o, e)
    assert _digest([bad]) == before


def test_pickle_bearing_model_is_refused_by_loader(tmp_path: Path) -> None:
    """The model loader itself refuses arrays that need unpickling (no code runs)."""
    from bifid.errors import BifidInputError
    from bifid.io import load_model, save_model

    d = save_model(tmp_path / "m", "hopf_hybrid", {"a": 1.0}, {"x": np.arange(3.0)}, {})
    buf = io.BytesIO()
    np.savez(buf, x=np.array([object()], dtype=object))
    (Path(d) / "arrays.npz").write_bytes(buf.getvalue())
    with pytest.raises(BifidInputError):
        load_model(d)


def test_zz_report_counts() -> None:
    """How many generated bad inputs the property tests tried (printed with ``-s``)."""
    print("\nCLI hardening inputs tried:", json.dumps(N_TRIED, sort_keys=True))
    assert sum(v for k, v in N_TRIED.items() if k.endswith("argv")) > 0
