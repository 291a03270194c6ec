"""PP-CBC on the Hopf normal form (Example 3.2) against analytic limit cycles.

``hopf`` in polar form: ṙ = (μ - μ0) r + a2 r³ - q5 r⁵, θ̇ = ω0. LCOs: with q5 = 0,
r² = -(μ - μ0)/a2 (eq. 3.16, unstable for a2 > 0); with q5 = 1,
r² = (a2 ± sqrt(a2² + 4(μ - μ0)))/2 (− unstable, + stable), folding at μ0 - a2²/4.
"""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest

from bifid.cbc import (
    AbstractRig,
    Measurement,
    PolarTarget,
    PPCBCOptions,
    VirtualRig,
    ppcbc_campaign,
    ppcbc_scan,
)
from bifid.data import load_dataset
from bifid.errors import ConvergenceWarning
from bifid.systems import get_system

OPTS = dict(
    x1="u1",
    x2="u2",
    kp=1.0,
    kd=0.0,
    n_harmonics=3,
    settle_periods=5.0,
    measure_periods=2.0,
    watch_periods=10.0,
)


def r_lco(mu: float, q5: float, a2: float = 1.0) -> tuple[float, ...]:
    if q5 == 0:
        return (math.sqrt(-mu / a2),)
    d = math.sqrt(a2**2 + 4 * mu)
    return (math.sqrt((a2 - d) / 2), math.sqrt((a2 + d) / 2))


@pytest.fixture(scope="module")
def hopf():
    return get_system("hopf")


@pytest.mark.parametrize("target", ["elliptic", "polar"])
def test_example_3_2_unstable_lco(hopf, target):
    """Check PP-CBC finds the unstable LCO of eq. 3.16 (λ = -0.1): r = √0.1, unstable."""
    rig = VirtualRig(hopf, {"mu": -0.1, "q5": 0.0}, sample_rate=100.0)
    opts = PPCBCOptions(target=target, **OPTS)
    pts, fails = ppcbc_scan(rig, "mu", -0.1, np.linspace(0.15, 0.33, 4), opts)
    assert not fails
    assert len(pts) == 1
    pt = pts[0]
    assert pt.amplitude["u1"] == pytest.approx(math.sqrt(0.1), rel=1e-3)
    assert pt.amplitude["u2"] == pytest.approx(math.sqrt(0.1), rel=1e-3)
    assert pt.frequency == pytest.approx(1.0, rel=1e-4)
    assert pt.stable is False
    assert pt.invasiveness < 1e-2
    assert pt.growth > 1.0


def test_subcritical_pair_with_noise(hopf):
    """Check both LCOs of the subcritical q5 = 1 case, labels, with 1 % measurement noise."""
    mu = -0.1
    r_u, r_s = r_lco(mu, 1.0)
    noise = 0.01 * r_u
    rig = VirtualRig(hopf, {"mu": mu, "q5": 1.0}, sample_rate=100.0, noise=noise, seed=1)
    opts = PPCBCOptions(target="polar", **{**OPTS, "measure_periods": 4.0})
    pts, fails = ppcbc_scan(rig, "mu", mu, np.linspace(0.2, 1.1, 6), opts)
    assert not fails
    assert [p.stable for p in pts] == [False, True]
    assert pts[0].amplitude["u1"] == pytest.approx(r_u, rel=0.03)
    assert pts[1].amplitude["u1"] == pytest.approx(r_s, rel=0.03)


@pytest.mark.parametrize("mu, kp", [(-0.0025, 3.0), (-0.01, 1.0)])
def test_near_hopf_lco_with_noise_is_accurate_or_refused(hopf, mu, kp):
    """Check a small LCO near the Hopf point with 1 % noise: its control error is flat in
    A* (slope of order |μ|/kp: the response follows the target), so the noise moves the
    zero by percent. Every point is within 1 % of r = √-μ, or the LCO is refused as noise-limited
    (at μ = -0.0025 with kp = 3, where the measured zero scatters by ±1.5 %); the one
    farther from the Hopf point (μ = -0.01, kp = 1) is measured."""
    r = math.sqrt(-mu)
    for seed in (1, 2):
        rig = VirtualRig(hopf, {"mu": mu, "q5": 0.0}, sample_rate=100.0, noise=0.01 * r, seed=seed)
        opts = PPCBCOptions(
            target="polar", **{**OPTS, "kp": kp, "measure_periods": 4.0, "stability": False}
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            pts, fails = ppcbc_scan(rig, "mu", mu, np.linspace(0.6 * r, 1.5 * r, 4), opts)
        assert all(abs(p.amplitude["u1"] / r - 1.0) <= 0.01 for p in pts)
        assert pts or any("standard error" in f.reason for f in fails)
        if mu == -0.01:
            assert len(pts) == 1


#: a PP-CBC continuation campaign on the subcritical ``hopf`` system (q5 = 1), kept short
HOPF_CAMPAIGN = dict(
    overrides={"q5": 1.0},
    param_scale=0.1,
    rig_options={"sample_rate": 100.0},
    options={"stability": False, "settle_periods": 5.0, "measure_periods": 2.0, "n_harmonics": 3},
)


def test_campaign_continues_round_the_fold(tmp_path):
    """Check a continuation campaign (scan, then the measured zero problem on the
    continuation driver) through the cycle fold.

    Starting on the unstable LCO at μ = -0.1 and moving to smaller μ, the q5 = 1 branch
    folds at μ = -1/4 and returns on the stable side; every point must lie on the
    analytic curve r⁴ - r² - μ = 0 within 0.5 %, the fold located on the measured
    points within 1 % of -1/4, and the dataset written point by point must hold the scan's
    LCOs and every continuation point.
    """
    out = tmp_path / "hopf.nc"
    r = ppcbc_campaign(
        "hopf",
        param="mu",
        span=(-0.1, -0.3),
        continuation=8,
        amplitudes=[0.2, 0.35, 0.5],
        ds=0.5,
        out=out,
        **HOPF_CAMPAIGN,
    )
    d = r.diagram.to_json()
    assert d["complete"] and not r.failures
    cont = [p for p in r.points if p.branch == "continuation"]
    assert len(cont) == 8
    mus = np.array([p.param for p in r.points])
    rs = np.array([p.amplitude["u1"] for p in r.points])
    np.testing.assert_allclose(rs**4 - rs**2 - mus, 0.0, atol=5e-3 * np.max(rs**2))
    assert rs[0] == pytest.approx(r_lco(-0.1, 1.0)[0], rel=2e-3)  # the scan's first LCO
    assert min(p.param for p in cont) < -0.2  # went towards the fold at -0.25 ...
    assert cont[-1].amplitude["u1"] > 1 / math.sqrt(2)  # ... and came back stable (r² > 1/2)
    assert np.all(np.diff([p.amplitude["u1"] for p in cont]) > 0)
    assert [f["param"] for f in d["cycle_folds"]] == [pytest.approx(-0.25, rel=0.01)]
    saved = load_dataset(out)
    assert saved.attrs["bifid_kind"] == "lco" and saved.sizes["record"] == len(r.points)
    np.testing.assert_allclose(saved["param"].values, mus)
    assert json.loads(saved.attrs["settings"])["campaign"]["protocol"] == "ppcbc"


def test_default_step_follows_a_short_unstable_branch():
    """Check the default arclength step of a continuation campaign scales with its range.

    From μ = -0.2 to -0.26 the unstable LCO (r = 0.526 at the start) climbs to the cycle
    fold (μ = -1/4, r = 1/√2) over a fraction of the range; with the default step the
    campaign measures points along it (at least three between the start and the fold,
    none more than a third of the way between them in one step), not one step across it.
    """
    r = ppcbc_campaign(
        "hopf",
        param="mu",
        span=(-0.2, -0.26),
        continuation=10,
        amplitudes=[0.3, 0.45, 0.6],
        **HOPF_CAMPAIGN,
    )
    assert not r.failures
    cont = [p for p in r.points if p.branch == "continuation"]
    rs = np.array([p.amplitude["u1"] for p in cont])
    mus = np.array([p.param for p in cont])
    np.testing.assert_allclose(rs**4 - rs**2 - mus, 0.0, atol=5e-3)
    start = r_lco(-0.2, 1.0)[0]
    unstable = np.r_[start, rs[rs < 1 / math.sqrt(2)]]
    assert len(unstable) >= 4
    assert np.max(np.diff(unstable)) <= (1 / math.sqrt(2) - start) / 3


def test_destabilising_controller_is_reported_not_recorded(hopf):
    """Check a controller that cannot hold the orbit yields failures and no points."""
    rig = VirtualRig(hopf, {"mu": -0.1, "q5": 0.0}, sample_rate=100.0)
    opts = PPCBCOptions(target="polar", **{**OPTS, "kp": 0.2})  # kp/2 < 2 r0² = 0.2
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pts, fails = ppcbc_scan(rig, "mu", -0.1, np.linspace(0.15, 0.45, 4), opts)
    assert pts == []
    assert fails
    assert any(issubclass(w.category, ConvergenceWarning) for w in caught)


class _OffCentreRig(AbstractRig):
    """A rig that draws the unit circle round the origin for the bootstrap's ellipse
    and, for any polar target, a circle beside the origin (a controller that lost lock:
    the response does not go round the target's centre)."""

    output_names = ("u1", "u2")
    sample_rate = 100.0

    def __init__(self) -> None:
        self.t, self.target, self.params = 0.0, None, {"mu": 0.0}

    @property
    def time(self) -> float:
        return self.t

    def get_parameter(self, name: str) -> float:
        return self.params[name]

    def set_parameter(self, name: str, value: float) -> None:
        self.params[name] = value

    def set_forcing(self, amplitude, frequency=None, phase=0.0) -> None:
        pass

    def set_controller(self, controller, target=None) -> None:
        self.target = target

    def run(self, duration: float) -> Measurement:
        n = max(1, round(duration * self.sample_rate))
        t = self.t + np.arange(n) / self.sample_rate
        self.t = float(t[-1]) + 1.0 / self.sample_rate
        shift = 3.0 if isinstance(self.target, PolarTarget) else 0.0
        y = np.column_stack([shift + np.cos(t), np.sin(t)])
        dy = np.column_stack([-np.sin(t), np.cos(t)])
        zero = np.zeros(n)
        return Measurement(
            time=t,
            outputs=y,
            output_names=self.output_names,
            derivatives=dy,
            control=zero,
            target=zero,
            force=zero,
            phase=np.full(n, np.nan),
            sample_rate=self.sample_rate,
        )


def test_lost_lock_is_a_failure_not_a_target():
    """Check a response that does not go round the polar target's centre fails the scan
    with its reason instead of being read as an orbit (its fit in φ is ill-conditioned)."""
    opts = PPCBCOptions(target="polar", **OPTS)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pts, fails = ppcbc_scan(_OffCentreRig(), "mu", 0.0, [0.5, 1.0, 1.5], opts)
    assert pts == []
    assert len(fails) == 1
    assert "lost lock" in fails[0].reason
    assert "0.0 turns" in fails[0].reason
