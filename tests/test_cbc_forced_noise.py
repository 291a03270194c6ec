"""Folds of noisy measured forced-response curves: exactly the true folds, none from noise.

Near a fold a measured curve is tangent to the direction of its parameter, so the points
are close in that parameter and the measurement noise can reverse it between two points:
a pair of spurious folds. The references are independent of CBC: the duffing FRC at
γ = 0.01 and its folds from numerical continuation (:func:`bifid.continuation.frc`).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from bifid.cbc import (
    ForcedCBCOptions,
    ForcedPoint,
    FourierTarget,
    VirtualRig,
    folds_of,
    frc_cbc,
)
from bifid.continuation import ContinuationOptions, frc
from bifid.systems import get_system

FORCING = 0.01


@pytest.fixture(scope="module")
def truth():
    br = frc(
        get_system("duffing"),
        FORCING,
        (0.95, 1.12),
        n_mesh=8,
        options=ContinuationOptions(ds=0.02, ds_min=1e-9, ds_max=0.05, max_steps=2000),
    )
    folds = sorted(sp.param for sp in br.special("fold"))
    assert len(folds) == 2
    return np.asarray(br.params), np.asarray(br.data["observed_amplitude"]), folds


def _points(omega: np.ndarray, amp: np.ndarray) -> list[ForcedPoint]:
    return [
        ForcedPoint(
            omega=float(w),
            forcing=FORCING,
            force_phase=0.0,
            target=FourierTarget(np.zeros(3)),
            coefficients=np.zeros(3),
            measurement=None,
            amplitude=float(a),
            phase=0.0,
        )
        for w, a in zip(omega, amp, strict=True)
    ]


def _along(w: np.ndarray, a: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points at uniform arclength in the normalised ``(Ω, A)`` plane (as a measured
    curve's steps: close in Ω near the folds)."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(w) / np.ptp(w), np.diff(a) / np.ptp(a)))])
    at = np.linspace(0.0, s[-1], n)
    return np.interp(at, s, w), np.interp(at, s, a)


@pytest.mark.parametrize("seed", range(6))
def test_noisy_points_along_the_frc_give_exactly_its_two_folds(truth, seed):
    """Check points scattered about the continuation FRC (σ = 1 % of the width of the
    bistable range in Ω, 0.2 % in A) give exactly its two folds, each within 5 % of that
    width, though the scatter reverses Ω between neighbouring points near the folds."""
    w, a, folds = truth
    wi, ai = _along(w, a, 120)
    rng = np.random.default_rng(seed)
    width = folds[1] - folds[0]
    wn = wi + 0.01 * width * rng.standard_normal(wi.shape)
    an = ai * (1.0 + 0.002 * rng.standard_normal(ai.shape))
    dw = np.diff(wn)
    assert np.count_nonzero(dw[1:] * dw[:-1] < 0) > 2  # the noise reverses Ω
    got = sorted(f["omega"] for f in folds_of(_points(wn, an), "omega"))
    assert len(got) == 2
    for g, ref in zip(got, folds, strict=True):
        assert abs(g - ref) < 0.05 * width
        assert g == pytest.approx(ref, rel=0.02)


def test_noise_free_coarse_curve_keeps_its_folds(truth):
    """Check a coarse noise-free curve (a few points round each fold) keeps both folds:
    the noise estimate does not take the shape of a fold for noise."""
    w, a, folds = truth
    got = sorted(f["omega"] for f in folds_of(_points(*_along(w, a, 25)), "omega"))
    assert len(got) == 2
    width = folds[1] - folds[0]
    for g, ref in zip(got, folds, strict=True):
        assert abs(g - ref) < 0.1 * width


@pytest.mark.slow
def test_noisy_frc_on_the_rig_reports_exactly_two_folds(truth):
    """Check a measured FRC with 1 % measurement noise on the virtual duffing rig reports
    exactly the two folds of continuation, each within 2 % of the width of the bistable
    range."""
    _, a, folds = truth
    rig = VirtualRig(
        get_system("duffing"), sample_rate=100.0, noise={"q": 0.01 * float(a.max())}, seed=2
    )
    opts = ForcedCBCOptions(signal="q", kp=0.1, kd=0.1, settle_periods=20, measure_periods=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pts, fails = frc_cbc(rig, FORCING, (1.0, 1.06), opts)
    assert not fails
    got = sorted(f["omega"] for f in folds_of(pts, "omega"))
    assert len(got) == 2
    width = folds[1] - folds[0]
    for g, ref in zip(got, folds, strict=True):
        assert abs(g - ref) < 0.02 * width
