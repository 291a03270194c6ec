"""`bifid cbc`: the measured diagram as JSON, the dataset written point by point, --resume
(exact continuation, refusal of another campaign, nothing changed on a finished one),
failures reported with exit 3."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from bifid.cli import app, load_commands
from bifid.data import load_dataset

load_commands()
RUNNER = CliRunner()

# The coarse grid puts the secant estimate of the unstable LCO (r = 0.3357) near the
# maximum of Ξ (A* ≈ 0.23), where the Broyden corrector on the polar target cannot start:
# the scan must fall back to the bracketing secant and still find it.
HOPF_ARGS = [
    "hopf",
    "--protocol",
    "ppcbc",
    "--set",
    "q5=1",
    "--values=-0.1",
    "--amplitude-range",
    "0.2",
    "1.1",
    "--n-amplitudes",
    "4",
    "--measure-periods",
    "2",
    "--settle-periods",
    "5",
    "--n-harmonics",
    "3",
    "--sample-rate",
    "100",
    "--no-truth",
    "--quiet",
    "--json",
]
SCURVE_ARGS = [
    "duffing",
    "--protocol",
    "scurve",
    "--omega",
    "1.05",
    "--forcing-range",
    "0.008",
    "0.03",
    "--sample-rate",
    "40",
    "--n-harmonics",
    "3",
    "--settle-periods",
    "4",
    "--measure-periods",
    "2",
    "--noise",
    "2e-4",
    "--seed",
    "3",
    "--no-truth",
    "--quiet",
    "--json",
]


def invoke(args):
    r = RUNNER.invoke(app, ["cbc", *args])
    return r, (json.loads(r.stdout) if r.stdout.strip().startswith("{") else None)


def test_ppcbc_json_dataset_and_resume(tmp_path):
    """Check points in the JSON diagram and in the dataset, then that --resume of the
    finished campaign records nothing and leaves the file as it was."""
    out = tmp_path / "hopf.nc"
    r, data = invoke([*HOPF_ARGS, "--out", str(out)])
    assert r.exit_code == 0, r.stderr
    r_u = math.sqrt((1 - math.sqrt(0.6)) / 2)
    r_s = math.sqrt((1 + math.sqrt(0.6)) / 2)
    pts = data["points"]
    assert [p["stable"] for p in pts] == [False, True]
    assert pts[0]["amplitude"]["u1"] == pytest.approx(r_u, rel=2e-3)
    assert pts[1]["amplitude"]["u1"] == pytest.approx(r_s, rel=2e-3)
    assert all(p["param"] == -0.1 and p["control_rms"] >= 0 for p in pts)
    assert data["kind"] == "bifurcation" and data["source"] == "measurement"
    assert data["complete"] is True and data["settings"]["campaign"]["protocol"] == "ppcbc"
    ds = load_dataset(out)
    assert ds.attrs["bifid_kind"] == "lco" and ds.sizes["record"] == 2
    assert json.loads(ds.attrs["settings"])["campaign"]["options"]["kp"] == 1.0
    np.testing.assert_array_equal(ds["stable"].values, [0, 1])
    # signals are centred and cover whole periods; the control is recorded
    assert np.abs(ds["signals"].isel(record=0).mean("time")).max() < 1e-3
    assert float(ds["control_rms"].max()) < 1e-3

    before = out.read_bytes()
    r, again = invoke([*HOPF_ARGS, "--out", str(out), "--resume"])
    assert r.exit_code == 0, r.stderr
    assert again["resumed_from"] == 2 and len(again["points"]) == 2
    assert out.read_bytes() == before


def test_failures_are_reported_and_not_recorded(tmp_path):
    """Check a value without LCOs (beyond the fold at -1/4): exit 3, failure in JSON, no record."""
    out = tmp_path / "h.nc"
    args = [a if a != "--values=-0.1" else "--values=-0.1,-0.3" for a in HOPF_ARGS]
    r, data = invoke([*args, "--out", str(out)])
    assert r.exit_code == 3
    assert data["complete"] is False and data["failures"]
    assert data["failures"][0]["param"] == -0.3 and data["failures"][0]["reason"]
    assert "error" in r.stderr
    ds = load_dataset(out)
    assert set(np.round(ds["param"].values, 6)) == {-0.1}
    assert json.loads(ds.attrs["cbc_campaign"])["failures"][0]["param"] == -0.3


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["duffing", "--protocol", "ppcbc"], "forced"),
        (["hopf", "--protocol", "scurve"], "autonomous"),
        (["hopf", "--protocol", "magic"], "ppcbc, scurve or frc"),
        (["hopf", "--protocol", "ppcbc", "--values=-0.1", "--noise", "u9=1"], "not outputs"),
        (["duffing", "--protocol", "scurve", "--omega", "1.05"], "forcing-range"),
    ],
)
def test_bad_invocations(tmp_path, args, needle):
    """Check user errors exit 2 with a one-line message saying what is wrong."""
    r = RUNNER.invoke(app, ["cbc", *args, "--out", str(tmp_path / "x.nc"), "--quiet"])
    assert r.exit_code == 2
    assert needle in r.stderr


def test_existing_output_needs_resume(tmp_path):
    """Check an existing --out is never overwritten without --resume."""
    out = tmp_path / "x.nc"
    out.write_bytes(b"not a dataset")
    r = RUNNER.invoke(
        app, ["cbc", "hopf", "--protocol", "ppcbc", "--values=-0.1", "--out", str(out)]
    )
    assert r.exit_code == 2 and "--resume" in r.stderr
    assert out.read_bytes() == b"not a dataset"


def test_resumed_scurve_is_the_uninterrupted_one(tmp_path):
    """Check the S-curve cut after half its points (as an interruption leaves it) and
    resumed equals the uninterrupted S-curve point for point, with noise; --resume with
    another Ω refuses the file with one line (exit 2) and changes nothing."""
    from bifid.data import save_dataset

    ref, cut = tmp_path / "s.nc", tmp_path / "cut.nc"
    r, full = invoke([*SCURVE_ARGS, "--out", str(ref)])
    assert r.exit_code == 0, r.stderr
    n = len(full["points"])
    assert n >= 8 and len(full["folds"]) == 2
    A = load_dataset(ref)
    save_dataset(A.isel(record=slice(0, n // 2)), cut)
    r, resumed = invoke([*SCURVE_ARGS, "--out", str(cut), "--resume"])
    assert r.exit_code == 0, r.stderr
    assert resumed["resumed_from"] == n // 2 and len(resumed["points"]) == n
    B = load_dataset(cut)
    for v in ("forcing", "amplitude", "phase", "signals", "control"):
        np.testing.assert_allclose(B[v].values, A[v].values, rtol=1e-12, atol=0)
    before = cut.read_bytes()
    other = [a if a != "1.05" else "1.06" for a in SCURVE_ARGS]
    r, _ = invoke([*other, "--out", str(cut), "--resume"])
    assert r.exit_code == 2
    assert "another campaign" in r.stderr and "omega" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert cut.read_bytes() == before
