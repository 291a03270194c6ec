"""Equilibria in one parameter: continuation, stability, Hopf and fold points.

Hopf points are detected by a change in the number of unstable complex eigenvalue
pairs and located by Newton's method on the standard defining system (Kuznetsov,
*Elements of Applied Bifurcation Theory*, §10.2)

.. math::

    f(x, \\lambda) = 0,\\quad J v_r + \\omega v_i = 0,\\quad J v_i - \\omega v_r = 0,\\quad
    \\langle g, v\\rangle = 1,

with ``v = v_r + i v_i`` the critical eigenvector (``J v = i omega v``) and ``g`` the
eigenvector guess; it converges quadratically, so the parameter is located to
round-off (≈1e-12). The first Lyapunov coefficient uses Kuznetsov's formula (eq. 3.20
there) with JAX derivatives:

.. math::

    l_1 = \\frac{1}{2\\omega}\\,\\mathrm{Re}\\Big[\\langle p, C(q,q,\\bar q)\\rangle
        - 2\\langle p, B(q, J^{-1}B(q,\\bar q))\\rangle
        + \\langle p, B(\\bar q, (2i\\omega I - J)^{-1} B(q,q))\\rangle\\Big],

``J q = i omega q``, ``J^T p = -i omega p``, ``<p, q> = 1``. ``l1 > 0``: subcritical.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from bifid.continuation._branch import Branch, SpecialPoint
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._palc import ZeroProblem, correct, palc
from bifid.errors import BifidInputError, ConvergenceError
from bifid.systems import System

Array = jnp.ndarray


def _with_param(p: Array, idx: Array, lam: Array) -> Array:
    return p.at[idx].set(lam)


@functools.lru_cache(maxsize=32)
def equilibrium_problem(field: Callable) -> ZeroProblem:
    """Zero problem ``f(x, p[idx] = lambda) = 0`` with ``y = [x, lambda]``."""

    def residual(y, args):
        return field(y[:-1], _with_param(args["p"], args["idx"], y[-1]))

    return ZeroProblem(residual=residual, param_index=-1)


@functools.lru_cache(maxsize=32)
def _hopf_kernels(field: Callable):
    def jac(x, p):
        return jax.jacfwd(field)(x, p)

    def hopf_residual(z, args):
        n = args["g_r"].shape[0]
        x, lam, om = z[:n], z[n], z[n + 1]
        vr, vi = z[n + 2 : 2 * n + 2], z[2 * n + 2 :]
        p = _with_param(args["p"], args["idx"], lam)
        J = jac(x, p)
        gr, gi = args["g_r"], args["g_i"]
        return jnp.concatenate(
            [
                field(x, p),
                J @ vr + om * vi,
                J @ vi - om * vr,
                jnp.stack([gr @ vr + gi @ vi - 1.0, gr @ vi - gi @ vr]),
            ]
        )

    @jax.jit
    def newton(z, args):
        def body(state):
            z, _, it = state
            dz = jnp.linalg.solve(jax.jacfwd(hopf_residual)(z, args), -hopf_residual(z, args))
            return z + dz, jnp.max(jnp.abs(dz)), it + 1

        def cond(state):
            _, err, it = state
            return (it < 30) & (err > 1e-13) & jnp.isfinite(err)

        z, err, _it = jax.lax.while_loop(cond, body, (z, jnp.asarray(1e300), 0))
        return z, err, jnp.max(jnp.abs(hopf_residual(z, args)))

    return jax.jit(jac), newton


@functools.lru_cache(maxsize=32)
def _multilinear(field: Callable):
    """Jitted second and third derivatives ``B(x0,p;u,v)``, ``C(x0,p;u,v,w)`` of ``field``."""

    def dir1(x, p, u):
        return jax.jvp(lambda y: field(y, p), (x,), (u,))[1]

    def B(x0, p, u, v):
        return jax.jvp(lambda x: dir1(x, p, u), (x0,), (v,))[1]

    def C(x0, p, u, v, w):
        return jax.jvp(lambda x: B(x, p, u, v), (x0,), (w,))[1]

    return jax.jit(B), jax.jit(C)


def _complex_B(B, u, v):
    ur, ui, vr, vi = u.real, u.imag, v.real, v.imag
    re = B(ur, vr) - B(ui, vi)
    im = B(ur, vi) + B(ui, vr)
    return np.asarray(re) + 1j * np.asarray(im)


def _complex_C(C, u, v, w):
    parts = [(u.real, 1.0), (u.imag, 1j)]
    total = 0j
    for a, ca in parts:
        for b, cb in [(v.real, 1.0), (v.imag, 1j)]:
            for c, cc in [(w.real, 1.0), (w.imag, 1j)]:
                total = total + ca * cb * cc * np.asarray(C(a, b, c))
    return total


def first_lyapunov_coefficient(field: Callable, x: Array, p: Array, omega: float) -> float:
    """First Lyapunov coefficient ``l1`` at a Hopf point (Kuznetsov normalisation).

    Parameters
    ----------
    field : callable ``(x, p) -> dx``
    x : array of shape (n,)
        Equilibrium at the Hopf point.
    p : array
        Parameter vector at the Hopf point.
    omega : float
        Hopf angular frequency (> 0).

    Returns
    -------
    float
        ``l1``; positive means subcritical (unstable cycles born), negative supercritical.
    """
    x = jnp.asarray(x)
    J = np.asarray(jax.jacfwd(field)(x, p))
    n = J.shape[0]
    w, V = np.linalg.eig(J)
    q = V[:, int(np.argmin(np.abs(w - 1j * omega)))]
    wl, W = np.linalg.eig(J.T)
    pv = W[:, int(np.argmin(np.abs(wl + 1j * omega)))]
    q = q / np.linalg.norm(q)
    pv = pv / np.conj(np.vdot(pv, q))  # <p, q> = conj(p) . q = 1
    Bj, Cj = _multilinear(field)

    def B(u, v):
        return Bj(x, p, jnp.asarray(u), jnp.asarray(v))

    def C(u, v, w):
        return Cj(x, p, jnp.asarray(u), jnp.asarray(v), jnp.asarray(w))

    def inner(a, b):
        return np.vdot(a, b)

    Bqqb = _complex_B(B, q, np.conj(q)).real
    Bqq = _complex_B(B, q, q)
    h11 = np.linalg.solve(J, Bqqb)
    h20 = np.linalg.solve(2j * omega * np.eye(n) - J, Bqq)
    # l1 = Re[<p,C(q,q,qb)> - 2<p,B(q,J^{-1}B(q,qb))> + <p,B(qb,(2iw-J)^{-1}B(q,q))>]/(2w)
    val = (
        inner(pv, _complex_C(C, q, q, np.conj(q)))
        - 2.0 * inner(pv, _complex_B(B, q, h11.astype(complex)))
        + inner(pv, _complex_B(B, np.conj(q), h20))
    )
    return float(val.real / (2.0 * omega))


def locate_hopf(
    system: System,
    param: str,
    x_guess: np.ndarray,
    lam_guess: float,
    p: Array,
    *,
    omega_guess: float | None = None,
) -> SpecialPoint:
    """Locate a Hopf point by Newton's method on the defining system.

    Raises
    ------
    ConvergenceError
        If Newton does not converge.
    """
    idx = system.index(param)
    jac, newton = _hopf_kernels(system.field)
    p = jnp.asarray(p)
    J = np.asarray(jac(jnp.asarray(x_guess), _with_param(p, idx, lam_guess)))
    w, V = np.linalg.eig(J)
    if omega_guess is None:
        cand = np.where(np.abs(w.imag) > 1e-10, np.abs(w.real), np.inf)
        k = int(np.argmin(cand))
    else:
        k = int(np.argmin(np.abs(w - 1j * omega_guess)))
    lam_c, v = w[k], V[:, k]
    if lam_c.imag < 0:
        lam_c, v = np.conj(lam_c), np.conj(v)
    g = v / np.linalg.norm(v)
    vn = v / np.vdot(g, v)  # normalised so that <g, v> = 1
    z0 = np.concatenate([x_guess, [lam_guess, lam_c.imag], vn.real, vn.imag])
    args = {"p": p, "idx": jnp.asarray(idx), "g_r": jnp.asarray(g.real), "g_i": jnp.asarray(g.imag)}
    z, err, res = newton(jnp.asarray(z0), args)
    z = np.asarray(z)
    n = len(x_guess)
    if not (np.isfinite(float(err)) and float(res) < 1e-9):
        raise ConvergenceError(
            f"Hopf point of {system.name!r} near {param}={lam_guess:.6g} could not be located "
            f"(residual {float(res):.1e})."
        )
    x, lam, om = z[:n], float(z[n]), float(abs(z[n + 1]))
    q = z[n + 2 : 2 * n + 2] + 1j * z[2 * n + 2 :]
    p_h = _with_param(p, idx, lam)
    l1 = first_lyapunov_coefficient(system.field, jnp.asarray(x), p_h, om)
    return SpecialPoint(
        kind="hopf",
        param=lam,
        index=-1,
        bracket=(lam, lam),
        solution=x,
        precision=float(err) + 1e-14,
        status="converged",
        data={
            "omega": om,
            "frequency_hz": om / (2 * np.pi),
            "lyapunov": l1,
            "criticality": "subcritical" if l1 > 0 else "supercritical",
            "eigenvector": q,
            "p": np.asarray(p_h),
            "param_name": param,
        },
    )


@functools.lru_cache(maxsize=32)
def _batched_jacobian(field: Callable) -> Callable:
    return jax.jit(jax.vmap(jax.jacfwd(field), in_axes=(0, 0)))


def _unstable_counts(eigs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    re = eigs.real
    complex_ = np.abs(eigs.imag) > 1e-9
    return np.sum((re > 0) & complex_, axis=1), np.sum((re > 0) & ~complex_, axis=1)


def equilibria(
    system: System,
    param: str,
    *,
    p: Array | None = None,
    x0: np.ndarray | None = None,
    start: float | None = None,
    options: ContinuationOptions | None = None,
    progress: Callable[[int, float], None] | None = None,
) -> Branch:
    """Continue equilibria of an autonomous system in ``param``.

    Parameters
    ----------
    system : System
    param : str
        Continuation parameter.
    p : array, optional
        Parameter vector (defaults); ``param`` starts at ``start`` or ``p[param]``.
    x0 : array of shape (n,), optional
        Guess of the starting equilibrium (default zeros).
    start : float, optional
        Starting parameter value.
    options : ContinuationOptions
        Bounds ``p_min``/``p_max`` and ``direction`` set the range.

    Returns
    -------
    Branch
        ``kind="equilibrium"``; ``data["eigenvalues"]`` (n_points, n); special points
        "hopf" (located, with ``omega``, ``lyapunov``, ``criticality``) and "fold".

    Raises
    ------
    BifidInputError
        For a forced system or an unknown parameter.
    ConvergenceError
        If no equilibrium can be found at the start.
    """
    if system.kind != "autonomous":
        raise BifidInputError(
            f"{system.name!r} is a forced system: it has periodic responses, not equilibria; "
            "use frc/scurve."
        )
    options = options or ContinuationOptions()
    idx = system.index(param)
    p = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    lam0 = float(p[idx]) if start is None else float(start)
    x0 = np.zeros(system.n_states) if x0 is None else np.asarray(x0, dtype=float)
    problem = equilibrium_problem(system.field)
    args = {"p": p, "idx": jnp.asarray(idx), "param_name": param}
    args_j = {k: v for k, v in args.items() if k != "param_name"}
    y0 = np.concatenate([x0, [lam0]])
    e = np.zeros_like(y0)
    e[-1] = 1.0
    y_c, ok, _, res = correct(problem, y0, e, lam0, args_j, tol=options.newton_tol)
    if not ok:
        raise ConvergenceError(
            f"No equilibrium of {system.name!r} found near the start {param}={lam0:.6g} "
            f"(Newton residual {res:.1e}); pass a better x0."
        )
    t0 = np.zeros_like(y0)
    t0[-1] = float(options.direction)
    result = palc(problem, y_c, t0, args_j, options, progress=progress, correct_start=False)
    if result.ys.shape[0] == 0:
        raise ConvergenceError(result.message)
    ys = result.ys
    jac = _batched_jacobian(system.field)
    ps = np.repeat(np.asarray(p)[None, :], ys.shape[0], axis=0)
    ps[:, idx] = ys[:, -1]
    eigs = np.linalg.eigvals(np.asarray(jac(jnp.asarray(ys[:, :-1]), jnp.asarray(ps))))
    n_cplx, n_real = _unstable_counts(eigs)
    stable = (n_cplx + n_real) == 0
    specials: list[SpecialPoint] = []
    for i in range(len(ys) - 1):
        if n_cplx[i] != n_cplx[i + 1]:
            a, b = ys[i], ys[i + 1]
            # linear interpolation of the critical real part gives the Newton guess
            ra = _crit_re(eigs[i])
            rb = _crit_re(eigs[i + 1])
            s = ra / (ra - rb) if ra != rb else 0.5
            guess = a + s * (b - a)
            try:
                sp = locate_hopf(system, param, guess[:-1], float(guess[-1]), p)
            except ConvergenceError:
                sp = SpecialPoint(
                    kind="hopf", param=float(guess[-1]), index=i, bracket=(a[-1], b[-1]),
                    solution=guess[:-1], status="guess",
                    data={"omega": float(np.abs(eigs[i].imag).max()), "lyapunov": float("nan"),
                          "criticality": "unknown"},
                )
            sp.index = i
            sp.bracket = (float(a[-1]), float(b[-1]))
            specials.append(sp)
    for i, y_f, prec in result.folds:
        specials.append(
            SpecialPoint(kind="fold", param=float(y_f[-1]), index=i,
                         bracket=(float(ys[i][-1]), float(ys[i + 1][-1])),
                         solution=y_f[:-1], precision=prec, status="converged")
        )
    for i in result.branch_points:
        specials.append(
            SpecialPoint(kind="branch_point", param=float(0.5 * (ys[i][-1] + ys[i + 1][-1])),
                         index=i, bracket=(float(ys[i][-1]), float(ys[i + 1][-1])),
                         solution=ys[i][:-1], status="guess")
        )
    specials.sort(key=lambda s: s.index)
    return Branch(
        kind="equilibrium", system=system.name, param=param, params=ys[:, -1],
        solutions=ys[:, :-1], stable=stable, special_points=specials,
        data={"eigenvalues": eigs, "state": ys[:, :-1]}, p=np.asarray(p),
        status=result.status, message=result.message, options=options,
        signals=tuple(system.states), meta={"states": list(system.states)},
    )


def _crit_re(eigs: np.ndarray) -> float:
    cplx = eigs[np.abs(eigs.imag) > 1e-9]
    if cplx.size == 0:
        return 0.0
    return float(cplx.real[np.argmin(np.abs(cplx.real))])
