"""Control-based continuation (CBC) on rigs, thesis chapter 3 (user guide: ``docs/cbc.md``).

- Rigs: :class:`AbstractRig` (what an experiment offers CBC), :class:`VirtualRig` (a System
  simulated as one: sampled controller, zero-order hold, noise, saturation, safety
  envelope), and the :class:`Measurement` a run returns.
- Controllers and targets: :class:`PDController`, :class:`FourierTarget` (eq. 3.3),
  :class:`EllipticTarget` (eqs. 3.13, 3.28), :class:`PolarTarget` (eqs. 3.20-3.22).
- Measured zero problems (:class:`MeasuredProblem`): :class:`PPCBCProblem` (self-excited
  systems, §3.3) and :class:`ForcedProblem` (S-curves and FRCs, §3.2), solved by the
  :class:`BroydenCorrector` on the continuation driver of :mod:`bifid.continuation`;
  :func:`ppcbc_scan`, the amplitude scan at one parameter value (§3.3.3.2).
- Campaigns: :func:`run_campaign` (the one runner: point by point, resumable, retries,
  failures recorded), with :func:`ppcbc_campaign` and :func:`forced_campaign` building
  the rig and options from the system (:func:`defaults_for`); results are a
  :class:`~bifid.continuation.Diagram` and a :mod:`bifid.data` dataset.
- Stability: :func:`switch_off_test` (measured, Fig. 3.18) and :func:`controlled_floquet`
  (Floquet multipliers of the controlled system, Fig. 3.9).
"""

from bifid.cbc._campaign import CampaignResult, CampaignSpec
from bifid.cbc._campaigns import (
    forced_campaign,
    frc_cbc,
    noise_levels,
    ppcbc_campaign,
    scurve_cbc,
)
from bifid.cbc._controllers import (
    AbstractTarget,
    EllipticTarget,
    FourierTarget,
    PDController,
    PolarTarget,
)
from bifid.cbc._defaults import CBCDefaults, defaults_for
from bifid.cbc._derive import retry_controller
from bifid.cbc._forced import ForcedProblem
from bifid.cbc._forced_measure import ForcedCBCOptions, ForcedPoint, folds_of
from bifid.cbc._measured import (
    BroydenCorrector,
    Evaluation,
    Failure,
    MeasuredProblem,
    RigTripped,
)
from bifid.cbc._ppcbc import LCOPoint, PPCBCOptions, PPCBCProblem
from bifid.cbc._ppcbc_scan import ppcbc_scan
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.cbc._runner import run_campaign
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
    "BroydenCorrector",
    "CBCDefaults",
    "CampaignResult",
    "CampaignSpec",
    "EllipticTarget",
    "Evaluation",
    "Failure",
    "ForcedCBCOptions",
    "ForcedPoint",
    "ForcedProblem",
    "FourierTarget",
    "LCOPoint",
    "MeasuredProblem",
    "Measurement",
    "PDController",
    "PPCBCOptions",
    "PPCBCProblem",
    "PolarTarget",
    "RigTripped",
    "StabilityResult",
    "VirtualRig",
    "controlled_floquet",
    "defaults_for",
    "folds_of",
    "forced_campaign",
    "frc_cbc",
    "noise_levels",
    "orbit_polar_target",
    "ppcbc_campaign",
    "ppcbc_scan",
    "retry_controller",
    "run_campaign",
    "scurve_cbc",
    "switch_off_test",
]
