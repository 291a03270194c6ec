"""Centre-manifold reduction and cubic normal form at a Hopf point (thesis §4.2, eqs. 4.2–4.6).

Everything is computed numerically from JAX derivatives of ``system.field``; nothing is
derived by hand for a particular system.

Normalisation (stated once, used everywhere)
--------------------------------------------
At the Hopf point :math:`(x^*, \\lambda_H)` let :math:`J = \\partial_x f`,
:math:`Jq = i\\omega q`, :math:`J^T p = -i\\omega p`, with

.. math:: \\langle q, q\\rangle = 1,\\qquad \\langle p, q\\rangle = 1,\\qquad
          \\langle a, b\\rangle = \\bar a^T b,

and the phase of ``q`` fixed by making its largest component real and positive. Near the
Hopf point the centre manifold is :math:`x = x^* + zq + \\bar z\\bar q + O(|z|^2)` and the
reduced dynamics in Poincaré normal form are (eqs. 4.4–4.5)

.. math:: \\dot w = \\lambda(\\mu)\\, w + c_1 w|w|^2 + O(|w|^5),\\qquad
          \\mu = \\lambda - \\lambda_H,

so that with :math:`w = R e^{i\\theta}` the amplitude equation is eq. 4.6 in physical
time,

.. math:: \\dot R = \\alpha_1 \\mu R + \\alpha_2 R^3,\\qquad
          \\alpha_1 = \\frac{d\\,\\mathrm{Re}\\,\\lambda}{d\\mu},\\quad
          \\alpha_2 = \\mathrm{Re}\\,c_1 = \\omega\\, l_1 .

:math:`l_1` is Kuznetsov's first Lyapunov coefficient (same normalisation); in the
rescaled time :math:`\\tau = \\omega t` of the thesis (eigenvalues :math:`\\pm i`) the
coefficients are :math:`\\alpha_1/\\omega` and :math:`\\alpha_2/\\omega = l_1`. The cubic
coefficient is (Kuznetsov, *Elements*, §5.4 / §10.2, with multilinear forms
:math:`B = D^2 f`, :math:`C = D^3 f` from nested ``jax.jvp``)

.. math::

    h_{20} = (2i\\omega I - J)^{-1} B(q,q),\\qquad h_{11} = -J^{-1} B(q,\\bar q),\\\\
    c_1 = \\tfrac12 \\langle p,\\ C(q,q,\\bar q) + B(\\bar q, h_{20}) + 2B(q, h_{11})\\rangle,

which is the complete complex :math:`c_1` (the full-space solves contain the
:math:`i(g_{20}g_{11} - 2|g_{11}|^2 - |g_{02}|^2/3)/(2\\omega)` terms). The transversality
coefficient uses :math:`d\\lambda/d\\mu = \\langle p, (dJ/d\\mu) q\\rangle` with the total
derivative :math:`dJ/d\\mu = \\partial_\\mu J + \\partial_x J\\,[dx^*/d\\mu]`,
:math:`dx^*/d\\mu = -J^{-1}\\partial_\\mu f`.

Predicted limit cycles (leading order, the near-identity transformation taken as the
identity as in §4.3.2): :math:`R^2 = -\\alpha_1\\mu/\\alpha_2` and, since
:math:`x_s(t) - x^*_s = 2R|q_s|\\cos(\\omega t + \\arg q_s)`, the amplitude
:math:`\\max_t |x_s(t) - x^*_s| = 2R|q_s|`. Its error is :math:`O(\\mu)` while the
amplitude is :math:`O(\\sqrt{|\\mu|})`: the relative error shrinks like
:math:`\\sqrt{|\\mu|}`. The frequency is
:math:`\\omega + (\\omega_1 - \\alpha_1\\,\\mathrm{Im}\\,c_1/\\mathrm{Re}\\,c_1)\\mu` with
:math:`\\omega_1 = d\\,\\mathrm{Im}\\lambda/d\\mu`.
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

from bifid.continuation import critical_pair, multilinear_forms
from bifid.errors import BifidInputError, ConvergenceError
from bifid.systems import System, get_system

Array = jnp.ndarray

__all__ = ["HopfNormalForm", "hopf_normal_form"]


# ----------------------------------------------------------------- multilinear forms
@functools.lru_cache(maxsize=32)
def _derivs(field: Callable):
    """Jitted Jacobian, field, multilinear forms and their parameter derivatives.

    Each is a small compiled graph; the complex combinations are assembled in NumPy
    (compiling the whole ``c1`` expression as one graph takes minutes).
    """

    # B(u, v) = D^2 f(x)[u, v], C(u, v, w) = D^3 f(x)[u, v, w]: continuation's forms
    B, C = multilinear_forms(field)

    def jac(x, p):
        return jax.jacfwd(field)(x, p)

    def dJ(x, p, dx, dp):
        # total derivative of J along (dx, dp)
        return jax.jvp(jac, (x, p), (dx, dp))[1]

    def Bp(x, p, u, v, dp):
        # d/dp B(u, v) along dp
        return jax.jvp(lambda pp: B(x, pp, u, v), (p,), (dp,))[1]

    def Cp(x, p, u, v, w, dp):
        return jax.jvp(lambda pp: C(x, pp, u, v, w), (p,), (dp,))[1]

    return (
        jax.jit(jac),
        jax.jit(field),
        B,
        C,
        jax.jit(dJ),
        jax.jit(Bp),
        jax.jit(Cp),
    )


def _cB(B, u, v) -> np.ndarray:
    """Complex bilinear extension of a real bilinear form ``B(u, v)``."""
    re = np.asarray(B(u.real, v.real)) - np.asarray(B(u.imag, v.imag))
    im = np.asarray(B(u.real, v.imag)) + np.asarray(B(u.imag, v.real))
    return re + 1j * im


def _cC(C, q) -> np.ndarray:
    """``C(q, q, conj q)`` from four real evaluations (C symmetric, q = a + ib).

    Expanding the trilinear form: ``C(q,q,qb) = C(a,a,a) + C(a,b,b) + i [C(a,a,b) + C(b,b,b)]``.
    """
    a, b = q.real, q.imag
    re = np.asarray(C(a, a, a)) + np.asarray(C(a, b, b))
    im = np.asarray(C(a, a, b)) + np.asarray(C(b, b, b))
    return re + 1j * im


def _c1_parts(B, C, J, omega, q, pa):
    """c1 = 1/2 <p, C(q,q,qb) + B(qb, h20) + 2 B(q, h11)> (see module docstring)."""
    n = J.shape[0]
    qb = np.conj(q)
    # (2 i w I - J) h20 = B(q, q)
    h20 = np.linalg.solve(2j * omega * np.eye(n) - J, _cB(B, q, q))
    # J h11 = -B(q, qb)
    h11 = -np.linalg.solve(J, _cB(B, q, qb).real).astype(complex)
    g = _cC(C, q) + _cB(B, qb, h20) + 2.0 * _cB(B, q, h11)
    return complex(0.5 * np.vdot(pa, g)), h20, h11


def _c1_derivative(B, C, Bd, Cd, J, omega, q, pa, h20, h11) -> complex:
    """Derivative of c1 along a parameter direction that leaves ``J`` unchanged.

    ``Bd``/``Cd`` are the parameter derivatives of the forms. With ``J`` fixed,
    ``h20' = (2iw - J)^{-1} B'(q,q)``, ``h11' = -J^{-1} B'(q,qb)`` and
    ``c1' = 1/2 <p, C'(q,q,qb) + B'(qb,h20) + B(qb,h20') + 2B'(q,h11) + 2B(q,h11')>``.
    """
    n = J.shape[0]
    qb = np.conj(q)
    h20d = np.linalg.solve(2j * omega * np.eye(n) - J, _cB(Bd, q, q))
    h11d = -np.linalg.solve(J, _cB(Bd, q, qb).real).astype(complex)
    g = (
        _cC(Cd, q)
        + _cB(Bd, qb, h20)
        + _cB(B, qb, h20d)
        + 2.0 * _cB(Bd, q, h11)
        + 2.0 * _cB(B, q, h11d)
    )
    return complex(0.5 * np.vdot(pa, g))


# --------------------------------------------------------------------- result type
@dataclass(frozen=True)
class HopfNormalForm:
    """Cubic normal form of a Hopf point (normalisation in the module docstring).

    Attributes
    ----------
    system : str
    param : str
        The bifurcation parameter; ``mu = param - param_value``.
    param_value : float
        Parameter at the Hopf point.
    p : ndarray
        Parameter vector at the Hopf point.
    x_eq : ndarray
        Equilibrium at the Hopf point.
    omega : float
        Angular frequency at the Hopf point [rad/s].
    q, p_adj : complex ndarray
        Critical right and adjoint eigenvectors, ``<q,q> = 1``, ``<p,q> = 1``.
    alpha1 : float
        ``d Re(lambda)/d mu`` (transversality), per unit of the parameter and per second.
    omega1 : float
        ``d Im(lambda)/d mu``.
    c1 : complex
        Cubic normal-form coefficient (physical time).
    states : tuple of str
    """

    system: str
    param: str
    param_value: float
    p: np.ndarray
    x_eq: np.ndarray
    omega: float
    q: np.ndarray
    p_adj: np.ndarray
    alpha1: float
    omega1: float
    c1: complex
    states: tuple[str, ...] = field(default=())

    @property
    def alpha2(self) -> float:
        """``Re c1``: the cubic coefficient of eq. 4.6 in physical time."""
        return float(self.c1.real)

    @property
    def l1(self) -> float:
        """First Lyapunov coefficient ``Re c1 / omega`` (Kuznetsov)."""
        return float(self.c1.real / self.omega)

    @property
    def criticality(self) -> str:
        """ "subcritical" (``l1 > 0``: unstable cycles born) or "supercritical"."""
        return "subcritical" if self.l1 > 0 else "supercritical"

    def tau_coefficients(self) -> tuple[float, float]:
        """``(alpha1, alpha2)`` in the rescaled time ``tau = omega t`` of thesis eq. 4.6."""
        return self.alpha1 / self.omega, self.alpha2 / self.omega

    def radius(self, values: Any) -> np.ndarray:
        """Normal-form radius ``R = sqrt(-alpha1 mu / alpha2)`` (NaN where no cycle exists)."""
        mu = np.asarray(values, dtype=float) - self.param_value
        r2 = -self.alpha1 * mu / self.alpha2
        with np.errstate(invalid="ignore"):
            return np.where(r2 >= 0, np.sqrt(np.abs(r2)), np.nan)

    def amplitude(self, values: Any, state: str | None = None) -> np.ndarray:
        """Predicted LCO amplitude ``max_t |x_s(t) - x*_s| = 2 R |q_s|`` near the Hopf point.

        Parameters
        ----------
        values : float or array
            Parameter values.
        state : str, optional
            One state; otherwise all states (last axis).

        Returns
        -------
        ndarray of shape ``values.shape`` (one state) or ``values.shape + (n_states,)``.
        NaN on the side of the Hopf point without cycles.
        """
        R = self.radius(values)
        scale = 2.0 * np.abs(self.q)
        if state is not None:
            return R * scale[self._state_index(state)]
        return R[..., None] * scale

    def frequency(self, values: Any) -> np.ndarray:
        """Predicted LCO angular frequency to first order in ``mu`` [rad/s]."""
        mu = np.asarray(values, dtype=float) - self.param_value
        slope = self.omega1 - self.alpha1 * self.c1.imag / self.c1.real
        return self.omega + slope * mu

    def initial_orbit(self, value: float, n_mesh: int) -> tuple[np.ndarray, float]:
        """Leading-order periodic orbit at parameter ``value``, for seeding a collocation solve.

        Returns mesh values ``x* + 2 R Re(q e^{i tau_k})`` on ``tau_k = 2 pi k / M``
        (shape ``(M, n)``) and the predicted period ``2 pi / omega(value)``.

        Raises
        ------
        BifidInputError
            If the normal form has no cycle at ``value``.
        """
        R = float(self.radius(value))
        if not np.isfinite(R):
            raise BifidInputError(
                f"no cycle at {self.param}={value:.6g}: the {self.criticality} normal form has "
                f"cycles on the other side of {self.param_value:.8g}."
            )
        tau = 2.0 * np.pi * np.arange(n_mesh) / n_mesh
        V = self.x_eq[None, :] + 2.0 * R * np.real(np.outer(np.exp(1j * tau), self.q))
        return V, float(2.0 * np.pi / self.frequency(value))

    def _state_index(self, state: str) -> int:
        if state not in self.states:
            raise BifidInputError(f"unknown state {state!r}; states: {', '.join(self.states)}.")
        return self.states.index(state)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary."""
        a1t, a2t = self.tau_coefficients()
        return {
            "system": self.system,
            "param": self.param,
            "param_value": self.param_value,
            "omega": self.omega,
            "frequency_hz": self.omega / (2 * math.pi),
            "alpha1": self.alpha1,
            "omega1": self.omega1,
            "c1_real": float(self.c1.real),
            "c1_imag": float(self.c1.imag),
            "alpha2": self.alpha2,
            "l1": self.l1,
            "alpha1_tau": a1t,
            "alpha2_tau": a2t,
            "criticality": self.criticality,
            "eigenvector_modulus": dict(zip(self.states, map(float, np.abs(self.q)), strict=True)),
            "normalisation": "<q,q>=1, <p,q>=1, x = x* + z q + conj(z q); physical time",
        }


# ----------------------------------------------------------------------- builders
def _normalise(q: np.ndarray) -> np.ndarray:
    q = q / np.linalg.norm(q)
    k = int(np.argmax(np.abs(q)))
    return q * np.exp(-1j * np.angle(q[k]))


def hopf_normal_form(
    system: str | System,
    param: str | None = None,
    *,
    p: Array | Mapping[str, float] | None = None,
    guess: float | None = None,
    x_guess: np.ndarray | None = None,
    hopf: Any = None,
) -> HopfNormalForm:
    """Locate a Hopf point and compute its cubic normal form.

    Parameters
    ----------
    system : str or System
    param : str, optional
        Bifurcation parameter (default: the system's ``default_param``).
    p : array or mapping, optional
        Parameter vector, or overrides of the defaults.
    guess : float, optional
        Starting value of the parameter for the Hopf location (default: ``p[param]``).
    x_guess : array, optional
        Equilibrium guess (zeros by default).
    hopf : SpecialPoint, optional
        An already located Hopf point (from :func:`bifid.continuation.equilibria`); it is
        refined again by Newton.

    Returns
    -------
    HopfNormalForm

    Raises
    ------
    ConvergenceError
        If no Hopf point is found near the guess, or it is degenerate (``alpha1 = 0``
        or ``Re c1 = 0``).
    """
    from bifid.continuation import locate_hopf

    sys_ = get_system(system) if isinstance(system, str) else system
    param = param or sys_.default_param
    idx = sys_.index(param)
    if isinstance(p, Mapping) or p is None:
        pv = sys_.param_vector(dict(p or {}))
    else:
        pv = jnp.asarray(p, dtype=jnp.float64)
    if hopf is not None:
        lam0 = float(hopf.param)
        x0 = np.asarray(hopf.solution, dtype=float)
        if "p" in hopf.data:
            pv = jnp.asarray(hopf.data["p"], dtype=jnp.float64)
        omega_guess = float(hopf.data.get("omega", 0.0)) or None
    else:
        lam0 = float(pv[idx]) if guess is None else float(guess)
        x0 = np.zeros(sys_.n_states) if x_guess is None else np.asarray(x_guess, dtype=float)
        omega_guess = None
    sp = locate_hopf(sys_, param, x0, lam0, pv, omega_guess=omega_guess)
    lam_h = float(sp.param)
    x = np.asarray(sp.solution, dtype=float)
    p_h = jnp.asarray(pv).at[idx].set(lam_h)
    jac, f, B, C, dJ, _, _ = _derivs(sys_.field)
    xj = jnp.asarray(x)
    J = np.asarray(jac(xj, p_h))
    lam, q = critical_pair(J, float(sp.data["omega"]))
    omega = float(lam.imag)
    q = _normalise(q)
    wl, W = np.linalg.eig(J.T)
    pa = W[:, int(np.argmin(np.abs(wl + 1j * omega)))]
    pa = pa / np.conj(np.vdot(pa, q))  # <p, q> = conj(p).q = 1
    # transversality: d lambda / d mu = <p, (dJ/dmu) q>, dJ/dmu total along the equilibrium
    e = jnp.zeros_like(p_h).at[idx].set(1.0)
    f_mu = np.asarray(jax.jvp(lambda pp: f(xj, pp), (p_h,), (e,))[1])
    dx = -np.linalg.solve(J, f_mu)
    dJm = np.asarray(dJ(xj, p_h, jnp.asarray(dx), e))
    dlam = np.vdot(pa, dJm @ q)
    c1, _, _ = _c1_parts(_bind(B, xj, p_h), _bind(C, xj, p_h), J, omega, q, pa)
    nf = HopfNormalForm(
        system=sys_.name,
        param=param,
        param_value=lam_h,
        p=np.asarray(p_h),
        x_eq=x,
        omega=omega,
        q=q,
        p_adj=pa,
        alpha1=float(dlam.real),
        omega1=float(dlam.imag),
        c1=c1,
        states=tuple(sys_.states),
    )
    if abs(nf.alpha1) < 1e-14 or abs(nf.alpha2) < 1e-300:
        raise ConvergenceError(
            f"Degenerate Hopf point of {sys_.name!r} at {param}={lam_h:.8g}: "
            f"alpha1={nf.alpha1:.3g}, "
            f"Re c1={nf.alpha2:.3g}; the cubic normal form does not decide the cycles."
        )
    return nf


def _bind(form: Callable, x: Array, p: Array) -> Callable:
    """Fix the base point of a multilinear form: ``form(x, p, *dirs)`` -> ``g(*dirs)``."""

    def g(*dirs):
        return form(x, p, *(jnp.asarray(d) for d in dirs))

    return g


def _bind_dp(form: Callable, x: Array, p: Array, dp: Array) -> Callable:
    def g(*dirs):
        return form(x, p, *(jnp.asarray(d) for d in dirs), dp)

    return g
