"""Forced responses of the Duffing oscillator: harmonic balance, folds, backbone."""

from __future__ import annotations

import numpy as np
import pytest

from bifid.continuation import backbone, frc, scurve
from bifid.signal import fourier_coefficients
from bifid.systems import get_system

ZETA, GAMMA = 0.01, 0.5


@pytest.fixture(scope="module")
def duffing():
    return get_system("duffing")


def _first_harmonic_amplitude(br, M):
    V = br.solutions[:, : M * 2].reshape(-1, M, 2)[:, :, 0]
    _, a, b = fourier_coefficients(V.T)
    a1, b1 = a[0], b[0]
    return np.hypot(a1, b1)


def test_small_forcing_frc_matches_harmonic_balance(duffing):
    """Check the FRC at small F against first-order harmonic balance.

    ((1 - W^2 + 3/4 g A^2)^2 + (2 z W)^2) A^2 = F^2 for the first-harmonic amplitude A.
    """
    F = 0.002
    br = frc(duffing, F, (0.9, 1.1), n_mesh=32)
    A = _first_harmonic_amplitude(br, 32)
    W = br.data["omega"]
    hb = ((1 - W**2 + 0.75 * GAMMA * A**2) ** 2 + (2 * ZETA * W) ** 2) * A**2
    assert np.max(np.abs(hb / F**2 - 1)) < 2e-3
    assert br.status == "range"
    # phase: lag rises through pi/2 at the peak
    k = int(np.argmax(br.data["observed_amplitude"]))
    assert br.data["phase"][k] == pytest.approx(np.pi / 2, abs=0.05)
    assert br.data["phase"][0] < 0.2 and br.data["phase"][-1] > np.pi - 0.3


def test_scurve_folds_agree_with_frc_folds(duffing):
    """Check that S-curve folds at a FRC fold's frequency sit at the FRC's forcing."""
    F = 0.01
    fr = frc(duffing, F, (0.95, 1.15), n_mesh=32)
    folds = fr.special("fold")
    assert len(folds) == 2
    lo, hi = sorted(f.param for f in folds)
    # unstable exactly between the two folds (the middle branch of the bistable region)
    for sp in folds:
        sc = scurve(duffing, sp.param, (0.0, 0.03), n_mesh=32)
        Fs = [f.param for f in sc.special("fold")]
        assert min(abs(np.array(Fs) - F)) < 1e-7
    assert 1.02 < lo < hi < 1.05


def test_scurve_at_1p05_has_two_folds_and_unstable_middle(duffing):
    """Check the S-curve at Omega = 1.05: folds near F = 0.011 and 0.022, unstable between."""
    sc = scurve(duffing, 1.05, (0.0, 0.04), n_mesh=32)
    Fs = sorted(f.param for f in sc.special("fold"))
    assert len(Fs) == 2
    assert Fs[0] == pytest.approx(0.0109, rel=0.02) and Fs[1] == pytest.approx(0.0216, rel=0.02)
    a, b = sorted(f.index for f in sc.special("fold"))
    assert not sc.stable[a + 2 : b].any()
    assert sc.stable[:a].all() and sc.stable[b + 2 :].all()


def test_backbone_matches_first_order_frequency_amplitude_relation(duffing):
    """Check the quadrature locus against W = sqrt(1 + 3/4 g A^2) at small amplitude."""
    bb = backbone(duffing, (0.01, 0.3), n_mesh=32)
    A, W = bb.data["observed_amplitude"], bb.data["omega"]
    assert np.all(np.diff(W) > 0)  # hardening
    small = A < 0.2
    assert np.max(np.abs(W[small] - np.sqrt(1 + 0.75 * GAMMA * A[small] ** 2))) < 2e-3
    assert np.allclose(np.cos(bb.data["phase"]), 0.0, atol=1e-8)


def test_backbone_follows_the_requested_mode_within_the_range():
    """Check the second shaw_pierre mode (which the system's symmetric force cannot
    excite): it starts at sqrt(3), stays that mode (share > 0.99), starts and ends exactly
    on the amplitude range, and matches the first-order NNM frequency at small amplitude."""
    sp = get_system("shaw_pierre")
    bb = backbone(sp, (0.01, 0.5), mode=1, n_mesh=16)
    A, W = bb.data["observed_amplitude"], bb.data["omega"]
    assert bb.status == "range" and bb.complete
    assert A[0] == pytest.approx(0.01, rel=1e-10) and A[-1] == pytest.approx(0.5, rel=1e-10)
    assert np.all(bb.data["mode_share"] > 0.99)
    assert W[0] == pytest.approx(np.sqrt(3.0), rel=1e-5)
    # the cubic spring of mass 1 projected on the mode (1, -1) gives the modal equation
    # eta'' + 3 eta + (kappa / 2) eta^3 = 0: to first order W = sqrt(3 + 3/4 kappa/2 A^2)
    kappa = 0.003
    assert np.allclose(W, np.sqrt(3 + 0.75 * kappa / 2 * A**2), rtol=1e-6)


def test_bad_inputs_raise_clear_errors(duffing):
    """Check the errors for an autonomous system, a degenerate range and non-finite forcing."""
    from bifid.errors import BifidInputError

    with pytest.raises(BifidInputError, match="autonomous"):
        frc(get_system("hopf"), 0.1, (0.9, 1.1))
    with pytest.raises(BifidInputError, match="two different finite"):
        frc(duffing, 0.01, (1.0, 1.0))
    with pytest.raises(BifidInputError, match="finite"):
        frc(duffing, float("nan"), (0.9, 1.1))


def test_coarse_start_mesh_is_refined_and_unresolved_start_refused():
    """Check that a too-coarse starting mesh is refined until every response is resolved,
    and that without adaptation an unresolved start is refused."""
    sp = get_system("shaw_pierre")
    br = frc(sp, 0.02, (0.98, 1.02), n_mesh=8)
    assert br.status == "range" and br.complete
    assert br.data["n_mesh"].min() >= 16
    assert np.all(br.verification["spectral_tail"] <= 1e-9)
    from bifid.errors import ConvergenceError

    with pytest.raises(ConvergenceError, match="spectral tail"):
        frc(sp, 0.02, (0.98, 1.02), n_mesh=8, adapt=False)
