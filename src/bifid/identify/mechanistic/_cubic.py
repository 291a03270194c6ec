"""Structure of the cubic normal-form coefficient in the nonlinear parameters (thesis eq. 4.10).

For parameters that enter only the nonlinear terms of the field at the equilibrium, the Hopf
point, ``J``, ``omega``, ``q`` and ``p`` stay fixed and :math:`\\alpha_2 = \\mathrm{Re}\\,c_1`
is re-evaluated, with its exact gradient, from the multilinear forms alone
(:class:`CubicCoefficient`). :func:`quadratic_cubic_structure` shows the form
:math:`\\alpha_2 = c_3 k_3 + c_{22} k_2^2` of a quadratic and a cubic stiffness;
:func:`hopf_point_regression` estimates a Hopf point from measured unstable LCOs (Fig. 4.1).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError
from bifid.identify.mechanistic._normal_form import (
    HopfNormalForm,
    _bind,
    _bind_dp,
    _c1_derivative,
    _c1_parts,
    _derivs,
)
from bifid.systems import System, get_system

Array = jnp.ndarray

__all__ = [
    "CubicCoefficient",
    "cubic_coefficient_fn",
    "hopf_point_regression",
    "nonlinear_only",
    "quadratic_cubic_structure",
]


@dataclass(frozen=True)
class CubicCoefficient:
    """``Re c1`` (and its gradient) as a function of parameters that leave the linearisation fixed.

    Built by :func:`cubic_coefficient_fn` from a :class:`HopfNormalForm`. For such
    parameters (e.g. ``ka2``, ``ka3`` of ``flutter``) the Hopf point, ``J``, ``omega``,
    ``q`` and ``p`` do not move, so ``c1`` is re-evaluated with the fixed linear data and
    its gradient follows exactly from the parameter derivatives of the forms ``B``, ``C``
    (see :func:`_c1_derivative`).
    """

    nf: HopfNormalForm
    field: Callable
    index: dict[str, int]

    def c1(self, p: Array) -> complex:
        """Complex cubic coefficient at parameter vector ``p``."""
        _, _, B, C, _, _, _ = _derivs(self.field)
        x, pj = jnp.asarray(self.nf.x_eq), jnp.asarray(p, dtype=jnp.float64)
        J = self._J()
        c1, _, _ = _c1_parts(
            _bind(B, x, pj), _bind(C, x, pj), J, self.nf.omega, self.nf.q, self.nf.p_adj
        )
        return c1

    def __call__(self, p: Array) -> float:
        """``alpha2 = Re c1`` at ``p``."""
        return float(self.c1(p).real)

    def gradient(self, p: Array, names: Sequence[str]) -> np.ndarray:
        """Exact ``d Re c1 / d p_name`` for each name (JAX derivatives of ``B`` and ``C``)."""
        _, _, B, C, _, Bp, Cp = _derivs(self.field)
        x, pj = jnp.asarray(self.nf.x_eq), jnp.asarray(p, dtype=jnp.float64)
        J = self._J()
        Bx, Cx = _bind(B, x, pj), _bind(C, x, pj)
        _, h20, h11 = _c1_parts(Bx, Cx, J, self.nf.omega, self.nf.q, self.nf.p_adj)
        out = []
        for nm in names:
            e = jnp.zeros_like(pj).at[self.index[nm]].set(1.0)
            d = _c1_derivative(
                Bx,
                Cx,
                _bind_dp(Bp, x, pj, e),
                _bind_dp(Cp, x, pj, e),
                J,
                self.nf.omega,
                self.nf.q,
                self.nf.p_adj,
                h20,
                h11,
            )
            out.append(d.real)
        return np.asarray(out)

    def _J(self) -> np.ndarray:
        jac = _derivs(self.field)[0]
        return np.asarray(jac(jnp.asarray(self.nf.x_eq), jnp.asarray(self.nf.p)))


def cubic_coefficient_fn(system: str | System, nf: HopfNormalForm) -> CubicCoefficient:
    """``Re c1`` as a function of the parameter vector, the linear data of ``nf`` held fixed.

    Valid for changes of parameters that enter only the nonlinear part of the field at
    the equilibrium (check with :func:`nonlinear_only`).
    """
    sys_ = get_system(system) if isinstance(system, str) else system
    return CubicCoefficient(
        nf=nf, field=sys_.field, index={n: i for i, n in enumerate(sys_.parameter_names)}
    )


def nonlinear_only(system: str | System, nf: HopfNormalForm, names: Sequence[str]) -> bool:
    """True if the parameters ``names`` leave ``f(x*)`` and ``J(x*)`` unchanged at the Hopf point.

    Checked by exact JAX directional derivatives along each parameter.
    """
    sys_ = get_system(system) if isinstance(system, str) else system
    _, f, _, _, dJ, _, _ = _derivs(sys_.field)
    x, p = jnp.asarray(nf.x_eq), jnp.asarray(nf.p)
    for nm in names:
        e = jnp.zeros_like(p).at[sys_.index(nm)].set(1.0)
        df = np.asarray(jax.jvp(lambda pp: f(x, pp), (p,), (e,))[1])
        dj = np.asarray(dJ(x, p, jnp.zeros_like(x), e))
        if np.max(np.abs(df)) > 1e-12 or np.max(np.abs(dj)) > 1e-12:
            return False
    return True


def quadratic_cubic_structure(
    system: str | System,
    nf: HopfNormalForm,
    quadratic: str,
    cubic: str,
    *,
    grid: tuple[float, float] = (0.5, 1.5),
    n_grid: int = 4,
) -> dict[str, Any]:
    """Show ``alpha2(k2, k3) = c3 k3 + c22 k2^2`` (thesis eq. 4.10) and return the coefficients.

    ``c3 = d alpha2 / d k3`` and ``c22 = (d alpha2 / d k2) / (2 k2)`` come from exact JAX
    derivatives at the nominal point. The structure is then checked in two independent
    ways: (i) a least-squares fit of the general quadratic
    ``a0 + a1 k2 + a2 k3 + a3 k2^2 + a4 k2 k3 + a5 k3^2`` to ``alpha2`` on an
    ``n_grid x n_grid`` grid over ``[grid[0], grid[1]] x nominal`` — every term except
    ``k3`` and ``k2^2`` must vanish to round-off and the two-term model must reproduce
    ``alpha2`` to round-off; (ii) the exact gradient at every grid point must equal
    ``(2 c22 k2, c3)``.

    Returns
    -------
    dict
        ``c3``, ``c22`` (physical time, ``<q,q>=1``), the same in ``tau = omega t``
        (``c3_tau``, ``c22_tau``; the normalisation of thesis eq. 4.10), ``ratio``
        ``c22/c3`` (independent of the normalisation), ``fit`` (polynomial
        coefficients), ``max_rel_residual`` (two-term model vs computed ``alpha2``),
        ``max_rel_gradient_error``, ``k3_critical`` (``k3`` at which the bifurcation
        changes criticality at the nominal ``k2``).
    """
    sys_ = get_system(system) if isinstance(system, str) else system
    if not nonlinear_only(sys_, nf, [quadratic, cubic]):
        raise BifidInputError(
            f"{quadratic!r}/{cubic!r} change the linearisation of {sys_.name!r} at the Hopf "
            "point; the structure alpha2 = c3 k3 + c22 k2^2 does not apply."
        )
    cc = cubic_coefficient_fn(sys_, nf)
    i2, i3 = sys_.index(quadratic), sys_.index(cubic)
    p0 = np.asarray(nf.p, dtype=float)
    k20, k30 = float(p0[i2]), float(p0[i3])

    def at(k2: float, k3: float) -> np.ndarray:
        p = p0.copy()
        p[i2], p[i3] = k2, k3
        return p

    g0 = cc.gradient(at(k20, k30), [quadratic, cubic])
    c3 = float(g0[1])
    c22 = float(g0[0] / (2.0 * k20))
    ks2 = np.linspace(grid[0], grid[1], n_grid) * k20
    ks3 = np.linspace(grid[0], grid[1], n_grid) * k30
    K2, K3 = np.meshgrid(ks2, ks3, indexing="ij")
    vals = np.array([[cc(at(u, v)) for v in ks3] for u in ks2])
    grads = np.array([[cc.gradient(at(u, v), [quadratic, cubic]) for v in ks3] for u in ks2])
    X = np.column_stack(
        [
            np.ones(K2.size),
            K2.ravel() / k20,
            K3.ravel() / k30,
            (K2.ravel() / k20) ** 2,
            (K2.ravel() / k20) * (K3.ravel() / k30),
            (K3.ravel() / k30) ** 2,
        ]
    )
    coef, *_ = np.linalg.lstsq(X, vals.ravel(), rcond=None)
    fit = coef / np.array([1.0, k20, k30, k20**2, k20 * k30, k30**2])
    model = c3 * K3 + c22 * K2**2
    scale = float(np.max(np.abs(vals)))
    rel = float(np.max(np.abs(model - vals)) / scale)
    g_model = np.stack([2.0 * c22 * K2, np.full_like(K3, c3)], axis=-1)
    g_err = float(np.max(np.abs(grads - g_model) / np.maximum(np.abs(g_model), 1e-300)))
    names = ["1", "k2", "k3", "k2^2", "k2*k3", "k3^2"]
    return {
        "c3": c3,
        "c22": c22,
        "c3_tau": c3 / nf.omega,
        "c22_tau": c22 / nf.omega,
        "ratio": c22 / c3 if c3 else math.nan,
        "k3_critical": -c22 * k20**2 / c3 if c3 else math.nan,
        "alpha2": cc(p0),
        "fit": dict(zip(names, map(float, fit), strict=True)),
        "fit_relative": dict(zip(names, map(float, coef / scale), strict=True)),
        "max_rel_residual": rel,
        "max_rel_gradient_error": g_err,
    }


def hopf_point_regression(
    param: Sequence[float],
    amplitude: Sequence[float],
    frequency: Sequence[float] | None = None,
) -> dict[str, float]:
    """Flutter (Hopf) speed and frequency from unstable LCOs near the Hopf point (Fig. 4.1).

    Eq. 4.6 gives :math:`A^2 \\propto (\\lambda_H - \\lambda)` near the Hopf point, so a
    straight line fitted to the squared amplitudes crosses zero at :math:`\\lambda_H`; the
    frequency varies linearly with the parameter there, and the line fitted to the
    measured frequencies evaluated at :math:`\\lambda_H` estimates the flutter frequency.

    Parameters
    ----------
    param : sequence of float
        Parameter (wind speed) of each measured unstable LCO.
    amplitude : sequence of float
        Their amplitudes (any one state).
    frequency : sequence of float, optional
        Their frequencies (any unit; the result is in the same unit).

    Returns
    -------
    dict
        ``param`` (the Hopf estimate), ``slope``, ``intercept`` of ``A^2`` vs parameter,
        ``r2`` (coefficient of determination), ``stderr`` of the Hopf estimate (delta
        method), and ``frequency`` / ``frequency_slope`` when frequencies are given.
    """
    U = np.asarray(param, dtype=float)
    A = np.asarray(amplitude, dtype=float)
    if U.shape != A.shape or U.ndim != 1 or U.size < 2:
        raise BifidInputError(
            f"param and amplitude must be 1-D of the same length >= 2, got {U.shape}, {A.shape}."
        )
    if np.ptp(U) == 0:
        raise BifidInputError("the LCOs must be measured at two or more distinct parameter values.")
    y = A**2
    X = np.column_stack([np.ones_like(U), U])
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    b0, b1 = float(coef[0]), float(coef[1])
    if b1 == 0:
        raise BifidInputError("squared amplitudes do not vary with the parameter.")
    Uf = -b0 / b1
    res = y - X @ coef
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    out: dict[str, float] = {
        "param": Uf,
        "slope": b1,
        "intercept": b0,
        "r2": 1.0 - float(res @ res) / ss_tot if ss_tot > 0 else float("nan"),
    }
    if U.size > 2:
        s2 = float(res @ res) / (U.size - 2)
        cov = s2 * np.linalg.inv(X.T @ X)
        grad = np.array([-1.0 / b1, b0 / b1**2])
        out["stderr"] = float(math.sqrt(max(grad @ cov @ grad, 0.0)))
    if frequency is not None:
        F = np.asarray(frequency, dtype=float)
        if F.shape != U.shape:
            raise BifidInputError("frequency must have the same length as param.")
        cf, *_ = np.linalg.lstsq(X, F, rcond=None)
        out["frequency"] = float(cf[0] + cf[1] * Uf)
        out["frequency_slope"] = float(cf[1])
    return out
