"""Hopf points of equilibria: location, verification and the first Lyapunov coefficient.

A Hopf point is located by Newton's method on the standard defining system (Kuznetsov,
*Elements of Applied Bifurcation Theory*, §10.2)

.. math::

    f(x, \\lambda) = 0,\\quad J v_r + \\omega v_i = 0,\\quad J v_i - \\omega v_r = 0,\\quad
    \\langle g, v\\rangle = 1,

with ``v = v_r + i v_i`` the critical eigenvector (``J v = i omega v``) and ``g`` the
eigenvector guess; it converges quadratically, so the parameter is located to
round-off. The system also has solutions that are not Hopf points — ``omega = 0`` at a
fold (``J v = 0``) — so every located point is *verified* (``bifid.continuation._verify``)
by an eigenvalue computation at the point: a complex pair ``±i omega`` on the imaginary
axis (``|Re| <= HOPF_REAL_TOL * s``, ``s = max(1, max |eig|)``) with ``omega`` clearly
positive (``omega >= HOPF_OMEGA_MIN * s``), which excludes folds, neutral saddles
(``±mu`` real) and complex-to-real collisions.

The first Lyapunov coefficient uses Kuznetsov's formula (eq. 3.20 there) with JAX
derivatives:

.. math::

    l_1 = \\frac{1}{2\\omega}\\,\\mathrm{Re}\\Big[\\langle p, C(q,q,\\bar q)\\rangle
        - 2\\langle p, B(q, J^{-1}B(q,\\bar q))\\rangle
        + \\langle p, B(\\bar q, (2i\\omega I - J)^{-1} B(q,q))\\rangle\\Big],

``J q = i omega q``, ``J^T p = -i omega p``, ``<p, q> = 1``. ``l1 > 0``: subcritical.
It is undefined where ``J`` or ``2 i omega I - J`` is singular (a zero eigenvalue at the
Hopf point, or a 1:2 resonance); there it is reported as unknown, never as ``±inf``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bifid.continuation._branch import SpecialPoint
from bifid.continuation._verify import Check, Verdict, confirm, register_verifier
from bifid.errors import ConvergenceError
from bifid.systems import System

Array = jnp.ndarray

#: largest |Re| of the critical pair at a verified Hopf point, relative to the spectrum
HOPF_REAL_TOL = 1e-7
#: smallest omega of a verified Hopf point, relative to the spectrum (omega -> 0 is a fold
#: or a Bogdanov-Takens point, not a Hopf point)
HOPF_OMEGA_MIN = 1e-6
#: largest condition number of J and 2 i omega - J for which l1 is computed
LYAPUNOV_MAX_COND = 1e12


def with_param(p: Array, idx: Array, lam: Array) -> Array:
    """``p`` with ``p[idx] = lam`` (traced: no recompilation per value)."""
    return p.at[idx].set(lam)


@functools.lru_cache(maxsize=32)
def _hopf_kernels(field: Callable):
    def jac(x, p):
        return jax.jacfwd(field)(x, p)

    def hopf_residual(z, args):
        n = args["g_r"].shape[0]
        x, lam, om = z[:n], z[n], z[n + 1]
        vr, vi = z[n + 2 : 2 * n + 2], z[2 * n + 2 :]
        p = with_param(args["p"], args["idx"], lam)
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
        scale = 1.0 + jnp.max(jnp.abs(z))

        def body(state):
            z, _, it = state
            dz = jnp.linalg.solve(jax.jacfwd(hopf_residual)(z, args), -hopf_residual(z, args))
            return z + dz, jnp.max(jnp.abs(dz)), it + 1

        def cond(state):
            _, err, it = state
            return (it < 30) & (err > 1e-13 * scale) & jnp.isfinite(err)

        z, err, _it = jax.lax.while_loop(cond, body, (z, jnp.asarray(1e300), 0))
        return z, err, jnp.max(jnp.abs(hopf_residual(z, args))), scale

    return jax.jit(jac), newton


@functools.lru_cache(maxsize=32)
def _jitted_field(field: Callable) -> Callable:
    """``field`` compiled once (evaluated eagerly, a model's field dispatches hundreds of
    small operations: a fraction of a second per call)."""
    return jax.jit(field)


@functools.lru_cache(maxsize=32)
def multilinear_forms(field: Callable) -> tuple[Callable, Callable]:
    """Jitted multilinear forms of ``field``: ``B(x0, p, u, v) = D²f(x0)[u, v]`` and
    ``C(x0, p, u, v, w) = D³f(x0)[u, v, w]`` (nested forward-mode directional
    derivatives; cached per field, parameters traced). These are the forms of
    Kuznetsov's normal-form coefficients (``c1`` of the Hopf normal form)."""

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
    total = 0j
    for a, ca in ((u.real, 1.0), (u.imag, 1j)):
        for b, cb in ((v.real, 1.0), (v.imag, 1j)):
            for c, cc in ((w.real, 1.0), (w.imag, 1j)):
                total = total + ca * cb * cc * np.asarray(C(a, b, c))
    return total


def _solve_checked(A: np.ndarray, b: np.ndarray, what: str) -> np.ndarray:
    if not np.all(np.isfinite(A)) or np.linalg.cond(A) > LYAPUNOV_MAX_COND:
        raise ConvergenceError(f"the first Lyapunov coefficient is undefined: {what} is singular")
    return np.linalg.solve(A, b)


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

    Raises
    ------
    ConvergenceError
        Where ``l1`` is undefined: ``omega <= 0``, a zero eigenvalue at the point
        (``J`` singular), a 1:2 resonance (``2 i omega I - J`` singular), or a
        non-finite result.
    """
    if not (math.isfinite(omega) and omega > 0):
        raise ConvergenceError(f"the first Lyapunov coefficient needs omega > 0, got {omega!r}")
    x = jnp.asarray(x)
    J = np.asarray(_hopf_kernels(field)[0](x, p))
    n = J.shape[0]
    try:
        w, V = np.linalg.eig(J)
        wl, W = np.linalg.eig(J.T)
    except np.linalg.LinAlgError as exc:
        raise ConvergenceError(f"eigenvalues at the Hopf point failed: {exc}") from None
    q = V[:, int(np.argmin(np.abs(w - 1j * omega)))]
    pv = W[:, int(np.argmin(np.abs(wl + 1j * omega)))]
    q = q / np.linalg.norm(q)
    pq = np.vdot(pv, q)
    if abs(pq) < 1e-12:
        raise ConvergenceError(
            "the first Lyapunov coefficient is undefined: the critical eigenvalue is not simple"
        )
    pv = pv / np.conj(pq)  # <p, q> = conj(p) . q = 1
    Bj, Cj = multilinear_forms(field)

    def B(u, v):
        return Bj(x, p, jnp.asarray(u), jnp.asarray(v))

    def C(u, v, w_):
        return Cj(x, p, jnp.asarray(u), jnp.asarray(v), jnp.asarray(w_))

    Bqqb = _complex_B(B, q, np.conj(q)).real
    Bqq = _complex_B(B, q, q)
    h11 = _solve_checked(J, Bqqb, "the Jacobian (zero eigenvalue)")
    h20 = _solve_checked(2j * omega * np.eye(n) - J, Bqq, "2 i omega - J (1:2 resonance)")
    val = (
        np.vdot(pv, _complex_C(C, q, q, np.conj(q)))
        - 2.0 * np.vdot(pv, _complex_B(B, q, h11.astype(complex)))
        + np.vdot(pv, _complex_B(B, np.conj(q), h20))
    )
    l1 = float(val.real / (2.0 * omega))
    if not math.isfinite(l1):
        raise ConvergenceError("the first Lyapunov coefficient is not finite")
    return l1


def critical_pair(J: np.ndarray, omega_guess: float | None = None) -> tuple[complex, np.ndarray]:
    """Eigenvalue with positive imaginary part nearest ``i omega_guess`` (or, without a
    guess, the complex one nearest the imaginary axis) and its eigenvector."""
    w, V = np.linalg.eig(J)
    if omega_guess is None:
        cand = np.where(np.abs(w.imag) > 0, np.abs(w.real), np.inf)
        if not np.any(np.isfinite(cand)):
            cand = np.abs(w.real)
        k = int(np.argmin(cand))
    else:
        k = int(np.argmin(np.abs(w - 1j * abs(omega_guess))))
    lam_c, v = w[k], V[:, k]
    if lam_c.imag < 0:
        lam_c, v = np.conj(lam_c), np.conj(v)
    return complex(lam_c), v


def newton_hopf(
    system: System,
    param: str,
    x_guess: np.ndarray,
    lam_guess: float,
    p: Array,
    *,
    omega_guess: float | None = None,
) -> SpecialPoint:
    """Newton on the defining system from a guess; the point is *not* verified.

    Raises
    ------
    ConvergenceError
        If Newton does not converge.
    """
    idx = system.index(param)
    jac, newton = _hopf_kernels(system.field)
    p = jnp.asarray(p)
    x_guess = np.asarray(x_guess, dtype=float)
    J = np.asarray(jac(jnp.asarray(x_guess), with_param(p, idx, lam_guess)))
    if not np.all(np.isfinite(J)):
        raise ConvergenceError(f"the Jacobian is not finite at {param}={lam_guess:.6g}")
    lam_c, v = critical_pair(J, omega_guess)
    g = v / np.linalg.norm(v)
    vn = v / np.vdot(g, v)  # normalised so that <g, v> = 1
    z0 = np.concatenate([x_guess, [lam_guess, lam_c.imag], vn.real, vn.imag])
    args = {"p": p, "idx": jnp.asarray(idx), "g_r": jnp.asarray(g.real), "g_i": jnp.asarray(g.imag)}
    z, err, res, scale = (np.asarray(a) for a in newton(jnp.asarray(z0), args))
    n = len(x_guess)
    if not (np.all(np.isfinite(z)) and float(res) < 1e-9 * float(scale)):
        raise ConvergenceError(
            f"Newton on the Hopf system of {system.name!r} near {param}={lam_guess:.6g} "
            f"did not converge (residual {float(res):.1e})"
        )
    x, lam, om = z[:n], float(z[n]), float(abs(z[n + 1]))
    q = z[n + 2 : 2 * n + 2] + 1j * z[2 * n + 2 :]
    p_h = with_param(p, idx, lam)
    return SpecialPoint(
        kind="hopf",
        param=lam,
        index=-1,
        bracket=(lam, lam),
        solution=x,
        precision=float(err) + 1e-14 * float(scale),
        data={
            "omega": om,
            "frequency_hz": om / (2 * np.pi),
            "eigenvector": q,
            "p": np.asarray(p_h),
            "param_name": param,
        },
        verification={"defining_system_residual": float(res)},
    )


def add_lyapunov(field: Callable, point: SpecialPoint) -> SpecialPoint:
    """Fill in ``lyapunov`` and ``criticality`` of a verified Hopf point (``unknown`` where
    ``l1`` is undefined, with the reason in ``verification["lyapunov"]``)."""
    try:
        l1 = first_lyapunov_coefficient(
            field, jnp.asarray(point.solution), jnp.asarray(point.data["p"]), point.data["omega"]
        )
    except ConvergenceError as exc:
        point.data.update(lyapunov=math.nan, criticality="unknown")
        point.verification["lyapunov"] = str(exc)
        return point
    point.data.update(lyapunov=l1, criticality="subcritical" if l1 > 0 else "supercritical")
    return point


@register_verifier("hopf")
def verify_hopf(point: SpecialPoint, context: Mapping[str, Any]) -> Verdict:
    """A located Hopf point of an equilibrium (``context["field"]``): equilibrium residual,
    a complex pair on the imaginary axis at ``±i omega``, ``omega`` clearly positive."""
    field = context["field"]
    x = jnp.asarray(point.solution)
    p = jnp.asarray(point.data["p"])
    f = np.asarray(_jitted_field(field)(x, p))
    J = np.asarray(_hopf_kernels(field)[0](x, p))
    if not (np.all(np.isfinite(f)) and np.all(np.isfinite(J))):
        return Verdict((Check.finite("jacobian", math.inf),))
    eig = np.linalg.eigvals(J)
    s = max(1.0, float(np.max(np.abs(eig))))
    om = float(point.data["omega"])
    k = int(np.argmin(np.abs(eig - 1j * om)))
    xscale = 1.0 + float(np.max(np.abs(np.asarray(point.solution))))
    return Verdict(
        (
            Check.at_most("residual", float(np.max(np.abs(f))), 1e-8 * xscale),
            Check.at_most("real_part", float(eig[k].real), HOPF_REAL_TOL * s),
            Check.at_most("omega_mismatch", float(eig[k].imag) - om, HOPF_REAL_TOL * s),
            Check.at_least("omega", om, HOPF_OMEGA_MIN * s),
        )
    )


def locate_hopf(
    system: System,
    param: str,
    x_guess: np.ndarray,
    lam_guess: float,
    p: Array,
    *,
    omega_guess: float | None = None,
    bracket: tuple[float, float] | None = None,
) -> SpecialPoint:
    """Locate a Hopf point by Newton's method on the defining system and verify it.

    Parameters
    ----------
    system : System
    param : str
    x_guess : array of shape (n,)
        Guess of the equilibrium.
    lam_guess : float
        Guess of the parameter.
    p : array
        Parameter vector.
    omega_guess : float, optional
        Guess of the frequency (default: the complex eigenvalue nearest the axis).
    bracket : (float, float), optional
        Where the point must lie (default: anywhere).

    Returns
    -------
    SpecialPoint
        ``kind="hopf"``, ``status="converged"``, with ``omega``, ``lyapunov``,
        ``criticality`` and the ``verification`` record.

    Raises
    ------
    ConvergenceError
        If Newton does not converge or the point is not verified as a Hopf point.
    """
    result = confirm(
        "hopf",
        bracket or (lam_guess, lam_guess),
        lambda: newton_hopf(system, param, x_guess, lam_guess, p, omega_guess=omega_guess),
        context={"field": system.field},
        slack=None if bracket else math.inf,
    )
    if not isinstance(result, SpecialPoint):
        raise ConvergenceError(
            f"No Hopf point of {system.name!r} near {param}={lam_guess:.6g}: {result.reason}."
        )
    return add_lyapunov(system.field, result)
