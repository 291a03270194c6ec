"""Control-based continuation (CBC) on rigs, thesis chapter 3.

- :class:`AbstractRig` -- what an experiment offers CBC; :class:`VirtualRig` -- a System
  simulated as one (sampled controller, zero-order hold, noise, saturation).
- Controllers and targets: :class:`PDController`, :class:`FourierTarget` (eq. 3.3),
  :class:`EllipticTarget` (eqs. 3.13, 3.28), :class:`PolarTarget` (eqs. 3.20-3.22).
"""

from bifid.cbc._controllers import (
    AbstractTarget,
    EllipticTarget,
    FourierTarget,
    PDController,
    PolarTarget,
)
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.cbc._virtual import VirtualRig

__all__ = [
    "AbstractRig",
    "AbstractTarget",
    "EllipticTarget",
    "FourierTarget",
    "Measurement",
    "PDController",
    "PolarTarget",
    "VirtualRig",
]
