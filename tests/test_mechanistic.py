"""Mechanistic identification (thesis §4.3) on a model with analytic limit cycles.

The ``hopf`` system is eq. 5.2: its cycles are circles of radius
``r² = (a2 ± sqrt(a2² + 4 q5 (mu − mu0))) / (2 q5)`` (+ stable, − unstable), so amplitudes,
their derivatives in the parameters and the fold ``mu0 − a2²/(4 q5)`` are known in closed
form. The flutter model's runs (eq. 4.10, ±30 % starts, the real rig) are in
``tests/slow/test_mechanistic_recovery.py``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bifid.errors import BifidInputError, ConvergenceError, NotFittedError
from bifid.identify import LCOData, MechanisticModel, load
from bifid.identify.mechanistic import (
    OrbitSet,
    fit_near_hopf,
    hopf_normal_form,
    max_abs_with_weights,
    model_branch,
    whole_diagram_update,
)
from bifid.signal import max_abs
from bifid.systems import get_system

MU = np.array([-0.2, -0.12, -0.05, -0.02, -0.22, -0.15, -0.05, 0.05])
STABLE = np.array([0, 0, 0, 0, 1, 1, 1, 1])
A2, Q5 = 1.0, 1.0  # the system's defaults; mu0 = 0


def radius(mu, stable, a2=A2, q5=Q5):
    s = np.sqrt(a2**2 + 4 * q5 * np.asarray(mu))
    return np.sqrt((a2 + np.where(stable, s, -s)) / (2 * q5))


@pytest.fixture(scope="module")
def hopf():
    return get_system("hopf")


@pytest.fixture(scope="module")
def data():
    return LCOData.from_amplitudes(
        MU, radius(MU, STABLE == 1)[:, None], STABLE, ("u1",), param_name="mu"
    )


@pytest.fixture(scope="module")
def orbits(hopf, data):
    """The true model's orbits at the measured parameters (matched on its branch)."""
    p = np.array(hopf.param_vector())
    br = model_branch(hopf, p, "mu", n_mesh=16, guess=0.0, param_range=(-0.3, 0.1))
    o = OrbitSet(hopf, "mu", 16, ("u1",))
    o.match(br, data, p)
    return {"p": p, "branch": br, "orbits": o}


def test_max_abs_weights_match_max_abs_and_finite_differences() -> None:
    """Check the orbit amplitude against bifid.signal.max_abs and its weights (the envelope
    theorem's derivative) against finite differences."""
    rng = np.random.default_rng(1)
    M = 32
    tau = 2 * np.pi * np.arange(M) / M
    v = 0.3 + np.cos(tau + 0.4) + 0.2 * np.sin(3 * tau) + 0.05 * rng.standard_normal(1)
    amp, w = max_abs_with_weights(v)
    assert amp == pytest.approx(max_abs(v), rel=1e-12)
    h = 1e-6
    for j in (0, 5, 17):
        e = np.zeros(M)
        e[j] = h
        fd = (max_abs_with_weights(v + e)[0] - max_abs_with_weights(v - e)[0]) / (2 * h)
        assert w[j] == pytest.approx(fd, abs=1e-7)


def test_orbits_match_the_analytic_cycles_and_fold_sides(orbits) -> None:
    """Check the matched orbits' amplitudes, the fold side of each and the fold itself."""
    o = orbits["orbits"]
    np.testing.assert_allclose(o.amplitudes()[:, 0], radius(MU, STABLE == 1), rtol=1e-10)
    # unstable cycles lie between the Hopf point and the fold (d mu / d A < 0), stable beyond
    np.testing.assert_array_equal(o.sides, np.where(STABLE == 0, -1, 1))
    (fold,) = orbits["branch"].special("cycle_fold")
    assert fold.param == pytest.approx(-(A2**2) / (4 * Q5), abs=1e-6)


def test_implicit_amplitude_jacobian_is_the_analytic_derivative(hopf, orbits) -> None:
    """Check d amplitude / d (a2, q5) by implicit differentiation against the closed form."""
    J = orbits["orbits"].amplitude_jacobian(orbits["p"], ("a2", "q5"))[:, 0, :]
    s = np.sqrt(A2**2 + 4 * Q5 * MU) * np.where(STABLE == 1, 1.0, -1.0)
    r = radius(MU, STABLE == 1)
    # r^2 = (a2 + s) / (2 q5): d r/d a2 = (1 + a2/s) / (4 q5 r), d r/d q5 from the same rule
    dr_da2 = (1 + A2 / s) / (4 * Q5 * r)
    dr_dq5 = ((2 * MU / s) * 2 * Q5 - 2 * (A2 + s)) / (4 * Q5**2) / (2 * r)
    np.testing.assert_allclose(J[:, 0], dr_da2, rtol=1e-7)
    np.testing.assert_allclose(J[:, 1], dr_dq5, rtol=1e-7)


def test_whole_diagram_update_recovers_the_parameters(hopf, data) -> None:
    """Check that (a2, q5) perturbed by ±20 % are recovered from the whole diagram (the data
    homotopy, the branch recomputed between its steps) with exact gradients."""
    p0 = np.array(hopf.param_vector({"a2": 1.2, "q5": 0.8}))
    res = whole_diagram_update(hopf, p0, ("a2", "q5"), data, n_mesh=16, hopf_guess=0.0)
    assert res.params["a2"] == pytest.approx(A2, rel=1e-7)
    assert res.params["q5"] == pytest.approx(Q5, rel=1e-7)
    assert res.rms < 1e-9 and res.lm.converged
    assert res.n_jev >= res.lm.n_jev and res.jac_time_s > 0
    fd = whole_diagram_update(
        hopf, p0, ("a2", "q5"), data, n_mesh=16, hopf_guess=0.0, gradient="fd", schedule="all"
    )
    assert fd.params["a2"] == pytest.approx(A2, rel=1e-6)


def test_normal_form_stage_identifies_only_alpha2(hopf) -> None:
    """Check that the normal-form stage finds alpha2 and leaves the direction the near-Hopf
    amplitudes do not inform (q5 enters at fifth order) exactly where it started."""
    nf = hopf_normal_form(hopf, "mu", guess=0.0)
    mu = np.array([-0.04, -0.03, -0.02, -0.01])
    near = LCOData.from_amplitudes(
        mu, nf.amplitude(mu, "u1")[:, None], np.zeros(4, int), ("u1",), param_name="mu"
    )
    p0 = np.array(hopf.param_vector({"a2": 0.7, "q5": 1.3}))
    res = fit_near_hopf(hopf, p0, ("a2", "q5"), near, nf=nf)
    assert res.alpha2 == pytest.approx(nf.alpha2, rel=1e-9)
    assert res.params["a2"] == pytest.approx(A2, rel=1e-9)
    assert res.params["q5"] == pytest.approx(1.3, rel=1e-12)  # minimum-norm: untouched
    assert res.rms < 1e-10
    assert res.singular_values[1] < 1e-10 * res.singular_values[0]
    assert abs(res.unidentifiable["q5"]) == pytest.approx(1.0, abs=1e-9)
    assert "not identifiable" in res.statement
    with pytest.raises(BifidInputError, match="linearisation"):
        fit_near_hopf(hopf, p0, ("mu0",), near, nf=nf)
    with pytest.raises(BifidInputError, match="no cycles"):
        fit_near_hopf(
            hopf, p0, ("a2",), LCOData.from_amplitudes([0.05], [[0.1]], [0], ("u1",)), nf=nf
        )


def test_lco_data_validation_and_not_fitted() -> None:
    """Check that malformed cycles and an unfitted model are rejected with clear errors."""
    with pytest.raises(BifidInputError):
        LCOData.from_amplitudes([1.0], [[-1.0]], [0], ("h",))
    with pytest.raises(BifidInputError, match="stable must be"):
        LCOData.from_amplitudes([1.0], [[1.0]], [2], ("h",))
    with pytest.raises(BifidInputError):
        LCOData.from_amplitudes([1.0], [[1.0, 2.0]], [0], ("h",))
    with pytest.raises(NotFittedError):
        MechanisticModel("hopf", ("a2",)).summary()
    with pytest.raises(BifidInputError, match="stages"):
        MechanisticModel("hopf", ("a2",), stages=("bogus",)).fit(
            LCOData.from_amplitudes([-0.1], [[0.5]], [0], ("u1",))
        )


def test_lco_data_from_real_cbc_dataset(shared_data) -> None:
    """Check the rig's nine PP-CBC cycles: labels, noise-robust amplitudes, frequency."""
    from bifid.data import flutter_cbc_dataset

    files = sorted((shared_data / "flutter_rig" / "cbc_model1").glob("*.mat"))
    d = LCOData.from_dataset(flutter_cbc_dataset(files))
    assert len(d) == 9 and d.signal_names[:2] == ("h", "alpha")
    assert sorted(d.param[d.stable == 1].tolist()) == [14.9, 15.6, 16.5, 17.3]
    assert sorted(d.param[d.stable == 0].tolist()) == [14.9, 15.7, 16.4, 16.5, 17.2]
    # Fourier amplitudes are below the raw maxima (noise removed) but close to them
    raw = np.array([np.max(np.abs(s - s.mean(axis=0)), axis=0) for s in d.signals])
    assert np.all(d.amplitude <= raw * 1.001)
    assert np.all(d.amplitude > 0.85 * raw)
    assert np.all(np.abs(d.frequency / (2 * np.pi) - 2.5) < 0.1)


def test_fit_save_load_predict_cli(tmp_path, hopf, orbits, bifid_cli) -> None:
    """Check fit / save / load / predict through the CLI on a dataset sampled from the true
    model's orbits: JSON keys of the contract, recovered parameters, Hopf point and fold,
    the refusal of a level outside (0, 1), and the exit codes of bad input."""
    from bifid.data import LCORecord, lco_dataset, save_dataset

    o = orbits["orbits"]
    M, n = 16, 2
    recs = []
    for j, y in enumerate(o.ys):
        V, T = y[: M * n].reshape(M, n), y[M * n]
        fine = np.fft.irfft(np.fft.rfft(V, axis=0), n=4 * M, axis=0) * 4
        recs.append(
            LCORecord(
                param=float(MU[j]),
                signals=np.tile(fine, (3, 1)),
                sample_rate=4 * M / T,
                stable=bool(STABLE[j]),
                frequency=2 * np.pi / T,
            )
        )
    path = tmp_path / "lco.nc"
    save_dataset(
        lco_dataset(
            recs,
            ["u1", "u2"],
            param_name="mu",
            param_units="",
            system="hopf",
            settings={},
            source="test",
        ),
        path,
    )
    out = tmp_path / "model"
    r = bifid_cli(
        "fit",
        "mechanistic",
        path,
        "--model",
        "hopf",
        "--free",
        "a2,q5",
        "--set",
        "a2=1.2",
        "--set",
        "q5=0.8",
        "--mesh",
        "16",
        "--out",
        out,
        "--json",
    )
    assert r.code == 0, r.stderr
    payload = r.json
    assert set(payload) >= {"parameters", "standard_errors", "losses", "settings", "hopf"}
    # the records' amplitudes are Fourier estimates at an estimated frequency (the
    # convention of measured data): exact to a few 1e-3 on three periods of 64 samples
    assert payload["parameters"]["a2"] == pytest.approx(A2, rel=5e-3)
    assert payload["parameters"]["q5"] == pytest.approx(Q5, rel=5e-3)
    assert payload["hopf"]["param"] == pytest.approx(0.0, abs=1e-9)
    assert payload["losses"]["whole_diagram"] < 2e-3
    m = load(out)
    assert isinstance(m, MechanisticModel) and m.params_ == payload["parameters"]
    a2, q5 = m.params_["a2"], m.params_["q5"]
    np.testing.assert_allclose(
        m.predict_amplitude([-0.1], stable=False)[0], radius(-0.1, False, a2, q5), rtol=1e-8
    )
    orbit = m.predict_orbit(-0.1, stable=True, n_points=64)
    assert orbit.period == pytest.approx(2 * math.pi, rel=1e-8)
    np.testing.assert_allclose(
        np.hypot(orbit.signal("u1"), orbit.signal("u2")), radius(-0.1, True, a2, q5), rtol=1e-8
    )
    r = bifid_cli("predict", out, "--param", "mu", "--range", "-0.3", "0.1", "--json")
    assert r.code == 0, r.stderr
    pred = r.json
    assert set(pred) >= {"hopf", "cycle_folds", "secondary", "orbits", "complete"}
    assert pred["hopf"][0]["param"] == pytest.approx(0.0, abs=1e-8)
    assert pred["hopf"][0]["criticality"] == "subcritical"
    assert pred["cycle_folds"][0]["param"] == pytest.approx(-(a2**2) / (4 * q5), abs=1e-6)
    r = bifid_cli("predict", out, "--range", "-0.3", "0.1", "--level", "1.5")
    assert r.code == 2 and "level" in r.stderr
    r = bifid_cli(
        "fit", "mechanistic", path, "--model", "hopf", "--free", "nope", "--out", tmp_path / "m2"
    )
    assert r.code == 2
    r = bifid_cli(
        "fit",
        "mechanistic",
        path,
        "--model",
        "hopf",
        "--free",
        "a2",
        "--stages",
        "linear",
        "--out",
        tmp_path / "m3",
    )
    assert r.code == 2 and "free decay" in r.stderr


def test_fit_cli_free_decay_options_are_checked(tmp_path, shared_data, bifid_cli) -> None:
    """The free decay's columns and stored scalars map onto the model only as the options say."""
    lco = shared_data / "flutter_rig" / "cbc_model1"
    decay = shared_data / "flutter_rig" / "free_decay" / "model1_free_decay.mat"
    base = ("fit", "mechanistic", *sorted(lco.glob("*.mat"))[:1], "--model", "flutter")
    base = (*base, "--free", "ka2,ka3", "--free-decay", decay, "--out", tmp_path / "m")
    r = bifid_cli(*base)
    assert r.code == 2 and "--linear-outputs" in r.stderr
    r = bifid_cli(*base, "--linear-outputs", "h,alpha", "--file-params", "I__alpha=Ia,nope=ka")
    assert r.code == 2 and "no scalar named nope" in r.stderr
    r = bifid_cli(*base, "--linear-outputs", "h,alpha", "--file-params", "I__alpha=nope")
    assert r.code == 2 and "nope" in r.stderr
    assert not (tmp_path / "m").exists()


def test_orbits_ignore_a_branch_that_collapsed_onto_the_equilibrium(hopf, data, orbits) -> None:
    """A branch whose last steps fell onto the equilibrium (a constant solves the collocation
    equations anywhere) matches only its genuine orbits: the unstable cycles are found with
    their exact amplitudes, the stable ones are reported missing rather than sought on the
    collapsed segment."""
    br = orbits["branch"]
    (fold,) = br.special("cycle_fold")
    k = fold.index - 1  # the unstable side only: no fold, no stable cycle on the branch
    sols = np.asarray(br.solutions)[:k]
    flat = np.zeros((2, sols.shape[1]))  # mesh values and period of the equilibrium
    flat[:, -1] = 2 * np.pi
    broken = dataclasses.replace(
        br,
        params=np.concatenate([np.asarray(br.params)[:k], [-0.3, 0.0]]),
        solutions=np.vstack([sols, flat]),
        stable=np.concatenate([np.asarray(br.stable)[:k], [True, True]]),
        special_points=[],
    )
    o = OrbitSet(hopf, "mu", 16, ("u1",))
    matched = o.match(broken, data, orbits["p"], skip_missing=True)
    reachable = (STABLE == 0) & (MU > np.asarray(br.params)[k - 1])
    np.testing.assert_array_equal(matched, np.flatnonzero(reachable))
    np.testing.assert_allclose(o.amplitudes()[:, 0], radius(MU[reachable], False), rtol=1e-10)
    with pytest.raises(ConvergenceError, match=r"has no (un)?stable periodic orbit"):
        OrbitSet(hopf, "mu", 16, ("u1",)).match(broken, data, orbits["p"])
