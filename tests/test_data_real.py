"""Importers on the real measurements in ../shared/data (skipped when absent).

Checks against independent numbers: the raw MATLAB arrays recomputed here, the authors'
own amplitude tables (ulco_amplitudes), and physics (phase resonance on backbones).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import scipy.io
import xarray as xr

from bifid.data import (
    detect_format,
    forced_records,
    import_files,
    lco_records,
    load_dataset,
    load_free_decay,
    load_open_loop,
    load_thesis_curves,
    load_ulco_amplitudes,
    open_loop_dataset,
    open_loop_summary,
    save_dataset,
)


def _md5s(paths: list[Path]) -> dict[str, str]:
    return {p.name: hashlib.md5(p.read_bytes()).hexdigest() for p in paths}


@pytest.fixture(scope="module")
def model1(shared_data: Path) -> xr.Dataset:
    files = sorted((shared_data / "flutter_rig" / "cbc_model1").glob("*.mat"))
    before = _md5s(files)
    ds = import_files(files)
    assert _md5s(files) == before  # inputs never modified
    return ds


@pytest.fixture(scope="module")
def em(shared_data: Path) -> xr.Dataset:
    d = shared_data / "em_oscillator"
    return import_files(
        [
            d / "scurve_16p5Hz.mat",
            d / "scurve_16p6Hz.mat",
            d / "backbone_1.mat",
            d / "backbone_2.mat",
        ]
    )


def test_cbc_model1_records(model1: xr.Dataset) -> None:
    ds = model1
    assert ds.attrs["bifid_kind"] == "lco" and ds.sizes["record"] == 9
    assert [str(s) for s in ds["signal"].values] == ["h", "alpha"]
    stable = ds["stable"].values == 1
    np.testing.assert_allclose(np.sort(ds["param"].values[stable]), [14.9, 15.6, 16.5, 17.3])
    np.testing.assert_allclose(np.sort(ds["param"].values[~stable]), [14.9, 15.7, 16.4, 16.5, 17.2])
    np.testing.assert_array_equal(ds["sample_rate"].values, 5000.0)
    np.testing.assert_array_equal(ds["n_samples"].values, 100000)
    f_hz = ds["frequency"].values / (2 * np.pi)
    assert np.all((f_hz > 2.3) & (f_hz < 2.6))
    heave = ds["amplitude"].values[:, 0]
    assert np.all((heave > 0.005) & (heave < 0.05))  # a few mm to a few cm
    # subcritical Hopf: stable amplitudes grow with U, unstable ones shrink towards the Hopf
    for mask, sign in ((stable, 1), (~stable, -1)):
        order = np.argsort(ds["param"].values[mask])
        assert np.all(sign * np.diff(heave[mask][order]) > 0)
    assert ds["param"].attrs == {"name": "U", "units": "m/s"}


def test_cbc_model1_against_raw_file_and_authors(model1: xr.Dataset, shared_data: Path) -> None:
    recs = lco_records(model1)
    files = sorted((shared_data / "flutter_rig" / "cbc_model1").glob("*.mat"))
    # independent recomputation from the raw matrix of one file
    m = scipy.io.loadmat(files[0], squeeze_me=True, struct_as_record=False)
    raw = m["data"]
    np.testing.assert_allclose(recs[0].signals[:, 0], (raw[0] - raw[0].mean()) * 0.18)
    np.testing.assert_allclose(recs[0].signals[:, 1], raw[3] - raw[3].mean())
    np.testing.assert_allclose(recs[0].control, raw[2])
    np.testing.assert_allclose(recs[0].target, (raw[1] - raw[0].mean()) * 0.18)
    assert recs[0].param == m["Wind_sped"] and recs[0].extra["amplitude_target"] == m["amplitude"]
    assert recs[0].frequency == pytest.approx(2 * np.pi * m["freq_actual"])
    # the controller tracks its target: small tracking error relative to the response
    for r in recs:
        h = r.signals[:, 0]
        assert np.sqrt(np.mean((h - r.target) ** 2)) < 0.3 * np.sqrt(np.mean(h**2))
    # the authors' amplitude table (thesis Fig. 4.1) from the same runs, in file order
    u = load_ulco_amplitudes(
        shared_data / "flutter_rig" / "ulco_amplitudes" / "ULCO_data_torsional_spring-1.mat"
    )
    amp = model1["amplitude"].values
    st = model1["stable"].values == 1
    np.testing.assert_allclose(amp[st, 1], u.stable_pitch, rtol=2e-3)
    np.testing.assert_allclose(amp[~st, 1], u.unstable_pitch, rtol=2e-3)
    np.testing.assert_allclose(amp[st, 0], u.stable_heave, rtol=0.05)
    assert u.flutter_speed == pytest.approx(17.89, abs=0.01)


def test_cbc_model2_pitch_wraps_cleaned(shared_data: Path, tmp_path: Path) -> None:
    d = shared_data / "flutter_rig" / "cbc_model2"
    files = [d / "CBC_stable_v20_7.mat", d / "CBC_v20_7.mat"]
    ds = import_files(files, format="flutter-cbc")
    np.testing.assert_allclose(ds["param"].values, [20.7, 20.6])
    np.testing.assert_array_equal(ds["stable"].values, [1, 0])
    np.testing.assert_array_equal(ds["n_samples"].values, [100000, 10000])
    assert ds["extra_pitch_longest_gap"].values[1] > 25  # includes Fourier-filled runs
    for i, f in enumerate(files):
        raw = scipy.io.loadmat(f, squeeze_me=True)["data"][3]
        wrapped = np.abs(raw - 6.2832) < 1e-4
        assert wrapped.sum() == ds["extra_pitch_wrapped_samples"].values[i] > 1000
        alpha = ds["signals"].values[i, : ds["n_samples"].values[i], 1]
        # untouched samples are the raw ones minus the offset; repaired ones stay in range
        np.testing.assert_allclose(
            alpha[~wrapped] + ds["extra_pitch_offset_rad"].values[i], raw[~wrapped]
        )
        good = raw[~wrapped]
        off = ds["extra_pitch_offset_rad"].values[i]
        assert alpha[wrapped].max() <= good.max() - off + 0.01
        assert alpha[wrapped].min() >= good.min() - off - 0.01
    save_dataset(ds, tmp_path / "m2.nc")
    assert load_dataset(tmp_path / "m2.nc").sizes["record"] == 2


def test_em_scurves_and_backbones(em: xr.Dataset) -> None:
    assert em.attrs["bifid_kind"] == "forced" and em.attrs["observed"] == "x"
    curve = em["curve"].values
    assert [int((curve == c).sum()) for c in range(4)] == [67, 67, 47, 47]
    omega_hz = em["omega"].values / (2 * np.pi)
    np.testing.assert_allclose(omega_hz[curve == 0], 16.5)
    np.testing.assert_allclose(omega_hz[curve == 1], 16.6, rtol=1e-6)
    bb = curve >= 2
    assert omega_hz[bb].min() == pytest.approx(17.86, abs=0.05)
    assert omega_hz[bb].max() == pytest.approx(24.37, abs=0.05)
    np.testing.assert_array_equal(em["n_samples"].values, 2000)
    np.testing.assert_array_equal(em["sample_rate"].values, 5000.0)
    amp = em["amplitude"].values
    phase = em["phase"].values
    for c in range(4):
        assert np.all(np.diff(amp[curve == c]) > 0)  # continuation in response amplitude
    # backbone = phase resonance: x lags the force by pi/2 once the response is measurable
    big = bb & (amp > 0.1)
    assert big.sum() > 80
    dev = np.abs(phase[big] - np.pi / 2)
    assert np.median(dev) < 0.01 and np.mean(dev < 0.05) > 0.95 and dev.max() < 0.2
    # S-curves below the linear resonance: lags between 0 and pi/2
    assert np.all((phase[~bb] > 0) & (phase[~bb] < np.pi / 2))
    # time-series phase agrees with the file's averaged Fourier coefficients
    pc = em["extra_phase_coeffs"].values
    ok = amp > 0.05
    diff = np.abs(np.angle(np.exp(1j * (phase[ok] - pc[ok]))))
    assert np.median(diff) < 0.01 and np.quantile(diff, 0.95) < 0.05 and diff.max() < 0.15
    # forcing = the file's base_amp on S-curves; agrees with |first harmonic| of the base
    sc = ~bb
    np.testing.assert_array_equal(em["forcing"].values[sc], em["extra_base_amp"].values[sc])
    np.testing.assert_allclose(
        em["forcing"].values[sc], em["extra_base_h1"].values[sc], rtol=2e-3, atol=2e-4
    )
    # noise-free amplitude sits between the first harmonic and the raw max |x|
    assert np.all(amp[ok] >= 0.99 * em["extra_x_h1"].values[ok])
    assert np.all(amp[ok] <= 1.002 * em["extra_x_max_raw"].values[ok])


def test_em_force_signal_and_records(em: xr.Dataset, shared_data: Path) -> None:
    recs = forced_records(em)
    m = scipy.io.loadmat(
        shared_data / "em_oscillator" / "scurve_16p5Hz.mat", squeeze_me=True, struct_as_record=False
    )
    p = m["exp"].data[30]
    r = recs[30]
    np.testing.assert_allclose(r.force, -(p.base_disp - p.base_disp.mean()))
    np.testing.assert_allclose(r.signals[:, 0] + r.extra["x_offset"], p.x)
    np.testing.assert_allclose(r.control, p.out)
    assert r.forcing == p.base_amp and r.omega == pytest.approx(2 * np.pi * 16.5)


def test_free_decay(shared_data: Path) -> None:
    fd = load_free_decay(shared_data / "flutter_rig" / "free_decay" / "model1_free_decay.mat")
    t, heave, pitch = fd
    assert t.shape == heave.shape == pitch.shape == (80000,)
    assert fd.sample_rate == 5000.0 and t[1] == pytest.approx(2e-4)
    one_s = 5000
    # decays to rest (centred on the rest value)
    assert np.std(heave[:one_s]) > 100 * np.std(heave[-one_s:])
    assert np.std(pitch[:one_s]) > 100 * np.std(pitch[-one_s:])
    assert abs(np.median(heave[-one_s:])) < 1e-4 and abs(np.median(pitch[-one_s:])) < 1e-4
    assert 0.01 < np.max(np.abs(heave)) < 0.2  # m
    assert fd.guesses["sen"] == 0.18


def test_open_loop(shared_data: Path) -> None:
    d = shared_data / "flutter_rig" / "open_loop_2018"
    files = [
        d / "17092018_CBC_V163_BackFromHB.mat",
        d / "17092018_CBC_V171_TowardsHB.mat",
        d / "17092018_CBC_V241_Hammer.mat",
    ]
    run = load_open_loop(files[0])
    raw = scipy.io.loadmat(files[0], squeeze_me=True)
    np.testing.assert_allclose(run.heave_mm, (raw["data"][1] - raw["data"][1].mean()) * 470)
    assert run.speed == 16.3 and run.direction == "BackFromHB" and run.sample_rate == 250.0
    s = open_loop_summary(files)
    np.testing.assert_allclose(s["speed"], [16.3, 17.1, 24.1])
    assert list(s["direction"]) == ["BackFromHB", "TowardsHB", "Hammer"]
    half_ptp = 0.5 * np.ptp(run.heave_mm)
    assert 0.9 * half_ptp < s["amplitude_mm"][0] <= half_ptp  # steady LCO
    assert s["spread_mm"][0] < 0.05 * s["amplitude_mm"][0]
    assert s["spread_mm"][2] > 0.5 * s["amplitude_mm"][2]  # hammer run: transient
    assert np.all((s["frequency_hz"][:2] > 2.5) & (s["frequency_hz"][:2] < 3.2))
    ds = open_loop_dataset(files)
    np.testing.assert_array_equal(ds["stable"].values, [1, 1, -1])


def test_small_loaders_and_detection(shared_data: Path) -> None:
    fr = shared_data / "flutter_rig"
    speed, heave, pitch = load_thesis_curves(fr / "thesis_curves" / "linear_id_Data_8-2.csv")
    assert speed.shape == heave.shape == pitch.shape == (41,)
    assert speed[0] == 13.96 and heave[0] == 0.033448 and pitch[0] == 0.089638
    u2 = load_ulco_amplitudes(fr / "ulco_amplitudes" / "ULCO_data_torsional_spring-2.mat")
    assert u2.flutter_speed == pytest.approx(26.25, abs=0.01)
    assert np.isnan(u2.unstable_pitch).all() and u2.unstable_speed.shape == (8,)
    assert detect_format(fr / "cbc_model1" / "CBC_stable_v14_9.mat") == "flutter-cbc"
    assert detect_format(fr / "cbc_model2" / "CBC_v25_0.mat") == "flutter-cbc"
    assert (
        detect_format(fr / "open_loop_2018" / "17092018_CBC_V163_BackFromHB.mat")
        == "flutter-openloop"
    )
    em = shared_data / "em_oscillator"
    assert detect_format(em / "scurve_16p5Hz.mat") == "em-scurve"
    assert detect_format(em / "backbone_2.mat") == "em-backbone"
