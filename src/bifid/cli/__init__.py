"""The ``bifid`` command.

Every command accepts ``--json`` (one JSON object on stdout, nothing else there);
progress and logs go to stderr. Exit codes: 0 done and complete, 2 bad input, 3
numerical failure or incomplete result, 4 environment (disk full, read-only, permission,
network), 130 interrupted; each failure prints one line on stderr, never a traceback
(the mapping is :func:`bifid.cli._common.exit_status`).

Sub-commands live in one module each (``_continuation``, ``_cbc``, ``_fit``,
``_predict``, ``_data``, ``_demo``, ``_systems``) and register themselves on :data:`app`.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import sys

from bifid.cli._common import (
    EXIT_CODES,
    EXIT_ENVIRONMENT,
    EXIT_INTERRUPTED,
    EXIT_USER,
    REPORTED,
    app,
    emit_json,
    exit_status,
    fit_app,
    interrupted_payload,
    is_usage_error,
    one_line,
)

_COMMAND_MODULES = (
    "bifid.cli._continuation",
    "bifid.cli._cbc",
    "bifid.cli._fit",
    "bifid.cli._predict",
    "bifid.cli._data",
    "bifid.cli._demo",
    "bifid.cli._systems",
)


def load_commands() -> None:
    """Register every sub-command on :data:`app` (``main`` does this before parsing)."""
    for name in _COMMAND_MODULES:
        importlib.import_module(name)


def _enable_compilation_cache() -> None:
    """Persistent XLA cache: repeated commands skip JIT compilation.

    ``BIFID_JAX_CACHE=""`` disables it; another path moves it.
    """
    from pathlib import Path

    import jax

    path = os.environ.get("BIFID_JAX_CACHE", str(Path.home() / ".cache" / "bifid" / "jax"))
    if path:
        jax.config.update("jax_compilation_cache_dir", path)
        # every program: reading one back takes ~10 ms, compiling even a small one ~0.1 s
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Python warnings as one line on stderr (the default shows a source line too)."""
    print(f"bifid: warning: {one_line(message)}", file=sys.stderr)


def _usage_error(exc: Exception) -> int:
    """A usage error of typer's click (unknown option, missing value): one line, exit 2."""
    ctx = getattr(exc, "ctx", None)
    name = "" if ctx is None or ctx.info_name == "bifid" else f" {ctx.info_name}"
    message = one_line(f"{exc.format_message()} (see 'bifid{name} --help')")
    print(f"bifid: error: {message}", file=sys.stderr)
    return EXIT_USER if exc.exit_code in (1, 2) else int(exc.exit_code)


def _failure(exc: BaseException, argv: list[str]) -> int:
    """A failure outside a command's body (start-up, interruption while parsing)."""
    code, message = exit_status(exc)
    if code == EXIT_INTERRUPTED and "--json" in argv:
        words = [a for a in argv[:2] if not a.startswith("-")]
        params = {"out": argv[argv.index("--out") + 1]} if "--out" in argv[:-1] else {}
        if "--resume" in argv:
            params["resume"] = True
        emit_json(interrupted_payload(" ".join(["bifid", *words]), params))
    print(f"bifid: error: {one_line(message)}", file=sys.stderr)
    return code


def _raise_interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def _unraisable(info) -> None:
    """Errors Python cannot raise (in a finaliser or a garbage-collector callback): one line
    on stderr instead of a traceback."""
    if info.exc_type is not None and issubclass(info.exc_type, KeyboardInterrupt):
        message = "an interruption arrived during a clean-up and was lost; interrupt again"
    else:
        name = getattr(info.exc_type, "__name__", "error")
        message = f"ignored {name}: {one_line(info.exc_value, 200)}"
    print(f"bifid: warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``bifid`` console script.

    Exits with the documented codes (0, 2, 3, 4, 130; see :mod:`bifid.cli._common`);
    SIGTERM is handled as an interruption (outputs already written stay valid).
    """
    import signal
    import warnings

    import typer

    args = list(argv if argv is not None else sys.argv[1:])
    previous_term = None
    with contextlib.suppress(ValueError):  # only the main thread may set handlers
        previous_term = signal.signal(signal.SIGTERM, _raise_interrupt)
    shown, unraisable = warnings.showwarning, sys.unraisablehook
    warnings.showwarning, sys.unraisablehook = _show_warning, _unraisable
    REPORTED.clear()
    try:
        _enable_compilation_cache()
        load_commands()
        rv = app(args=args, prog_name="bifid", standalone_mode=False)
        code = rv if isinstance(rv, int) else 0
        if code == EXIT_INTERRUPTED and not REPORTED:  # typer's own Ctrl-C handling
            code = _failure(KeyboardInterrupt(), args)
    except typer.Exit as exc:
        code = exc.exit_code
    except SystemExit as exc:  # typer exits 1 when stdout is a closed pipe
        code = exc.code if exc.code in EXIT_CODES else EXIT_ENVIRONMENT
    except (typer.Abort, KeyboardInterrupt):
        code = _failure(KeyboardInterrupt(), args)
    except Exception as exc:
        if is_usage_error(exc):
            code = _usage_error(exc)
        elif os.environ.get("BIFID_DEBUG"):
            raise
        else:
            code = _failure(exc, args)
    finally:
        warnings.showwarning, sys.unraisablehook = shown, unraisable
        if previous_term is not None:
            signal.signal(signal.SIGTERM, previous_term)
    _flush_stdout()
    sys.exit(code)


def _flush_stdout() -> None:
    """Flush stdout; a reader that went away (``bifid ... | head``) is not an error."""
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        # point stdout at devnull so the interpreter's own flush at exit stays quiet
        devnull = os.open(os.devnull, os.O_WRONLY)
        with contextlib.suppress(OSError, ValueError, AttributeError):
            os.dup2(devnull, sys.stdout.fileno())


__all__ = ["app", "fit_app", "load_commands", "main"]
