"""A virtual rig: a System simulated as an experiment with a sampled controller in the loop.

Between samples ``t_k = k / f_s`` the rig integrates

.. math::

    \\dot x = f(x, p) + b(p)\\,γ\\cos(θ(t) - ψ) + e(p)\\,u_k,\\qquad θ̇ = Ω,

with the control ``u_k`` held constant (zero-order hold, as a DAC does). At each sample
it measures the outputs ``y_k = C x(t_k) + ε_k`` (Gaussian noise per channel), estimates
their derivatives, evaluates the controller on those *measurements* and saturates it.

Everything per sample happens in one compiled :func:`jax.lax.scan` over a block of
samples, each sample interval integrated by ``substeps`` classic Runge–Kutta steps (the
tableau below, checked when built). Targets, gains, parameters and noise levels are
traced arrays: changing them never re-compiles; compiled blocks are cached per
(system, outputs, controller signals, target type, derivative mode, sizes).

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

from bifid.cbc._controllers import AbstractTarget, PDController, target_to_json
from bifid.cbc._fastfield import PreparedField, check_prepared, prepared_field
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

    def block(carry, dyn, scal):
        # scal = [theta0, t0, n_valid, block counter]: the only per-block numbers
        x, yprev, dfilt, uprev = carry
        th0, n_valid = scal[0], scal[2]
        c = st.field.prepare(dyn["p"])
        dt = dyn["dt"]  # traced: another sample rate does not re-compile
        h = dt / st.substeps
        b, e = dyn["b"], dyn["e"]
        gamma, Om, psi = dyn["gamma"], dyn["Omega"], dyn["psi"]
        key = jax.random.fold_in(dyn["key"], scal[3].astype(jnp.int32))
        noise = jax.random.normal(key, (st.block, len(st.outputs))) * dyn["noise"]
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
        self._n_blocks_run = 0
        self.trips = 0
        self._key = np.asarray(jax.random.PRNGKey(self._seed))
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
        self._gains = jnp.zeros(2)
        self._ctrl_on = 0.0
        self._fast, self._generic = prepared_field(system)
        self._field = self._fast
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
        self._gains = jnp.asarray([controller.kp, controller.kd])
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

    def _run_samples(self, n: int) -> Measurement:
        big, small = self._block, max(16, self._block // 8)
        b, e = self._directions
        dt = 1.0 / self._fs
        alpha = 1.0 - math.exp(-2.0 * math.pi * self._cutoff * dt)
        carry = (self._x, self._yprev, self._dfilt, self._uprev)
        dyn = jax.device_put({
            "p": np.asarray(self._p), "b": b, "e": e,
            "gamma": np.float64(self._gamma if self._forcing_on else 0.0),
            "Omega": np.float64(self._Omega), "psi": np.float64(self._psi),
            "noise": self._noise, "alpha": np.float64(alpha),
            "target": np.asarray(self._target_vec), "gains": np.asarray(self._gains),
            "ctrl_on": np.float64(self._ctrl_on), "umax": np.float64(self._umax),
            "key": self._key, "dt": np.float64(dt),
        })
        outs = []
        done = 0
        theta = self._theta
        k0 = self._k
        while done < n:
            size = big if n - done >= big else small
            fn = _block_fn(self._static(size))
            m = min(size, n - done)
            scal = np.array([theta, (k0 + done) * dt, m, self._n_blocks_run], dtype=np.float64)
            carry, o = fn(carry, dyn, scal)
            outs.append((m, o))
            self._n_blocks_run += 1
            done += m
            theta = math.fmod(theta + self._Omega * m * dt, 2.0 * math.pi)
        self._x, self._yprev, self._dfilt, self._uprev = carry
        data = np.concatenate([np.asarray(o)[:m] for m, o in outs])
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
