"""A mechanistic fit works on branches whose multipliers come from the collocation
operator; what it reports is verified.

The ``hopf`` system (eq. 5.2) has circular cycles of radius
``r² = (a2 ± sqrt(a2² + 4 q5 mu)) / (2 q5)`` and its cycle fold at ``-a2² / (4 q5)``.
"""

from __future__ import annotations

import numpy as np
import pytest

from bifid.identify import LCOData, MechanisticModel

MU = np.array([-0.2, -0.12, -0.05, -0.22, -0.15, -0.05, 0.05])
STABLE = np.array([0, 0, 0, 1, 1, 1, 1])
A2, Q5 = 1.0, 1.0


def _radius(mu, stable):
    s = np.sqrt(A2**2 + 4 * Q5 * np.asarray(mu))
    return np.sqrt((A2 + np.where(stable, s, -s)) / (2 * Q5))


@pytest.fixture(scope="module")
def fitted():
    data = LCOData.from_amplitudes(
        MU, _radius(MU, STABLE == 1)[:, None], STABLE, ("u1",), param_name="mu"
    )
    m = MechanisticModel(
        "hopf",
        ("a2",),
        params={"a2": 1.15},
        outputs=("u1",),
        stages=("whole_diagram",),
        n_mesh=16,
        hopf_guess=0.0,
    )
    return m.fit(data)


def test_fit_reports_the_analytic_parameter_and_fold(fitted):
    """Check a2 (1e-7) and the summary's cycle fold (1e-6) against the closed form."""
    assert fitted.params_["a2"] == pytest.approx(A2, rel=1e-7)
    assert fitted.cycle_fold_ == pytest.approx(-(A2**2) / (4 * Q5), abs=1e-6)


def test_reported_diagram_is_verified_with_integrated_multipliers(fitted):
    """Check that the predicted diagram's orbit branch takes its multipliers from the
    integrated variational equation and that every special point it reports is
    converged with its verification record (Hopf at 0, cycle fold at -1/4)."""
    d = fitted.predict_diagram(param="mu", range=(-0.3, 0.1))
    orbit_branches = [b for b in d.branches if b.kind == "periodic"]
    assert orbit_branches
    assert all(b.meta["stability"] == "integrated" for b in orbit_branches)
    points = [sp for b in d.branches for sp in b.special_points]
    assert {sp.kind for sp in points} >= {"hopf", "cycle_fold"}
    for sp in points:
        assert sp.status == "converged" and sp.verification
    (fold,) = d.special("cycle_fold")
    assert fold.param == pytest.approx(-(A2**2) / (4 * Q5), abs=1e-6)
    assert fold.verification["multiplier_minus_one"] <= 1e-4
