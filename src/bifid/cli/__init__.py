"""The ``bifid`` command.

Every command accepts ``--json`` (one JSON object on stdout, nothing else there);
progress and logs go to stderr. User errors exit with status 2, numerical failures
with status 3, each with a one-line message on stderr and no traceback.

Sub-commands live in one module each (``_continuation``, ``_cbc``, ``_fit_*``,
``_predict``, ``_data``, ``_demo``) and register themselves on :data:`app`.
"""

from __future__ import annotations

import importlib
import sys

from bifid.cli._common import app, fit_app

_COMMAND_MODULES = (
    "bifid.cli._continuation",
    "bifid.cli._cbc",
    "bifid.cli._fit_hopf",
    "bifid.cli._fit_forced",
    "bifid.cli._fit_mechanistic",
    "bifid.cli._predict",
    "bifid.cli._data",
    "bifid.cli._demo",
)


def _load_commands() -> None:
    for name in _COMMAND_MODULES:
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as exc:  # a capability not built yet
            if exc.name != name:
                raise


def _enable_compilation_cache() -> None:
    """Persistent XLA cache: repeated commands skip JIT compilation.

    ``BIFID_JAX_CACHE=""`` disables it; another path moves it.
    """
    import os
    from pathlib import Path

    import jax

    path = os.environ.get("BIFID_JAX_CACHE", str(Path.home() / ".cache" / "bifid" / "jax"))
    if path:
        jax.config.update("jax_compilation_cache_dir", path)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the ``bifid`` console script."""
    import typer

    _enable_compilation_cache()
    _load_commands()
    try:
        rv = app(args=argv if argv is not None else sys.argv[1:], prog_name="bifid",
                 standalone_mode=False)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort:
        print("bifid: error: aborted", file=sys.stderr)
        sys.exit(130)
    except Exception as exc:
        # usage errors (unknown option, missing value) of typer's bundled click: one line
        if hasattr(exc, "format_message") and hasattr(exc, "exit_code"):
            ctx = getattr(exc, "ctx", None)
            name = "" if ctx is None or ctx.info_name == "bifid" else f" {ctx.info_name}"
            hint = f" (see 'bifid{name} --help')"
            print(f"bifid: error: {exc.format_message()}{hint}", file=sys.stderr)
            sys.exit(2 if exc.exit_code == 2 else exc.exit_code)
        raise
    sys.exit(rv if isinstance(rv, int) else 0)


__all__ = ["app", "fit_app", "main"]
