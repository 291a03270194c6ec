"""Reference systems and the system registry.

>>> from bifid.systems import get_system
>>> get_system("flutter").states
('h', 'hd', 'alpha', 'alphad', 'w', 'wd')
"""

from bifid.systems._base import Envelope, Parameter, System, get_system, list_systems, register
from bifid.systems._library import duffing, flutter, flutter_matrices, hopf, shaw_pierre, vanderpol

__all__ = [
    "Envelope",
    "Parameter",
    "System",
    "duffing",
    "flutter",
    "flutter_matrices",
    "get_system",
    "hopf",
    "list_systems",
    "register",
    "shaw_pierre",
    "vanderpol",
]
