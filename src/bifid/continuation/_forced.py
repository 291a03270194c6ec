"""Forced periodic responses by Fourier collocation: FRCs, S-curves, backbone curves.

A response of period ``2 pi / Omega`` is represented on ``tau_k = 2 pi k / M`` with
``t = tau / Omega``; the unknowns are the mesh values and the continuation parameter
(``Omega`` for an FRC, ``F`` for an S-curve):

.. math:: \\Omega D_M v - f(v_k, \\tau_k/\\Omega, p) = 0,\\qquad k = 1..M .

The phase lag ``psi`` of the observed coordinate's first harmonic behind the force
``F cos(Omega t)`` is ``atan2(b_1, a_1)`` with ``x ≈ a_1 cos tau + b_1 sin tau``.
The backbone curve is the locus of phase quadrature (``psi = pi/2``, i.e. ``a_1 = 0``),
followed with both ``Omega`` and ``F`` free (thesis §6.2.3.4).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from bifid.continuation._branch import Branch, SpecialPoint
from bifid.continuation._floquet import floquet_multipliers
from bifid.continuation._fourier import (
    check_resolution,
    fourier_differentiation_matrix,
    fourier_grid,
)
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._palc import ZeroProblem, correct, palc
from bifid.errors import BifidInputError, ConvergenceError
from bifid.signal import fourier_coefficients, max_abs, spectral_tail
from bifid.systems import System

Array = jnp.ndarray


@functools.lru_cache(maxsize=32)
def forced_problem(system: System, n_mesh: int, n_free: int) -> ZeroProblem:
    """Collocation problem of forced responses.

    ``y = [v (M*n), lam_1..lam_nfree]``; ``args = {"p", "idx" (n_free,), "obs"}``. With
    ``n_free = 2`` (backbone) the extra equation ``a_1(v_obs) = 0`` (quadrature) is added.
    """
    M, n = n_mesh, system.n_states
    D = jnp.asarray(fourier_differentiation_matrix(M))
    KD = jnp.kron(D, jnp.eye(n))
    tau = jnp.asarray(fourier_grid(M))
    iOm = system.index("Omega")
    rhs = system.rhs
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
        dV = Om * KD - block
        dl = jax.jacfwd(lambda l: core(V, l, args))(lams)  # (M*n, n_free)
        top = jnp.concatenate([dV, dl], axis=1)
        if n_free == 2:
            row = jnp.zeros((M, n)).at[:, args["obs"]].set(cos_row).ravel()
            bottom = jnp.concatenate([row, jnp.zeros(2)])[None, :]
            top = jnp.concatenate([top, bottom], axis=0)
        return top

    return ZeroProblem(residual=residual, param_index=M * n, jacobian=jacobian)


def _forced_branch(system, kind, param, ys, result, p, idx_free, M, options, observed,
                   resolution_tol) -> Branch:
    n = system.n_states
    obs = system.state_index(observed)
    orbits = ys[:, : M * n].reshape(-1, M, n)
    ps = np.repeat(np.asarray(p)[None, :], len(ys), axis=0)
    for j, i in enumerate(idx_free):
        ps[:, i] = ys[:, M * n + j]
    omega = ps[:, system.index("Omega")]
    forcing = ps[:, system.index("F")]
    periods = 2.0 * np.pi / omega
    mults, stable, fmax = floquet_multipliers(system.rhs, orbits, periods, ps, autonomous=False)
    amps = np.array([max_abs(o) for o in orbits])
    _, a_k, b_k = fourier_coefficients(np.moveaxis(orbits[:, :, obs], 1, 0))
    a1, b1 = a_k[0], b_k[0]
    phase = np.arctan2(b1, a1)
    if kind != "backbone":
        # continuous lag in (-pi/2, 3pi/2]
        phase = np.where(phase < -np.pi / 2, phase + 2 * np.pi, phase)
    tails = np.array([spectral_tail(o) for o in orbits])
    check_resolution(tails, M, resolution_tol, f"forced responses of {system.name!r}")
    specials: list[SpecialPoint] = []
    pidx = 0
    for i, y_f, prec in result.folds:
        V = y_f[: M * n].reshape(M, n)
        specials.append(
            SpecialPoint(
                kind="fold", param=float(y_f[M * n + pidx]), index=i,
                bracket=(float(ys[i, M * n]), float(ys[i + 1, M * n])),
                solution=y_f, precision=prec, status="converged",
                data={"amplitude": float(max_abs(V[:, obs])), "omega": float(
                    y_f[M * n] if param == "Omega" else p[system.index("Omega")]),
                      "forcing": float(y_f[M * n] if param == "F" else p[system.index("F")])},
            )
        )
    for i in result.branch_points:
        specials.append(
            SpecialPoint(kind="branch_point", param=float(ys[i, M * n]), index=i,
                         bracket=(float(ys[i, M * n]), float(ys[i + 1, M * n])),
                         solution=ys[i], status="guess")
        )
    return Branch(
        kind=kind, system=system.name, param=param, params=ys[:, M * n],
        solutions=ys[:, : M * n], stable=stable, special_points=specials,
        data={"amplitude": amps, "observed_amplitude": amps[:, obs], "phase": phase,
              "omega": omega, "forcing": forcing, "period": periods, "floquet": mults,
              "floquet_max": fmax, "spectral_tail": tails},
        p=np.asarray(p), status=result.status, message=result.message, options=options,
        signals=tuple(system.states),
        meta={"n_mesh": M, "states": list(system.states), "observed": observed},
    )


def _weights(M: int, n: int, span: float) -> np.ndarray:
    """Arclength weights: mesh values as an RMS over the period, the parameter relative to
    its range, so a unit step means "the response changes by one unit or the parameter
    crosses its whole range" whatever the parameter's scale."""
    return np.concatenate([np.full(M * n, 1.0 / M), [1.0 / span**2]])


def _require_forced(system: System) -> None:
    if system.kind != "forced":
        raise BifidInputError(
            f"{system.name!r} is autonomous: forced responses need a forced system "
            "(parameters F and Omega)."
        )


def _check_range(name: str, lo: float, hi: float) -> tuple[float, float]:
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo == hi:
        raise BifidInputError(f"{name} must be two different finite numbers, got {lo!r}, {hi!r}.")
    return float(lo), float(hi)


def _start_solution(system, problem, p, lam_index, lam0, M, options, what):
    """Newton from the linear response (rest for F = 0) at fixed parameter ``lam0``."""
    n = system.n_states
    x_lin = _linear_response(system, p, M)
    y0 = np.concatenate([x_lin.ravel(), [lam0]])
    e = np.zeros_like(y0)
    e[-1] = 1.0
    args = {"p": jnp.asarray(p), "idx": jnp.asarray([lam_index]),
            "obs": jnp.asarray(system.state_index(system.observed))}
    y, ok, _, res = correct(problem, y0, e, lam0, args, tol=options.newton_tol, max_iter=30)
    if not ok:
        raise ConvergenceError(
            f"No periodic response of {system.name!r} found at the start of the {what} "
            f"(residual {res:.1e}); start further from resonance or at a smaller forcing."
        )
    assert y.shape[0] == M * n + 1
    return y, args


def _linear_response(system: System, p: Array, M: int) -> np.ndarray:
    """Linear steady-state response about x = 0 on the collocation grid (start guess)."""
    J = np.asarray(jax.jacfwd(system.field)(jnp.zeros(system.n_states), jnp.asarray(p)))
    b = np.asarray(system.forcing_direction(jnp.asarray(p)))
    Om = float(p[system.index("Omega")])
    F = float(p[system.index("F")])
    X = np.linalg.solve(1j * Om * np.eye(system.n_states) - J, b * F)
    tau = fourier_grid(M)
    return np.real(np.outer(np.exp(1j * tau), X))



def frc(
    system: System,
    forcing: float,
    omega_range: tuple[float, float],
    *,
    p: Array | None = None,
    n_mesh: int = 64,
    options: ContinuationOptions | None = None,
    observed: str | None = None,
    progress: Callable[[int, float], None] | None = None,
    resolution_tol: float = 1e-9,
) -> Branch:
    """Frequency response curve: continuation in ``Omega`` at fixed forcing ``F``.

    Returns
    -------
    Branch
        ``kind="forced"``, ``param="Omega"``; data ``observed_amplitude``, ``phase``,
        ``floquet``; special points "fold".
    """
    if not math.isfinite(forcing):
        raise BifidInputError(f"forcing must be finite, got {forcing!r}.")
    return _one_parameter(system, "Omega", omega_range, {"F": forcing}, p, n_mesh, options,
                          observed, progress, resolution_tol, "FRC")


def scurve(
    system: System,
    omega: float,
    forcing_range: tuple[float, float],
    *,
    p: Array | None = None,
    n_mesh: int = 64,
    options: ContinuationOptions | None = None,
    observed: str | None = None,
    progress: Callable[[int, float], None] | None = None,
    resolution_tol: float = 1e-9,
) -> Branch:
    """S-curve: continuation in the forcing amplitude ``F`` at fixed ``Omega``."""
    if not (math.isfinite(omega) and omega > 0):
        raise BifidInputError(f"omega must be a positive finite number, got {omega!r}.")
    return _one_parameter(system, "F", forcing_range, {"Omega": omega}, p, n_mesh, options,
                          observed, progress, resolution_tol, "S-curve")


def _one_parameter(system, param, rng, fixed, p, n_mesh, options, observed, progress,
                   resolution_tol, what) -> Branch:
    """Continuation of forced responses in ``param`` ("Omega" or "F") over ``rng``."""
    _require_forced(system)
    lo, hi = _check_range(f"{'omega' if param == 'Omega' else 'forcing'} range", *rng)
    direction = 1 if hi > lo else -1
    p = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    for name, value in fixed.items():
        p = p.at[system.index(name)].set(value)
    i_lam = system.index(param)
    p = p.at[i_lam].set(lo)
    options = options or ContinuationOptions(ds=0.01, ds_min=1e-10, ds_max=0.1, max_steps=2000)
    options = options.with_(p_min=min(lo, hi), p_max=max(lo, hi), direction=direction)
    problem = forced_problem(system, n_mesh, 1)
    y0, args = _start_solution(system, problem, p, i_lam, lo, n_mesh, options, what)
    t0 = np.zeros_like(y0)
    t0[-1] = direction
    result = palc(problem, y0, t0, args, options, weights=_weights(n_mesh, system.n_states,
                                                                    abs(hi - lo)),
                  progress=progress, correct_start=False)
    return _forced_branch(system, "forced", param, result.ys, result, p, [i_lam], n_mesh,
                          options, observed or system.observed, resolution_tol)


def backbone(
    system: System,
    amplitude_range: tuple[float, float],
    *,
    p: Array | None = None,
    n_mesh: int = 64,
    mode: int = 0,
    options: ContinuationOptions | None = None,
    observed: str | None = None,
    progress: Callable[[int, float], None] | None = None,
    resolution_tol: float = 1e-9,
) -> Branch:
    """Backbone curve as the locus of phase quadrature (lag ``pi/2``), thesis §6.2.3.4.

    Starts at the linear resonance of mode ``mode`` (modes ordered by frequency) with the
    forcing that gives amplitude ``amplitude_range[0]``, then follows the quadrature
    locus with ``Omega`` and ``F`` free until the observed amplitude exceeds
    ``amplitude_range[1]``.

    Returns
    -------
    Branch
        ``kind="backbone"``, ``param="F"``; data ``omega``, ``forcing``,
        ``observed_amplitude``.
    """
    _require_forced(system)
    a_lo, a_hi = _check_range("amplitude range", *amplitude_range)
    a_lo, a_hi = min(a_lo, a_hi), max(a_lo, a_hi)
    if a_lo <= 0:
        raise BifidInputError(f"the amplitude range must be positive, got {amplitude_range}.")
    p = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    n = system.n_states
    M = n_mesh
    obs_name = observed or system.observed
    obs = system.state_index(obs_name)
    J = np.asarray(jax.jacfwd(system.field)(jnp.zeros(n), p))
    ev = np.linalg.eigvals(J)
    freqs = np.sort(np.unique(np.round(np.abs(ev.imag[ev.imag > 1e-12]), 12)))
    if mode >= len(freqs):
        raise BifidInputError(f"{system.name!r} has {len(freqs)} oscillatory modes; mode={mode}.")
    Om0 = float(freqs[mode])
    b = np.asarray(system.forcing_direction(p))
    X = np.linalg.solve(1j * Om0 * np.eye(n) - J, b)
    F0 = a_lo / abs(X[obs])
    p = p.at[system.index("Omega")].set(Om0).at[system.index("F")].set(F0)
    tau = fourier_grid(M)
    V0 = np.real(np.outer(np.exp(1j * tau), X * F0))
    iF, iOm = system.index("F"), system.index("Omega")
    problem = forced_problem(system, M, 2)
    args = {"p": p, "idx": jnp.asarray([iF, iOm]), "obs": jnp.asarray(obs)}
    y0 = np.concatenate([V0.ravel(), [F0, Om0]])
    e = np.zeros_like(y0)
    e[M * n] = 1.0
    y0, ok, _, res = correct(problem, y0, e, F0, args, tol=1e-10, max_iter=30)
    if not ok:
        raise ConvergenceError(
            f"Could not start the backbone of {system.name!r} at amplitude {a_lo:g} "
            f"(residual {res:.1e}); try a smaller start amplitude."
        )
    options = options or ContinuationOptions(
        ds=a_lo, ds_min=a_lo * 1e-8, ds_max=(a_hi - a_lo) / 20, max_steps=2000,
        detect_folds=False
    )
    w = np.concatenate([np.full(M * n, 1.0 / M), [1.0, 1.0]])
    t0 = np.zeros_like(y0)
    t0[M * n] = 1.0

    def stop(y):
        return bool(np.max(np.abs(y[obs : M * n : n])) > a_hi)

    result = palc(problem, y0, t0, args, options, weights=w, stop=stop, progress=progress,
                  correct_start=False)
    br = _forced_branch(system, "backbone", "F", result.ys, result, p, [iF, iOm], M, options,
                        obs_name, resolution_tol)
    br.meta["mode"] = mode
    br.meta["linear_frequency"] = Om0
    return br
