"""Training data of the kernel models: forced responses ``(Ω_j, F_j, ρ_j, lag_j)`` with
their time series, from forced datasets and/or arrays (:func:`training_data`)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from bifid.data import forced_records, load_dataset
from bifid.errors import BifidInputError
from bifid.signal import fourier_project

__all__ = ["ForcedTrainingData", "training_data", "usable_points"]


@dataclass
class ForcedTrainingData:
    """Forced-response points ``(Ω_j, F_j, ρ_j, lag_j)`` and optional time series.

    ``series[j]`` is ``(t, y)`` (times [s], centred observed signal) or None.
    """

    omega: np.ndarray
    forcing: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray
    stable: np.ndarray
    curve: np.ndarray
    series: list[tuple[np.ndarray, np.ndarray] | None]
    sources: list[str]

    def __len__(self) -> int:
        return int(self.omega.shape[0])


def _as_1d(name: str, v: Any, n: int | None = None) -> np.ndarray:
    try:
        a = np.asarray(v, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise BifidInputError(f"{name} must be a numeric array.") from None
    if n is not None and a.shape[0] != n:
        raise BifidInputError(f"{name} must have {n} values (one per point), got {a.shape[0]}.")
    return a


def _harmonic_amplitude(t: np.ndarray, y: np.ndarray, omega: float) -> float:
    """Amplitude of the first harmonic of ``y(t)`` (least squares, one harmonic)."""
    c = fourier_project(y, omega * t, 1)
    return float(np.hypot(c[1], c[2]))


def _read_dataset(item: Any, parts: dict[str, list], series: list, amplitude_kind: str) -> str:
    """Append the points and time series of one forced dataset (or path); its source."""
    ds = load_dataset(item) if isinstance(item, (str, os.PathLike)) else item
    source = (
        os.fspath(item)
        if isinstance(item, (str, os.PathLike))
        else str(getattr(ds, "attrs", {}).get("source", "dataset"))
    )
    if getattr(ds, "attrs", {}).get("bifid_kind") != "forced":
        raise BifidInputError(
            "forced kernel models train on 'forced' datasets (S-curves, FRCs); got a "
            f"{getattr(ds, 'attrs', {}).get('bifid_kind')!r} dataset."
        )
    obs = str(ds.attrs.get("observed", ""))
    names = [str(s) for s in ds["signal"].values.tolist()]
    j_obs = names.index(obs) if obs in names else 0
    offset = max(parts["curve"]) + 1 if parts["curve"] else 0
    for r in forced_records(ds):
        parts["omega"].append(r.omega)
        parts["forcing"].append(r.forcing)
        parts["phase"].append(np.nan if r.phase is None else r.phase)
        parts["stable"].append(-1 if r.stable is None else int(r.stable))
        parts["curve"].append(r.curve + offset)
        y = np.asarray(r.signals[:, j_obs], dtype=float)
        t = np.arange(y.shape[0]) / r.sample_rate
        y = y - y.mean()
        series.append((t, y) if y.shape[0] >= 4 else None)
        if amplitude_kind == "harmonic" and y.shape[0] >= 4:
            parts["amplitude"].append(_harmonic_amplitude(t, y, r.omega))
        else:
            parts["amplitude"].append(
                r.amplitude if r.amplitude is not None else float(np.max(np.abs(y)))
            )
    return source


POINT_KEYS = ("omega", "forcing", "amplitude", "phase", "stable", "time_series")


def training_data(
    data: Any = None,
    points: Mapping[str, Any] | None = None,
    *,
    amplitude_kind: Literal["max", "harmonic"] = "max",
) -> ForcedTrainingData:
    """Collect training points from forced datasets and/or plain arrays.

    Parameters
    ----------
    data : xarray.Dataset, path, or a sequence of them, optional
        ``"forced"`` datasets (:mod:`bifid.data`). Their ``amplitude`` (max |y|),
        ``phase`` (lag behind the force), ``omega``, ``forcing``, ``stable``, and the
        observed signal's time series are used.
    points : mapping, optional
        Points given directly, appended to ``data``'s: arrays ``omega``, ``forcing``,
        ``amplitude``, ``phase`` (lag of the response's first harmonic behind the force
        [rad]), optionally ``stable`` (1 stable, 0 unstable, -1 unknown; diagnostics only)
        and ``time_series`` (one ``(t, y)`` or None per point: the observed signal over
        whole periods). None values count as absent.
    amplitude_kind : {"max", "harmonic"}
        ``"max"``: ``max_t |y|`` (thesis eq. 6.5, the dataset's ``amplitude``);
        ``"harmonic"``: amplitude of the first harmonic of the time series (less sensitive
        to noise and higher harmonics in measured data).
    """
    points = {k: v for k, v in (points or {}).items() if v is not None}
    unknown = set(points) - set(POINT_KEYS)
    if unknown:
        raise BifidInputError(
            f"unknown point arrays {sorted(unknown)}; expected {', '.join(POINT_KEYS)}."
        )
    omega, forcing, amplitude, phase, stable, time_series = (points.get(k) for k in POINT_KEYS)
    if amplitude_kind not in ("max", "harmonic"):
        raise BifidInputError(
            f"amplitude_kind must be 'max' or 'harmonic', got {amplitude_kind!r}."
        )
    parts: dict[str, list] = {
        k: [] for k in ("omega", "forcing", "amplitude", "phase", "stable", "curve")
    }
    series: list[tuple[np.ndarray, np.ndarray] | None] = []
    sources: list[str] = []
    if data is not None:
        for item in data if isinstance(data, (list, tuple)) else [data]:
            sources.append(_read_dataset(item, parts, series, amplitude_kind))
    curve_offset = max(parts["curve"]) + 1 if parts["curve"] else 0
    if omega is not None or forcing is not None or amplitude is not None or phase is not None:
        if omega is None or forcing is None or amplitude is None or phase is None:
            raise BifidInputError(
                "give all four arrays omega, forcing, amplitude and phase (or a dataset)."
            )
        om = _as_1d("omega", omega)
        n = om.shape[0]
        fo = _as_1d("forcing", forcing, n)
        am = _as_1d("amplitude", amplitude, n)
        ph = _as_1d("phase", phase, n)
        st = np.full(n, -1) if stable is None else _as_1d("stable", stable, n).astype(int)
        ts = list(time_series) if time_series is not None else [None] * n
        if len(ts) != n:
            raise BifidInputError(f"time_series needs one entry (or None) per point ({n}).")
        for i in range(n):
            s = ts[i]
            if s is not None:
                t_i = _as_1d("time_series t", s[0])
                y_i = _as_1d("time_series y", s[1], t_i.shape[0])
                s = (t_i, y_i - y_i.mean())
                if amplitude_kind == "harmonic":
                    am[i] = _harmonic_amplitude(s[0], s[1], om[i])
            series.append(s)
        parts["omega"].extend(om)
        parts["forcing"].extend(fo)
        parts["amplitude"].extend(am)
        parts["phase"].extend(ph)
        parts["stable"].extend(st)
        parts["curve"].extend(np.full(n, curve_offset))
        sources.append("arrays")
    if not parts["omega"]:
        raise BifidInputError("no training data: give forced datasets or the four arrays.")
    out = ForcedTrainingData(
        omega=np.asarray(parts["omega"], dtype=float),
        forcing=np.asarray(parts["forcing"], dtype=float),
        amplitude=np.asarray(parts["amplitude"], dtype=float),
        phase=np.asarray(parts["phase"], dtype=float),
        stable=np.asarray(parts["stable"], dtype=int),
        curve=np.asarray(parts["curve"], dtype=int),
        series=series,
        sources=sources,
    )
    if not np.all(np.isfinite(out.omega)) or np.any(out.omega <= 0):
        raise BifidInputError("forcing frequencies omega must be finite and > 0 [rad/s].")
    return out


def usable_points(td: ForcedTrainingData, rho_min_fraction: float) -> tuple[np.ndarray, list[str]]:
    """Mask of the points with a phase, a forcing and an amplitude above ``rho_min_fraction``
    of the largest, and notes on the points skipped."""
    ok = (
        np.isfinite(td.forcing)
        & np.isfinite(td.amplitude)
        & np.isfinite(td.phase)
        & (td.forcing > 0)
        & (td.amplitude > 0)
    )
    if not np.any(ok):
        raise BifidInputError(
            "no usable training point: every point lacks a phase, has zero forcing or "
            "zero amplitude (the phase needs a recorded force signal)."
        )
    small = ok & (td.amplitude < rho_min_fraction * float(np.max(td.amplitude[ok])))
    notes = []
    if np.any(~ok):
        notes.append(f"{int(np.sum(~ok))} points without phase, forcing or amplitude were skipped")
    if np.any(small):
        notes.append(
            f"{int(np.sum(small))} points with amplitude < "
            f"{rho_min_fraction:g} × max were skipped (eq. 6.15 divides by ρ)"
        )
    if int(np.sum(ok & ~small)) < 4:
        raise BifidInputError(
            f"need at least 4 usable forced-response points, got {int(np.sum(ok & ~small))}."
        )
    return ok & ~small, notes
