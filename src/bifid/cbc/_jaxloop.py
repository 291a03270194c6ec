"""The virtual rig's sample loop as compiled JAX blocks (for fields numba code cannot express).

The same sample as :mod:`bifid.cbc._fastloop` (measurement, derivative estimate, PD law
with output filter, safety gate, saturation, zero-order hold, harmonic force, classic RK4
with the embedded third-order error estimate), written as one :func:`jax.lax.scan` per
block of samples. Targets, gains, parameters and noise levels are traced arrays: changing
them (or the number of RK4 steps per interval) never re-compiles; compiled blocks are
cached per (field, outputs, controller signals, target type, derivative mode, block size).

Error control works per block here: each sample reports its error ratio and the rig
repeats a block whose ratio exceeds one with twice the steps, where the numba loop adapts
per sample. Each sample also reports whether the
safety gate would fire (state outside the envelope, control beyond the actuator limit
or non-finite); the rig keeps the samples before the first such one.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp

__all__ = ["BlockStatic", "block_function"]

# gate codes per sample (as the numba loop's trip codes)
GATE_STATE, GATE_CONTROL, GATE_SIGNAL = 1.0, 2.0, 5.0


@dataclass(frozen=True)
class BlockStatic:
    """Everything a compiled block depends on (hashable)."""

    field: Callable
    outputs: tuple[int, ...]
    # (target class (its compile / fast_reference) or None, x1, x2); a signal is
    # (output index, is derivative)
    control: tuple[type | None, tuple[int, bool], tuple[int, bool]]
    derivative: str
    block: int
    forced: bool


def _rk4_interval(field, x, fx, inputs, forcing, m, h, rtol, atol, xscale):
    """``m`` (traced) RK4 steps with the held input; returns (x, f(x), error ratio)."""

    def one(j, carry):
        xn, fn, ratio = carry
        f0, fm, f1 = (forcing(j * h), forcing((j + 0.5) * h), forcing((j + 1.0) * h))
        k1 = fn + inputs + f0
        k2 = field(xn + 0.5 * h * k1) + (inputs + fm)
        k3 = field(xn + 0.5 * h * k2) + (inputs + fm)
        k4 = field(xn + h * k3) + (inputs + f1)
        new = xn + h * (k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0
        fnew = field(new)
        err = jnp.abs(h * (k4 - (fnew + inputs + f1)) / 6.0)
        tol = (rtol * jnp.maximum(jnp.maximum(jnp.abs(xn), jnp.abs(new)), xscale) + atol) / m
        bad = ~jnp.all(jnp.isfinite(new) & jnp.isfinite(fnew))
        return new, fnew, jnp.where(bad, jnp.inf, jnp.maximum(ratio, jnp.max(err / tol)))

    return jax.lax.fori_loop(0, m, one, (x, fx, jnp.zeros(())))


@functools.lru_cache(maxsize=64)
def block_function(st: BlockStatic) -> Callable:
    """Compiled ``(carry, dyn, scal, noise) -> (carry, outputs)`` advancing ``st.block``
    samples (masked past ``scal[2]``; ``scal[1]`` RK4 steps per interval);
    ``carry = (x, f(x), yprev, dfilt, uprev, xscale)``, outputs per sample
    ``[y, yd, u, ref, ratio, gate, x]``."""

    def outs_of(v):  # static slices, not a gather
        return jnp.stack([v[i] for i in st.outputs])

    def pick(sig, y, yd):
        i, is_d = sig
        return yd[i] if is_d else y[i]

    def block(carry, dyn, scal, noise):
        th0, m, n_valid = scal[0], scal[1].astype(jnp.int32), scal[2]
        p, dt = dyn["p"], dyn["dt"]  # traced: another sample rate does not re-compile
        h = dt / m
        b, e = dyn["b"], dyn["e"]
        gamma, Om, psi = dyn["gamma"], dyn["Omega"], dyn["psi"]
        target_ref, sig1, sig2 = st.control
        aux = target_ref.compile(dyn["target"]) if target_ref is not None else None

        def field(x):
            return st.field(x, p)

        def step(carry, inp):
            x, fx, yprev, dfilt, uprev, xscale = carry
            k, eps = inp
            theta = th0 + Om * (k * dt)
            y = outs_of(x) + eps
            ph = theta - psi
            fk = gamma * jnp.cos(ph) if st.forced else jnp.zeros(())
            if st.derivative == "state":
                yd = outs_of(fx + b * fk + e * uprev)
                dnew = dfilt
            else:
                dnew = dfilt + dyn["alpha"] * ((y - yprev) / dt - dfilt)
                yd = dnew
            if target_ref is not None:
                x1, x2 = pick(sig1, y, yd), pick(sig2, y, yd)
                r1, r2 = target_ref.fast_reference(aux, x1, x2, theta, Om)
                u = dyn["ctrl_on"] * (dyn["gains"][0] * (r1 - x1) + dyn["gains"][1] * (r2 - x2))
                # first-order output low-pass (PDController.filter_hz; afilt = 1: none)
                u = jnp.where(dyn["afilt"] < 1.0, uprev + dyn["afilt"] * (u - uprev), u)
                ref = jnp.where(dyn["ctrl_on"] > 0, r1, jnp.nan)
            else:
                u, ref = jnp.zeros(()), jnp.asarray(jnp.nan)
            outside = ~jnp.all((x >= dyn["env_lo"]) & (x <= dyn["env_hi"]))
            gate = jnp.where(
                outside,
                GATE_STATE,
                jnp.where(
                    ~jnp.isfinite(u),
                    GATE_SIGNAL,
                    jnp.where(jnp.abs(u) > dyn["env_umax"], GATE_CONTROL, 0.0),
                ),
            )
            u = jnp.clip(u, -dyn["umax"], dyn["umax"])

            def forcing(s):  # the harmonic force at t_k + s along b
                return b * (gamma * jnp.cos(ph + Om * s)) if st.forced else 0.0

            xn, fn, ratio = _rk4_interval(
                field, x, fx, e * u, forcing, m, h, dyn["rtol"], dyn["atol"], xscale
            )
            valid = k < n_valid
            keep = [xn, fn, y, dnew, u, jnp.maximum(xscale, jnp.abs(xn))]
            new = tuple(jnp.where(valid, a, o) for a, o in zip(keep, carry, strict=True))
            return new, jnp.concatenate([y, yd, u[None], ref[None], ratio[None], gate[None], x])

        ks = jnp.arange(st.block, dtype=jnp.float64)
        return jax.lax.scan(step, carry, (ks, noise))

    return jax.jit(block)
