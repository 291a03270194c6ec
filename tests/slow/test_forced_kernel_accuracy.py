"""Forced kernel model of ``shaw_pierre`` (thesis §6.3.1) against continuation of the true
system: the accuracy required at untrained forcing levels. Long (several FRC
continuations); run with ``--runslow``."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from bifid.continuation import ContinuationOptions, backbone, frc
from bifid.data import ForcedRecord, forced_dataset
from bifid.identify import ForcedKernelModel, band_coverage
from bifid.systems import get_system

pytestmark = pytest.mark.slow

M = 32
WINDOW = (0.95, 1.05)
OPTS = ContinuationOptions(ds=0.005, ds_min=1e-9, ds_max=0.02, max_steps=20000)


def _truth(forcing: float) -> dict:
    s = get_system("shaw_pierre")
    br = frc(s, forcing, WINDOW, n_mesh=M, options=OPTS)
    orbits = br.solutions[:, : M * s.n_states].reshape(-1, M, s.n_states)[:, :, 0]
    return {
        "omega": br.data["omega"],
        "amplitude": br.data["observed_amplitude"],
        "phase": br.data["phase"],
        "stable": br.stable,
        "orbits": orbits,
        "folds": np.sort([sp.param for sp in br.special("fold")]),
    }


def _pick(d: dict, n: int = 16) -> np.ndarray:
    m = (d["omega"] >= 0.96) & (d["omega"] <= 1.03)
    o, a = d["omega"][m], d["amplitude"][m]
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(o) / np.ptp(o), np.diff(a) / np.ptp(a)))])
    return np.nonzero(m)[0][np.unique(np.searchsorted(s, np.linspace(0, s[-1], n)))]


def _peak(d: dict) -> float:
    i = int(np.argmax(d["amplitude"]))
    c = np.polyfit(d["phase"][i - 1 : i + 2], d["amplitude"][i - 1 : i + 2], 2)
    return float(np.polyval(c, -c[1] / (2 * c[0])))


@pytest.fixture(scope="module")
def truth() -> dict:
    return {f: _truth(f) for f in (0.01, 0.007, 0.003, 0.006, 0.009, 0.012)}


@pytest.fixture(scope="module")
def model(truth) -> ForcedKernelModel:
    recs = []
    for c, f in enumerate((0.01, 0.007)):
        d = truth[f]
        for i in _pick(d):
            om = float(d["omega"][i])
            fs = M * om / (2 * np.pi)
            t = np.arange(M) / fs
            recs.append(
                ForcedRecord(
                    omega=om,
                    forcing=f,
                    signals=d["orbits"][i][:, None],
                    sample_rate=fs,
                    stable=bool(d["stable"][i]),
                    force=f * np.cos(om * t),
                    amplitude=float(d["amplitude"][i]),
                    phase=float(d["phase"][i]),
                    curve=c,
                )
            )
    assert any(r.stable is False for r in recs)  # unstable points are in the training set
    ds = forced_dataset(recs, ["x1"], observed="x1", system="shaw_pierre", source="test")
    return ForcedKernelModel(forcing_scale="fit").fit(ds)


@pytest.mark.parametrize("forcing", [0.003, 0.006, 0.009, 0.012])
def test_untrained_frc(model, truth, forcing):
    d = truth[forcing]
    with warnings.catch_warnings():  # 0.003 and 0.012 lie outside the trained forcings
        warnings.simplefilter("ignore", UserWarning)
        br = model.predict_diagram(forcing=forcing, range=WINDOW, level=0.95).branches[0]
    assert abs(br.special("peak")[0].data["amplitude"] / _peak(d) - 1) < 0.02
    folds = np.sort([sp.param for sp in br.special("fold")])
    assert folds.size == d["folds"].size
    if folds.size:
        np.testing.assert_allclose(folds, d["folds"], rtol=1e-3)
    assert band_coverage(br, d["omega"], d["amplitude"], d["phase"])["coverage"] > 0.5


def test_backbone_within_one_percent(model):
    r_hi = model.rho_range_[1]
    tb = backbone(
        get_system("shaw_pierre"),
        (0.05, r_hi),
        n_mesh=M,
        options=ContinuationOptions(
            ds=0.02, ds_min=1e-9, ds_max=0.03, max_steps=5000, detect_folds=False
        ),
    )
    mb = model.backbone((0.05, r_hi))
    om = np.interp(tb.data["observed_amplitude"], mb.params, mb.data["omega"])
    assert np.max(np.abs(om / tb.data["omega"] - 1)) < 0.01
    # and within 5 % of the backbone's own frequency shift
    shift = np.ptp(tb.data["omega"])
    assert np.max(np.abs(om - tb.data["omega"])) < 0.05 * shift


def test_time_series_at_untrained_points(model, truth):
    for f, om in ((0.006, 1.002), (0.009, 1.0)):
        d = truth[f]
        i = int(np.argmin(np.abs(d["omega"] - om)))
        om_i, y_true = float(d["omega"][i]), d["orbits"][i]
        t = np.arange(M) * 2 * np.pi / om_i / M
        p = min(model.fixed_points(om_i, f), key=lambda q: abs(q["rho"] - d["amplitude"][i]))
        y = model.time_series(t, p["rho"], p["psi"], om_i)
        assert np.sqrt(np.mean((y - y_true) ** 2)) < 0.05 * np.sqrt(np.mean(y_true**2))
