r"""Stage 2 of the mechanistic identification: the normal-form fit (thesis §4.2, §4.3.2).

Nonlinear parameters from the amplitudes of measured unstable LCOs near the Hopf point,
through the cubic normal form (:mod:`bifid.identify.normal_form`), eq. 4.6 at leading order:

.. math::

    A_s(\lambda) = 2|q_s|\sqrt{-\alpha_1(\lambda - \lambda_{ref})/\alpha_2(\theta)},

constrained subcritical (:math:`\alpha_2 > 0`). These amplitudes depend on the nonlinear
parameters only through :math:`\alpha_2 = \mathrm{Re}\,c_1`: **one combination** is
identifiable (for the flutter model :math:`c_3 k_{\alpha3} + c_{22} k_{\alpha2}^2`,
eq. 4.10). The amplitudes are linear in :math:`\alpha_2^{-1/2}`, so the least-squares
:math:`\alpha_2^*` is explicit; the parameters are moved onto the manifold
:math:`\alpha_2(\theta) = \alpha_2^*` and polished on the amplitude residuals by
Levenberg–Marquardt steps in log parameters (:func:`~bifid.identify._least_squares.least_squares`),
which move only along the identifiable direction and land on the point of the solution
manifold nearest the start. The singular values of the Jacobian and the identifiable /
unidentifiable directions are reported.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError, ConvergenceError
from bifid.identify._least_squares import LeastSquaresResult, least_squares
from bifid.identify._records import LCOData
from bifid.identify.mechanistic._cubic import (
    cubic_coefficient_fn,
    hopf_point_regression,
    nonlinear_only,
    quadratic_cubic_structure,
)
from bifid.identify.mechanistic._normal_form import HopfNormalForm, hopf_normal_form
from bifid.systems import System

__all__ = ["LogParameters", "NearHopfResult", "fit_near_hopf"]


class LogParameters:
    """Free parameters of a parameter vector, searched as ``φ = log θ`` where ``θ > 0``.

    Parameters
    ----------
    system : System
    p : ndarray
        The full parameter vector (the other entries stay fixed).
    free : sequence of str
    """

    def __init__(self, system: System, p: np.ndarray, free: Sequence[str]) -> None:
        self.p = np.asarray(p, dtype=float).copy()
        self.idx = [system.index(n) for n in free]
        self.log = self.p[self.idx] > 0

    def phi(self, p: np.ndarray | None = None) -> np.ndarray:
        """``φ`` of the free entries of ``p`` (default: the base vector)."""
        v = (self.p if p is None else np.asarray(p))[self.idx]
        return np.where(self.log, np.log(np.where(self.log, v, 1.0)), v)

    def p_of(self, phi: np.ndarray) -> np.ndarray:
        """The full parameter vector at ``φ``."""
        q = self.p.copy()
        q[self.idx] = np.where(self.log, np.exp(phi), phi)
        return q

    def chain(self, p: np.ndarray) -> np.ndarray:
        """``dθ/dφ`` of each free parameter at ``p``."""
        return np.where(self.log, np.asarray(p)[self.idx], 1.0)


@dataclass
class NearHopfResult:
    """Result of :func:`fit_near_hopf`."""

    params: dict[str, float]
    p: np.ndarray
    alpha2: float
    normal_form: HopfNormalForm
    param_ref: float
    output: str
    rms: float
    singular_values: np.ndarray
    identifiable: dict[str, float]
    unidentifiable: dict[str, float]
    statement: str
    lm: LeastSquaresResult
    structure: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "params": self.params,
            "alpha2": self.alpha2,
            "alpha2_tau": self.alpha2 / self.normal_form.omega,
            "param_ref": self.param_ref,
            "output": self.output,
            "rms": self.rms,
            "singular_values": self.singular_values.tolist(),
            "identifiable_direction": self.identifiable,
            "unidentifiable_direction": self.unidentifiable,
            "statement": self.statement,
            "iterations": self.lm.n_iter,
            "structure": self.structure,
        }


def _reference(param_ref: float | str, nf: HopfNormalForm, data: LCOData, output: str) -> float:
    if isinstance(param_ref, str):
        if param_ref == "model":
            return nf.param_value
        if param_ref == "data":
            return float(hopf_point_regression(data.param, data.column(output))["param"])
        raise BifidInputError(f"param_ref must be 'model', 'data' or a number, got {param_ref!r}.")
    return float(param_ref)


def _statement(
    system: System,
    nf: HopfNormalForm,
    free: tuple[str, ...],
    a2: float,
    grad: np.ndarray,
    logm: np.ndarray,
) -> tuple[str, dict[str, Any] | None]:
    terms = " + ".join(
        f"{grad[i]:.4g}·log({n})" if logm[i] else f"{grad[i]:.4g}·{n}" for i, n in enumerate(free)
    )
    statement = (
        f"Near-Hopf LCO amplitudes determine only alpha2 = Re c1 = {a2:.6g} (1/s), i.e. one "
        f"combination of {', '.join(free)}; locally d alpha2 = {terms}. "
    )
    if len(free) == 2:
        try:
            structure = quadratic_cubic_structure(system, nf, free[0], free[1], n_grid=3)
        except (BifidInputError, ConvergenceError):
            structure = None
        if structure is not None and structure["max_rel_residual"] < 1e-8:
            statement += (
                f"alpha2 = c3·{free[1]} + c22·{free[0]}² with c3 = {structure['c3']:.4g}, "
                f"c22 = {structure['c22']:.4g} (tau-time: {structure['c3_tau']:.3g}, "
                f"{structure['c22_tau']:.3g}; eq. 4.10): only c3·{free[1]} + c22·{free[0]}² "
                f"is identifiable, {free[0]} and {free[1]} separately are not."
            )
            return statement, structure
    if len(free) > 1:
        statement += f"The other {len(free) - 1} direction(s) are not identifiable from these data."
    return statement, None


def _fit_alpha2(
    cc: Any, lp: LogParameters, free: tuple[str, ...], wts: np.ndarray, a: np.ndarray, max_iter: int
) -> LeastSquaresResult:
    """Fit the amplitudes ``a ≈ wts / sqrt(alpha2(θ))`` (eq. 4.6) in log parameters.

    They are linear in ``u = alpha2^(-1/2)``, so the least-squares ``alpha2*`` is explicit:
    the parameters are first moved onto ``alpha2(θ) = alpha2*`` (minimum-norm steps; the
    start may even be supercritical), then polished on the amplitude residuals with the
    subcritical constraint ``alpha2 > 0`` as a barrier.
    """

    def gradient(phi: np.ndarray) -> np.ndarray:
        q = lp.p_of(phi)
        return cc.gradient(q, free) * lp.chain(q)

    u = float(wts @ a) / float(wts @ wts)
    if not u > 0:
        raise BifidInputError("the measured amplitudes are all zero; nothing to fit.")
    a2_star = 1.0 / u**2
    onto = least_squares(
        lambda phi: np.array([cc(lp.p_of(phi)) / a2_star - 1.0]),
        lambda phi: gradient(phi)[None, :] / a2_star,
        lp.phi(),
        max_iter=100,
        rtol=1e-13,
        atol=1e-15,
    )
    if abs(onto.fun[0]) > 1e-10:
        raise ConvergenceError(
            f"Could not move {', '.join(free)} to alpha2 = {a2_star:.6g} (the value the "
            "near-Hopf amplitudes require)."
        )

    def residual(phi: np.ndarray) -> np.ndarray | None:
        a2 = cc(lp.p_of(phi))
        if not a2 > 0:  # subcritical constraint (barrier): infeasible point
            return None
        return wts / np.sqrt(a2) - a

    def jacobian(phi: np.ndarray) -> np.ndarray:
        a2 = cc(lp.p_of(phi))
        return (-0.5 * wts / a2**1.5)[:, None] * gradient(phi)[None, :]

    return least_squares(residual, jacobian, onto.x, max_iter=max_iter)


def fit_near_hopf(
    system: System,
    p: np.ndarray,
    free: Sequence[str],
    data: LCOData,
    *,
    output: str | None = None,
    param: str | None = None,
    nf: HopfNormalForm | None = None,
    guess: float | None = None,
    param_ref: float | str = "model",
    max_iter: int = 50,
) -> NearHopfResult:
    """Fit nonlinear parameters to unstable LCO amplitudes near a Hopf point (§4.3.2).

    Model (eq. 4.6, leading order): :math:`A(\\lambda_i) = 2|q_s|\\sqrt{-\\alpha_1
    (\\lambda_i - \\lambda_{ref})/\\alpha_2(\\theta)}`; residuals :math:`A(\\lambda_i) - a_i`.

    Parameters
    ----------
    system : System
    p : array
        Parameter vector (linear parameters already identified; starting values of
        ``free``).
    free : sequence of str
        Nonlinear parameters to fit; they must not change the linearisation at the Hopf
        point (checked).
    data : LCOData
        The LCOs to use (normally the unstable ones near the Hopf point).
    output : str, optional
        Output whose amplitude is fitted (default: the data's first signal).
    param : str, optional
        Bifurcation parameter (default: the data's, else the system's).
    nf : HopfNormalForm, optional
        The normal form at ``p`` (computed if not given, from ``guess``).
    param_ref : "model", "data" or float
        Reference :math:`\\lambda_{ref}`: the model's Hopf point ("model"), the Hopf point
        estimated from the data by the squared-amplitude regression ("data", what the
        thesis does), or a number.

    Returns
    -------
    NearHopfResult
        With the fitted parameters, :math:`\\alpha_2`, the singular values of the
        (log-parameter) Jacobian, the identifiable and unidentifiable directions, and for
        two parameters whose :math:`\\alpha_2` has the form of eq. 4.10 its coefficients.

    Raises
    ------
    BifidInputError
        If a free parameter changes the linearisation, or an LCO lies on the side of the
        Hopf point where the (subcritical) model has no cycles.
    ConvergenceError
        If the fit ends supercritical (the constraint could not be met).
    """
    param = param or (
        data.param_name if data.param_name in system.parameter_names else system.default_param
    )
    output = output or data.signal_names[0]
    p = np.asarray(p, dtype=float)
    if nf is None:
        nf = hopf_normal_form(system, param, p=jnp.asarray(p), guess=guess)
    free = tuple(free)
    if not free:
        raise BifidInputError("free must name at least one nonlinear parameter.")
    if not nonlinear_only(system, nf, free):
        raise BifidInputError(
            f"Some of {free} change the linearisation of {system.name!r} at the Hopf point; the "
            "normal-form stage fits parameters of the nonlinear terms only (identify linear "
            "parameters in the linear stage)."
        )
    lam_ref = _reference(param_ref, nf, data, output)
    a = data.column(output)
    k = 2.0 * abs(nf.q[system.state_index(output)])
    s = -nf.alpha1 * (data.param - lam_ref)  # = alpha2 R^2 > 0 where a subcritical model has cycles
    if np.any(s <= 0):
        raise BifidInputError(
            f"{int(np.sum(s <= 0))} LCO(s) lie on the side of the Hopf point "
            f"({param}={lam_ref:.6g}) where a subcritical model has no cycles; pass only the "
            "unstable LCOs below the flutter speed."
        )
    cc = cubic_coefficient_fn(system, nf)
    lp = LogParameters(system, p, free)
    lm = _fit_alpha2(cc, lp, free, k * np.sqrt(s), a, max_iter)
    p_fit = lp.p_of(lm.x)
    a2 = cc(p_fit)
    if not a2 > 0:
        raise ConvergenceError("The normal-form fit ended supercritical.")
    _, sv, Vt = np.linalg.svd(lm.jac, full_matrices=True)
    sv_full = np.zeros(len(free))
    sv_full[: sv.size] = sv
    ident = Vt[0] * np.sign(Vt[0][np.argmax(np.abs(Vt[0]))])
    null = Vt[-1] if len(free) > 1 else np.zeros(1)
    statement, structure = _statement(
        system, nf, free, a2, cc.gradient(p_fit, free) * lp.chain(p_fit), lp.log
    )
    return NearHopfResult(
        params={n: float(p_fit[i]) for n, i in zip(free, lp.idx, strict=True)},
        p=p_fit,
        alpha2=float(a2),
        normal_form=nf,
        param_ref=float(lam_ref),
        output=output,
        rms=float(np.sqrt(np.mean(lm.fun**2))),
        singular_values=sv_full,
        identifiable=dict(zip(free, map(float, ident), strict=True)),
        unidentifiable=dict(zip(free, map(float, null), strict=True)),
        statement=statement,
        lm=lm,
        structure=structure,
    )
