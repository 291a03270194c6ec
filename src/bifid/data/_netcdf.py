"""Datasets: build from records, save/load as netCDF (h5netcdf), combine.

Schema (details in ``docs/data-formats.md``): dims ``record``, ``time``, ``signal``;
records shorter than the longest are NaN-padded along ``time`` and ``n_samples`` gives
each valid length. ``bifid_kind`` ("lco" | "forced") selects the kind-specific variables.
Appending records to a file: :mod:`bifid.data._append`.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from bifid.data._growable import GROWING, growable_image
from bifid.data._hdf5check import check_self_contained
from bifid.data._iterate import forced_records, lco_records
from bifid.data._records import ForcedRecord, LCORecord
from bifid.data._validate import EXTRA_PREFIX, parse_json_attr, validate_dataset
from bifid.errors import BifidInputError
from bifid.io import atomic_write_bytes, check_input_file, jsonable
from bifid.signal import phase_lag

__all__ = [
    "combine_datasets",
    "forced_dataset",
    "lco_dataset",
    "load_dataset",
    "save_dataset",
]

# refuse to load more than this into memory (hostile files can declare huge dimensions)
MAX_DATASET_BYTES = int(os.environ.get("BIFID_MAX_DATASET_BYTES", 4 * 1024**3))
TIME_CHUNK = 16384  # samples per chunk of a sampled signal (128 KiB of float64)
RECORD_CHUNK = 256  # records per chunk of the per-record variables
_RESERVED_ATTRS = {
    "bifid_kind",
    "system",
    "source",
    "settings",
    "bifid_version",
    "created",
    "signal_units",
    "observed",
    "forcing_units",
    "param_name",
    "param_units",
}


def _settings_json(settings: Mapping[str, Any] | str | None) -> str:
    if settings is None:
        return "{}"
    if isinstance(settings, str):
        try:
            json.loads(settings)
        except json.JSONDecodeError:
            raise BifidInputError("settings given as a string must be valid JSON.") from None
        return settings
    if not isinstance(settings, Mapping):
        raise BifidInputError(f"settings must be a dict, got {type(settings).__name__}.")
    try:
        return json.dumps(jsonable(dict(settings)))
    except BifidInputError:
        return json.dumps(dict(settings), default=str)


def _signal_names(signal_names: Sequence[str], n_signals: int) -> list[str]:
    if isinstance(signal_names, str):
        signal_names = [signal_names]
    names = [str(s) for s in signal_names]
    if len(names) != n_signals:
        raise BifidInputError(
            f"{len(names)} signal names {names} given for records with {n_signals} signals."
        )
    if any(not n.strip() for n in names) or len(set(names)) != len(names):
        raise BifidInputError(f"signal names must be unique and non-empty, got {names}.")
    return names


def _units(signal_units: Mapping[str, str] | None, names: list[str]) -> dict[str, str]:
    units = {n: "" for n in names}
    for k, v in dict(signal_units or {}).items():
        if k not in units:
            raise BifidInputError(f"signal_units names {k!r}, which is not a signal of {names}.")
        units[k] = str(v)
    return units


def _pad(rows: list[np.ndarray | None], n_time: int) -> np.ndarray:
    """Stack 1-D rows into (n_rows, n_time), NaN-padded; a ``None`` row is all NaN."""
    out = np.full((len(rows), n_time), np.nan)
    for i, row in enumerate(rows):
        if row is not None:
            out[i, : row.shape[0]] = row
    return out


def _rms(x: np.ndarray) -> float:
    """Root mean square without overflow for values near the float64 limit."""
    scale = float(np.max(np.abs(x))) if x.size else 0.0
    if scale == 0.0:
        return 0.0
    return scale * float(np.sqrt(np.mean((x / scale) ** 2)))


def _common(records: Sequence[LCORecord | ForcedRecord], names: list[str]) -> dict[str, Any]:
    n_time = max(r.n_samples for r in records)
    n_sig = len(names)
    sig = np.full((len(records), n_time, n_sig), np.nan)
    control = np.full((len(records), n_time), np.nan)
    target = np.full((len(records), n_time), np.nan)
    crms = np.zeros(len(records))
    for i, r in enumerate(records):
        n = r.n_samples
        sig[i, :n] = r.signals
        c = r.control if r.control is not None else np.zeros(n)
        control[i, :n] = c
        crms[i] = _rms(c)
        if r.target is not None:
            target[i, :n] = r.target
    stable = np.array([-1 if r.stable is None else int(r.stable) for r in records], dtype=np.int8)
    return {
        "n_samples": (
            ("record",),
            np.array([r.n_samples for r in records], dtype=np.int64),
            {"long_name": "number of valid samples"},
        ),
        "sample_rate": (("record",), np.array([r.sample_rate for r in records]), {"units": "Hz"}),
        "stable": (
            ("record",),
            stable,
            {"long_name": "stability", "flag_values": "1 stable, 0 unstable, -1 unknown"},
        ),
        "signals": (("record", "time", "signal"), sig, {"long_name": "measured outputs (centred)"}),
        "control": (("record", "time"), control, {"long_name": "control signal (0 when none)"}),
        "target": (("record", "time"), target, {"long_name": "control target (NaN when none)"}),
        "control_rms": (("record",), crms, {"long_name": "RMS of the control signal"}),
    }


def _extras(records: Sequence[LCORecord | ForcedRecord]) -> dict[str, Any]:
    keys: list[str] = []
    for r in records:
        keys.extend(k for k in r.extra if k not in keys)
    out: dict[str, Any] = {}
    for k in keys:
        values = [r.extra.get(k) for r in records]
        if any(isinstance(v, str) for v in values):
            arr = np.array(["" if v is None else str(v) for v in values], dtype=object)
        else:
            arr = np.array([np.nan if v is None else float(v) for v in values])
        out[EXTRA_PREFIX + k] = (("record",), arr, {})
    return out


def _attrs(
    kind: str,
    system: str,
    settings: Any,
    source: str | Sequence[str],
    units: dict[str, str],
    attrs: Mapping[str, Any] | None,
) -> dict[str, Any]:
    from bifid import __version__

    if not isinstance(source, str):
        source = json.dumps([str(s) for s in source])
    out: dict[str, Any] = {
        "bifid_kind": kind,
        "system": str(system),
        "source": str(source),
        "settings": _settings_json(settings),
        "bifid_version": __version__,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "signal_units": json.dumps(units),
    }
    for k, v in dict(attrs or {}).items():
        if k in _RESERVED_ATTRS:
            raise BifidInputError(f"attribute {k!r} is set by the builder; pass it as an argument.")
        out[str(k)] = v if isinstance(v, (str, int, float)) else json.dumps(jsonable(v))
    return out


def _assemble(
    kind: str,
    data: dict[str, Any],
    recs: Sequence[LCORecord | ForcedRecord],
    names: list[str],
    attrs: dict[str, Any],
    own: Mapping[str, str],
) -> xr.Dataset:
    """The validated dataset of ``kind``: the variables ``data`` and the records' extras on
    the ``record`` and ``signal`` coordinates, with ``attrs`` (:func:`_attrs`) and the
    builder's ``own`` attributes."""
    data.update(_extras(recs))
    ds = xr.Dataset(
        data,
        coords={"record": np.arange(len(recs)), "signal": np.array(names, dtype=object)},
        attrs=attrs,
    )
    ds.attrs.update(own)
    return validate_dataset(ds, f"{kind}_dataset")


def _check_records(records: Iterable[Any], cls: type) -> list[Any]:
    recs = list(records)
    if not recs:
        raise BifidInputError("no records given: a dataset needs at least one record.")
    for i, r in enumerate(recs):
        if not isinstance(r, cls):
            raise BifidInputError(
                f"record {i} is a {type(r).__name__}; this dataset kind takes {cls.__name__}."
            )
    n_sig = {r.signals.shape[1] for r in recs}
    if len(n_sig) != 1:
        raise BifidInputError(f"records have different numbers of signals: {sorted(n_sig)}.")
    return recs


def lco_dataset(
    records: Iterable[LCORecord],
    signal_names: Sequence[str],
    param_name: str = "param",
    param_units: str = "",
    system: str = "experiment",
    settings: Mapping[str, Any] | str | None = None,
    source: str | Sequence[str] = "",
    *,
    signal_units: Mapping[str, str] | None = None,
    attrs: Mapping[str, Any] | None = None,
) -> xr.Dataset:
    """Build an ``"lco"`` dataset (limit cycles of an autonomous system).

    Parameters
    ----------
    records
        :class:`LCORecord` values, all with the same number of signals.
    signal_names
        One name per signal column (e.g. ``["h", "alpha"]``).
    param_name, param_units
        Name and units of the bifurcation parameter (e.g. ``"U"``, ``"m/s"``).
    system
        Registry name of the simulated system, or ``"experiment"``.
    settings
        Everything that generated the data (stored as a JSON string).
    source
        Where the data came from (file names, rig, protocol).
    signal_units
        ``{signal: units}``.
    attrs
        Further dataset attributes.

    Returns
    -------
    xarray.Dataset
        With ``amplitude[r, s] = max_t |x_s(t)|`` (thesis eq. 6.5) and ``control_rms``
        computed from the records; validated.
    """
    recs = _check_records(records, LCORecord)
    names = _signal_names(signal_names, recs[0].signals.shape[1])
    units = _units(signal_units, names)
    data = _common(recs, names)
    data["param"] = (
        ("record",),
        np.array([r.param for r in recs]),
        {"name": str(param_name), "units": str(param_units)},
    )
    data["frequency"] = (
        ("record",),
        np.array([r.frequency for r in recs]),
        {"units": "rad/s", "long_name": "angular frequency of the orbit"},
    )
    data["amplitude"] = (
        ("record", "signal"),
        np.stack([r.amplitude for r in recs]),
        {"long_name": "max_t |x(t)| of the centred signals"},
    )
    own = {"param_name": str(param_name), "param_units": str(param_units)}
    return _assemble(
        "lco", data, recs, names, _attrs("lco", system, settings, source, units, attrs), own
    )


def forced_dataset(
    records: Iterable[ForcedRecord],
    signal_names: Sequence[str],
    observed: str | None = None,
    system: str = "experiment",
    settings: Mapping[str, Any] | str | None = None,
    source: str | Sequence[str] = "",
    *,
    signal_units: Mapping[str, str] | None = None,
    forcing_units: str = "",
    attrs: Mapping[str, Any] | None = None,
) -> xr.Dataset:
    """Build a ``"forced"`` dataset (steady responses to harmonic forcing).

    ``amplitude`` is the record's own value when given, else ``max_t |x_obs(t)|`` of the
    observed signal; ``phase`` is the record's value when given, else the lag of the
    observed first harmonic behind the force's (:func:`bifid.signal.phase_lag`) when a
    ``force`` series is present, else NaN. ``observed`` defaults to the first signal.
    """
    recs = _check_records(records, ForcedRecord)
    names = _signal_names(signal_names, recs[0].signals.shape[1])
    observed = names[0] if observed is None else str(observed)
    if observed not in names:
        raise BifidInputError(f"observed signal {observed!r} is not one of {names}.")
    j = names.index(observed)
    units = _units(signal_units, names)
    data = _common(recs, names)
    n_time = max(r.n_samples for r in recs)
    amp = np.array(
        [r.amplitude if r.amplitude is not None else np.max(np.abs(r.signals[:, j])) for r in recs]
    )
    phase = np.array(
        [
            r.phase
            if r.phase is not None
            else (
                phase_lag(r.signals[:, j], r.force, r.omega, r.sample_rate)
                if r.force is not None and r.omega > 0
                else np.nan
            )
            for r in recs
        ]
    )
    data["omega"] = (
        ("record",),
        np.array([r.omega for r in recs]),
        {"units": "rad/s", "long_name": "forcing frequency"},
    )
    data["forcing"] = (
        ("record",),
        np.array([r.forcing for r in recs]),
        {"units": str(forcing_units), "long_name": "forcing amplitude"},
    )
    data["amplitude"] = (
        ("record",),
        amp,
        {"units": units[observed], "long_name": f"max_t |{observed}(t)|"},
    )
    data["phase"] = (
        ("record",),
        phase,
        {
            "units": "rad",
            "long_name": "lag of the observed first harmonic behind the force, in [-pi/2, 3pi/2)",
        },
    )
    data["force"] = (
        ("record", "time"),
        _pad([r.force for r in recs], n_time),
        {"units": str(forcing_units), "long_name": "forcing signal (NaN if absent)"},
    )
    data["curve"] = (
        ("record",),
        np.array([r.curve for r in recs], dtype=np.int64),
        {"long_name": "id of the curve (S-curve, FRC, backbone) of each point"},
    )
    own = {"observed": observed, "forcing_units": str(forcing_units)}
    return _assemble(
        "forced", data, recs, names, _attrs("forced", system, settings, source, units, attrs), own
    )


# ---------------------------------------------------------------------------------------------
# file IO
# ---------------------------------------------------------------------------------------------


def _chunks(var: xr.Variable) -> tuple[int, ...]:
    """Chunk shape of a per-record variable: one record of a sampled signal (a power of two
    from ``TIME_CHUNK / 4`` to ``TIME_CHUNK`` samples: records appended later may be
    longer), or ``RECORD_CHUNK`` records of the others."""
    if "time" not in var.dims:
        return tuple(RECORD_CHUNK if d == "record" else var.sizes[d] for d in var.dims)
    n_time = min(TIME_CHUNK, max(TIME_CHUNK // 4, 1 << (var.sizes["time"] - 1).bit_length()))
    return tuple(n_time if d == "time" else 1 for d in var.dims)


def save_dataset(ds: xr.Dataset, path: str | os.PathLike[str]) -> Path:
    """Validate ``ds`` and write it to ``path`` as netCDF-4 (h5netcdf), atomically.

    The file is built in memory and appears only once complete (temporary file +
    :func:`os.replace`, :func:`bifid.io.atomic_write_bytes`); on any failure, a full disk
    included, the previous file, if any, is untouched. Sampled signals are compressed
    (deflate level 1 after the byte-shuffle filter, both standard netCDF-4: on noisy
    float64 records shuffling makes deflate 1.7x faster and the file 13 % smaller), in
    chunks of one record and at most ``TIME_CHUNK`` samples of one signal; ``record`` and
    ``time`` can be extended (:mod:`bifid.data._growable`), so
    :func:`bifid.data.append_records` adds records without rewriting the others.
    """
    ds = validate_dataset(ds, "save_dataset")
    path = Path(path)
    encoding: dict[str, dict[str, Any]] = {}
    for name, var in ds.variables.items():
        if "record" not in var.dims:
            continue
        encoding[name] = {"chunksizes": _chunks(var)}
        if var.dtype.kind == "f" and var.ndim >= 2:
            encoding[name].update(zlib=True, complevel=1, shuffle=True)
    image = ds.to_netcdf(None, engine="h5netcdf", encoding=encoding, unlimited_dims=GROWING)
    atomic_write_bytes(path, growable_image(image))
    return path


def load_dataset(path: str | os.PathLike[str]) -> xr.Dataset:
    """Load and validate a bifid dataset.

    The file is read with h5netcdf (HDF5 through h5py: no code in the file is ever
    executed) into memory and closed. Files that take data from outside themselves
    (external storage, virtual datasets, external links) are refused before they are
    opened (:func:`~bifid.data._hdf5check.check_self_contained`).

    Raises
    ------
    BifidInputError
        If the file is missing, is not netCDF-4/HDF5, or departs from the schema in any way
        (see :func:`bifid.data.validate_dataset`).
    """
    path = check_input_file(path, "dataset")
    where = str(path)
    check_self_contained(path, where)
    try:
        with xr.open_dataset(
            path, engine="h5netcdf", decode_times=False, decode_timedelta=False
        ) as raw:
            if raw.nbytes > MAX_DATASET_BYTES:
                raise BifidInputError(
                    f"{where}: dataset would take {raw.nbytes / 1e9:.1f} GB in memory "
                    f"(limit {MAX_DATASET_BYTES / 1e9:.1f} GB, env BIFID_MAX_DATASET_BYTES)."
                )
            ds = raw.load()
    except BifidInputError:
        raise
    except Exception as exc:  # h5py/h5netcdf/xarray raise many types on malformed files
        msg = str(exc).splitlines()[0][:200] if str(exc) else type(exc).__name__
        raise BifidInputError(
            f"{where} is not a readable netCDF-4 (HDF5) file ({type(exc).__name__}: {msg}); "
            "bifid datasets are written by `bifid import`, `bifid cbc` or save_dataset."
        ) from None
    return validate_dataset(ds, where)


def _builder_kwargs(ds: xr.Dataset) -> dict[str, Any]:
    kind = ds.attrs["bifid_kind"]
    kw: dict[str, Any] = {
        "signal_names": [str(s) for s in ds["signal"].values.tolist()],
        "system": ds.attrs.get("system", "experiment"),
        "settings": ds.attrs.get("settings", "{}"),
        "source": ds.attrs.get("source", ""),
        "signal_units": parse_json_attr(ds, "signal_units"),
        "attrs": {k: v for k, v in ds.attrs.items() if k not in _RESERVED_ATTRS},
    }
    if kind == "lco":
        kw["param_name"] = ds["param"].attrs.get("name", ds.attrs.get("param_name", "param"))
        kw["param_units"] = ds["param"].attrs.get("units", ds.attrs.get("param_units", ""))
    else:
        kw["observed"] = ds.attrs["observed"]
        kw["forcing_units"] = ds.attrs.get("forcing_units", "")
    return kw


def combine_datasets(datasets: Sequence[xr.Dataset], source: str | None = None) -> xr.Dataset:
    """Concatenate datasets of the same kind and signals into one (records in order).

    Attributes are taken from the first dataset; ``source`` lists every input's source
    unless given. ``curve`` ids of forced datasets are offset so curves stay distinct.
    """
    if not datasets:
        raise BifidInputError("combine_datasets needs at least one dataset.")
    first = datasets[0]
    kind = first.attrs.get("bifid_kind")
    kw = _builder_kwargs(first)
    records: list[Any] = []
    curve_offset = 0
    for ds in datasets:
        if ds.attrs.get("bifid_kind") != kind:
            raise BifidInputError(
                f"cannot combine a {ds.attrs.get('bifid_kind')!r} dataset with a {kind!r} one."
            )
        names = [str(s) for s in ds["signal"].values.tolist()]
        if names != kw["signal_names"]:
            raise BifidInputError(
                f"cannot combine datasets with signals {kw['signal_names']} and {names}."
            )
        if kind == "lco":
            records.extend(lco_records(ds))
        else:
            recs = forced_records(ds)
            for r in recs:
                r.curve += curve_offset
            curve_offset = max(r.curve for r in recs) + 1 if recs else curve_offset
            records.extend(recs)
    kw["source"] = (
        source
        if source is not None
        else json.dumps([str(ds.attrs.get("source", "")) for ds in datasets])
    )
    return (lco_dataset if kind == "lco" else forced_dataset)(records, **kw)
