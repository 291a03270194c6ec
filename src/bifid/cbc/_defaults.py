"""Per-system CBC settings that work: gains, signals, sample rates, amplitude grids.

Every gain pair below was chosen from the Floquet multipliers of the *controlled* system
at converged orbits (``controlled_floquet``; the numbers are in ``docs/cbc.md`` and
checked by ``tests/test_cbc_stability.py``):

- ``flutter`` -- PP-CBC in the plane of the two measured displacements ``(h, α)``
  (laser and encoder on the rig: no derivative is estimated), control on the heave
  equation (eq. 3.25), polar target with ``n_h = 10``: ``kp = -150, kd = -20`` keep every
  non-trivial multiplier below 0.48 on both branches for U = 15-18 m/s (0.43-0.48; the
  unstable LCOs have 1.05-1.16 without control). With noisy measurements this is the
  plane to use: the gains multiply the raw noise of h and α (0.015 m/s² for 1 % noise)
  instead of a differentiated one. The oscillation is started from rest by an elliptic
  ``(h, ḣ)`` target with ``kp = 50, kd = 40`` (``bootstrap_gains``). The controller's
  output passes a 100 Hz first-order low-pass (``filter_hz``; 2.5 Hz LCOs, 1.4° of lag):
  with 1 % measurement noise it cuts the noise the gains pass to the shaker from ~1 % to
  ~0.25 % of the feedback, and the controlled multipliers stay below 0.6 (filter state
  included). The bootstrap controller (its own plane and gains) runs unfiltered, as its
  gains were validated. The ``(h, ḣ)`` plane also
  works (``--x2 h_dot --kp 50 --kd 40``: multipliers <= 0.58; ``kd > 0`` adds damping in
  proportion to the radial error) but its derivative estimate feeds noise through
  ``kd``. (The thesis's ``kp = kd = -100`` of Example 3.3 are unstable in either plane
  with our conventions.)
- ``hopf`` -- PP-CBC on ``(u1, u2)``, control on ``u1``: ``kp = 1`` gives a radial
  feedback ``kp (r* - r)/2`` that beats the LCO's instability ``2 r0² = 0.2`` of eq. 3.16
  (multiplier 0.15); the thesis's ``kp = 0.5, kd = -0.5`` also work (0.73).
- ``duffing`` -- ``kp = kd = 0.5`` on ``q``: multipliers 0.21 on all three branches
  (the middle branch is a saddle with multiplier up to 1.11 without control). With
  measurement noise (``noisy_options``, see shaw_pierre for why): ``kp = kd = 0.1``,
  multipliers <= 0.70 (``kp = kd = 0.2``: 0.52; ``kd = 0.1`` alone: 0.83).
- ``shaw_pierre`` -- ``kp = kd = 1`` on ``x1``: multipliers <= 0.44 (the thesis's 0.01
  stabilise too, but at 0.976 per period a point takes hundreds of periods to settle).
  With measurement noise (``noisy_options``): ``kp = 0, kd = 0.1``, multipliers <= 0.86
  (``kp = kd = 0.1``: 0.86, ``kp = kd = 0.3``: 0.67; the uncontrolled middle branch has
  1.009). Why lower gains: the controller feeds the measurement noise ``ε`` back as a
  force, and the fundamental of that force -- which the forcing update of eq. 3.6 must
  tell apart from zero -- has the standard error ``σ_ε |k_p + iΩk_d| sqrt(2/n)`` over
  ``n`` samples. Relative to the forcing ``γ ≈ 0.01`` of the S-curve at Ω = 1.005 with
  ``σ_ε`` = 1 % of the largest response (0.036) this is ``5 sqrt(2/n)`` for
  ``kp = kd = 1``: verifying a point to 0.5 % of ``γ`` (3σ) would take ~30 000 forcing
  periods, against ~100-400 with ``|k_p + iΩk_d| = 0.1``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

__all__ = ["CBCDefaults", "defaults_for"]


@dataclass(frozen=True)
class CBCDefaults:
    """Settings that make CBC work on one registered system."""

    sample_rate: float = 5000.0
    derivative_cutoff: float | None = None
    outputs: tuple[str, ...] | None = None
    # phase-plane CBC (autonomous systems)
    x1: str = ""
    x2: str = ""
    kp: float = 1.0
    kd: float = 1.0
    bootstrap_gains: tuple[float, float] | None = None
    filter_hz: float | None = None
    amplitude_range: tuple[float, float] = (0.1, 1.0)
    n_amplitudes: int = 16
    omega_guess: float = 1.0
    # forced CBC
    signal: str = ""
    n_harmonics: int = 5
    settle_periods: float = 10.0
    measure_periods: float = 5.0
    # forced CBC with noisy measurements: ForcedCBCOptions overrides (scurve_campaign)
    noisy_options: dict[str, Any] = field(default_factory=dict)
    signal_units: dict[str, str] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def ppcbc_options(self, **overrides: Any):
        """:class:`~bifid.cbc.PPCBCOptions` with these defaults (and overrides)."""
        from bifid.cbc._ppcbc import PPCBCOptions

        kw: dict[str, Any] = dict(x1=self.x1, x2=self.x2, kp=self.kp, kd=self.kd,
                                  settle_periods=self.settle_periods,
                                  measure_periods=self.measure_periods,
                                  bootstrap_gains=self.bootstrap_gains,
                                  filter_hz=self.filter_hz)
        kw.update(overrides)
        return PPCBCOptions(**kw)

    def forced_options(self, *, noisy: bool = False, **overrides: Any):
        """:class:`~bifid.cbc.ForcedCBCOptions` with these defaults, the system's
        ``noisy_options`` when the measurements are noisy, then ``overrides``."""
        from bifid.cbc._forced import ForcedCBCOptions

        kw: dict[str, Any] = dict(signal=self.signal, kp=self.kp, kd=self.kd,
                                  n_harmonics=self.n_harmonics,
                                  settle_periods=self.settle_periods,
                                  measure_periods=self.measure_periods)
        if noisy:
            kw.update(self.noisy_options)
        kw.update(overrides)
        return ForcedCBCOptions(**kw)

    def rig(self, system, params=None, **overrides: Any):
        """A :class:`~bifid.cbc.VirtualRig` of ``system`` with these defaults."""
        from bifid.cbc._virtual import VirtualRig

        kw: dict[str, Any] = dict(sample_rate=self.sample_rate, outputs=self.outputs,
                                  derivative_cutoff=self.derivative_cutoff)
        kw.update(overrides)
        return VirtualRig(system, params, **kw)


_DEFAULTS: dict[str, CBCDefaults] = {
    "flutter": CBCDefaults(
        sample_rate=5000.0, derivative_cutoff=25.0, outputs=("h", "alpha"), x1="h",
        x2="alpha", kp=-150.0, kd=-20.0, bootstrap_gains=(50.0, 40.0), filter_hz=100.0,
        amplitude_range=(0.004, 0.032), n_amplitudes=15, omega_guess=15.0,
        settle_periods=6.0, measure_periods=4.0,
        signal_units={"h": "m", "alpha": "rad"},
        # the scan grid ends just above the largest stable LCO (30.5 mm at 17 m/s): targets
        # far outside it (34 mm at 17 m/s) are not held and the rig trips (a reported failure)
        # amplitudes of the smallest LCO of the U = 15-17.5 m/s diagram (unstable, 17.5):
        # "1 % noise" means 1 % of these
        extra={"noise_reference": {"h": 0.00743, "alpha": 0.02157}},
    ),
    "hopf": CBCDefaults(
        sample_rate=200.0, outputs=("u1", "u2"), x1="u1", x2="u2", kp=1.0, kd=0.0,
        amplitude_range=(0.05, 0.34), n_amplitudes=8, omega_guess=1.0,
        settle_periods=6.0, measure_periods=3.0,
    ),
    "vanderpol": CBCDefaults(
        sample_rate=200.0, outputs=("z1", "z2"), x1="z1", x2="z1_dot", kp=1.0, kd=1.0,
        amplitude_range=(0.2, 3.0), n_amplitudes=12, omega_guess=1.0,
        settle_periods=8.0, measure_periods=3.0,
    ),
    "duffing": CBCDefaults(
        sample_rate=100.0, outputs=("q",), signal="q", kp=0.5, kd=0.5, n_harmonics=5,
        settle_periods=8.0, measure_periods=3.0,
        noisy_options={"kp": 0.1, "kd": 0.1, "settle_periods": 20.0},
    ),
    "shaw_pierre": CBCDefaults(
        sample_rate=100.0, outputs=("x1", "x2"), signal="x1", kp=1.0, kd=1.0, n_harmonics=5,
        settle_periods=10.0, measure_periods=3.0,
        noisy_options={"kp": 0.0, "kd": 0.1, "settle_periods": 30.0,
                       "max_measure_periods": 1000.0},
    ),
}


def defaults_for(system_name: str) -> CBCDefaults:
    """Known-good CBC settings for a registered system (generic ones otherwise)."""
    return _DEFAULTS.get(system_name, CBCDefaults())
