"""The registry of systems: built-ins, systems registered at run time, installed packages'
entry points, and system files.

``get_system(spec)`` resolves, in this order:

1. a path: ``model.py`` (a module that calls :func:`register`), ``model.py:name`` (one of
   several systems it registers) or ``model.toml`` (:mod:`bifid.systems._toml`);
2. a name registered in this process (the built-ins, and :func:`register` calls);
3. the name of an entry point of the group ``bifid.systems`` of an installed package; the
   entry point resolves to a :class:`~bifid.systems.System` or a zero-argument callable
   returning one.

Every system carries where it came from in :attr:`System.source`: ``built-in``, a file path,
or ``package:entry-point``.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import inspect
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from bifid.errors import BifidInputError
from bifid.systems._base import System
from bifid.systems._files import COLLECTING, load_system_file

__all__ = [
    "BUILT_IN",
    "ENTRY_POINT_GROUP",
    "SystemEntry",
    "get_system",
    "list_systems",
    "register",
    "system_entries",
]

#: The modules of :mod:`bifid.systems` that hold one built-in system each (``system()``).
BUILT_IN = ("hopf", "vanderpol", "flutter", "duffing", "shaw_pierre")
#: The entry-point group through which installed packages publish systems.
ENTRY_POINT_GROUP = "bifid.systems"

Factory = Callable[[], System]


@dataclass(frozen=True)
class SystemEntry:
    """One system that :func:`get_system` can resolve by name, and where it comes from."""

    name: str
    source: str
    load: Factory


def _built_in(module_name: str) -> Factory:
    def load() -> System:
        module = importlib.import_module(f"bifid.systems.{module_name}")
        return module.system()

    return load


_REGISTRY: dict[str, SystemEntry] = {
    name: SystemEntry(name, "built-in", _built_in(name)) for name in BUILT_IN
}
_CACHE: dict[str, System] = {}


def _as_factory(name: str, factory: Factory | System) -> Factory:
    if isinstance(factory, System):
        system = factory
        return lambda: system
    if not callable(factory):
        raise BifidInputError(
            f"register({name!r}, ...) needs a System or a zero-argument function returning "
            f"one, got {type(factory).__name__}."
        )
    return factory


def _caller_file() -> str:
    frame = inspect.currentframe()
    try:
        caller = frame.f_back.f_back if frame and frame.f_back else None
        path = caller.f_globals.get("__file__") if caller else None
    finally:
        del frame
    return str(Path(path).resolve()) if path else "<interactive>"


def register(name: str, factory: Factory | System, *, overwrite: bool = False) -> None:
    """Register a system (or a zero-argument factory building one) under ``name``.

    A system registered this way has as ``source`` the file of the module that registered
    it. Inside a system file (``bifid continue model.py ...``) the calls register the file's
    systems, which are then known by the file's path.

    Raises
    ------
    BifidInputError
        If ``name`` is taken (pass ``overwrite=True`` to replace it) or is not a valid name.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from bifid.systems import Parameter, System, register, get_system
    >>> def field(x, p):
    ...     return jnp.array([x[1], -p[0] * x[0] - 0.1 * x[1] - x[0] ** 3])
    >>> register("my_osc", System(name="my_osc", states=("q", "qd"),
    ...          parameters=(Parameter("k", 1.0, "N/m"),), field=field,
    ...          default_param="k"), overwrite=True)
    >>> get_system("my_osc").n_states
    2
    """
    if not isinstance(name, str) or not name or any(c in name for c in ":/\\"):
        raise BifidInputError(
            f"a system name must be a non-empty string without ':', '/' or '\\', got {name!r}."
        )
    load = _as_factory(name, factory)
    collecting = COLLECTING.get()
    if collecting is not None:
        if name in collecting and not overwrite:
            raise BifidInputError(f"the file registers the system {name!r} twice.")
        collecting[name] = load
        return
    if name in _REGISTRY and not overwrite:
        raise BifidInputError(
            f"A system named {name!r} is already registered; pass overwrite=True."
        )
    _REGISTRY[name] = SystemEntry(name, _caller_file(), load)
    _CACHE.pop(name, None)


def _entry_points() -> dict[str, SystemEntry]:
    found: dict[str, SystemEntry] = {}
    for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        dist = ep.dist.name if ep.dist is not None else ep.module
        source = f"{dist}:{ep.name}"
        found.setdefault(ep.name, SystemEntry(ep.name, source, _entry_point_loader(ep, source)))
    return found


def _entry_point_loader(ep: importlib.metadata.EntryPoint, source: str) -> Factory:
    def load() -> System:
        try:
            obj = ep.load()
            system = obj if isinstance(obj, System) else obj() if callable(obj) else obj
        except BifidInputError as exc:
            raise BifidInputError(f"entry point {source} ({ep.value}): {exc}") from None
        except Exception as exc:  # a broken plugin: one line, never a traceback
            raise BifidInputError(
                f"entry point {source} ({ep.value}) failed to load: {type(exc).__name__}: {exc}"
            ) from None
        if not isinstance(system, System):
            raise BifidInputError(
                f"entry point {source} ({ep.value}) must give a bifid System or a "
                f"zero-argument function returning one, got {type(system).__name__}."
            )
        return system

    return load


def system_entries() -> list[SystemEntry]:
    """Every system known by name: built-ins, registered ones, then installed packages'
    entry points (an entry point whose name is taken is left out), sorted by name."""
    entries = dict(_REGISTRY)
    for name, entry in _entry_points().items():
        entries.setdefault(name, entry)
    return [entries[n] for n in sorted(entries)]


def list_systems() -> list[str]:
    """Names of all systems known by name (built-in, registered, installed packages)."""
    return [e.name for e in system_entries()]


def _with_source(system: System, source: str) -> System:
    return system if system.source == source else replace(system, source=source)


def _looks_like_path(spec: str) -> bool:
    base = _split_path(spec)[0]
    return base.endswith((".py", ".toml")) or "/" in base or os.sep in base


def _split_path(spec: str) -> tuple[str, str | None]:
    head, sep, tail = spec.rpartition(":")
    if sep and head.endswith((".py", ".toml")) and tail and "/" not in tail:
        return head, tail
    return spec, None


def get_system(name_or_path: str | os.PathLike) -> System:
    """The system ``name_or_path`` names: a registered name, an installed package's entry
    point, or a system file (``model.py``, ``model.py:name``, ``model.toml``).

    Raises
    ------
    BifidInputError
        If no system of that name is known, or the file is missing or malformed (one line
        naming the file and what is wrong).
    """
    spec = os.fspath(name_or_path)
    if not isinstance(spec, str):
        raise BifidInputError(f"a system is named by a string or a path, got {spec!r}.")
    if isinstance(name_or_path, os.PathLike) or _looks_like_path(spec):
        path, name = _split_path(spec)
        return load_system_file(path, name)
    if spec in _CACHE:
        return _CACHE[spec]
    entry = _REGISTRY.get(spec) or _entry_points().get(spec)
    if entry is None:
        raise BifidInputError(
            f"Unknown system {spec!r}; known systems: {', '.join(list_systems())} "
            "(or give a path to a .py or .toml system file)."
        )
    system = _with_source(_checked(entry.load(), spec), entry.source)
    _CACHE[spec] = system
    return system


def _checked(system: object, name: str) -> System:
    if not isinstance(system, System):
        raise BifidInputError(
            f"the factory registered as {name!r} returned {type(system).__name__}, "
            "not a bifid System."
        )
    return system
