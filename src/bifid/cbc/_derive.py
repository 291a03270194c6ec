"""CBC settings derived from a system: its linearisation and a first continuation run.

- **Linearisation** at the equilibrium (forced systems: at rest without force): the
  eigenvalues ``λ_i`` give the frequency ``ω`` of the least damped oscillatory mode and
  the fastest rate ``max |λ_i|``. The sample rate is the larger of 500 samples per period
  of ``ω`` and ten samples per time constant of the fastest mode (RK4 with one step per
  sample is then accurate and stable), rounded up to 1, 2 or 5 × 10^k Hz; derivative
  estimates are low-passed at ten times the oscillation frequency.
- **Forced systems**: a PD controller on the observed coordinate adds the stiffness
  ``kp b`` and damping ``kd b`` (``b`` the size of the input direction): ``kp = ω²/(2b)``,
  ``kd = ω/(2b)`` add a damping ratio of 1/4 — enough to hold the unstable responses of
  an S-curve or FRC — and ``kp, kd`` five times lower with noisy measurements (the
  controller feeds the noise back as a force).
- **Self-excited systems**: the limit cycles of the model over the campaign's range
  (:func:`bifid.continuation.continue_from_hopf`, the Hopf point searched for in the range
  widened on both sides by its width or a quarter of its values, whichever is larger)
  give the frequency guess, the scan's amplitude grid (half the smallest to 1.15 times
  the largest first-harmonic amplitude of ``x1``, spaced at most half the smallest
  distance between coexisting cycles) and the noise reference (the smallest centred
  amplitude per output). The gains are the candidates
  ``kp ∈ {0, 0.3, 1} ω²/b``, ``kd ∈ {0.1, 0.3, 1, 3} ω/b`` on ``(x1, ẋ1)`` whose largest
  non-trivial *controlled* Floquet multiplier over three cycles of the range (smallest,
  middle, largest) is smallest (thesis Fig. 3.9).
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bifid.cbc._controllers import PDController
from bifid.cbc._stability import augmented_params, controlled_rhs, orbit_polar_target
from bifid.continuation import ContinuationOptions, continue_from_hopf, floquet_multipliers
from bifid.errors import BifidInputError, ConvergenceWarning
from bifid.systems import System

__all__ = ["derive", "linearisation"]


def _nice(x: float) -> float:
    """The smallest of 1, 2, 5 × 10^k that is >= x."""
    k = math.floor(math.log10(x))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10.0**k >= x * (1 - 1e-12):
            return m * 10.0**k
    return 10.0 ** (k + 1)


def linearisation(system: System, p: jnp.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(x_eq, eigenvalues)`` at the equilibrium nearest the origin (Newton from 0;
    forced systems without force)."""
    if system.kind == "forced":
        p = p.at[system.index("F")].set(0.0)
    f = jax.jit(lambda x: system.field(x, p))
    jac = jax.jit(jax.jacfwd(lambda x: system.field(x, p)))
    x = jnp.zeros(system.n_states)
    for _ in range(30):
        J = np.asarray(jac(x))
        try:
            dx = np.linalg.solve(J, -np.asarray(f(x)))
        except np.linalg.LinAlgError:
            break
        x = x + dx
        if float(np.max(np.abs(dx))) <= 1e-12 * (1 + float(np.max(np.abs(x)))):
            break
    x = np.asarray(x) if np.all(np.isfinite(np.asarray(x))) else np.zeros(system.n_states)
    return x, np.linalg.eigvals(np.asarray(jac(jnp.asarray(x))))


def _input_size(system: System, p: jnp.ndarray) -> float:
    if system.input_direction is None:
        return 1.0
    e = np.abs(np.asarray(system.input_direction(p), dtype=float))
    return float(np.max(e)) if np.max(e) > 0 else 1.0


def derive(
    system: System,
    params: dict[str, float],
    given: set[str],
    param: str | None,
    param_range: tuple[float, float] | None,
    noise_reference: bool = False,
) -> dict[str, Any]:
    """Derived values of every setting (see the module docstring); the continuation run is
    skipped when ``given`` holds all it would set (the noise reference only counts when
    asked for)."""
    p = system.param_vector(params)
    _, lam = linearisation(system, p)
    osc = [lv for lv in lam if abs(lv.imag) > 1e-9]
    omega = (
        abs(min(osc, key=lambda lv: abs(lv.real) / abs(lv)).imag)
        if osc
        else max(float(np.max(np.abs(lam))), 1e-3)
    )
    fastest = max(float(np.max(np.abs(lam))), omega)
    fs = _nice(max(500.0 * omega / (2 * math.pi), 10.0 * fastest / (2 * math.pi)))
    b = _input_size(system, p)
    out: dict[str, Any] = {
        "sample_rate": fs,
        "omega_guess": float(omega),
        "n_harmonics": 5,
        "settle_periods": 8.0,
        "measure_periods": 3.0,
        "derivative_cutoff": _nice(10.0 * omega / (2 * math.pi)),
    }
    if system.kind == "forced":
        kp, kd = 0.5 * omega**2 / b, 0.5 * omega / b
        out.update(
            outputs=(system.observed,),
            signal=system.observed,
            kp=kp,
            kd=kd,
            derivative_cutoff=None,
            noisy_options={"kp": 0.2 * kp, "kd": 0.2 * kd, "settle_periods": 20.0},
        )
        return out
    x1 = system.observed
    out.update(
        outputs=(x1,),
        x1=x1,
        x2=f"{x1}_dot",
        kp=0.5 * omega**2 / b,
        kd=0.5 * omega / b,
        measure_periods=4.0,
        amplitude_range=(0.1, 1.0),
        n_amplitudes=16,
    )
    need = {"amplitude_range", "n_amplitudes", "kp", "kd", "omega_guess"}
    if noise_reference:
        need.add("noise_reference")
    if need <= given or param is None or param_range is None:
        return out
    cycles = _cycles(system, p, param, param_range)
    if not cycles:
        return out
    out.update(_from_cycles(system, cycles, x1))
    if not {"kp", "kd"} <= given and not ({"x1", "x2"} & given):
        out.update(_gains(system, p, param, cycles, x1, f"{x1}_dot", out["omega_guess"], b))
    return out


def _cycles(
    system: System, p, param: str, param_range: tuple[float, float]
) -> list[tuple[float, np.ndarray, float]]:
    """``(λ, orbit (M, n), period)`` of the model's limit cycles in the range."""
    lo, hi = sorted(float(v) for v in param_range)
    # the Hopf point may lie well outside the campaign's range: search a generous window
    span = max(hi - lo, 0.25 * max(abs(lo), abs(hi)), 1e-9)
    a, b = lo - span, hi + span
    opts = ContinuationOptions(
        ds=1e-3, ds_max=span / 10, ds_min=1e-9, p_min=a, p_max=b, max_steps=400
    )
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _, branches = continue_from_hopf(
                system, param, a, b, p=p, n_mesh=32, orbit_options=opts
            )
    except (BifidInputError, ArithmeticError, ValueError) as exc:
        warnings.warn(
            f"CBC defaults of {system.name!r}: no limit cycles found by "
            f"continuation ({exc}); generic amplitude grid.",
            ConvergenceWarning,
            stacklevel=4,
        )
        return []
    out = []
    for br in branches:
        M = int(br.meta.get("n_mesh", 32))
        n = system.n_states
        for i in range(len(br)):
            lam = float(br.params[i])
            if lo <= lam <= hi:
                out.append(
                    (lam, br.solutions[i, : M * n].reshape(M, n), float(br.data["period"][i]))
                )
    return out


def _from_cycles(system: System, cycles, x1: str) -> dict[str, Any]:
    i1 = system.state_index(x1)
    first = []
    for lam, orbit, _ in cycles:
        c = np.fft.rfft(orbit[:, i1]) / orbit.shape[0]
        first.append((lam, 2.0 * abs(c[1])))
    amps = np.array([a for _, a in first])
    lo_a, hi_a = 0.5 * float(np.min(amps)), 1.15 * float(np.max(amps))
    # coexisting cycles: the smallest distance between amplitudes at nearby parameters
    lams = np.array([lam for lam, _ in first])
    tol = 1e-3 * max(float(np.ptp(lams)), 1e-12)
    gaps = [
        abs(amps[i] - amps[j])
        for i in range(len(amps))
        for j in range(i)
        if abs(lams[i] - lams[j]) <= 10 * tol and abs(amps[i] - amps[j]) > 0.05 * amps[i]
    ]
    n = 16
    if gaps:
        n = int(min(max(math.ceil((hi_a - lo_a) / (0.5 * min(gaps))) + 1, 8), 32))
    reference = {}
    for name in system.states:
        i = system.state_index(name)
        reference[name] = float(min(np.max(np.abs(o[:, i] - o[:, i].mean())) for _, o, _ in cycles))
    periods = np.array([T for _, _, T in cycles])
    return {
        "amplitude_range": (lo_a, hi_a),
        "n_amplitudes": n,
        "noise_reference": reference,
        "omega_guess": float(2 * math.pi / np.median(periods)),
    }


def _gains(
    system: System, p, param: str, cycles, x1: str, x2: str, omega: float, b: float
) -> dict[str, float]:
    """The candidate gains with the smallest controlled Floquet multipliers (all
    candidates and cycles in one batched Floquet computation)."""
    i1 = system.state_index(x1)
    order = sorted(range(len(cycles)), key=lambda k: float(np.ptp(cycles[k][1][:, i1])))
    picks = sorted({order[0], order[len(order) // 2], order[-1]})
    candidates = [
        (kp_f * omega**2 / b, kd_f * omega / b)
        for kp_f in (0.0, 0.3, 1.0)
        for kd_f in (0.1, 0.3, 1.0, 3.0)
    ]
    targets, pvs = [], []
    for k in picks:
        lam, orbit, _ = cycles[k]
        pvs.append(np.asarray(p.at[system.index(param)].set(lam)))
        targets.append(orbit_polar_target(orbit, system, x1, x2, 10, p=pvs[-1]))
    rhs, _ = controlled_rhs(system, PDController(1.0, 1.0, x1, x2), targets[0])
    orbits, periods, qs = [], [], []
    for kp, kd in candidates:
        for j, k in enumerate(picks):
            _, orbit, period = cycles[k]
            orbits.append(orbit)
            periods.append(period)
            qs.append(augmented_params(pvs[j], PDController(kp, kd, x1, x2), targets[j]))
    try:
        _, _, fmax = floquet_multipliers(
            rhs, np.stack(orbits), np.array(periods), np.stack(qs), autonomous=True
        )
    except (BifidInputError, ArithmeticError, ValueError):
        return {}
    worst = np.nan_to_num(
        np.asarray(fmax, dtype=float).reshape(len(candidates), len(picks)), nan=np.inf
    ).max(axis=1)
    best = int(np.argmin(worst))
    if worst[best] >= 1.0:
        warnings.warn(
            f"CBC defaults of {system.name!r}: no candidate gains stabilise the "
            f"limit cycles (largest controlled multiplier {worst[best]:.3g}); give "
            "kp and kd.",
            ConvergenceWarning,
            stacklevel=4,
        )
    return {"kp": candidates[best][0], "kd": candidates[best][1]}
