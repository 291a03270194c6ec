"""Dynamical systems: one module per built-in system, the registry, and system files.

Each built-in lives in one module (``hopf``, ``vanderpol``, ``flutter``, ``duffing``,
``shaw_pierre``) holding its JAX field, parameters with units, safety envelope and CBC
settings. :func:`get_system` also resolves a system file (``model.py``, ``model.py:name``,
``model.toml``) and installed packages' entry points of the group ``bifid.systems``.

>>> from bifid.systems import get_system
>>> get_system("flutter").states
('h', 'hd', 'alpha', 'alphad', 'w', 'wd')
"""

from bifid.systems._base import Envelope, Parameter, System, state_direction
from bifid.systems._files import systems_in_file
from bifid.systems._registry import (
    BUILT_IN,
    ENTRY_POINT_GROUP,
    SystemEntry,
    get_system,
    list_systems,
    register,
    system_entries,
)
from bifid.systems.flutter import flutter_matrices

__all__ = [
    "BUILT_IN",
    "ENTRY_POINT_GROUP",
    "Envelope",
    "Parameter",
    "System",
    "SystemEntry",
    "flutter_matrices",
    "get_system",
    "list_systems",
    "register",
    "state_direction",
    "system_entries",
    "systems_in_file",
]
