"""The rig protocol: what a CBC protocol may do to an experiment, and what it gets back.

A rig is something that can only be *pushed and measured*, like a laboratory rig:

- :meth:`AbstractRig.set_parameter` -- change a physical parameter (wind speed, ...);
- :meth:`AbstractRig.set_forcing` -- switch the harmonic excitation
  ``γ cos(θ(t) - ψ)``, ``θ̇ = Ω``, on (amplitude, frequency, phase) or off;
- :meth:`AbstractRig.set_controller` -- switch a feedback controller with its target on
  (or off with ``None``);
- :meth:`AbstractRig.run` -- let time pass and return the sampled signals.

The rig keeps its state between calls: there is no reset, so every change is followed
by a real transient (:meth:`AbstractRig.rest`, where a rig offers it, only does what its
safety gate does: the rig brought to rest at its rest position). CBC code in
:mod:`bifid.cbc` uses nothing else, so a real rig only has to implement these methods
(see ``docs/cbc.md``).
"""

from __future__ import annotations

import abc
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bifid.cbc._controllers import AbstractTarget, PDController

__all__ = ["AbstractRig", "Measurement"]


@dataclass(frozen=True, eq=False)
class Measurement:
    """Signals sampled by a rig during one :meth:`AbstractRig.run`.

    Attributes
    ----------
    time : ndarray of shape (n,)
        Sample times [s] on the rig's clock (continues across runs).
    outputs : ndarray of shape (n, n_outputs)
        Measured outputs (with the rig's measurement noise).
    output_names : tuple of str
    derivatives : ndarray of shape (n, n_outputs)
        The rig's estimates of the outputs' time derivatives (what a controller sees as
        ``"<name>_dot"``).
    control : ndarray of shape (n,)
        Control signal ``u`` applied over ``[t_k, t_k + 1/fs)`` (0 when off).
    target : ndarray of shape (n,)
        Control target ``x1*`` at each sample (NaN when no controller is on).
    force : ndarray of shape (n,)
        Harmonic excitation at each sample (0 when off).
    phase : ndarray of shape (n,)
        Phase ``θ`` of the forcing generator (NaN when forcing is off).
    sample_rate : float
        [Hz].
    saturated : int
        Number of samples at which the actuator saturated.
    extra : dict
        Rig-specific extras (a virtual rig adds the true ``states``).
    status : {"ok", "tripped"}
        ``tripped`` when the rig's safety gate fired during the run (a state or the
        actuator left the safety envelope, or the rig could not keep its state finite):
        the controller was disarmed and the rig brought to rest; the samples up to the
        trip are returned.
    reason : str
        Why it tripped (which limit, at what time), empty when ``ok``.
    """

    time: np.ndarray
    outputs: np.ndarray
    output_names: tuple[str, ...]
    derivatives: np.ndarray
    control: np.ndarray
    target: np.ndarray
    force: np.ndarray
    phase: np.ndarray
    sample_rate: float
    saturated: int = 0
    extra: dict[str, Any] = field(default_factory=dict)
    status: str = "ok"
    reason: str = ""

    def __len__(self) -> int:
        return int(self.time.shape[0])

    def signal(self, name: str) -> np.ndarray:
        """An output (``"h"``) or its derivative estimate (``"h_dot"``) by name."""
        if name in self.output_names:
            return self.outputs[:, self.output_names.index(name)]
        if name.endswith("_dot") and name[:-4] in self.output_names:
            return self.derivatives[:, self.output_names.index(name[:-4])]
        raise KeyError(
            f"no signal {name!r}; outputs are {', '.join(self.output_names)} "
            "(and their derivative estimates '<name>_dot')."
        )

    def tail(self, n: int) -> Measurement:
        """The last ``n`` samples."""
        n = max(0, min(int(n), len(self)))
        sl = slice(len(self) - n, None)
        extra = {
            k: (v[sl] if isinstance(v, np.ndarray) and v.shape[:1] == self.time.shape else v)
            for k, v in self.extra.items()
        }
        return Measurement(
            time=self.time[sl],
            outputs=self.outputs[sl],
            output_names=self.output_names,
            derivatives=self.derivatives[sl],
            control=self.control[sl],
            target=self.target[sl],
            force=self.force[sl],
            phase=self.phase[sl],
            sample_rate=self.sample_rate,
            saturated=self.saturated,
            extra=extra,
            status=self.status,
            reason=self.reason,
        )


class AbstractRig(abc.ABC):
    """An experiment that CBC can push and measure (see the module docstring).

    Implementations keep their state between calls and never reset: a change of
    parameter, forcing or controller is followed by a transient, as on a real rig.
    """

    @property
    @abc.abstractmethod
    def output_names(self) -> tuple[str, ...]:
        """Names of the measured outputs (e.g. ``("h", "alpha")``)."""

    @property
    @abc.abstractmethod
    def sample_rate(self) -> float:
        """Sampling (and control) rate [Hz]."""

    @property
    @abc.abstractmethod
    def time(self) -> float:
        """Current time on the rig's clock [s]."""

    @abc.abstractmethod
    def get_parameter(self, name: str) -> float:
        """Current value of a physical parameter."""

    @abc.abstractmethod
    def set_parameter(self, name: str, value: float) -> None:
        """Change a physical parameter (e.g. the wind speed ``U``)."""

    @abc.abstractmethod
    def set_forcing(
        self, amplitude: float | None, frequency: float | None = None, phase: float = 0.0
    ) -> None:
        """Excite with ``amplitude cos(θ(t) - phase)``, ``θ̇ = frequency`` [rad/s].

        ``amplitude=None`` switches the excitation off. The generator phase ``θ`` is
        continuous across changes of frequency.
        """

    @abc.abstractmethod
    def set_controller(
        self, controller: PDController | None, target: AbstractTarget | None = None
    ) -> None:
        """Switch a controller with its target on, or off with ``controller=None``."""

    @abc.abstractmethod
    def run(self, duration: float) -> Measurement:
        """Let ``duration`` seconds pass and return what was sampled meanwhile."""

    def seed(self, seed: int) -> None:  # noqa: B027 - optional: rigs without noise ignore it
        """Restart the rig's measurement-noise stream from ``seed`` (a campaign seeds each
        point from its index, so that a resumed campaign measures exactly what an
        uninterrupted one would)."""

    def rest(self) -> bool:
        """Disarm the controller, switch the forcing off and bring the rig to rest at its
        rest position, as its safety gate does (optional). Returns False when the rig
        cannot (the default): then only the controller can move it."""
        return False

    def describe(self) -> Mapping[str, Any]:
        """Settings worth recording with a dataset (JSON-able)."""
        return {
            "rig": type(self).__name__,
            "outputs": list(self.output_names),
            "sample_rate": self.sample_rate,
        }
