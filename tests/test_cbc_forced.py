"""CBC of forced systems (§3.2): the duffing S-curve at Ω = 1.05 round both folds.

The reference is independent of CBC: every measured point is compared with the
uncontrolled system's periodic response at exactly the measured forcing, found by
Newton's method on the Fourier collocation equations started from the rig's true
states; the folds are compared with numerical continuation
(``bifid scurve duffing --omega 1.05 --forcing-range 0.002 0.04``: F = 0.0215934 and
0.0109005, recomputed in ``tests/slow/test_cbc_accuracy.py``).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from bifid.cbc import ForcedCBCOptions, VirtualRig, folds_of, frc_cbc, scurve_cbc
from bifid.continuation.truth import correct_forced, orbit_from_samples
from bifid.errors import ConvergenceWarning
from bifid.signal import max_abs
from bifid.systems import get_system

FOLDS_CONTINUATION = (0.0215934, 0.0109005)


@pytest.fixture(scope="module")
def duffing_scurve():
    s = get_system("duffing")
    rig = VirtualRig(s, sample_rate=50.0, record_states=True)
    opts = ForcedCBCOptions(
        signal="q",
        kp=0.5,
        kd=0.5,
        n_harmonics=3,
        settle_periods=6,
        measure_periods=2,
        ds=0.1,
        ds_max=0.15,
        stability=False,
    )
    pts, fails = scurve_cbc(rig, 1.05, (0.008, 0.026), opts)
    return s, pts, fails


def test_scurve_goes_round_both_folds(duffing_scurve):
    """Check the S-curve is followed from the lower to the upper branch with 2 folds,
    from one end of the forcing range to the other."""
    _, pts, fails = duffing_scurve
    assert not fails
    amps = np.array([p.amplitude for p in pts])
    assert np.all(np.diff(amps) > 0)  # amplitude grows along an S-curve
    assert pts[0].forcing == pytest.approx(0.008) and pts[-1].forcing == pytest.approx(0.026)
    folds = folds_of(pts)
    assert len(folds) == 2
    for f, ref in zip(folds, FOLDS_CONTINUATION, strict=True):
        assert f["forcing"] == pytest.approx(ref, rel=0.02)
    middle = [p for p in pts if folds[0]["amplitude"] < p.amplitude < folds[1]["amplitude"]]
    assert len(middle) >= 5  # the unstable middle branch is measured


def test_points_are_responses_of_the_uncontrolled_system(duffing_scurve):
    """Check amplitudes within 1 % of the uncontrolled response at the same forcing.

    Each point's true states are Newton-corrected (forced collocation) at its own
    (γ, Ω); the control is non-invasive, so the correction must barely move them. (A
    point on a fold -- within 0.1 % of its γ -- is not checked: Newton at a fixed γ is
    singular there.)
    """
    s, pts, _ = duffing_scurve
    worst = 0.0
    for p in pts:
        if min(abs(p.forcing / f - 1.0) for f in FOLDS_CONTINUATION) < 1e-3:
            continue
        m = p.measurement
        V = orbit_from_samples(m.extra["states"], m.phase - p.force_phase, m.sample_rate, n_mesh=32)
        Vc = correct_forced(s, p.omega, p.forcing, V, n_mesh=32)
        a_true = float(max_abs(Vc[:, 0]))
        worst = max(worst, abs(p.amplitude / a_true - 1.0))
        assert p.invasiveness < 2e-3
    assert worst < 0.01


def test_force_update_matches_eq_3_6_with_exact_derivative():
    """Check the control force of the rig's PD controller equals eq. 3.6 when the
    derivative comes from the state: its first harmonic, projected here on whole periods of
    the generator phase, against ``kp d + kd Ω`` applied to the target's minus the
    response's first harmonic."""
    from bifid.cbc import FourierTarget
    from bifid.signal import fourier_project, whole_periods

    s = get_system("duffing")
    rig = VirtualRig(s, sample_rate=100.0, derivative="state")
    opts = ForcedCBCOptions(signal="q", kp=0.5, kd=0.5, n_harmonics=3)
    q, Om = 3, 1.05
    rig.set_forcing(0.01, Om, 0.0)
    pstar = np.array([0.0, 0.1, 0.0, 0.0, 0.02, 0.0, 0.0])
    rig.set_controller(opts.controller, FourierTarget(pstar))
    rig.run(30 * 2 * np.pi / Om)  # settle
    m = rig.run(10 * 2 * np.pi / Om + 0.02)
    m = m.tail(whole_periods(len(m), Om, m.sample_rate))
    c = fourier_project(np.column_stack([m.signal("q"), m.control]), m.phase, q)
    p, u = c[:, 0], c[:, 1]
    d = pstar - p
    A_hat = opts.kp * d[1] + Om * opts.kd * d[q + 1]  # eq. 3.6, cos part of u
    B_hat = opts.kp * d[q + 1] - Om * opts.kd * d[1]  # sin part
    assert u[1] == pytest.approx(A_hat, rel=1e-3, abs=1e-9)
    assert u[q + 1] == pytest.approx(B_hat, rel=1e-3, abs=1e-9)


# ------------------------------------------------------------------ measurement noise
def test_band_noise_is_the_scatter_of_a_fundamental_of_blue_noise():
    """Check the control's noise floor: 3 × RMS of its fundamental, not of its samples.

    A PD controller fed with white measurement noise ε gives ``u = kp ε + kd ε̇`` -- blue
    noise, nearly all of its power far above Ω. ``band_noise`` must give 3 × the RMS
    magnitude of the fitted fundamental ``(a_1, b_1)`` over many records (within 25 %),
    while the white-noise formula on the samples overstates it > 10× (the cause of the
    accepted-but-invasive points of noisy S-curves). Part of that scatter enters through
    the record's ends (``kd (e_n - e_0)/Δt``) and falls on ``a_1`` or ``b_1`` by the end
    phase: both a whole-sample period (6 s at 100 Hz) and a non-integer one (Ω = 1.05).
    """
    from bifid.signal import (
        band_noise,
        coefficient_noise,
        evaluate_series,
        fourier_project,
    )

    rng = np.random.default_rng(0)
    fs, kp, kd, sig = 100.0, 0.5, 0.5, 0.01
    for om in (2 * np.pi / 6.0, 1.05):
        n = round(6 * 2 * np.pi / om * fs)  # 6 periods
        theta = om * np.arange(n) / fs + 0.7
        c1, floors, white = [], [], []
        for _ in range(300):
            e = sig * rng.normal(size=n + 1)
            u = kp * e[1:] + kd * np.diff(e) * fs  # backward-difference derivative
            c = fourier_project(u, theta, 3)
            r = u - evaluate_series(c, theta)
            c1.append((c[1], c[4]))
            floors.append(band_noise(r, om, fs))
            white.append(coefficient_noise(r))
        rms = float(np.sqrt(np.mean(np.sum(np.square(c1), axis=1))))
        assert np.mean(floors) / 3 == pytest.approx(rms, rel=0.25)
        assert np.mean(white) / 3 > 10 * rms


def _noisy_run(sigma: float, gains: float, max_points: int, protocol, **opts):
    """``protocol(rig, options)`` on a duffing rig with noise ``sigma`` on q; returns the
    system, points, failures and the ConvergenceWarnings raised."""
    s = get_system("duffing")
    rig = VirtualRig(s, sample_rate=100.0, noise={"q": sigma}, seed=3, record_states=True)
    o = ForcedCBCOptions(
        signal="q",
        kp=gains,
        kd=gains,
        n_harmonics=3,
        settle_periods=20,
        measure_periods=3,
        max_points=max_points,
        **opts,
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pts, fails = protocol(rig, o)
    return s, pts, fails, [w for w in caught if issubclass(w.category, ConvergenceWarning)]


def _noisy_duffing(gains: float, lo: float, max_points: int, **opts):
    """A duffing S-curve (Ω = 1.05) with σ = 1 % of its largest amplitude (0.63) on q."""
    return _noisy_run(
        0.0063, gains, max_points, lambda rig, o: scurve_cbc(rig, 1.05, (lo, 0.03), o), **opts
    )


def _amplitude_error(s, p) -> float:
    m = p.measurement
    V = orbit_from_samples(m.extra["states"], m.phase - p.force_phase, m.sample_rate, n_mesh=32)
    Vc = correct_forced(s, p.omega, p.forcing, V, n_mesh=32)
    return abs(p.amplitude / float(max_abs(Vc[:, 0])) - 1.0)


def test_noisy_scurve_reports_points_it_cannot_verify():
    """Check a point whose forcing update is lost in the noise is a failure, not a point.

    High gains (kp = kd = 0.5) at γ = 0.002 with 1 % noise: the controller feeds back a
    force whose fundamental scatters by ~8 % of γ over 3 periods, and even 60 periods
    cannot tell the forcing update from zero to 0.5 % of γ. Before the fix the noise floor
    of the control was that of white noise (~10× γ) and every target was accepted at the
    first iteration with γ unchanged: this very run recorded 4 points at γ = 0.002 with
    amplitude errors of 1-430 % (and the low-gain run below 7 points, errors 10-47 %).
    Now: nothing recorded, one failure that says why, a ConvergenceWarning.
    """
    s, pts, fails, warned = _noisy_duffing(0.5, 0.002, 4, max_measure_periods=60.0)
    for p in pts:  # whatever is recorded must be a verified uncontrolled response
        assert p.forcing_floor <= 0.005
        assert _amplitude_error(s, p) < 0.01
    assert len(fails) == 1 and "noise floor" in fails[0].reason
    assert warned


def test_noisy_scurve_points_are_responses_of_the_uncontrolled_system():
    """Check noisy S-curve points (1 % noise, low gains) within 1 % of the true responses.

    kp = kd = 0.1 (``defaults_for("duffing").noisy_options``), γ from 0.01 along the
    lower branch round the upper fold (0.0216): every point's forcing update is verified
    to 0.5 % of γ (3σ) and its amplitude is within 1 % of the uncontrolled response
    Newton-corrected at the recorded γ (points where the S-curve is steep -- next to the
    fold, within 2 % of its γ -- are excluded: there 0.5 % in γ is more than 1 % in A).
    The run ends on the unstable middle branch, past the fold.
    """
    s, pts, fails, _ = _noisy_duffing(0.1, 0.01, 11, ds=0.1, ds_max=0.2)
    assert not fails and len(pts) == 11
    assert all(np.diff([p.amplitude for p in pts]) > 0)
    checked = 0
    for p in pts:
        assert p.forcing_floor <= 0.005
        if min(abs(p.forcing / f - 1.0) for f in FOLDS_CONTINUATION) > 0.02:
            assert _amplitude_error(s, p) < 0.01
            checked += 1
    assert checked >= 7
    # middle branch: between the folds' amplitudes (0.3115 and 0.518 by continuation)
    assert 0.3115 < pts[-1].amplitude < 0.518 and pts[-1].forcing < pts[-2].forcing


# ------------------------------------------------------------ FRC with measurement noise
def _noisy_frc(gains: float, max_points: int, **opts):
    """A duffing FRC at γ = 0.01 from Ω = 0.95 up, σ = 1 % of its largest amplitude (0.48)."""
    return _noisy_run(
        0.0048, gains, max_points, lambda rig, o: frc_cbc(rig, 0.01, (0.95, 1.1), o), **opts
    )


def test_noisy_frc_points_are_responses_of_the_uncontrolled_system():
    """Check noisy FRC points (1 % noise, low gains) within 1 % of the true responses.

    kp = kd = 0.1 (``defaults_for("duffing").noisy_options``), Ω from 0.95 up the lower
    flank of the resonance (``|dlnA/dlnγ| < 1`` there: the amplitude at the point's own
    (γ, Ω) is well conditioned). Every point's control fundamental is verified to 0.5 % of
    γ (3σ) and its amplitude is within 1 % of the uncontrolled response Newton-corrected
    at (γ, Ω). Before the fix (a floor accepted whatever its size, the residual judged
    against the target's amplitude instead of the force) this very run recorded a point
    1.7 % off (errors 0.1-1.7 %; now <= 0.3 %).
    """
    s, pts, fails, warned = _noisy_frc(0.1, 6)
    assert not fails and not warned and len(pts) == 6
    assert all(np.diff([p.omega for p in pts]) > 0)
    for p in pts:
        assert p.forcing_floor <= 0.005
        assert _amplitude_error(s, p) < 0.01


def test_noisy_frc_reports_points_it_cannot_verify():
    """Check an FRC point whose control cannot be told from zero is a failure, not a point.

    kp = kd = 0.5 with 1 % noise: the control's fundamental scatters by
    ``3σ |kp + iΩkd| sqrt(2/n)`` ≈ 2 % of γ over 12 periods, so non-invasiveness to 0.5 %
    of γ cannot be verified within ``max_measure_periods = 12``. The old code accepted
    such points within the (large) floor: this very run recorded 3 points, one 7.5 % off
    the uncontrolled response. Now: no point, one failure that says why, a
    ConvergenceWarning.
    """
    _, pts, fails, warned = _noisy_frc(0.5, 3, max_measure_periods=12.0)
    assert not pts
    assert len(fails) == 1 and "noise floor" in fails[0].reason
    assert warned
