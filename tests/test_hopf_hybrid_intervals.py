"""Intervals of the hybrid Hopf model: bootstrap of the measurement noise and ensemble over
seeds.

The data are the analytic normal-form cycles of ``test_hopf_hybrid`` with a little noise, so
the true Hopf point and fold are known; the interval's formula is checked against an
independent computation from the replicates (refits on resampled noise, warm from the full
fit) and the ensemble members in the best optimum, and its level scaling against Student's
t. Coverage over replications: ``benchmarks/bench_calibration.py --method hybrid``.
"""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
import scipy.stats

from bifid.errors import BifidInputError
from bifid.identify import HopfHybridModel, load
from test_hopf_hybrid import FAST, FOLD, MU0, NAMES, records

NOISE, SEED = 0.003, 3
CALIBRATION = 1.05  # the factor on Student's t of docs/uncertainty.md
N_BOOTSTRAP = 8  # replicates; the t quantile has (N_BOOTSTRAP - 1) / 2 degrees of freedom
DOF_FRACTION = 0.5
LOSS_FACTOR = 2.0  # a member whose training loss is above twice the best is in another optimum


@pytest.fixture(scope="module")
def model() -> HopfHybridModel:
    return HopfHybridModel(**FAST).fit(
        records(noise=NOISE, seed=SEED), signal_names=NAMES, uncertainty=True
    )


@pytest.fixture(scope="module")
def diagram(model):
    with pytest.warns(UserWarning, match="extrapolates"):
        return model.predict_diagram(range=(0.5, 1.3), n_points=40, level=0.95)


def bootstrap_half_width(boots: list[float], members: list[float], level: float) -> float:
    """``c t_{(1+level)/2, (B-1)/2} sqrt(v_B + v_S)`` computed from scratch."""
    f, s = np.asarray(boots), np.asarray(members)
    n = f.size
    v_boot = np.sum((f - f.mean()) ** 2) / (n - 1)
    v_seed = np.sum((s - s.mean()) ** 2) / (s.size - 1)
    t = scipy.stats.t.ppf(0.5 + level / 2, DOF_FRACTION * (n - 1))
    return CALIBRATION * t * math.sqrt(v_boot + v_seed)


def as_model(model: HopfHybridModel, replicate) -> HopfHybridModel:
    """A view of one replicate (a refit on resampled noise) as a fitted model."""
    view = copy.copy(model)
    view.state_ = replicate
    return view


def best_members(model: HopfHybridModel) -> list[int]:
    """The members whose final training loss is within ``LOSS_FACTOR`` of the best one's."""
    final = np.asarray(model.summary()["losses"]["map_final"])
    return [s for s in range(final.size) if final[s] <= LOSS_FACTOR * final.min()]


def test_intervals_are_the_bootstrap_and_ensemble_variance(model, diagram):
    """Check the Hopf and fold intervals against the replicates and the members."""
    reps = [as_model(model, r) for r in model.replicates_]
    assert len(reps) == N_BOOTSTRAP
    members = best_members(model)
    (hopf,) = diagram.special("hopf")
    (fold,) = diagram.special("cycle_fold")
    for sp, point in (
        (hopf, lambda m, s: m.hopf_point(s)["param"]),
        (fold, lambda m, s: m.cycle_fold(s)["param"]),
    ):
        half = bootstrap_half_width(
            [point(r, 0) for r in reps], [point(model, s) for s in members], 0.95
        )
        lo, hi = sp.intervals["param"]
        assert half > 0
        assert lo == pytest.approx(sp.param - half, abs=1e-9 + 1e-6 * half)
        assert hi == pytest.approx(sp.param + half, abs=1e-9 + 1e-6 * half)
    se = model.summary()["standard_errors"]
    t975 = scipy.stats.t.ppf(0.975, DOF_FRACTION * (len(reps) - 1))
    assert CALIBRATION * se["mu0"] * t975 == pytest.approx(
        (hopf.intervals["param"][1] - hopf.intervals["param"][0]) / 2, rel=1e-6
    )
    assert set(se) == {"mu0", "a2", "omega0", "hopf_omega", "fold"}
    assert all(v > 0 and math.isfinite(v) for v in se.values())


def test_replicates_stay_in_the_full_fits_optimum(model):
    """Check that every refit on resampled noise keeps the full fit's Hopf point and fold to
    within a few noise-limited errors (0.02 at 0.3 % noise), where a cold start may land in
    another optimum of the training loss, and that the replicates differ (the noise was
    resampled)."""
    for r in model.replicates_:
        view = as_model(model, r)
        assert view.hopf_point(0)["param"] == pytest.approx(model.mu0_, abs=0.02)
        assert view.cycle_fold(0)["param"] == pytest.approx(model.cycle_fold()["param"], abs=0.02)
        assert view.hopf_point(0)["param"] == pytest.approx(MU0, abs=0.05)
    hopfs = [as_model(model, r).hopf_point(0)["param"] for r in model.replicates_]
    assert np.std(hopfs) > 0


def test_member_in_another_optimum_is_left_out(model, diagram):
    """Check that a member whose training loss is far above the best one's does not enter
    the seed term: with the other member's loss raised 100-fold, the Hopf interval is the
    bootstrap's alone (computed from scratch with no seed variance)."""
    worse = copy.copy(model)
    final = list(model.summary()["losses"]["map_final"])
    primary = model.summary()["parameters"]["primary_member"]
    other = 1 - primary
    final[other] = 100.0 * max(final)
    worse.losses_ = {**model.losses_, "map_final": final}
    with pytest.warns(UserWarning, match="extrapolates"):
        d = worse.predict_diagram(range=(0.5, 1.3), n_points=40, level=0.95)
    (hopf,) = d.special("hopf")
    f = np.asarray([as_model(model, r).hopf_point(0)["param"] for r in model.replicates_])
    n = f.size
    half = CALIBRATION * scipy.stats.t.ppf(0.975, DOF_FRACTION * (n - 1))
    half *= math.sqrt(np.sum((f - f.mean()) ** 2) / (n - 1))
    assert hopf.intervals["param"][1] - hopf.param == pytest.approx(half, rel=1e-6)


def test_intervals_hold_the_truth_and_scale_with_the_level(model, diagram):
    """Check that the 95 % intervals hold the generating Hopf point and fold, and that a
    lower level narrows every interval by the ratio of Student's t quantiles."""
    (hopf,) = diagram.special("hopf")
    (fold,) = diagram.special("cycle_fold")
    assert hopf.intervals["param"][0] <= MU0 <= hopf.intervals["param"][1]
    assert fold.intervals["param"][0] <= FOLD <= fold.intervals["param"][1]
    with pytest.warns(UserWarning, match="extrapolates"):
        d50 = model.predict_diagram(range=(0.5, 1.3), n_points=40, level=0.5)
    dof = DOF_FRACTION * (N_BOOTSTRAP - 1)
    ratio = scipy.stats.t.ppf(0.75, dof) / scipy.stats.t.ppf(0.975, dof)
    (h50,) = d50.special("hopf")
    w95 = np.subtract(*hopf.intervals["omega"][::-1])
    assert np.subtract(*h50.intervals["omega"][::-1]) == pytest.approx(ratio * w95, rel=1e-9)
    band95, band50 = (
        diagram.branches[0].intervals["amplitude"],
        d50.branches[0].intervals["amplitude"],
    )
    amp = diagram.branches[0].data["amplitude"]
    ok = np.isfinite(band95[0])
    assert ok.sum() > 20  # the band is defined away from the fold
    assert np.all(band95[0][ok] < amp[ok]) and np.all(amp[ok] < band95[1][ok])
    np.testing.assert_allclose(band50[1][ok] - amp[ok], ratio * (band95[1][ok] - amp[ok]))


def test_json_persistence_and_refusal(model, diagram, tmp_path, bifid_cli):
    """Check the JSON keys of the contract, that a saved model predicts the same intervals,
    and that a model fitted without uncertainty refuses a level and says how to get one."""
    j = diagram.to_json()
    assert j["level"] == 0.95
    assert {"param_interval", "omega_interval"} <= set(j["hopf"][0])
    assert {"param_interval", "period_interval", "amplitude_interval"} <= set(j["cycle_folds"][0])
    assert set(j["cycle_folds"][0]["amplitude_interval"]) == set(NAMES)
    assert any(o.get("amplitude_interval") for o in j["orbits"])
    json.dumps(j)
    model.save(tmp_path / "m")
    loaded = load(tmp_path / "m")
    assert loaded.summary()["standard_errors"] == model.summary()["standard_errors"]
    with pytest.warns(UserWarning, match="extrapolates"):
        again = loaded.predict_diagram(range=(0.5, 1.3), n_points=40, level=0.95)
    assert again.special("hopf")[0].intervals == diagram.special("hopf")[0].intervals
    r = bifid_cli("predict", tmp_path / "m", "--range", "0.5", "1.3", "--level", "0.9", "--json")
    assert r.code == 0, r.stderr
    assert len(r.json["hopf"][0]["param_interval"]) == 2
    plain = HopfHybridModel(**FAST).fit(records(), signal_names=NAMES)
    assert plain.summary()["standard_errors"] == {}
    with pytest.raises(BifidInputError, match="uncertainty=True"):
        plain.predict_diagram(level=0.95)
    # a model saved with replicates of another interval method (an orbit jackknife) loads
    # without them, with a warning, and refuses a level: never intervals of the wrong formula
    meta_path = tmp_path / "m" / "model.json"
    meta = json.loads(meta_path.read_text())
    state = meta["params"]["state"]
    state["jackknife"] = state.pop("bootstrap")
    meta_path.write_text(json.dumps(meta))
    with pytest.warns(UserWarning, match="jackknife replicates"):
        old = load(tmp_path / "m")
    with pytest.raises(BifidInputError, match="uncertainty=True"):
        old.predict_diagram(level=0.95)


def test_cli_fit_hopf_level(tmp_path, bifid_cli):
    """Check `bifid fit hopf --level`: the intervals and standard errors in the JSON, and a
    level outside (0, 1) refused before any training (exit 2)."""
    from bifid.data import LCORecord, lco_dataset, save_dataset

    recs = [
        LCORecord(param=mu, signals=s, sample_rate=fs, stable=st)
        for mu, s, fs, st in records(noise=NOISE, seed=SEED)
    ]
    ds = lco_dataset(
        recs, list(NAMES), param_name="mu", param_units="", system="hopf", settings={}, source="t"
    )
    save_dataset(ds, tmp_path / "d.nc")
    opts = ["--quiet", "--harmonics", "6", "--width", "8", "--iterations", "150"]
    opts += ["--ensemble", "2", "--regularization", "1e-6", "--stopping", "final"]
    opts += ["--omega-harmonics", "2", "--json"]
    r = bifid_cli("fit", "hopf", tmp_path / "d.nc", "--level", "2", *opts)
    assert r.code == 2 and "level" in r.stderr
    r = bifid_cli(
        "fit", "hopf", tmp_path / "d.nc", "--out", tmp_path / "m", "--level", "0.9", *opts
    )
    assert r.code == 0, r.stderr
    out = r.json
    assert out["intervals"]["level"] == 0.9
    lo, hi = out["intervals"]["hopf"][0]["param_interval"]
    assert lo < out["parameters"]["mu0"] < hi
    lo, hi = out["intervals"]["cycle_folds"][0]["param_interval"]
    assert lo < out["parameters"]["fold"] < hi
    assert set(out["standard_errors"]) == {"mu0", "a2", "omega0", "hopf_omega", "fold"}
