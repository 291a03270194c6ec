"""Training data of the hybrid Hopf model: limit-cycle records from any accepted source.

Accepted inputs (each validated, with a message saying what was expected):

* an ``xarray.Dataset`` of ``bifid_kind = "lco"`` (schema in ``notes/HELPERS.md``), or a path to
  such a netCDF file, or a list of them (concatenated; signal names must agree);
* a sequence of records, each either an object with attributes ``param``, ``signals``
  (``(n_samples, n_signals)``), ``sample_rate`` and ``stable`` (``bifid.data.LCORecord``), or a
  tuple ``(param, signals, sample_rate, stable)``; ``stable`` is ``True``, ``False`` or ``None``
  (unknown).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bifid.errors import BifidInputError
from bifid.identify._hopf_normal_form import STABLE, UNKNOWN, UNSTABLE


@dataclass
class LCOData:
    """Limit-cycle records, validated.

    Attributes
    ----------
    params : ndarray of shape (n_records,)
    signals : list of ndarray of shape (n_samples_i, n_signals)
    sample_rates : ndarray of shape (n_records,) [Hz]
    branch : ndarray of int of shape (n_records,)
        +1 stable, -1 unstable, 0 unknown.
    signal_names : tuple of str
    param_name, param_units : str
    signal_units : dict
    """

    params: np.ndarray
    signals: list[np.ndarray]
    sample_rates: np.ndarray
    branch: np.ndarray
    signal_names: tuple[str, ...]
    param_name: str = "mu"
    param_units: str = ""
    signal_units: dict[str, str] = field(default_factory=dict)
    source: str = ""

    @property
    def n_records(self) -> int:
        return len(self.params)

    def subset(self, keep: np.ndarray) -> LCOData:
        """Records ``keep`` (indices or boolean mask)."""
        idx = np.arange(self.n_records)[keep]
        return LCOData(
            params=self.params[idx],
            signals=[self.signals[i] for i in idx],
            sample_rates=self.sample_rates[idx],
            branch=self.branch[idx],
            signal_names=self.signal_names,
            param_name=self.param_name,
            param_units=self.param_units,
            signal_units=dict(self.signal_units),
            source=self.source,
        )


def _branch_code(stable: Any) -> int:
    if stable is None:
        return UNKNOWN
    if isinstance(stable, (bool, np.bool_)):
        return STABLE if stable else UNSTABLE
    try:
        v = int(stable)
    except (TypeError, ValueError):
        raise BifidInputError(
            f"stable must be True, False, None or 1/0/-1, got {stable!r}."
        ) from None
    if v not in (1, 0, -1):
        raise BifidInputError(f"stable must be 1 (stable), 0 (unstable) or -1 (unknown), got {v}.")
    return {1: STABLE, 0: UNSTABLE, -1: UNKNOWN}[v]


def _from_dataset(ds: Any) -> LCOData:
    kind = ds.attrs.get("bifid_kind")
    if kind != "lco":
        raise BifidInputError(
            f"The hybrid Hopf model trains on limit-cycle datasets (bifid_kind='lco'); "
            f"got bifid_kind={kind!r}. Use `bifid fit forced` for forced responses."
        )
    for var in ("param", "signals", "sample_rate"):
        if var not in ds:
            raise BifidInputError(f"LCO dataset lacks the variable {var!r}.")
    names = tuple(str(s) for s in ds["signal"].values)
    sig = np.asarray(ds["signals"].transpose("record", "time", "signal").values, dtype=float)
    n_valid = (
        np.asarray(ds["n_samples"].values, dtype=int)
        if "n_samples" in ds
        else np.full(sig.shape[0], sig.shape[1])
    )
    stable = ds["stable"].values if "stable" in ds else np.full(sig.shape[0], -1)
    records = []
    for i in range(sig.shape[0]):
        code = int(stable[i])
        records.append(
            (
                float(ds["param"].values[i]),
                sig[i, : n_valid[i]],
                float(ds["sample_rate"].values[i]),
                None if code == -1 else bool(code == 1),
            )
        )
    import json

    units = ds.attrs.get("signal_units", "{}")
    try:
        units = json.loads(units) if isinstance(units, str) else dict(units)
    except (ValueError, TypeError):
        units = {}
    data = _from_records(records, names)
    data.param_name = str(ds["param"].attrs.get("name", "mu"))
    data.param_units = str(ds["param"].attrs.get("units", ""))
    data.signal_units = {str(k): str(v) for k, v in units.items()}
    data.source = str(ds.attrs.get("source", ""))
    return data


def _load_path(path: str | Path) -> Any:
    path = Path(path)
    if not path.exists():
        raise BifidInputError(f"Dataset file {str(path)!r} does not exist.")
    try:
        from bifid.data import load_dataset  # type: ignore[attr-defined]
    except ImportError:  # the data module is not available: read the schema directly
        import xarray as xr

        try:
            with xr.open_dataset(path, engine="h5netcdf") as ds:
                return ds.load()
        except (OSError, ValueError) as exc:
            raise BifidInputError(f"Cannot read {str(path)!r} as a netCDF dataset: {exc}") from None
    return load_dataset(path)


def _from_records(records: Sequence[Any], signal_names: Sequence[str] | None) -> LCOData:
    params, signals, rates, branch = [], [], [], []
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
        if s.ndim == 1:
            raise BifidInputError(
                f"Record {i}: signals must have shape (n_samples, n_signals >= 2) so that a "
                f"plane of two signals can be formed; got shape {s.shape}."
            )
        if s.ndim != 2 or s.shape[1] < 2 or s.shape[0] < 16:
            raise BifidInputError(
                f"Record {i}: signals must have shape (n_samples >= 16, n_signals >= 2); "
                f"got {s.shape}."
            )
        if not np.all(np.isfinite(s)):
            raise BifidInputError(f"Record {i}: signals contain NaN or inf.")
        try:
            p, fs = float(p), float(fs)
        except (TypeError, ValueError):
            raise BifidInputError(f"Record {i}: param and sample_rate must be numbers.") from None
        if not math.isfinite(p):
            raise BifidInputError(f"Record {i}: param must be finite, got {p!r}.")
        if not (math.isfinite(fs) and fs > 0):
            raise BifidInputError(f"Record {i}: sample_rate must be > 0 [Hz], got {fs!r}.")
        params.append(p)
        signals.append(s)
        rates.append(fs)
        branch.append(_branch_code(st))
    if len(params) < 2:
        raise BifidInputError(
            f"The hybrid Hopf model needs at least 2 limit-cycle records; got {len(params)}."
        )
    n_sig = {s.shape[1] for s in signals}
    if len(n_sig) != 1:
        raise BifidInputError(f"All records must have the same number of signals; got {n_sig}.")
    m = n_sig.pop()
    names = (
        tuple(signal_names) if signal_names is not None else tuple(f"z{k + 1}" for k in range(m))
    )
    if len(names) != m:
        raise BifidInputError(f"{len(names)} signal names given for {m} signals.")
    return LCOData(
        params=np.asarray(params),
        signals=signals,
        sample_rates=np.asarray(rates),
        branch=np.asarray(branch, dtype=int),
        signal_names=names,
    )


def as_lco_data(data: Any, signal_names: Sequence[str] | None = None) -> LCOData:
    """Convert any accepted input (see module docstring) into :class:`LCOData`.

    Raises
    ------
    BifidInputError
        On an unsupported type, a non-LCO dataset, malformed records or mismatched signals.
    """
    if isinstance(data, LCOData):
        return data
    if isinstance(data, (str, Path)):
        return as_lco_data(_load_path(data), signal_names)
    if hasattr(data, "attrs") and hasattr(data, "data_vars"):
        return _from_dataset(data)
    if isinstance(data, Sequence) and len(data) > 0:
        first = data[0]
        if isinstance(first, (str, Path)) or (
            hasattr(first, "attrs") and hasattr(first, "data_vars")
        ):
            parts = [as_lco_data(d) for d in data]
            names = parts[0].signal_names
            for p in parts[1:]:
                if p.signal_names != names:
                    raise BifidInputError(
                        f"Datasets have different signals: {names} vs {p.signal_names}."
                    )
            if len({p.param_name for p in parts}) != 1:
                raise BifidInputError(
                    "Datasets have different bifurcation parameters: "
                    f"{sorted({p.param_name for p in parts})}."
                )
            return LCOData(
                params=np.concatenate([p.params for p in parts]),
                signals=[s for p in parts for s in p.signals],
                sample_rates=np.concatenate([p.sample_rates for p in parts]),
                branch=np.concatenate([p.branch for p in parts]),
                signal_names=names,
                param_name=parts[0].param_name,
                param_units=parts[0].param_units,
                signal_units=parts[0].signal_units,
                source="; ".join(p.source for p in parts if p.source),
            )
        return _from_records(data, signal_names)
    raise BifidInputError(
        "Training data must be an LCO dataset (xarray or .nc path), a list of them, or a list "
        f"of records (param, signals, sample_rate, stable); got {type(data).__name__}."
    )
