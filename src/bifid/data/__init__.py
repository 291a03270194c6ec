"""Datasets of measured or computed periodic responses, and importers of real data.

Two dataset kinds, stored as netCDF-4 (xarray + h5netcdf), schema in
``docs/data-formats.md``:

- ``"lco"``: limit cycles of an autonomous system at values of one parameter
  (:class:`LCORecord`, :func:`lco_dataset`, :func:`lco_records`);
- ``"forced"``: steady responses to harmonic forcing (:class:`ForcedRecord`,
  :func:`forced_dataset`, :func:`forced_records`).

:func:`save_dataset` writes atomically, :func:`load_dataset` validates everything and
raises :class:`~bifid.errors.BifidInputError` on any malformed file, :func:`append_records`
and :func:`append_record` add records to a file without rewriting those it holds (CBC
campaigns save after every point).

Importers: :func:`import_files` (what ``bifid import`` runs: format detection, MATLAB
files of the flutter rig and the electromagnetic oscillator, CSV in bifid's schema);
loaders of the files that are not limit-cycle records: :func:`load_free_decay`,
:func:`load_open_loop` / :func:`open_loop_summary`, :func:`load_ulco_amplitudes`,
:func:`load_thesis_curves`.
"""

from bifid.data._append import append_record, append_records
from bifid.data._csv import ThesisCurve, load_thesis_curves, read_csv_dataset, write_csv
from bifid.data._em_rig import em_dataset, read_em_curve
from bifid.data._flutter_rig import (
    RIG_PARAMETER_NAMES,
    FreeDecay,
    OpenLoopRun,
    ULCOAmplitudes,
    flutter_cbc_dataset,
    load_free_decay,
    load_open_loop,
    load_ulco_amplitudes,
    open_loop_dataset,
    open_loop_summary,
    read_flutter_cbc,
)
from bifid.data._import import FORMATS, detect_format, expand_paths, import_files
from bifid.data._iterate import forced_records, lco_records
from bifid.data._matlab import load_mat
from bifid.data._netcdf import (
    combine_datasets,
    forced_dataset,
    lco_dataset,
    load_dataset,
    save_dataset,
)
from bifid.data._records import ForcedRecord, LCORecord
from bifid.data._validate import KINDS, validate_dataset

__all__ = [
    "FORMATS",
    "KINDS",
    "RIG_PARAMETER_NAMES",
    "ForcedRecord",
    "FreeDecay",
    "LCORecord",
    "OpenLoopRun",
    "ThesisCurve",
    "ULCOAmplitudes",
    "append_record",
    "append_records",
    "combine_datasets",
    "detect_format",
    "em_dataset",
    "expand_paths",
    "flutter_cbc_dataset",
    "forced_dataset",
    "forced_records",
    "import_files",
    "lco_dataset",
    "lco_records",
    "load_dataset",
    "load_free_decay",
    "load_mat",
    "load_open_loop",
    "load_thesis_curves",
    "load_ulco_amplitudes",
    "open_loop_dataset",
    "open_loop_summary",
    "read_csv_dataset",
    "read_em_curve",
    "read_flutter_cbc",
    "save_dataset",
    "validate_dataset",
    "write_csv",
]
