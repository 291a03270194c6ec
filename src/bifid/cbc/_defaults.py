"""CBC settings of a system: derived from the system, overridden by ``System.cbc``.

A new system's first campaign must work without tuning, so every setting has a value
derived from the system itself (:mod:`bifid.cbc._derive`): the sample rate, gains,
settling time and amplitude grid come from its linearisation (natural or Hopf frequency,
damping) and, for self-excited systems, from a first continuation run of its limit
cycles (their amplitudes set the scan's grid and the reference of relative noise; the
gains are the candidates whose *controlled* Floquet multipliers are smallest on those
orbits, :func:`~bifid.cbc.controlled_floquet`). A system's own ``cbc`` dict (e.g. the
gains validated on a laboratory rig) overrides any of them; its keys are the fields of
:class:`CBCDefaults`. Its amplitude grid, noise reference and frequency belong to the
system's default parameters: with other values of the other parameters (a variant of the
system) they are derived again. Derivations run only for what the system does not set.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from bifid.cbc._derive import derive
from bifid.cbc._forced_measure import ForcedCBCOptions
from bifid.cbc._ppcbc import PPCBCOptions
from bifid.cbc._virtual import VirtualRig
from bifid.errors import BifidInputError
from bifid.systems import System, get_system

__all__ = ["CBCDefaults", "defaults_for"]


@dataclass(frozen=True)
class CBCDefaults:
    """Settings that make CBC work on one system (module docstring).

    Attributes
    ----------
    sample_rate : float
        Sampling and control rate of the rig [Hz].
    derivative_cutoff : float or None
        Low-pass cut-off of the rig's derivative estimates [Hz].
    outputs : tuple of str
        Measured states.
    x1, x2 : str
        PP-CBC phase-plane signals; ``kp``, ``kd`` the gains (forced CBC: on ``signal``).
    bootstrap_gains : (float, float) or None
        PP-CBC: gains of the elliptic ``(x1, ẋ1)`` target that starts an oscillation.
    filter_hz : float or None
        Cut-off of the controller's output low-pass.
    amplitude_range, n_amplitudes
        PP-CBC scan grid of target amplitudes.
    omega_guess : float
        Frequency of the oscillations [rad/s].
    signal : str
        Forced CBC: the controlled (observed) output.
    n_harmonics, settle_periods, measure_periods
        Target harmonics, periods to settle and to record.
    noisy_options : dict
        Forced CBC with noisy measurements: option overrides (lower gains).
    signal_units : dict
    noise_reference : dict
        Amplitudes per output that a relative noise level refers to (the smallest
        limit cycle of the range, or the response at the start of a forced range).
    equilibrium : dict
        The free system's equilibrium per state (from the linearisation): the PP-CBC
        bootstrap centres its first target there.
    origin : dict
        Where each value came from: ``"system"`` (``System.cbc``) or ``"derived"``.
    """

    sample_rate: float = 5000.0
    derivative_cutoff: float | None = None
    outputs: tuple[str, ...] = ()
    x1: str = ""
    x2: str = ""
    kp: float = 1.0
    kd: float = 1.0
    bootstrap_gains: tuple[float, float] | None = None
    filter_hz: float | None = None
    amplitude_range: tuple[float, float] = (0.1, 1.0)
    n_amplitudes: int = 16
    omega_guess: float = 1.0
    signal: str = ""
    n_harmonics: int = 5
    settle_periods: float = 10.0
    measure_periods: float = 5.0
    noisy_options: dict[str, Any] = field(default_factory=dict)
    signal_units: dict[str, str] = field(default_factory=dict)
    noise_reference: dict[str, float] = field(default_factory=dict)
    equilibrium: dict[str, float] = field(default_factory=dict)
    origin: dict[str, str] = field(default_factory=dict)

    def centre(self, x1: str, x2: str) -> tuple[float, float]:
        """The equilibrium in the phase plane ``(x1, x2)`` (a derivative's is 0)."""
        return (self.equilibrium.get(x1, 0.0), self.equilibrium.get(x2, 0.0))

    def ppcbc_options(self, **overrides: Any):
        """:class:`~bifid.cbc.PPCBCOptions` with these defaults (and overrides)."""
        kw: dict[str, Any] = dict(
            x1=self.x1,
            x2=self.x2,
            kp=self.kp,
            kd=self.kd,
            settle_periods=self.settle_periods,
            measure_periods=self.measure_periods,
            bootstrap_gains=self.bootstrap_gains,
            filter_hz=self.filter_hz,
        )
        x1, x2 = overrides.get("x1", self.x1), overrides.get("x2", self.x2)
        if any(self.centre(x1, x2)):
            kw["centre"] = self.centre(x1, x2)
        kw.update(overrides)
        return PPCBCOptions(**kw)

    def forced_options(self, *, noisy: bool = False, **overrides: Any):
        """:class:`~bifid.cbc.ForcedCBCOptions` with these defaults, the system's
        ``noisy_options`` when the measurements are noisy, then ``overrides``."""
        kw: dict[str, Any] = dict(
            signal=self.signal,
            kp=self.kp,
            kd=self.kd,
            n_harmonics=self.n_harmonics,
            settle_periods=self.settle_periods,
            measure_periods=self.measure_periods,
        )
        if noisy:
            kw.update(self.noisy_options)
        kw.update(overrides)
        return ForcedCBCOptions(**kw)

    def rig(self, system: System, params: Mapping[str, float] | None = None, **overrides: Any):
        """A :class:`~bifid.cbc.VirtualRig` of ``system`` with these defaults."""
        kw: dict[str, Any] = dict(
            sample_rate=self.sample_rate,
            outputs=self.outputs or None,
            derivative_cutoff=self.derivative_cutoff,
        )
        kw.update(overrides)
        return VirtualRig(system, params, **kw)


_NAMES = {f.name for f in fields(CBCDefaults)} - {"origin"}
#: settings that depend on the amplitudes of the system's orbits, hence on its parameters
_AMPLITUDE_SETTINGS = ("amplitude_range", "n_amplitudes", "noise_reference", "omega_guess")


def defaults_for(
    system: System | str,
    params: Mapping[str, float] | None = None,
    *,
    param: str | None = None,
    param_range: tuple[float, float] | None = None,
    noise_reference: bool = False,
) -> CBCDefaults:
    """CBC settings of ``system``: ``System.cbc`` where it sets them, derived otherwise.

    Parameters
    ----------
    system : System or str
    params : dict, optional
        Parameter overrides at which to derive (default values otherwise).
    param, param_range : optional
        Self-excited systems: the bifurcation parameter and the range a campaign spans
        (the continuation run that sets the amplitude grid covers it).
    noise_reference : bool
        Derive the reference amplitudes of relative noise too (when the system does not
        give them).

    Raises
    ------
    BifidInputError
        If ``System.cbc`` names a setting that does not exist.
    """
    if isinstance(system, str):
        system = get_system(system)
    given = dict(system.cbc)
    unknown = sorted(set(given) - _NAMES - {"extra"})
    if unknown:
        raise BifidInputError(
            f"System {system.name!r}: unknown CBC settings {unknown}; known: "
            f"{', '.join(sorted(_NAMES))}."
        )
    extra = given.pop("extra", {}) or {}
    if "noise_reference" in extra and "noise_reference" not in given:
        given["noise_reference"] = dict(extra["noise_reference"])
    defaults = system.param_dict(system.param_vector())
    if any(
        float(v) != defaults[k]
        for k, v in dict(params or {}).items()
        if k != param and k in defaults
    ):
        # the amplitudes (and frequencies) of the system's settings belong to its default
        # parameters: another variant of the system gets them from its own cycles
        for key in _AMPLITUDE_SETTINGS:
            given.pop(key, None)
    for key in ("outputs", "amplitude_range", "bootstrap_gains"):
        if given.get(key) is not None:
            given[key] = tuple(given[key])
    derived = derive(system, dict(params or {}), set(given), param, param_range, noise_reference)
    origin = {k: "system" for k in given} | {k: "derived" for k in derived if k not in given}
    return CBCDefaults(**{**derived, **given, "origin": origin})
