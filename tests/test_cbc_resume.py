"""Campaigns interrupted anywhere resume exactly: S-curve, FRC and PP-CBC continuation.

Each campaign (small grids, measurement noise on, one seed) is run once uninterrupted;
then the same campaign is interrupted again and again -- alternately as SIGINT does (a
``KeyboardInterrupt`` raised between or inside the rig's evaluations) and as SIGKILL does
(the process stops without any clean-up: the file as last written, and a temporary file
of a write in progress left beside it) -- and resumed each time, until it finishes. The
resumed file must equal the uninterrupted one in every measured value to 1e-12 relative
(provenance attributes aside); no temporary file may be left; and resuming the finished
campaign must change nothing.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from bifid.cbc import forced_campaign, ppcbc_campaign
from bifid.data import load_dataset

BASE = dict(n_harmonics=3, settle_periods=4, measure_periods=2, stability=False)


class Killed(BaseException):
    """The process stopped, no clean-up (as SIGKILL)."""


def _run(
    protocol: str, out, resume: bool = False, stop_after: int | None = None, how: str = "sigint"
):
    """The campaign; stopped after ``stop_after`` rig evaluations if given."""
    count = [0]

    def on_evaluation(k: int) -> None:
        count[0] += k
        if stop_after is not None and count[0] >= stop_after:
            raise KeyboardInterrupt if how == "sigint" else Killed

    kw = dict(
        out=out,
        resume=resume,
        seed=7,
        on_evaluation=on_evaluation,
        rig_options={"sample_rate": 40.0},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if protocol == "scurve":
            return forced_campaign(
                "duffing",
                "scurve",
                omega=1.05,
                span=(0.008, 0.03),
                noise=2e-4,
                options=dict(BASE, kp=0.5, kd=0.5, ds=0.15, ds_max=0.3, max_points=12),
                **kw,
            )
        if protocol == "frc":
            return forced_campaign(
                "duffing",
                "frc",
                forcing=0.01,
                span=(0.98, 1.06),
                noise=2e-4,
                options=dict(BASE, kp=0.5, kd=0.5, ds=0.15, ds_max=0.3, max_points=12),
                **kw,
            )
        return ppcbc_campaign(
            "hopf",
            param="mu",
            span=(-0.1, -0.3),
            continuation=6,
            overrides={"q5": 1.0},
            amplitudes=[0.25, 0.45],
            ds=0.6,
            param_scale=0.1,
            noise=1e-3,
            options=dict(BASE, n_harmonics=2),
            **kw,
        )


def _equal(a, b) -> float:
    """Largest relative difference of two datasets' numeric variables (inf if they differ
    in shape or in which values are missing)."""
    worst = 0.0
    if a.sizes != b.sizes or set(a.data_vars) != set(b.data_vars):
        return np.inf
    for v in a.data_vars:
        x, y = a[v].values, b[v].values
        if x.dtype.kind != "f":
            if not np.array_equal(x, y):
                return np.inf
            continue
        if not np.array_equal(np.isnan(x), np.isnan(y)):
            return np.inf
        m = ~np.isnan(x)
        if m.any():
            worst = max(
                worst, float(np.max(np.abs(x[m] - y[m]) / np.maximum(np.abs(x[m]), 1e-300)))
            )
    return worst


@pytest.mark.parametrize("protocol", ["scurve", "frc", "ppcbc"])
def test_interrupted_campaign_resumes_exactly(tmp_path, protocol):
    """Check ≥ 10 interruptions (SIGINT and SIGKILL alternately) resume to the
    uninterrupted file."""
    ref = tmp_path / "ref.nc"
    full = _run(protocol, ref)
    assert full.complete and len(full.points) >= 6
    out = tmp_path / "cut.nc"
    stops, step, last = 0, 4, -1
    while True:
        how = "sigint" if stops % 2 == 0 else "sigkill"
        try:
            r = _run(protocol, out, resume=out.exists(), stop_after=step, how=how)
        except (KeyboardInterrupt, Killed):
            stops += 1
            assert stops < 100
            if how == "sigkill" and out.exists():  # a write in progress when killed
                (tmp_path / f".{out.name}.abc123.tmp").write_bytes(b"partial")
            n = load_dataset(out).sizes["record"] if out.exists() else 0
            # stop elsewhere next time; later if nothing was recorded since the last stop
            step = 2 * step if n == last else 4 + 2 * (stops % 3)
            last = n
            continue
        break
    assert stops >= 10, f"only {stops} interruptions"
    assert r.complete
    assert not list(tmp_path.glob(".*.tmp"))
    a, b = load_dataset(ref), load_dataset(out)
    assert _equal(a, b) <= 1e-12
    before = out.read_bytes()
    again = _run(protocol, out, resume=True)
    assert again.points == [] and out.read_bytes() == before
