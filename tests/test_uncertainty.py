"""Calibrated intervals: the shared statistics, the mechanistic model's delta method and the
kernel model's coverage of exact folds and peaks.

The mechanistic checks use the ``hopf`` system (eq. 5.2), whose cycles are circles of radius
``r² = (a2 ± sqrt(a2² + 4 q5 mu)) / (2 q5)`` with the cycle fold at ``mu_f = -a2²/(4 q5)``
and ``r_f² = a2/(2 q5)``: the covariance and every propagated interval are recomputed here
in closed form. The parametric bootstrap and a longer coverage run are in
``tests/slow/test_uncertainty_calibration.py``.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import scipy.stats

from bifid.errors import BifidInputError
from bifid.identify import (
    LCOData,
    MechanisticModel,
    conformal_quantile,
    coverage_test,
)

MU = np.array([-0.2, -0.12, -0.05, -0.02, -0.22, -0.15, -0.05, 0.05])
STABLE = np.array([0, 0, 0, 0, 1, 1, 1, 1])
NOISE = 0.01


def radius(mu, stable, a2=1.0, q5=1.0):
    s = np.sqrt(a2**2 + 4 * q5 * np.asarray(mu))
    return np.sqrt((a2 + np.where(stable, s, -s)) / (2 * q5))


def radius_gradient(mu, stable, a2, q5):
    """Analytic d r / d (a2, q5), shape (n, 2)."""
    s = np.sqrt(a2**2 + 4 * q5 * mu)
    sg = np.where(stable, 1.0, -1.0)
    r2 = (a2 + sg * s) / (2 * q5)
    d_a2 = (1 + sg * a2 / s) / (2 * q5)
    d_q5 = (sg * 2 * mu / s) / (2 * q5) - r2 / q5
    return np.column_stack([d_a2, d_q5]) / (2 * np.sqrt(r2))[:, None]


def noisy_data(seed: int) -> LCOData:
    rng = np.random.default_rng(seed)
    amp = radius(MU, STABLE == 1) + NOISE * rng.standard_normal(MU.size)
    return LCOData.from_amplitudes(MU, amp[:, None], STABLE, ("u1",), param_name="mu")


def fit(seed: int) -> MechanisticModel:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return MechanisticModel("hopf", ("a2", "q5"), stages=("whole_diagram",), n_mesh=16).fit(
            noisy_data(seed)
        )


@pytest.fixture(scope="module")
def model():
    return fit(0)


@pytest.fixture(scope="module")
def diagram(model):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return model.predict_diagram(range=(-0.3, 0.1), level=0.9, n_points=30)


# ------------------------------------------------------------------ shared statistics
def test_coverage_test_rejects_miscalibrated_rates() -> None:
    hits = np.r_[np.ones(190, bool), np.zeros(10, bool)]  # 95 %
    ok = coverage_test(hits, 0.95)
    assert ok["rate"] == 0.95 and not ok["rejected"] and ok["n"] == 200
    assert ok["rate_ci"][0] < 0.95 < ok["rate_ci"][1]
    bad = coverage_test(np.r_[np.ones(170, bool), np.zeros(30, bool)], 0.95)  # 85 %
    assert bad["rejected"]
    assert bad["p_value"] == pytest.approx(scipy.stats.binomtest(170, 200, 0.95).pvalue)


def test_conformal_quantile_is_the_finite_sample_order_statistic() -> None:
    scores = np.arange(1.0, 20.0)  # n = 19
    assert conformal_quantile(scores, 0.9) == 18.0  # ceil(20 * 0.9) = 18th smallest
    assert conformal_quantile(-scores, 0.5) == 10.0
    assert math.isinf(conformal_quantile(scores, 0.99))  # ceil(20 * 0.99) = 20 > n
    # exchangeable scores: a new one falls below the quantile with probability
    # ceil((n+1) level)/(n+1) = 16/20 (0.8; 4000 draws: a standard error of 0.0063)
    rng = np.random.default_rng(1)
    s = rng.standard_normal((4000, 20))
    q = np.array([conformal_quantile(row[:19], 0.8) for row in s])
    rate = np.mean(np.abs(s[:, 19]) <= q)
    assert rate == pytest.approx(0.8, abs=0.02)


# ---------------------------------------------------------------- mechanistic model
def test_covariance_is_the_gauss_newton_covariance_of_the_analytic_model(model) -> None:
    """σ̂²(JᵀJ)⁻¹ with J and the residuals from the closed-form radii at the fit."""
    a2, q5 = model.params_["a2"], model.params_["q5"]
    data = noisy_data(0)
    res = radius(MU, STABLE == 1, a2, q5) - data.column("u1")
    J = radius_gradient(MU, STABLE == 1, a2, q5)
    sigma2 = res @ res / (MU.size - 2)
    cov = model.covariance()
    np.testing.assert_allclose(cov.cov, sigma2 * np.linalg.inv(J.T @ J), rtol=1e-5)
    assert cov.dof == 6 and cov.names == ("a2", "q5")
    se = model.summary()["standard_errors"]
    np.testing.assert_allclose([se["a2"], se["q5"]], np.sqrt(np.diag(cov.cov)), rtol=1e-12)


def test_fold_and_hopf_intervals_are_the_delta_method(model, diagram) -> None:
    """Fold speed and amplitude: ``q ± t_{0.95, 6} sqrt(gᵀ C g)`` with g in closed form."""
    a2, q5 = model.params_["a2"], model.params_["q5"]
    C = model.covariance().cov
    t = scipy.stats.t.ppf(0.95, 6)
    (fold,) = diagram.special("cycle_fold")
    assert fold.param == pytest.approx(-(a2**2) / (4 * q5), abs=1e-9)
    g = np.array([-a2 / (2 * q5), a2**2 / (4 * q5**2)])
    lo, hi = fold.intervals["param"]
    assert (hi - lo) / 2 == pytest.approx(t * math.sqrt(g @ C @ g), rel=1e-6)
    assert (lo + hi) / 2 == pytest.approx(fold.param, abs=1e-12)
    r_f = math.sqrt(a2 / (2 * q5))
    g_r = np.array([1 / (4 * q5 * r_f), -a2 / (4 * q5**2 * r_f)])
    lo_a, hi_a = (np.asarray(v)[0] for v in fold.intervals["amplitude"])
    assert (hi_a - lo_a) / 2 == pytest.approx(t * math.sqrt(g_r @ C @ g_r), rel=1e-5)
    # the Hopf point mu0 = 0 does not depend on the free parameters: a zero-width interval
    (hopf,) = diagram.special("hopf")
    assert hopf.intervals["param"] == pytest.approx((0.0, 0.0), abs=1e-12)


def test_branch_band_is_the_delta_method_at_fixed_parameter(model, diagram) -> None:
    a2, q5 = model.params_["a2"], model.params_["q5"]
    C = model.covariance().cov
    t = scipy.stats.t.ppf(0.95, 6)
    (b,) = diagram.of_kind("periodic")
    lo, hi = (np.asarray(v)[:, 0] for v in b.intervals["amplitude"])
    amp = np.asarray(b.data["amplitude"])[:, 0]
    mu = np.asarray(b.params)
    # away from the Hopf end and the fold, on both sides of the fold
    stable = amp > math.sqrt(a2 / (2 * q5))
    sel = (amp > 0.2) & (np.abs(mu + a2**2 / (4 * q5)) > 0.02)
    assert np.sum(sel & stable) >= 3 and np.sum(sel & ~stable) >= 3
    g = radius_gradient(mu[sel], stable[sel], a2, q5)
    half = t * np.sqrt(np.einsum("ni,ij,nj->n", g, C, g))
    np.testing.assert_allclose((hi - lo)[sel] / 2, half, rtol=1e-4)


def test_json_contract_and_level_validation(model, diagram, tmp_path, bifid_cli) -> None:
    out = diagram.to_json()
    assert out["level"] == 0.9
    assert len(out["cycle_folds"][0]["param_interval"]) == 2
    assert set(out["cycle_folds"][0]["amplitude_interval"]) == {"u1", "u2"}
    assert "param_interval" in out["hopf"][0]
    assert all("amplitude_interval" in o for o in out["orbits"])
    for bad in (0.0, 1.0, 1.5, "x"):
        with pytest.raises(BifidInputError, match="level"):
            model.predict_diagram(range=(-0.3, 0.1), level=bad)
    with pytest.warns(UserWarning, match="extrapolates"):
        model.predict_diagram(range=(-0.3, 0.2), level=0.9, n_points=10)
    model.save(tmp_path / "m")
    r = bifid_cli("predict", tmp_path / "m", "--range", "-0.3", "0.1", "--level", "0.95", "--json")
    assert r.code == 0, r.stderr
    assert r.json["level"] == 0.95 and "param_interval" in r.json["cycle_folds"][0]
    r = bifid_cli("predict", tmp_path / "m", "--range", "-0.3", "0.1", "--level", "2")
    assert r.code == 2 and "level" in r.stderr


def test_coverage_small_in_process() -> None:
    """Six seeded replications, four quantities each (a2, q5, fold speed and amplitude) at
    nominal 90 %: the intervals hold the truth at a rate the binomial test accepts, and
    intervals half as wide do not."""
    truth = {"a2": 1.0, "q5": 1.0, "fold": -0.25, "fold_amp": math.sqrt(0.5)}
    hits, narrow = [], []
    t = scipy.stats.t.ppf(0.95, 6)
    for seed in range(1, 7):
        m = fit(seed)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            d = m.predict_diagram(range=(-0.3, 0.05), level=0.9, n_points=10)
        (fold,) = d.special("cycle_fold")
        se = m.covariance().standard_errors()
        est = {
            "a2": (m.params_["a2"], t * se["a2"]),
            "q5": (m.params_["q5"], t * se["q5"]),
            "fold": (fold.param, np.diff(fold.intervals["param"])[0] / 2),
            "fold_amp": (
                fold.data["amplitude"][0],
                (fold.intervals["amplitude"][1][0] - fold.intervals["amplitude"][0][0]) / 2,
            ),
        }
        for k, (v, half) in est.items():
            hits.append(abs(v - truth[k]) <= half)
            narrow.append(abs(v - truth[k]) <= half / 2)
    assert not coverage_test(hits, 0.9)["rejected"], hits
    assert np.mean(hits) >= 0.8, hits
    assert np.mean(narrow) < 0.75, narrow


# ------------------------------------------------------------------- kernel model
# The averaged hardening Duffing oscillator a(ρ) = −cρ, b(ρ) = ω₀ + kρ², Γ = κF: on its FRC
# ρ = Γ sin ψ / c and Ω = b(ρ) + Γ cos ψ / ρ are explicit in the phase ψ, so the folds
# (extrema of Ω(ψ)), the peak and the amplitude at every phase are known exactly.
KC, KK, KW0, KKAPPA = 0.0015, 0.0005, 1.0, 0.5
K_TRAIN, K_PREDICT = (0.007, 0.01), 0.0085


def duffing_frc(forcing, psi):
    g = KKAPPA * forcing
    rho = g * np.sin(psi) / KC
    return KW0 + KK * rho**2 + g * np.cos(psi) / rho, rho


def kernel_fit(seed: int, noise: float = 0.01):
    from bifid.identify import ForcedKernelModel

    rng = np.random.default_rng(seed)
    psi = np.linspace(0.12, np.pi - 0.12, 16)
    cols = {"omega": [], "forcing": [], "amplitude": [], "phase": []}
    for f in K_TRAIN:
        om, rho = duffing_frc(f, psi)
        cols["omega"].append(om)
        cols["forcing"].append(np.full(psi.size, f))
        cols["amplitude"].append(rho * (1 + noise * rng.standard_normal(psi.size)))
        cols["phase"].append(np.pi - psi + noise * rng.standard_normal(psi.size))
    model = ForcedKernelModel(forcing_scale=KKAPPA, selection="ml", observation=False, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return model.fit(**{k: np.concatenate(v) for k, v in cols.items()})


def kernel_truth(forcing: float) -> dict[str, float]:
    """Folds (extrema of Ω(ψ)) and peak of the exact FRC, on a dense ψ grid."""
    om, rho = duffing_frc(forcing, np.linspace(1e-3, np.pi - 1e-3, 200_001))
    d = np.diff(om)
    folds = np.sort(om[np.nonzero(np.sign(d[:-1]) != np.sign(d[1:]))[0] + 1])
    i = int(np.argmax(rho))
    return {"fold_low": folds[0], "fold_high": folds[-1], "peak": om[i], "peak_amp": rho[i]}


def kernel_hits(seed: int, level: float) -> tuple[list[bool], dict]:
    """Whether the intervals at ``level`` of the FRC at the untrained forcing hold the exact
    folds and peak, and the predicted diagram."""
    m = kernel_fit(seed)
    d = m.predict_diagram(kind="frc", forcing=K_PREDICT, range=(0.95, 1.2), level=level)
    low, high = sorted(d.special("fold"), key=lambda sp: sp.param)
    (peak,) = d.special("peak")
    truth = kernel_truth(K_PREDICT)
    ivs = {
        "fold_low": low.intervals["param"],
        "fold_high": high.intervals["param"],
        "peak": peak.intervals["param"],
        "peak_amp": [peak.intervals["amplitude"][0][0], peak.intervals["amplitude"][1][0]],
    }
    return [lo <= truth[k] <= hi for k, (lo, hi) in ivs.items()], d


def test_kernel_intervals_hold_the_exact_folds_and_peak() -> None:
    """Check the kernel model's 95 % intervals on the folds and the peak of an FRC at an
    untrained forcing hold the exact values (averaged Duffing oscillator, 1 % noise) at
    least as often as a binomial bound allows, and that its 50 % intervals are not so wide
    that they always do. With 12 trials, 95 % coverage gives ≥ 10 hits with probability
    0.98 and 50 % coverage 12 hits with probability 0.0002."""
    hits95, hits50 = [], []
    for seed in (0, 1, 2):
        h, d = kernel_hits(seed, 0.95)
        hits95 += h
        assert d.level == 0.95
        b = d.branches[0]
        lo, hi = b.intervals["amplitude"]
        amp = np.asarray(b.solutions)[:, 0]
        ok = np.isfinite(lo[:, 0])
        assert ok.mean() > 0.9 and np.all((lo[ok, 0] <= amp[ok]) & (amp[ok] <= hi[ok, 0]))
        hits50 += kernel_hits(seed, 0.5)[0]
    assert sum(hits95) >= 10, hits95
    assert sum(hits50) < 12, hits50


def test_kernel_frc_samples_are_solved_at_the_peak() -> None:
    """Check the posterior samples of an FRC at an untrained forcing are solved where the
    response is most sensitive (the peak, the high fold): a converged fixed-phase solve of a
    sampled model leaves a residual at the rounding floor of its kernel sums and is kept;
    the sampled peaks lie around the exact one."""
    m = kernel_fit(0)
    br = m.predict_diagram(forcing=K_PREDICT, range=(0.95, 1.2), level=0.95).branches[0]
    rho_s = br.data["sample_amplitude"]
    i = int(np.argmax(np.asarray(br.solutions)[:, 0]))
    near = rho_s[:, max(i - 5, 0) : i + 6]
    # (with an acceptance threshold below that floor, 1.1 % of them were discarded here)
    assert np.mean(np.isfinite(near)) >= 0.995, np.mean(np.isfinite(near))
    peaks = np.nanmax(rho_s, axis=1)
    assert np.nanmedian(peaks) == pytest.approx(kernel_truth(K_PREDICT)["peak_amp"], rel=0.05)


def test_kernel_intervals_widen_beyond_the_trained_forcing() -> None:
    """Check a prediction at a forcing above the trained ones (its peak amplitude beyond
    every trained amplitude) warns and says so by its width: the peak amplitude's 95 %
    interval, relative to the amplitude, is wider than at the untrained forcing between
    the trained ones, and still holds the exact peak."""
    m = kernel_fit(0)
    widths = {}
    for f in (K_PREDICT, 0.013):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            d = m.predict_diagram(kind="frc", forcing=f, range=(0.95, 1.2), level=0.95)
        assert any("outside the trained range" in str(w.message) for w in caught) == (f > 0.01)
        (peak,) = d.special("peak")
        (lo,), (hi,) = peak.intervals["amplitude"]
        amp = float(np.ravel(peak.data["amplitude"])[0])
        widths[f] = (hi - lo) / amp
        assert lo <= kernel_truth(f)["peak_amp"] <= hi
    assert widths[0.013] > widths[K_PREDICT], widths


def _one(v):
    """The value of a one-signal entry (``{signal: v}`` or ``v``)."""
    return next(iter(v.values())) if isinstance(v, dict) else v


def test_kernel_level_in_the_cli(tmp_path, bifid_cli) -> None:
    """Check `bifid predict MODEL --level` answers for a kernel model with the contract's
    interval keys, each interval around its estimate."""
    m = kernel_fit(0)
    m.save(tmp_path / "k")
    args = ("predict", tmp_path / "k", "--forcing", K_PREDICT, "--omega-range", "0.95", "1.2")
    r = bifid_cli(*args, "--level", "0.95", "--json")
    assert r.code == 0, r.stderr
    p = r.json
    assert p["level"] == 0.95 and len(p["folds"]) == 2
    for f in p["folds"]:
        assert f["omega_interval"][0] < f["omega"] < f["omega_interval"][1]
    peak = p["peak"]
    assert peak["omega_interval"][0] < peak["omega"] < peak["omega_interval"][1]
    (lo, hi), amp = _one(peak["amplitude_interval"]), _one(peak["amplitude"])
    assert lo < amp < hi
    assert all("amplitude_interval" in q for q in p["points"])
    assert bifid_cli(*args, "--level", "1.5", "--json").code == 2
