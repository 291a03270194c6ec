"""CSV in and out: bifid's documented column schema, and the thesis' amplitude tables.

Schema (``docs/data-formats.md``): optional ``# key: value`` comment lines, then a header
row, then one row per sample.

- LCO files: columns ``record, param, stable, time, <signal>...``;
- forced files: ``record, omega, forcing, stable, time, <signal>...``;
- optional columns: ``frequency`` (LCO, rad/s, constant per record), ``curve`` (forced,
  integer per record), ``amplitude``, ``phase`` (forced, per record; computed when
  absent or empty), ``force`` (forced), ``control``, ``target`` (per sample).

Every other column is a measured signal, in the order given. ``time`` is in seconds and
must be uniformly spaced within a record; ``stable`` is 1, 0, -1 or empty (unknown).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from bifid.data._iterate import forced_records, lco_records
from bifid.data._netcdf import forced_dataset, lco_dataset
from bifid.data._records import ForcedRecord, LCORecord
from bifid.data._validate import parse_json_attr, validate_dataset
from bifid.errors import BifidInputError
from bifid.io import atomic_write_text, check_input_file
from bifid.signal import estimate_frequency

__all__ = ["ThesisCurve", "load_thesis_curves", "read_csv_dataset", "write_csv"]

CSV_MAGIC = "bifid-csv"
_LCO_RECORD_COLS = ("param", "frequency")
_FORCED_RECORD_COLS = ("omega", "forcing", "curve", "amplitude", "phase")
_SAMPLE_COLS = ("control", "target", "force")
_RESERVED = {"record", "stable", "time", *_LCO_RECORD_COLS, *_FORCED_RECORD_COLS, *_SAMPLE_COLS}
_META_KEYS = ("param_name", "units", "system", "source", "observed")
MAX_CSV_BYTES = 2 * 1024**3
_TIME_RTOL = 1e-3


def _read_text(path: Path) -> str:
    check_input_file(path)
    size = path.stat().st_size
    if size > MAX_CSV_BYTES:
        raise BifidInputError(f"{path}: {size / 1e9:.1f} GB is larger than the 2 GB CSV limit.")
    raw = path.read_bytes()
    if b"\x00" in raw[:65536]:
        raise BifidInputError(f"{path} is a binary file, not CSV text.")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise BifidInputError(
            f"{path} is not UTF-8 text ({exc.reason} at byte {exc.start})."
        ) from None


def _parse_units(text: str, where: str) -> dict[str, str]:
    units: dict[str, str] = {}
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        name, sep, unit = item.partition("=")
        if not sep or not name.strip():
            raise BifidInputError(f"{where}: '# units:' expects NAME=UNIT, ... ; got {item!r}.")
        units[name.strip()] = unit.strip()
    return units


def _float(cell: str, col: str, line: int, where: str, *, allow_empty: bool = False) -> float:
    cell = cell.strip()
    if not cell:
        if allow_empty:
            return math.nan
        raise BifidInputError(f"{where}, line {line}: column {col!r} is empty.")
    try:
        value = float(cell)
    except ValueError:
        raise BifidInputError(
            f"{where}, line {line}: column {col!r} must be a number, got {cell[:40]!r}."
        ) from None
    if math.isinf(value) or (math.isnan(value) and not allow_empty):
        raise BifidInputError(
            f"{where}, line {line}: column {col!r} must be a finite number, got {cell[:40]!r}"
            + (" (beyond the float64 range)." if math.isinf(value) else ".")
        )
    return value


def read_csv_dataset(path: str | os.PathLike[str]) -> xr.Dataset:
    """Read a CSV file in bifid's column schema into an ``"lco"`` or ``"forced"`` dataset.

    The kind follows from the columns: ``param`` → LCO, ``omega`` + ``forcing`` → forced.
    For LCO records without a ``frequency`` column the frequency is estimated from the
    spectral peak of the first signal (:func:`~bifid.signal.estimate_frequency`),
    flagged by the extra ``frequency_estimated = 1``.

    Raises
    ------
    BifidInputError
        With the file name and line number of the first problem found.
    """
    path = Path(path)
    where = str(path)
    lines = _read_text(path).splitlines()
    meta, start = _metadata(lines, where)
    try:
        csv.field_size_limit(1 << 20)
        reader = csv.reader(io.StringIO("\n".join(lines[start:])))
        header = [h.strip() for h in next(reader)]
        rows = list(reader)
    except (csv.Error, StopIteration) as exc:
        raise BifidInputError(f"{where}: malformed CSV ({exc}).") from None
    kind, cols, signals = _schema(header, where)
    if not rows:
        raise BifidInputError(f"{where}: the file holds no data rows.")
    groups = _group_rows(rows, header, cols, signals, start + 2, where)
    records = [
        _record(kind, rid, g, f"{where}, record {rid!r} (from line {g['line']})")
        for rid, g in groups.items()
    ]
    return _dataset(kind, records, signals, meta, path, where)


def _metadata(lines: list[str], where: str) -> tuple[dict[str, str], int]:
    """``# key: value`` lines before the header, and the index of the header row."""
    meta: dict[str, str] = {}
    for start, line in enumerate(lines):
        s = line.strip()
        if not s:
            continue
        if not s.startswith("#"):
            return meta, start
        key, sep, value = s.lstrip("#").strip().partition(":")
        if sep and key.strip() in _META_KEYS:
            meta[key.strip()] = value.strip()
    raise BifidInputError(f"{where}: no header row (expected e.g. record,param,stable,time,h).")


def _schema(header: list[str], where: str) -> tuple[str, dict[str, int], list[str]]:
    """The dataset kind, the column index by name and the signal columns of a header."""
    if len(set(header)) != len(header) or any(not h for h in header):
        raise BifidInputError(f"{where}: column names must be unique and non-empty: {header}.")
    cols = {h: i for i, h in enumerate(header)}
    if "param" in cols and ("omega" in cols or "forcing" in cols):
        raise BifidInputError(f"{where}: columns 'param' and 'omega'/'forcing' cannot be mixed.")
    if "param" in cols:
        kind, required = "lco", ("record", "param", "stable", "time")
    elif "omega" in cols and "forcing" in cols:
        kind, required = "forced", ("record", "omega", "forcing", "stable", "time")
    else:
        raise BifidInputError(
            f"{where}: cannot tell the dataset kind; an LCO file needs columns "
            "record,param,stable,time,<signals>; a forced file record,omega,forcing,stable,"
            f"time,<signals>. Found {header}."
        )
    missing = [c for c in required if c not in cols]
    if missing:
        raise BifidInputError(f"{where}: missing column(s) {missing}.")
    foreign = ("frequency",) if kind == "forced" else ("force", "curve", "amplitude", "phase")
    bad = [c for c in header if c in foreign]
    if bad:
        raise BifidInputError(f"{where}: column(s) {bad} do not belong in a {kind!r} file.")
    signals = [h for h in header if h not in _RESERVED]
    if not signals:
        raise BifidInputError(f"{where}: no signal columns (every column is a reserved name).")
    return kind, cols, signals


def _group_rows(
    rows: list[list[str]],
    header: list[str],
    cols: dict[str, int],
    signals: list[str],
    first_line: int,
    where: str,
) -> dict[str, dict[str, Any]]:
    """Rows grouped by record id: per-record constants and per-sample columns."""
    rec_cols = [c for c in (*_LCO_RECORD_COLS, *_FORCED_RECORD_COLS, "stable") if c in cols]
    groups: dict[str, dict[str, Any]] = {}
    for j, row in enumerate(rows):
        line = first_line + j
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) != len(header):
            raise BifidInputError(
                f"{where}, line {line}: {len(row)} fields, the header has {len(header)}."
            )
        rid = row[cols["record"]].strip()
        if not rid:
            raise BifidInputError(f"{where}, line {line}: empty record id.")
        consts = {
            c: _float(
                row[cols[c]],
                c,
                line,
                where,
                allow_empty=c in ("stable", "frequency", "amplitude", "phase"),
            )
            for c in rec_cols
        }
        g = groups.get(rid)
        if g is None:
            g = groups[rid] = {
                "consts": consts,
                "line": line,
                "time": [],
                "sig": [],
                **{c: [] for c in _SAMPLE_COLS if c in cols},
            }
        else:
            for c, v in consts.items():
                old = g["consts"][c]
                if not (v == old or (math.isnan(v) and math.isnan(old))):
                    raise BifidInputError(
                        f"{where}, line {line}: {c!r} changes within record {rid!r} "
                        f"({old!r} → {v!r}); it must be constant per record."
                    )
        g["time"].append(_float(row[cols["time"]], "time", line, where))
        g["sig"].append([_float(row[cols[s]], s, line, where) for s in signals])
        for c in _SAMPLE_COLS:
            if c in cols:
                g[c].append(_float(row[cols[c]], c, line, where, allow_empty=c == "target"))
    if not groups:
        raise BifidInputError(f"{where}: the file holds no data rows.")
    return groups


def _sample_rate(t: np.ndarray, rwhere: str) -> float:
    """The sample rate of a uniformly sampled time column."""
    if t.shape[0] < 2:
        raise BifidInputError(f"{rwhere}: needs at least 2 samples to define a sample rate.")
    if not np.all(np.isfinite(t)):
        raise BifidInputError(f"{rwhere}: time contains NaN/inf.")
    dt = np.diff(t)
    step = (t[-1] - t[0]) / (t.shape[0] - 1)
    if step <= 0 or np.any(dt <= 0):
        raise BifidInputError(f"{rwhere}: time must increase strictly within a record.")
    if np.max(np.abs(dt - step)) > _TIME_RTOL * step + 1e-12 * max(abs(t[-1]), 1.0):
        raise BifidInputError(
            f"{rwhere}: time is not uniformly sampled (steps from {dt.min():g} to "
            f"{dt.max():g} s); resample to a uniform grid first."
        )
    with np.errstate(over="ignore"):
        rate = float(1.0 / step)
    if not math.isfinite(rate):
        raise BifidInputError(f"{rwhere}: time step {step:g} s is too small.")
    return rate


def _record(kind: str, rid: str, g: dict[str, Any], rwhere: str) -> LCORecord | ForcedRecord:
    """One record of a grouped CSV file."""
    rate = _sample_rate(np.array(g["time"]), rwhere)
    c = g["consts"]
    stable_v = c.get("stable", math.nan)
    if math.isnan(stable_v) or stable_v == -1:
        stable = None
    elif stable_v in (0.0, 1.0):
        stable = bool(stable_v)
    else:
        raise BifidInputError(f"{rwhere}: stable must be 1, 0, -1 or empty, got {stable_v!r}.")
    sig = np.array(g["sig"])
    extra: dict[str, Any] = {"record_id": rid}
    per_sample = {k: (np.array(g[k]) if k in g else None) for k in _SAMPLE_COLS}
    common: dict[str, Any] = {
        "signals": sig,
        "sample_rate": rate,
        "stable": stable,
        "control": per_sample["control"],
        "target": per_sample["target"],
        "extra": extra,
    }
    try:
        if kind == "lco":
            freq = c.get("frequency", math.nan)
            if math.isnan(freq):
                freq = estimate_frequency(sig[:, 0], rate)
                extra["frequency_estimated"] = 1.0
            return LCORecord(param=c["param"], frequency=freq, **common)
        curve = c.get("curve", 0.0)
        if not math.isfinite(curve) or curve != int(curve):
            raise BifidInputError(f"curve must be an integer, got {curve!r}.")
        return ForcedRecord(
            omega=c["omega"],
            forcing=c["forcing"],
            force=per_sample["force"],
            curve=int(curve),
            **common,
            amplitude=None if math.isnan(c.get("amplitude", math.nan)) else c["amplitude"],
            phase=None if math.isnan(c.get("phase", math.nan)) else c["phase"],
        )
    except BifidInputError as exc:
        raise BifidInputError(f"{rwhere}: {exc}") from None


def _dataset(
    kind: str, records: list[Any], signals: list[str], meta: dict[str, str], path: Path, where: str
) -> xr.Dataset:
    """The dataset of the records, with the file's metadata and units."""
    units = _parse_units(meta.get("units", ""), where)
    signal_units = {s: units[s] for s in signals if s in units}
    settings = {"format": "csv", "file": str(path), "metadata": meta}
    attrs = {f"{k}_units": units[k] for k in ("control", "target") if k in units}
    if kind == "lco":
        return lco_dataset(
            records,
            signals,
            param_name=meta.get("param_name", "param"),
            param_units=units.get("param", ""),
            system=meta.get("system", "experiment"),
            settings=settings,
            source=meta.get("source", str(path)),
            signal_units=signal_units,
            attrs=attrs,
        )
    observed = meta.get("observed") or signals[0]
    if observed not in signals:
        raise BifidInputError(f"{where}: '# observed: {observed}' is not a signal column.")
    return forced_dataset(
        records,
        signals,
        observed=observed,
        system=meta.get("system", "experiment"),
        settings=settings,
        source=meta.get("source", str(path)),
        signal_units=signal_units,
        forcing_units=units.get("forcing", ""),
        attrs=attrs,
    )


def _fmt(v: float) -> str:
    return "" if math.isnan(v) else repr(float(v))


def write_csv(ds: xr.Dataset, path: str | os.PathLike[str]) -> Path:
    """Write a dataset in bifid's CSV schema (atomically); :func:`read_csv_dataset` reads it
    back to the same records (per-record extras are not exported)."""
    ds = validate_dataset(ds, "write_csv")
    kind = ds.attrs["bifid_kind"]
    names = [str(s) for s in ds["signal"].values.tolist()]
    clash = [n for n in names if n in _RESERVED]
    if clash:
        raise BifidInputError(f"signal names {clash} clash with reserved CSV column names.")
    units = parse_json_attr(ds, "signal_units")
    buf = io.StringIO()
    buf.write(f"# {CSV_MAGIC} 1\n")
    if kind == "lco":
        unit_items = {"param": ds["param"].attrs.get("units", ""), **units}
        buf.write(f"# param_name: {ds['param'].attrs.get('name', 'param')}\n")
        recs: list[Any] = lco_records(ds)
        head = ["record", "param", "stable", "time", *names, "frequency", "control", "target"]
    else:
        unit_items = {"forcing": ds.attrs.get("forcing_units", ""), **units}
        buf.write(f"# observed: {ds.attrs['observed']}\n")
        recs = forced_records(ds)
        with_force = [r.force is not None for r in recs]
        if any(with_force) and not all(with_force):
            raise BifidInputError(
                "write_csv: some forced records have a force signal and some not; the CSV "
                "force column needs one for every record (or none)."
            )
        head = [
            "record",
            "omega",
            "forcing",
            "stable",
            "time",
            *names,
            "curve",
            "amplitude",
            "phase",
            *(["force"] if all(with_force) else []),
            "control",
            "target",
        ]
    unit_str = ", ".join(f"{k}={v}" for k, v in unit_items.items() if v)
    if unit_str:
        buf.write(f"# units: {unit_str}, time=s\n")
    buf.write(f"# system: {ds.attrs.get('system', 'experiment')}\n")
    src = str(ds.attrs.get("source", "")).replace("\n", " ")
    if src:
        buf.write(f"# source: {src}\n")
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(head)
    for i, r in enumerate(recs):
        stable = "" if r.stable is None else str(int(r.stable))
        t = r.time
        control = r.control if r.control is not None else np.zeros(r.n_samples)
        target = r.target if r.target is not None else np.full(r.n_samples, np.nan)
        for k in range(r.n_samples):
            sig = [_fmt(v) for v in r.signals[k]]
            if kind == "lco":
                row = [
                    str(i),
                    _fmt(r.param),
                    stable,
                    _fmt(t[k]),
                    *sig,
                    _fmt(r.frequency),
                    _fmt(control[k]),
                    _fmt(target[k]),
                ]
            else:
                force = [_fmt(r.force[k])] if r.force is not None else []
                row = [
                    str(i),
                    _fmt(r.omega),
                    _fmt(r.forcing),
                    stable,
                    _fmt(t[k]),
                    *sig,
                    str(r.curve),
                    _fmt(r.amplitude),
                    _fmt(r.phase),
                    *force,
                    _fmt(control[k]),
                    _fmt(target[k]),
                ]
            writer.writerow(row)
    path = Path(path)
    atomic_write_text(path, buf.getvalue())
    return path


@dataclasses.dataclass
class ThesisCurve:
    """A model bifurcation curve of thesis ch. 4 (``thesis_curves/*.csv``).

    Unpacks as ``speed, heave_amp, pitch_amp = load_thesis_curves(path)``: wind speed
    [m/s], heave amplitude and pitch amplitude as stored by the authors.
    """

    speed: np.ndarray
    heave_amp: np.ndarray
    pitch_amp: np.ndarray
    source: str

    def __iter__(self) -> Iterator[np.ndarray]:
        return iter((self.speed, self.heave_amp, self.pitch_amp))


def load_thesis_curves(path: str | os.PathLike[str]) -> ThesisCurve:
    """Read a headerless 3-column CSV (wind speed, heave amplitude, pitch amplitude)."""
    path = Path(path)
    text = _read_text(path)
    rows = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        cells = s.split(",")
        if len(cells) != 3:
            raise BifidInputError(f"{path}, line {line_no}: expected 3 columns, got {len(cells)}.")
        vals = [
            _float(c, name, line_no, str(path))
            for c, name in zip(cells, ("speed", "heave", "pitch"), strict=True)
        ]
        if not all(math.isfinite(v) for v in vals):
            raise BifidInputError(f"{path}, line {line_no}: values must be finite.")
        rows.append(vals)
    if not rows:
        raise BifidInputError(f"{path}: no data rows.")
    arr = np.array(rows)
    return ThesisCurve(speed=arr[:, 0], heave_amp=arr[:, 1], pitch_amp=arr[:, 2], source=str(path))
