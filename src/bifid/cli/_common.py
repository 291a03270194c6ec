"""Shared pieces of the CLI: the typer apps, JSON output, option checks, output paths, and
the one mapping from failures to exit codes.

Exit codes (``docs/cli.md``): **0** done and complete; **2** bad input or a path the
command line can fix (unknown name, bad value, missing or unreadable input, a name too
long, a missing parent directory, an existing output without ``--force``, an unknown plot
format); **3** numerical failure or incomplete result, and unexpected internal errors;
**4** the environment (no space left, read-only file system, permission denied, network,
memory); **130** interrupted (with ``--json`` still one JSON object,
``{"complete": false, "status": "interrupted", ...}``). Every failure prints one line on
stderr, never a traceback (``BIFID_DEBUG=1`` re-raises unexpected errors for debugging).
"""

from __future__ import annotations

import contextlib
import errno
import importlib
import json
import math
import os
import re
import secrets
import sys
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from bifid.errors import BifidError, BifidInputError, ConvergenceError
from bifid.io import check_output_path

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="bifid: bifurcation diagrams by continuation and control-based continuation, "
    "and ODE models identified from them.",
)
fit_app = typer.Typer(no_args_is_help=True, help="Fit a model to datasets.")
app.add_typer(fit_app, name="fit")

EXIT_OK = 0
EXIT_USER = 2
EXIT_NUMERICAL = 3
EXIT_ENVIRONMENT = 4
EXIT_INTERRUPTED = 130
EXIT_CODES = (EXIT_OK, EXIT_USER, EXIT_NUMERICAL, EXIT_ENVIRONMENT, EXIT_INTERRUPTED)

ForceOpt = Annotated[
    bool,
    typer.Option(
        "--force",
        help="Replace existing outputs (without it an existing output "
        "file or non-empty output directory is refused).",
    ),
]

_MESSAGE_CHARS = 600  # longest error line
_TOKEN_CHARS = 120  # longest run of non-blank characters quoted in an error line

# errors of the operating system the user fixes in the command line (exit 2); every other
# OSError is the environment's (exit 4)
_USER_ERRNOS = {
    errno.ENAMETOOLONG: "file name too long",
    errno.ENOENT: "no such file or directory",
    errno.ENOTDIR: "not a directory",
    errno.EISDIR: "is a directory",
    errno.ELOOP: "too many levels of symbolic links",
    errno.ENXIO: "not a regular file (no such device or address)",
    errno.ESPIPE: "not a regular file (cannot seek)",
}
_ENV_HINTS = {
    errno.ENOSPC: "no space left on device; free some space or write elsewhere",
    errno.EDQUOT: "disk quota exceeded; free some space or write elsewhere",
    errno.EROFS: "read-only file system; write the output elsewhere",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EIO: "input/output error of the device",
    errno.EMFILE: "too many open files",
    errno.ENOMEM: "out of memory",
}


# ---------------------------------------------------------------------------------------------
# messages and exit codes
# ---------------------------------------------------------------------------------------------


def one_line(message: object, limit: int = _MESSAGE_CHARS) -> str:
    """``message`` as one line of bounded length.

    Newlines become spaces; a run of more than 120 non-blank characters (a pasted 100 KB
    argument, a long path) keeps its start and end; the whole line is cut at ``limit``.
    """
    text = " ".join(str(message).split())

    def shorten(m: re.Match[str]) -> str:
        s = m.group(0)
        return f"{s[:60]}…[{len(s)} characters]…{s[-20:]}"

    text = re.sub(rf"\S{{{_TOKEN_CHARS + 1},}}", shorten, text)
    return text if len(text) <= limit else text[: limit - 1] + "…"


REPORTED: list[int] = []  # exit codes whose one-line message was printed (see main)


def fail(message: str, code: int = EXIT_USER) -> None:
    """Print a one-line error on stderr and exit with ``code``."""
    print(f"bifid: error: {one_line(message)}", file=sys.stderr)
    REPORTED.append(code)
    raise typer.Exit(code)


def _os_error(exc: OSError) -> tuple[int, str]:
    where = exc.filename if exc.filename is not None else ""
    if exc.filename2 is not None:
        where = f"{where} → {exc.filename2}"
    code = exc.errno
    if isinstance(exc, ConnectionError | TimeoutError) or code in (
        errno.ECONNREFUSED,
        errno.ECONNRESET,
        errno.EHOSTUNREACH,
        errno.ENETUNREACH,
        errno.ETIMEDOUT,
    ):
        return EXIT_ENVIRONMENT, f"network: {exc.strerror or exc}" + (f": {where}" if where else "")
    if code in _USER_ERRNOS:
        return EXIT_USER, f"{_USER_ERRNOS[code]}: {where or exc}"
    hint = _ENV_HINTS.get(code) if code is not None else None
    what = hint or (exc.strerror or str(exc) or type(exc).__name__)
    return EXIT_ENVIRONMENT, f"{what}" + (f": {where}" if where else f" ({exc})")


def exit_status(exc: BaseException) -> tuple[int, str]:
    """The exit code and one-line message of a failure: the single mapping of the CLI.

    ``BifidInputError`` → 2; ``ConvergenceError`` and other bifid errors, floating-point and
    linear-algebra failures → 3; ``OSError`` → 2 when the command line can fix it (name too
    long, missing file, not a regular file), else 4 (no space, read-only, permission,
    network); ``MemoryError`` → 4; ``KeyboardInterrupt`` → 130; anything else is an
    internal error → 3.
    """
    if isinstance(exc, KeyboardInterrupt):
        return EXIT_INTERRUPTED, "interrupted"
    if isinstance(exc, BifidInputError):
        return EXIT_USER, str(exc)
    if isinstance(exc, ConvergenceError | BifidError):
        return EXIT_NUMERICAL, str(exc)
    if isinstance(exc, OSError):
        return _os_error(exc)
    if isinstance(exc, MemoryError):
        return EXIT_ENVIRONMENT, "out of memory; try a smaller problem"
    if isinstance(exc, ArithmeticError | np.linalg.LinAlgError):
        return EXIT_NUMERICAL, f"numerical failure ({type(exc).__name__}: {exc})"
    return EXIT_NUMERICAL, (
        f"internal error ({type(exc).__name__}: {exc}); please report "
        "it (BIFID_DEBUG=1 shows the traceback)"
    )


def is_usage_error(exc: BaseException) -> bool:
    """A usage error of typer's click (``BadParameter``, unknown option): it knows its
    message and exit code. Typer may bundle its own click, so it is told by duck typing."""
    return hasattr(exc, "format_message") and hasattr(exc, "exit_code")


def _context_params() -> tuple[str, dict[str, Any]]:
    """The running command's path and parameters (typer bundles its own click, or uses
    the installed one: both are asked)."""
    for module in ("typer._click.globals", "click.globals"):
        try:
            ctx = importlib.import_module(module).get_current_context(silent=True)
        except (ImportError, AttributeError):
            continue
        if ctx is not None:
            return ctx.command_path, dict(ctx.params)
    return "bifid", {}


def interrupted_payload(command: str, params: dict[str, Any]) -> dict[str, Any]:
    """The JSON object an interrupted ``--json`` run prints."""
    payload: dict[str, Any] = {
        "complete": False,
        "status": "interrupted",
        "command": command,
        "message": "interrupted before the end",
    }
    out = params.get("out")
    if out is not None:
        payload["out"] = str(out)
        if "resume" in params and Path(out).exists():
            payload["message"] += (
                f"; every point measured so far is in {out}: run the same "
                "command with --resume to continue"
            )
    return payload


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Run a command's body: every failure becomes one line on stderr and its exit code.

    See :func:`exit_status` for the mapping. An interrupted ``--json`` run also prints
    :func:`interrupted_payload` on stdout. Outputs moved aside by :func:`check_outputs`
    (``--force`` on a campaign file) are restored if nothing new was written.
    """
    try:
        yield
    except (typer.Exit, SystemExit, GeneratorExit):
        raise
    except BaseException as exc:
        if is_usage_error(exc):
            raise
        if os.environ.get("BIFID_DEBUG") and not isinstance(exc, BifidError | KeyboardInterrupt):
            raise
        code, message = exit_status(exc)
        if code == EXIT_INTERRUPTED:
            command, params = _context_params()
            if params.get("json_out"):
                emit_json(interrupted_payload(command, params))
        fail(message, code)
    finally:
        _settle_replaced()


# ---------------------------------------------------------------------------------------------
# outputs: checked before any computation, one overwrite policy
# ---------------------------------------------------------------------------------------------

_REPLACED: list[tuple[Path, Path]] = []  # (output, the previous file moved aside)


def _settle_replaced() -> None:
    """Drop the previous files whose outputs were written; restore the others."""
    while _REPLACED:
        out, backup = _REPLACED.pop()
        with contextlib.suppress(OSError):
            if out.exists():
                backup.unlink()
            else:
                os.replace(backup, out)


def _check_plot(plot: Path, force: bool) -> None:
    from matplotlib.backend_bases import FigureCanvasBase

    check_output_path(plot, "--plot")
    known = FigureCanvasBase.get_supported_filetypes()
    fmt = plot.suffix.lower().lstrip(".")
    if fmt not in known:
        raise BifidInputError(
            f"--plot {plot}: unknown figure format {plot.suffix or '(no suffix)'!r}; name the "
            f"file with one of {', '.join('.' + k for k in sorted(known))}."
        )
    if plot.exists() and not force:
        raise BifidInputError(f"--plot {plot} exists; pass --force to replace it.")


def _check_out_dir(out: Path, force: bool, resume: bool | None) -> None:
    check_output_path(out, "--out", directory=True)
    if force or resume or not out.is_dir() or not any(out.iterdir()):
        return
    also = " or --resume to reuse what is there" if resume is not None else ""
    raise BifidInputError(
        f"--out {out} is a directory that is not empty; pass --force to write into it"
        f"{also}, or choose another directory."
    )


def _check_out_file(out: Path, force: bool, resume: bool | None) -> None:
    check_output_path(out, "--out")
    if resume:
        if not out.exists():
            raise BifidInputError(f"--resume: {out} does not exist (nothing to resume).")
        return
    if not out.exists():
        return
    if not force:
        also = ", or --resume to continue it" if resume is not None else ""
        raise BifidInputError(f"--out {out} exists; pass --force to replace it{also}.")
    if resume is not None:
        # a campaign appends to its file: move the old one aside until new points exist
        backup = out.with_name(f".{out.name[:64]}.replaced-{secrets.token_hex(4)}")
        os.replace(out, backup)
        _REPLACED.append((out, backup))


def check_outputs(
    *,
    out: str | os.PathLike[str] | None = None,
    plot: str | os.PathLike[str] | None = None,
    force: bool = False,
    resume: bool | None = None,
    directory: bool = False,
    inputs: Iterable[str | os.PathLike[str]] = (),
) -> None:
    """Check a command's outputs before it computes anything; apply the overwrite policy.

    Every command that writes calls this first, e.g.
    ``check_outputs(out=out, plot=plot, force=force)``.

    Parameters
    ----------
    out
        ``--out``: a file, or a directory when ``directory`` is true.
    plot
        ``--plot``: a figure file whose suffix names a format matplotlib writes.
    force
        ``--force``: replace an existing output file, write into a non-empty directory.
        Without it both are refused.
    resume
        ``None`` for commands without ``--resume``. Otherwise the output is a campaign
        that grows point by point: ``--resume`` (``True``) is the only way to append, and
        needs the file to exist; with ``--force`` the old file is moved aside and deleted
        once the new run has written its first point (restored if it writes none).
    directory
        ``--out`` is a directory (models, demos). ``resume`` then reuses what is there.
    inputs
        Input files: none may be an output.

    Raises
    ------
    BifidInputError
        A name too long, a missing parent directory, an existing output without
        ``--force``, an unknown figure format, an output that is also an input.
    OSError
        A read-only file system, no permission, no space left (exit 4).
    """
    paths = {}
    if plot is not None:
        plot = Path(plot)
        _check_plot(plot, force)
        paths["--plot"] = plot
    if out is not None:
        out = Path(out)
        if directory:
            _check_out_dir(out, force, resume)
        else:
            _check_out_file(out, force, resume)
        paths["--out"] = out
    resolved = {name: p.resolve() for name, p in paths.items()}
    if len(set(resolved.values())) < len(resolved):
        raise BifidInputError("--out and --plot name the same file; give two names.")
    for p in inputs:
        for name, r in resolved.items():
            if Path(p).resolve() == r:
                raise BifidInputError(
                    f"{name} {paths[name]} is one of the inputs; inputs are never modified."
                )


# ---------------------------------------------------------------------------------------------
# option values
# ---------------------------------------------------------------------------------------------


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


def _bounds_text(gt: float | None, ge: float | None, lt: float | None, le: float | None) -> str:
    parts = [
        f"{op} {b:g}" for op, b in ((">", gt), (">=", ge), ("<", lt), ("<=", le)) if b is not None
    ]
    return " and ".join(parts)


def option_value(
    name: str,
    value: float | None,
    default: float | None = None,
    *,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    integer: bool = False,
) -> Any:
    """A numeric option checked by its meaning: ``value``, or ``default`` when not given.

    ``None`` means "not given"; ``0`` is a value and is checked like any other (never
    ``value or default``). The result must be finite, an integer when ``integer``, and
    within the bounds: e.g. a sample rate ``gt=0``, a number of periods ``ge=1``, a
    frequency Ω ``gt=0``.

    Examples
    --------
    >>> option_value("--sample-rate", None, 5000.0, gt=0)
    5000.0
    >>> option_value("--measure-periods", 0, 3, ge=1)
    Traceback (most recent call last):
    ...
    bifid.errors.BifidInputError: --measure-periods must be >= 1, got 0.

    Raises
    ------
    BifidInputError
        A value that is not a finite number, not an integer when one is needed, or out of
        bounds.
    """
    v = default if value is None else value
    if v is None:
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise BifidInputError(f"{name} must be a number, got {v!r}.") from None
    if not math.isfinite(x):
        raise BifidInputError(f"{name} must be a finite number, got {v!r}.")
    if integer and x != int(x):
        raise BifidInputError(f"{name} must be a whole number, got {v!r}.")
    ok = (
        (gt is None or x > gt)
        and (ge is None or x >= ge)
        and (lt is None or x < lt)
        and (le is None or x <= le)
    )
    if not ok:
        raise BifidInputError(f"{name} must be {_bounds_text(gt, ge, lt, le)}, got {v!r}.")
    return int(x) if integer else x


def finite_range(
    name: str, a: float, b: float, *, gt: float | None = None, ge: float | None = None
) -> tuple[float, float]:
    """Check a ``A B`` range option: finite, A != B, both ends within the bounds
    (``gt=0`` for frequencies and forcing amplitudes, where values ≤ 0 mean nothing)."""
    if not (math.isfinite(a) and math.isfinite(b)):
        raise BifidInputError(f"{name} must be finite numbers, got {a!r} {b!r}.")
    if a == b:
        raise BifidInputError(f"{name} must span an interval, got {a!r} {b!r}.")
    for v in (a, b):
        option_value(name, v, gt=gt, ge=ge)
    return float(a), float(b)


# ---------------------------------------------------------------------------------------------
# JSON output
# ---------------------------------------------------------------------------------------------


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
