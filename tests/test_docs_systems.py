"""The systems pages of the user guide do what they say: the example system files are the
ones shown, and every ``$ bifid ...`` command of ``docs/systems.md`` and of the "bring your
own system" tutorial runs (in a directory holding the example files) and gives numbers that
agree with the analysis (Hopf point b = 1 + a², harmonic balance of the softening oscillator,
CBC against continuation)."""

from __future__ import annotations

import re
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "docs" / "examples" / "systems"
SYSTEMS_PAGE = ROOT / "docs" / "systems.md"
TUTORIAL_PAGE = ROOT / "docs" / "own-system.md"


def console_commands(page: Path) -> list[str]:
    """The ``$ bifid ...`` lines of the page's ``console`` blocks, in order."""
    blocks = re.findall(r"```console\n(.*?)```", page.read_text(), flags=re.S)
    return [
        line[2:].strip()
        for block in blocks
        for line in block.splitlines()
        if line.startswith("$ bifid ")
    ]


def _run_page(
    page: Path, bifid_cli, tmp_path: Path, monkeypatch, suffix: str = ".toml"
) -> dict[str, dict]:
    """Run every command of ``page`` in a copy of the examples (with the system files of
    ``suffix`` in place of the ``.toml`` ones); the JSON outputs by command (as written)."""
    for f in EXAMPLES.iterdir():
        shutil.copy(f, tmp_path / f.name)
    monkeypatch.chdir(tmp_path)
    outputs = {}
    for command in console_commands(page):
        args = [
            a.replace(".toml", suffix) if a.endswith(".toml") else a for a in shlex.split(command)
        ]
        r = bifid_cli(*args[1:])
        assert r.code == 0, f"{command}: exit {r.code}: {r.stderr[-2000:]}"
        if "--json" in command:
            outputs[command] = r.json
    return outputs


def _one(outputs: dict[str, dict], prefix: str) -> dict:
    (found,) = [v for k, v in outputs.items() if k.removeprefix("bifid ").startswith(prefix)]
    return found


def test_systems_page_shows_the_example_files_verbatim():
    """Check every example system file appears, whole, in docs/systems.md (no drift)."""
    page = SYSTEMS_PAGE.read_text()
    files = sorted(EXAMPLES.glob("*.*"))
    assert {f.name for f in files} >= {
        "brusselator.py",
        "brusselator.toml",
        "softening.py",
        "softening.toml",
    }
    for f in files:
        assert f.read_text().strip() in page, f.name


def test_bifid_systems_lists_built_ins_and_files_with_their_source(bifid_cli, monkeypatch):
    """Check `bifid systems FILE...` (human and --json): the built-ins, then the files'
    systems with their paths as source; a malformed file is one line and exit 2."""
    monkeypatch.chdir(EXAMPLES)
    r = bifid_cli("systems", "brusselator.toml", "softening.py", "--json")
    assert r.code == 0, r.stderr
    by_name = {s["name"]: s for s in r.json["systems"]}
    assert r.json["complete"] is True and r.json["errors"] == []
    for name in ("hopf", "vanderpol", "flutter", "duffing", "shaw_pierre"):
        assert by_name[name]["source"] == "built-in"
        assert by_name[name]["envelope"] is not None
    assert by_name["brusselator"]["source"] == str(EXAMPLES / "brusselator.toml")
    assert by_name["softening"]["source"] == str(EXAMPLES / "softening.py")
    assert by_name["softening"]["kind"] == "forced"
    human = bifid_cli("systems", "softening.toml")
    assert human.code == 0 and f"softening  (forced, {EXAMPLES / 'softening.toml'})" in human.stdout


def test_malformed_system_file_through_the_cli_is_one_line_exit_2(bifid_cli, tmp_path):
    """Check a bad equation reaches the user as one line naming file, key, equation, symbol."""
    bad = tmp_path / "bad.toml"
    bad.write_text((EXAMPLES / "brusselator.toml").read_text().replace('x**2*y"\n', 'x**2*z"\n', 1))
    for args in (("systems", bad), ("continue", bad, "--param", "b", "--range", "1.5", "3")):
        r = bifid_cli(*args)
        assert r.code == 2 and r.stdout == ""
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1, r.stderr
        assert "bad.toml: [equations] x = 'a - (b + 1)*x + x**2*z': unknown symbol 'z'" in lines[0]


@pytest.mark.slow
def test_systems_page_commands_run_and_agree_with_the_analysis(bifid_cli, tmp_path, monkeypatch):
    """Run every command of docs/systems.md; check the Brusselator's Hopf point (b = 1 + a²,
    ω = a), the softening FRC against harmonic balance, and CBC against continuation."""
    out = _run_page(SYSTEMS_PAGE, bifid_cli, tmp_path, monkeypatch)
    bruss = _one(out, "continue brusselator.toml")
    (hopf,) = bruss["hopf"]
    assert hopf["param"] == pytest.approx(2.0, abs=1e-8)
    assert hopf["omega"] == pytest.approx(1.0, abs=1e-8)
    assert hopf["criticality"] == "supercritical"
    frc = _one(out, "frc softening.toml")
    beta, zeta, forcing = 0.5, 0.01, 0.01
    w, a = frc["peak"]["omega"], frc["peak"]["amplitude"]
    assert w**2 == pytest.approx(1.0 - 0.75 * beta * a**2, abs=5e-3)  # backbone
    assert a == pytest.approx(forcing / (2 * zeta * w), rel=0.02)  # energy balance at the peak
    folds = sorted(f["omega"] for f in frc["folds"])
    assert len(folds) == 2 and folds[1] < 1.0
    _check_ppcbc_against_continuation(_one(out, "cbc brusselator.toml"), bruss)
    measured_folds = sorted(f["omega"] for f in _one(out, "cbc softening.toml")["folds"])
    np.testing.assert_allclose(measured_folds, folds, rtol=0.01)


def _check_ppcbc_against_continuation(measured: dict, truth: dict) -> None:
    orbits = sorted(truth["orbits"], key=lambda o: o["param"])
    params = np.array([o["param"] for o in orbits])
    centred = np.array(
        [
            o["amplitude_centred"]["x"]
            if isinstance(o["amplitude_centred"], dict)
            else o["amplitude_centred"]
            for o in orbits
        ]
    )
    assert measured["points"], "no measured point"
    for point in measured["points"]:
        amplitude = point["amplitude"]
        amplitude = amplitude["x"] if isinstance(amplitude, dict) else amplitude
        expected = np.interp(point["param"], params, centred)
        assert amplitude == pytest.approx(expected, rel=0.01), point


@pytest.mark.slow
@pytest.mark.parametrize("suffix", [".toml", ".py"])
def test_own_system_tutorial_runs_from_equations_to_prediction(
    bifid_cli, tmp_path, monkeypatch, suffix
):
    """Run every command of the tutorial, with both systems written as ``.toml`` and as
    ``.py`` files; the predicted Hopf point within 1 % of the continuation's (b = 2), the
    predicted FRC folds within 1 % of the continuation's."""
    out = _run_page(TUTORIAL_PAGE, bifid_cli, tmp_path, monkeypatch, suffix)
    (hopf,) = _one(out, "predict model ")["hopf"]
    assert hopf["param"] == pytest.approx(2.0, rel=0.01)
    folds = sorted(f["omega"] for f in _one(out, "frc softening.toml")["folds"])
    predicted = sorted(f["omega"] for f in _one(out, "predict forced-model")["folds"])
    np.testing.assert_allclose(predicted, folds, rtol=0.01)
