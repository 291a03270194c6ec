"""Control-based continuation (CBC) on rigs, thesis chapter 3 (user guide: ``docs/cbc.md``).

- Rigs: :class:`AbstractRig` (what an experiment offers CBC), :class:`VirtualRig` (a System
  simulated as one: sampled controller, zero-order hold, noise, saturation), and the
  :class:`Measurement` a run returns.
- Controllers and targets: :class:`PDController`, :class:`FourierTarget` (eq. 3.3),
  :class:`EllipticTarget` (eqs. 3.13, 3.28), :class:`PolarTarget` (eqs. 3.20-3.22).
- Protocols: :func:`scurve_cbc` and :func:`frc_cbc` (forced systems, §3.2),
  :func:`ppcbc_scan`, :func:`ppcbc_sweep` and :func:`ppcbc_continuation` (self-excited
  systems, §3.3), with their options and point types.
- Campaigns (rig + protocol + dataset in one call, as ``bifid demo`` runs them):
  :func:`lco_campaign` (PP-CBC scan + continuation) and :func:`scurve_campaign`.
- Stability: :func:`switch_off_test` (measured, Fig. 3.18) and :func:`controlled_floquet`
  (Floquet multipliers of the controlled system, Fig. 3.9).
"""

from bifid.cbc._campaign import lco_campaign, scurve_campaign
from bifid.cbc._controllers import (
    AbstractTarget,
    EllipticTarget,
    FourierTarget,
    PDController,
    PolarTarget,
)
from bifid.cbc._defaults import CBCDefaults, defaults_for
from bifid.cbc._forced import (
    ForcedCBCOptions,
    ForcedFailure,
    ForcedPoint,
    folds_of,
    frc_cbc,
    scurve_cbc,
)
from bifid.cbc._ppcbc import (
    LCOPoint,
    PPCBCFailure,
    PPCBCOptions,
    ppcbc_continuation,
    ppcbc_scan,
    ppcbc_sweep,
)
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.cbc._stability import (
    StabilityResult,
    controlled_floquet,
    orbit_polar_target,
    switch_off_test,
)
from bifid.cbc._virtual import VirtualRig

__all__ = [
    "AbstractRig",
    "AbstractTarget",
    "CBCDefaults",
    "EllipticTarget",
    "ForcedCBCOptions",
    "ForcedFailure",
    "ForcedPoint",
    "FourierTarget",
    "LCOPoint",
    "Measurement",
    "PDController",
    "PPCBCFailure",
    "PPCBCOptions",
    "PolarTarget",
    "StabilityResult",
    "VirtualRig",
    "controlled_floquet",
    "defaults_for",
    "folds_of",
    "frc_cbc",
    "lco_campaign",
    "orbit_polar_target",
    "ppcbc_continuation",
    "ppcbc_scan",
    "ppcbc_sweep",
    "scurve_campaign",
    "scurve_cbc",
    "switch_off_test",
]
