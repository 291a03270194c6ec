"""Periodic orbits of autonomous systems by Fourier spectral collocation (thesis eqs. 4.12–4.14).

Unknowns ``y = [v_1 .. v_M, T, lambda]`` (mesh values on ``tau_k = 2 pi k / M``, the
period and the parameter); equations

.. math::

    D_M v - \\frac{T}{2\\pi} f(v_k, \\lambda) = 0 \\quad (k = 1..M),\\qquad
    \\frac1M\\sum_k \\langle v_k, (D_M v^{\\rm ref})_k\\rangle = 0,

the second being the integral phase condition against the previous point of the
branch. Pseudo-arclength continuation (``_palc``) adds the arclength equation. The
Jacobian is assembled explicitly — ``kron(D_M, I) - T/2pi blockdiag(f_x(v_k))`` plus two
columns — which is far cheaper than differentiating the whole residual.
"""

from __future__ import annotations

import functools
import warnings
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from bifid.continuation._branch import Branch, SpecialPoint
from bifid.continuation._equilibria import equilibria
from bifid.continuation._floquet import autonomous_rhs, floquet_multipliers
from bifid.continuation._fourier import (
    check_resolution,
    fourier_differentiation_matrix,
    fourier_grid,
)
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._palc import ZeroProblem, correct, palc
from bifid.errors import BifidInputError, ConvergenceError
from bifid.signal import max_abs, spectral_tail
from bifid.systems import System

Array = jnp.ndarray
TWO_PI = 2.0 * np.pi


@functools.lru_cache(maxsize=32)
def orbit_problem(field: Callable, n_mesh: int, n_states: int) -> ZeroProblem:
    """Collocation zero problem of autonomous periodic orbits (see module docstring).

    ``args = {"p": parameter vector, "idx": index of lambda, "dref": (M*n,) flattened
    D_M v_ref}``. ``y`` has ``M*n + 2`` components: mesh values (row-major ``(M, n)``),
    then ``T``, then ``lambda``.
    """
    M, n = n_mesh, n_states
    D = jnp.asarray(fourier_differentiation_matrix(M))
    KD = jnp.kron(D, jnp.eye(n))
    vfield = jax.vmap(field, in_axes=(0, None))
    vjac = jax.vmap(jax.jacfwd(field), in_axes=(0, None))

    def split(y, args):
        V = y[: M * n].reshape(M, n)
        T, lam = y[M * n], y[M * n + 1]
        return V, T, lam, args["p"].at[args["idx"]].set(lam)

    def residual(y, args):
        V, T, _, p = split(y, args)
        R = D @ V - T / TWO_PI * vfield(V, p)
        phase = jnp.sum(y[: M * n] * args["dref"]) / M
        return jnp.concatenate([R.ravel(), phase[None]])

    def jacobian(y, args):
        V, T, lam, p = split(y, args)
        Jk = vjac(V, p)  # (M, n, n)
        block = jnp.einsum("kij,kl->kilj", Jk, jnp.eye(M)).reshape(M * n, M * n)
        dV = KD - T / TWO_PI * block
        dT = -vfield(V, p).ravel() / TWO_PI

        def f_of_lam(l):
            return vfield(V, args["p"].at[args["idx"]].set(l)).ravel()

        dlam = -T / TWO_PI * jax.jvp(f_of_lam, (lam,), (jnp.ones_like(lam),))[1]
        top = jnp.concatenate([dV, dT[:, None], dlam[:, None]], axis=1)
        bottom = jnp.concatenate([args["dref"] / M, jnp.zeros(2)])[None, :]
        return jnp.concatenate([top, bottom], axis=0)

    return ZeroProblem(residual=residual, param_index=-1, jacobian=jacobian)


def _orbit_weights(M: int, n: int) -> np.ndarray:
    # mesh values enter the arclength norm as an average over the orbit
    return np.concatenate([np.full(M * n, 1.0 / M), [1.0, 1.0]])


def _dref_updater(M: int, n: int):
    D = fourier_differentiation_matrix(M)

    def update(y, args):
        V = np.asarray(y[: M * n]).reshape(M, n)
        return {**args, "dref": jnp.asarray((D @ V).ravel())}

    return update


def hopf_orbits(
    system: System,
    hopf: SpecialPoint,
    *,
    p: Array | None = None,
    n_mesh: int = 64,
    options: ContinuationOptions | None = None,
    amplitude0: float | None = None,
    progress: Callable[[int, float], None] | None = None,
    resolution_tol: float = 1e-9,
) -> Branch:
    """Continue the branch of periodic orbits born at a Hopf point.

    The first orbit is ``x_H + eps Re(q e^{i tau})`` (``q`` the critical eigenvector)
    corrected with its projection on ``q`` fixed; continuation then proceeds by
    pseudo-arclength until a parameter bound, ``max_steps``, or the orbit shrinks back
    to an equilibrium.

    Parameters
    ----------
    system : System
    hopf : SpecialPoint
        A located Hopf point (from :func:`equilibria` or :func:`locate_hopf`).
    p : array, optional
        Parameter vector (defaults to the one stored with the Hopf point).
    n_mesh : int
        Collocation points M (even).
    options : ContinuationOptions
        ``ds`` is the first amplitude step (RMS norm over the orbit).
    amplitude0 : float, optional
        Size of the first orbit (default ``options.ds``).

    Returns
    -------
    Branch
        ``kind="periodic"``; ``solutions[:, :M*n]`` mesh values, ``data`` has
        ``period``, ``amplitude`` (n_points, n) = max_t|x_s(t)|, ``floquet``
        (n_points, n), ``floquet_max``, ``spectral_tail``; special points
        "cycle_fold", "period_doubling", "torus", "branch_point".
    """
    if hopf.kind != "hopf" or "eigenvector" not in hopf.data:
        raise BifidInputError("hopf_orbits needs a located Hopf point (kind 'hopf' with data).")
    options = options or ContinuationOptions()
    param = hopf.data.get("param_name") or system.default_param
    idx = system.index(param)
    p = jnp.asarray(hopf.data["p"] if p is None else p, dtype=jnp.float64)
    M, n = n_mesh, system.n_states
    problem = orbit_problem(system.field, M, n)
    tau = fourier_grid(M)
    q = np.asarray(hopf.data["eigenvector"], dtype=complex)
    q = q / np.max(np.abs(q))
    direction = np.real(np.outer(np.exp(1j * tau), q))  # (M, n)
    omega = float(hopf.data["omega"])
    x_h = np.asarray(hopf.solution, dtype=float)
    y_h = np.concatenate([np.tile(x_h, M), [TWO_PI / omega, hopf.param]])
    t0 = np.concatenate([direction.ravel(), [0.0, 0.0]])
    w = _orbit_weights(M, n)
    t0 = t0 / np.sqrt(t0 @ (w * t0))
    eps = options.ds if amplitude0 is None else float(amplitude0)
    D = fourier_differentiation_matrix(M)
    args = {"p": p, "idx": jnp.asarray(idx), "dref": jnp.asarray((D @ direction).ravel())}
    y_pred = y_h + eps * t0
    row = w * t0
    y1, ok, _, res = correct(problem, y_pred, row, float(row @ y_pred), args,
                             tol=options.newton_tol, max_iter=options.newton_max_iter)
    if not ok:
        raise ConvergenceError(
            f"Could not converge the first periodic orbit next to the Hopf point at "
            f"{param}={hopf.param:.8g} (residual {res:.1e}); try a smaller first step (ds)."
        )
    update = _dref_updater(M, n)
    args = update(y1, args)
    amp_h = float(np.max(np.abs(direction))) * eps

    def stop(y):
        V = y[: M * n].reshape(M, n)
        small = np.max(np.abs(V - V.mean(axis=0))) < 1e-3 * amp_h
        long = y[M * n] > 100.0 * TWO_PI / omega
        return bool(small or long)

    result = palc(problem, y1, t0, args, options, weights=w, update_args=update, stop=stop,
                  progress=progress, correct_start=False)
    ys = np.vstack([y_h[None, :], result.ys])
    return _orbit_branch(system, param, p, ys, result, options, M, hopf, resolution_tol)


def resample_orbit(values: np.ndarray, n_mesh: int) -> np.ndarray:
    """Trigonometric interpolation of periodic mesh values ``(M, n)`` onto ``n_mesh`` points."""
    v = np.asarray(values, dtype=float)
    M = v.shape[0]
    c = np.fft.rfft(v, axis=0)
    if n_mesh < M:
        c = c[: n_mesh // 2 + 1]
    return np.fft.irfft(c, n=n_mesh, axis=0) * (n_mesh / M)


def periodic_orbits(
    system: System,
    param: str,
    orbit: np.ndarray,
    period: float,
    *,
    p: Array | None = None,
    n_mesh: int | None = None,
    options: ContinuationOptions | None = None,
    progress: Callable[[int, float], None] | None = None,
    resolution_tol: float = 1e-9,
) -> Branch:
    """Continue periodic orbits from an approximate orbit.

    Parameters
    ----------
    system : System
    param : str
        Continuation parameter; its start value is ``p[param]``.
    orbit : array of shape (M0, n)
        Approximate orbit on an equispaced grid over one period (resampled to ``n_mesh``).
    period : float
        Approximate period.
    options : ContinuationOptions
        ``direction`` sets the initial direction of the parameter.

    Raises
    ------
    ConvergenceError
        If the initial orbit cannot be corrected at the start parameter.
    """
    options = options or ContinuationOptions(ds=1e-2, ds_max=0.25, ds_min=1e-9)
    idx = system.index(param)
    p = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    orbit = np.asarray(orbit, dtype=float)
    if orbit.ndim != 2 or orbit.shape[1] != system.n_states:
        raise BifidInputError(
            f"orbit must have shape (M, {system.n_states}), got {orbit.shape}."
        )
    M = n_mesh or orbit.shape[0]
    V = resample_orbit(orbit, M) if orbit.shape[0] != M else orbit
    n = system.n_states
    problem = orbit_problem(system.field, M, n)
    D = fourier_differentiation_matrix(M)
    lam0 = float(p[idx])
    y0 = np.concatenate([V.ravel(), [period, lam0]])
    args = {"p": p, "idx": jnp.asarray(idx), "dref": jnp.asarray((D @ V).ravel())}
    e = np.zeros_like(y0)
    e[-1] = 1.0
    y0, ok, _, res = correct(problem, y0, e, lam0, args, tol=options.newton_tol, max_iter=30)
    if not ok:
        raise ConvergenceError(
            f"The starting orbit of {system.name!r} at {param}={lam0:.8g} did not converge "
            f"(residual {res:.1e})."
        )
    update = _dref_updater(M, n)
    args = update(y0, args)
    t0 = np.zeros_like(y0)
    t0[-1] = float(options.direction)
    w = _orbit_weights(M, n)
    result = palc(problem, y0, t0, args, options, weights=w, update_args=update,
                  progress=progress, correct_start=False)
    pseudo_hopf = SpecialPoint(kind="start", param=lam0, index=0, bracket=(lam0, lam0),
                               solution=y0, data={})
    return _orbit_branch(system, param, p, result.ys, result, options, M, pseudo_hopf,
                         resolution_tol, offset=0)


def _orbit_branch(system, param, p, ys, result, options, M, hopf, resolution_tol,
                  offset: int = 1) -> Branch:
    n = system.n_states
    idx = system.index(param)
    orbits = ys[:, : M * n].reshape(-1, M, n)
    periods = ys[:, M * n]
    params = ys[:, M * n + 1]
    ps = np.repeat(np.asarray(p)[None, :], len(ys), axis=0)
    ps[:, idx] = params
    mults, stable, fmax = floquet_multipliers(
        autonomous_rhs(system.field), orbits, periods, ps, autonomous=True
    )
    amps = np.array([max_abs(o) for o in orbits])
    tails = np.array([spectral_tail(o) if np.ptp(o) > 0 else 0.0 for o in orbits])
    check_resolution(tails[1:], M, resolution_tol, f"periodic orbits of {system.name!r}")
    specials: list[SpecialPoint] = []
    # offset = 1 when ys has the Hopf point prepended
    for i, y_f, prec in result.folds:
        V = y_f[: M * n].reshape(M, n)
        specials.append(
            SpecialPoint(
                kind="cycle_fold", param=float(y_f[M * n + 1]), index=i + offset,
                bracket=(float(params[i + offset]), float(params[i + offset + 1])),
                solution=y_f[: M * n + 1], precision=prec, status="converged",
                data={"period": float(y_f[M * n]), "amplitude": max_abs(V),
                      "amplitude_centred": max_abs(V - V.mean(axis=0)),
                      "amplitude_states": list(system.states)},
            )
        )
    for i in result.branch_points:
        specials.append(
            SpecialPoint(kind="branch_point", param=float(params[i + offset]), index=i + offset,
                         bracket=(float(params[i + offset]), float(params[i + offset + 1])),
                         solution=ys[i + offset, : M * n + 1], status="guess")
        )
    specials.extend(_secondary_from_floquet(mults, params, ys, M, n))
    specials.sort(key=lambda s: s.index)
    if hopf.kind == "hopf":  # the Hopf point itself: a zero-amplitude orbit
        stable[0] = bool(hopf.data.get("criticality") == "supercritical")
    return Branch(
        kind="periodic", system=system.name, param=param, params=params,
        solutions=ys[:, : M * n + 1], stable=stable, special_points=specials,
        data={"period": periods, "amplitude": amps,
              # about the orbit's mean, as a rig measures it (offsets removed)
              "amplitude_centred": np.array([max_abs(o - o.mean(axis=0)) for o in orbits]),
              "floquet": mults, "floquet_max": fmax, "spectral_tail": tails},
        p=np.asarray(p), status=result.status, message=result.message, options=options,
        signals=tuple(system.states),
        meta={"n_mesh": M, "states": list(system.states), "start_param": hopf.param,
              "start_kind": hopf.kind},
    )


def _secondary_from_floquet(mults, params, ys, M, n) -> list[SpecialPoint]:
    """Period-doubling and torus points bracketed by the non-trivial multipliers."""
    out: list[SpecialPoint] = []

    def crossings(m):
        m = np.delete(m, int(np.argmin(np.abs(m - 1.0))))
        outside = np.abs(m) > 1.0
        pd = np.sum(outside & (np.abs(m.imag) < 1e-8) & (m.real < 0))
        ns = np.sum(outside & (np.abs(m.imag) >= 1e-8))
        return pd, ns

    prev = crossings(mults[1]) if len(mults) > 1 else (0, 0)
    for i in range(2, len(mults)):
        cur = crossings(mults[i])
        for kind, a, b in (("period_doubling", prev[0], cur[0]), ("torus", prev[1], cur[1])):
            if a != b:
                out.append(
                    SpecialPoint(kind=kind, param=float(0.5 * (params[i - 1] + params[i])),
                                 index=i - 1, bracket=(float(params[i - 1]), float(params[i])),
                                 solution=ys[i, : M * n + 1], status="guess")
                )
        prev = cur
    return out


def continue_from_hopf(
    system: System,
    param: str,
    lo: float,
    hi: float,
    *,
    p: Array | None = None,
    n_mesh: int = 64,
    eq_options: ContinuationOptions | None = None,
    orbit_options: ContinuationOptions | None = None,
    progress: Callable[[int, float], None] | None = None,
) -> tuple[Branch, list[Branch]]:
    """Equilibria over ``[lo, hi]`` and the periodic-orbit branch of every Hopf point found.

    Raises
    ------
    BifidInputError
        If the range contains no Hopf point.
    """
    if not lo < hi:
        lo, hi = hi, lo
    span = hi - lo
    eq_options = eq_options or ContinuationOptions(
        ds=span / 50, ds_max=span / 20, ds_min=span * 1e-8, p_min=lo, p_max=hi, max_steps=2000
    )
    p = system.param_vector() if p is None else jnp.asarray(p)
    eq = equilibria(system, param, p=p, start=lo, options=eq_options)
    hopfs = [sp for sp in eq.special_points if sp.kind == "hopf" and sp.status == "converged"]
    if not hopfs:
        raise BifidInputError(
            f"No Hopf point of {system.name!r} in {param} ∈ [{lo:g}, {hi:g}]; "
            "widen the range or change parameters."
        )
    branches = []
    for h in hopfs:
        opts = orbit_options or ContinuationOptions(
            ds=1e-3, ds_max=0.25, ds_min=1e-9, p_min=lo, p_max=hi, max_steps=600
        )
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            branches.append(hopf_orbits(system, h, p=p, n_mesh=n_mesh, options=opts,
                                        progress=progress))
    return eq, branches
