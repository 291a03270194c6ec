"""The estimator contract shared by the three identification methods.

``docs/examples/identify_generic.py`` runs the three methods through one function (fit →
save → predict_diagram → JSON → figure); it is executed here on its small data, whose
answers are known in closed form: the ``hopf`` system's Hopf point at mu = 0 and fold of
cycles at mu = -a2**2 / 4 = -0.25, and the averaged Duffing oscillator's FRC, explicit in
the phase of its fixed points. ``bifid predict`` then reads every saved model through the
same code path and must give the same diagram. (The script's hybrid and kernel settings
and the layout of its records are those of ``test_hopf_hybrid.py`` and
``test_forced_kernel.py``: in one test run the compiled training loops are shared.)
"""

from __future__ import annotations

import runpy
from pathlib import Path

import numpy as np
import pytest

from bifid.errors import BifidInputError, NotFittedError
from bifid.identify import ForcedKernelModel, HopfHybridModel, MechanisticModel, load

SCRIPT = Path(__file__).resolve().parents[1] / "docs" / "examples" / "identify_generic.py"
QUESTIONS = {  # the questions of the script's main(), as bifid predict options
    "mechanistic": ("--range", "-0.4", "0.2"),
    "hopf_hybrid": ("--range", "-0.4", "0.2", "--n-points", "60"),
    "forced_kernel": ("--frc", "--forcing", "0.015", "--omega-range", "0.95", "1.2"),
}


def _numbers(tree) -> list[float]:
    """The numbers of a JSON tree, in order."""
    if isinstance(tree, dict):
        return [x for k in sorted(tree) for x in _numbers(tree[k])]
    if isinstance(tree, list):
        return [x for v in tree for x in _numbers(v)]
    return [float(tree)] if isinstance(tree, (int, float)) and not isinstance(tree, bool) else []


@pytest.fixture(scope="module")
def script():
    return runpy.run_path(str(SCRIPT))


@pytest.fixture(scope="module")
def run(script, tmp_path_factory):
    out = tmp_path_factory.mktemp("generic")
    return out, script["main"](out)


def test_autonomous_models_find_the_hopf_point_and_the_fold(run) -> None:
    """Check the Hopf point (mu = 0) and the fold of cycles (mu = -0.25) predicted by the
    mechanistic and the hybrid model trained on the same cycles."""
    out, results = run
    for name, tol in (("mechanistic", 5e-4), ("hopf_hybrid", 1e-3)):
        d = results[name]
        assert d["kind"] == "bifurcation" and d["complete"], name
        (hopf,) = d["hopf"]
        assert hopf["param"] == pytest.approx(0.0, abs=tol)
        assert hopf["criticality"] == "subcritical"
        (fold,) = d["cycle_folds"]
        assert fold["param"] == pytest.approx(-0.25, abs=tol)
        assert (out / f"{name}.png").stat().st_size > 0
    assert load(out / "mechanistic").summary()["parameters"]["a2"] == pytest.approx(1.0, abs=1e-3)


def test_kernel_model_predicts_the_frc_at_an_untrained_forcing(script, run) -> None:
    """Check the FRC at F = 0.015 (trained at 0.01 and 0.02): its two folds and its peak
    against the closed-form curve of the averaged Duffing oscillator."""
    _, results = run
    d = results["forced_kernel"]
    assert d["kind"] == "frc" and d["complete"]
    omega, rho = script["duffing_frc"](0.015, np.linspace(1e-4, np.pi - 1e-4, 400_001))
    turn = np.nonzero(np.diff(np.sign(np.diff(omega))))[0] + 1
    exact = np.sort(omega[turn])
    assert len(exact) == 2
    folds = np.sort([f["omega"] for f in d["folds"]])
    np.testing.assert_allclose(folds, exact, rtol=5e-4)
    peak = d["peak"]
    assert peak["amplitude"] == pytest.approx(rho.max(), rel=1e-3)
    assert peak["omega"] == pytest.approx(omega[np.argmax(rho)], rel=5e-4)


@pytest.mark.parametrize("name", list(QUESTIONS))
def test_bifid_predict_reads_every_model_the_same_way(run, bifid_cli, name) -> None:
    """Check that ``bifid predict DIR`` loads each saved model (whatever its method) and
    prints the diagram the script computed before saving."""
    out, results = run
    r = bifid_cli("predict", out / name, *QUESTIONS[name], "--json")
    assert r.code == 0, r.stderr
    expected = results[name]
    assert r.json["kind"] == expected["kind"]
    for key in ("hopf", "cycle_folds", "folds", "peak"):
        if key in expected:
            assert _numbers(r.json[key]) == pytest.approx(_numbers(expected[key])), key
    # a level is answered by a model with calibrated intervals and refused by the others
    expected_code = 0 if load(out / name).calibrated else 2
    assert (
        bifid_cli("predict", out / name, *QUESTIONS[name], "--level", "0.9").code == expected_code
    )


@pytest.mark.parametrize(
    "model", [MechanisticModel("hopf", ("a2",)), HopfHybridModel(), ForcedKernelModel()]
)
def test_contract_before_fit(model, tmp_path) -> None:
    """Check that every prediction refuses to run before fit, and that hyperparameters are
    the constructor's arguments."""
    params = model.get_params()
    assert type(model)(**params).get_params() == params
    with pytest.raises(NotFittedError):
        model.predict_diagram()
    with pytest.raises(NotFittedError):
        model.predict_amplitude([0.1])
    with pytest.raises(NotFittedError):
        model.summary()
    with pytest.raises(NotFittedError):
        model.save(tmp_path / "m")


def test_questions_a_model_cannot_answer(run) -> None:
    """Check that a model refuses a kind of diagram or a level it has no answer for."""
    out, _ = run
    hybrid, kernel = load(out / "hopf_hybrid"), load(out / "forced_kernel")
    with pytest.raises(BifidInputError, match="frc"):
        hybrid.predict_diagram(kind="frc", forcing=0.1)
    with pytest.raises(BifidInputError, match="no calibrated intervals"):
        hybrid.predict_diagram(level=0.95)
    with pytest.raises(BifidInputError, match="not 'bifurcation'"):
        kernel.predict_diagram(kind="bifurcation")
    with pytest.raises(BifidInputError):
        hybrid.predict_orbit(0.0, forcing=0.1)
