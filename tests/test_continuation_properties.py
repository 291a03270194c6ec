"""Property test: the bifurcation diagrams of random variants of every built-in autonomous
system against an independent dense eigenvalue scan (``tests/_properties.py``): no false
and no missed Hopf point, fold or real crossing; orbits and forced responses against
independent Floquet multipliers. One variant per system (one with orbits, one forced)
here; twenty per system in ``benchmarks/bench_properties.py``."""

from __future__ import annotations

import pytest

from _properties import autonomous_builtins, run_variant, variants

SAMPLE = [v for name in autonomous_builtins() for v in variants(name, 1, seed=1)]


@pytest.mark.parametrize("variant", SAMPLE, ids=lambda v: v.system)
def test_equilibrium_special_points_match_an_independent_scan(variant):
    """Check one random variant per system: every located Hopf point and fold is in the
    scan, and every Hopf point and real crossing of the scan is located or flagged."""
    _, failures = run_variant(variant)
    assert failures == [], variant.label


ORBIT_SAMPLE = variants("hopf", 1, seed=1) + variants("duffing", 1, seed=1)


@pytest.mark.parametrize("variant", ORBIT_SAMPLE, ids=lambda v: v.system)
def test_orbits_and_forced_responses_match_independent_multipliers(variant):
    """Check one variant with orbits (hopf) and one FRC (duffing): stability labels, every
    change of stability at a located point and every located orbit bifurcation against
    Floquet multipliers integrated by SciPy."""
    diagram, failures = run_variant(variant, orbits=True)
    assert failures == [], variant.label
    assert any(b.kind != "equilibrium" and len(b) > 10 for b in diagram.branches)
