"""Readers of the electromagnetic oscillator's MATLAB files (thesis §3.2.1.1, ch. 6):
S-curves and backbone curves measured by CBC, as forced datasets.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from bifid.data._matlab import (
    _experiment_par,
    _need,
    _opt_scalar,
    _scalar,
    _struct,
    _vector,
    load_mat,
)
from bifid.data._netcdf import forced_dataset
from bifid.data._records import ForcedRecord
from bifid.errors import BifidInputError
from bifid.signal import periodic_amplitude

__all__ = [
    "em_dataset",
    "read_em_curve",
]

# The base and tip lasers read displacement with opposite signs: with the recorded signs
# the backbone curves (phase resonance, a lag of pi/2 by construction of the experiment)
# show a lag of -pi/2. The force reference is therefore -base_disp.
EM_FORCE_SIGN = -1.0


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
        raise BifidInputError(
            f"{path}: exp.data({i + 1}).{key} has {arr.shape[0]} values; "
            "expected 16 Fourier coefficients."
        )
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
        f_hz = _scalar(
            getattr(p, "forcing_freq", None), f"{where}.forcing_freq", path, positive=True
        )
        if f_hz >= fs / 2:
            raise BifidInputError(
                f"{path}: {where}.forcing_freq = {f_hz:g} Hz is not below "
                f"the Nyquist frequency {fs / 2:g} Hz."
            )
        freqs.append(f_hz)
        omega = 2 * np.pi * f_hz
        x = _vector(getattr(p, "x", None), f"{where}.x", path)
        n = x.shape[0]
        if n < 8:
            raise BifidInputError(f"{path}: {where}.x has only {n} samples.")
        base = _vector(getattr(p, "base_disp", None), f"{where}.base_disp", path, n)
        control = _vector(p.out, f"{where}.out", path, n) if hasattr(p, "out") else None
        x_target = (
            _vector(p.x_target, f"{where}.x_target", path, n) if hasattr(p, "x_target") else None
        )
        amp, x_mean = periodic_amplitude(x, omega, fs, n_harmonics=n_modes, trim=False)
        xc = _em_coeffs(p, "x_coeffs_ave", path, i)
        bc = _em_coeffs(p, "base_coeffs_ave", path, i)
        extra: dict[str, Any] = {
            "file": path.name,
            "point": i + 1,
            "forcing_freq_hz": f_hz,
            "x_offset": x_mean,
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
        records.append(
            ForcedRecord(
                omega=omega,
                forcing=forcing,
                signals=(x - x_mean)[:, None],
                sample_rate=fs,
                stable=None,
                force=EM_FORCE_SIGN * (base - float(np.mean(base))),
                control=control,
                target=None if x_target is None else x_target - x_mean,
                amplitude=amp,
                phase=None,
                curve=curve,
                extra=extra,
            )
        )
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
        records,
        ["x"],
        observed="x",
        system="experiment",
        settings={
            "format": "em",
            "files": [str(p) for p in paths],
            "amplitude": "max over one period of the 7-harmonic least-squares Fourier "
            "series of x (mean removed)",
            "forcing": "base_amp if stored, else |first harmonic of base_coeffs_ave|",
            "phase": "lag of x's first harmonic behind the force's (force = "
            "-base_disp: the lasers' signs are opposite), from time series",
            "force_sign": EM_FORCE_SIGN,
        },
        source=[str(p) for p in paths],
        signal_units={"x": ""},
        forcing_units="",
        attrs={
            "rig": "electromagnetic oscillator, University of Bristol (thesis §3.2.1.1)",
            "units_note": "x, base displacement and forcing are in the rig's recorded "
            "units (not stated in the source files)",
            "curves": curves,
        },
    )
