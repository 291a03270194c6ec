"""A user's own system through ``bifid cbc`` with no option but the values.

The Brusselator of ``docs/examples/systems/brusselator.toml`` (equations in a file, its
equilibrium (a, b/a) away from the origin, a supercritical Hopf point at b = 1 + a² = 2)
gets every CBC setting derived from its linearisation and a first continuation run; its
stable limit cycles at b = 2.2 and 2.5 must be measured, labelled stable, and agree with
the cycles Newton-corrected at the same b (``--truth``) within 1 %.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

BRUSSELATOR = Path(__file__).resolve().parents[2] / "docs/examples/systems/brusselator.toml"

pytestmark = pytest.mark.slow


def test_brusselator_cycles_with_derived_settings(tmp_path, bifid_cli):
    """Check both cycles measured, stable, within 1 % of the corrected orbits."""
    out = tmp_path / "b.nc"
    r = bifid_cli(
        "cbc",
        BRUSSELATOR,
        "--protocol",
        "ppcbc",
        "--values",
        "2.2,2.5",
        "--out",
        out,
        "--json",
        "--quiet",
    )
    assert r.code == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["complete"] is True
    pts = sorted(d["points"], key=lambda p: p["param"])
    assert [p["param"] for p in pts] == [2.2, 2.5]
    for p in pts:
        assert p["stable"] is True
        assert p["truth_stable"] is True
        assert max(abs(e) for e in p["relative_error"].values()) < 0.01
