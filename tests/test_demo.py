"""The demo's machinery: stage cache, comparison metrics, option checking (fast parts).

The whole demo runs in ``tests/slow/test_demo_e2e.py`` (``--runslow``) and in ``make demo``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bifid.cli import main
from bifid.demo import FlutterDemoSettings, StageCache, settings_key
from bifid.signal import aligned_orbit_error


def test_settings_key_is_order_free_and_sensitive():
    """Check the key ignores dict order and changes with any value."""
    a = settings_key({"x": 1, "y": [1.0, 2.0]})
    assert a == settings_key({"y": [1.0, 2.0], "x": 1})
    assert a != settings_key({"x": 1, "y": [1.0, 2.0000001]})


def test_stage_cache_reuse_refresh_and_missing_files(tmp_path):
    """Check a stage is fresh only with the same key, its files present, and no refresh."""
    (tmp_path / "data.nc").write_text("x")
    c = StageCache(tmp_path)
    assert not c.fresh("campaign", "k1", ["data.nc"])
    c.done("campaign", "k1", 1.5, n_points=3)
    c2 = StageCache(tmp_path)  # a second run reads the manifest
    assert c2.fresh("campaign", "k1", ["data.nc"]) and c2.reused == ["campaign"]
    assert c2.info("campaign")["n_points"] == 3
    assert not c2.fresh("campaign", "k2", ["data.nc"])  # settings changed
    assert not StageCache(tmp_path, refresh=True).fresh("campaign", "k1", ["data.nc"])
    (tmp_path / "data.nc").unlink()
    assert not StageCache(tmp_path).fresh("campaign", "k1", ["data.nc"])  # file gone
    (tmp_path / "cache.json").write_text("{not json")
    assert StageCache(tmp_path).entries == {}  # a damaged manifest costs a re-run only


def test_chained_keys_change_downstream_only():
    """Check noise changes the campaign and model keys but not the truth key."""
    a = FlutterDemoSettings().stage_settings()
    b = FlutterDemoSettings(noise_fraction=0.02).stage_settings()
    assert a["truth"] == b["truth"]
    assert a["campaign"] != b["campaign"]
    assert a["model"] == b["model"]  # equal by itself; chained through the campaign key


def test_aligned_error_is_phase_free_and_exact():
    """Check the one-period error ignores a time shift and measures an amplitude error."""
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    truth = np.column_stack([np.cos(t), 0.3 * np.sin(t) + 0.1 * np.cos(2 * t)])
    shifted = np.roll(
        np.column_stack(
            [
                np.cos(np.linspace(0, 2 * np.pi, 256, endpoint=False)),
                0.3 * np.sin(np.linspace(0, 2 * np.pi, 256, endpoint=False))
                + 0.1 * np.cos(2 * np.linspace(0, 2 * np.pi, 256, endpoint=False)),
            ]
        ),
        37,
        axis=0,
    )
    assert aligned_orbit_error(shifted, truth) < 1e-10  # resampled 64 -> 256 and shifted
    assert aligned_orbit_error(1.05 * shifted, truth) == pytest.approx(0.05, rel=1e-9)


@pytest.mark.parametrize(
    "args,needle",
    [
        (["demo", "banana"], "flutter"),
        (["demo", "flutter", "--noise", "nan"], "--noise"),
        (["demo", "flutter", "--noise", "0.9"], "--noise"),
    ],
)
def test_demo_bad_options_exit_2(args, needle, capsys, tmp_path):
    """Check bad demo options give one line on stderr and exit status 2."""
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(SystemExit) as e:
        main([*args, "--out", str(tmp_path / "o")])
    out, err = capsys.readouterr()
    assert e.value.code == 2 and out == "" and needle in err
    assert len(err.strip().splitlines()) == 1
    with pytest.raises(SystemExit) as e:
        main(["demo", "flutter", "--out", str(f)])  # --out is a file
    assert e.value.code == 2


def test_stage_cache_ensure_builds_once_and_records(tmp_path):
    """Check ensure() builds a missing stage once, records its facts, and then reuses it."""
    calls = []

    def build():
        calls.append(1)
        (tmp_path / "out.txt").write_text("x")
        return {"n_points": 7}

    StageCache(tmp_path).ensure("s", "k", ["out.txt"], build)
    c = StageCache(tmp_path)
    c.ensure("s", "k", ["out.txt"], build)
    assert calls == [1] and c.reused == ["s"] and c.info("s")["n_points"] == 7
    StageCache(tmp_path).ensure("s", "k2", ["out.txt"], build)  # new settings: rebuilt
    assert calls == [1, 1]


def test_cached_model_without_the_asked_intervals_is_fitted_again(tmp_path) -> None:
    """A saved model that loads without calibrated intervals although the stage asked for
    them (saved by a version whose intervals this one does not read) is refitted."""
    fits: list[bool] = []

    class Estimator:
        def __init__(self, calibrated: bool = True) -> None:
            self.calibrated = calibrated

        def fit(self, data, uncertainty: bool = False):
            fits.append(uncertainty)
            return self

        def save(self, path, settings) -> None:
            path.mkdir(exist_ok=True)
            (path / "model.json").write_text(json.dumps({"calibrated": len(fits) > 1}))

        @classmethod
        def load(cls, path):
            return cls(json.loads((path / "model.json").read_text())["calibrated"])

    cache = StageCache(tmp_path)
    _, model = cache.model("k", Estimator, {}, None, {}, fit_options={"uncertainty": True})
    assert fits == [True, True] and model.calibrated  # the first save was not calibrated
    _, model = StageCache(tmp_path).model("k", Estimator, {}, None, {}, {"uncertainty": True})
    assert fits == [True, True] and model.calibrated  # now reused as it is
