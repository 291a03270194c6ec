"""The public CLI contract of the continuation commands (DESIGN.md)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ENV = {**os.environ, "BIFID_JAX_CACHE": str(Path(__file__).resolve().parents[1] / ".jax_cache")}


def run(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bifid", *args], capture_output=True, text=True,
                          timeout=timeout, env=ENV)


def test_systems_json_lists_every_reference_system():
    """Check `bifid systems --json`: one JSON object with each system's kind/states/parameters."""
    r = run("systems", "--json")
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    by = {s["name"]: s for s in data["systems"]}
    assert {"hopf", "vanderpol", "flutter", "duffing", "shaw_pierre"} <= set(by)
    assert by["flutter"]["states"] == ["h", "hd", "alpha", "alphad", "w", "wd"]
    assert by["duffing"]["kind"] == "forced" and by["flutter"]["kind"] == "autonomous"
    names = [p["name"] for p in by["flutter"]["parameters"]]
    assert names[:4] == ["U", "b", "a", "rho"] and "ka3" in names


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("continue", "nosuch", "--range", "0", "1"), "Unknown system"),
        (("continue", "hopf", "--range", "0", "1", "--set", "bogus=1"), "no parameter 'bogus'"),
        (("continue", "hopf", "--range", "0", "1", "--set", "mu0=nan"), "finite"),
        (("continue", "hopf", "--range", "0", "1", "--set", "mu0=inf"), "finite"),
        (("continue", "hopf", "--range", "0", "1", "--set", "mu0"), "NAME=VALUE"),
        (("continue", "hopf", "--range", "1", "1"), "span an interval"),
        (("continue", "hopf", "--range", "nan", "1"), "finite"),
        (("continue", "duffing", "--range", "0", "1"), "forced"),
        (("frc", "hopf", "--forcing", "0.1", "--omega-range", "0.9", "1.1"), "autonomous"),
        (("continue", "flutter", "--range", "5", "10"), "No Hopf point"),
        (("continue", "hopf", "--range", "0", "1", "--bogus"), "No such option"),
        (("continue", "hopf", "--range", "0", "x"), "Invalid value"),
        (("nosuchcommand",), "No such command"),
    ],
)
def test_user_errors_exit_2_with_one_line_and_no_traceback(args, needle):
    """Check bad input: exit code 2, one line on stderr naming the problem, empty stdout."""
    r = run(*args, "--json")
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert r.stdout == ""
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0], r.stderr


def test_newton_failure_is_reported_not_hidden():
    """Check a failing continuation exits 3 with complete=false, never a silent partial branch."""
    # Use an FRC start where the response cannot be found: enormous forcing at resonance.
    r = run("frc", "duffing", "--forcing", "1e6", "--omega-range", "1.0", "1.1", "--json",
            "--quiet")
    assert r.returncode == 3, r.stderr
    assert "Traceback" not in r.stderr
    if r.stdout:
        assert json.loads(r.stdout)["complete"] is False


def test_continue_json_contract_and_outputs(tmp_path):
    """Check `bifid continue hopf --json`: keys of the contract, values, plot and dataset files."""
    png, nc = tmp_path / "h.png", tmp_path / "h.nc"
    r = run("continue", "hopf", "--param", "mu", "--range", "-1", "1", "--set", "mu0=0.2",
            "--set", "a2=1", "--mesh", "16", "--json", "--quiet", "--plot", str(png),
            "--out", str(nc))
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    (h,) = data["hopf"]
    assert set(h) >= {"param", "omega", "lyapunov", "criticality"}
    assert h["param"] == pytest.approx(0.2, abs=1e-10) and h["criticality"] == "subcritical"
    (f,) = data["cycle_folds"]
    assert f["param"] == pytest.approx(0.2 - 0.25, abs=1e-8)
    assert set(f) >= {"param", "period", "amplitude"}
    o = data["orbits"][5]
    assert set(o) >= {"param", "period", "stable", "floquet_max", "amplitude"}
    assert set(o["amplitude"]) == {"u1", "u2"}
    assert data["secondary"] == []
    assert data["complete"] is True and data["settings"]["parameters"]["mu0"] == 0.2
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"
    from bifid.data import load_dataset

    ds = load_dataset(nc)
    assert ds.attrs["bifid_kind"] == "lco" and ds.sizes["record"] == len(data["orbits"])
