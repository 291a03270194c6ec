"""Systems from files: ``model.py`` (a module that calls :func:`bifid.systems.register`) and
``model.toml`` (equations as text, :mod:`bifid.systems._toml`).

A file is read once per modification: its systems are cached by the resolved path, the
modification time and the size, so every command of a session sees the same
:class:`~bifid.systems.System` objects (and the compiled functions keyed on them are reused).
"""

from __future__ import annotations

import contextvars
import hashlib
import importlib.util
import stat as stat_mode
import sys
import traceback
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from bifid.errors import BifidInputError
from bifid.systems._base import System

__all__ = ["COLLECTING", "load_system_file", "systems_in_file"]

#: While a ``.py`` system file runs, :func:`bifid.systems.register` puts its systems here.
COLLECTING: contextvars.ContextVar[dict[str, Callable[[], System]] | None] = contextvars.ContextVar(
    "bifid_systems_collecting", default=None
)

_CACHE: dict[Path, tuple[tuple[int, int], dict[str, System]]] = {}


def systems_in_file(path: str | Path) -> dict[str, System]:
    """The systems a ``.py`` or ``.toml`` file defines, by name (each with ``source`` the
    file's path).

    Raises
    ------
    BifidInputError
        If the file is missing, has another suffix, or is malformed (one line naming the file
        and what is wrong).
    """
    given = Path(path).expanduser()
    if given.suffix not in (".py", ".toml"):
        raise BifidInputError(
            f"{path}: a system file must end in .py or .toml, got {given.suffix or 'no suffix'!r}."
        )
    try:
        resolved = given.resolve(strict=True)
        stat = resolved.stat()
    except OSError:
        raise BifidInputError(
            f"{path}: no such system file (give a registered system name, or the path of a "
            ".py or .toml system file)."
        ) from None
    if not stat_mode.S_ISREG(stat.st_mode):
        # checked before opening: a FIFO would block the reader, a device never ends
        raise BifidInputError(f"{path}: a system file must be a regular file (this is not).")
    stamp = (stat.st_mtime_ns, stat.st_size)
    cached = _CACHE.get(resolved)
    if cached is not None and cached[0] == stamp:
        return cached[1]
    if resolved.suffix == ".toml":
        # SymPy takes most of a second to import: only when a .toml file is read
        from bifid.systems._toml import system_from_toml

        system = system_from_toml(resolved, label=str(path))
        systems = {system.name: system}
    else:
        systems = _systems_from_python(resolved, label=str(path))
    _CACHE[resolved] = (stamp, systems)
    return systems


def load_system_file(path: str | Path, name: str | None = None) -> System:
    """The system of a file; ``name`` picks one when the file defines several."""
    systems = systems_in_file(path)
    if name is None:
        if len(systems) == 1:
            return next(iter(systems.values()))
        raise BifidInputError(
            f"{path} defines several systems ({', '.join(systems)}); pick one with {path}:NAME."
        )
    try:
        return systems[name]
    except KeyError:
        raise BifidInputError(
            f"{path} defines no system {name!r}; it defines: {', '.join(systems)}."
        ) from None


def _line_in(exc: BaseException, path: Path) -> str:
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if Path(f.filename) == path]
    return f"line {frames[-1].lineno}: " if frames else ""


def _user_error(exc: Exception, path: Path, label: str) -> BifidInputError:
    if isinstance(exc, BifidInputError):
        return BifidInputError(f"{label}: {_line_in(exc, path)}{exc}")
    if isinstance(exc, SyntaxError):
        return BifidInputError(f"{label}: line {exc.lineno}: syntax error: {exc.msg}")
    return BifidInputError(f"{label}: {_line_in(exc, path)}{type(exc).__name__}: {exc}")


def _systems_from_python(path: Path, label: str) -> dict[str, System]:
    """Execute the module at ``path`` and collect the systems it registers."""
    module_name = "bifid_system_file_" + hashlib.sha256(str(path).encode()).hexdigest()[:16]
    spec = importlib.util.spec_from_file_location(module_name, path)
    if spec is None or spec.loader is None:
        raise BifidInputError(f"{label}: cannot be loaded as a Python module.")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module  # dataclasses and pickling-free tools look it up
    collected: dict[str, Callable[[], System]] = {}
    token = COLLECTING.set(collected)
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # the user's module: one line, never a traceback
        sys.modules.pop(module_name, None)
        raise _user_error(exc, path, label) from None
    finally:
        COLLECTING.reset(token)
    if not collected:
        raise BifidInputError(
            f"{label}: registers no system; call bifid.systems.register(name, System(...)) in it."
        )
    systems: dict[str, System] = {}
    for name, factory in collected.items():
        try:
            system = factory()
        except Exception as exc:
            raise _user_error(exc, path, label) from None
        if not isinstance(system, System):
            raise BifidInputError(
                f"{label}: the factory registered as {name!r} returned "
                f"{type(system).__name__}, not a bifid System."
            )
        systems[name] = replace(system, source=str(path))
    return systems
