"""A PP-CBC continuation whose start fails: the campaign records the failure with its
reason (in the result and in the dataset on disk), keeps the scan's points, and is not
complete."""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np

from bifid.cbc import VirtualRig, ppcbc_campaign
from bifid.data import load_dataset
from bifid.systems import get_system

START = -0.1  # both LCOs exist (q5 = 1: r = 0.33 unstable, 0.94 stable)
CAMPAIGN = dict(
    param="mu",
    overrides={"q5": 1.0},
    amplitudes=[0.2, 0.35, 0.5],
    param_scale=0.1,
    options={"stability": False, "settle_periods": 5.0, "measure_periods": 2.0, "n_harmonics": 3},
)


class _FailingRig(VirtualRig):
    """A virtual rig whose response vanishes after ``alive`` runs (an actuator that fails
    between the scan and the continuation started from it)."""

    def __init__(self, alive: float) -> None:
        super().__init__(get_system("hopf"), {"q5": 1.0, "mu": START}, sample_rate=100.0)
        self.alive, self.runs = alive, 0

    def run(self, duration: float):
        m = super().run(duration)
        self.runs += 1
        if self.runs <= self.alive:
            return m
        return dataclasses.replace(m, outputs=0.0 * m.outputs, derivatives=0.0 * m.derivatives)


def test_failed_continuation_start_is_recorded(tmp_path):
    """Check the failure path at the start of a continuation: the rig works for the scan
    at the start value (as many runs as the same scan alone takes) and then stops
    responding; the campaign must keep the scan's two LCOs (on the analytic radii),
    record a failure with a reason for the branch that could not be started, say it is
    incomplete, and write all of it to the dataset."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        counting = _FailingRig(alive=np.inf)
        scan = ppcbc_campaign("hopf", values=[START], rig=counting, **CAMPAIGN)
        assert len(scan.points) == 2 and not scan.failures
        out = tmp_path / "c.nc"
        r = ppcbc_campaign(
            "hopf",
            span=(START, -0.3),
            continuation=6,
            rig=_FailingRig(alive=counting.runs),
            out=out,
            **CAMPAIGN,
        )
    radii = sorted(p.amplitude["u1"] for p in r.points)
    disc = np.sqrt(1 + 4 * START)
    np.testing.assert_allclose(radii, np.sqrt([(1 - disc) / 2, (1 + disc) / 2]), rtol=5e-3)
    assert r.failures
    assert all(f.reason for f in r.failures)
    assert any("could not be" in f.reason for f in r.failures)
    d = r.diagram.to_json()
    assert d["complete"] is False
    saved = load_dataset(out)
    assert saved.sizes["record"] == 2
    failures = json.loads(saved.attrs["cbc_campaign"])["failures"]
    assert [f["reason"] for f in failures] == [f.reason for f in r.failures]
