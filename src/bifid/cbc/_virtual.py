"""A virtual rig: a System simulated as an experiment with a sampled controller in the loop.

Between samples ``t_k = k / f_s`` the rig integrates

.. math::

    \\dot x = f(x, p) + b(p)\\,γ\\cos(θ(t) - ψ) + e(p)\\,u_k,\\qquad θ̇ = Ω,

with the control ``u_k`` held constant (zero-order hold, as a DAC does). At each sample
it measures the outputs ``y_k = C x(t_k) + ε_k`` (Gaussian noise per channel), estimates
their derivatives, evaluates the controller on those *measurements* and saturates it.

Each sample interval is integrated by ``substeps`` classic Runge–Kutta steps (the tableau
below, checked when built) with the control held. Two engines run the same loop:

- ``"numba"`` (default for the built-in systems): :func:`bifid.cbc._fastloop.run_block`,
  a loop compiled once by numba (cached on disk), a few hundred ns per sample;
- ``"jax"`` (any system, e.g. a user-registered one): one compiled :func:`jax.lax.scan`
  per block of samples. Targets, gains, parameters and noise levels are traced arrays:
  changing them never re-compiles; compiled blocks are cached per (system, outputs,
  controller signals, target type, derivative mode, sizes).

Both draw the measurement noise from one seeded :class:`numpy.random.Generator` owned by
the rig (so a seed gives the same experiment on either engine) and agree sample for
sample to rounding (tested). The hand-written fixed-step loop replaces diffrax here
because at one step per sample diffrax's per-step machinery costs more than the step;
the rig is validated against :func:`bifid.simulate` (diffrax, adaptive Dopri) instead.

Derivative estimates (``"<output>_dot"`` signals):

- ``derivative="samples"`` (default, as on a real rig): backward difference of the
  measured samples through a first-order low-pass at ``derivative_cutoff`` Hz,
  ``d_k = d_{k-1} + a (f_s (y_k - y_{k-1}) - d_{k-1})``, ``a = 1 - exp(-2π f_c / f_s)``;
- ``derivative="state"``: the exact derivative of the (noise-free) state, as from a
  perfect velocity sensor.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bifid.cbc import _fastloop
from bifid.cbc._controllers import (
    POLAR_TABLE,
    AbstractTarget,
    PDController,
    target_to_json,
)
from bifid.cbc._fastfield import (
    PreparedField,
    check_batched,
    check_prepared,
    prepared_field,
)
from bifid.cbc._rig import AbstractRig, Measurement
from bifid.errors import BifidInputError, ConvergenceError, ConvergenceWarning
from bifid.systems import System

Array = jnp.ndarray

__all__ = ["RK4", "ButcherTableau", "VirtualRig"]

# Default measured outputs of the reference systems (what their laboratory rigs measure).
DEFAULT_OUTPUTS: dict[str, tuple[str, ...]] = {
    "flutter": ("h", "alpha"),
    "hopf": ("u1", "u2"),
    "vanderpol": ("z1", "z2"),
    "duffing": ("q",),
    "shaw_pierre": ("x1", "x2"),
}


@dataclass(frozen=True)
class ButcherTableau:
    """Coefficients of an explicit Runge–Kutta method (data, checked when built)."""

    a: tuple[tuple[float, ...], ...]
    b: tuple[float, ...]
    c: tuple[float, ...]

    def __post_init__(self) -> None:
        s = len(self.b)
        if len(self.c) != s or len(self.a) != s - 1:
            raise BifidInputError("Butcher tableau: need s weights, s nodes, s-1 rows of a.")
        if not math.isclose(sum(self.b), 1.0, rel_tol=0, abs_tol=1e-14):
            raise BifidInputError(f"Butcher tableau weights must sum to 1, got {sum(self.b)}.")
        for i, row in enumerate(self.a, start=1):
            if len(row) != i or not math.isclose(sum(row), self.c[i], abs_tol=1e-14):
                raise BifidInputError(f"Butcher tableau row {i} must have {i} entries "
                                      f"summing to c[{i}] = {self.c[i]}.")


RK4 = ButcherTableau(
    a=((0.5,), (0.0, 0.5), (0.0, 0.0, 1.0)),
    b=(1 / 6, 1 / 3, 1 / 3, 1 / 6),
    c=(0.0, 0.5, 0.5, 1.0),
)


@dataclass(frozen=True)
class _Static:
    """Everything a compiled block depends on (hashable)."""

    field: PreparedField
    n_states: int
    outputs: tuple[int, ...]
    target_ref: type | None  # the target class (its compile / fast_reference)
    x1: tuple[int, bool]  # (output index, is derivative)
    x2: tuple[int, bool]
    derivative: str
    substeps: int
    block: int
    tableau: ButcherTableau
    forced: bool
    record_states: bool


@functools.lru_cache(maxsize=64)
def _block_fn(st: _Static) -> Callable:
    """Compiled function advancing the rig by ``st.block`` samples (masked past ``n_valid``)."""

    def outs_of(v):  # static slices, not a gather
        return jnp.stack([v[i] for i in st.outputs])
    tab = st.tableau

    def pick(sig, y, yd):
        i, is_d = sig
        return yd[i] if is_d else y[i]

    def block(carry, dyn, scal, noise):
        # scal = [theta0, t0, n_valid]: the only per-block numbers; noise (block, n_out)
        x, yprev, dfilt, uprev = carry
        th0, n_valid = scal[0], scal[2]
        c = st.field.prepare(dyn["p"])
        dt = dyn["dt"]  # traced: another sample rate does not re-compile
        h = dt / st.substeps
        b, e = dyn["b"], dyn["e"]
        gamma, Om, psi = dyn["gamma"], dyn["Omega"], dyn["psi"]
        alpha = dyn["alpha"]
        aux = st.target_ref.compile(dyn["target"]) if st.target_ref is not None else None
        # forcing at t_k + δ from cos/sin at t_k by rotation (2 transcendentals per sample)
        rot = [(jnp.cos(Om * ci * h), jnp.sin(Om * ci * h)) for ci in (0.5, 1.0)]

        def rotate(cs, frac):
            if frac == 0.0:
                return cs[0]
            cr, sr = rot[0] if frac == 0.5 else rot[1]
            return cs[0] * cr - cs[1] * sr

        def step(carry, inp):
            x, yprev, dfilt, uprev = carry
            k, eps = inp
            s = k * dt
            theta = th0 + Om * s
            fx = st.field.field(x, c)
            y = outs_of(x) + eps
            if st.forced:
                ph = theta - psi
                cs = (jnp.cos(ph), jnp.sin(ph))
                fk = gamma * cs[0]
            else:
                fk = jnp.zeros(())
            if st.derivative == "state":
                yd = outs_of(fx + b * fk + e * uprev)
                dnew = dfilt
            else:
                raw = (y - yprev) / dt
                dnew = dfilt + alpha * (raw - dfilt)
                yd = dnew
            if st.target_ref is not None:
                x1 = pick(st.x1, y, yd)
                x2 = pick(st.x2, y, yd)
                r1, r2 = st.target_ref.fast_reference(aux, x1, x2, theta, Om)
                u = dyn["ctrl_on"] * (dyn["gains"][0] * (r1 - x1) + dyn["gains"][1] * (r2 - x2))
                # first-order output low-pass (PDController.filter_hz; afilt = 1: none)
                u = jnp.where(dyn["afilt"] < 1.0, uprev + dyn["afilt"] * (u - uprev), u)
                ref = jnp.where(dyn["ctrl_on"] > 0, r1, jnp.nan)
            else:
                u = jnp.zeros(())
                ref = jnp.asarray(jnp.nan)
            u = jnp.clip(u, -dyn["umax"], dyn["umax"])
            eu = e * u
            # zero-order hold: u fixed over [t_k, t_k + dt), `substeps` explicit RK steps
            xn = x
            for j in range(st.substeps):
                if st.forced and j > 0:
                    cj, sj = jnp.cos(ph + Om * j * h), jnp.sin(ph + Om * j * h)
                    cs = (cj, sj)

                def g(xx, frac, _cs=cs if st.forced else None):
                    out = st.field.field(xx, c) + eu
                    if st.forced:
                        out = out + b * (gamma * rotate(_cs, frac))
                    return out

                k1 = fx + eu + (b * fk if st.forced else 0.0) if j == 0 else g(xn, 0.0)
                ks = [k1]
                for i, row in enumerate(tab.a, start=1):
                    xi = xn + h * sum(aij * kj for aij, kj in zip(row, ks, strict=True) if aij)
                    ks.append(g(xi, tab.c[i]))
                xn = xn + h * sum(bi * ki for bi, ki in zip(tab.b, ks, strict=True))
            valid = k < n_valid
            new = (
                jnp.where(valid, xn, x),
                jnp.where(valid, y, yprev),
                jnp.where(valid, dnew, dfilt),
                jnp.where(valid, u, uprev),
            )
            packed = [y, yd, u[None], ref[None]]
            if st.record_states:
                packed.append(x)
            return new, jnp.concatenate(packed)

        ks = jnp.arange(st.block, dtype=jnp.float64)
        carry, outs = jax.lax.scan(step, (x, yprev, dfilt, uprev), (ks, noise))
        return carry, outs

    return jax.jit(block)


def _noise_vector(noise: Any, names: tuple[str, ...]) -> np.ndarray:
    if noise is None:
        return np.zeros(len(names))
    if isinstance(noise, Mapping):
        unknown = set(noise) - set(names)
        if unknown:
            raise BifidInputError(
                f"noise given for {sorted(unknown)}, which are not outputs ({', '.join(names)})."
            )
        out = np.array([float(noise.get(n, 0.0)) for n in names])
    else:
        arr = np.asarray(noise, dtype=float).reshape(-1)
        if arr.size == 1:
            out = np.full(len(names), float(arr[0]))
        elif arr.size == len(names):
            out = arr.astype(float)
        else:
            raise BifidInputError(
                f"noise must be one number, one per output ({len(names)}) or a dict; "
                f"got {arr.size} values."
            )
    if not np.all(np.isfinite(out)) or np.any(out < 0):
        raise BifidInputError(f"noise standard deviations must be finite and >= 0, got {out}.")
    return out


class VirtualRig(AbstractRig):
    """A :class:`~bifid.systems.System` run as an experiment (see the module docstring).

    Parameters
    ----------
    system : System
    params : mapping, optional
        Parameter overrides (``{"U": 16.0}``); the rest take their defaults.
    outputs : sequence of str, optional
        Measured states (default per system, e.g. ``("h", "alpha")`` for flutter).
    sample_rate : float
        Sampling and control rate [Hz] (default 5 kHz, as the flutter rig).
    noise : float, sequence or mapping, optional
        Standard deviation of the white measurement noise per output (in the output's
        units): one number for all, one per output, or ``{name: std}``.
    saturation : float, optional
        Actuator limit: ``|u| <= saturation``.
    derivative : {"samples", "state"}
        How ``"<output>_dot"`` signals are obtained (module docstring).
    derivative_cutoff : float, optional
        Cut-off [Hz] of the low-pass on the differenced samples (default
        ``min(100 Hz, sample_rate / 10)``).
    substeps : int
        Runge–Kutta steps per sample interval.
    seed : int
        Seed of the measurement noise.
    x0 : array, optional
        Initial state (default: the origin plus nothing, i.e. at rest).
    block : int
        Samples per compiled block (the remainder of a run goes in blocks of
        ``block // 8``, so at most that many samples are computed and discarded).
    record_states : bool
        Also return the true states (``Measurement.extra["states"]``), for validation.
    engine : {"auto", "numba", "jax"}
        The compiled sample loop (module docstring). ``"auto"``: numba for the built-in
        systems and targets, JAX otherwise; ``"numba"`` raises if it cannot be used.

    Examples
    --------
    >>> from bifid.systems import get_system
    >>> from bifid.cbc import VirtualRig
    >>> rig = VirtualRig(get_system("hopf"), {"mu": -0.1, "q5": 0.0}, x0=[0.2, 0.0])
    >>> m = rig.run(1.0)
    >>> m.outputs.shape
    (5000, 2)
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
        names = tuple(outputs) if outputs else DEFAULT_OUTPUTS.get(system.name, system.states)
        for n in names:
            system.state_index(n)
        self._outputs = names
        self._out_idx = tuple(system.state_index(n) for n in names)
        self._out_idx_arr = np.asarray(self._out_idx, dtype=np.int64)
        sr = float(sample_rate)
        if not (math.isfinite(sr) and sr > 0):
            raise BifidInputError(
                f"sample_rate must be a positive number of Hz, got {sample_rate!r}."
            )
        self._fs = sr
        self._noise = _noise_vector(noise, names)
        if saturation is not None and not (float(saturation) > 0):
            raise BifidInputError(f"saturation must be > 0 (or None), got {saturation!r}.")
        self._umax = math.inf if saturation is None else float(saturation)
        if derivative not in ("samples", "state"):
            raise BifidInputError(
                f"derivative must be 'samples' or 'state', got {derivative!r}."
            )
        self._derivative = derivative
        fc = min(100.0, sr / 10.0) if derivative_cutoff is None else float(derivative_cutoff)
        if not (fc > 0 and math.isfinite(fc)):
            raise BifidInputError(f"derivative_cutoff must be > 0 Hz, got {derivative_cutoff!r}.")
        self._cutoff = fc
        if int(substeps) < 1:
            raise BifidInputError(f"substeps must be a positive integer, got {substeps!r}.")
        self._substeps = int(substeps)
        if int(block) < 16:
            raise BifidInputError(f"block must be >= 16 samples, got {block!r}.")
        self._block = int(block)
        self._record_states = bool(record_states)
        self._seed = int(seed)
        self.trips = 0
        self._rng = np.random.default_rng(self._seed)
        if engine not in ("auto", "numba", "jax"):
            raise BifidInputError(f"engine must be 'auto', 'numba' or 'jax', got {engine!r}.")
        if engine == "numba" and not self._numba_possible(system):
            raise BifidInputError(
                f"the numba engine has no compiled field for system {system.name!r} (it has "
                f"{', '.join(_fastloop.SYSTEM_IDS)}); use engine='jax' or 'auto'."
            )
        self._engine_request = engine
        x = np.zeros(system.n_states) if x0 is None else np.asarray(x0, dtype=float)
        if x.shape != (system.n_states,) or not np.all(np.isfinite(x)):
            raise BifidInputError(
                f"x0 must be {system.n_states} finite numbers ({', '.join(system.states)})."
            )
        self._x = jnp.asarray(x)
        y0 = x[list(self._out_idx)]
        self._yprev = jnp.asarray(y0)
        self._dfilt = jnp.zeros(len(names))
        self._uprev = jnp.zeros(())
        self._k = 0  # samples elapsed
        self._theta = 0.0
        self._gamma, self._Omega, self._psi = 0.0, 0.0, 0.0
        self._forcing_on = False
        self._controller: PDController | None = None
        self._target: AbstractTarget | None = None
        self._static_target: tuple[type | None, tuple[int, bool], tuple[int, bool]] = (
            None, (0, False), (0, False))
        self._target_vec = jnp.zeros(1)
        self._target_packed: np.ndarray | None = None
        self._afilt = 1.0
        self._gains = jnp.zeros(2)
        self._ctrl_on = 0.0
        self._fast, self._generic = prepared_field(system)
        self._field = self._fast
        self._numba_ok = engine != "jax" and self._numba_possible(system)
        self._check_field()

    # -- protocol -----------------------------------------------------------------------
    @property
    def output_names(self) -> tuple[str, ...]:
        return self._outputs

    @property
    def sample_rate(self) -> float:
        return self._fs

    @property
    def time(self) -> float:
        return self._k / self._fs

    @property
    def state(self) -> np.ndarray:
        """The true state (a virtual rig's privilege; CBC protocols never use it)."""
        return np.asarray(self._x)

    @property
    def params(self) -> dict[str, float]:
        return self.system.param_dict(self._p)

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

    @property
    def engine(self) -> str:
        """The sample loop in use now: ``"numba"`` or ``"jax"``."""
        if not self._numba_ok:
            return "jax"
        if self._target is not None and self._target.kind not in _fastloop.TARGET_KINDS:
            return "jax"
        return "numba"

    @staticmethod
    def _numba_possible(system: System) -> bool:
        return _fastloop.HAVE_NUMBA and system.name in _fastloop.SYSTEM_IDS

    def set_noise(self, noise: float | Sequence[float] | Mapping[str, float] | None) -> None:
        """Change the measurement noise (virtual rigs only)."""
        self._noise = _noise_vector(noise, self._outputs)

    def set_forcing(
        self, amplitude: float | None, frequency: float | None = None, phase: float = 0.0
    ) -> None:
        if amplitude is None:
            self._forcing_on = False
            self._gamma = 0.0
            return
        gamma = float(amplitude)
        if frequency is None:
            raise BifidInputError("set_forcing needs a frequency [rad/s] with an amplitude.")
        Om = float(frequency)
        psi = float(phase)
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
        if name in self._outputs:
            return self._outputs.index(name), False
        if name.endswith("_dot") and name[:-4] in self._outputs:
            return self._outputs.index(name[:-4]), True
        raise BifidInputError(
            f"the rig measures {', '.join(self._outputs)} (and derivative estimates "
            f"'<name>_dot'); a controller cannot use {name!r}."
        )

    def set_controller(
        self, controller: PDController | None, target: AbstractTarget | None = None
    ) -> None:
        if controller is None:
            self._ctrl_on = 0.0
            self._controller = None
            self._target = None
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
        i1 = self.signal_index(controller.x1)
        i2 = self.signal_index(controller.x2)
        self._static_target = (type(target), i1, i2)
        self._target_vec = jnp.asarray(target.vector())
        kind = getattr(target, "kind", "")
        self._target_packed = (
            _fastloop.pack_target(kind, target.vector(), POLAR_TABLE)
            if kind in _fastloop.TARGET_KINDS else None
        )
        self._gains = jnp.asarray([controller.kp, controller.kd])
        self._afilt = controller.filter_coefficient(self._fs)
        self._ctrl_on = 1.0
        self._controller = controller
        self._target = target

    @property
    def controller(self) -> tuple[PDController | None, AbstractTarget | None]:
        return self._controller, self._target

    def run(self, duration: float) -> Measurement:
        d = float(duration)
        if not (math.isfinite(d) and d > 0):
            raise BifidInputError(
                f"duration must be a positive number of seconds, got {duration!r}."
            )
        n = max(1, round(d * self._fs))
        return self._run_samples(n)

    def describe(self) -> dict[str, Any]:
        return {
            "rig": "VirtualRig",
            "system": self.system.name,
            "outputs": list(self._outputs),
            "sample_rate": self._fs,
            "noise": dict(zip(self._outputs, self._noise.tolist(), strict=True)),
            "saturation": None if math.isinf(self._umax) else self._umax,
            "derivative": self._derivative,
            "derivative_cutoff_hz": self._cutoff,
            "substeps": self._substeps,
            "seed": self._seed,
            "integrator": "classic RK4 per sample interval, zero-order-hold control",
            "engine": self.engine,
        }

    def controller_json(self) -> dict | None:
        if self._controller is None:
            return None
        return {**self._controller.to_json(), "target": target_to_json(self._target)}

    # -- internals ----------------------------------------------------------------------
    def _check_field(self) -> None:
        # forcing and input directions at the current parameters (cached per change)
        p = jnp.asarray(self._p)
        zeros = np.zeros(self.system.n_states)
        bdir = self.system.forcing_direction or self.system.input_direction
        b = np.asarray(bdir(p), dtype=float) if bdir is not None else zeros
        edir = self.system.input_direction
        e = np.asarray(edir(p), dtype=float) if edir is not None else zeros
        self._directions = (b, e)
        if self._numba_ok:
            self._numba_consts = _fastloop.prepare_constants(self.system.name, self._p)
            sid, consts = _fastloop.SYSTEM_IDS[self.system.name], self._numba_consts
            if not check_batched(self.system, lambda xs: _fastloop.field_batch(sid, xs, consts),
                                 self._p, np.full(self.system.n_states, 0.1)):
                if self._engine_request == "numba":
                    raise BifidInputError(
                        f"the numba field of {self.system.name!r} disagrees with system.field "
                        "(a re-registered system?); use engine='jax'."
                    )
                warnings.warn(
                    f"the rig's numba field for {self.system.name!r} disagrees with "
                    "system.field; using the (slower) JAX engine.",
                    ConvergenceWarning,
                    stacklevel=3,
                )
                self._numba_ok = False
        self._fast_checked = False  # the JAX engine checks its prepared field when used

    def _ensure_jax_field(self) -> None:
        """Check the JAX engine's prepared field at the current parameters (once each)."""
        if self._fast_checked:
            return
        self._fast_checked = True
        if self._fast is self._generic:
            return
        scale = np.full(self.system.n_states, 0.1)
        if check_prepared(self.system, self._fast, jnp.asarray(self._p), scale):
            self._field = self._fast
        else:
            warnings.warn(
                f"the rig's fast field for {self.system.name!r} disagrees with system.field; "
                "using the (slower) generic field.",
                ConvergenceWarning,
                stacklevel=3,
            )
            self._field = self._generic

    def _trip(self) -> None:
        self._x = jnp.zeros(self.system.n_states)
        self._yprev = jnp.zeros(len(self._outputs))
        self._dfilt = jnp.zeros(len(self._outputs))
        self._uprev = jnp.zeros(())
        self._ctrl_on = 0.0
        self._controller = None
        self._target = None
        self._forcing_on = False
        self._gamma = 0.0
        self.trips += 1

    def _static(self, block: int) -> _Static:
        ref, i1, i2 = self._static_target
        return _Static(
            field=self._field,
            n_states=self.system.n_states,
            outputs=self._out_idx,
            target_ref=ref,
            x1=i1,
            x2=i2,
            derivative=self._derivative,
            substeps=self._substeps,
            block=block,
            tableau=RK4,
            forced=self._forcing_on,
            record_states=self._record_states,
        )

    def _draw_noise(self, n: int) -> np.ndarray:
        if not np.any(self._noise > 0):
            return np.zeros((n, len(self._outputs)))
        return self._rng.standard_normal((n, len(self._outputs))) * self._noise

    def _run_numba(self, n: int, eps: np.ndarray, theta: float) -> tuple[np.ndarray, float]:
        """Advance by n samples with the numba loop; returns packed outputs like the JAX one."""
        b, e = self._directions
        dt = 1.0 / self._fs
        alpha = 1.0 - math.exp(-2.0 * math.pi * self._cutoff * dt)
        no, ns = len(self._outputs), self.system.n_states
        x = np.array(self._x, dtype=np.float64)
        yprev = np.array(self._yprev, dtype=np.float64)
        dfilt = np.array(self._dfilt, dtype=np.float64)
        Y, YD = np.empty((n, no)), np.empty((n, no))
        U, REF = np.empty(n), np.empty(n)
        XS = np.empty((n, ns)) if self._record_states else np.empty((0, ns))
        on = self._controller is not None
        tkind = _fastloop.TARGET_KINDS[self._target.kind] if on else 0
        tv = self._target_packed if on else np.zeros(1)
        (_, i1, i2) = self._static_target
        kp, kd = (float(self._gains[0]), float(self._gains[1])) if on else (0.0, 0.0)
        uprev, _n_done = _fastloop.run_block(
            _fastloop.SYSTEM_IDS[self.system.name], self._numba_consts, b, e,
            x, yprev, dfilt, float(self._uprev), self._out_idx_arr,
            np.ascontiguousarray(eps, dtype=np.float64),
            self._forcing_on, float(self._gamma if self._forcing_on else 0.0),
            float(self._Omega), float(self._psi), float(theta),
            tkind, tv, i1[0], i1[1], i2[0], i2[1], kp, kd, float(self._ctrl_on),
            float(self._umax), self._afilt if on else 1.0, self._derivative == "state",
            alpha, dt, self._substeps, self._record_states, Y, YD, U, REF, XS,
        )
        self._x = x
        self._yprev, self._dfilt, self._uprev = yprev, dfilt, uprev
        cols = [Y, YD, U[:, None], REF[:, None]]
        if self._record_states:
            cols.append(XS)
        theta_end = math.fmod(theta + self._Omega * n * dt, 2.0 * math.pi)
        return np.concatenate(cols, axis=1), theta_end

    def _run_jax(self, n: int, eps: np.ndarray, theta: float) -> tuple[np.ndarray, float]:
        """Advance by n samples with compiled ``lax.scan`` blocks."""
        self._ensure_jax_field()
        big, small = self._block, max(16, self._block // 8)
        b, e = self._directions
        dt = 1.0 / self._fs
        alpha = 1.0 - math.exp(-2.0 * math.pi * self._cutoff * dt)
        carry = (self._x, self._yprev, self._dfilt, self._uprev)
        dyn = jax.device_put({
            "p": np.asarray(self._p), "b": b, "e": e,
            "gamma": np.float64(self._gamma if self._forcing_on else 0.0),
            "Omega": np.float64(self._Omega), "psi": np.float64(self._psi),
            "alpha": np.float64(alpha),
            "target": np.asarray(self._target_vec), "gains": np.asarray(self._gains),
            "ctrl_on": np.float64(self._ctrl_on), "umax": np.float64(self._umax),
            "afilt": np.float64(self._afilt if self._controller is not None else 1.0),
            "dt": np.float64(dt),
        })
        outs = []
        done = 0
        k0 = self._k
        while done < n:
            size = big if n - done >= big else small
            fn = _block_fn(self._static(size))
            m = min(size, n - done)
            scal = np.array([theta, (k0 + done) * dt, m], dtype=np.float64)
            block_eps = np.zeros((size, len(self._outputs)))
            block_eps[:m] = eps[done : done + m]
            carry, o = fn(carry, dyn, scal, block_eps)
            outs.append((m, o))
            done += m
            theta = math.fmod(theta + self._Omega * m * dt, 2.0 * math.pi)
        self._x, self._yprev, self._dfilt, self._uprev = carry
        return np.concatenate([np.asarray(o)[:m] for m, o in outs]), theta

    def _run_samples(self, n: int) -> Measurement:
        dt = 1.0 / self._fs
        k0 = self._k
        eps = self._draw_noise(n)
        if self.engine == "numba":
            data, theta = self._run_numba(n, eps, self._theta)
        else:
            data, theta = self._run_jax(n, eps, self._theta)
        n_out = len(self._outputs)
        y, yd = data[:, :n_out], data[:, n_out : 2 * n_out]
        u, ref = data[:, 2 * n_out], data[:, 2 * n_out + 1]
        xs = data[:, 2 * n_out + 2 :] if self._record_states else None
        if not np.all(np.isfinite(data[:, : 2 * n_out + 1])) or not np.all(
            np.isfinite(np.asarray(self._x))
        ):
            # the virtual rig's emergency stop: controller and forcing off, back at rest
            self._trip()
            self._k += n
            self._theta = theta
            raise ConvergenceError(
                f"the virtual {self.system.name!r} rig blew up (non-finite state) during "
                f"t = {k0 * dt:.3f}..{(k0 + n) * dt:.3f} s and tripped (controller and "
                "forcing off, state back at rest); the controller did not stabilise the "
                "response, or the sample rate is too low for the system (raise substeps)."
            )
        self._k += n
        th = self._theta + self._Omega * dt * np.arange(n)
        self._theta = theta
        time = (k0 + np.arange(n)) * dt
        forcing = self._forcing_on
        fk = self._gamma * np.cos(th - self._psi) if forcing else np.zeros(n)
        sat = np.abs(u) >= self._umax
        return Measurement(
            time=time,
            outputs=y,
            output_names=self._outputs,
            derivatives=yd,
            control=u,
            target=ref,
            force=fk,
            phase=th if forcing else np.full(n, np.nan),
            sample_rate=self._fs,
            saturated=int(np.count_nonzero(sat)),
            extra={} if xs is None else {"states": xs},
        )
