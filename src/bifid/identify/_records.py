"""Measured limit cycles as the identification methods train on them: :class:`LCOData`.

One type for every method that learns from limit cycles (mechanistic, thesis ch. 4; hybrid,
ch. 5), with the stability encoding of bifid's netCDF files: **1 stable, 0 unstable, −1
unknown**. It is built from whatever holds limit cycles (:func:`as_lco_data`):

* an ``xarray.Dataset`` of ``bifid_kind = "lco"`` (``docs/data-formats.md``), a path to
  such a netCDF file, or a list of them (records concatenated; signals must agree);
* a sequence of records: :class:`bifid.data.LCORecord` or tuples
  ``(param, signals (n, m), sample_rate, stable)`` with ``stable`` True, False or None;
* amplitudes alone (:meth:`LCOData.from_amplitudes`), e.g. read off a figure.

Amplitudes follow the convention of measured data (``DESIGN.md``): ``max_t |x − x̄|``
about the orbit's mean, taken on the record's least-squares Fourier series with
:data:`N_HARMONICS` harmonics at the frequency of its first signal
(:func:`bifid.signal.periodic_amplitude`) — measurement noise, which inflates a raw maximum
(by up to ~10 % on the unstable rig orbits), is filtered out.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from bifid.continuation import Branch, Diagram
from bifid.data import load_dataset
from bifid.errors import BifidInputError
from bifid.signal import estimate_frequency, periodic_amplitude

__all__ = ["N_HARMONICS", "STABLE", "UNKNOWN", "UNSTABLE", "LCOData", "as_lco_data"]

STABLE, UNSTABLE, UNKNOWN = 1, 0, -1
#: harmonics of the Fourier series whose maximum is a record's amplitude
N_HARMONICS = 7


def _stability(value: Any, where: str) -> int:
    if value is None:
        return UNKNOWN
    if isinstance(value, (bool, np.bool_)):
        return STABLE if value else UNSTABLE
    try:
        v = int(value)
    except (TypeError, ValueError):
        raise BifidInputError(
            f"{where}: stable must be True, False, None or 1/0/-1, got {value!r}."
        ) from None
    if v not in (STABLE, UNSTABLE, UNKNOWN):
        raise BifidInputError(
            f"{where}: stable must be 1 (stable), 0 (unstable) or -1 (unknown), got {v}."
        )
    return v


@dataclass(frozen=True, eq=False)
class LCOData:
    """Limit cycles measured at values of one parameter.

    Attributes
    ----------
    param : ndarray of shape (n,)
        Parameter value of each cycle.
    stable : ndarray of int, shape (n,)
        1 stable, 0 unstable, −1 unknown.
    signal_names : tuple of str
    amplitude : ndarray of shape (n, n_signals)
        ``max_t |x_s − x̄_s|`` of each signal (module docstring).
    frequency : ndarray of shape (n,)
        Angular frequency [rad/s]; NaN where unknown.
    signals : tuple of ndarray of shape (n_samples_i, n_signals)
        The sampled records (empty when only amplitudes are known).
    sample_rate : ndarray of shape (n,)
        [Hz]; NaN without records.
    param_name, param_units : str
    signal_units : dict of str
    source : str
    """

    param: np.ndarray
    stable: np.ndarray
    signal_names: tuple[str, ...]
    amplitude: np.ndarray
    frequency: np.ndarray
    signals: tuple[np.ndarray, ...] = ()
    sample_rate: np.ndarray | None = None
    param_name: str = "param"
    param_units: str = ""
    signal_units: Mapping[str, str] = field(default_factory=dict)
    source: str = ""

    def __post_init__(self) -> None:
        param = np.asarray(self.param, dtype=float).reshape(-1)
        n = param.shape[0]
        names = tuple(str(s) for s in self.signal_names)
        amp = np.asarray(self.amplitude, dtype=float).reshape(n, -1)
        stable = np.array(
            [
                _stability(s, f"cycle {i}")
                for i, s in enumerate(np.asarray(self.stable).reshape(-1))
            ],
            dtype=int,
        )
        freq = np.asarray(self.frequency, dtype=float).reshape(-1)
        rate = (
            np.full(n, np.nan)
            if self.sample_rate is None
            else np.asarray(self.sample_rate, dtype=float).reshape(-1)
        )
        if n == 0:
            raise BifidInputError("LCOData needs at least one limit cycle.")
        if amp.shape[1] != len(names):
            raise BifidInputError(
                f"amplitude has {amp.shape[1]} columns but {len(names)} signal names were given."
            )
        if stable.shape != (n,) or freq.shape != (n,) or rate.shape != (n,):
            raise BifidInputError("stable, frequency and sample_rate need one entry per cycle.")
        if not (np.all(np.isfinite(param)) and np.all(np.isfinite(amp))):
            raise BifidInputError("cycle parameters and amplitudes must be finite.")
        if np.any(amp < 0):
            raise BifidInputError("cycle amplitudes must be >= 0.")
        if self.signals and len(self.signals) != n:
            raise BifidInputError(f"{len(self.signals)} records for {n} cycles.")
        for k, v in (
            ("param", param),
            ("stable", stable),
            ("amplitude", amp),
            ("frequency", freq),
            ("sample_rate", rate),
            ("signal_names", names),
            ("signal_units", dict(self.signal_units)),
        ):
            object.__setattr__(self, k, v)

    def __len__(self) -> int:
        return int(self.param.shape[0])

    # -------------------------------------------------------------------- builders
    @classmethod
    def from_amplitudes(
        cls,
        param: Sequence[float],
        amplitude: Any,
        stable: Sequence[int | bool | None],
        signal_names: Sequence[str],
        *,
        frequency: Sequence[float] | None = None,
        param_name: str = "param",
    ) -> LCOData:
        """Cycles known by their amplitudes only (no records)."""
        n = len(np.atleast_1d(np.asarray(param)))
        return cls(
            param=np.atleast_1d(np.asarray(param, dtype=float)),
            stable=np.atleast_1d(np.asarray(stable, dtype=object)),
            signal_names=tuple(signal_names),
            amplitude=amplitude,
            frequency=np.full(n, np.nan) if frequency is None else frequency,
            param_name=param_name,
        )

    @classmethod
    def from_records(
        cls,
        records: Sequence[Any],
        signal_names: Sequence[str] | None = None,
        *,
        param_name: str = "param",
        param_units: str = "",
        signal_units: Mapping[str, str] | None = None,
        source: str = "",
    ) -> LCOData:
        """Cycles from records (:class:`bifid.data.LCORecord` or ``(param, signals,
        sample_rate, stable)`` tuples); amplitudes and frequencies from the records."""
        params, sigs, rates, stable = [], [], [], []
        for i, rec in enumerate(records):
            if hasattr(rec, "signals") and hasattr(rec, "param"):
                p, s, fs, st = rec.param, rec.signals, rec.sample_rate, getattr(rec, "stable", None)
            elif isinstance(rec, (tuple, list)) and len(rec) == 4:
                p, s, fs, st = rec
            else:
                raise BifidInputError(
                    f"Record {i}: expected an LCORecord or a tuple (param, signals (n, m), "
                    f"sample_rate, stable); got {type(rec).__name__}."
                )
            s = np.asarray(s, dtype=float)
            if s.ndim != 2 or s.shape[0] < 16:
                raise BifidInputError(
                    f"Record {i}: signals must have shape (n_samples >= 16, n_signals); got "
                    f"{s.shape}."
                )
            if not np.all(np.isfinite(s)):
                raise BifidInputError(f"Record {i}: signals contain NaN or inf.")
            try:
                p, fs = float(p), float(fs)
            except (TypeError, ValueError):
                raise BifidInputError(
                    f"Record {i}: param and sample_rate must be numbers."
                ) from None
            if not math.isfinite(p):
                raise BifidInputError(f"Record {i}: param must be finite, got {p!r}.")
            if not (math.isfinite(fs) and fs > 0):
                raise BifidInputError(f"Record {i}: sample_rate must be > 0 [Hz], got {fs!r}.")
            params.append(p)
            sigs.append(s)
            rates.append(fs)
            stable.append(_stability(st, f"Record {i}"))
        if not params:
            raise BifidInputError("no limit-cycle records were given.")
        widths = {s.shape[1] for s in sigs}
        if len(widths) != 1:
            raise BifidInputError(
                f"All records must have the same number of signals; got {sorted(widths)}."
            )
        m = widths.pop()
        names = (
            tuple(signal_names)
            if signal_names is not None
            else tuple(f"z{k + 1}" for k in range(m))
        )
        if len(names) != m:
            raise BifidInputError(f"{len(names)} signal names given for {m} signals.")
        amp, freq = _measure(sigs, rates)
        return cls(
            param=np.asarray(params),
            stable=np.asarray(stable),
            signal_names=names,
            amplitude=amp,
            frequency=freq,
            signals=tuple(sigs),
            sample_rate=np.asarray(rates),
            param_name=param_name,
            param_units=param_units,
            signal_units=dict(signal_units or {}),
            source=source,
        )

    @classmethod
    def from_dataset(cls, ds: Any) -> LCOData:
        """Cycles from an ``"lco"`` dataset (:mod:`bifid.data`).

        Raises
        ------
        BifidInputError
            If the dataset is not of kind ``lco`` or lacks a variable.
        """
        kind = ds.attrs.get("bifid_kind")
        if kind != "lco":
            raise BifidInputError(
                f"expected a limit-cycle dataset (bifid_kind='lco'), got bifid_kind={kind!r}; "
                "forced responses train `bifid fit forced`."
            )
        for var in ("param", "signals", "sample_rate"):
            if var not in ds:
                raise BifidInputError(f"the LCO dataset lacks the variable {var!r}.")
        names = tuple(str(s) for s in ds["signal"].values)
        sig = np.asarray(ds["signals"].transpose("record", "time", "signal").values, dtype=float)
        n_valid = (
            np.asarray(ds["n_samples"].values, dtype=int)
            if "n_samples" in ds
            else np.full(sig.shape[0], sig.shape[1])
        )
        stable = ds["stable"].values if "stable" in ds else np.full(sig.shape[0], UNKNOWN)
        records = [
            (
                float(ds["param"].values[i]),
                sig[i, : n_valid[i]],
                float(ds["sample_rate"].values[i]),
                int(stable[i]),
            )
            for i in range(sig.shape[0])
        ]
        units = ds.attrs.get("signal_units", "{}")
        try:
            units = json.loads(units) if isinstance(units, str) else dict(units)
        except (ValueError, TypeError):
            units = {}
        return cls.from_records(
            records,
            names,
            param_name=str(ds["param"].attrs.get("name", ds.attrs.get("param_name", "param"))),
            param_units=str(ds["param"].attrs.get("units", "")),
            signal_units={str(k): str(v) for k, v in units.items()},
            source=str(ds.attrs.get("source", "")),
        )

    # ------------------------------------------------------------------ selections
    @property
    def has_records(self) -> bool:
        """Whether the sampled records are held (not only amplitudes)."""
        return bool(self.signals)

    def select(self, keep: Any) -> LCOData:
        """The cycles ``keep`` (boolean mask or indices), in that order."""
        idx = np.arange(len(self))[np.asarray(keep)]
        return replace(
            self,
            param=self.param[idx],
            stable=self.stable[idx],
            amplitude=self.amplitude[idx],
            frequency=self.frequency[idx],
            signals=tuple(self.signals[i] for i in idx) if self.signals else (),
            sample_rate=self.sample_rate[idx],
        )

    def column(self, name: str) -> np.ndarray:
        """Amplitudes of one signal."""
        return self.amplitude[:, self.index(name)]

    def index(self, name: str) -> int:
        """Column of a signal."""
        if name not in self.signal_names:
            raise BifidInputError(
                f"signal {name!r} is not in the data ({', '.join(self.signal_names)})."
            )
        return self.signal_names.index(name)

    def diagram(self) -> Diagram:
        """The cycles as a measured :class:`~bifid.continuation.Diagram` (one branch of kind
        ``measured``, for overlays on predicted diagrams)."""
        n = len(self)
        branch = Branch(
            kind="measured",
            system=self.source or "data",
            param=self.param_name,
            params=self.param,
            solutions=np.zeros((n, 0)),
            stable=np.where(self.stable < 0, np.nan, self.stable.astype(float)),
            special_points=[],
            data={"amplitude": self.amplitude, "frequency": self.frequency},
            p=np.zeros(0),
            status="completed",
            message="",
            signals=self.signal_names,
        )
        return Diagram(
            kind="bifurcation",
            system=self.source or "data",
            param=self.param_name,
            branches=[branch],
            source="measurement",
            units={self.param_name: self.param_units, **self.signal_units},
        )

    def concat(self, other: LCOData) -> LCOData:
        """The cycles of both (same signals and parameter)."""
        if other.signal_names != self.signal_names:
            raise BifidInputError(
                f"Datasets have different signals: {self.signal_names} vs {other.signal_names}."
            )
        if other.param_name != self.param_name:
            raise BifidInputError(
                "Datasets have different bifurcation parameters: "
                f"{self.param_name!r} and {other.param_name!r}."
            )
        if self.has_records != other.has_records:
            raise BifidInputError("cannot combine cycles with records and amplitudes only.")
        return replace(
            self,
            param=np.concatenate([self.param, other.param]),
            stable=np.concatenate([self.stable, other.stable]),
            amplitude=np.concatenate([self.amplitude, other.amplitude]),
            frequency=np.concatenate([self.frequency, other.frequency]),
            signals=self.signals + other.signals,
            sample_rate=np.concatenate([self.sample_rate, other.sample_rate]),
            source="; ".join(s for s in (self.source, other.source) if s),
        )


def _measure(signals: Sequence[np.ndarray], rates: Sequence[float]) -> tuple[np.ndarray, ...]:
    """Amplitudes (module docstring) and frequencies of records (a record without a
    frequency, e.g. a constant one, keeps its raw ``max |x − x̄|``)."""
    amps, freqs = [], []
    for s, fs in zip(signals, rates, strict=True):
        w = estimate_frequency(s[:, 0], fs)
        if math.isfinite(w) and w > 0:
            amps.append(
                [
                    periodic_amplitude(s[:, c], w, fs, N_HARMONICS, trim=False)[0]
                    for c in range(s.shape[1])
                ]
            )
        else:
            amps.append(np.max(np.abs(s - s.mean(axis=0)), axis=0))
        freqs.append(w)
    return np.asarray(amps, dtype=float), np.asarray(freqs, dtype=float)


def as_lco_data(data: Any, signal_names: Sequence[str] | None = None) -> LCOData:
    """:class:`LCOData` from any accepted input (module docstring).

    Raises
    ------
    BifidInputError
        On an unsupported type, a dataset of another kind, malformed records or datasets
        whose signals or parameters differ.
    """
    if isinstance(data, LCOData):
        return data
    if isinstance(data, (str, Path)):
        return LCOData.from_dataset(load_dataset(data))
    if hasattr(data, "attrs") and hasattr(data, "data_vars"):
        return LCOData.from_dataset(data)
    if isinstance(data, Sequence) and len(data) > 0:
        first = data[0]
        if isinstance(first, (str, Path, LCOData)) or (
            hasattr(first, "attrs") and hasattr(first, "data_vars")
        ):
            parts = [as_lco_data(d) for d in data]
            out = parts[0]
            for p in parts[1:]:
                out = out.concat(p)
            return out
        return LCOData.from_records(data, signal_names)
    raise BifidInputError(
        "Limit-cycle data must be an LCO dataset (xarray or .nc path), a list of them, or a "
        f"list of records (param, signals, sample_rate, stable); got {type(data).__name__}."
    )
