"""Readers of the flutter rig's MATLAB files (University of Bristol, thesis §3.3.3, ch. 4–5):
PP-CBC runs, free decays, open-loop runs and the unstable-LCO amplitude table.

Conventions (see ``docs/data-formats.md``): heave in m, pitch in rad, angular frequencies
in rad/s, static offsets removed from the signals and kept as per-record extras.
"""

from __future__ import annotations

import dataclasses
import os
import re
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from bifid.data._matlab import (
    _experiment_par,
    _finite_rows,
    _matrix,
    _need,
    _opt_scalar,
    _scalar,
    _vector,
    load_mat,
)
from bifid.data._netcdf import lco_dataset
from bifid.data._records import LCORecord
from bifid.errors import BifidInputError
from bifid.signal import estimate_frequency, fill_gaps

__all__ = [
    "RIG_PARAMETER_NAMES",
    "FreeDecay",
    "OpenLoopRun",
    "ULCOAmplitudes",
    "flutter_cbc_dataset",
    "load_free_decay",
    "load_open_loop",
    "load_ulco_amplitudes",
    "open_loop_dataset",
    "open_loop_summary",
    "read_flutter_cbc",
]

HEAVE_M_PER_V = 0.18  # flutter rig heave sensor, CBC and free-decay files
OPEN_LOOP_MM_PER_V = 470.0  # flutter rig heave sensor, 2018 open-loop files
PITCH_WRAP_VALUE = 6.2832  # pitch sensor wrap/clipping value in cbc_model2 [rad]
PITCH_WRAP_TOL = 1e-4
#: scalars stored in the rig's free-decay files -> the flutter model's parameter names
RIG_PARAMETER_NAMES = {
    "I__alpha": "Ia",
    "c__alpha": "ca",
    "c__h": "ch",
    "k__alpha": "ka",
    "k__h": "kh",
    "x__alpha": "xa",
    "m": "mw",
    "m__T": "mT",
    "b": "b",
    "a": "a",
    "rho": "rho",
}


# ---------------------------------------------------------------------------------------------
# generic helpers


# ---------------------------------------------------------------------------------------------


def _stable_from_name(name: str) -> bool | None:
    low = name.lower()
    if low.startswith("cbc_stable"):
        return True
    if low.startswith("cbc_unstable") or re.match(r"cbc_v\d", low):
        return False
    return None


_CBC_EXTRAS = (
    "error1",
    "error2",
    "error_tol",
    "freq_error",
    "picard",
    "success",
    "mean_pos",
    "initial_amp",
    "initial_freq",
    "PicardTol",
    "PicardTol_Freq",
)


def read_flutter_cbc(path: str | os.PathLike[str]) -> LCORecord:
    """One PP-CBC limit cycle of the flutter rig (``cbc_model1``/``cbc_model2`` files).

    - ``param`` = stored ``Wind_sped`` [m/s] (the file names are not reliable);
    - signals ``h`` [m] = (row 1 − mean) × 0.18 m/V and ``alpha`` [rad] = row 4 − mean,
      where pitch samples equal to 6.2832 (sensor wrap, ``cbc_model2``) are first replaced
      by :func:`~bifid.signal.fill_gaps` (linear interpolation for runs ≤ 25 samples
      = 5 ms, else the 7-harmonic Fourier series of the good samples at ``freq_actual``);
    - ``target`` = (row 2 − heave mean) × 0.18 [m]; ``control`` = shaker force row 3 [V];
    - ``stable`` from the file name (``CBC_stable_*`` → True; ``CBC_unstable_*``,
      ``CBC_v*`` → False; otherwise unknown);
    - ``frequency`` = 2π ``freq_actual``; ``sample_rate`` = ``exp.par.sample_freq`` (5 kHz);
    - extras: ``amplitude_target`` (non-invasive target A* [V]), ``mean_pos``, convergence
      errors and Picard settings, offsets, controller gains, the number of repaired pitch
      samples and the longest repaired run.

    The dataset's ``amplitude`` (``max_t |x(t)|`` of the centred signals) reproduces the
    authors' pitch amplitudes in ``ulco_amplitudes`` exactly.
    """
    path = Path(path)
    m = load_mat(path)
    data = _matrix(_need(m, "data", path, "5 × n channels"), "data", path, min_rows=4, min_cols=8)
    _finite_rows(data, (0, 1, 2, 3), "data", path)
    speed = _scalar(_need(m, "Wind_sped", path, "wind speed"), "Wind_sped", path)
    freq_hz = _scalar(
        _need(m, "freq_actual", path, "LCO frequency [Hz]"), "freq_actual", path, positive=True
    )
    par = _experiment_par(m.get("exp"), path)
    fs = _scalar(par.sample_freq, "exp.par.sample_freq", path, positive=True)
    if freq_hz >= fs / 2:
        raise BifidInputError(
            f"{path}: freq_actual = {freq_hz:g} Hz is not below the Nyquist "
            f"frequency {fs / 2:g} Hz."
        )
    omega = 2 * np.pi * freq_hz

    heave_v = data[0]
    h_off = float(np.mean(heave_v))
    h = (heave_v - h_off) * HEAVE_M_PER_V
    target = (data[1] - h_off) * HEAVE_M_PER_V
    control = data[2]
    pitch_raw = data[3]
    wrapped = np.abs(pitch_raw - PITCH_WRAP_VALUE) < PITCH_WRAP_TOL
    try:
        pitch, longest = fill_gaps(pitch_raw, wrapped, omega, fs)
    except BifidInputError as exc:
        raise BifidInputError(f"{path}: pitch: {exc}") from None
    a_off = float(np.mean(pitch))
    alpha = pitch - a_off

    extra: dict[str, Any] = {
        "file": path.name,
        "heave_offset_V": h_off,
        "pitch_offset_rad": a_off,
        "pitch_wrapped_samples": int(wrapped.sum()),
        "pitch_longest_gap": longest,
        "freq_actual_hz": freq_hz,
    }
    amp_target = _opt_scalar(m, "amplitude")
    if amp_target is not None:
        extra["amplitude_target"] = amp_target
    for key in _CBC_EXTRAS:
        v = _opt_scalar(m, key)
        if v is not None:
            extra[key] = v
    if par is not None:
        for key in ("x_Kp", "x_Kd"):
            v = _opt_scalar(par, key)
            if v is not None:
                extra[key] = v
    return LCORecord(
        param=speed,
        signals=np.stack([h, alpha], axis=1),
        sample_rate=fs,
        stable=_stable_from_name(path.name),
        control=control,
        target=target,
        frequency=omega,
        extra=extra,
    )


def flutter_cbc_dataset(paths: Sequence[str | os.PathLike[str]]) -> xr.Dataset:
    """``"lco"`` dataset of flutter-rig PP-CBC files (:func:`read_flutter_cbc` each)."""
    paths = [Path(p) for p in paths]
    records = [read_flutter_cbc(p) for p in paths]
    settings = {
        "format": "flutter-cbc",
        "files": [str(p) for p in paths],
        "heave_m_per_V": HEAVE_M_PER_V,
        "pitch_wrap_value": PITCH_WRAP_VALUE,
        "pitch_gap_fill": "linear interpolation for runs <= 25 samples, else 7-harmonic "
        "Fourier series of the good samples at freq_actual",
        "centring": "heave: record mean of row 1; pitch: record mean after gap filling",
        "stable_from": "file name (CBC_stable_* stable, CBC_unstable_*/CBC_v* unstable)",
    }
    return lco_dataset(
        records,
        ["h", "alpha"],
        param_name="U",
        param_units="m/s",
        system="experiment",
        settings=settings,
        source=[str(p) for p in paths],
        signal_units={"h": "m", "alpha": "rad"},
        attrs={
            "rig": "flutter rig, University of Bristol (thesis §3.3.3)",
            "control_units": "V (shaker force command)",
            "target_units": "m",
        },
    )


# ---------------------------------------------------------------------------------------------
# flutter rig: free decay
# ---------------------------------------------------------------------------------------------


@dataclasses.dataclass
class FreeDecay:
    """A free-decay response of the flutter rig at zero airspeed (thesis §4.3.1).

    Unpacks as ``t, heave, pitch = load_free_decay(path)``.

    Attributes
    ----------
    time : ndarray
        ``k / sample_rate`` [s].
    heave : ndarray
        Heave [m] = (row 2 − rest value) × 0.18 m/V.
    pitch : ndarray
        Pitch [rad] = row 1 − rest value.
    sample_rate : float
        [Hz] (``fs`` in the file, 5 kHz).
    heave_offset_V, pitch_offset_rad : float
        Rest values removed: medians of the last quarter of the record, where the rig is
        at rest.
    guesses : dict
        The other scalars of the file: the authors' starting guesses, not identified values.
    source : str
    """

    time: np.ndarray
    heave: np.ndarray
    pitch: np.ndarray
    sample_rate: float
    heave_offset_V: float
    pitch_offset_rad: float
    guesses: dict[str, float]
    source: str

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter((self.time, self.heave, self.pitch))


def load_free_decay(path: str | os.PathLike[str]) -> FreeDecay:
    """Read a ``flutter_rig/free_decay`` file (``data``: row 1 pitch [rad], row 2 heave [V]).

    A free decay is not a set of limit cycles, so it is not an ``"lco"`` dataset: use the
    arrays directly for linear identification (thesis §4.3.1).
    """
    path = Path(path)
    m = load_mat(path)
    data = _matrix(
        _need(m, "data", path, "2 × n: pitch, heave"), "data", path, min_rows=2, min_cols=8
    )
    _finite_rows(data, (0, 1), "data", path)
    fs = _scalar(_need(m, "fs", path, "sample rate [Hz]"), "fs", path, positive=True)
    n = data.shape[1]
    rest = slice(n - n // 4, n)
    p_off = float(np.median(data[0, rest]))
    h_off = float(np.median(data[1, rest]))
    guesses = {
        k: v
        for k in sorted(m)
        if k not in ("data", "time", "fs", "ans") and (v := _opt_scalar(m, k)) is not None
    }
    return FreeDecay(
        time=np.arange(n) / fs,
        heave=(data[1] - h_off) * HEAVE_M_PER_V,
        pitch=data[0] - p_off,
        sample_rate=fs,
        heave_offset_V=h_off,
        pitch_offset_rad=p_off,
        guesses=guesses,
        source=str(path),
    )


# ---------------------------------------------------------------------------------------------
# flutter rig: open-loop sweeps 2018
# ---------------------------------------------------------------------------------------------


@dataclasses.dataclass
class OpenLoopRun:
    """One open-loop wind-tunnel run of the flutter rig (``open_loop_2018``).

    Attributes
    ----------
    speed : float
        Wind speed [m/s] (``Speed``).
    direction : str
        ``"TowardsHB"`` / ``"BackFromHB"`` (sweep towards / back from the Hopf bifurcation),
        ``"Hammer"`` (hammer-excited run) or ``""`` when the name says none.
    time : ndarray
        [s].
    heave_mm : ndarray
        Heave [mm] = (row 2 − mean) × 470.
    sample_rate : float
        250 Hz.
    source : str
    """

    speed: float
    direction: str
    time: np.ndarray
    heave_mm: np.ndarray
    sample_rate: float
    source: str

    def amplitude_mm(self, n_segments: int = 10) -> tuple[float, float]:
        """Heave amplitude [mm]: median over ``n_segments`` equal segments of half their
        peak-to-peak, and the spread (max − min) of those values (large for transients)."""
        n = self.heave_mm.shape[0] // n_segments * n_segments
        if n == 0:
            half = 0.5 * float(np.ptp(self.heave_mm))
            return half, 0.0
        seg = self.heave_mm[:n].reshape(n_segments, -1)
        halves = 0.5 * (seg.max(axis=1) - seg.min(axis=1))
        return float(np.median(halves)), float(np.ptp(halves))


def _rate_of_time(t: np.ndarray, path: Path) -> float:
    """Sample rate of a uniformly sampled ``time`` vector [s]."""
    dt = np.diff(t)
    step = float(np.median(dt)) if dt.size else 0.0
    if not step > 0 or np.max(np.abs(dt - step)) > 1e-3 * step:
        raise BifidInputError(
            f"{path}: time is not uniformly increasing; cannot tell the sample rate."
        )
    return float(f"{(t.shape[0] - 1) / (t[-1] - t[0]):.9g}")  # 250.0, not 249.99999999999977


def _direction(name: str) -> str:
    for d in ("TowardsHB", "BackFromHB", "Hammer"):
        if d.lower() in name.lower():
            return d
    return ""


def load_open_loop(path: str | os.PathLike[str]) -> OpenLoopRun:
    """Read one ``open_loop_2018`` file: ``Speed``, heave row 2 × 470 → mm; the sample rate
    (250 Hz in the rig's files) from the file's ``time`` vector."""
    path = Path(path)
    m = load_mat(path)
    data = _matrix(_need(m, "data", path, "6 × n channels"), "data", path, min_rows=2, min_cols=8)
    _finite_rows(data, (1,), "data", path)
    speed = _scalar(_need(m, "Speed", path, "wind speed [m/s]"), "Speed", path)
    heave = (data[1] - float(np.mean(data[1]))) * OPEN_LOOP_MM_PER_V
    fs = _rate_of_time(
        _vector(_need(m, "time", path, "sample times [s]"), "time", path, n=data.shape[1]), path
    )
    return OpenLoopRun(
        speed=speed,
        direction=_direction(path.name),
        time=np.arange(heave.shape[0]) / fs,
        heave_mm=heave,
        sample_rate=fs,
        source=str(path),
    )


def open_loop_summary(paths: Sequence[str | os.PathLike[str]]) -> dict[str, np.ndarray]:
    """Amplitude per open-loop run, for hysteresis plots (amplitude vs speed by direction).

    Returns
    -------
    dict of ndarray
        ``speed`` [m/s], ``direction`` (str), ``amplitude_mm`` (median half peak-to-peak of
        10 segments), ``spread_mm`` (max − min of the segment values: a steady run has a
        small spread), ``frequency_hz`` (spectral peak), ``file``; sorted by speed.
    """
    runs = [load_open_loop(p) for p in paths]
    if not runs:
        raise BifidInputError("open_loop_summary: no files given.")
    amps = [r.amplitude_mm() for r in runs]
    out = {
        "speed": np.array([r.speed for r in runs]),
        "direction": np.array([r.direction for r in runs]),
        "amplitude_mm": np.array([a for a, _ in amps]),
        "spread_mm": np.array([s for _, s in amps]),
        "frequency_hz": np.array(
            [estimate_frequency(r.heave_mm, r.sample_rate) / (2 * np.pi) for r in runs]
        ),
        "file": np.array([Path(r.source).name for r in runs]),
    }
    order = np.argsort(out["speed"], kind="stable")
    return {k: v[order] for k, v in out.items()}


def open_loop_dataset(paths: Sequence[str | os.PathLike[str]]) -> xr.Dataset:
    """``"lco"`` dataset of open-loop runs: signal ``h`` [m], 250 Hz, no control.

    Open-loop responses that persist are stable attractors, so sweep runs
    (``TowardsHB``/``BackFromHB``) are labelled stable; hammer runs (transients) unknown.
    ``frequency`` is the spectral peak (:func:`~bifid.signal.estimate_frequency`).
    """
    paths = [Path(p) for p in paths]
    records = []
    for p in paths:
        run = load_open_loop(p)
        amp, spread = run.amplitude_mm()
        records.append(
            LCORecord(
                param=run.speed,
                signals=run.heave_mm[:, None] / 1000.0,
                sample_rate=run.sample_rate,
                stable=None if run.direction in ("Hammer", "") else True,
                frequency=estimate_frequency(run.heave_mm, run.sample_rate),
                extra={
                    "file": p.name,
                    "direction": run.direction,
                    "amplitude_mm": amp,
                    "spread_mm": spread,
                },
            )
        )
    return lco_dataset(
        records,
        ["h"],
        param_name="U",
        param_units="m/s",
        system="experiment",
        settings={
            "format": "flutter-openloop",
            "files": [str(p) for p in paths],
            "heave_mm_per_V": OPEN_LOOP_MM_PER_V,
            "centring": "record mean",
            "stable_from": "sweep runs stable (open-loop attractors), hammer unknown",
        },
        source=[str(p) for p in paths],
        signal_units={"h": "m"},
        attrs={"rig": "flutter rig, University of Bristol, open-loop sweeps 2018"},
    )


# ---------------------------------------------------------------------------------------------
# flutter rig: the authors' LCO amplitudes
# ---------------------------------------------------------------------------------------------


@dataclasses.dataclass
class ULCOAmplitudes:
    """LCO amplitudes extracted by the authors (``ulco_amplitudes``; thesis Fig. 4.1).

    ``unstable_*``: unstable LCOs (``U``, ``amp`` [m], ``angle`` [rad], ``freq`` [Hz]);
    ``stable_*``: stable LCOs (``s_U``, ``s_amp``, ``sangle``); NaN-filled arrays when the
    file lacks a field (set-up 2 has no pitch amplitudes). ``flutter_speed`` [m/s] and
    ``flutter_freq_hz`` are the authors' amplitude² regression estimates.
    """

    unstable_speed: np.ndarray
    unstable_heave: np.ndarray
    unstable_pitch: np.ndarray
    unstable_freq_hz: np.ndarray
    stable_speed: np.ndarray
    stable_heave: np.ndarray
    stable_pitch: np.ndarray
    flutter_speed: float
    flutter_freq_hz: float
    source: str


def load_ulco_amplitudes(path: str | os.PathLike[str]) -> ULCOAmplitudes:
    """Read a ``ulco_amplitudes`` file into :class:`ULCOAmplitudes`."""
    path = Path(path)
    m = load_mat(path)
    u = _vector(_need(m, "U", path, "unstable LCO speeds"), "U", path)
    su = _vector(_need(m, "s_U", path, "stable LCO speeds"), "s_U", path)

    def opt(key: str, n: int) -> np.ndarray:
        return _vector(m[key], key, path, n) if key in m else np.full(n, np.nan)

    return ULCOAmplitudes(
        unstable_speed=u,
        unstable_heave=_vector(_need(m, "amp", path, "heave amplitudes"), "amp", path, len(u)),
        unstable_pitch=opt("angle", len(u)),
        unstable_freq_hz=opt("freq", len(u)),
        stable_speed=su,
        stable_heave=_vector(
            _need(m, "s_amp", path, "stable heave amplitudes"), "s_amp", path, len(su)
        ),
        stable_pitch=opt("sangle", len(su)),
        flutter_speed=_scalar(_need(m, "flutter_speed", path, "m/s"), "flutter_speed", path),
        flutter_freq_hz=_scalar(_need(m, "flutter_freq", path, "Hz"), "flutter_freq", path),
        source=str(path),
    )
