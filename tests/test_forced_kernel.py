"""Kernel models of forced systems (thesis ch. 6) against analytic answers.

The data come from a reduced model whose FRCs, folds, backbone, S-curves and stability
are known in closed form: ``a(ρ) = −cρ``, ``b(ρ) = ω₀ + kρ²`` with ``Γ = κF`` (first-order
averaging of a hardening Duffing oscillator). On a fixed point of eq. 6.10 at phase ψ:
``ρ = Γ sin ψ / c`` and ``Ω = b(ρ) + Γ cos ψ / ρ``, so every quantity is explicit in ψ.
The GP machinery is checked against tinygp and against brute-force leave-one-out.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from bifid.data import ForcedRecord, forced_dataset, save_dataset
from bifid.errors import BifidInputError, NotFittedError
from bifid.identify import ForcedKernelModel, GPRegressor, band_coverage, load
from bifid.identify.forced_kernel import neg_log_marginal_likelihood, sample_eval

C, K, W0, KAPPA = 0.0015, 0.0005, 1.0, 0.5
TRAIN_F = (0.007, 0.01)


def curve(forcing: float, psi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact FRC of the reduced model at phase ψ (thesis convention): (Ω, ρ)."""
    g = KAPPA * forcing
    rho = g * np.sin(psi) / C
    return W0 + K * rho**2 + g * np.cos(psi) / rho, rho


def exact_folds(forcing: float) -> np.ndarray:
    psi = np.linspace(1e-3, np.pi - 1e-3, 400_001)
    om, _ = curve(forcing, psi)
    d = np.diff(om)
    idx = np.nonzero(np.sign(d[:-1]) != np.sign(d[1:]))[0]
    return np.sort(om[idx + 1])


def records(forcing: float, n: int = 16, curve_id: int = 0) -> list[ForcedRecord]:
    psi = np.linspace(0.12, np.pi - 0.12, n)
    om, rho = curve(forcing, psi)
    out = []
    for o, r, p in zip(om, rho, psi, strict=True):
        fs = 64 * o / (2 * np.pi)  # 64 samples per period, 2 periods
        t = np.arange(128) / fs
        y = -r * np.cos(o * t + p)  # y = −Re z: its first harmonic lags the force by π − ψ
        out.append(
            ForcedRecord(
                omega=o,
                forcing=forcing,
                signals=y[:, None],
                sample_rate=fs,
                force=forcing * np.cos(o * t),
                amplitude=r,
                curve=curve_id,
            )
        )
    return out


def scurve_records(
    omega: float, rho: np.ndarray, curve_id: int, gamma_per_f: float = KAPPA
) -> list[ForcedRecord]:
    """Exact S-curve points at fixed Ω (eq. 6.11 solved for Γ at each ρ; ``F = Γ /
    gamma_per_f``)."""
    b = W0 + K * rho**2
    forcing = np.sqrt((C * rho) ** 2 + ((b - omega) * rho) ** 2) / gamma_per_f
    psi = np.arctan2(C * rho, -(b - omega) * rho)
    out = []
    for f, r, p in zip(forcing, rho, psi, strict=True):
        fs = 64 * omega / (2 * np.pi)
        t = np.arange(128) / fs
        y = -r * np.cos(omega * t + p)
        out.append(
            ForcedRecord(
                omega=omega,
                forcing=f,
                signals=y[:, None],
                sample_rate=fs,
                force=f * np.cos(omega * t),
                amplitude=r,
                curve=curve_id,
            )
        )
    return out


@pytest.fixture(scope="module")
def dataset():
    recs = records(TRAIN_F[0]) + records(TRAIN_F[1], curve_id=1)
    return forced_dataset(recs, ["y"], observed="y", system="analytic", source="test")


@pytest.fixture(scope="module")
def model(dataset) -> ForcedKernelModel:
    return ForcedKernelModel(forcing_scale="fit", n_restarts=0, max_phi_points=64).fit(dataset)


# ------------------------------------------------------------------------------ GP core


def test_gp_likelihood_matches_tinygp_and_loo_is_exact():
    tinygp = pytest.importorskip("tinygp")
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 3, (30, 2))
    y = np.sin(x[:, 0]) * x[:, 1] + 0.02 * rng.normal(size=30)
    gp = GPRegressor(n_restarts=0).fit(x, y)
    st = gp.state_
    th = np.asarray(st.theta)
    ys = y / float(st.y_scale)
    kern = np.exp(2 * th[0]) * tinygp.transforms.Linear(
        1.0 / (np.asarray(st.x_scale) * np.exp(th[1:3])), tinygp.kernels.ExpSquared()
    )
    jitter = 1e-10 * np.exp(2 * th[0])
    ref = tinygp.GaussianProcess(kern, x, diag=np.exp(2 * th[-1]) + jitter).log_probability(ys)
    ours = -neg_log_marginal_likelihood(
        st.theta, jnp.asarray(x), jnp.asarray(ys), st.x_scale, st.x_center
    )
    assert float(ours) == pytest.approx(float(ref), rel=1e-9, abs=1e-8)
    # closed-form LOO residuals = refits without each point at the same hyperparameters
    brute = []
    for i in range(0, 30, 10):
        keep = np.arange(30) != i
        gi = GPRegressor(n_restarts=0).fit(
            x[keep], y[keep], theta=th, x_scale=np.asarray(st.x_scale), y_scale=float(st.y_scale)
        )
        brute.append(float(gi.predict(x[i : i + 1])[0]) - y[i])
    chol = np.asarray(st.chol)[:30, :30]  # the state is padded to a bucket size
    kinv = np.linalg.inv(chol @ chol.T)
    closed = -(kinv @ ys)[::10] / np.diag(kinv)[::10] * float(st.y_scale)
    np.testing.assert_allclose(closed, brute, rtol=1e-6, atol=1e-10)


def test_gp_selection_recovers_noise_instead_of_interpolating():
    rng = np.random.default_rng(1)
    x = np.linspace(0, 6, 60)[:, None]
    y = np.sin(x[:, 0]) + 0.05 * rng.normal(size=60)
    for crit in ("ml", "loo"):
        gp = GPRegressor(criterion=crit, n_restarts=1, seed=2).fit(x, y)
        noise = gp.hyperparameters_["noise_std"]
        assert 0.03 < noise < 0.08, (crit, noise)  # a training-loss fit would give ~0
        assert gp.train_rmse_ > 0.02


def test_gp_hyperparameter_errors_match_the_fisher_information():
    """The noise level of n Gaussian residuals has Fisher information 2n in log σ, so its
    standard error is σ / sqrt(2n) (the smooth part takes a few effective points)."""
    rng = np.random.default_rng(3)
    n = 200
    x = rng.uniform(0, 3, (n, 1))
    y = np.sin(2 * x[:, 0]) + 0.05 * rng.normal(size=n)
    gp = GPRegressor(n_restarts=0).fit(x, y)
    hp, se = gp.hyperparameters_, gp.hyperparameter_errors_
    assert se["noise_std"] / hp["noise_std"] == pytest.approx(1 / math.sqrt(2 * n), rel=0.15)
    assert 0 < se["length_scales"][0] < 0.5 * hp["length_scales"][0]


def test_gp_pathwise_samples_have_the_posterior_moments():
    rng = np.random.default_rng(3)
    x = rng.uniform(0, 3, (25, 2))
    y = np.cos(x[:, 0]) + x[:, 1] ** 2 + 0.05 * rng.normal(size=25)
    # sampling, not selection, is under test: fixed hyperparameters (log σ, log ℓ, log τ, log σ_n)
    theta = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, np.log(0.05)])
    gp = GPRegressor(basis=((0, 0), (1, 0), (0, 2))).fit(x, y, theta=theta)
    xt = np.array([[0.5, 0.5], [1.5, 2.9], [4.5, 1.0]])  # the last one extrapolates
    mu, sd = gp.predict(xt, return_std=True)
    s = gp.sample_functions(600, seed=5, n_features=1024)
    vals = np.asarray(
        jax.jit(jax.vmap(sample_eval, in_axes=(None, 0, None)))(gp.state_, s, jnp.asarray(xt))
    )
    np.testing.assert_allclose(vals.mean(0), mu, atol=4 * sd.max() / math.sqrt(600) + 1e-6)
    np.testing.assert_allclose(vals.std(0), sd, rtol=0.15)
    assert sd[2] > 2 * max(sd[0], sd[1])  # wider away from the data


# ------------------------------------------------------------------------------ the model


def test_fit_recovers_forcing_scale_and_reduced_dynamics(model):
    assert model.forcing_scale_ == pytest.approx(KAPPA, rel=1e-3)
    rho = np.linspace(0.3, 3.3, 7)
    a, b = model.reduced_dynamics(rho, 1.002)
    np.testing.assert_allclose(a, -C * rho, rtol=1e-3, atol=1e-7)
    np.testing.assert_allclose(b, W0 + K * rho**2, rtol=0, atol=2e-6)
    assert model.losses_["forcing_rel_rms"] < 1e-4
    assert model.losses_["phase_rms"] < 1e-4
    assert model.summary()["parameters"]["linear_frequency"] == pytest.approx(W0, abs=1e-5)


@pytest.mark.parametrize("forcing", [0.004, 0.012])
def test_frc_at_untrained_forcing_matches_the_exact_curve(model, forcing):
    with pytest.warns(UserWarning, match="outside the trained range"):  # 0.007..0.01
        br = model.predict_diagram(forcing=forcing, range=(0.97, 1.03), level=0.95).branches[0]
    g = KAPPA * forcing
    (peak,) = br.special("peak")
    assert peak.data["amplitude"] == pytest.approx(g / C, rel=1e-3)
    assert peak.param == pytest.approx(W0 + K * (g / C) ** 2, abs=2e-5)
    folds = np.sort([sp.param for sp in br.special("fold")])
    np.testing.assert_allclose(folds, exact_folds(forcing), rtol=1e-5)
    # every point is on the exact curve at its own phase
    psi = br.solutions[:, 1]
    om, rho = curve(forcing, psi)
    np.testing.assert_allclose(br.solutions[:, 0], rho, rtol=1e-3, atol=1e-6)
    np.testing.assert_allclose(br.params, om, atol=2e-5)
    # stability: the exact Jacobian of eq. 6.10 (a = −cρ, b = ω₀ + kρ²) at each point
    r, cp, sp_ = br.solutions[:, 0], np.cos(psi), np.sin(psi)
    det = C * g * sp_ / r - g * cp * (2 * K * r - g * cp / r**2)
    clear = np.abs(det) > 0.02 * np.abs(det).max()
    assert np.array_equal(br.stable[clear], det[clear] > 0)
    assert np.any(det < 0) == (folds.size == 2)
    # interval: the exact curve is inside it at most points
    cov = band_coverage(br, om, rho, np.pi - psi)
    assert cov["n"] > 50 and cov["coverage"] > 0.6


@pytest.mark.parametrize("seed", [300009, 300011])
def test_noisy_frcs_give_the_two_true_folds_between_them(seed):
    """1 % noise on amplitude and phase: the weakly bistable FRC between the two trained
    levels (folds 7e-4 apart in Ω) has exactly its two folds, not extra pairs from a GP that
    interpolates the noise (``a``'s noise at its floor, its length scale below the data
    spacing)."""
    rng = np.random.default_rng(seed)
    psi = np.linspace(0.12, np.pi - 0.12, 16)
    cols: dict[str, list] = {"omega": [], "forcing": [], "amplitude": [], "phase": []}
    for f in TRAIN_F:
        om, rho = curve(f, psi)
        cols["omega"].append(om)
        cols["forcing"].append(np.full(psi.size, f))
        cols["amplitude"].append(rho * (1 + 0.01 * rng.standard_normal(psi.size)))
        cols["phase"].append(np.pi - psi + 0.01 * rng.standard_normal(psi.size))
    m = ForcedKernelModel(forcing_scale=KAPPA, observation=False, seed=seed)
    m.fit(**{k: np.concatenate(v) for k, v in cols.items()})
    br = m.frc(0.0085, (0.95, 1.2))
    folds = np.sort([sp.param for sp in br.special("fold")])
    np.testing.assert_allclose(folds, exact_folds(0.0085), rtol=0, atol=1e-4)


def test_fit_from_scurves_with_default_settings():
    """S-curves (fixed Ω, curve ids) at four frequencies, default settings: κ identified,
    FRC at an untrained forcing level exact (the setting of ``bifid demo forced``)."""
    recs = []
    for c, om in enumerate((0.995, 1.0, 1.004, 1.008)):
        recs += scurve_records(om, np.linspace(0.2, 4.0, 8), c)
    ds = forced_dataset(recs, ["y"], observed="y", system="analytic", source="test")
    m = ForcedKernelModel(n_restarts=0, max_phi_points=64).fit(ds)
    assert m.forcing_scale_ == pytest.approx(KAPPA, rel=1e-3)
    br = m.frc(0.009, (0.97, 1.03))
    g = KAPPA * 0.009
    assert br.special("peak")[0].data["amplitude"] == pytest.approx(g / C, rel=1e-3)
    folds = np.sort([sp.param for sp in br.special("fold")])
    np.testing.assert_allclose(folds, exact_folds(0.009), rtol=1e-5)


def inverse_curve(forcing: float, psi: np.ndarray, omega_ref: float):
    """Exact FRC (Ω, ρ) at phase ψ of the reduced model forced by ``Γ = κF Ω̄/Ω``: from
    eq. 6.10, ``ρΩ = κFΩ̄ sin ψ / c =: q`` and ``Ω = ω₀ + kρ² + c cot ψ``, so Ω is the one
    positive root of ``Ω³ − (ω₀ + c cot ψ)Ω² − kq² = 0`` (Newton from above)."""
    q = KAPPA * forcing * omega_ref * np.sin(psi) / C
    p = W0 + C / np.tan(psi)
    om = p + K * q**2 / p**2 + 0.05
    for _ in range(60):
        om = om - (om**3 - p * om**2 - K * q**2) / (3 * om**2 - 2 * p * om)
    return om, q / om


def test_inverse_forcing_frequency_from_scurves(tmp_path):
    """Data forced by ``Γ = κF Ω̄/Ω`` (Ω̄ the mean trained frequency): with
    ``forcing_frequency="inverse"`` κ is identified and every F ↔ Γ conversion (FRC
    continuation, S-curve, stability, intervals, save/load) reproduces the exact model."""
    omegas = (0.99, 1.0, 1.004, 1.012)
    w_ref = float(np.mean(omegas))
    recs = []
    for c, om in enumerate(omegas):
        recs += scurve_records(om, np.linspace(0.2, 4.0, 8), c, KAPPA * w_ref / om)
    m = ForcedKernelModel(forcing_frequency="inverse", n_restarts=0, observation=False)
    m.fit(forced_dataset(recs, ["y"], observed="y", system="analytic", source="test"))
    assert m.forcing_scale_ == pytest.approx(KAPPA, rel=1e-3)
    f = 0.009
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # extrapolation warning
        br = m.predict_diagram(forcing=f, range=(0.97, 1.03), level=0.95).branches[0]
    psi = br.solutions[:, 1]
    om, rho = inverse_curve(f, psi, w_ref)
    np.testing.assert_allclose(br.solutions[:, 0], rho, rtol=1e-4)  # Γ off by Ω̄/Ω: 1e-2
    np.testing.assert_allclose(br.params, om, atol=1e-6)
    g = KAPPA * f * w_ref / br.params  # Γ at each point's own Ω
    r, cp, sp_ = br.solutions[:, 0], np.cos(psi), np.sin(psi)
    det = C * g * sp_ / r - g * cp * (2 * K * r - g * cp / r**2)
    clear = np.abs(det) > 0.02 * np.abs(det).max()
    assert np.array_equal(br.stable[clear], det[clear] > 0)
    assert band_coverage(br, om, rho, np.pi - psi)["coverage"] > 0.6
    # S-curve at an untrained frequency: F = Γ(ρ) / (κ Ω̄/Ω)
    sc = m.scurve(1.008, (0.0, 0.012))
    rs = sc.data["observed_amplitude"]
    g_s = np.sqrt((C * rs) ** 2 + (W0 + K * rs**2 - 1.008) ** 2 * rs**2)
    np.testing.assert_allclose(sc.params, g_s / (KAPPA * w_ref / 1.008), rtol=1e-4)
    loaded = load(m.save(tmp_path / "m"))
    assert loaded.summary()["parameters"]["forcing_frequency"] == "inverse"
    np.testing.assert_allclose(loaded.frc(f, (0.97, 1.03)).params, m.frc(f, (0.97, 1.03)).params)


def test_band_widens_away_from_the_data(model):
    def predicted(**query):
        with warnings.catch_warnings():  # the extrapolation warning is tested elsewhere
            warnings.simplefilter("ignore", UserWarning)
            return model.predict_diagram(level=0.95, **query).branches[0]

    def width_at_peak(br):  # amplitude width of the interval where the FRC peaks
        i = int(np.argmax(br.data["observed_amplitude"]))
        lo, hi = br.intervals["amplitude"]
        return abs(hi[i, 0] - lo[i, 0])

    inside = predicted(forcing=0.0085, range=(0.97, 1.03))
    outside = predicted(forcing=0.02, range=(0.97, 1.05))
    assert width_at_peak(outside) > 3 * width_at_peak(inside)
    bb = predicted(kind="backbone", range=(0.1, 8.0))
    lo, hi = bb.intervals["omega"]
    width = np.asarray(hi) - np.asarray(lo)
    trained = bb.params <= model.rho_range_[1]
    assert np.median(width[~trained]) > 3 * np.median(width[trained])


def test_backbone_and_scurve_match_exact_formulas(model):
    bb = model.backbone((0.2, 3.2))
    np.testing.assert_allclose(bb.data["omega"], W0 + K * bb.params**2, atol=2e-6)
    om = 1.004  # above resonance: an S-curve with two folds
    sc = model.scurve(om, (0.0, 0.012))
    rho = sc.data["observed_amplitude"]
    f_exact = np.sqrt((C * rho) ** 2 + (W0 + K * rho**2 - om) ** 2 * rho**2) / KAPPA
    np.testing.assert_allclose(sc.params, f_exact, rtol=2e-3, atol=1e-7)
    rr = np.linspace(1e-3, 6, 600_001)
    ff = np.sqrt((C * rr) ** 2 + (W0 + K * rr**2 - om) ** 2 * rr**2) / KAPPA
    dd = np.diff(ff)
    exact = np.sort(ff[np.nonzero(np.sign(dd[:-1]) != np.sign(dd[1:]))[0] + 1])
    folds = np.sort([sp.param for sp in sc.special("fold")])
    np.testing.assert_allclose(folds, exact, rtol=2e-3)
    # the middle branch between the folds is unstable, the others stable
    lo, hi = sorted(sp.data["amplitude"] for sp in sc.special("fold"))
    mid = (rho > lo * 1.02) & (rho < hi * 0.98)
    assert np.all(~sc.stable[mid]) and np.all(sc.stable[(rho < lo * 0.98) | (rho > hi * 1.02)])


def test_time_series_through_the_observation_model(model):
    fp = model.fixed_points(1.002, 0.009)
    assert len(fp) >= 1
    p = fp[0]
    t = np.linspace(0, 2 * np.pi / 1.002, 50)
    y = model.time_series(t, p["rho"], p["psi"], 1.002)
    exact = -p["rho"] * np.cos(1.002 * t + p["psi"])
    assert np.sqrt(np.mean((y - exact) ** 2)) < 1e-3 * p["rho"]


def test_save_load_roundtrip_and_no_pickle(model, tmp_path):
    d = model.save(tmp_path / "m")
    meta = json.loads((d / "model.json").read_text())
    assert meta["type"] == "forced_kernel"
    loaded = load(d)
    assert isinstance(loaded, ForcedKernelModel)
    r = np.linspace(0.5, 3, 5)
    np.testing.assert_allclose(
        loaded.reduced_dynamics(r, 1.0), model.reduced_dynamics(r, 1.0), rtol=1e-12, atol=1e-15
    )
    assert loaded.frc(0.01, (0.98, 1.02)).special("peak")[0].param == pytest.approx(
        model.frc(0.01, (0.98, 1.02)).special("peak")[0].param, rel=1e-10
    )
    with np.load(d / "arrays.npz", allow_pickle=False) as z:
        assert all(z[k].dtype.kind in "biuf" for k in z.files)


def test_invariance_to_a_given_forcing_scale(dataset):
    m2 = ForcedKernelModel(forcing_scale=1.0, n_restarts=0, observation=False).fit(dataset)
    peak = m2.frc(0.01, (0.98, 1.02)).special("peak")[0].data["amplitude"]
    assert peak == pytest.approx(KAPPA * 0.01 / C, rel=2e-3)


def test_input_errors_and_unfitted():
    with pytest.raises(NotFittedError):
        ForcedKernelModel().frc(0.01)
    with pytest.raises(BifidInputError, match="forcing_scale"):
        ForcedKernelModel(forcing_scale=-1.0).fit(
            omega=[1, 1.1, 1.2, 1.3], forcing=[1] * 4, amplitude=[1] * 4, phase=[1] * 4
        )
    with pytest.raises(BifidInputError, match="four arrays"):
        ForcedKernelModel().fit(omega=[1.0, 1.1])
    with pytest.raises(BifidInputError, match="at least 4"):
        ForcedKernelModel().fit(
            omega=[1, 1.1, 1.2, 1.3],
            forcing=[1] * 4,
            amplitude=[1] * 4,
            phase=[np.nan, np.nan, 1, 1],
        )
    with pytest.raises(BifidInputError, match="forcing_frequency"):
        ForcedKernelModel(forcing_frequency="cubic").fit(
            omega=[1, 1.1, 1.2, 1.3], forcing=[1] * 4, amplitude=[1] * 4, phase=[1] * 4
        )
    with pytest.raises(BifidInputError, match="a_basis"):
        ForcedKernelModel(a_basis=((0, 0),)).fit(
            omega=[1, 1.1, 1.2, 1.3], forcing=[1] * 4, amplitude=[1] * 4, phase=[1] * 4
        )


def test_single_frequency_needs_a_scale_or_linear_frequency():
    om = 0.98
    rho = np.linspace(0.2, 3.0, 32)  # the fixture's size: the same compiled programs
    g = np.sqrt((C * rho) ** 2 + (W0 + K * rho**2 - om) ** 2 * rho**2)
    lag = np.pi - np.arctan2(C * rho, -(W0 + K * rho**2 - om) * rho)
    with pytest.raises(BifidInputError, match="several forcing frequencies"):
        ForcedKernelModel(forcing_scale="fit", observation=False).fit(
            omega=np.full(32, om), forcing=g / KAPPA, amplitude=rho, phase=lag
        )
    m = ForcedKernelModel(linear_frequency=W0, n_restarts=0, observation=False).fit(
        omega=np.full(32, om), forcing=g / KAPPA, amplitude=rho, phase=lag
    )
    assert m.forcing_scale_ == pytest.approx(KAPPA, rel=1e-3)
    m1 = ForcedKernelModel(n_restarts=0, observation=False).fit(
        omega=np.full(32, om), forcing=g / KAPPA, amplitude=rho, phase=lag
    )
    assert m1.forcing_scale_ == 1.0 and any("κ" in n for n in m1.notes_)


# ------------------------------------------------------------------------------ CLI


def test_cli_fit_and_predict(dataset, tmp_path: Path, bifid_cli):
    """Check `bifid fit forced` and `bifid predict` (FRC, S-curve, backbone): contract keys
    and analytic values; a level is answered with intervals."""
    data = tmp_path / "d.nc"
    save_dataset(dataset, data)
    r = bifid_cli(
        "fit",
        "forced",
        data,
        "--out",
        tmp_path / "m",
        "--restarts",
        "0",
        "--no-observation",
        "--json",
    )
    assert r.code == 0, r.stderr
    payload = r.json
    assert {"parameters", "standard_errors", "losses", "settings"} <= set(payload)
    assert payload["parameters"]["forcing_scale"] == pytest.approx(KAPPA, rel=1e-3)
    errors = payload["standard_errors"]
    assert 0 < errors["forcing_scale"] < 1e-3 * KAPPA  # exact training data
    assert set(errors["b"]) == set(payload["parameters"]["b"])
    r = bifid_cli(
        "predict",
        tmp_path / "m",
        "--frc",
        "--forcing",
        "0.012",
        "--omega-range",
        "0.97",
        "1.03",
        "--json",
    )
    assert r.code == 0, r.stderr
    p = r.json
    assert {"points", "folds", "peak", "complete"} <= set(p)
    assert p["peak"]["amplitude"] == pytest.approx(KAPPA * 0.012 / C, rel=1e-3)
    assert len(p["folds"]) == 2 and all(isinstance(q["stable"], bool) for q in p["points"])
    r = bifid_cli(
        "predict",
        tmp_path / "m",
        "--scurve",
        "--omega",
        "1.004",
        "--forcing-range",
        "0",
        "0.012",
        "--json",
    )
    assert r.code == 0, r.stderr
    p = r.json
    assert {"points", "folds"} <= set(p) and len(p["folds"]) == 2
    r = bifid_cli(
        "predict",
        tmp_path / "m",
        "--backbone",
        "--amplitude-range",
        "0.5",
        "3",
        "--n-points",
        "5",
        "--json",
    )
    assert r.code == 0, r.stderr
    p = r.json
    assert len(p["points"]) == 5
    assert p["points"][-1]["omega"] == pytest.approx(W0 + K * 9, abs=1e-5)
    r = bifid_cli(
        "predict", tmp_path / "m", "--frc", "--forcing", "0.01", "--level", "0.95", "--json"
    )
    assert r.code == 0 and r.json["level"] == 0.95, r.stderr
    r = bifid_cli("predict", tmp_path / "m", "--forcing", "0.01", "--omega", "1.0")
    assert r.code == 2 and "does not apply" in r.stderr
