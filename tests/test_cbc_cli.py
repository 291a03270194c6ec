"""`bifid cbc`: JSON contract, dataset written point by point, --resume, failures reported."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from typer.testing import CliRunner

from bifid.cli import _load_commands, app
from bifid.data import load_dataset

_load_commands()
RUNNER = CliRunner()

# The coarse grid puts the secant estimate of the unstable LCO (r = 0.3357) near the
# maximum of Ξ (A* ≈ 0.23), where Newton-Broyden on the polar target cannot start: the
# scan must fall back to the bracketing secant and still find it.
HOPF_ARGS = ["hopf", "--protocol", "ppcbc", "--set", "q5=1", "--values=-0.1",
             "--amplitude-range", "0.2", "1.1", "--n-amplitudes", "4", "--measure-periods", "2",
             "--settle-periods", "5", "--n-harmonics", "3", "--sample-rate", "100", "--no-truth",
             "--quiet", "--json"]


def invoke(args):
    r = RUNNER.invoke(app, ["cbc", *args])
    return r, (json.loads(r.stdout) if r.stdout.strip().startswith("{") else None)


def test_ppcbc_json_dataset_and_resume(tmp_path):
    """Check points in JSON and in the dataset, then that --resume re-records nothing."""
    out = tmp_path / "hopf.nc"
    r, data = invoke([*HOPF_ARGS, "--out", str(out)])
    assert r.exit_code == 0, r.stderr
    r_u = math.sqrt((1 - math.sqrt(0.6)) / 2)
    r_s = math.sqrt((1 + math.sqrt(0.6)) / 2)
    pts = data["points"]
    assert [p["stable"] for p in pts] == [False, True]
    assert pts[0]["amplitude"]["u1"] == pytest.approx(r_u, rel=2e-3)
    assert pts[1]["amplitude"]["u1"] == pytest.approx(r_s, rel=2e-3)
    assert all(p["mu"] == -0.1 and p["control_rms"] >= 0 for p in pts)
    assert data["settings"]["protocol"] == "ppcbc" and data["complete"] is True
    ds = load_dataset(out)
    assert ds.attrs["bifid_kind"] == "lco" and ds.sizes["record"] == 2
    assert json.loads(ds.attrs["settings"])["options"]["kp"] == 1.0
    np.testing.assert_array_equal(ds["stable"].values, [0, 1])
    # signals are centred and cover whole periods; the control is recorded
    assert np.abs(ds["signals"].isel(record=0).mean("time")).max() < 1e-3
    assert float(ds["control_rms"].max()) < 1e-3

    r, again = invoke([*HOPF_ARGS, "--out", str(out), "--resume"])
    assert r.exit_code == 0, r.stderr
    assert again["skipped_existing"] == 2 and again["points"] == []
    assert load_dataset(out).sizes["record"] == 2


def test_failures_are_reported_and_not_recorded(tmp_path):
    """Check a value without LCOs (beyond the fold at -1/4): exit 3, failure in JSON, no record."""
    out = tmp_path / "h.nc"
    args = [a if a != "--values=-0.1" else "--values=-0.1,-0.3" for a in HOPF_ARGS]
    r, data = invoke([*args, "--out", str(out)])
    assert r.exit_code == 3
    assert data["complete"] is False and data["failures"]
    assert "error" in r.stderr
    ds = load_dataset(out)
    assert set(np.round(ds["param"].values, 6)) == {-0.1}


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["duffing", "--protocol", "ppcbc"], "forced"),
        (["hopf", "--protocol", "scurve"], "autonomous"),
        (["hopf", "--protocol", "magic"], "ppcbc, scurve or frc"),
        (["hopf", "--protocol", "ppcbc", "--noise", "u9=1"], "not outputs"),
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
    r = RUNNER.invoke(app, ["cbc", "hopf", "--protocol", "ppcbc", "--values=-0.1", "--out",
                            str(out)])
    assert r.exit_code == 2 and "--resume" in r.stderr
    assert out.read_bytes() == b"not a dataset"


def test_frc_resume_continues_the_curve(tmp_path):
    """Check that an interrupted FRC (a shorter Ω range) continues with --resume from its
    last points: new points only beyond them, the dataset holds both runs, and every
    point lies on the FRC computed by numerical continuation (within 1 %)."""
    from bifid.continuation import frc
    from bifid.systems import get_system

    out = tmp_path / "frc.nc"
    base = ["duffing", "--protocol", "frc", "--forcing", "0.01", "--no-stability",
            "--no-truth", "--quiet", "--json", "--out", str(out)]
    r, first = invoke([*base, "--omega-range", "0.95", "0.99"])
    assert r.exit_code == 0, r.stderr
    n1 = len(first["points"])
    om1 = [p["omega"] for p in first["points"]]
    assert n1 >= 2 and max(om1) >= 0.99
    r, second = invoke([*base, "--omega-range", "0.95", "1.01", "--resume"])
    assert r.exit_code == 0, r.stderr
    assert second["resumed_from"] == n1
    om2 = [p["omega"] for p in second["points"]]
    assert om2 and min(om2) > max(om1) and max(om2) >= 1.01
    ds = load_dataset(out)
    assert ds.sizes["record"] == n1 + len(om2)
    # the lower branch below the first fold (Ω ≈ 1.028) is single-valued in Ω
    s = get_system("duffing")
    br = frc(s, 0.01, (0.94, 1.02), n_mesh=32, observed="q")
    om_c = np.asarray(br.data["omega"])
    amp_c = np.asarray(br.data["observed_amplitude"])
    order = np.argsort(om_c)
    for p in first["points"] + second["points"]:
        ref = np.interp(p["omega"], om_c[order], amp_c[order])
        assert p["amplitude"] == pytest.approx(ref, rel=0.01)
