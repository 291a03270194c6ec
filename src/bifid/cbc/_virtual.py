"""A virtual rig: a System simulated as an experiment with a sampled controller in the loop.

Between samples ``t_k = k / f_s`` the rig integrates

.. math::

    \\dot x = f(x, p) + b(p)\\,γ\\cos(θ(t) - ψ) + e(p)\\,u_k,\\qquad θ̇ = Ω,

with the control ``u_k`` held constant (zero-order hold, as a DAC does). At each sample
it measures the outputs ``y_k = C x(t_k) + ε_k`` (Gaussian noise per channel), estimates
their derivatives, evaluates the controller on those *measurements* and saturates it.

Integration. Each sample interval takes ``m`` classic Runge–Kutta steps with the control
held; an embedded third-order estimate of every step's error (no extra field evaluation)
doubles ``m`` until the error is within ``rtol`` of the state's size, and halves it again
when there is ample margin (:mod:`bifid.cbc._fastloop`). ``m`` never drops below
``substeps``; with ``substeps=1`` and an accurate step the result is plain RK4. The rig is
validated against :func:`bifid.simulate` (diffrax, adaptive Dopri).

Safety gate. At each sample the true state must lie inside the envelope (the system's
:attr:`~bifid.systems.System.envelope` unless one is given), the controller output within
its actuator limit, and everything must stay finite (if the integration cannot keep the
state finite or accurate even with ``max_substeps`` steps, the gate trips as well). A trip
disarms the controller, switches the forcing off and brings the rig to rest (the
equilibrium of the free system that a solve of ``f(x, p) = 0`` from the initial state
reaches); the run returns the samples
before the trip with ``Measurement.status == "tripped"`` and the ``reason``.

Engines (``engine=``):

- ``"numba"``: the loop compiled by numba for this system's own field -- the field is
  translated to scalar code from its jaxpr (:mod:`bifid.cbc._codegen`) and compiled
  once per field, cached on disk (:mod:`bifid.cbc._compiled`): a few hundred ns a sample;
- ``"jax"``: one compiled :func:`jax.lax.scan` per block of samples
  (:mod:`bifid.cbc._jaxloop`), for fields with operations the translator cannot express
  on the state (about ten times slower);
- ``"auto"`` (default): numba whenever the field translates, JAX otherwise.

Both draw the measurement noise from one seeded :class:`numpy.random.Generator` owned by
the rig (:meth:`VirtualRig.seed` restarts it) and agree sample for sample to rounding.

Derivative estimates (``"<output>_dot"`` signals):

- ``derivative="samples"`` (default, as on a real rig): backward difference of the
  measured samples through a first-order low-pass at ``derivative_cutoff`` Hz,
  ``d_k = d_{k-1} + a (f_s (y_k - y_{k-1}) - d_{k-1})``, ``a = 1 - exp(-2π f_c / f_s)``;
- ``derivative="state"``: the exact derivative of the (noise-free) state, as from a
  perfect velocity sensor.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bifid.cbc._compiled import CompiledLoop, compiled_loop
from bifid.cbc._controllers import AbstractTarget, PDController, target_to_json
from bifid.cbc._fastfield import check_batched
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.cbc._rigstate import Engines, RigSettings, rest_state, trip_reason
from bifid.errors import BifidInputError, ConvergenceWarning
from bifid.systems import Envelope, System

__all__ = ["VirtualRig"]


class VirtualRig(AbstractRig):
    """A :class:`~bifid.systems.System` run as an experiment (see the module docstring).

    Parameters
    ----------
    system : System
    params : mapping, optional
        Parameter overrides (``{"U": 16.0}``); the rest take their defaults.
    outputs : sequence of str, optional
        Measured states (default: the system's ``cbc["outputs"]``, else every state).
    sample_rate : float
        Sampling and control rate [Hz] (default 5 kHz, as the flutter rig).
    noise : float, sequence or mapping, optional
        Standard deviation of the white measurement noise per output (in the output's
        units): one number for all, one per output, or ``{name: std}``.
    saturation : float, optional
        Actuator limit: ``|u| <= saturation`` (clipped; the envelope's ``control_max``
        trips the gate instead).
    derivative : {"samples", "state"}
        How ``"<output>_dot"`` signals are obtained (module docstring).
    derivative_cutoff : float, optional
        Cut-off [Hz] of the low-pass on the differenced samples (default
        ``min(100 Hz, sample_rate / 10)``).
    substeps : int
        Fewest Runge–Kutta steps per sample interval.
    max_substeps : int
        Most steps per interval the error control may use before the gate trips.
    rtol, atol : float
        Tolerance of each step's error estimate: ``rtol`` times the state's size (the
        largest of its current value and the largest seen so far) plus ``atol``.
    envelope : Envelope, optional
        Safety limits (default: the system's; ``Envelope()`` for none).
    seed : int
        Seed of the measurement noise.
    x0 : array, optional
        Initial state (default: the system's own starting guess ``System.x0``, else the
        origin).
    block : int
        Samples per compiled block of the JAX engine.
    record_states : bool
        Also return the true states (``Measurement.extra["states"]``), for validation.
    engine : {"auto", "numba", "jax"}
        The compiled sample loop (module docstring); ``"numba"`` raises if the field
        cannot be translated.

    Examples
    --------
    >>> from bifid.systems import get_system
    >>> from bifid.cbc import VirtualRig
    >>> rig = VirtualRig(get_system("hopf"), {"mu": -0.1, "q5": 0.0}, x0=[0.2, 0.0])
    >>> m = rig.run(1.0)
    >>> m.outputs.shape, m.status
    ((5000, 2), 'ok')
    """

    def __init__(
        self,
        system: System,
        params: Mapping[str, float] | None = None,
        *,
        outputs: Sequence[str] | None = None,
        sample_rate: float = 5000.0,
        noise: float | Sequence[float] | Mapping[str, float] | None = None,
        saturation: float | None = None,
        derivative: str = "samples",
        derivative_cutoff: float | None = None,
        substeps: int = 1,
        max_substeps: int = 1024,
        rtol: float = 1e-6,
        atol: float = 1e-12,
        envelope: Envelope | None = None,
        seed: int = 0,
        x0: Sequence[float] | None = None,
        block: int = 4096,
        record_states: bool = False,
        engine: str = "auto",
    ) -> None:
        if not isinstance(system, System):
            raise BifidInputError(f"system must be a bifid System, got {type(system).__name__}.")
        self.system = system
        self._p = np.asarray(system.param_vector(dict(params or {})), dtype=float)
        default = (system.cbc or {}).get("outputs") or system.states
        self._cfg = RigSettings.build(
            system,
            outputs=outputs or default,
            sample_rate=sample_rate,
            saturation=saturation,
            derivative=derivative,
            derivative_cutoff=derivative_cutoff,
            substeps=substeps,
            max_substeps=max_substeps,
            rtol=rtol,
            atol=atol,
            envelope=system.envelope if envelope is None else envelope,
            block=block,
            record_states=record_states,
            engine=engine,
        )
        self._noise = self._cfg.noise_vector(noise)
        self._seed = int(seed)
        self._rng = np.random.default_rng(self._seed)
        self.trips = 0
        if x0 is None:
            x0 = system.x0
        x = np.zeros(system.n_states) if x0 is None else np.asarray(x0, dtype=float)
        if x.shape != (system.n_states,) or not np.all(np.isfinite(x)):
            raise BifidInputError(
                f"x0 must be {system.n_states} finite numbers ({', '.join(system.states)})."
            )
        self._x0 = x.copy()
        self._k = 0  # samples elapsed
        self._theta = 0.0
        self._gamma, self._Omega, self._psi = 0.0, 0.0, 0.0
        self._forcing_on = False
        self._controller: PDController | None = None
        self._target: AbstractTarget | None = None
        self._ctrl = self._cfg.no_controller()
        self._loop: CompiledLoop | None = None
        self._r = np.zeros(0)  # the field's opaque parameter-only values (numba engine)
        if engine != "jax":
            got = compiled_loop(system.field, system.n_states, len(system.parameters))
            if isinstance(got, str):
                if engine == "numba":
                    raise BifidInputError(
                        f"engine='numba': system {system.name!r} has no compiled loop: {got}; "
                        "use engine='jax' or 'auto'."
                    )
                warnings.warn(
                    f"the virtual rig of {system.name!r} runs on the (slower) JAX engine: {got}.",
                    UserWarning,
                    stacklevel=2,
                )
            else:
                self._loop = got
        self._engines = Engines(self._cfg, system)
        self._set_state(x)
        self._check_field()

    # -- protocol -----------------------------------------------------------------------
    @property
    def output_names(self) -> tuple[str, ...]:
        return self._cfg.outputs

    @property
    def sample_rate(self) -> float:
        return self._cfg.fs

    @property
    def time(self) -> float:
        return self._k / self._cfg.fs

    @property
    def state(self) -> np.ndarray:
        """The true state (a virtual rig's privilege; CBC protocols never use it)."""
        return self._x.copy()

    @property
    def params(self) -> dict[str, float]:
        return self.system.param_dict(self._p)

    @property
    def engine(self) -> str:
        """The sample loop in use: ``"numba"`` or ``"jax"``."""
        return "numba" if self._loop is not None else "jax"

    def get_parameter(self, name: str) -> float:
        return float(self._p[self.system.index(name)])

    def set_parameter(self, name: str, value: float) -> None:
        i = self.system.index(name)
        v = float(value)
        if not math.isfinite(v):
            raise BifidInputError(f"parameter {name} must be finite, got {value!r}.")
        self._p = self._p.copy()
        self._p[i] = v
        self._check_field()

    def set_noise(self, noise: float | Sequence[float] | Mapping[str, float] | None) -> None:
        """Change the measurement noise (virtual rigs only)."""
        self._noise = self._cfg.noise_vector(noise)

    def seed(self, seed: int) -> None:
        """Restart the measurement-noise stream from ``seed``."""
        self._seed = int(seed)
        self._rng = np.random.default_rng(self._seed)

    def set_forcing(
        self, amplitude: float | None, frequency: float | None = None, phase: float = 0.0
    ) -> None:
        if amplitude is None:
            self._forcing_on = False
            self._gamma = 0.0
            return
        if frequency is None:
            raise BifidInputError("set_forcing needs a frequency [rad/s] with an amplitude.")
        gamma, Om, psi = float(amplitude), float(frequency), float(phase)
        if not (math.isfinite(gamma) and math.isfinite(Om) and math.isfinite(psi)):
            raise BifidInputError(
                f"forcing amplitude, frequency and phase must be finite; got {amplitude!r}, "
                f"{frequency!r}, {phase!r}."
            )
        if Om <= 0:
            raise BifidInputError(f"forcing frequency must be > 0 rad/s, got {Om!r}.")
        if self.system.forcing_direction is None and self.system.input_direction is None:
            raise BifidInputError(f"system {self.system.name!r} has no forcing or input direction.")
        self._gamma, self._Omega, self._psi = gamma, Om, psi
        self._forcing_on = True

    @property
    def forcing(self) -> tuple[float, float, float] | None:
        """``(amplitude, frequency, phase)`` of the excitation, or None when off."""
        return (self._gamma, self._Omega, self._psi) if self._forcing_on else None

    def signal_index(self, name: str) -> tuple[int, bool]:
        """``(output index, is_derivative)`` of a signal name (``"h"`` or ``"h_dot"``)."""
        return self._cfg.signal_index(name)

    def set_controller(
        self, controller: PDController | None, target: AbstractTarget | None = None
    ) -> None:
        if controller is None:
            self._controller, self._target = None, None
            self._ctrl = self._cfg.no_controller()
            return
        if not isinstance(controller, PDController):
            raise BifidInputError(f"controller must be a PDController, got {controller!r}.")
        if not isinstance(target, AbstractTarget):
            raise BifidInputError(
                f"a controller needs a target (FourierTarget, EllipticTarget, PolarTarget), "
                f"got {target!r}."
            )
        if self.system.input_direction is None:
            raise BifidInputError(f"system {self.system.name!r} has no input direction.")
        self._ctrl = self._cfg.controller(controller, target)
        self._controller, self._target = controller, target

    @property
    def controller(self) -> tuple[PDController | None, AbstractTarget | None]:
        return self._controller, self._target

    def run(self, duration: float) -> Measurement:
        d = float(duration)
        if not (math.isfinite(d) and d > 0):
            raise BifidInputError(
                f"duration must be a positive number of seconds, got {duration!r}."
            )
        return self._run_samples(max(1, round(d * self._cfg.fs)))

    def describe(self) -> dict[str, Any]:
        cfg = self._cfg
        return {
            "rig": "VirtualRig",
            "system": self.system.name,
            "outputs": list(cfg.outputs),
            "sample_rate": cfg.fs,
            "noise": dict(zip(cfg.outputs, self._noise.tolist(), strict=True)),
            "saturation": None if math.isinf(cfg.umax) else cfg.umax,
            "derivative": cfg.derivative,
            "derivative_cutoff_hz": cfg.cutoff,
            "substeps": cfg.substeps,
            "max_substeps": cfg.max_substeps,
            "rtol": cfg.rtol,
            "atol": cfg.atol,
            "envelope": None if cfg.envelope is None else cfg.envelope.to_json(),
            "seed": self._seed,
            "integrator": "classic RK4 per sample interval, zero-order-hold control, steps "
            "doubled or halved by an embedded 3rd-order error estimate",
            "engine": self.engine,
        }

    def snapshot(self) -> dict[str, Any]:
        """The rig's state (physical and of its loop: states, filters, clock, parameters,
        forcing), as plain numbers: :meth:`restore` continues exactly from it (a resumed
        CBC campaign measures what the uninterrupted one would have)."""
        return {
            "x": np.asarray(self._x, dtype=float).tolist(),
            "yprev": np.asarray(self._yprev, dtype=float).tolist(),
            "dfilt": np.asarray(self._dfilt, dtype=float).tolist(),
            "uprev": float(self._uprev),
            "xscale": np.asarray(self._xscale, dtype=float).tolist(),
            "steps": np.asarray(self._steps).tolist(),
            "k": int(self._k),
            "theta": float(self._theta),
            "p": np.asarray(self._p, dtype=float).tolist(),
            "forcing": [
                float(self._gamma),
                float(self._Omega),
                float(self._psi),
                bool(self._forcing_on),
            ],
        }

    def restore(self, snapshot: Mapping[str, Any]) -> None:
        """Continue from a :meth:`snapshot` (the controller stays off until set)."""
        self._p = np.array(snapshot["p"], dtype=float)
        self._check_field()
        self._x = np.array(snapshot["x"], dtype=np.float64)
        self._yprev = np.array(snapshot["yprev"], dtype=np.float64)
        self._dfilt = np.array(snapshot["dfilt"], dtype=np.float64)
        self._uprev = float(snapshot["uprev"])
        self._xscale = np.array(snapshot["xscale"], dtype=np.float64)
        self._steps = np.array(snapshot["steps"], dtype=np.asarray(self._steps).dtype)
        self._k, self._theta = int(snapshot["k"]), float(snapshot["theta"])
        g, om, psi, on = snapshot["forcing"]
        self._gamma, self._Omega, self._psi, self._forcing_on = (
            float(g),
            float(om),
            float(psi),
            bool(on),
        )
        self.set_controller(None)

    def controller_json(self) -> dict | None:
        if self._controller is None:
            return None
        return {**self._controller.to_json(), "target": target_to_json(self._target)}

    # -- internals ----------------------------------------------------------------------
    def _set_state(self, x: np.ndarray) -> None:
        self._x = np.array(x, dtype=np.float64)
        self._yprev = self._x[list(self._cfg.out_idx)].copy()
        self._dfilt = np.zeros(len(self._cfg.outputs))
        self._uprev = 0.0
        self._xscale = np.abs(self._x)
        self._steps = self._cfg.initial_steps()

    def _check_field(self) -> None:
        """Directions (and opaque values) at the current parameters; the compiled field
        is checked against ``system.field`` there (the JAX engine takes over on a
        mismatch, so a translation can never silently change the model)."""
        self._directions = self._cfg.directions(self.system, self._p)
        if self._loop is None:
            return
        loop, why = self._loop, "disagrees with system.field"
        try:
            self._r = loop.residuals(self._p)
            scale = np.maximum(np.abs(self._x0), 0.1)
            if check_batched(self.system, lambda xs: loop.field_batch(xs, self._p), self._p, scale):
                return
        except Exception as exc:  # numba could not compile the generated code
            why = f"could not be compiled ({type(exc).__name__})"
        if self._cfg.engine == "numba":
            raise BifidInputError(
                f"engine='numba': the compiled field of {self.system.name!r} {why}; "
                "use engine='jax'."
            )
        warnings.warn(
            f"the rig's compiled field for {self.system.name!r} {why}; using the "
            "(slower) JAX engine.",
            ConvergenceWarning,
            stacklevel=3,
        )
        self._loop = None

    def rest(self) -> bool:
        """Controller and forcing off, the rig at rest (the equilibrium of the free system
        that a solve of ``f(x, p) = 0`` from the initial state reaches), as after a trip."""
        self._set_state(rest_state(self.system, self._p, self._x0))
        self.set_controller(None)
        self._forcing_on = False
        self._gamma = 0.0
        return True

    def _trip(self) -> None:
        """The safety gate: controller and forcing off, the rig at rest."""
        self.rest()
        self.trips += 1

    def _draw_noise(self, n: int) -> np.ndarray:
        if not np.any(self._noise > 0):
            return np.zeros((n, len(self._cfg.outputs)))
        return self._rng.standard_normal((n, len(self._cfg.outputs))) * self._noise

    def _run_samples(self, n: int) -> Measurement:
        cfg = self._cfg
        dt = 1.0 / cfg.fs
        k0 = self._k
        eps = self._draw_noise(n)
        forcing = (self._gamma, self._Omega, self._psi) if self._forcing_on else None
        run = self._engines.numba if self._loop is not None else self._engines.jax
        state = (self._x, self._yprev, self._dfilt, self._uprev, self._xscale, self._steps)
        data, state, trip = run(
            self._loop,
            self._p,
            self._r,
            self._directions,
            state,
            eps,
            forcing,
            self._theta,
            self._ctrl,
        )
        (self._x, self._yprev, self._dfilt, self._uprev, self._xscale, self._steps) = state
        m = data.shape[0]
        th = self._theta + self._Omega * dt * np.arange(m)
        fk = self._gamma * np.cos(th - self._psi) if forcing else np.zeros(m)
        peak = int(self._steps[3])
        self._steps[3] = self._steps[0]
        no = len(cfg.outputs)
        y, yd = data[:, :no], data[:, no : 2 * no]
        u, ref = data[:, 2 * no], data[:, 2 * no + 1]
        self._theta = math.fmod(self._theta + self._Omega * m * dt, 2.0 * math.pi)
        self._k += m
        status, reason = "ok", ""
        if trip is not None:
            status, reason = "tripped", trip_reason(self, trip, (k0 + m) * dt)
            self._trip()
        extra: dict[str, Any] = {"rk4_steps_max": peak}
        if cfg.record_states:
            extra["states"] = data[:, 2 * no + 2 :]
        return Measurement(
            time=(k0 + np.arange(m)) * dt,
            outputs=y,
            output_names=cfg.outputs,
            derivatives=yd,
            control=u,
            target=ref,
            force=fk,
            phase=th if forcing else np.full(m, np.nan),
            sample_rate=cfg.fs,
            saturated=int(np.count_nonzero(np.abs(u) >= cfg.umax)),
            extra=extra,
            status=status,
            reason=reason,
        )
