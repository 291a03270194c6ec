"""The flutter model of Appendix A as ground truth: Hopf point, l1, fold of cycles, Floquet."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

from bifid.continuation import (
    ContinuationOptions,
    continue_from_hopf,
    periodic_orbits,
    resample_orbit,
)
from bifid.simulate import simulate
from bifid.systems import flutter_matrices, get_system


@pytest.fixture(scope="module")
def flutter():
    s = get_system("flutter")
    eq, (br,) = continue_from_hopf(s, "U", 14.0, 20.0, n_mesh=64)
    return s, eq, br


def _linear_matrix(s, U: float) -> np.ndarray:
    """State matrix assembled independently from M, D, K (numpy, not the JAX field)."""
    M, D, K = (np.asarray(m) for m in flutter_matrices(s.param_vector(U=U)))
    Minv = np.linalg.inv(M)
    A = np.zeros((6, 6))
    pos, vel = [0, 2, 4], [1, 3, 5]
    A[np.ix_(pos, vel)] = np.eye(3)
    A[np.ix_(vel, pos)] = -Minv @ K
    A[np.ix_(vel, vel)] = -Minv @ D
    return A


def test_hopf_speed_matches_eigenvalue_root_finding(flutter):
    """Check U_H against SciPy eigvals + Brent root finding on the max real part (1e-8 rel)."""
    s, eq, _ = flutter
    (h,) = eq.special("hopf")

    def growth(U):
        return np.max(scipy.linalg.eigvals(_linear_matrix(s, U)).real)

    U_ref = scipy.optimize.brentq(growth, 17.0, 19.0, xtol=1e-13, rtol=1e-15)
    assert h.param == pytest.approx(U_ref, rel=1e-8)
    w = scipy.linalg.eigvals(_linear_matrix(s, U_ref))
    assert h.data["omega"] == pytest.approx(abs(w[np.argmax(w.real)].imag), rel=1e-6)
    assert h.data["lyapunov"] > 0 and h.data["criticality"] == "subcritical"
    assert 18.2 < h.param < 18.35  # the thesis's subcritical Hopf at U ≈ 18.28 m/s


def test_unstable_branch_folds_into_stable_branch(flutter):
    """Check: unstable orbits from the Hopf point, a cycle fold, then stable orbits."""
    _, _eq, br = flutter
    (fold,) = br.special("cycle_fold")
    k = fold.index
    assert not br.stable[1 : k + 1].any()
    assert br.stable[k + 2 :].all()
    assert 14.5 < fold.param < 15.5
    assert fold.param <= br.params.min() + 1e-9  # the fold is the leftmost point
    # a fold is a parameter extremum: it lies just beyond both bracketing points
    lo, _hi = sorted(fold.bracket)
    assert lo - 0.01 < fold.param <= lo + 1e-12


def test_stable_orbit_matches_long_simulation_and_one_trivial_multiplier(flutter):
    """Check a stable orbit against direct simulation (1e-5 rel) and its one trivial multiplier."""
    s, _, br = flutter
    i = int(np.argmin(np.abs(br.params - 16.5) + 100 * (~br.stable)))
    U, T = float(br.params[i]), float(br.data["period"][i])
    M = br.meta["n_mesh"]
    x0 = br.solutions[i, : M * 6].reshape(M, 6)[0] * 1.05  # start off the orbit
    ts = np.concatenate(
        [np.linspace(0, 150 * T, 3000, endpoint=False), np.linspace(150 * T, 151 * T, 20001)]
    )
    ys = simulate(s, x0, ts, s.param_vector(U=U))
    tail = ys[ts >= 150 * T]
    amp = br.data["amplitude"][i]
    for k in (0, 2):  # heave and pitch
        j = int(np.argmax(np.abs(tail[:, k])))
        y0, y1, y2 = np.abs(tail[j - 1 : j + 2, k])
        peak = y1 + (y0 - y2) ** 2 / (8 * (2 * y1 - y0 - y2))
        assert peak == pytest.approx(amp[k], rel=1e-5)
    mult = br.data["floquet"][i]
    near_one = np.abs(mult - 1.0)
    assert np.sum(near_one < 1e-8) == 1
    assert np.sort(near_one)[1] > 1e-3


@pytest.mark.slow
def test_cycle_fold_converged_in_mesh_size(flutter):
    """Check the fold-of-cycles speed changes by < 1e-8 between M = 64 and 2M = 128
    (slow: a second branch on 768 unknowns; run with --runslow)."""
    s, _, br = flutter
    (fold,) = br.special("cycle_fold")
    M = br.meta["n_mesh"]
    i = fold.index - 2  # an unstable orbit just before the fold
    V = resample_orbit(br.solutions[i, : M * 6].reshape(M, 6), 2 * M)
    fine = periodic_orbits(
        s,
        "U",
        V,
        float(br.data["period"][i]),
        p=s.param_vector(U=float(br.params[i])),
        n_mesh=2 * M,
        options=ContinuationOptions(ds=0.02, ds_max=0.05, max_steps=12, direction=-1),
    )
    (fold2,) = fine.special("cycle_fold")
    assert abs(fold2.param - fold.param) < 1e-8
