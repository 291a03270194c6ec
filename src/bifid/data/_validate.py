"""Checks that a dataset follows bifid's netCDF schema (see ``docs/data-formats.md``).

Every problem raises :class:`~bifid.errors.BifidInputError` naming the file, the variable,
what was expected and what was found. Validation runs on load and before every save, so
a dataset on disk is always one the rest of bifid can use without further checks.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import xarray as xr

from bifid.errors import BifidInputError

KINDS = ("lco", "forced")

# variable -> dims, for each kind
COMMON_VARS: dict[str, tuple[str, ...]] = {
    "n_samples": ("record",),
    "sample_rate": ("record",),
    "stable": ("record",),
    "signals": ("record", "time", "signal"),
    "control": ("record", "time"),
    "target": ("record", "time"),
    "control_rms": ("record",),
}
KIND_VARS: dict[str, dict[str, tuple[str, ...]]] = {
    "lco": {
        "param": ("record",),
        "frequency": ("record",),
        "amplitude": ("record", "signal"),
    },
    "forced": {
        "omega": ("record",),
        "forcing": ("record",),
        "amplitude": ("record",),
        "phase": ("record",),
        "force": ("record", "time"),
        "curve": ("record",),
    },
}
JSON_ATTRS = ("settings", "signal_units")
EXTRA_PREFIX = "extra_"


def _fail(where: str, msg: str) -> None:
    raise BifidInputError(f"{where}: {msg}")


def _numeric(where: str, ds: xr.Dataset, name: str) -> np.ndarray:
    values = ds[name].values
    if values.dtype.kind not in "biuf":
        _fail(where, f"variable {name!r} must be numeric, found dtype {values.dtype}.")
    return values.astype(float, copy=False)


def _valid_mask(n_samples: np.ndarray, n_time: int) -> np.ndarray:
    """(record, time) boolean mask of the samples inside each record's valid length."""
    return np.arange(n_time)[None, :] < n_samples[:, None]


def parse_json_attr(ds: xr.Dataset, name: str, where: str = "dataset") -> Any:
    """Decode a JSON-string attribute (``settings``, ``signal_units``); ``{}`` if absent."""
    raw = ds.attrs.get(name)
    if raw is None:
        return {}
    if isinstance(raw, bytes):
        raw = raw.decode("utf-8", errors="replace")
    if not isinstance(raw, str):
        _fail(where, f"attribute {name!r} must be a JSON string, found {type(raw).__name__}.")
    try:
        return json.loads(raw)
    except (json.JSONDecodeError, RecursionError) as exc:
        _fail(where, f"attribute {name!r} is not valid JSON ({exc}).")
    return None  # pragma: no cover


def validate_dataset(ds: xr.Dataset, where: str = "dataset") -> xr.Dataset:
    """Check ``ds`` against the schema and return a normalised copy.

    Normalisation: integer dtypes for ``n_samples``/``stable``/``curve``, and every sample
    past a record's ``n_samples`` set to NaN (so ``nanmax`` etc. are safe).

    Raises
    ------
    BifidInputError
        On any departure from the schema: unknown ``bifid_kind``, missing variables or
        dimensions, wrong shapes, non-finite values where values are required,
        ``n_samples`` outside ``1..len(time)``, ``sample_rate <= 0``, no records...
    """
    kind, names = _check_structure(ds, where)
    n_time = ds.sizes["time"]
    n_samples = _numeric(where, ds, "n_samples")
    if not np.all(np.isfinite(n_samples)) or np.any(n_samples != np.round(n_samples)):
        _fail(where, "n_samples must be integers.")
    if np.any(n_samples < 1) or np.any(n_samples > n_time):
        _fail(
            where,
            f"n_samples must lie in 1..{n_time} (the time length), "
            f"found {int(n_samples.min())}..{int(n_samples.max())}.",
        )
    n_samples = n_samples.astype(np.int64)
    mask = _valid_mask(n_samples, n_time)

    rate = _numeric(where, ds, "sample_rate")
    if not np.all(np.isfinite(rate)) or np.any(rate <= 0):
        _fail(where, "sample_rate must be finite and > 0 [Hz] for every record.")
    stable = _numeric(where, ds, "stable")
    if not np.all(np.isin(stable, (-1.0, 0.0, 1.0))):
        _fail(where, "stable must be 1 (stable), 0 (unstable) or -1 (unknown).")

    signals = _numeric(where, ds, "signals")
    bad = ~np.isfinite(signals) & mask[:, :, None]
    if np.any(bad):
        r = int(np.argwhere(bad)[0, 0])
        _fail(
            where,
            f"signals of record {r} contain NaN/inf within its n_samples "
            f"({int(bad.sum())} bad values in all).",
        )
    control = _numeric(where, ds, "control")
    if np.any(~np.isfinite(control) & mask):
        _fail(where, "control must be finite within each record (0 when there is no control).")
    target = _numeric(where, ds, "target")
    if np.any(np.isinf(target)):
        _fail(where, "target contains inf (use NaN for 'no target').")
    crms = _numeric(where, ds, "control_rms")
    if not np.all(np.isfinite(crms)) or np.any(crms < 0):
        _fail(where, "control_rms must be finite and >= 0.")

    if kind == "lco":
        _check_lco(ds, where)
    else:
        _check_forced(ds, where, names, mask)

    for attr in JSON_ATTRS:
        value = parse_json_attr(ds, attr, where)
        if attr == "signal_units" and not isinstance(value, dict):
            _fail(where, "attribute 'signal_units' must be a JSON object {signal: units}.")

    for name in ds.data_vars:
        if str(name).startswith(EXTRA_PREFIX):
            var = ds[name]
            if var.dims != ("record",) or var.dtype.kind not in "biufUSO":
                _fail(
                    where, f"extra variable {name!r} must be a numeric or string (record,) array."
                )

    out = ds.copy()
    out["n_samples"] = ("record", n_samples, dict(ds["n_samples"].attrs))
    out["stable"] = ("record", stable.astype(np.int8), dict(ds["stable"].attrs))
    nan_pad = ~mask
    for name in ("signals", "control", "target") + (("force",) if kind == "forced" else ()):
        values = _numeric(where, ds, name).copy()
        values[nan_pad] = np.nan  # broadcasts over the signal axis of `signals`
        out[name] = (ds[name].dims, values, dict(ds[name].attrs))
    if kind == "forced":
        out["curve"] = (
            "record",
            _numeric(where, ds, "curve").astype(np.int64),
            dict(ds["curve"].attrs),
        )
    return out


def _check_structure(ds: xr.Dataset, where: str) -> tuple[str, list[str]]:
    """The dataset kind and signal names, after checking dimensions and variables."""
    if not isinstance(ds, xr.Dataset):
        raise BifidInputError(f"{where}: expected an xarray.Dataset, got {type(ds).__name__}.")
    kind = ds.attrs.get("bifid_kind")
    if isinstance(kind, bytes):
        kind = kind.decode("utf-8", errors="replace")
    if kind is None:
        _fail(
            where,
            "not a bifid dataset (attribute 'bifid_kind' is missing); "
            "import raw measurements with `bifid import`.",
        )
    if not isinstance(kind, str) or kind not in KINDS:
        _fail(where, f"unknown bifid_kind {kind!r}; expected one of {', '.join(KINDS)}.")
    for dim in ("record", "time", "signal"):
        if dim not in ds.sizes:
            _fail(where, f"dimension {dim!r} is missing.")
    n_rec, n_time, n_sig = ds.sizes["record"], ds.sizes["time"], ds.sizes["signal"]
    if n_rec == 0:
        _fail(where, "the dataset holds no records.")
    if n_time == 0 or n_sig == 0:
        _fail(where, f"empty dimension (time={n_time}, signal={n_sig}).")
    if "signal" not in ds.coords or ds["signal"].dims != ("signal",):
        _fail(where, "coordinate 'signal' (signal names) is missing.")
    names = [str(s) for s in ds["signal"].values.tolist()]
    if any(not n for n in names) or len(set(names)) != len(names):
        _fail(where, f"signal names must be unique and non-empty, found {names}.")

    required = {**COMMON_VARS, **KIND_VARS[kind]}
    for name, dims in required.items():
        if name not in ds.variables:
            _fail(where, f"required variable {name!r} is missing (bifid_kind={kind!r}).")
        if ds[name].dims != dims:
            _fail(where, f"variable {name!r} must have dims {dims}, found {ds[name].dims}.")
    return kind, names


def _check_lco(ds: xr.Dataset, where: str) -> None:
    """Per-record variables of a limit-cycle dataset."""
    param = _numeric(where, ds, "param")
    if not np.all(np.isfinite(param)):
        _fail(where, "param must be finite for every record.")
    freq = _numeric(where, ds, "frequency")
    if np.any(np.isinf(freq)) or np.any(freq < 0):
        _fail(where, "frequency must be >= 0 rad/s (NaN when unknown).")
    amp = _numeric(where, ds, "amplitude")
    if not np.all(np.isfinite(amp)) or np.any(amp < 0):
        _fail(where, "amplitude must be finite and >= 0.")


def _check_forced(ds: xr.Dataset, where: str, names: list[str], mask: np.ndarray) -> None:
    """Per-record variables of a forced-response dataset."""
    omega = _numeric(where, ds, "omega")
    if not np.all(np.isfinite(omega)) or np.any(omega < 0):
        _fail(where, "omega must be finite and >= 0 rad/s.")
    forcing = _numeric(where, ds, "forcing")
    if not np.all(np.isfinite(forcing)):
        _fail(where, "forcing must be finite.")
    amp = _numeric(where, ds, "amplitude")
    if not np.all(np.isfinite(amp)) or np.any(amp < 0):
        _fail(where, "amplitude must be finite and >= 0.")
    phase = _numeric(where, ds, "phase")
    if np.any(np.isinf(phase)):
        _fail(where, "phase must be finite or NaN (unknown).")
    force = _numeric(where, ds, "force")
    fin = np.isfinite(force) & mask
    partial = np.any(fin, axis=1) & np.any(~np.isfinite(force) & mask, axis=1)
    if np.any(partial) or np.any(np.isinf(force)):
        _fail(where, "force must be finite over a record's samples, or all NaN when absent.")
    curve = _numeric(where, ds, "curve")
    if not np.all(np.isfinite(curve)) or np.any(curve != np.round(curve)):
        _fail(where, "curve must hold integer ids.")
    observed = ds.attrs.get("observed")
    if isinstance(observed, bytes):
        observed = observed.decode("utf-8", errors="replace")
    if not isinstance(observed, str) or observed not in names:
        _fail(where, f"attribute 'observed' must name a signal in {names}, found {observed!r}.")
