"""Forced periodic responses by Fourier collocation: FRCs and S-curves.

A response of period ``2 pi / Omega`` is represented on ``tau_k = 2 pi k / M`` with
``t = tau / Omega``; the unknowns are the mesh values and the continuation parameter
(``Omega`` for an FRC, ``F`` for an S-curve):

.. math:: \\Omega D_M v - f(v_k, \\tau_k/\\Omega, p) = 0,\\qquad k = 1..M .

The phase lag ``psi`` of the observed coordinate's first harmonic behind the force
``F cos(Omega t)`` is ``atan2(b_1, a_1)`` with ``x ≈ a_1 cos tau + b_1 sin tau``.

The mesh follows the responses (``_mesh``), and the step control resolves the curve: a
step is accepted only when no harmonic of the response changed by more than
:data:`HARMONIC_CHANGE` of itself (complex coefficients, so amplitude and phase both
count; harmonics below :data:`HARMONIC_FLOOR` of the largest are ignored). Across a
``k:1`` superharmonic resonance the ``k``-th harmonic turns its phase by about π, so a
step can never jump over a resonance, however narrow; approaching one, the allowed step
shrinks in proportion to the distance, so its peak is resolved. Local maxima of the
observed amplitude are located (``peak`` special points) and verified; folds are
verified by ``_folds``; period doubling (a multiplier through -1), torus points (a complex
pair through the unit circle) and branch points (a multiplier through +1 where the curve
does not turn, e.g. a symmetry-breaking pitchfork) are located and verified on the
multipliers by ``_orbit_bifurcations``, as for autonomous orbits.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from bifid.continuation._branch import Branch, SpecialPoint
from bifid.continuation._floquet import floquet
from bifid.continuation._fourier import fourier_differentiation_matrix, fourier_grid
from bifid.continuation._mesh import (
    AdaptiveRun,
    Arc,
    MeshPolicy,
    Stage,
    bracket_slack,
    mesh_tail,
    on_common_mesh,
    remesh,
    residual_check,
    run_adaptive,
    run_residuals,
)
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._orbit_bifurcations import BracketContext, find_orbit_special_points
from bifid.continuation._palc import ZeroProblem, correct
from bifid.continuation._verify import Check, Findings, Verdict, register_verifier
from bifid.errors import BifidInputError, ConvergenceError
from bifid.signal import fourier_coefficients, max_abs
from bifid.systems import System

Array = jnp.ndarray

#: largest relative change of any harmonic of the response in one step
HARMONIC_CHANGE = 0.3
#: harmonics below this fraction of the largest do not limit the step
HARMONIC_FLOOR = 1e-5


@functools.lru_cache(maxsize=32)
def forced_rhs(system: System, forcing: tuple[float, ...] | None = None) -> Callable:
    """``(x, t, p) -> dx``: the system's right-hand side, or with the force along
    ``forcing`` instead of the system's forcing direction (mode appropriation)."""
    if forcing is None:
        return system.rhs
    b = jnp.asarray(forcing)
    iF, iOm = system.index("F"), system.index("Omega")

    def rhs(x, t, p):
        return system.field(x, p) + b * p[iF] * jnp.cos(p[iOm] * t)

    return rhs


@functools.lru_cache(maxsize=32)
def _directed_rhs(system: System) -> Callable:
    """``(x, t, [p, b]) -> dx``, the force along ``b``: one compiled Floquet integrator for
    a system's FRCs, S-curves and backbones (whose appropriated force has its own ``b``)."""
    n_p, iF, iOm = len(system.parameters), system.index("F"), system.index("Omega")

    def rhs(x, t, q):
        return system.field(x, q[:n_p]) + q[n_p:] * q[iF] * jnp.cos(q[iOm] * t)

    return rhs


@functools.lru_cache(maxsize=32)
def forced_problem(
    system: System, n_mesh: int, n_free: int, forcing: tuple[float, ...] | None = None
) -> ZeroProblem:
    """Collocation problem of forced responses.

    ``y = [v (M*n), lam_1..lam_nfree]``; ``args = {"p", "idx" (n_free,), "obs"}``. With
    ``n_free = 2`` (backbone) the extra equation ``a_1(v_obs) = 0`` (quadrature) is added.
    ``forcing`` replaces the system's forcing direction (see :func:`forced_rhs`).
    """
    M, n = n_mesh, system.n_states
    D = jnp.asarray(fourier_differentiation_matrix(M))
    tau = jnp.asarray(fourier_grid(M))
    iOm = system.index("Omega")
    rhs = forced_rhs(system, forcing)
    vrhs = jax.vmap(rhs, in_axes=(0, 0, None))
    vjac = jax.vmap(jax.jacfwd(rhs, argnums=0), in_axes=(0, 0, None))
    cos_row = jnp.cos(tau) * 2.0 / M

    def params(lams, args):
        return args["p"].at[args["idx"]].set(lams)

    def core(V, lams, args):
        p = params(lams, args)
        Om = p[iOm]
        return (Om * (D @ V) - vrhs(V, tau / Om, p)).ravel()

    def residual(y, args):
        V = y[: M * n].reshape(M, n)
        R = core(V, y[M * n :], args)
        if n_free == 2:
            R = jnp.concatenate([R, (cos_row @ V[:, args["obs"]])[None]])
        return R

    def jacobian(y, args):
        V = y[: M * n].reshape(M, n)
        lams = y[M * n :]
        p = params(lams, args)
        Om = p[iOm]
        Jk = vjac(V, tau / Om, p)
        block = jnp.einsum("kij,kl->kilj", Jk, jnp.eye(M)).reshape(M * n, M * n)
        # kron(D, I) built at run time: as a compile-time constant XLA would fold a
        # (Mn)^2 array, which takes seconds for large meshes
        KD = jnp.kron(jax.lax.optimization_barrier(D), jnp.eye(n))
        dV = Om * KD - block
        dl = jax.jacfwd(lambda l: core(V, l, args))(lams)  # (M*n, n_free)
        top = jnp.concatenate([dV, dl], axis=1)
        if n_free == 2:
            row = jnp.zeros((M, n)).at[:, args["obs"]].set(cos_row).ravel()
            bottom = jnp.concatenate([row, jnp.zeros(2)])[None, :]
            top = jnp.concatenate([top, bottom], axis=0)
        return top

    return ZeroProblem(residual=residual, param_index=M * n, jacobian=jacobian)


def forced_stage(
    system: System,
    M: int,
    n_free: int,
    args: dict,
    span: float,
    forcing: tuple[float, ...] | None = None,
) -> Stage:
    """The collocation problem of forced responses on ``M`` points (``_mesh.Stage``).

    Arclength weights: mesh values as an RMS over the period, each free parameter
    relative to ``span``, so a unit step means "the response changes by one unit or the
    parameter crosses ``span``" whatever the parameter's scale."""
    n = system.n_states
    w = np.concatenate([np.full(M * n, 1.0 / M), np.full(n_free, 1.0 / span**2)])
    return Stage(
        problem=forced_problem(system, M, n_free, forcing),
        weights=w,
        args=lambda y, prev=None: args,
    )


def harmonic_monitor(
    n: int, change: float = HARMONIC_CHANGE, floor: float = HARMONIC_FLOOR
) -> Callable[[np.ndarray, np.ndarray, int], float]:
    """Step control on the harmonic content (module docstring): ``(y, y_new, M) ->
    factor``, the headroom ``change / (largest relative change)``: ``< 1`` rejects the
    step, ``> 1`` lets the next one grow."""

    def monitor(y, y_new, M):
        c0 = np.fft.rfft(np.asarray(y[: M * n]).reshape(M, n), axis=0)[: M // 2]
        c1 = np.fft.rfft(np.asarray(y_new[: M * n]).reshape(M, n), axis=0)[: M // 2]
        size0, size1 = float(np.max(np.abs(c0[1:]))), float(np.max(np.abs(c1[1:])))
        scale = max(size0, size1)
        if size0 == 0.0:  # the first step from rest (F = 0): nothing to compare
            return math.inf
        ref = np.maximum(np.abs(c0), np.abs(c1))
        keep = ref > floor * scale
        rel = float(np.max(np.abs(c1 - c0)[keep] / ref[keep])) if np.any(keep) else 0.0
        return change / rel if rel > 0.0 else math.inf

    return monitor


def forced_branch(
    system: System,
    kind: str,
    param: str,
    run: AdaptiveRun,
    p,
    idx_free,
    options: ContinuationOptions,
    policy: MeshPolicy,
    observed: str,
    stage_of: Callable[[int], Stage],
    forcing: tuple[float, ...] | None = None,
) -> Branch:
    """Assemble the :class:`Branch` of an adaptive run of forced responses."""
    n = system.n_states
    obs = system.state_index(observed)
    ys, M = on_common_mesh(run.ys, run.meshes, n)
    orbits = ys[:, : M * n].reshape(-1, M, n)
    ps = np.repeat(np.asarray(p)[None, :], len(ys), axis=0)
    for j, i in enumerate(idx_free):
        ps[:, i] = ys[:, M * n + j]
    omega = ps[:, system.index("Omega")]
    forcing_amp = ps[:, system.index("F")]
    periods = 2.0 * np.pi / omega
    if forcing is None:  # the system's own direction
        b = np.asarray(jax.vmap(system.forcing_direction)(jnp.asarray(ps)))
    else:
        b = np.broadcast_to(np.asarray(forcing, dtype=float), (len(ps), n))
    fl = floquet(
        _directed_rhs(system),
        [np.asarray(y[: m * n]).reshape(m, n) for y, m in zip(run.ys, run.meshes, strict=True)],
        periods,
        np.concatenate([ps, b], axis=1),
        autonomous=False,
    )
    mults, logm, label = fl.multipliers, fl.log_moduli, fl.stable()
    stable = label.astype(bool) if np.all(np.isfinite(label)) else label
    amps = np.array([max_abs(o) for o in orbits])
    _, a_k, b_k = fourier_coefficients(np.moveaxis(orbits[:, :, obs], 1, 0))
    phase = np.arctan2(b_k[0], a_k[0])
    if kind != "backbone":
        # continuous lag in (-pi/2, 3pi/2]
        phase = np.where(phase < -np.pi / 2, phase + 2 * np.pi, phase)
    findings = Findings()
    params = ys[:, M * n]
    _report_folds(findings, system, run, params, p, stage_of, obs)
    if kind == "forced":
        _report_peaks(findings, system, run, params, stage_of, obs)
        # period doubling, torus and branch points of the responses, on the multipliers
        ctx = BracketContext(
            system=system,
            param=param,
            p=np.asarray(p),
            idx=idx_free[0],
            run=run,
            stage_of=stage_of,
            floquet=fl,
            zero=np.zeros(len(run.ys), bool),
            forced_rhs=forced_rhs(system, forcing),
        )
        find_orbit_special_points(findings, ctx, params)
    residual = run_residuals(run, stage_of)
    tails = np.asarray(run.tails)
    return Branch(
        kind=kind,
        system=system.name,
        param=param,
        params=params,
        solutions=ys[:, : M * n],
        stable=stable,
        special_points=findings.sorted_points(),
        data={
            "amplitude": amps,
            "observed_amplitude": amps[:, obs],
            "phase": phase,
            "omega": omega,
            "forcing": forcing_amp,
            "period": periods,
            "floquet": mults,
            "floquet_log": logm,
            "floquet_max": np.exp(np.nanmax(logm, axis=1)),
            "spectral_tail": tails,
            "n_mesh": np.asarray(run.meshes),
        },
        p=np.asarray(p),
        status=run.status,
        message=run.message,
        options=options,
        signals=tuple(system.states),
        meta={
            "n_mesh": int(M),
            "states": list(system.states),
            "observed": observed,
            "max_mesh": policy.max_mesh,
            "resolution_tol": policy.tol,
        },
        verification={"residual": residual, "spectral_tail": tails},
        candidates=findings.candidates,
    )


def _report_folds(findings, system, run, params, p, stage_of, obs) -> None:
    n = system.n_states
    iOm, iF = system.index("Omega"), system.index("F")
    for i, kind, y_f, prec, M in run.events:
        if kind != "fold":
            continue
        bracket = (params[i], params[i + 1])
        if y_f is None:
            findings.flag(
                "fold",
                bracket,
                "the parameter turned between these points but the fold could not be located",
            )
            continue
        stage = stage_of(M)
        q = np.asarray(stage.args(y_f)["p"]).copy()
        q[np.asarray(stage.args(y_f)["idx"])] = y_f[M * n :]
        V = np.asarray(y_f[: M * n]).reshape(M, n)
        point = SpecialPoint(
            kind="fold",
            param=float(y_f[M * n]),
            index=i,
            bracket=bracket,
            solution=np.asarray(y_f),
            precision=prec,
            data={
                "amplitude": float(max_abs(V[:, obs])),
                "omega": float(q[iOm]),
                "forcing": float(q[iF]),
                "n_mesh": int(M),
            },
        )
        findings.confirm(
            "fold",
            bracket,
            lambda point=point: point,
            context={
                "problem": stage.problem,
                "args": stage.args(y_f),
                "weights": stage.weights,
                "y": y_f,
            },
            index=i,
            slack=bracket_slack(run.ys[i], run.meshes[i], run.ys[i + 1], run.meshes[i + 1], n),
        )


@register_verifier("peak")
def verify_peak(point: SpecialPoint, context) -> Verdict:
    """A local maximum of the observed amplitude: on the curve, and no larger than the
    amplitude at its located neighbours (``context["neighbours"]``)."""
    a = float(point.data["amplitude"])
    excess = max(0.0, max(context["neighbours"]) - a)
    return Verdict(
        (residual_check(context), Check.at_most("neighbour_excess", excess, 1e-10 * max(1.0, a)))
    )


def _report_peaks(findings, system, run, params, stage_of, obs) -> None:
    """Locate each interior local maximum of the observed amplitude (golden-section
    search along the arcs on both sides of the largest point)."""
    n = system.n_states
    amp = np.array(
        [
            max_abs(np.asarray(y[: m * n]).reshape(m, n)[:, obs])
            for y, m in zip(run.ys, run.meshes, strict=True)
        ]
    )
    for i in range(1, len(amp) - 1):
        if not (amp[i] > amp[i - 1] and amp[i] >= amp[i + 1]):
            continue
        best = (amp[i], run.ys[i], run.meshes[i], 0.0)
        for j in (i - 1, i):
            found = _golden_max(system, run, j, stage_of, obs)
            if found is not None and found[0] > best[0]:
                best = found
        a, y, M, prec = best
        bracket = (params[i - 1], params[i + 1])
        point = SpecialPoint(
            kind="peak",
            param=float(y[M * n]),
            index=i,
            bracket=bracket,
            solution=np.asarray(y),
            precision=prec,
            data={"amplitude": float(a), "n_mesh": int(M)},
        )
        stage = stage_of(M)
        findings.confirm(
            "peak",
            bracket,
            lambda point=point: point,
            context={
                "problem": stage.problem,
                "args": stage.args(y),
                "y": y,
                "neighbours": (amp[i - 1], amp[i + 1]),
            },
            index=i,
        )


def _golden_max(system, run, j, stage_of, obs, iters: int = 40):
    """Largest observed amplitude on the arc between points ``j`` and ``j + 1``."""
    n = system.n_states
    M = max(run.meshes[j], run.meshes[j + 1])
    arc = Arc(stage_of(M), run.ys[j], run.meshes[j], run.ys[j + 1], run.meshes[j + 1], n)
    if arc.length == 0.0:
        return None

    def value(s):
        y = arc.point(s)
        if y is None or mesh_tail(y, M, n) > 1e-6:
            return -math.inf, None
        return float(max_abs(np.asarray(y[: M * n]).reshape(M, n)[:, obs])), y

    g = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = 0.0, arc.length
    c, e = b - g * (b - a), a + g * (b - a)
    (fc, yc), (fe, ye) = value(c), value(e)
    for _ in range(iters):
        if fc >= fe:
            b, e, fe, ye = e, c, fc, yc
            c = b - g * (b - a)
            fc, yc = value(c)
        else:
            a, c, fc, yc = c, e, fe, ye
            e = a + g * (b - a)
            fe, ye = value(e)
        if b - a < 1e-10 * arc.length:
            break
    fbest, ybest = (fc, yc) if fc >= fe else (fe, ye)
    return (fbest, ybest, M, abs(b - a)) if ybest is not None else None


def _require_forced(system: System) -> None:
    if system.kind != "forced":
        raise BifidInputError(
            f"{system.name!r} is autonomous: forced responses need a forced system "
            "(parameters F and Omega)."
        )


def check_range(name: str, lo: float, hi: float) -> tuple[float, float]:
    """A parameter range of two different finite numbers."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo == hi:
        raise BifidInputError(f"{name} must be two different finite numbers, got {lo!r}, {hi!r}.")
    return float(lo), float(hi)


def _linear_response(system: System, p: Array, M: int) -> np.ndarray:
    """Linear steady-state response about x = 0 on the collocation grid (start guess)."""
    J = np.asarray(jax.jacfwd(system.field)(jnp.zeros(system.n_states), jnp.asarray(p)))
    b = np.asarray(system.forcing_direction(jnp.asarray(p)))
    Om, F = float(p[system.index("Omega")]), float(p[system.index("F")])
    X = np.linalg.solve(1j * Om * np.eye(system.n_states) - J, b * F)
    return np.real(np.outer(np.exp(1j * fourier_grid(M)), X))


def frc(
    system: System,
    forcing: float,
    omega_range: tuple[float, float],
    *,
    p: Array | None = None,
    n_mesh: int = 64,
    max_mesh: int | None = None,
    adapt: bool = True,
    options: ContinuationOptions | None = None,
    observed: str | None = None,
    progress: Callable[[int, float], None] | None = None,
    resolution_tol: float = 1e-9,
) -> Branch:
    """Frequency response curve: continuation in ``Omega`` at fixed forcing ``F``.

    ``n_mesh`` is the starting (and smallest) mesh, ``max_mesh`` the limit (default: at
    most 4096 unknowns ``M * n``), ``adapt=False`` keeps ``n_mesh``.

    Returns
    -------
    Branch
        ``kind="forced"``, ``param="Omega"``; data ``observed_amplitude``, ``phase``,
        ``floquet``, ``n_mesh``; verified special points "fold" and "peak".
    """
    if not math.isfinite(forcing):
        raise BifidInputError(f"forcing must be finite, got {forcing!r}.")
    mesh = (p, n_mesh, max_mesh, adapt, options, observed, progress, resolution_tol)
    return _one_parameter(system, "Omega", omega_range, {"F": forcing}, mesh, "FRC")


def scurve(
    system: System,
    omega: float,
    forcing_range: tuple[float, float],
    *,
    p: Array | None = None,
    n_mesh: int = 64,
    max_mesh: int | None = None,
    adapt: bool = True,
    options: ContinuationOptions | None = None,
    observed: str | None = None,
    progress: Callable[[int, float], None] | None = None,
    resolution_tol: float = 1e-9,
) -> Branch:
    """S-curve: continuation in the forcing amplitude ``F`` at fixed ``Omega`` (mesh
    options as in :func:`frc`)."""
    if not (math.isfinite(omega) and omega > 0):
        raise BifidInputError(f"omega must be a positive finite number, got {omega!r}.")
    mesh = (p, n_mesh, max_mesh, adapt, options, observed, progress, resolution_tol)
    return _one_parameter(system, "F", forcing_range, {"Omega": omega}, mesh, "S-curve")


def _one_parameter(system, param, rng, fixed, settings, what) -> Branch:
    """Continuation of forced responses in ``param`` ("Omega" or "F") over ``rng``
    (``settings``: the keyword arguments of :func:`frc` from ``p`` on, in order)."""
    p, n_mesh, max_mesh, adapt, options, observed, progress, resolution_tol = settings
    _require_forced(system)
    lo, hi = check_range(f"{'omega' if param == 'Omega' else 'forcing'} range", *rng)
    if param == "Omega" and min(lo, hi) <= 0:
        raise BifidInputError(
            f"the omega range must be positive (a forcing frequency), got {lo:g}, {hi:g}."
        )
    if param == "F" and min(lo, hi) < 0:
        raise BifidInputError(f"the forcing range must not be negative, got {lo:g}, {hi:g}.")
    direction = 1 if hi > lo else -1
    n = system.n_states
    policy = MeshPolicy.of(n_mesh, max_mesh, resolution_tol, adapt, n)
    p = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    for name, value in fixed.items():
        p = p.at[system.index(name)].set(value)
    i_lam = system.index(param)
    p = p.at[i_lam].set(lo)
    options = options or ContinuationOptions(ds=0.01, ds_min=1e-10, ds_max=0.1, max_steps=2000)
    options = options.with_(p_min=min(lo, hi), p_max=max(lo, hi), direction=direction)
    args = {
        "p": jnp.asarray(p),
        "idx": jnp.asarray([i_lam]),
        "obs": jnp.asarray(system.state_index(system.observed)),
    }
    span = abs(hi - lo)

    def stage_of(M):
        return forced_stage(system, M, 1, args, span)

    M = n_mesh
    y0 = np.concatenate([_linear_response(system, p, M).ravel(), [lo]])
    e = np.zeros_like(y0)
    e[-1] = 1.0
    y0, ok, _, res = correct(
        stage_of(M).problem, y0, e, lo, args, tol=options.newton_tol, max_iter=30
    )
    while ok and mesh_tail(y0, M, n) > resolution_tol and policy.finer(M):
        M_new = policy.finer(M)
        y1 = remesh(y0, M, M_new, n)
        M = M_new
        e = np.zeros_like(y1)
        e[-1] = 1.0
        y0, ok, _, res = correct(
            stage_of(M).problem, y1, e, lo, args, tol=options.newton_tol, max_iter=30
        )
    if not ok or mesh_tail(y0, M, n) > resolution_tol:
        raise ConvergenceError(
            f"No resolved periodic response of {system.name!r} found at the start of the "
            f"{what} (residual {res:.1e}, spectral tail {mesh_tail(y0, M, n):.1e} on {M} "
            "points); start further from resonance, at a smaller forcing or with a larger "
            "mesh limit."
        )
    t0 = np.zeros_like(y0)
    t0[-1] = direction
    run = run_adaptive(
        stage_of, y0, t0, policy, options, n, M0=M, monitor=harmonic_monitor(n), progress=progress
    )
    return forced_branch(
        system,
        "forced",
        param,
        run,
        p,
        [i_lam],
        options,
        policy,
        observed or system.observed,
        stage_of,
    )
