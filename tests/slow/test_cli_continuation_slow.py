"""Slow CLI checks of continuation (run with --runslow)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from test_continuation_vanderpol import simulated_orbit

pytestmark = pytest.mark.slow


def test_van_der_pol_has_exactly_one_hopf_point_and_true_orbits(bifid_cli):
    """Check `continue vanderpol --range -3 5 --json`: exactly one Hopf point, at mu = 0
    (the complex-to-real collisions of the origin's eigenvalues at mu = ±1 are not), a
    complete answer, and the orbits of the JSON nearest mu = 1, 2, 3, 5 against a direct
    simulation at their parameter: periods and amplitudes to 1e-8 relative, on the mesh
    each orbit records (relaxation oscillations need a finer mesh as mu grows)."""
    r = bifid_cli(
        "continue", "vanderpol", "--param", "mu", "--range", "-3", "5", "--json", "--quiet"
    )
    assert "Traceback" not in r.stderr
    data = r.json
    (h,) = data["hopf"]
    assert abs(h["param"]) < 1e-12 and h["omega"] == pytest.approx(1.0, abs=1e-12)
    assert not [c for c in data["candidates"] if c["kind"] == "hopf"]
    assert data["complete"] and r.code == 0
    meshes = []
    for mu in (1.0, 2.0, 3.0, 5.0):
        orbit = min(data["orbits"], key=lambda o: abs(o["param"] - mu))
        assert abs(orbit["param"] - mu) < 0.05
        period, amp = simulated_orbit(orbit["param"])
        assert orbit["period"] == pytest.approx(period, rel=1e-8), orbit["param"]
        amps = orbit["amplitude"]
        amps = [amps[k] for k in ("z1", "z2")]
        assert np.allclose(amps, amp, rtol=1e-8), orbit["param"]
        meshes.append(orbit["n_mesh"])
    assert meshes == sorted(meshes) and meshes[-1] > meshes[0]


def test_frc_finds_the_narrow_superharmonic_peak(bifid_cli):
    """Check `frc duffing --forcing 0.1 --omega-range 0.25 0.45 --set zeta=0.002 --set
    gamma=1`: the 3:1 superharmonic peak (0.1830 at Omega 0.3373, by shooting on the
    narrowed range) is found, not the range end."""
    r = bifid_cli(
        "frc",
        "duffing",
        "--forcing",
        "0.1",
        "--omega-range",
        "0.25",
        "0.45",
        "--set",
        "zeta=0.002",
        "--set",
        "gamma=1",
        "--json",
        "--quiet",
    )
    assert r.code == 0, r.stderr
    peak = r.json["peak"]
    assert peak["omega"] == pytest.approx(0.3373, abs=5e-5)
    assert peak["amplitude"] == pytest.approx(0.1830, abs=5e-5)


def test_backbone_of_the_second_mode_stays_on_it(bifid_cli):
    """Check `backbone shaw_pierre --mode 1 --amplitude-range 0.01 2`: every point on the
    second mode (frequency near sqrt(3), mode share > 0.99), amplitudes exactly the range."""
    r = bifid_cli(
        "backbone",
        "shaw_pierre",
        "--mode",
        "1",
        "--amplitude-range",
        "0.01",
        "2",
        "--json",
        "--quiet",
    )
    assert r.code == 0, r.stderr
    pts = r.json["points"]
    assert r.json["complete"] is True
    assert pts[0]["amplitude"] == pytest.approx(0.01, rel=1e-10)
    assert pts[-1]["amplitude"] == pytest.approx(2.0, rel=1e-10)
    assert all(abs(q["omega"] - np.sqrt(3)) < 2e-3 for q in pts)
    assert all(q["verification"]["mode_share"] > 0.99 for q in pts)
