"""Slow CLI checks of continuation (run with --runslow)."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.slow


def test_van_der_pol_has_exactly_one_hopf_point(bifid_cli):
    """Check `continue vanderpol --range -3 5 --json`: exactly one Hopf point, at mu = 0
    (the complex-to-real collisions of the origin's eigenvalues at mu = ±1 are not)."""
    r = bifid_cli("continue", "vanderpol", "--param", "mu", "--range", "-3", "5", "--json",
                  "--quiet")
    assert "Traceback" not in r.stderr
    data = r.json
    (h,) = data["hopf"]
    assert abs(h["param"]) < 1e-12 and h["omega"] == pytest.approx(1.0, abs=1e-12)
    assert not [c for c in data["candidates"] if c["kind"] == "hopf"]
