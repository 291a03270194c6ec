"""Slow checks of the mechanistic intervals against a parametric bootstrap; `--runslow`.

The delta-method standard deviations of the fitted parameters and of the cycle fold of the
``hopf`` system (eq. 5.2) are compared with the spread of refits on data simulated from the
fitted model with the residuals' noise level (a parametric bootstrap, an independent
estimate of the same sampling distribution).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from bifid.identify import LCOData, MechanisticModel

pytestmark = pytest.mark.slow

MU = np.array([-0.2, -0.12, -0.05, -0.02, -0.22, -0.15, -0.05, 0.05])
STABLE = np.array([0, 0, 0, 0, 1, 1, 1, 1])
N_BOOT = 30


def radius(mu, stable, a2, q5):
    s = np.sqrt(a2**2 + 4 * q5 * np.asarray(mu))
    return np.sqrt((a2 + np.where(stable, s, -s)) / (2 * q5))


def fit(amp: np.ndarray) -> MechanisticModel:
    data = LCOData.from_amplitudes(MU, amp[:, None], STABLE, ("u1",), param_name="mu")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MechanisticModel("hopf", ("a2", "q5"), stages=("whole_diagram",), n_mesh=16).fit(
            data
        )


def test_delta_method_matches_a_parametric_bootstrap() -> None:
    rng = np.random.default_rng(0)
    m = fit(radius(MU, STABLE == 1, 1.0, 1.0) + 0.01 * rng.standard_normal(MU.size))
    cov = m.covariance()
    a2, q5 = m.params_["a2"], m.params_["q5"]
    g_fold = np.array([-a2 / (2 * q5), a2**2 / (4 * q5**2)])
    delta = {
        "a2": math.sqrt(cov.cov[0, 0]),
        "q5": math.sqrt(cov.cov[1, 1]),
        "fold": math.sqrt(g_fold @ cov.cov @ g_fold),
    }
    fitted = radius(MU, STABLE == 1, a2, q5)
    boot = []
    for b in range(N_BOOT):
        r = np.random.default_rng(100 + b)
        mb = fit(fitted + cov.sigma * r.standard_normal(MU.size))
        a, q = mb.params_["a2"], mb.params_["q5"]
        boot.append((a, q, -(a**2) / (4 * q)))
    sd = np.std(np.array(boot), axis=0, ddof=1)
    # 30 refits estimate a standard deviation to about ±13 % (one standard error)
    for k, s in zip(("a2", "q5", "fold"), sd, strict=True):
        assert s == pytest.approx(delta[k], rel=0.35), (k, s, delta[k])
