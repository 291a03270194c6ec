"""CBC settings derived from the system: a system without CBC settings works at once.

The built-in systems carry CBC settings validated on their rigs (``System.cbc``); these
tests strip them, so that every setting -- sample rate, gains, amplitude grid, frequency --
is derived from the linearisation and a first continuation run, and check that a first
campaign with no option but the values measures what the system's analytic or continued
curves say.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from bifid.cbc import defaults_for, forced_campaign, ppcbc_campaign
from bifid.systems import get_system


def _plain(name: str):
    return dataclasses.replace(get_system(name), name=f"{name}_plain", cbc={})


def test_system_settings_override_derived_ones():
    """Check System.cbc wins where it speaks, derivation elsewhere, and that the settings
    tied to the amplitudes are derived again for other parameter values."""
    d = defaults_for("flutter")
    assert (d.kp, d.kd, d.sample_rate) == (-150.0, -20.0, 5000.0)
    assert d.origin["kp"] == "system" and d.origin["n_harmonics"] == "derived"
    variant = defaults_for("flutter", {"ka3": 6000.0})
    assert variant.kp == -150.0 and variant.origin.get("amplitude_range") != "system"


def test_derived_forced_settings_measure_the_scurve():
    """Check duffing without CBC settings: the S-curve at Ω = 1.05 with derived settings
    (ω = 1 from the linearisation: kp = 1/2, kd = 1/2, 500 samples per period) goes round
    both folds, located within 1 % of continuation (0.0215934, 0.0109005)."""
    s = _plain("duffing")
    d = defaults_for(s)
    assert d.kp == pytest.approx(0.5, rel=0.01) and d.kd == pytest.approx(0.5, rel=0.01)
    assert d.omega_guess == pytest.approx(1.0, rel=0.01) and d.sample_rate >= 50
    r = forced_campaign(s, "scurve", omega=1.05, span=(0.005, 0.026))
    folds = r.diagram.to_json()["folds"]
    assert r.complete and len(folds) == 2
    assert folds[0]["forcing"] == pytest.approx(0.0215934, rel=0.01)
    assert folds[1]["forcing"] == pytest.approx(0.0109005, rel=0.01)


@pytest.mark.slow
def test_derived_ppcbc_settings_measure_the_cycles():
    """Check the subcritical Hopf normal form (q5 = 1) without CBC settings: gains chosen
    by the controlled Floquet multipliers of the continued cycles, the amplitude grid from
    their amplitudes; both LCOs at μ = -0.1 within 1 % of r⁴ - r² = μ, correctly labelled.

    Slow (about a minute): the continuation of the cycles and the batched Floquet
    multipliers of 12 gain candidates are compiled for a new system."""
    s = _plain("hopf")
    d = defaults_for(s, {"q5": 1.0}, param="mu", param_range=(-0.15, -0.05))
    assert d.origin["kp"] == "derived" and d.origin["amplitude_range"] == "derived"
    r = ppcbc_campaign(s, param="mu", values=[-0.1], overrides={"q5": 1.0}, defaults=d)
    assert r.complete
    amps = sorted((p.amplitude[d.x1], p.stable) for p in r.points)
    assert [st for _, st in amps] == [False, True]
    for (a, _), exact in zip(
        amps,
        (math.sqrt((1 - math.sqrt(0.6)) / 2), math.sqrt((1 + math.sqrt(0.6)) / 2)),
        strict=True,
    ):
        assert a == pytest.approx(exact, rel=0.01)


BRUSSELATOR = Path(__file__).resolve().parents[1] / "docs/examples/systems/brusselator.toml"


def test_user_system_rests_at_its_equilibrium():
    """Check the Brusselator (equilibrium (a, b/a) = (1, 1.5), away from the origin): the
    derived defaults find it from the file's own x0, centre the first PP-CBC target on it
    (x = a; the derivative's centre is 0), take the frequency of its linearisation
    (eigenvalues (b - 1 - a²)/2 ± i sqrt(a² - ((b - 1 - a²)/2)²) = -0.25 ± 0.968i) and the
    virtual rig starts at rest there."""
    s = get_system(str(BRUSSELATOR))
    d = defaults_for(s)
    assert d.equilibrium == pytest.approx({"x": 1.0, "y": 1.5}, abs=1e-10)
    assert d.omega_guess == pytest.approx(math.sqrt(1.0 - 0.25**2), rel=1e-9)
    assert d.ppcbc_options().centre == pytest.approx((1.0, 0.0), abs=1e-10)
    m = d.rig(s).run(2.0)
    assert m.status == "ok"
    assert np.max(np.abs(m.signal("x") - 1.0)) < 1e-9
