"""Mechanistic three-stage identification (thesis §4.3): optimiser, normal-form stage,
implicit gradients through the collocation orbits, whole-diagram update, IO, CLI."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from bifid.errors import BifidInputError, ConvergenceError, NotFittedError
from bifid.identify.mechanistic import (
    LCOData,
    MechanisticModel,
    OrbitSet,
    fit_near_hopf,
    levenberg_marquardt,
    model_branch,
    whole_diagram_update,
)
from bifid.identify.normal_form import hopf_normal_form
from bifid.signal import max_abs
from bifid.systems import get_system

U_MEAS = np.array([15.5, 16.5, 17.5, 18.0, 15.2, 16.0, 17.0, 18.0])
STABLE = np.array([0, 0, 0, 0, 1, 1, 1, 1])


@pytest.fixture(scope="module")
def flutter():
    return get_system("flutter")


@pytest.fixture(scope="module")
def truth(flutter):
    """Noise-free LCO amplitudes (h, alpha) of the true model at 8 wind speeds."""
    p = np.array(flutter.param_vector())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        br = model_branch(flutter, p, "U", n_mesh=32, guess=18.0, param_range=(14.0, 18.5))
    probe = LCOData(U_MEAS, np.zeros((8, 2)), STABLE, ("h", "alpha"), np.full(8, np.nan))
    orbits = OrbitSet(flutter, "U", 32, ("h", "alpha"))
    orbits.match(br, probe, p)
    amps = orbits.amplitudes()
    return {"p": p, "branch": br, "orbits": orbits,
            "data": LCOData(U_MEAS, amps[:, :1], STABLE, ("h",), np.full(8, np.nan)),
            "amps": amps}


# --------------------------------------------------------------------- optimiser
def test_levenberg_marquardt_min_norm_on_rank_deficient_problem() -> None:
    # r = A x - b with A of rank 1: LM must reach the solution nearest x0
    A = np.array([[1.0, 2.0], [2.0, 4.0], [3.0, 6.0]])
    b = np.array([1.0, 2.0, 3.0])
    x0 = np.array([3.0, -1.0])
    res = levenberg_marquardt(lambda x: A @ x - b, lambda x: A, x0, max_iter=100)
    expected = x0 - np.linalg.pinv(A) @ (A @ x0 - b)
    np.testing.assert_allclose(res.x, expected, atol=1e-8)
    assert res.cost < 1e-16


def test_levenberg_marquardt_rejects_infeasible_steps() -> None:
    # minimum of (x-3)^2 with x > 1 enforced by returning None: start at 2, converge to 3
    def fun(x):
        return None if x[0] <= 1.0 else np.array([x[0] - 3.0, 0.1 * (x[0] - 3.0)])

    res = levenberg_marquardt(fun, lambda x: np.array([[1.0], [0.1]]), np.array([2.0]))
    assert res.x[0] == pytest.approx(3.0, abs=1e-9)
    with pytest.raises(ConvergenceError):
        levenberg_marquardt(fun, lambda x: np.ones((2, 1)), np.array([0.0]))


# ------------------------------------------------------------ amplitude of an orbit
def test_max_abs_weights_match_lead_and_finite_differences() -> None:
    from bifid.identify.mechanistic import _max_abs_with_weights

    rng = np.random.default_rng(1)
    M = 32
    tau = 2 * np.pi * np.arange(M) / M
    v = 0.3 + np.cos(tau + 0.4) + 0.2 * np.sin(3 * tau) + 0.05 * rng.standard_normal(1)
    amp, w = _max_abs_with_weights(v)
    assert amp == pytest.approx(max_abs(v), rel=1e-12)
    # envelope theorem: d max / d v = sign w(t*)
    h = 1e-6
    for j in (0, 5, 17):
        e = np.zeros(M)
        e[j] = h
        fd = (_max_abs_with_weights(v + e)[0] - _max_abs_with_weights(v - e)[0]) / (2 * h)
        assert w[j] == pytest.approx(fd, abs=1e-7)


# ---------------------------------------------------------------- normal-form stage
def test_normal_form_stage_identifies_only_alpha2(flutter) -> None:
    p = np.array(flutter.param_vector())
    nf = hopf_normal_form(flutter, "U", p=p, guess=18.0)
    U = np.array([17.6, 17.8, 18.0, 18.2])
    amps = nf.amplitude(U, "h")  # exact leading-order amplitudes of the true model
    data = LCOData(U, amps, np.zeros(4, int), ("h",), np.full(4, np.nan))
    # start supercritical (ka2 -30 %, ka3 +30 %): the closed-form alpha2 still gets there
    p0 = p.copy()
    p0[flutter.index("ka2")] *= 0.7
    p0[flutter.index("ka3")] *= 1.3
    res = fit_near_hopf(flutter, p0, ("ka2", "ka3"), data, nf=nf)
    assert res.alpha2 == pytest.approx(nf.alpha2, rel=1e-9)
    assert res.rms < 1e-10
    s = res.structure
    assert s["c3"] * res.params["ka3"] + s["c22"] * res.params["ka2"] ** 2 == pytest.approx(
        nf.alpha2, rel=1e-9)
    # rank one: a single identifiable combination
    assert res.singular_values[1] < 1e-8 * res.singular_values[0]
    assert "only c3·ka3 + c22·ka2² is identifiable" in res.statement
    # the unidentifiable direction is tangent to alpha2 = const
    g = np.array([2 * s["c22"] * res.params["ka2"] ** 2, s["c3"] * res.params["ka3"]])
    null = np.array([res.unidentifiable["ka2"], res.unidentifiable["ka3"]])
    assert abs(g @ null) < 1e-8 * np.linalg.norm(g)
    with pytest.raises(BifidInputError, match="linearisation"):
        fit_near_hopf(flutter, p0, ("ka", "ka3"), data, nf=nf)
    with pytest.raises(BifidInputError, match="no cycles"):
        fit_near_hopf(flutter, p0, ("ka2", "ka3"),
                      LCOData([18.5], [0.01], [0], ("h",), [np.nan]), nf=nf)


# ------------------------------------------------------------------ implicit gradient
def test_implicit_amplitude_jacobian_equals_finite_differences(flutter, truth) -> None:
    orbits = truth["orbits"]
    p = truth["p"]
    J = orbits.amplitude_jacobian(p, ("ka3", "ca"))
    for k, name in enumerate(("ka3", "ca")):
        i = flutter.index(name)
        h = 1e-5 * p[i]
        amps = []
        for sgn in (1, -1):
            q = p.copy()
            q[i] += sgn * h
            ys = orbits.solve(q)
            assert ys is not None
            amps.append(orbits.amplitudes(ys))
        fd = (amps[0] - amps[1]) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], fd, rtol=2e-5, atol=1e-12 * np.abs(fd).max())


def test_matching_follows_the_fold_sides(truth) -> None:
    orbits = truth["orbits"]
    # unstable LCOs lie between the Hopf point and the fold (d U / d A < 0), stable beyond
    np.testing.assert_array_equal(orbits.sides, np.where(STABLE == 0, -1, 1))
    a = truth["amps"][:, 0]
    assert np.all(a[4:] > a[:4])  # at U = 18 the stable orbit is the large one
    fold = truth["branch"].special("cycle_fold")[0].param
    assert fold == pytest.approx(14.9378, abs=1e-3)


# ------------------------------------------------------------------ whole diagram
def test_whole_diagram_update_small_perturbation(flutter, truth) -> None:
    p0 = truth["p"].copy()
    p0[flutter.index("ka2")] *= 1.05
    p0[flutter.index("ka3")] *= 0.95
    data = truth["data"].select(np.isin(np.arange(8), [1, 3, 5, 6]))
    # the true model's branch is the initial guess (no new continuation): the stable orbit
    # at U = 16 does not converge directly at p0 and is followed from p to p0 in substeps
    res = whole_diagram_update(flutter, p0, ("ka2", "ka3"), data, n_mesh=32,
                               branch=truth["branch"], hopf_guess=18.2, schedule="all",
                               max_iter=20)
    assert res.params["ka2"] == pytest.approx(751.6, rel=1e-6)
    assert res.params["ka3"] == pytest.approx(5006.7, rel=1e-6)
    assert res.rms < 1e-9
    assert res.lm.converged
    # Gauss-Newton with exact gradients: few iterations
    assert res.lm.n_iter <= 8
    assert res.n_jev == res.lm.n_jev and res.jac_time_s > 0


def test_lco_data_validation() -> None:
    with pytest.raises(BifidInputError):
        LCOData([1.0], [[-1.0]], [0], ("h",), [np.nan])
    with pytest.raises(BifidInputError):
        LCOData([1.0], [[1.0]], [2], ("h",), [np.nan])
    with pytest.raises(BifidInputError):
        LCOData([1.0], [[1.0, 2.0]], [0], ("h",), [np.nan])
    with pytest.raises(NotFittedError):
        MechanisticModel().summary()
    with pytest.raises(BifidInputError, match="stages"):
        MechanisticModel(stages=("bogus",)).fit(
            LCOData([17.0], [[0.01]], [0], ("h",), [np.nan]))


def test_lco_data_from_real_cbc_dataset(shared_data) -> None:
    from bifid.data import flutter_cbc_dataset

    files = sorted((shared_data / "flutter_rig" / "cbc_model1").glob("*.mat"))
    d = LCOData.from_dataset(flutter_cbc_dataset(files), ("h", "alpha"))
    assert len(d) == 9
    assert sorted(d.param[d.stable == 1].tolist()) == [14.9, 15.6, 16.5, 17.3]
    assert sorted(d.param[d.stable == 0].tolist()) == [14.9, 15.7, 16.4, 16.5, 17.2]
    # Fourier amplitudes are below the raw maxima (noise removed) but close to them
    raw = LCOData.from_dataset(flutter_cbc_dataset(files), ("h", "alpha"), amplitude="dataset")
    assert np.all(d.amplitude <= raw.amplitude * 1.001)
    assert np.all(d.amplitude > 0.85 * raw.amplitude)
    assert np.all(np.abs(d.frequency / (2 * np.pi) - 2.5) < 0.1)


def test_fit_save_load_predict_cli(tmp_path, flutter, truth) -> None:
    """The CLI on a dataset written from the true model; normal-form stage only (fast)."""
    from typer.testing import CliRunner

    from bifid.cli import _load_commands, app
    from bifid.data import LCORecord, lco_dataset, save_dataset

    orbits = truth["orbits"]
    M, n = 32, 6
    recs = []
    for j, y in enumerate(orbits.ys):
        V = y[: M * n].reshape(M, n)
        T = y[M * n]
        fine = np.fft.irfft(np.fft.rfft(V, axis=0), n=4 * M, axis=0) * 4
        sig = np.tile(fine[:, [0, 2]], (3, 1))
        recs.append(LCORecord(param=float(U_MEAS[j]), signals=sig, sample_rate=4 * M / T,
                              stable=bool(STABLE[j]), frequency=2 * np.pi / T))
    ds = lco_dataset(recs, ["h", "alpha"], param_name="U", param_units="m/s", system="flutter",
                     settings={"test": True}, source="test")
    path = tmp_path / "lco.nc"
    save_dataset(ds, path)
    _load_commands()
    runner = CliRunner()
    out = tmp_path / "model"
    r = runner.invoke(app, ["fit", "mechanistic", str(path), "--model", "flutter", "--free",
                            "ka2,ka3", "--stages", "normal_form", "--set", "ka2=700",
                            "--out", str(out), "--json", "--quiet"])
    assert r.exit_code == 0, r.output
    payload = json.loads(r.stdout)
    assert set(payload) >= {"parameters", "losses", "settings", "hopf"}
    assert payload["hopf"]["param"] == pytest.approx(18.2748, abs=1e-3)
    # leading-order normal form: a few per cent of the largest amplitude over the diagram
    assert 0 < payload["losses"]["normal_form"] < 4e-3
    m = MechanisticModel.load(out)
    assert m.params_ == payload["parameters"]
    assert m.p_[flutter.index("ka2")] == pytest.approx(payload["parameters"]["ka2"])
    r = runner.invoke(app, ["predict", str(out), "--param", "U", "--range", "17.8", "18.5",
                            "--json"])
    assert r.exit_code == 0, r.output
    pred = json.loads(r.stdout)
    assert set(pred) >= {"hopf", "cycle_folds", "secondary", "orbits"}
    assert pred["hopf"][0]["param"] == pytest.approx(18.2748, abs=1e-3)
    assert pred["hopf"][0]["criticality"] == "subcritical"
    # user errors exit 2 with a message
    r = runner.invoke(app, ["fit", "mechanistic", str(path), "--free", "nope", "--stages",
                            "normal_form", "--out", str(tmp_path / "m2")])
    assert r.exit_code == 2
    r = runner.invoke(app, ["fit", "mechanistic", str(path), "--stages", "linear",
                            "--out", str(tmp_path / "m3")])
    assert r.exit_code == 2
