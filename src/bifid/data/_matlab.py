"""Readers of the MATLAB files of the two experiments in the thesis (``shared/data``).

Flutter rig (University of Bristol, thesis §3.3.3, ch. 4–5) and electromagnetic oscillator
(thesis §3.2.1.1, ch. 6). Files are read with ``scipy.io.loadmat`` (MATLAB v5; no code is
executed, MATLAB objects stay opaque); every missing field, wrong shape or non-finite
value raises :class:`~bifid.errors.BifidInputError` naming the file.

Conventions (see ``docs/data-formats.md``): heave in m, pitch in rad, angular frequencies
in rad/s, static offsets removed from the signals and kept as per-record extras.
"""

from __future__ import annotations

import dataclasses
import io
import math
import os
import re
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from bifid.data._matcheck import check_mat_v5
from bifid.data._netcdf import forced_dataset, lco_dataset
from bifid.data._records import ForcedRecord, LCORecord
from bifid.errors import BifidInputError
from bifid.io import check_input_file
from bifid.signal import estimate_frequency, fill_gaps, periodic_amplitude

__all__ = [
    "FreeDecay",
    "OpenLoopRun",
    "ULCOAmplitudes",
    "em_dataset",
    "flutter_cbc_dataset",
    "load_free_decay",
    "load_mat",
    "load_open_loop",
    "load_ulco_amplitudes",
    "open_loop_dataset",
    "open_loop_summary",
    "read_em_curve",
    "read_flutter_cbc",
]

HEAVE_M_PER_V = 0.18  # flutter rig heave sensor, CBC and free-decay files
OPEN_LOOP_MM_PER_V = 470.0  # flutter rig heave sensor, 2018 open-loop files
PITCH_WRAP_VALUE = 6.2832  # pitch sensor wrap/clipping value in cbc_model2 [rad]
PITCH_WRAP_TOL = 1e-4
# The base and tip lasers read displacement with opposite signs: with the recorded signs
# the backbone curves (phase resonance, a lag of pi/2 by construction of the experiment)
# show a lag of -pi/2. The force reference is therefore -base_disp.
EM_FORCE_SIGN = -1.0
MAX_MAT_BYTES = 512 * 1024**2


# ---------------------------------------------------------------------------------------------
# generic helpers
# ---------------------------------------------------------------------------------------------


def load_mat(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a MATLAB v5 file with ``loadmat(squeeze_me=True, struct_as_record=False)``.

    Raises
    ------
    BifidInputError
        Missing file, v7.3/HDF5 or otherwise unreadable file.
    """
    import scipy.io

    path = check_input_file(path)
    size = path.stat().st_size
    if size > MAX_MAT_BYTES:
        raise BifidInputError(f"{path}: {size / 1e6:.0f} MB is larger than the 512 MB limit.")
    blob = path.read_bytes()
    # scipy's compiled reader can crash the interpreter on corrupted element tags:
    # check the file's structure in Python first
    check_mat_v5(blob, str(path))
    try:
        m = scipy.io.loadmat(io.BytesIO(blob), squeeze_me=True, struct_as_record=False)
    except NotImplementedError:
        raise BifidInputError(
            f"{path}: MATLAB v7.3 (HDF5) files are not supported; re-save with "
            "save(..., '-v7') in MATLAB."
        ) from None
    except MemoryError:
        raise BifidInputError(f"{path}: declares arrays too large to load.") from None
    except Exception as exc:  # scipy raises ValueError, TypeError, OSError, ... on bad files
        msg = str(exc).splitlines()[0][:160] if str(exc) else type(exc).__name__
        raise BifidInputError(
            f"{path} is not a readable MATLAB v5 .mat file ({type(exc).__name__}: {msg})."
        ) from None
    if not isinstance(m, dict):
        raise BifidInputError(f"{path}: unexpected content.")
    return {k: v for k, v in m.items() if not k.startswith("__")}


def _need(m: dict[str, Any], key: str, path: Path, what: str) -> Any:
    if key not in m:
        raise BifidInputError(f"{path}: field {key!r} ({what}) is missing.")
    return m[key]


def _scalar(value: Any, name: str, path: Path, *, positive: bool = False) -> float:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise BifidInputError(f"{path}: {name} must be a number, found {type(value).__name__}.")\
            from None
    if arr.size != 1:
        raise BifidInputError(f"{path}: {name} must be a scalar, found shape {arr.shape}.")
    v = float(arr.reshape(()))
    if not math.isfinite(v) or (positive and v <= 0):
        raise BifidInputError(
            f"{path}: {name} must be finite{' and > 0' if positive else ''}, found {v!r}."
        )
    return v


def _opt_scalar(m: Any, key: str) -> float | None:
    value = m.get(key) if isinstance(m, dict) else getattr(m, key, None)
    if value is None:
        return None
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    if arr.size != 1 or not np.isfinite(arr).all():
        return None
    return float(arr.reshape(()))


def _matrix(value: Any, name: str, path: Path, min_rows: int, min_cols: int = 2) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise BifidInputError(f"{path}: {name} must be a numeric matrix.") from None
    if arr.ndim != 2 or arr.shape[0] < min_rows or arr.shape[1] < min_cols:
        raise BifidInputError(
            f"{path}: {name} must be a matrix with at least {min_rows} rows (channels) and "
            f"{min_cols} columns (samples), found shape {arr.shape}."
        )
    return arr


def _finite_rows(arr: np.ndarray, rows: Sequence[int], name: str, path: Path) -> None:
    for r in rows:
        bad = ~np.isfinite(arr[r])
        if bad.any():
            raise BifidInputError(
                f"{path}: {name} row {r + 1} has {int(bad.sum())} NaN/inf samples."
            )


def _vector(value: Any, name: str, path: Path, n: int | None = None) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise BifidInputError(f"{path}: {name} must be a numeric vector.") from None
    if n is not None and arr.shape[0] != n:
        raise BifidInputError(f"{path}: {name} must have {n} values, found {arr.shape[0]}.")
    if arr.shape[0] == 0:
        raise BifidInputError(f"{path}: {name} is empty.")
    if not np.all(np.isfinite(arr)):
        raise BifidInputError(f"{path}: {name} contains NaN/inf.")
    return arr


def _struct(value: Any, name: str, path: Path) -> Any:
    if not hasattr(value, "_fieldnames"):
        raise BifidInputError(f"{path}: {name} must be a MATLAB struct.")
    return value


def _experiment_par(exp: Any, path: Path) -> Any:
    """``exp.par`` of a rig file, which must give ``sample_freq``: no rate is assumed."""
    if exp is None or not hasattr(exp, "_fieldnames"):
        raise BifidInputError(
            f"{path}: the experiment struct 'exp' is missing, so the sample rate "
            "(exp.par.sample_freq) is unknown; bifid does not assume one. Export the file "
            "with its exp struct, or write the records as CSV with a time column."
        )
    par = getattr(exp, "par", None)
    if par is None or getattr(par, "sample_freq", None) is None:
        raise BifidInputError(
            f"{path}: exp.par.sample_freq (the sample rate) is missing; bifid does not "
            "assume one."
        )
    return par


# ---------------------------------------------------------------------------------------------
# flutter rig: PP-CBC limit cycles (cbc_model1, cbc_model2)
# ---------------------------------------------------------------------------------------------


def _stable_from_name(name: str) -> bool | None:
    low = name.lower()
    if low.startswith("cbc_stable"):
        return True
    if low.startswith("cbc_unstable") or re.match(r"cbc_v\d", low):
        return False
    return None


_CBC_EXTRAS = ("error1", "error2", "error_tol", "freq_error", "picard", "success", "mean_pos",
               "initial_amp", "initial_freq", "PicardTol", "PicardTol_Freq")


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
    freq_hz = _scalar(_need(m, "freq_actual", path, "LCO frequency [Hz]"), "freq_actual", path,
                      positive=True)
    par = _experiment_par(m.get("exp"), path)
    fs = _scalar(par.sample_freq, "exp.par.sample_freq", path, positive=True)
    if freq_hz >= fs / 2:
        raise BifidInputError(f"{path}: freq_actual = {freq_hz:g} Hz is not below the Nyquist "
                              f"frequency {fs / 2:g} Hz.")
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
        records, ["h", "alpha"], param_name="U", param_units="m/s", system="experiment",
        settings=settings, source=[str(p) for p in paths],
        signal_units={"h": "m", "alpha": "rad"},
        attrs={"rig": "flutter rig, University of Bristol (thesis §3.3.3)",
               "control_units": "V (shaker force command)", "target_units": "m"},
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
    data = _matrix(_need(m, "data", path, "2 × n: pitch, heave"), "data", path, min_rows=2,
                   min_cols=8)
    _finite_rows(data, (0, 1), "data", path)
    fs = _scalar(_need(m, "fs", path, "sample rate [Hz]"), "fs", path, positive=True)
    n = data.shape[1]
    rest = slice(n - n // 4, n)
    p_off = float(np.median(data[0, rest]))
    h_off = float(np.median(data[1, rest]))
    guesses = {k: v for k in sorted(m) if k not in ("data", "time", "fs", "ans")
               and (v := _opt_scalar(m, k)) is not None}
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
        raise BifidInputError(f"{path}: time is not uniformly increasing; cannot tell the "
                              "sample rate.")
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
    data = _matrix(_need(m, "data", path, "6 × n channels"), "data", path, min_rows=2,
                   min_cols=8)
    _finite_rows(data, (1,), "data", path)
    speed = _scalar(_need(m, "Speed", path, "wind speed [m/s]"), "Speed", path)
    heave = (data[1] - float(np.mean(data[1]))) * OPEN_LOOP_MM_PER_V
    fs = _rate_of_time(_vector(_need(m, "time", path, "sample times [s]"), "time", path,
                               n=data.shape[1]), path)
    return OpenLoopRun(speed=speed, direction=_direction(path.name),
                       time=np.arange(heave.shape[0]) / fs, heave_mm=heave, sample_rate=fs,
                       source=str(path))


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
        "frequency_hz": np.array([estimate_frequency(r.heave_mm, r.sample_rate) / (2 * np.pi)
                                  for r in runs]),
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
        records.append(LCORecord(
            param=run.speed, signals=run.heave_mm[:, None] / 1000.0,
            sample_rate=run.sample_rate,
            stable=None if run.direction in ("Hammer", "") else True,
            frequency=estimate_frequency(run.heave_mm, run.sample_rate),
            extra={"file": p.name, "direction": run.direction, "amplitude_mm": amp,
                   "spread_mm": spread},
        ))
    return lco_dataset(
        records, ["h"], param_name="U", param_units="m/s", system="experiment",
        settings={"format": "flutter-openloop", "files": [str(p) for p in paths],
                  "heave_mm_per_V": OPEN_LOOP_MM_PER_V, "centring": "record mean",
                  "stable_from": "sweep runs stable (open-loop attractors), hammer unknown"},
        source=[str(p) for p in paths], signal_units={"h": "m"},
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
        stable_heave=_vector(_need(m, "s_amp", path, "stable heave amplitudes"), "s_amp", path,
                             len(su)),
        stable_pitch=opt("sangle", len(su)),
        flutter_speed=_scalar(_need(m, "flutter_speed", path, "m/s"), "flutter_speed", path),
        flutter_freq_hz=_scalar(_need(m, "flutter_freq", path, "Hz"), "flutter_freq", path),
        source=str(path),
    )


# ---------------------------------------------------------------------------------------------
# electromagnetic oscillator: S-curves and backbone curves
# ---------------------------------------------------------------------------------------------

# Fourier coefficient vectors (16 values): 0-based index k = 1..7 holds the sine
# coefficient of harmonic k, index 8 the mean, index 8 + k the cosine coefficient of
# harmonic k (the file's exp.fourier.idx_sin/idx_DC/idx_cos are the 1-based versions).
_EM_SIN1, _EM_DC, _EM_COS1 = 1, 8, 9


def _em_coeffs(point: Any, key: str, path: Path, i: int) -> np.ndarray | None:
    value = getattr(point, key, None)
    if value is None:
        return None
    arr = _vector(value, f"exp.data({i + 1}).{key}", path)
    if arr.shape[0] < 10:
        raise BifidInputError(f"{path}: exp.data({i + 1}).{key} has {arr.shape[0]} values; "
                              "expected 16 Fourier coefficients.")
    return arr


def _lag(c_resp: np.ndarray, c_force: np.ndarray) -> float:
    # x ≈ c cos θ + s sin θ = A cos(θ − φ) with φ = atan2(s, c)
    phi_x = math.atan2(c_resp[_EM_SIN1], c_resp[_EM_COS1])
    phi_f = math.atan2(EM_FORCE_SIGN * c_force[_EM_SIN1], EM_FORCE_SIGN * c_force[_EM_COS1])
    return float((phi_x - phi_f + math.pi / 2) % (2 * math.pi) - math.pi / 2)


def read_em_curve(path: str | os.PathLike[str], curve: int = 0) -> tuple[list[ForcedRecord], str]:
    """The CBC points of one electromagnetic-oscillator file (S-curve or backbone).

    Per point ``exp.data(i)``:

    - ``omega`` = 2π ``forcing_freq`` [rad/s];
    - ``forcing`` = base displacement amplitude: ``base_amp`` where the file stores it
      (S-curves), else the first-harmonic magnitude of ``base_coeffs_ave`` (backbones;
      the two agree to 1e-4 where both exist);
    - signal ``x`` = the response time series (2000 samples at 5 kHz) minus its mean;
      ``force`` = −(``base_disp`` minus its mean) (sign: see ``EM_FORCE_SIGN``);
      ``target`` = ``x_target`` minus x's mean;
      ``control`` = ``out`` (controller output driving the shaker);
    - ``amplitude`` = ``max_t |x(t)|`` of the 7-harmonic least-squares Fourier series of
      the time series (noise removed; :func:`~bifid.signal.periodic_amplitude`);
    - ``phase`` left to the dataset builder: lag of x's first harmonic behind the force's,
      from the time series; the same from the averaged coefficients is kept as extra
      ``phase_coeffs``;
    - ``stable`` unknown; ``curve`` as given.

    Returns
    -------
    records : list of ForcedRecord
    kind : str
        ``"scurve"`` or ``"backbone"`` (from ``exp.name``, else from whether the forcing
        frequency varies).
    """
    path = Path(path)
    m = load_mat(path)
    exp = _struct(_need(m, "exp", path, "CBC experiment struct"), "exp", path)
    points = np.atleast_1d(getattr(exp, "data", np.array([])))
    if points.size == 0:
        raise BifidInputError(f"{path}: exp.data holds no points.")
    par = _experiment_par(exp, path)
    fs = _scalar(par.sample_freq, "exp.par.sample_freq", path, positive=True)
    n_modes = 7
    fourier = getattr(exp, "fourier", None)
    if fourier is not None and _opt_scalar(fourier, "n_modes") is not None:
        n_modes = int(min(max(_opt_scalar(fourier, "n_modes") or 7, 1), 20))
    records = []
    freqs = []
    for i, p in enumerate(points.reshape(-1)):
        where = f"exp.data({i + 1})"
        _struct(p, where, path)
        f_hz = _scalar(getattr(p, "forcing_freq", None), f"{where}.forcing_freq", path,
                       positive=True)
        if f_hz >= fs / 2:
            raise BifidInputError(f"{path}: {where}.forcing_freq = {f_hz:g} Hz is not below "
                                  f"the Nyquist frequency {fs / 2:g} Hz.")
        freqs.append(f_hz)
        omega = 2 * np.pi * f_hz
        x = _vector(getattr(p, "x", None), f"{where}.x", path)
        n = x.shape[0]
        if n < 8:
            raise BifidInputError(f"{path}: {where}.x has only {n} samples.")
        base = _vector(getattr(p, "base_disp", None), f"{where}.base_disp", path, n)
        control = (_vector(p.out, f"{where}.out", path, n) if hasattr(p, "out") else None)
        x_target = (_vector(p.x_target, f"{where}.x_target", path, n)
                    if hasattr(p, "x_target") else None)
        amp, x_mean = periodic_amplitude(x, omega, fs, n_harmonics=n_modes, trim=False)
        xc = _em_coeffs(p, "x_coeffs_ave", path, i)
        bc = _em_coeffs(p, "base_coeffs_ave", path, i)
        extra: dict[str, Any] = {
            "file": path.name, "point": i + 1, "forcing_freq_hz": f_hz, "x_offset": x_mean,
            "x_max_raw": float(np.max(np.abs(x - x_mean))),
        }
        base_amp = _opt_scalar(p, "base_amp")
        if bc is not None:
            extra["base_h1"] = float(np.hypot(bc[_EM_SIN1], bc[_EM_COS1]))
        if base_amp is not None:
            forcing = base_amp
            extra["base_amp"] = base_amp
        elif bc is not None:
            forcing = extra["base_h1"]
        else:
            raise BifidInputError(f"{path}: {where} has neither base_amp nor base_coeffs_ave.")
        if xc is not None:
            extra["x_h1"] = float(np.hypot(xc[_EM_SIN1], xc[_EM_COS1]))
            if bc is not None and extra["base_h1"] > 0 and extra["x_h1"] > 0:
                extra["phase_coeffs"] = _lag(xc, bc)
        for key in ("x_amp", "out_amp", "rand_ampl"):
            v = _opt_scalar(p, key)
            if v is not None:
                extra[key] = v
        records.append(ForcedRecord(
            omega=omega, forcing=forcing, signals=(x - x_mean)[:, None], sample_rate=fs,
            stable=None, force=EM_FORCE_SIGN * (base - float(np.mean(base))), control=control,
            target=None if x_target is None else x_target - x_mean,
            amplitude=amp, phase=None, curve=curve, extra=extra,
        ))
    raw_name = getattr(exp, "name", "")
    name = raw_name if isinstance(raw_name, str) else ""
    if "backbone" in name.lower():
        kind = "backbone"
    elif "amplitude" in name.lower() or "scurve" in name.lower():
        kind = "scurve"
    else:
        kind = "backbone" if np.ptp(freqs) > 1e-9 else "scurve"
    for r in records:
        r.extra["curve_kind"] = kind
    return records, kind


def em_dataset(paths: Sequence[str | os.PathLike[str]]) -> xr.Dataset:
    """``"forced"`` dataset of electromagnetic-oscillator CBC files, one curve id per file
    (in the order given); see :func:`read_em_curve`."""
    paths = [Path(p) for p in paths]
    records: list[ForcedRecord] = []
    curves = {}
    for c, p in enumerate(paths):
        recs, kind = read_em_curve(p, curve=c)
        records.extend(recs)
        curves[str(c)] = {"file": p.name, "kind": kind, "n_points": len(recs)}
    return forced_dataset(
        records, ["x"], observed="x", system="experiment",
        settings={"format": "em", "files": [str(p) for p in paths],
                  "amplitude": "max over one period of the 7-harmonic least-squares Fourier "
                               "series of x (mean removed)",
                  "forcing": "base_amp if stored, else |first harmonic of base_coeffs_ave|",
                  "phase": "lag of x's first harmonic behind the force's (force = "
                           "-base_disp: the lasers' signs are opposite), from time series",
                  "force_sign": EM_FORCE_SIGN},
        source=[str(p) for p in paths],
        signal_units={"x": ""},
        forcing_units="",
        attrs={"rig": "electromagnetic oscillator, University of Bristol (thesis §3.2.1.1)",
               "units_note": "x, base displacement and forcing are in the rig's recorded "
                             "units (not stated in the source files)",
               "curves": curves},
    )
