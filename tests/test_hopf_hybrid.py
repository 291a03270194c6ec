"""Hybrid normal-form + neural-network Hopf model (thesis ch. 5): fast checks.

The data here lie exactly in the model class — limit cycles of the normal form eq. 5.3 seen
through a known affine map, plus a third signal that is a known nonlinear function of the
plane — so the Hopf point, the fold of cycles, amplitudes, frequencies and time series have
analytic values to compare with. One small network configuration is shared by every test so
that the training loops compile once. Accuracy on Van der Pol and the flutter model:
``tests/slow/test_hopf_hybrid_accuracy.py`` and ``benchmarks/bench_hopf_hybrid.py``.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from bifid.errors import BifidInputError, NotFittedError
from bifid.identify import HopfHybridModel, load

MU0, A2, OMEGA = 1.0, 1.2, 2.0  # raw-units normal form: fold at MU0 - A2**2 / 4 = 0.64
FOLD = MU0 - A2**2 / 4
MAP = np.array([[0.8, 0.3], [-0.2, 0.5]])  # det < 0 is not needed; rotation is counter-clockwise
OFFSET = np.array([0.05, -0.02])
STABLE = (0.7, 0.85, 1.0, 1.15)
UNSTABLE = (0.68, 0.8, 0.92)
NAMES = ("x", "y", "w")

FAST = dict(
    n_harmonics=6,
    width=8,
    depth=2,
    n_lbfgs=150,
    n_ensemble=2,
    regularization=1e-6,
    stopping="final",
    omega_harmonics=2,
    omega_regularization=1e-4,
)


def radius(mu: float, stable: bool) -> float:
    """Cycle radius of dr/dt = (mu - mu0) r + a2 r^3 - r^5 (raw units, eq. 5.3)."""
    disc = A2**2 + 4 * (mu - MU0)
    return math.sqrt(0.5 * (A2 + (1 if stable else -1) * math.sqrt(disc)))


def signals(mu: float, stable: bool, t: np.ndarray, phase: float = 0.0) -> np.ndarray:
    r = radius(mu, stable)
    u = r * np.stack([np.cos(OMEGA * t + phase), np.sin(OMEGA * t + phase)], axis=1)
    z = u @ MAP.T + OFFSET
    w = z[:, 0] * z[:, 1] + 0.3 * z[:, 0]  # a third measured signal, nonlinear in the plane
    return np.column_stack([z, w])


def amplitude(mu: float, stable: bool) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi / OMEGA, 4096, endpoint=False)
    return np.max(np.abs(signals(mu, stable, t)), axis=0)


def records(noise: float = 0.0, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(800) / 100.0  # 8 s at 100 Hz, about 2.5 periods
    out = []
    for values, stable in ((STABLE, True), (UNSTABLE, False)):
        for mu in values:
            s = signals(mu, stable, t, phase=rng.uniform(0, 2 * np.pi))
            out.append((mu, s + noise * rng.standard_normal(s.shape), 100.0, stable))
    return out


@pytest.fixture(scope="module")
def model() -> HopfHybridModel:
    return HopfHybridModel(**FAST).fit(records(), signal_names=NAMES)


def test_recovers_hopf_point_and_fold(model):
    """Check that the Hopf point, the fold and a2 of the generating normal form are found."""
    assert model.hopf_point()["param"] == pytest.approx(MU0, abs=5e-3)
    assert model.hopf_point()["criticality"] == "subcritical"
    assert model.cycle_fold()["param"] == pytest.approx(FOLD, abs=5e-3)
    assert model.a2_ == pytest.approx(A2, rel=0.02)
    summary = model.summary()
    p = summary["parameters"]
    assert p["mu0"] == model.mu0_ and p["fold"] == model.cycle_fold()["param"]
    assert summary["ensemble"]["mu0"]["min"] <= p["mu0"] <= summary["ensemble"]["mu0"]["max"]


@pytest.mark.parametrize(
    ("mu", "stable"), [(0.78, True), (1.08, True), (0.74, False), (0.86, False)]
)
def test_amplitudes_and_frequency_at_untrained_parameters(model, mu, stable):
    """Check amplitudes of all three signals (incl. the regressed one) and the frequency."""
    pred = model.predict_amplitude([mu], stable=stable)[0]
    truth = amplitude(mu, stable)
    np.testing.assert_allclose(pred[:2], truth[:2], rtol=0.005)  # the plane: U_12
    np.testing.assert_allclose(pred[2], truth[2], rtol=0.02)  # regressed signal: U_3
    assert model.predict_frequency([mu], stable=stable)[0] == pytest.approx(OMEGA, rel=2e-3)
    orbit = model.predict_orbit(mu, stable=stable)
    np.testing.assert_allclose(orbit.amplitude, pred, rtol=0.01)
    assert orbit.period == pytest.approx(2 * np.pi / OMEGA, rel=2e-3)


def test_no_cycle_where_the_model_has_none(model):
    """Check that asking for a cycle below the fold is an input error naming the fold."""
    with pytest.raises(BifidInputError, match=r"no stable limit cycle.*fold"):
        model.predict_amplitude([0.5], stable=True)
    with pytest.raises(BifidInputError, match="no unstable limit cycle"):
        model.predict_amplitude([1.1], stable=False)


def test_time_series_phase_matched(model):
    """Check a predicted time series against the analytic one from the same first sample."""
    t = np.arange(300) / 100.0
    truth = signals(0.9, True, t, phase=0.7)
    pred = model.predict_time_series(0.9, t, stable=True, initial=truth[0])
    rms = np.sqrt(np.mean((pred - truth) ** 2, axis=0)) / np.sqrt(np.mean(truth**2, axis=0))
    assert np.all(rms < 0.03), rms


def test_diagram_matches_continue_contract(model):
    """Check the predicted Diagram: the keys of `bifid continue`, stability along the branch
    against the Floquet multipliers, and the ensemble spread around the prediction."""
    d = model.predict_diagram(range=(0.5, 1.3), n_points=60)
    assert d.kind == "bifurcation" and d.complete
    j = d.to_json()
    assert set(j) >= {"hopf", "cycle_folds", "secondary", "orbits", "complete", "status"}
    assert j["hopf"][0]["param"] == pytest.approx(MU0, abs=5e-3)
    assert {"param", "period", "amplitude"} <= set(j["cycle_folds"][0])
    orbits = j["orbits"]
    assert all({"param", "period", "stable", "floquet_max", "amplitude"} <= set(o) for o in orbits)
    assert all(0.5 <= o["param"] <= 1.3 for o in orbits)
    # the inner branch (small amplitude) is unstable, the outer one stable; multipliers agree
    for o in orbits:
        assert (o["floquet_max"] < 1) == o["stable"]
        assert o["period"] == pytest.approx(2 * np.pi / OMEGA, rel=5e-3)
    small = [o for o in orbits if o["amplitude"]["x"] < 0.5 * amplitude(FOLD, True)[0]]
    assert small and not any(o["stable"] for o in small)
    json.dumps(j)  # JSON-able
    spread = model.ensemble_spread((0.5, 1.3), n_points=12)
    assert spread["hopf_param"]["min"] <= j["hopf"][0]["param"] <= spread["hopf_param"]["max"]
    with pytest.raises(BifidInputError, match="no calibrated intervals"):
        model.predict_diagram(range=(0.5, 1.3), level=0.9)
    with pytest.raises(BifidInputError, match="predicts bifurcation"):
        model.predict_diagram(forcing=0.1)


def test_save_load_round_trip(model, tmp_path):
    """Check that a saved model predicts exactly the same, and holds no pickle."""
    path = model.save(tmp_path / "m", settings={"note": "test"})
    assert sorted(p.name for p in path.iterdir()) == ["arrays.npz", "model.json"]
    meta = json.loads((path / "model.json").read_text())
    assert meta["type"] == "hopf_hybrid"
    with np.load(path / "arrays.npz", allow_pickle=False) as npz:
        assert all(npz[k].dtype.kind in "biuf" for k in npz.files)
    loaded = load(path)
    assert isinstance(loaded, HopfHybridModel)
    np.testing.assert_allclose(
        loaded.predict_amplitude([0.9, 1.1]), model.predict_amplitude([0.9, 1.1]), rtol=1e-12
    )
    t = np.linspace(0, 3, 50)
    np.testing.assert_allclose(
        loaded.predict_time_series(0.9, t, stable=False),
        model.predict_time_series(0.9, t, stable=False),
        rtol=1e-10,
        atol=1e-12,
    )
    assert loaded.summary()["parameters"] == model.summary()["parameters"]


def test_training_record_holds_the_measured_orbits(model):
    """Check that the fit records every orbit's parameter, frequency and amplitude
    ``max_t |z_k|`` against their analytic values."""
    mus = [*STABLE, *UNSTABLE]
    stable = [True] * len(STABLE) + [False] * len(UNSTABLE)
    np.testing.assert_array_equal(model.training_["param"], mus)
    np.testing.assert_array_equal(model.training_["stable"], stable)
    np.testing.assert_allclose(model.training_["frequency"], OMEGA, rtol=1e-3)
    expected = [amplitude(mu, st) for mu, st in zip(mus, stable, strict=True)]
    np.testing.assert_allclose(model.training_["amplitude"], expected, rtol=1e-3)


def test_bootstrap_refits_keep_the_selected_harmonics():
    """Check that the refits of the intervals keep the number of polar harmonics the fit
    chose: chosen afresh on these records with their noise resampled, it ranges from 4 to
    20 (another model on every such refit)."""
    short = dict(n_linear=20, n_lbfgs=20, omega_fit_iterations=50, omega_iterations=0)
    m = HopfHybridModel(**{**FAST, **short, "n_harmonics": "auto", "n_ensemble": 1})
    m.fit(records(noise=0.01, seed=0), signal_names=NAMES, uncertainty=True)
    chosen = m.state_.map_config.n_harmonics
    assert 4 <= chosen <= 32
    assert len(m.replicates_) == 8
    assert [r.map_config.n_harmonics for r in m.replicates_] == [chosen] * 8


def test_load_rejects_other_model_types(tmp_path):
    """Check that loading a model of another type is a clear input error."""
    from bifid.io import save_model

    save_model(tmp_path / "other", "forced_kernel", {"x": 1})
    with pytest.raises(BifidInputError, match="not 'hopf_hybrid'"):
        HopfHybridModel.load(tmp_path / "other")


def test_not_fitted():
    """Check that predicting before fit raises NotFittedError."""
    with pytest.raises(NotFittedError, match="not fitted"):
        HopfHybridModel().predict_amplitude([1.0])


@pytest.mark.parametrize(
    ("kwargs", "data", "match"),
    [
        ({"plane": ("x", "nope")}, None, "plane signal 'nope'"),
        ({"criticality": "supercritical"}, None, "supercritical Hopf bifurcation has no"),
        ({"criticality": "subcritical", "quintic": False}, None, "needs the quintic"),
        ({"regularization": -1.0}, None, "'regularization' parameter"),
        ({}, "one", "at least 2 limit-cycle records"),
        ({}, "short", "less than one period"),
        ({}, "bad", "signals must have shape"),
    ],
)
def test_input_errors(kwargs, data, match):
    """Check that bad hyperparameters and data are rejected with a message saying why."""
    recs = records()
    if data == "one":
        recs = recs[:1]
    elif data == "short":
        recs = [(mu, s[:20], fs, st) for mu, s, fs, st in recs]
    elif data == "bad":
        recs = [(recs[0][0], recs[0][1][:, 0], 100.0, True), *recs[1:]]
    with pytest.raises(BifidInputError, match=match):
        HopfHybridModel(**{**FAST, **kwargs}).fit(recs, signal_names=NAMES)


def test_cross_validation_selects_and_reports():
    """Check CV picks from the grid, stops inside the budget, and LOO errors are small."""
    m = HopfHybridModel(
        **{
            **FAST,
            "regularization": "cv",
            "regularization_grid": (1e-6, 1e-2),
            "stopping": "cv",
            "n_ensemble": 1,
        }
    )
    m.fit(records(noise=0.002, seed=1), signal_names=NAMES)
    assert m.regularization_ in (1e-6, 1e-2)
    assert 1 <= m.n_iterations_ <= FAST["n_lbfgs"]
    assert len(m.cv_["held_out"]) == len(STABLE) + len(UNSTABLE)
    # the selected pair is the grid's best median held-out loss at a 10 % checkpoint
    assert m.cv_["aggregate"] == "median"
    assert m.cv_["best_score"] == pytest.approx(np.median(m.cv_["held_out"]))
    report = m.cross_validate(records(noise=0.002, seed=1), signal_names=NAMES)
    folds = report["folds"]
    assert len(folds) == len(STABLE) + len(UNSTABLE)
    inner = [
        f
        for f in folds
        if f["param"] not in (min(STABLE), max(STABLE), min(UNSTABLE), max(UNSTABLE))
    ]
    for f in inner:  # interpolation folds: the left-out orbit is predicted within 3 %
        assert max(f["amplitude_error"][k] for k in ("x", "y")) < 0.03, f
        assert f["frequency_error"] < 0.01


def test_cli_fit_and_predict(tmp_path, bifid_cli):
    """Check `bifid fit hopf --json` and `bifid predict` on a netCDF dataset (contract keys)."""
    from bifid.data import LCORecord, lco_dataset, save_dataset

    recs = [
        LCORecord(param=mu, signals=s, sample_rate=fs, stable=st) for mu, s, fs, st in records()
    ]
    ds = lco_dataset(
        recs,
        list(NAMES),
        param_name="mu",
        param_units="",
        system="hopf",
        settings={},
        source="test",
    )
    save_dataset(ds, tmp_path / "d.nc")
    r = bifid_cli(
        "fit",
        "hopf",
        tmp_path / "d.nc",
        "--out",
        tmp_path / "m",
        "--json",
        "--quiet",
        "--harmonics",
        "6",
        "--width",
        "8",
        "--iterations",
        "150",
        "--ensemble",
        "2",
        "--regularization",
        "1e-6",
        "--stopping",
        "final",
        "--omega-harmonics",
        "2",
    )
    assert r.code == 0, r.stderr
    out = r.json
    assert {"parameters", "standard_errors", "losses", "settings"} <= set(out)
    assert out["parameters"]["mu0"] == pytest.approx(MU0, abs=0.01)
    assert out["parameters"]["fold"] == pytest.approx(FOLD, abs=0.01)
    r = bifid_cli(
        "predict",
        tmp_path / "m",
        "--param",
        "mu",
        "--range",
        "0.5",
        "1.3",
        "--json",
        "--n-points",
        "30",
    )
    assert r.code == 0, r.stderr
    pred = r.json
    assert {"hopf", "cycle_folds", "orbits"} <= set(pred)
    assert pred["hopf"][0]["param"] == pytest.approx(out["parameters"]["mu0"])
    assert set(pred["orbits"][0]["amplitude"]) == set(NAMES)
    r = bifid_cli("predict", tmp_path / "m", "--param", "U", "--range", "0.5", "1.3")
    assert r.code == 2 and "not 'U'" in r.stderr
