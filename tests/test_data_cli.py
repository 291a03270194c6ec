"""``bifid import``: JSON contract, exit codes, one-line errors, inputs left untouched."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bifid.cli import main
from bifid.data import load_dataset

CSV = """\
# param_name: U
# units: param=m/s, h=m
record,param,stable,time,h
0,14.9,1,0.0,0.01
0,14.9,1,0.01,0.02
0,14.9,1,0.02,0.01
1,15.5,0,0.0,0.00
1,15.5,0,0.01,-0.01
"""

N_TRIED = {"cli argv": 0, "exit 0": 0, "exit 2": 0}


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    capsys.readouterr()
    try:
        main(argv)
        code = 0
    except SystemExit as exc:
        code = int(exc.code or 0)
    out, err = capsys.readouterr()
    return code, out, err


def _user_error(code: int, out: str, err: str) -> None:
    assert code == 2, (code, out, err)
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("bifid: error: "), err
    assert "Traceback" not in err


@pytest.fixture
def csv_file(tmp_path: Path) -> Path:
    p = tmp_path / "in.csv"
    p.write_text(CSV)
    return p


def test_import_csv_json(
    csv_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out_nc = tmp_path / "out.nc"
    before = csv_file.read_bytes()
    code, out, err = run(["import", str(csv_file), "--out", str(out_nc), "--json"], capsys)
    assert code == 0, err
    assert len(out.strip().splitlines()) == 1
    payload = json.loads(out)
    assert payload["records"] == [
        {
            "param": 14.9,
            "stable": True,
            "n_samples": 3,
            "sample_rate": pytest.approx(100.0),
            "frequency": payload["records"][0]["frequency"],
            "amplitude": {"h": 0.02},
        },
        {
            "param": 15.5,
            "stable": False,
            "n_samples": 2,
            "sample_rate": pytest.approx(100.0),
            "frequency": payload["records"][1]["frequency"],
            "amplitude": {"h": 0.01},
        },
    ]
    assert payload["source"] == [str(csv_file)] and payload["kind"] == "lco"
    assert payload["settings"]["command"] == "import"
    ds = load_dataset(out_nc)
    np.testing.assert_array_equal(ds["param"].values, [14.9, 15.5])
    assert json.loads(ds.attrs["settings"])["import"]["formats"] == ["csv"]
    assert csv_file.read_bytes() == before
    # human-readable output without --json
    code, out, _ = run(["import", str(csv_file), "--out", str(tmp_path / "o2.nc")], capsys)
    assert code == 0 and "2 lco records" in out


def test_import_user_errors(
    csv_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = hashlib.sha256(csv_file.read_bytes()).hexdigest()
    bad = tmp_path / "bad.csv"
    bad.write_text("record,param,stable,time,h\n0,1,1,0,zzz\n")
    cases = [
        ["import", str(csv_file), "--json"],  # no --out
        ["import", "--out", str(tmp_path / "x.nc")],  # no input
        ["import", str(tmp_path / "missing.csv"), "--out", str(tmp_path / "x.nc")],
        ["import", str(csv_file), "--out", str(tmp_path / "x.nc"), "--format", "excel"],
        ["import", str(csv_file), "--out", str(csv_file), "--json"],  # would overwrite input
        ["import", str(csv_file), "--out", str(tmp_path / "nodir" / "x.nc")],
        ["import", str(csv_file), "--out", str(tmp_path)],  # a directory
        ["import", str(bad), "--out", str(tmp_path / "x.nc"), "--json"],
        ["import", str(csv_file), "--format", "flutter-cbc", "--out", str(tmp_path / "x.nc")],
        ["import", str(tmp_path), "--out", str(tmp_path / "y.nc")],  # mixed csv formats dir
    ]
    for argv in cases:
        code, out, err = run(argv, capsys)
        _user_error(code, out, err)
    assert hashlib.sha256(csv_file.read_bytes()).hexdigest() == before
    assert not (tmp_path / "x.nc").exists()


_FORMATS = ["auto", "csv", "flutter-cbc", "em-scurve", "netcdf", "", "CSV", "a b", "--json"]


@settings(
    max_examples=30,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(data=st.data())
def test_cli_argv_property(
    tmp_path: Path, csv_file: Path, capsys: pytest.CaptureFixture[str], data: st.DataObject
) -> None:
    junk = tmp_path / "junk.csv"
    junk.write_bytes(data.draw(st.binary(max_size=64), label="junk"))
    # start from a valid command line, then break 0-2 parts of it
    inputs = [str(csv_file)]
    out_path: str | None = str(tmp_path / "ok.nc")
    fmt: str | None = data.draw(st.sampled_from([None, "auto", "csv"]), label="format")
    for _ in range(data.draw(st.integers(0, 2), label="n_breaks")):
        part = data.draw(st.sampled_from(["inputs", "out", "format"]), label="break")
        if part == "inputs":
            inputs = data.draw(
                st.lists(
                    st.sampled_from(
                        [str(csv_file), str(junk), str(tmp_path / "no"), str(tmp_path)]
                    ),
                    max_size=3,
                )
            )
        elif part == "out":
            out_path = data.draw(
                st.sampled_from(
                    [
                        None,
                        str(tmp_path / "nodir" / "x.nc"),
                        str(tmp_path),
                        str(csv_file),
                        str(junk),
                    ]
                )
            )
        else:
            fmt = data.draw(st.sampled_from(_FORMATS))
    argv = ["import", *inputs]
    if out_path is not None:
        argv += ["--out", out_path]
    if fmt is not None:
        argv += ["--format", fmt]
    json_out = data.draw(st.booleans(), label="json")
    if json_out:
        argv.append("--json")
    # inputs are never modified (an existing non-input --out file may be replaced)
    hashes = {
        p: hashlib.sha256(p.read_bytes()).hexdigest() for p in (csv_file, junk) if str(p) in inputs
    }
    N_TRIED["cli argv"] += 1
    code, out, err = run(argv, capsys)
    N_TRIED[f"exit {code}"] = N_TRIED.get(f"exit {code}", 0) + 1
    if code == 0:
        assert err == ""
        if json_out:
            payload = json.loads(out)
            assert isinstance(payload, dict) and payload["records"]
            assert len(out.strip().splitlines()) == 1
    else:
        _user_error(code, out, err)
    assert {p: hashlib.sha256(p.read_bytes()).hexdigest() for p in hashes} == hashes


def test_import_real_data_subprocess(shared_data: Path, tmp_path: Path) -> None:
    """The installed entry point on two real flutter-rig files (stdout: one JSON object)."""
    d = shared_data / "flutter_rig" / "cbc_model1"
    files = [d / "CBC_stable_v14_9.mat", d / "CBC_unstable_v15_6_2.mat"]
    out_nc = tmp_path / "m1.nc"
    cmd = [
        sys.executable,
        "-c",
        "from bifid.cli import main; main()",
        "import",
        *map(str, files),
        "--out",
        str(out_nc),
        "--json",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert proc.returncode == 0, proc.stderr
    payload = json.loads(proc.stdout)
    assert [r["param"] for r in payload["records"]] == [14.9, 16.4]  # Wind_sped, not names
    assert [r["stable"] for r in payload["records"]] == [True, False]
    assert all(r["n_samples"] == 100000 and r["sample_rate"] == 5000.0 for r in payload["records"])
    assert payload["source"] == [str(f) for f in files]
    assert load_dataset(out_nc).sizes["record"] == 2


def test_import_real_non_lco_files(
    shared_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    fr = shared_data / "flutter_rig"
    for path, hint in [
        (fr / "free_decay", "load_free_decay"),
        (fr / "ulco_amplitudes", "load_ulco_amplitudes"),
        (fr / "thesis_curves", "load_thesis_curves"),
        (fr / "cbc_model1" / "CBC_stable_v14_9.mat", "different formats"),
    ]:
        argv = ["import", str(path), "--out", str(tmp_path / "x.nc"), "--json"]
        if hint == "different formats":
            argv.insert(2, str(shared_data / "em_oscillator" / "backbone_1.mat"))
        code, out, err = run(argv, capsys)
        _user_error(code, out, err)
        assert hint in err


def test_zz_cli_counts() -> None:
    print(f"\ncli argv property: {N_TRIED}")
    if N_TRIED["cli argv"]:
        assert N_TRIED["exit 0"] > 0 and N_TRIED["exit 2"] > 0  # both outcomes exercised
