"""The public CLI contract of the continuation commands (DESIGN.md), run in-process."""

from __future__ import annotations

import jax.numpy as jnp
import pytest

from bifid.systems import Parameter, System, register


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("continue", "nosuch", "--range", "0", "1"), "Unknown system"),
        (("continue", "hopf", "--range", "0", "1", "--set", "bogus=1"), "no parameter 'bogus'"),
        (("continue", "hopf", "--range", "0", "1", "--set", "mu0=nan"), "finite"),
        (("continue", "hopf", "--range", "0", "1", "--set", "mu0"), "NAME=VALUE"),
        (("continue", "hopf", "--range", "1", "1"), "span an interval"),
        (("continue", "hopf", "--range", "nan", "1"), "finite"),
        (("continue", "hopf"), "--range A B is required"),
        (("continue", "duffing", "--range", "0", "1"), "forced"),
        (("continue", "hopf", "--range", "0", "1", "--x0", "1"), "--x0 expects 2"),
        (("continue", "hopf", "--range", "0", "1", "--x0", "1,a"), "--x0 expects 2"),
        (("continue", "hopf", "--range", "0", "1", "--x0", "1,inf"), "finite"),
        (("continue", "hopf", "--range", "0", "1", "--mesh", "7"), "--mesh"),
        (("continue", "hopf", "--range", "0", "1", "--max-steps", "0"), "--max-steps"),
        (("frc", "hopf", "--forcing", "0.1", "--omega-range", "0.9", "1.1"), "autonomous"),
        (("frc", "duffing", "--forcing", "0.01", "--omega-range", "-1.3", "-0.9"), "> 0"),
        (("frc", "duffing", "--forcing", "0", "--omega-range", "0.9", "1.1"), "--forcing must"),
        (("scurve", "duffing", "--omega", "0", "--forcing-range", "0", "1"), "--omega must"),
        (("scurve", "duffing", "--omega", "1", "--forcing-range", "-1", "1"), ">= 0"),
        (("backbone", "duffing", "--amplitude-range", "0", "1"), "> 0"),
        (("backbone", "duffing", "--amplitude-range", "0.1", "1", "--mode", "-1"), "--mode"),
        (("continue", "hopf", "--range", "0", "1", "--bogus"), "No such option"),
        (("continue", "hopf", "--range", "0", "x"), "Invalid value"),
    ],
)
def test_user_errors_exit_2_with_one_line_and_no_traceback(bifid_cli, args, needle):
    """Check bad input: exit code 2, one line on stderr naming the problem, empty stdout."""
    r = bifid_cli(*args, "--json")
    assert r.code == 2, (r.code, r.stderr)
    assert r.stdout == ""
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and needle in lines[0], r.stderr


def test_truncated_branch_is_incomplete_with_exit_3(bifid_cli):
    """Check `continue flutter --range 14 20 --max-steps 2`: one JSON object with
    complete=false and the branch's end reason, then exit 3."""
    r = bifid_cli(
        "continue",
        "flutter",
        "--param",
        "U",
        "--range",
        "14",
        "20",
        "--max-steps",
        "2",
        "--json",
        "--quiet",
    )
    assert r.code == 3, r.stderr
    data = r.json
    assert data["complete"] is False and data["status"] == "steps"
    assert data["ends"][0]["reason"] == "steps" and "maximum number of steps" in data["message"]
    assert "incomplete" in r.stderr and "Traceback" not in r.stderr


def test_no_hopf_point_in_range_is_a_complete_answer(bifid_cli):
    """Check flutter at 5..10 m/s: a stable equilibrium branch, no Hopf point, exit 0."""
    r = bifid_cli("continue", "flutter", "--param", "U", "--range", "5", "10", "--json", "--quiet")
    assert r.code == 0, r.stderr
    data = r.json
    assert data["hopf"] == [] and data["orbits"] == [] and data["candidates"] == []
    assert data["complete"] is True and data["ends"] == [
        {"branch": 0, "param": 10.0, "reason": "range", "message": "reached the parameter bound 10"}
    ]


def test_van_der_pol_collision_is_not_a_second_hopf_point(bifid_cli):
    """Check `continue vanderpol --range -0.2 1.2`: the eigenvalue collision at mu = 1
    (a complex pair becoming two real ones) is neither a Hopf point nor a candidate; the
    one Hopf point is mu = 0, in the JSON and the summary line alike."""
    args = (
        "continue",
        "vanderpol",
        "--param",
        "mu",
        "--range",
        "-0.2",
        "1.2",
        "--no-orbits",
        "--quiet",
    )
    data = bifid_cli(*args, "--json").json
    (h,) = data["hopf"]
    assert abs(h["param"]) < 1e-12 and h["omega"] == pytest.approx(1.0, abs=1e-12)
    assert data["candidates"] == [] and data["complete"] is True
    r = bifid_cli(*args)
    assert r.code == 0 and "Hopf at mu = 0 (supercritical" in r.stdout
    assert "candidates" not in r.stdout


def _fold_field(x, p):
    # x' = mu - x^2 (a fold at mu = 0, x = 0), y' = -y
    return jnp.stack([p[0] - x[0] ** 2, -x[1]])


register(
    "fold_test",
    System(
        name="fold_test",
        states=("x", "y"),
        parameters=(Parameter("mu", 1.0),),
        field=_fold_field,
        default_param="mu",
    ),
    overwrite=True,
)


def test_x0_picks_the_branch_and_the_range_starts_at_its_first_value(bifid_cli):
    """Check `--x0` and a descending range on x' = mu - x^2: from x = -1 at mu = 1 the run
    goes down to the fold at mu = 0 (verified, state x = 0), turns and ends at mu = 1 on
    x = +1; from the default x0 = 0 (a singular start) it fails with a hint."""
    r = bifid_cli(
        "continue",
        "fold_test",
        "--param",
        "mu",
        "--range",
        "1",
        "-1",
        "--x0",
        "-0.9,0",
        "--json",
        "--quiet",
    )
    assert r.code == 0, r.stderr
    data = r.json
    (fold,) = data["folds"]
    assert abs(fold["param"]) < 1e-10 and abs(fold["state"]["x"]) < 1e-5
    assert fold["verification"]["tangent_param"] < 1e-6
    assert data["ends"][0]["param"] == pytest.approx(1.0) and data["hopf"] == []
    assert data["settings"]["x0"] == [-0.9, 0.0] and data["settings"]["range"] == [1.0, -1.0]
    r = bifid_cli("continue", "fold_test", "--param", "mu", "--range", "1", "-1", "--x0", "-0.9,0")
    assert r.stdout.startswith("fold_test: Hopf at mu = none; folds at 0; cycle folds at none;")
    r = bifid_cli("continue", "fold_test", "--param", "mu", "--range", "1", "-1", "--json")
    assert r.code == 3 and "x0" in r.stderr and r.stdout == ""


def test_continue_json_contract_and_outputs(bifid_cli, tmp_path):
    """Check `bifid continue hopf --json`: keys of the contract, values, plot and dataset files."""
    png, nc = tmp_path / "h.png", tmp_path / "h.nc"
    r = bifid_cli(
        "continue",
        "hopf",
        "--param",
        "mu",
        "--range",
        "-1",
        "1",
        "--set",
        "mu0=0.2",
        "--set",
        "a2=1",
        "--mesh",
        "16",
        "--json",
        "--quiet",
        "--plot",
        str(png),
        "--out",
        str(nc),
    )
    assert r.code == 0, r.stderr
    data = r.json
    (h,) = data["hopf"]
    assert set(h) >= {"param", "omega", "lyapunov", "criticality", "verification", "branch"}
    assert h["param"] == pytest.approx(0.2, abs=1e-10) and h["criticality"] == "subcritical"
    assert abs(h["verification"]["real_part"]) <= 1e-7
    (f,) = data["cycle_folds"]
    assert f["param"] == pytest.approx(0.2 - 0.25, abs=1e-8)
    assert set(f) >= {"param", "period", "amplitude"}
    o = data["orbits"][5]
    assert set(o) >= {"param", "period", "stable", "floquet_max", "amplitude", "branch"}
    assert set(o["amplitude"]) == {"u1", "u2"} and o["branch"] == 1
    assert data["complete"] is True and data["settings"]["parameters"]["mu0"] == 0.2
    assert [e["reason"] for e in data["ends"]] == ["range", "range"]
    assert png.stat().st_size > 10_000 and png.read_bytes()[:4] == b"\x89PNG"
    from bifid.data import load_dataset

    ds = load_dataset(nc)
    assert ds.attrs["bifid_kind"] == "lco" and ds.sizes["record"] == len(data["orbits"])


def test_newton_failure_is_reported_not_hidden(bifid_cli):
    """Check a failing continuation exits 3 with complete=false, never a silent partial branch."""
    r = bifid_cli(
        "frc", "duffing", "--forcing", "1e6", "--omega-range", "1.0", "1.1", "--json", "--quiet"
    )
    assert r.code == 3, r.stderr
    assert "Traceback" not in r.stderr
    if r.stdout:
        assert r.json["complete"] is False
