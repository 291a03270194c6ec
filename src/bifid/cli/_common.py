"""Shared pieces of the CLI: the typer apps, JSON output, ``--set`` parsing, error handling."""

from __future__ import annotations

import contextlib
import json
import math
import sys
from collections.abc import Iterator
from typing import Any

import numpy as np
import typer

from bifid.errors import BifidError, BifidInputError, ConvergenceError

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="bifid: bifurcation diagrams by continuation and control-based continuation, "
    "and ODE models identified from them.",
)
fit_app = typer.Typer(no_args_is_help=True, help="Fit a model to datasets.")
app.add_typer(fit_app, name="fit")

EXIT_USER = 2
EXIT_NUMERICAL = 3


def fail(message: str, code: int = EXIT_USER) -> None:
    """Print a one-line error on stderr and exit with ``code``."""
    print(f"bifid: error: {message}", file=sys.stderr)
    raise typer.Exit(code)


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Turn bifid's exceptions into a one-line message and a non-zero exit."""
    try:
        yield
    except typer.Exit:
        raise
    except BifidInputError as exc:
        fail(str(exc), EXIT_USER)
    except ConvergenceError as exc:
        fail(str(exc), EXIT_NUMERICAL)
    except BifidError as exc:
        fail(str(exc), EXIT_NUMERICAL)
    except FileNotFoundError as exc:
        fail(f"file not found: {exc.filename or exc}", EXIT_USER)
    except PermissionError as exc:
        fail(f"permission denied: {exc.filename or exc}", EXIT_USER)
    except KeyboardInterrupt:
        fail("interrupted", 130)


def parse_sets(sets: list[str] | None) -> dict[str, float]:
    """Parse repeated ``--set NAME=VALUE`` options.

    Raises
    ------
    BifidInputError
        On a malformed item or a value that is not a finite number.
    """
    out: dict[str, float] = {}
    for item in sets or []:
        if "=" not in item:
            raise BifidInputError(f"--set expects NAME=VALUE, got {item!r}.")
        name, _, value = item.partition("=")
        name = name.strip()
        try:
            v = float(value)
        except ValueError:
            raise BifidInputError(f"--set {name}: {value!r} is not a number.") from None
        if not math.isfinite(v):
            raise BifidInputError(f"--set {name}: value must be finite, got {value!r}.")
        out[name] = v
    return out


def finite_range(name: str, a: float, b: float) -> tuple[float, float]:
    """Check a ``A B`` range option: finite and A != B."""
    if not (math.isfinite(a) and math.isfinite(b)):
        raise BifidInputError(f"{name} must be finite numbers, got {a!r} {b!r}.")
    if a == b:
        raise BifidInputError(f"{name} must span an interval, got {a!r} {b!r}.")
    return float(a), float(b)


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays (and NaN/inf, which JSON lacks) to plain JSON values."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, (np.bool_, bool)):
        return bool(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    return obj


def emit_json(payload: dict[str, Any]) -> None:
    """Print one JSON object on stdout."""
    sys.stdout.write(json.dumps(to_jsonable(payload)) + "\n")
    sys.stdout.flush()


# ``bifid predict MODEL`` reads ``model.json``'s "type" and calls the predictor
# registered for it: ``fn(model_dir, options) -> JSON payload`` where ``options`` holds
# the continue/frc/scurve/backbone options given on the command line.
PREDICTORS: dict[str, Any] = {}


def register_predictor(model_type: str, fn: Any) -> None:
    """Register the ``bifid predict`` handler of a model type."""
    PREDICTORS[model_type] = fn
