"""``bifid import``: measurement files (MATLAB, CSV, netCDF) → one bifid dataset."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from bifid.cli._common import ForceOpt, app, check_outputs, emit_json, user_errors
from bifid.errors import BifidInputError
from bifid.io import run_info

if TYPE_CHECKING:
    import xarray as xr


def _record_rows(ds: xr.Dataset) -> list[dict[str, Any]]:
    kind = ds.attrs["bifid_kind"]
    names = [str(s) for s in ds["signal"].values.tolist()]
    rows = []
    for i in range(ds.sizes["record"]):
        s = int(ds["stable"].values[i])
        row = {
            "param": float(ds["param"].values[i]) if kind == "lco" else None,
            "stable": None if s < 0 else bool(s),
            "n_samples": int(ds["n_samples"].values[i]),
            "sample_rate": float(ds["sample_rate"].values[i]),
        }
        if kind == "lco":
            row["frequency"] = float(ds["frequency"].values[i])
            row["amplitude"] = {n: float(ds["amplitude"].values[i, j]) for j, n in enumerate(names)}
        else:
            row.update(
                omega=float(ds["omega"].values[i]),
                forcing=float(ds["forcing"].values[i]),
                amplitude=float(ds["amplitude"].values[i]),
                phase=float(ds["phase"].values[i]),
                curve=int(ds["curve"].values[i]),
            )
        rows.append(row)
    return rows


@app.command("import")
def import_command(
    paths: list[Path] = typer.Argument(  # noqa: B008
        None, help="Measurement files or directories (MATLAB .mat, CSV, netCDF)."
    ),
    out: Path = typer.Option(None, "--out", "-o", help="Dataset file to write (netCDF)."),  # noqa: B008
    fmt: str = typer.Option(
        "auto",
        "--format",
        help="auto | flutter-cbc | flutter-openloop | em-scurve | em-backbone | csv | netcdf",
    ),
    force: ForceOpt = False,
    json_out: bool = typer.Option(False, "--json", help="Print one JSON object on stdout."),
) -> None:
    """Import measurements into a bifid dataset (format detected from the file content)."""
    with user_errors():
        from bifid.data import FORMATS, expand_paths, import_files, save_dataset

        if fmt not in FORMATS:
            raise BifidInputError(
                f"--format {fmt!r} is unknown; choose one of {', '.join(FORMATS)}."
            )
        if not paths:
            raise BifidInputError("give at least one input file or directory.")
        if out is None:
            raise BifidInputError("--out DATA.nc is required.")
        files = expand_paths(paths)
        check_outputs(out=out, force=force, inputs=files)
        settings = run_info("import", inputs=[str(p) for p in files], format=fmt, out=str(out))
        ds = import_files(files, format=fmt, settings=settings)
        save_dataset(ds, out)
        rows = _record_rows(ds)
    payload = {
        "kind": ds.attrs["bifid_kind"],
        "records": rows,
        "source": [str(p) for p in files],
        "out": str(out),
        "n_records": len(rows),
        "signals": [str(s) for s in ds["signal"].values.tolist()],
        "settings": settings,
    }
    if json_out:
        emit_json(payload)
        return
    kind = payload["kind"]
    print(f"wrote {out}: {len(rows)} {kind} records, signals {payload['signals']}")
    for r in rows:
        stab = {True: "stable", False: "unstable", None: "unknown"}[r["stable"]]
        if kind == "lco":
            f = r["frequency"]
            fs = f"{f / (2 * math.pi):.4g} Hz" if math.isfinite(f) else "?"
            print(
                f"  param={r['param']:<8.4g} {stab:<9} n={r['n_samples']:<7d} "
                f"fs={r['sample_rate']:g} Hz  f={fs}"
            )
        else:
            print(
                f"  omega={r['omega']:<9.5g} forcing={r['forcing']:<9.4g} "
                f"amplitude={r['amplitude']:<9.4g} curve={r['curve']} {stab}"
            )
    sys.stdout.flush()
