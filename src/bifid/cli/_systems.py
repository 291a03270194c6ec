"""``bifid systems [FILE ...]``: every system bifid knows, and where it came from.

Lists the built-in systems, the systems installed packages publish through the entry-point
group ``bifid.systems``, and the systems of the system files given on the command line
(``model.py``, ``model.toml``), each with its ``source``: ``built-in``, a file path, or
``package:entry-point``. A package whose entry point fails to load is reported (``errors``,
``complete: false``, exit 3) without hiding the others.
"""

from __future__ import annotations

import sys
from typing import Annotated, Any

import typer

from bifid.cli._common import EXIT_NUMERICAL, app, emit_json, one_line, user_errors
from bifid.errors import BifidInputError


def _entries(files: list[str]) -> tuple[list[dict[str, Any]], list[dict[str, str]]]:
    from bifid.systems import get_system, system_entries, systems_in_file

    systems, errors = [], []
    for entry in system_entries():
        try:
            systems.append(get_system(entry.name).to_json())
        except BifidInputError as exc:
            errors.append({"name": entry.name, "source": entry.source, "message": str(exc)})
    for path in files:
        systems += [s.to_json() for s in systems_in_file(path).values()]
    return systems, errors


def _print_human(systems: list[dict[str, Any]]) -> None:
    for e in systems:
        print(f"{e['name']}  ({e['kind']}, {e['source']})")
        if e["description"]:
            print(f"  {one_line(e['description'], 200)}")
        print(f"  states:     {', '.join(e['states'])}   observed: {e['observed']}")
        params = ", ".join(
            f"{p['name']}={p['default']:g}"
            + ("" if p["unit"] in ("", "nd", "1") else f" {p['unit']}")
            for p in e["parameters"]
        )
        print(f"  parameters: {params}")


@app.command("systems")
def systems_cmd(
    files: Annotated[
        list[str] | None,
        typer.Argument(metavar="[FILE]...", help="System files (.py, .toml) to describe too."),
    ] = None,
    json_out: Annotated[
        bool, typer.Option("--json", help="Print one JSON object on stdout.")
    ] = False,
) -> None:
    """List every system (built-in, installed packages, given files) with where it came from."""
    with user_errors():
        systems, errors = _entries(list(files or []))
        complete = not errors
        if json_out:
            emit_json(
                {
                    "systems": systems,
                    "errors": errors,
                    "complete": complete,
                    "status": "ok" if complete else "partial",
                }
            )
        else:
            _print_human(systems)
        for err in errors:
            print(f"bifid: error: {one_line(err['message'])}", file=sys.stderr)
        if errors:
            raise typer.Exit(EXIT_NUMERICAL)
