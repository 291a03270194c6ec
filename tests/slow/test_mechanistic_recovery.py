"""Slow accuracy runs of the mechanistic identification on the flutter model; `--runslow`."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from bifid.identify import LCOData, MechanisticModel
from bifid.identify.mechanistic import (
    OrbitSet,
    fit_near_hopf,
    hopf_normal_form,
    model_branch,
    whole_diagram_update,
)
from bifid.systems import get_system

pytestmark = pytest.mark.slow

U_MEAS = np.array([15.5, 16.5, 17.5, 18.0, 15.2, 16.0, 17.0, 18.0])
STABLE = np.array([0, 0, 0, 0, 1, 1, 1, 1])


@pytest.fixture(scope="module")
def truth():
    sys_ = get_system("flutter")
    p = np.array(sys_.param_vector())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        br = model_branch(sys_, p, "U", n_mesh=48, guess=18.0, param_range=(14.0, 19.0))
    probe = LCOData.from_amplitudes(U_MEAS, np.zeros((8, 1)), STABLE, ("h",), param_name="U")
    o = OrbitSet(sys_, "U", 48, ("h",))
    o.match(br, probe, p)
    return {
        "p": p,
        "data": LCOData.from_amplitudes(U_MEAS, o.amplitudes(), STABLE, ("h",), param_name="U"),
        "fold": br.special("cycle_fold")[0].param,
        "hopf": br.meta["start_param"],
    }


@pytest.mark.parametrize("f2,f3", [(1.3, 0.7), (1.3, 1.3), (0.7, 0.7), (0.7, 1.3)])
def test_whole_diagram_recovers_from_30_percent(truth, f2, f3) -> None:
    """(ka2, ka3) perturbed by ±30 % -> recovered within 2 %; fold and Hopf within 0.05 m/s."""
    sys_ = get_system("flutter")
    p0 = truth["p"].copy()
    p0[sys_.index("ka2")] *= f2
    p0[sys_.index("ka3")] *= f3
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = whole_diagram_update(
            sys_, p0, ("ka2", "ka3"), truth["data"], n_mesh=32, hopf_guess=18.2, max_iter=40
        )
        br = model_branch(sys_, r.p, "U", n_mesh=48, guess=18.2, param_range=(14.0, 19.0))
    assert r.params["ka2"] == pytest.approx(751.6, rel=0.02)
    assert r.params["ka3"] == pytest.approx(5006.7, rel=0.02)
    assert br.special("cycle_fold")[0].param == pytest.approx(truth["fold"], abs=0.05)
    assert br.meta["start_param"] == pytest.approx(truth["hopf"], abs=0.05)


def test_real_three_stage_pipeline(shared_data) -> None:
    from bifid.data import RIG_PARAMETER_NAMES, flutter_cbc_dataset, load_free_decay

    d = shared_data / "flutter_rig"
    fd = load_free_decay(d / "free_decay" / "model1_free_decay.mat")
    ds = flutter_cbc_dataset(sorted((d / "cbc_model1").glob("*.mat")))
    names = RIG_PARAMETER_NAMES
    params = {names[k]: float(v) for k, v in fd.guesses.items() if k in names}
    m = MechanisticModel(
        "flutter",
        ("ka2", "ka3"),
        params=params,
        outputs=("h",),
        linear_free=("Ia", "ca", "ch"),
        linear_outputs=("h", "alpha"),
        linear_ratios={"ka": "Ia"},
        param_ref="data",
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m.fit(ds, free_decay=fd)
    lin = m.stages_["linear"]["parameters"]
    assert lin["Ia"] == pytest.approx(0.1724, rel=0.15)
    assert lin["ca"] == pytest.approx(0.5628, rel=0.2)
    assert lin["ch"] == pytest.approx(14.5756, rel=0.1)
    assert m.data_hopf_["param"] == pytest.approx(17.92, abs=0.3)
    assert m.data_hopf_["frequency_hz"] == pytest.approx(2.52, abs=0.1)
    assert m.hopf_["param"] == pytest.approx(17.96, abs=0.3)
    assert m.hopf_["criticality"] == "subcritical"
    # each stage does not increase the RMS error over the LCOs it can match
    wd = m.stages_["whole_diagram"]
    assert wd["n_matched"] == 9
    assert wd["rms_all"] < 6e-3
    assert wd["rms_all"] <= wd["rms_start"] + 1e-12


def test_normal_form_stage_identifies_only_eq_4_10_combination() -> None:
    """Check that near-Hopf amplitudes fix c3·ka3 + c22·ka2² (eq. 4.10) from a supercritical
    start, and only that combination (rank one, null direction tangent to alpha2 = const)."""
    flutter = get_system("flutter")
    p = np.array(flutter.param_vector())
    nf = hopf_normal_form(flutter, "U", p=p, guess=18.0)
    U = np.array([17.6, 17.8, 18.0, 18.2])
    data = LCOData.from_amplitudes(
        U, nf.amplitude(U, "h")[:, None], np.zeros(4, int), ("h",), param_name="U"
    )
    p0 = p.copy()
    p0[flutter.index("ka2")] *= 0.7
    p0[flutter.index("ka3")] *= 1.3
    res = fit_near_hopf(flutter, p0, ("ka2", "ka3"), data, nf=nf)
    assert res.alpha2 == pytest.approx(nf.alpha2, rel=1e-9)
    s = res.structure
    assert s["c3"] * res.params["ka3"] + s["c22"] * res.params["ka2"] ** 2 == pytest.approx(
        nf.alpha2, rel=1e-9
    )
    assert res.singular_values[1] < 1e-8 * res.singular_values[0]
    assert "only c3·ka3 + c22·ka2² is identifiable" in res.statement
    g = np.array([2 * s["c22"] * res.params["ka2"] ** 2, s["c3"] * res.params["ka3"]])
    null = np.array([res.unidentifiable["ka2"], res.unidentifiable["ka3"]])
    assert abs(g @ null) < 1e-8 * np.linalg.norm(g)
