"""Accuracy of the hybrid Hopf model on the thesis's examples (slow, opt-in).

* Van der Pol (§5.4.1): six stable cycles, mu = 0.1 ... 1.0, 10 s at 0.02 s. Hopf point
  within 0.03 of 0, amplitudes at five untrained mu within 2 %, a time series at an untrained
  mu within 5 % RMS over one period.
* Flutter model (§5.4.2): four stable and four unstable cycles, 1 s at 1 kHz, from
  continuation. Hopf speed within 0.05 m/s and fold within 0.1 m/s of continuation, heave and
  pitch amplitudes at untrained speeds within 3 %, frequency within 1 %; with 1 % measurement
  noise, errors at most twice those.
"""

from __future__ import annotations

import numpy as np
import pytest

from bifid.continuation.truth import ContinuationTruth, simulated_records
from bifid.identify import HopfHybridModel

pytestmark = pytest.mark.slow

VDP_TRAIN = np.linspace(0.1, 1.0, 6)
VDP_TEST = np.array([0.19, 0.37, 0.55, 0.73, 0.91])
FLUTTER_STABLE = (15.2, 16.2, 17.2, 18.2)
FLUTTER_UNSTABLE = (15.3, 16.3, 17.3, 18.0)
TEST_STABLE = (15.7, 16.7, 17.7)
TEST_UNSTABLE = (15.8, 16.8, 17.65)
SIGNALS = ("h", "alpha", "hd", "alphad")


@pytest.fixture(scope="module")
def vdp():
    train = simulated_records("vanderpol", VDP_TRAIN, duration=10.0, dt=0.02)
    test = simulated_records("vanderpol", VDP_TEST, duration=30.0, dt=0.02)
    model = HopfHybridModel(n_ensemble=3).fit(train, signal_names=["z1", "z2"])
    return model, test


def test_vanderpol_hopf_point(vdp):
    """Check the Hopf point of Van der Pol (mu = 0) is found within 0.03."""
    model, _ = vdp
    assert abs(model.hopf_point()["param"]) < 0.03
    assert model.hopf_point()["criticality"] == "supercritical"


def test_vanderpol_amplitudes_untrained(vdp):
    """Check max|z1|, max|z2| at five untrained mu within 2 % of simulation."""
    model, test = vdp
    pred = model.predict_amplitude(VDP_TEST)
    truth = np.array([np.max(np.abs(r[1]), axis=0) for r in test])
    err = np.abs(pred - truth) / truth
    assert np.all(err < 0.02), err


def test_vanderpol_time_series_untrained(vdp):
    """Check the time series at mu = 0.55 (untrained) within 5 % RMS over one period."""
    model, test = vdp
    mu, ys, fs, _ = test[2]
    period = 2 * np.pi / model.predict_frequency([mu])[0]
    n = int(period * fs) + 1
    t = np.arange(n) / fs
    pred = model.predict_time_series(mu, t, initial=ys[0])
    rms = np.sqrt(np.mean((pred - ys[:n]) ** 2, axis=0)) / np.sqrt(np.mean(ys[:n] ** 2, axis=0))
    assert np.all(rms < 0.05), rms


@pytest.fixture(scope="module")
def flutter_truth():
    return ContinuationTruth.compute("flutter", p_range=(12.0, 22.0), n_mesh=32, ds=0.02)


def _flutter_errors(truth, noise):
    recs = truth.records(FLUTTER_STABLE, FLUTTER_UNSTABLE, SIGNALS, noise=noise, seed=3)
    model = HopfHybridModel(n_ensemble=3).fit(recs, signal_names=SIGNALS)
    amp, freq = [], []
    for values, stable in ((TEST_STABLE, True), (TEST_UNSTABLE, False)):
        pa = model.predict_amplitude(values, stable=stable)[:, :2]
        pf = model.predict_frequency(values, stable=stable)
        for k, u in enumerate(values):
            ta = truth.amplitude(u, stable, ("h", "alpha"))
            amp.append(np.abs(pa[k] - ta) / ta)
            freq.append(abs(pf[k] - truth.frequency(u, stable)) / truth.frequency(u, stable))
    return {
        "hopf": abs(model.hopf_point()["param"] - truth.hopf_param),
        "fold": abs(model.cycle_fold()["param"] - truth.fold_param),
        "amp": float(np.max(amp)),
        "freq": float(np.max(freq)),
    }


@pytest.fixture(scope="module")
def flutter_clean(flutter_truth):
    return _flutter_errors(flutter_truth, 0.0)


def test_flutter_noise_free(flutter_clean):
    """Check Hopf (0.05 m/s), fold (0.1 m/s), amplitudes (3 %) and frequency (1 %)."""
    e = flutter_clean
    assert e["hopf"] < 0.05, e
    assert e["fold"] < 0.1, e
    assert e["amp"] < 0.03, e
    assert e["freq"] < 0.01, e


def test_flutter_one_percent_noise(flutter_truth):
    """Check that with 1 % measurement noise every error is at most twice the bound."""
    e = _flutter_errors(flutter_truth, 0.01)
    assert e["hopf"] < 0.10, e
    assert e["fold"] < 0.2, e
    assert e["amp"] < 0.06, e
    assert e["freq"] < 0.02, e
