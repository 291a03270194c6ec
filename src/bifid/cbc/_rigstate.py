"""The virtual rig's settings, its two engines' drivers, the rest state and trip reasons.

:class:`RigSettings` validates and holds what :class:`~bifid.cbc.VirtualRig` is built
with; :class:`Engines` advances the rig by a number of samples with the numba loop
(:mod:`bifid.cbc._fastloop`) or the JAX blocks (:mod:`bifid.cbc._jaxloop`), both returning
the packed samples ``[y, yd, u, ref, (x)]`` before any trip and the trip itself.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from bifid.cbc import _fastloop as fl
from bifid.cbc._compiled import TARGET_KINDS, pack_target
from bifid.cbc._controllers import POLAR_TABLE, AbstractTarget, PDController
from bifid.cbc._fastfield import vmapped_field
from bifid.cbc._jaxloop import BlockStatic, block_function
from bifid.errors import BifidInputError
from bifid.systems import Envelope, System

__all__ = ["Engines", "RigSettings", "rest_state", "trip_reason"]


@dataclass(frozen=True, eq=False)
class Controller:
    """A controller and target packed for the loops (``tkind = 0``: none)."""

    target_ref: type | None = None
    i1: tuple[int, bool] = (0, False)
    i2: tuple[int, bool] = (0, False)
    tkind: int = 0
    packed: np.ndarray = field(default_factory=lambda: np.zeros(1))  # numba (polar: tabulated)
    vector: np.ndarray = field(default_factory=lambda: np.zeros(1))  # JAX: target.vector()
    kp: float = 0.0
    kd: float = 0.0
    afilt: float = 1.0


def _positive(name: str, value: Any, integer: bool = False) -> Any:
    v = int(value) if integer else float(value)
    if not (math.isfinite(v) and v > 0):
        kind = "positive integer" if integer else "positive number"
        raise BifidInputError(f"{name} must be a {kind}, got {value!r}.")
    return v


@dataclass(frozen=True, eq=False)
class RigSettings:
    """Validated settings of a virtual rig (see :class:`~bifid.cbc.VirtualRig`)."""

    outputs: tuple[str, ...]
    out_idx: tuple[int, ...]
    fs: float
    umax: float
    derivative: str
    cutoff: float
    substeps: int
    max_substeps: int
    rtol: float
    atol: float
    envelope: Envelope | None
    env_lo: np.ndarray
    env_hi: np.ndarray
    env_umax: float
    block: int
    record_states: bool
    engine: str

    @classmethod
    def build(
        cls,
        system: System,
        *,
        outputs,
        sample_rate,
        saturation,
        derivative,
        derivative_cutoff,
        substeps,
        max_substeps,
        rtol,
        atol,
        envelope,
        block,
        record_states,
        engine,
    ) -> RigSettings:
        names = tuple(outputs)
        idx = tuple(system.state_index(n) for n in names)
        fs = _positive("sample_rate", sample_rate)
        if saturation is not None:
            _positive("saturation", saturation)
        if derivative not in ("samples", "state"):
            raise BifidInputError(f"derivative must be 'samples' or 'state', got {derivative!r}.")
        fc = (
            min(100.0, fs / 10.0)
            if derivative_cutoff is None
            else _positive("derivative_cutoff", derivative_cutoff)
        )
        sub = _positive("substeps", substeps, integer=True)
        most = _positive("max_substeps", max_substeps, integer=True)
        if most < sub:
            raise BifidInputError(f"max_substeps ({most}) must be >= substeps ({sub}).")
        if int(block) < 16:
            raise BifidInputError(f"block must be >= 16 samples, got {block!r}.")
        if engine not in ("auto", "numba", "jax"):
            raise BifidInputError(f"engine must be 'auto', 'numba' or 'jax', got {engine!r}.")
        if envelope is not None and not isinstance(envelope, Envelope):
            raise BifidInputError(f"envelope must be a bifid Envelope, got {envelope!r}.")
        lo, hi = np.full(system.n_states, -np.inf), np.full(system.n_states, np.inf)
        for name, (a, b) in envelope.states.items() if envelope is not None else ():
            i = system.state_index(name)
            lo[i], hi[i] = float(a), float(b)
        cmax = envelope.control_max if envelope is not None else None
        return cls(
            outputs=names,
            out_idx=idx,
            fs=fs,
            umax=math.inf if saturation is None else float(saturation),
            derivative=derivative,
            cutoff=fc,
            substeps=sub,
            max_substeps=most,
            rtol=_positive("rtol", rtol),
            atol=_positive("atol", atol),
            envelope=envelope,
            env_lo=lo,
            env_hi=hi,
            env_umax=math.inf if cmax is None else float(cmax),
            block=int(block),
            record_states=bool(record_states),
            engine=engine,
        )

    @property
    def alpha(self) -> float:
        """Coefficient of the derivative estimate's low-pass."""
        return 1.0 - math.exp(-2.0 * math.pi * self.cutoff / self.fs)

    def initial_steps(self) -> np.ndarray:
        """``[m, m_min, m_max, peak, rejected]`` of the error control (module _fastloop)."""
        return np.array(
            [self.substeps, self.substeps, self.max_substeps, self.substeps, 0], dtype=np.int64
        )

    def noise_vector(self, noise: Any) -> np.ndarray:
        names = self.outputs
        if noise is None:
            return np.zeros(len(names))
        if isinstance(noise, Mapping):
            unknown = set(noise) - set(names)
            if unknown:
                raise BifidInputError(
                    f"noise given for {sorted(unknown)}, which are not outputs "
                    f"({', '.join(names)})."
                )
            out = np.array([float(noise.get(n, 0.0)) for n in names])
        else:
            arr = np.asarray(noise, dtype=float).reshape(-1)
            if arr.size not in (1, len(names)):
                raise BifidInputError(
                    f"noise must be one number, one per output ({len(names)}) or a dict; "
                    f"got {arr.size} values."
                )
            out = np.broadcast_to(arr, (len(names),)).astype(float)
        if not np.all(np.isfinite(out)) or np.any(out < 0):
            raise BifidInputError(f"noise standard deviations must be finite and >= 0, got {out}.")
        return out

    def signal_index(self, name: str) -> tuple[int, bool]:
        if name in self.outputs:
            return self.outputs.index(name), False
        if name.endswith("_dot") and name[:-4] in self.outputs:
            return self.outputs.index(name[:-4]), True
        raise BifidInputError(
            f"the rig measures {', '.join(self.outputs)} (and derivative estimates "
            f"'<name>_dot'); a controller cannot use {name!r}."
        )

    def no_controller(self) -> Controller:
        return Controller()

    def controller(self, controller: PDController, target: AbstractTarget) -> Controller:
        i1, i2 = self.signal_index(controller.x1), self.signal_index(controller.x2)
        kind = getattr(target, "kind", "")
        if kind not in TARGET_KINDS:
            raise BifidInputError(f"the virtual rig has no loop for targets of kind {kind!r}.")
        vec = np.asarray(target.vector(), dtype=np.float64)
        return Controller(
            target_ref=type(target),
            i1=i1,
            i2=i2,
            tkind=TARGET_KINDS[kind],
            packed=pack_target(kind, vec, POLAR_TABLE),
            vector=vec,
            kp=float(controller.kp),
            kd=float(controller.kd),
            afilt=controller.filter_coefficient(self.fs),
        )

    def directions(self, system: System, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(b, e)``: where the force and the control enter, at ``p``."""
        zeros = np.zeros(system.n_states)
        pj = jnp.asarray(p)
        bdir = system.forcing_direction or system.input_direction
        b = np.asarray(bdir(pj), dtype=float) if bdir is not None else zeros
        edir = system.input_direction
        e = np.asarray(edir(pj), dtype=float) if edir is not None else zeros
        return b, e


Trip = tuple[int, int, float]  # (code, index, value) of _fastloop's TRIP_*


class Engines:
    """Advance a rig by ``n`` samples: ``(data, state, trip)`` with ``data`` the packed
    samples before a trip (all ``n`` without one)."""

    def __init__(self, cfg: RigSettings, system: System) -> None:
        self.cfg, self.system = cfg, system

    def kernel_arguments(self, p, r, directions, state, eps, forcing, theta, ctrl: Controller):
        """The arguments of :func:`bifid.cbc._fastloop.run_block` (``state``, ``steps`` and
        the output buffers are fresh arrays that the call fills)."""
        cfg = self.cfg
        x, yprev, dfilt, uprev, xscale, steps = state
        n, no, ns = eps.shape[0], len(cfg.outputs), self.system.n_states
        gamma, om, psi = forcing if forcing is not None else (0.0, 0.0, 0.0)
        flags = np.array(
            [
                forcing is not None,
                ctrl.tkind,
                *ctrl.i1,
                *ctrl.i2,
                cfg.derivative == "state",
                cfg.record_states,
            ],
            dtype=np.int64,
        )
        reals = np.array(
            [
                uprev,
                gamma,
                om,
                psi,
                theta,
                ctrl.kp,
                ctrl.kd,
                1.0 if ctrl.tkind else 0.0,
                cfg.umax,
                ctrl.afilt,
                cfg.alpha,
                1.0 / cfg.fs,
                cfg.rtol,
                cfg.atol,
                cfg.env_umax,
            ],
            dtype=np.float64,
        )
        arrays = tuple(np.array(a, dtype=np.float64) for a in (x, yprev, dfilt, xscale))
        outs = (
            np.empty((n, no)),
            np.empty((n, no)),
            np.empty(n),
            np.empty(n),
            np.empty((n if cfg.record_states else 0, ns)),
        )
        return (
            np.asarray(p, dtype=np.float64),
            r,
            *directions,
            arrays,
            np.array(steps, dtype=np.int64),
            flags,
            reals,
            np.asarray(cfg.out_idx, dtype=np.int64),
            np.ascontiguousarray(eps, dtype=np.float64),
            ctrl.packed,
            (cfg.env_lo, cfg.env_hi),
            outs,
        )

    def numba(self, loop, p, r, directions, state, eps, forcing, theta, ctrl: Controller):
        args = self.kernel_arguments(p, r, directions, state, eps, forcing, theta, ctrl)
        (x, yprev, dfilt, xscale), steps, (Y, YD, U, REF, XS) = args[4], args[5], args[-1]
        uprev, n_done, code, index, value = loop.module.run_block(*args)
        cols = [Y[:n_done], YD[:n_done], U[:n_done, None], REF[:n_done, None]]
        if self.cfg.record_states:
            cols.append(XS[:n_done])
        trip = None if code == fl.TRIP_NONE else (int(code), int(index), float(value))
        return np.concatenate(cols, axis=1), (x, yprev, dfilt, uprev, xscale, steps), trip

    def _static(self, ctrl: Controller, forced: bool, size: int) -> BlockStatic:
        control = (ctrl.target_ref, ctrl.i1, ctrl.i2)
        return BlockStatic(
            self.system.field, self.cfg.out_idx, control, self.cfg.derivative, size, forced
        )

    def jax(self, loop, p, r, directions, state, eps, forcing, theta, ctrl: Controller):
        cfg = self.cfg
        x, yprev, dfilt, uprev, xscale, steps = state
        steps = steps.copy()
        gamma, om, psi = forcing if forcing is not None else (0.0, 0.0, 0.0)
        b, e = directions
        dyn = jax.device_put(
            {
                "p": np.asarray(p),
                "b": b,
                "e": e,
                "gamma": np.float64(gamma),
                "Omega": np.float64(om),
                "psi": np.float64(psi),
                "alpha": np.float64(cfg.alpha),
                "target": ctrl.vector,
                "gains": np.array([ctrl.kp, ctrl.kd]),
                "ctrl_on": np.float64(1.0 if ctrl.tkind else 0.0),
                "umax": np.float64(cfg.umax),
                "afilt": np.float64(ctrl.afilt),
                "dt": np.float64(1.0 / cfg.fs),
                "rtol": np.float64(cfg.rtol),
                "atol": np.float64(cfg.atol),
                "env_lo": cfg.env_lo,
                "env_hi": cfg.env_hi,
                "env_umax": np.float64(cfg.env_umax),
            }
        )
        fx = vmapped_field(self.system.field)(jnp.asarray(x)[None], jnp.asarray(p))[0]
        carry = tuple(
            jnp.asarray(np.asarray(a, dtype=np.float64))
            for a in (x, fx, yprev, dfilt, uprev, xscale)
        )
        n, no = eps.shape[0], len(cfg.outputs)
        big, small = cfg.block, max(16, cfg.block // 8)
        outs, done, trip = [], 0, None
        while done < n and trip is None:
            size = big if n - done >= big else small
            m = min(size, n - done)
            block_eps = np.zeros((size, no))
            block_eps[:m] = eps[done : done + m]
            fn = block_function(self._static(ctrl, forcing is not None, size))
            while True:
                scal = np.array([theta + om * done / cfg.fs, steps[0], m], dtype=np.float64)
                new, o = fn(carry, dyn, scal, block_eps)
                o = np.asarray(o)[:m]
                ratio, gate = o[:, 2 * no + 2], o[:, 2 * no + 3]
                first_gate = int(np.argmax(gate > 0)) if np.any(gate > 0) else m
                bad = ~(ratio[:first_gate] <= 1.0)
                if not np.any(bad):
                    break
                if steps[0] >= steps[2]:
                    k = int(np.argmax(bad))
                    code = fl.TRIP_ACCURACY if np.isfinite(ratio[k]) else fl.TRIP_NONFINITE
                    first_gate, trip = k, (code, -1, float(ratio[k]))
                    break
                steps[0] = min(2 * steps[0], steps[2])
                steps[4] += 1
            steps[3] = max(steps[3], steps[0])
            if first_gate < m and trip is None:
                trip = _gate_trip(
                    int(gate[first_gate]), o[first_gate, 2 * no], o[first_gate, 2 * no + 4 :], cfg
                )
            keep = o[:first_gate, : 2 * no + 2]
            if cfg.record_states:
                keep = np.concatenate([keep, o[:first_gate, 2 * no + 4 :]], axis=1)
            outs.append(keep)
            done += first_gate
            carry = new
            if trip is None and np.max(ratio, initial=0.0) < 1.0 / 32.0 and steps[0] > steps[1]:
                steps[0] = max(steps[0] // 2, steps[1])
        x, fx, yprev, dfilt, uprev, xscale = (np.asarray(a) for a in carry)
        data = np.concatenate(outs) if outs else np.empty((0, 2 * no + 2))
        return data, (x, yprev, dfilt, float(uprev), xscale, steps), trip


def _gate_trip(code: int, u: float, xk: np.ndarray, cfg: RigSettings) -> Trip:
    if code == fl.TRIP_STATE:
        i = int(np.argmax((xk < cfg.env_lo) | (xk > cfg.env_hi)))
        return code, i, float(xk[i])
    return code, -1, float(u)


@functools.lru_cache(maxsize=32)
def _equilibrium_solver(field: Callable) -> Callable:
    # least squares (Levenberg-Marquardt): converges where Newton's Jacobian is singular
    solver = optx.LevenbergMarquardt(rtol=1e-12, atol=1e-14)

    def solve(x0, p):
        sol = optx.least_squares(
            lambda x, args: field(x, args), solver, x0, args=p, max_steps=200, throw=False
        )
        return sol.value, sol.result == optx.RESULTS.successful

    return jax.jit(solve)


def rest_state(system: System, p: np.ndarray, x0: np.ndarray) -> np.ndarray:
    """The equilibrium of the free system that ``f(x, p) = 0`` solved from ``x0`` reaches
    (Levenberg-Marquardt), or ``x0`` itself when that fails."""
    x, ok = _equilibrium_solver(system.field)(jnp.asarray(x0), jnp.asarray(p))
    x = np.asarray(x)
    return x if bool(ok) and np.all(np.isfinite(x)) else np.array(x0, dtype=float)


def trip_reason(rig: Any, trip: Trip, t: float) -> str:
    """One line saying why the safety gate tripped."""
    code, i, value = trip
    cfg: RigSettings = rig._cfg
    if code == fl.TRIP_STATE:
        name = rig.system.states[i]
        what = (
            f"state {name} = {value:.6g} left the safety envelope "
            f"[{cfg.env_lo[i]:g}, {cfg.env_hi[i]:g}]"
        )
    elif code == fl.TRIP_CONTROL:
        what = f"controller output {value:.6g} exceeded the actuator limit {cfg.env_umax:g}"
    elif code == fl.TRIP_SIGNAL:
        what = "the controller output became non-finite"
    elif code == fl.TRIP_ACCURACY:
        what = (
            f"the integration missed its tolerance (rtol {cfg.rtol:g}) even with "
            f"{cfg.max_substeps} RK4 steps per sample (the state runs away)"
        )
    else:
        what = (
            f"the state became non-finite even with {cfg.max_substeps} RK4 steps per "
            "sample (numerical blow-up)"
        )
    return (
        f"safety gate tripped at t = {t:.4f} s: {what}; controller disarmed, forcing off, "
        "rig brought to rest"
    )
