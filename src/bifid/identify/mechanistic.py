"""Mechanistic identification of a system with a Hopf bifurcation, in three stages (thesis §4.3).

1. **Linear stage** (§4.3.1): the parameters of the linearisation from a free decay by
   prediction-error identification (:class:`~bifid.identify.linear_pem.LinearPEM`).
2. **Normal-form stage** (§4.2, §4.3.2): nonlinear parameters from the amplitudes of
   measured unstable LCOs near the Hopf point, through the cubic normal form
   (:mod:`bifid.identify.normal_form`): :math:`A_s(\\lambda) = 2|q_s|\\sqrt{-\\alpha_1
   (\\lambda-\\lambda_{ref})/\\alpha_2(\\theta)}`, constrained subcritical
   (:math:`\\alpha_2 > 0`). These amplitudes depend on the nonlinear parameters only through
   :math:`\\alpha_2 = \\mathrm{Re}\\,c_1`: **one combination** is identifiable (for
   ``flutter``, :math:`c_3 k_{\\alpha3} + c_{22} k_{\\alpha2}^2`, eq. 4.10). The stage
   therefore takes minimum-norm Levenberg–Marquardt steps (in log parameters) from the
   starting values, which moves only along the identifiable direction and lands on the
   point of the solution manifold nearest the start; the singular values of the Jacobian
   and the identifiable/unidentifiable directions are reported.
3. **Whole-diagram stage** (§4.3.3): all measured LCOs, stable and unstable, matched by
   the periodic orbits of the model computed by Fourier spectral collocation (eq. 4.14,
   the lead's :func:`bifid.continuation.orbit_problem`), cost eq. 4.15
   :math:`c(\\theta) = \\sum_j (\\|v_j^\\theta\\|_h - h_j)^2`. Each measurement
   :math:`(\\lambda_j, h_j)` is matched to an orbit of the branch born at the Hopf point
   (the side of the cycle fold given by its stability label, or the nearer amplitude when
   unknown) and re-solved at fixed :math:`\\lambda_j` by Newton
   (:func:`bifid.continuation.correct`). Exact gradients by implicit differentiation at
   the converged orbit :math:`y_j = (v_j, T_j, \\lambda_j)`:

   .. math::

       \\begin{bmatrix} G_y \\\\ e_\\lambda^T \\end{bmatrix} \\frac{dy_j}{d\\theta}
       = -\\begin{bmatrix} G_\\theta \\\\ 0 \\end{bmatrix},\\qquad
       \\frac{d\\|v_j\\|_h}{d\\theta} = \\mathrm{sign}(v_h(t^*))\\, w(t^*)^T
       \\frac{dv_{j,h}}{d\\theta},

   where :math:`G` is the collocation residual with its phase-condition row, :math:`t^*`
   the time of the maximum of the trigonometric interpolant and :math:`w(t^*)` its
   interpolation weights (the maximum is stationary in :math:`t`, so :math:`t^*` does not
   move to first order). Levenberg–Marquardt steps on the log parameters replace the
   thesis's finite-difference gradient descent (eq. 4.16); a step after which an orbit
   cannot be found (it moved past a fold) or lands on the wrong side of the fold
   (checked by the sign of :math:`d\\lambda/dA` along the branch) is rejected and the
   damping increased.
"""

from __future__ import annotations

import functools
import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bifid.errors import (
    BifidInputError,
    ConvergenceError,
    ConvergenceWarning,
    NotFittedError,
)
from bifid.identify.linear_pem import LinearPEM
from bifid.identify.normal_form import (
    HopfNormalForm,
    cubic_coefficient_fn,
    flutter_speed_regression,
    hopf_normal_form,
    nonlinear_only,
    quadratic_cubic_structure,
)
from bifid.systems import System, get_system

Array = jnp.ndarray
TWO_PI = 2.0 * math.pi

__all__ = [
    "LCOData",
    "LMResult",
    "MechanisticModel",
    "OrbitSet",
    "fit_near_hopf",
    "levenberg_marquardt",
    "plot_diagram",
    "release_index",
    "whole_diagram_update",
]


# ============================================================================ data
@dataclass(frozen=True)
class LCOData:
    """Measured limit cycles: parameter, amplitudes of some outputs, stability labels.

    Attributes
    ----------
    param : ndarray (n,)
        Parameter value of each LCO (e.g. wind speed).
    amplitude : ndarray (n, n_outputs)
        ``max_t |x_s(t)|`` of each output (centred signals).
    stable : ndarray (n,) of int
        1 stable, 0 unstable, -1 unknown.
    outputs : tuple of str
        State names of the amplitude columns.
    frequency : ndarray (n,)
        Angular frequency [rad/s] (NaN when unknown).
    param_name : str
    """

    param: np.ndarray
    amplitude: np.ndarray
    stable: np.ndarray
    outputs: tuple[str, ...]
    frequency: np.ndarray
    param_name: str = "U"

    def __post_init__(self) -> None:
        n = np.asarray(self.param).shape[0]
        amp = np.asarray(self.amplitude, dtype=float).reshape(n, -1)
        object.__setattr__(self, "amplitude", amp)
        object.__setattr__(self, "param", np.asarray(self.param, dtype=float))
        object.__setattr__(self, "stable", np.asarray(self.stable, dtype=int))
        object.__setattr__(self, "frequency", np.asarray(self.frequency, dtype=float))
        if amp.shape[1] != len(self.outputs):
            raise BifidInputError(
                f"amplitude has {amp.shape[1]} columns but outputs names {len(self.outputs)}."
            )
        if self.stable.shape != (n,) or self.frequency.shape != (n,):
            raise BifidInputError("stable and frequency must have one entry per LCO.")
        if n == 0:
            raise BifidInputError("LCOData needs at least one measured LCO.")
        if not (np.all(np.isfinite(self.param)) and np.all(np.isfinite(amp))):
            raise BifidInputError("LCO parameters and amplitudes must be finite.")
        if np.any(amp < 0):
            raise BifidInputError("LCO amplitudes must be >= 0.")
        if not np.all(np.isin(self.stable, (-1, 0, 1))):
            raise BifidInputError("stable labels must be 1 (stable), 0 (unstable) or -1.")

    def __len__(self) -> int:
        return int(self.param.shape[0])

    def select(self, mask: np.ndarray) -> LCOData:
        """The LCOs where ``mask`` is true."""
        m = np.asarray(mask, dtype=bool)
        return LCOData(self.param[m], self.amplitude[m], self.stable[m], self.outputs,
                       self.frequency[m], self.param_name)

    def column(self, output: str) -> np.ndarray:
        """Amplitudes of one output."""
        if output not in self.outputs:
            raise BifidInputError(f"output {output!r} not in the data ({', '.join(self.outputs)}).")
        return self.amplitude[:, self.outputs.index(output)]

    @classmethod
    def from_dataset(
        cls,
        ds: Any,
        outputs: Sequence[str] = ("h",),
        *,
        amplitude: str = "fourier",
        n_harmonics: int = 7,
    ) -> LCOData:
        """Build from a ``"lco"`` dataset (:mod:`bifid.data`).

        Parameters
        ----------
        ds : xarray.Dataset
        outputs : sequence of str
            Signal names to use (e.g. ``("h",)`` as in eq. 4.15, or ``("h", "alpha")``).
        amplitude : {"fourier", "dataset"}
            "dataset": the dataset's ``amplitude`` (raw ``max |x|`` of the centred signal);
            "fourier": ``max |x|`` of a least-squares Fourier series with ``n_harmonics``
            harmonics at a frequency estimated from the record itself
            (:func:`bifid.signal.periodic_amplitude`) — robust to measurement noise, which
            inflates a raw maximum (by up to ~10 % on the unstable rig LCOs).
        """
        from bifid.data import lco_records
        from bifid.signal import estimate_frequency, periodic_amplitude

        if ds.attrs.get("bifid_kind") != "lco":
            raise BifidInputError(
                f"expected an 'lco' dataset, got bifid_kind={ds.attrs.get('bifid_kind')!r}."
            )
        names = [str(s) for s in ds["signal"].values]
        for o in outputs:
            if o not in names:
                raise BifidInputError(f"output {o!r} not among the dataset signals {names}.")
        if amplitude not in ("fourier", "dataset"):
            raise BifidInputError(f"amplitude must be 'fourier' or 'dataset', got {amplitude!r}.")
        recs = list(lco_records(ds))
        cols = [names.index(o) for o in outputs]
        amps, freqs = [], []
        for r in recs:
            if amplitude == "dataset":
                sig = np.asarray(r.signals)
                amps.append([float(np.max(np.abs(sig[:, c] - sig[:, c].mean()))) for c in cols])
                freqs.append(r.frequency)
            else:
                ref = np.asarray(r.signals)[:, cols[0]]
                w = estimate_frequency(ref, r.sample_rate)
                amps.append([periodic_amplitude(np.asarray(r.signals)[:, c], w, r.sample_rate,
                                                n_harmonics, trim=False)[0] for c in cols])
                freqs.append(w)
        stable = [(-1 if r.stable is None else int(bool(r.stable))) for r in recs]
        pname = str(ds["param"].attrs.get("name", ds.attrs.get("param_name", "U")))
        return cls(np.array([r.param for r in recs]), np.array(amps), np.array(stable),
                   tuple(outputs), np.array(freqs, dtype=float), pname)


# ==================================================================== optimiser
@dataclass
class LMResult:
    """Result of :func:`levenberg_marquardt`."""

    x: np.ndarray
    fun: np.ndarray
    jac: np.ndarray
    cost: float
    n_iter: int
    n_fev: int
    n_jev: int
    converged: bool
    message: str
    history: list[dict[str, Any]] = field(default_factory=list)
    p: np.ndarray | None = None
    jac_time_s: float = 0.0  # wall time inside ``jac`` (set by the whole-diagram stage)


def levenberg_marquardt(
    fun: Callable[[np.ndarray], np.ndarray | None],
    jac: Callable[[np.ndarray], np.ndarray],
    x0: np.ndarray,
    *,
    max_iter: int = 50,
    xtol: float = 1e-10,
    gtol: float = 1e-12,
    ftol: float = 1e-14,
    damping: float = 1e-3,
    on_accept: Callable[[np.ndarray], None] | None = None,
) -> LMResult:
    """Levenberg–Marquardt with minimum-norm steps for rank-deficient problems.

    Each step solves :math:`\\min \\|J\\delta + r\\|^2 + \\mu\\|\\delta\\|^2` through the SVD
    :math:`J = U S V^T`: :math:`\\delta = -V\\,\\mathrm{diag}(s/(s^2+\\mu))\\,U^T r`, with
    :math:`\\mu = \\texttt{damping}\\cdot s_{max}^2` adapted (÷3 on success, ×4 on failure).
    Directions the data do not inform (zero singular values) are never moved, so the
    result of a rank-deficient problem is the solution nearest the start.

    ``fun`` may return ``None`` for an infeasible point (e.g. an orbit that no longer
    exists): the step is rejected like a step that increases the cost. ``jac`` is called
    only at accepted points, after ``fun``.
    """
    x = np.asarray(x0, dtype=float).copy()
    r = fun(x)
    if r is None:
        raise ConvergenceError("The starting point of the fit is infeasible (fun returned None).")
    J = jac(x)
    nfev, njev = 1, 1
    cost = 0.5 * float(r @ r)
    history = [{"iter": 0, "cost": cost, "x": x.tolist(), "mu": None, "accepted": True}]
    mu_rel = damping
    message, converged = "maximum number of iterations reached", False
    it = 0
    for it in range(1, max_iter + 1):
        g = J.T @ r
        if np.max(np.abs(g)) <= gtol * max(1.0, cost):
            message, converged = "gradient below gtol", True
            break
        U, s, Vt = np.linalg.svd(J, full_matrices=False)
        smax2 = float(s[0] ** 2) if s.size else 1.0
        accepted = False
        for _ in range(12):
            mu = mu_rel * smax2
            filt = np.where(s > 1e-12 * (s[0] if s.size else 1.0), s / (s**2 + mu), 0.0)
            delta = -(Vt.T * filt) @ (U.T @ r)
            x_new = x + delta
            r_new = fun(x_new)
            nfev += 1
            if r_new is not None and np.all(np.isfinite(r_new)):
                cost_new = 0.5 * float(r_new @ r_new)
                if cost_new < cost:
                    accepted = True
                    break
            mu_rel *= 4.0
        if not accepted:
            message = "no step reduces the cost (local minimum or infeasible neighbourhood)"
            converged = bool(np.max(np.abs(g)) <= 1e-6 * max(1.0, cost))
            break
        dcost = cost - cost_new
        step = float(np.linalg.norm(delta))
        x, r, cost = x_new, r_new, cost_new
        if on_accept is not None:
            on_accept(x)
        J = jac(x)
        njev += 1
        mu_rel = max(mu_rel / 3.0, 1e-12)
        history.append({"iter": it, "cost": cost, "x": x.tolist(), "mu": mu, "accepted": True,
                        "step": step})
        if step <= xtol * (xtol + float(np.linalg.norm(x))):
            message, converged = "step below xtol", True
            break
        if dcost <= ftol * max(cost, 1e-300):
            message, converged = "relative cost reduction below ftol", True
            break
    return LMResult(x=x, fun=r, jac=J, cost=cost, n_iter=it, n_fev=nfev, n_jev=njev,
                    converged=converged, message=message, history=history)


# =========================================================== log-parameter helpers
def _to_phi(values: np.ndarray, logm: np.ndarray) -> np.ndarray:
    return np.where(logm, np.log(np.where(logm, values, 1.0)), values)


def _from_phi(phi: np.ndarray, logm: np.ndarray) -> np.ndarray:
    return np.where(logm, np.exp(phi), phi)


def _log_mask(values: np.ndarray) -> np.ndarray:
    return np.asarray(values) > 0


# ======================================================== stage 2: normal form fit
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
    lm: LMResult
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


def fit_near_hopf(
    system: str | System,
    p: Array,
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
    system : str or System
    p : array
        Parameter vector (linear parameters already identified; starting values of
        ``free``).
    free : sequence of str
        Nonlinear parameters to fit; they must not change the linearisation at the Hopf
        point (checked), e.g. ``("ka2", "ka3")``.
    data : LCOData
        The LCOs to use (normally the unstable ones near the Hopf point).
    output : str, optional
        Output whose amplitude is fitted (default: ``data.outputs[0]``).
    param_ref : "model", "data" or float
        Reference :math:`\\lambda_{ref}`: the model's Hopf point ("model"), the Hopf point
        estimated from the data by the squared-amplitude regression ("data", what the
        thesis does: :math:`\\mu` measured from each one's own flutter speed), or a number.

    Returns
    -------
    NearHopfResult
        With the fitted parameters, the fitted :math:`\\alpha_2`, the singular values of
        the (log-parameter) Jacobian, the identifiable and unidentifiable directions, and
        for ``(ka2, ka3)`` the structure coefficients of eq. 4.10.

    The leading-order amplitudes depend on the parameters only through
    :math:`\alpha_2`, and are linear in :math:`\alpha_2^{-1/2}`: the least-squares
    :math:`\alpha_2^*` is explicit. The parameters are moved onto the manifold
    :math:`\alpha_2(\theta) = \alpha_2^*` by minimum-norm Gauss–Newton steps from the start
    (which may even be supercritical), then polished by :func:`levenberg_marquardt` on the
    amplitude residuals with the subcritical constraint :math:`\alpha_2 > 0` as a barrier.

    Raises
    ------
    BifidInputError
        If a free parameter changes the linearisation, or no LCO lies on the side of the
        Hopf point where the (subcritical) model has cycles.
    ConvergenceError
        If the fit ends supercritical (the constraint could not be met).
    """
    sys_ = get_system(system) if isinstance(system, str) else system
    param = param or data.param_name or sys_.default_param
    output = output or data.outputs[0]
    p = np.asarray(p, dtype=float)
    if nf is None:
        nf = hopf_normal_form(sys_, param, p=jnp.asarray(p), guess=guess)
    free = tuple(free)
    if not free:
        raise BifidInputError("free must name at least one nonlinear parameter.")
    if not nonlinear_only(sys_, nf, free):
        raise BifidInputError(
            f"Some of {free} change the linearisation of {sys_.name!r} at the Hopf point; the "
            "normal-form stage fits parameters of the nonlinear terms only (identify linear "
            "parameters in the linear stage)."
        )
    if isinstance(param_ref, str):
        if param_ref == "model":
            lam_ref = nf.param_value
        elif param_ref == "data":
            reg = flutter_speed_regression(data.param, data.column(output))
            lam_ref = float(reg["param"])
        else:
            raise BifidInputError(
                f"param_ref must be 'model', 'data' or a number, got {param_ref!r}."
            )
    else:
        lam_ref = float(param_ref)
    U = data.param
    a = data.column(output)
    k = 2.0 * abs(nf.q[sys_.state_index(output)])
    s = -nf.alpha1 * (U - lam_ref)  # = alpha2 R^2 ; > 0 where a subcritical model has cycles
    if np.any(s <= 0):
        raise BifidInputError(
            f"{int(np.sum(s <= 0))} LCO(s) lie on the side of the Hopf point "
            f"({param}={lam_ref:.6g}) where a subcritical model has no cycles; pass only the "
            "unstable LCOs below the flutter speed."
        )
    cc = cubic_coefficient_fn(sys_, nf)
    idx = [sys_.index(n) for n in free]
    theta0 = p[idx]
    logm = _log_mask(theta0)

    def p_of(phi):
        q = p.copy()
        q[idx] = _from_phi(phi, logm)
        return q

    def fun(phi):
        a2 = cc(p_of(phi))
        if not a2 > 0:  # subcritical constraint (barrier): infeasible point
            return None
        return k * np.sqrt(s / a2) - a

    def jac(phi):
        pp = p_of(phi)
        a2 = cc(pp)
        g = cc.gradient(pp, free) * np.where(logm, _from_phi(phi, logm), 1.0)
        dA = -0.5 * k * np.sqrt(s / a2) / a2  # dA/d alpha2
        return dA[:, None] * g[None, :]

    # Closed form: A_i = k sqrt(s_i) u with u = alpha2^(-1/2) is linear in u, so the
    # least-squares alpha2 is explicit; move the parameters onto alpha2(theta) = alpha2*
    # by minimum-norm Gauss-Newton steps (this also starts from a supercritical model).
    wts = k * np.sqrt(s)
    u = float(wts @ a) / float(wts @ wts)
    if not u > 0:
        raise BifidInputError("the measured amplitudes are all zero; nothing to fit.")
    a2_star = 1.0 / u**2
    phi0 = _to_phi(theta0, logm)
    for _ in range(100):
        pp = p_of(phi0)
        d = cc(pp) - a2_star
        if abs(d) <= 1e-13 * a2_star:
            break
        g = cc.gradient(pp, free) * np.where(logm, pp[idx], 1.0)
        step = -g * d / float(g @ g)
        # keep log-parameter steps moderate (alpha2 is far from linear in log space)
        phi0 = phi0 + step / max(1.0, float(np.max(np.abs(step))) / 0.5)
    else:
        raise ConvergenceError(
            f"Could not move {', '.join(free)} to alpha2 = {a2_star:.6g} (the value the "
            "near-Hopf amplitudes require)."
        )
    lm = levenberg_marquardt(fun, jac, phi0, max_iter=max_iter)
    p_fit = p_of(lm.x)
    a2 = cc(p_fit)
    if not a2 > 0:
        raise ConvergenceError("The normal-form fit ended supercritical.")
    _, sv, Vt = np.linalg.svd(lm.jac, full_matrices=True)
    sv_full = np.zeros(len(free))
    sv_full[: sv.size] = sv
    ident = Vt[0]
    ident = ident * np.sign(ident[np.argmax(np.abs(ident))])
    null = Vt[-1] if len(free) > 1 else np.zeros(1)
    gl = cc.gradient(p_fit, free) * np.where(logm, p_fit[idx], 1.0)
    terms = " + ".join(f"{gl[i]:.4g}·log({n})" if logm[i] else f"{gl[i]:.4g}·{n}"
                       for i, n in enumerate(free))
    statement = (
        f"Near-Hopf LCO amplitudes determine only alpha2 = Re c1 = {a2:.6g} (1/s), i.e. one "
        f"combination of {', '.join(free)}; locally d alpha2 = {terms}. "
    )
    structure = None
    if set(free) == {"ka2", "ka3"} and sys_.name == "flutter":
        structure = quadratic_cubic_structure(sys_, nf, "ka2", "ka3", n_grid=3)
        statement += (
            f"For flutter alpha2 = c3·ka3 + c22·ka2² with c3 = {structure['c3']:.4g}, "
            f"c22 = {structure['c22']:.4g} (tau-time: {structure['c3_tau']:.3g}, "
            f"{structure['c22_tau']:.3g}; eq. 4.10): only c3·ka3 + c22·ka2² is identifiable, "
            "ka2 and ka3 separately are not."
        )
    elif len(free) > 1:
        statement += f"The other {len(free) - 1} direction(s) are not identifiable from these data."
    rms = float(np.sqrt(np.mean(lm.fun**2)))
    return NearHopfResult(
        params={n: float(p_fit[i]) for n, i in zip(free, idx, strict=True)},
        p=p_fit, alpha2=float(a2), normal_form=nf, param_ref=float(lam_ref), output=output,
        rms=rms, singular_values=sv_full,
        identifiable=dict(zip(free, map(float, ident), strict=True)),
        unidentifiable=dict(zip(free, map(float, null), strict=True)), statement=statement, lm=lm,
        structure=structure,
    )


# ================================================== stage 3: collocation orbits
def _interp_weights(M: int, t: float) -> np.ndarray:
    """Trigonometric-interpolation weights ``w_j(t)`` on the grid ``t_j = 2 pi j / M`` (M even).

    ``x(t) = sum_j w_j(t) x_j`` with
    ``w_j = (1/M) [1 + 2 sum_{k=1}^{M/2-1} cos k(t - t_j) + cos (M/2)(t - t_j)]``.
    """
    tj = TWO_PI * np.arange(M) / M
    d = t - tj
    k = np.arange(1, M // 2)
    return (1.0 + 2.0 * np.cos(np.outer(d, k)).sum(axis=1) + np.cos(M / 2 * d)) / M


def _max_abs_with_weights(v: np.ndarray) -> tuple[float, np.ndarray]:
    """``max_t |x(t)|`` of the trigonometric interpolant of ``v`` and ``d max / d v``.

    The maximiser ``t*`` is found on a 16× finer grid and refined by Newton on the
    derivative; by stationarity, ``d max/d v = sign(x(t*)) w(t*)``.
    """
    v = np.asarray(v, dtype=float)
    M = v.shape[0]
    c = np.fft.rfft(v) / M
    fine = np.fft.irfft(np.fft.rfft(v), n=16 * M) * 16
    i = int(np.argmax(np.abs(fine)))
    t = TWO_PI * i / (16 * M)
    k = np.arange(c.shape[0])
    ck = c.copy()
    ck[1:] *= 2.0
    if M % 2 == 0:
        ck[-1] /= 2.0
    for _ in range(10):
        e = np.exp(1j * k * t)
        d1 = float(np.real(np.sum(1j * k * ck * e)))
        d2 = float(np.real(np.sum(-(k**2) * ck * e)))
        if d2 == 0.0:
            break
        step = float(np.clip(d1 / d2, -np.pi / M, np.pi / M))
        t -= step
        if abs(step) < 1e-14:
            break
    w = _interp_weights(M, t)
    val = float(w @ v)
    return abs(val), math.copysign(1.0, val) * w


@functools.lru_cache(maxsize=16)
def _param_jacobian(problem: Any) -> Callable:
    """Jitted ``dG/dp`` of a lead collocation problem (residual differentiated in ``args['p']``)."""

    def gp(y, args):
        return jax.jacfwd(lambda pp: problem.residual(y, {**args, "p": pp}))(args["p"])

    return jax.jit(gp)


@functools.lru_cache(maxsize=16)
def _full_jacobian(problem: Any) -> Callable:
    return jax.jit(problem.jacobian) if problem.jacobian is not None else jax.jit(
        jax.jacfwd(problem.residual))


@dataclass
class OrbitSet:
    """Collocation orbits of a model at the parameters of measured LCOs (fixed ``lambda_j``).

    Solves, differentiates and keeps the orbits warm between parameter updates.

    Parameters
    ----------
    system : System
    param : str
    n_mesh : int
    outputs : tuple of str
    """

    system: System
    param: str
    n_mesh: int
    outputs: tuple[str, ...]
    ys: np.ndarray | None = None  # (n_meas, M*n + 2): V, T, lambda
    sides: np.ndarray | None = None  # +1 stable side (dlambda/dA > 0), -1 Hopf side
    p_ys: np.ndarray | None = None  # parameter vector the orbits ``ys`` solve (if known)

    def __post_init__(self) -> None:
        from bifid.continuation import orbit_problem

        self.problem = orbit_problem(self.system.field, self.n_mesh, self.system.n_states)
        from bifid.continuation import fourier_differentiation_matrix

        self._D = fourier_differentiation_matrix(self.n_mesh)
        self._idx = self.system.index(self.param)
        self._out = [self.system.state_index(o) for o in self.outputs]

    # ---------------------------------------------------------------- initial match
    def match(self, branch: Any, data: LCOData, p: np.ndarray, *,
              skip_missing: bool = False) -> np.ndarray:
        """Initial orbits for each measurement from a continued branch (``hopf_orbits``).

        On a subcritical branch (unstable cycles born at the Hopf point, turning at a
        cycle fold) a measurement labelled unstable is matched between the Hopf point and
        the first cycle fold, a stable one beyond that fold — the thesis's arclength
        ordering; this holds even where a poor start model has other stability changes
        (e.g. a period doubling on the upper branch). Otherwise a label is matched to a
        segment whose end points have that Floquet stability. If several segments
        qualify, the first in arclength order wins. An unknown label takes the orbit of
        nearest amplitude. The guess is the
        linear interpolation of the two bracketing branch points, corrected at the
        measured parameter; the side of the cycle fold (sign of ``d lambda / d A``) found
        there is then kept through every later update.

        Returns
        -------
        ndarray of int
            Indices of the measurements that were matched (all of them unless
            ``skip_missing``); the orbits are stored in that order.

        Raises
        ------
        ConvergenceError
            If a measurement has no orbit of the right kind at its parameter (unless
            ``skip_missing``), or none has.
        """
        M, n = self.n_mesh, self.system.n_states
        params = np.asarray(branch.params)
        sols = np.asarray(branch.solutions)
        stab = np.asarray(branch.stable, dtype=bool)
        amps = np.asarray(branch.data.get("amplitude_centred", branch.data["amplitude"])
                          )[:, self._out[0]]
        folds_i = sorted(sp.index for sp in branch.special_points if sp.kind == "cycle_fold")
        hopf_start = branch.meta.get("start_kind") == "hopf"
        fold_i = folds_i[0] if (folds_i and hopf_start and not stab[1]) else None
        ys, matched = [], []
        for j in range(len(data)):
            lam = data.param[j]
            label = int(data.stable[j])
            cands = []
            for i in range(len(params) - 1):
                a, b = params[i], params[i + 1]
                if (a - lam) * (b - lam) <= 0 and a != b:
                    s = (lam - a) / (b - a)
                    amp = (1 - s) * amps[i] + s * amps[i + 1]
                    cands.append((i, s, amp))
            if label in (0, 1) and fold_i is not None:
                # subcritical branch: unstable between the Hopf point and the first cycle
                # fold, stable beyond it (arclength order, as in the thesis)
                cands = [c for c in cands if (c[0] < fold_i) == (label == 0)]
            elif label in (0, 1):
                cands = [c for c in cands
                         if stab[c[0]] == bool(label) and stab[c[0] + 1] == bool(label)]
            else:
                target = data.amplitude[j, 0]
                cands.sort(key=lambda c: abs(c[2] - target))
            if not cands and skip_missing:
                continue
            if not cands:
                kind = {0: "unstable", 1: "stable"}.get(label, "any")
                folds = [f"{sp.param:.6g}" for sp in branch.special_points
                         if sp.kind == "cycle_fold"]
                raise ConvergenceError(
                    f"The model has no {kind} periodic orbit at {self.param}={lam:.6g} (its "
                    f"branch spans {params.min():.6g}..{params.max():.6g}, cycle folds at "
                    f"{', '.join(folds) or 'none'}); start from parameters whose diagram "
                    "contains the measured LCOs."
                )
            i, s, _ = cands[0]
            guess = (1 - s) * sols[i] + s * sols[i + 1]
            ys.append(np.concatenate([guess[: M * n + 1], [lam]]))
            matched.append(j)
        if not ys:
            raise ConvergenceError(
                f"The model has none of the measured periodic orbits (its branch spans "
                f"{params.min():.6g}..{params.max():.6g})."
            )
        self.ys = np.array(ys)
        self.sides = None
        bp = getattr(branch, "p", None)
        self.p_ys = None if bp is None else np.asarray(bp, dtype=float).copy()
        new = self.solve(p)
        if new is None:
            raise ConvergenceError(
                "Could not converge the model orbits at the measured parameters from the "
                "continued branch (increase n_mesh or check the data)."
            )
        self.ys = new
        self.p_ys = np.asarray(p, dtype=float).copy()
        self.sides = np.array([self._side(y, p) for y in new])
        return np.asarray(matched, dtype=int)

    # ------------------------------------------------------------------- solving
    def _args(self, p: np.ndarray, y: np.ndarray) -> dict[str, Any]:
        M, n = self.n_mesh, self.system.n_states
        V = y[: M * n].reshape(M, n)
        return {"p": jnp.asarray(p), "idx": jnp.asarray(self._idx),
                "dref": jnp.asarray((self._D @ V).ravel())}

    def solve(self, p: np.ndarray, *, tol: float = 1e-11,
              max_substeps: int = 8) -> np.ndarray | None:
        """Re-solve every orbit at its fixed parameter from the current ones (warm start).

        If Newton fails from the current orbit and the parameters ``p_ys`` of the current
        orbits are known, the orbit is followed along the straight path from ``p_ys`` to
        ``p`` in 2, 4, ... ``max_substeps`` steps (a natural-parameter homotopy in the
        model parameters; the measured ``lambda_j`` stays fixed).

        Returns the new orbits (not stored), or None if an orbit fails to converge or has
        moved to the other side of a cycle fold.
        """
        assert self.ys is not None
        p = np.asarray(p, dtype=float)
        new = np.empty_like(self.ys)
        for j, y0 in enumerate(self.ys):
            y = self._correct(y0, p, tol)
            n_sub = 2
            while y is None and self.p_ys is not None and n_sub <= max_substeps:
                y = y0
                for k in range(1, n_sub + 1):
                    y = self._correct(y, self.p_ys + (p - self.p_ys) * (k / n_sub), tol)
                    if y is None:
                        break
                n_sub *= 2
            if y is None:
                return None
            if self.sides is not None and self._side(y, p) != self.sides[j]:
                return None
            new[j] = y
        return new

    def _correct(self, y0: np.ndarray, p: np.ndarray, tol: float) -> np.ndarray | None:
        """Newton correction of one orbit at fixed ``lambda`` (None if it fails)."""
        from bifid.continuation import correct

        row = np.zeros(y0.shape[0])
        row[-1] = 1.0
        y, ok, _, _ = correct(self.problem, y0, row, float(y0[-1]), self._args(p, y0), tol=tol,
                              max_iter=15)
        if not ok or not np.all(np.isfinite(y)):
            return None
        return np.asarray(y)

    def _side(self, y: np.ndarray, p: np.ndarray) -> int:
        """Sign of ``d lambda / d A`` along the branch at ``y`` (A: first output's amplitude).

        The tangent ``t`` spans the null space of the (N, N+1) collocation Jacobian;
        oriented so that the amplitude grows, its parameter component is negative between
        the Hopf point and a subcritical cycle fold and positive beyond the fold.
        """
        M, n = self.n_mesh, self.system.n_states
        Jf = np.asarray(_full_jacobian(self.problem)(jnp.asarray(y), self._args(p, y)))
        # null vector of the (N, N+1) Jacobian: [J; r^T] t = e_last with a fixed generic r
        r = np.random.default_rng(12345).standard_normal(Jf.shape[1])
        t = np.linalg.solve(np.vstack([Jf, r[None, :]]), np.eye(Jf.shape[1])[-1])
        _, dA = _max_abs_with_weights(y[: M * n].reshape(M, n)[:, self._out[0]])
        growth = float(dA @ t[: M * n].reshape(M, n)[:, self._out[0]])
        return int(np.sign(t[-1] * np.sign(growth))) or 1

    def amplitudes(self, ys: np.ndarray | None = None) -> np.ndarray:
        """``max_t |v_s(t) - mean(v_s)|`` of each output at each orbit, (n_meas, n_outputs).

        Centred like the measured signals (a rig's offsets are removed, and the LCOs of a
        model with even nonlinearities, e.g. ``k_a2``, are not symmetric about the
        equilibrium: without centring the fit is biased by the orbit's mean shift).
        """
        ys = self.ys if ys is None else ys
        assert ys is not None
        M, n = self.n_mesh, self.system.n_states
        out = np.empty((ys.shape[0], len(self._out)))
        for j, y in enumerate(ys):
            V = y[: M * n].reshape(M, n)
            for c, s in enumerate(self._out):
                out[j, c] = _max_abs_with_weights(V[:, s] - V[:, s].mean())[0]
        return out

    def amplitude_jacobian(self, p: np.ndarray, names: Sequence[str]) -> np.ndarray:
        """Exact ``d amplitude / d p_name`` by implicit differentiation, (n_meas, n_out, n_names).

        ``[G_y; e_lambda^T] dy/dp = -[G_p; 0]`` at each converged orbit (the phase-condition
        row is part of ``G``), then the envelope-theorem derivative of the maximum.
        """
        assert self.ys is not None
        M, n = self.n_mesh, self.system.n_states
        cols = [self.system.index(nm) for nm in names]
        jf = _full_jacobian(self.problem)
        gp = _param_jacobian(self.problem)
        out = np.empty((self.ys.shape[0], len(self._out), len(cols)))
        for j, y in enumerate(self.ys):
            args = self._args(p, y)
            A = np.asarray(jf(jnp.asarray(y), args))
            e = np.zeros((1, A.shape[1]))
            e[0, -1] = 1.0
            A = np.vstack([A, e])
            Gp = np.asarray(gp(jnp.asarray(y), args))[:, cols]
            rhs = -np.vstack([Gp, np.zeros((1, len(cols)))])
            dy = np.linalg.solve(A, rhs)
            V = y[: M * n].reshape(M, n)
            dV = dy[: M * n].reshape(M, n, len(cols))
            for c, s in enumerate(self._out):
                _, w = _max_abs_with_weights(V[:, s] - V[:, s].mean())
                out[j, c] = w @ (dV[:, s, :] - dV[:, s, :].mean(axis=0))
        return out


@dataclass
class WholeDiagramResult:
    """Result of :func:`whole_diagram_update`."""

    params: dict[str, float]
    p: np.ndarray
    amplitudes: np.ndarray
    residuals: np.ndarray
    rms: float
    rms_start: float
    lm: LMResult
    gradient: str
    time_s: float
    orbits: OrbitSet
    singular_values: np.ndarray
    jac_time_s: float = 0.0
    n_jev: int = 0
    branch_time_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        return {
            "params": self.params,
            "rms": self.rms,
            "rms_start": self.rms_start,
            "iterations": self.lm.n_iter,
            "function_evaluations": self.lm.n_fev,
            "jacobian_evaluations": self.lm.n_jev,
            "converged": self.lm.converged,
            "message": self.lm.message,
            "gradient": self.gradient,
            "time_s": self.time_s,
            "jacobian_time_s": self.jac_time_s,
            "jacobian_evaluations_total": self.n_jev,
            "branch_time_s": self.branch_time_s,
            "singular_values": self.singular_values.tolist(),
            "cost_history": [h["cost"] for h in self.lm.history],
        }


def whole_diagram_update(
    system: str | System,
    p: Array,
    free: Sequence[str],
    data: LCOData,
    *,
    param: str | None = None,
    outputs: Sequence[str] | None = None,
    n_mesh: int = 32,
    branch: Any = None,
    gradient: str = "implicit",
    fd_step: float = 1e-6,
    max_iter: int = 40,
    xtol: float = 1e-10,
    hopf_guess: float | None = None,
    schedule: str = "arclength",
) -> WholeDiagramResult:
    """Update parameters so that the model's LCO branch matches all measured LCOs (§4.3.3).

    Parameters
    ----------
    system : str or System
    p : array
        Parameter vector (start).
    free : sequence of str
        Parameters to update (e.g. ``("ka2", "ka3")``); searched in log space if positive.
    data : LCOData
        Measured LCOs with stability labels (1/0, or -1 unknown).
    outputs : sequence of str, optional
        Outputs in the cost (default ``data.outputs``; eq. 4.15 uses heave). Residuals are
        divided by each output's largest measured amplitude so units can be mixed.
    n_mesh : int
        Collocation points per orbit.
    branch : Branch, optional
        A periodic-orbit branch (``hopf_orbits``) for the initial matching, of the model at
        ``p`` or of a nearby model (its orbits are then followed from ``branch.p`` to
        ``p``, see :meth:`OrbitSet.solve`); used for the first step of the schedule,
        computed if not given.
    gradient : {"implicit", "fd"}
        Exact implicit-differentiation Jacobian, or forward finite differences (each
        column re-solves every orbit) — the baseline the thesis used.
    fd_step : float
        Step of the finite differences in log-parameter units.
    schedule : {"arclength", "all"}
        "all": one Levenberg–Marquardt run on every LCO. "arclength" (default): a homotopy
        in the data — fit first the unstable LCOs nearest the Hopf point (their amplitudes
        depend on the parameters almost only through the normal-form coefficient
        ``alpha2``, so the minimum-norm steps fix that combination first), then all
        unstable LCOs, then everything; the branch is recomputed and the orbits
        re-matched between steps. The cost of eq. 4.15 over the whole diagram has
        spurious local minima where the cycle fold jumps between the two folds of an
        S-shaped branch; the schedule keeps the iterates in the basin of the data.

    Returns
    -------
    WholeDiagramResult
    """
    sys_ = get_system(system) if isinstance(system, str) else system
    param = param or data.param_name or sys_.default_param
    outputs = tuple(outputs or data.outputs)
    if gradient not in ("implicit", "fd"):
        raise BifidInputError(f"gradient must be 'implicit' or 'fd', got {gradient!r}.")
    if schedule not in ("arclength", "all"):
        raise BifidInputError(f"schedule must be 'arclength' or 'all', got {schedule!r}.")
    for o in outputs:
        data.column(o)
    free = tuple(free)
    if not free:
        raise BifidInputError("free must name at least one parameter.")
    p = np.asarray(p, dtype=float).copy()
    t_start = time.perf_counter()
    meas_all = np.column_stack([data.column(o) for o in outputs])
    scale = np.max(meas_all, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    groups = _schedule(data, hopf_guess) if schedule == "arclength" else [np.arange(len(data))]
    history: list[dict[str, Any]] = []
    rms_start = None
    lm = orbits = None
    nf_init = None
    jac_time, n_jev, branch_time = 0.0, 0, 0.0
    if schedule == "arclength":
        p, nf_init = _normal_form_start(sys_, p, free, data, param, outputs[0], hopf_guess,
                                        n_mesh)
        if nf_init is not None:
            branch = None
    for g, members in enumerate(groups):
        sub = data.select(np.isin(np.arange(len(data)), members))
        for attempt in range(4):
            if branch is None or g > 0 or attempt > 0:
                tb = time.perf_counter()
                branch = model_branch(sys_, p, param, n_mesh=n_mesh, guess=hopf_guess,
                                      param_range=_default_range(data))
                branch_time += time.perf_counter() - tb
            hopf_guess = float(branch.meta.get("start_param",
                                               hopf_guess or p[sys_.index(param)]))
            orbits = OrbitSet(sys_, param, n_mesh, outputs)
            matched = orbits.match(branch, sub, p, skip_missing=schedule == "arclength")
            sub_m = sub.select(np.isin(np.arange(len(sub)), matched))
            if rms_start is None and len(sub_m) == len(data):
                rms_start = float(np.sqrt(np.mean((orbits.amplitudes() - meas_all) ** 2)))
            lm = _fit_orbits(orbits, sys_, p, free, sub_m, outputs, scale, gradient, fd_step,
                             max_iter, xtol)
            jac_time += lm.jac_time_s
            n_jev += lm.n_jev
            for h in lm.history:
                history.append({**h, "group": g, "n_lcos": len(sub_m)})
            p = lm.p
            if len(matched) == len(sub):
                break
        else:
            if g < len(groups) - 1:
                continue  # an intermediate step of the homotopy: go on with what matched
            raise ConvergenceError(
                f"After {attempt + 1} attempts the model still lacks {len(sub) - len(matched)} "
                f"of the measured LCOs at {param} = "
                f"{np.setdiff1d(sub.param, sub_m.param).tolist()}; the diagram cannot be "
                "matched from this start."
            )
    assert lm is not None and orbits is not None
    if rms_start is None:
        rms_start = float("nan")
    lm.history = history
    if nf_init is not None:
        lm.history.insert(0, {"iter": 0, "group": -1, "normal_form_start": nf_init})
    amps = orbits.amplitudes()
    res = amps - meas_all
    sv = np.linalg.svd(lm.jac, compute_uv=False)
    if not lm.converged:
        warnings.warn(f"whole-diagram update did not converge: {lm.message}", ConvergenceWarning,
                      stacklevel=2)
    idx = [sys_.index(nm) for nm in free]
    return WholeDiagramResult(
        params={nm: float(p[i]) for nm, i in zip(free, idx, strict=True)}, p=p,
        amplitudes=amps, residuals=res, rms=float(np.sqrt(np.mean(res**2))), rms_start=rms_start,
        lm=lm, gradient=gradient, time_s=time.perf_counter() - t_start, orbits=orbits,
        singular_values=sv, jac_time_s=jac_time, n_jev=n_jev, branch_time_s=branch_time,
    )


def _normal_form_start(sys_: System, p: np.ndarray, free: tuple[str, ...], data: LCOData,
                       param: str, output: str, hopf_guess: float | None, n_mesh: int
                       ) -> tuple[np.ndarray, dict[str, Any] | None]:
    """Start of the data homotopy when the model cannot hold the measured unstable LCOs.

    If the model is supercritical, or its unstable branch does not reach the unstable LCO
    nearest the Hopf point, the free parameters (if they leave the linearisation fixed)
    are first moved by the normal-form fit (:func:`fit_near_hopf`) so that ``alpha2``
    matches the unstable LCOs. Returns the (possibly) updated parameters and a summary
    (None when nothing was done).
    """
    unstable = data.stable == 0
    if not np.any(unstable):
        return p, None
    try:
        nf = hopf_normal_form(sys_, param, p=jnp.asarray(p), guess=hopf_guess)
    except ConvergenceError:
        return p, None
    if not nonlinear_only(sys_, nf, free):
        return p, None
    sel = unstable & (data.param < nf.param_value) if nf.alpha1 > 0 else unstable
    if not np.any(sel):
        return p, None
    nearest = float(data.param[sel][np.argmin(np.abs(data.param[sel] - nf.param_value))])
    if nf.alpha2 > 0:
        # subcritical: does the unstable branch reach the nearest unstable LCO?
        try:
            br = model_branch(sys_, p, param, n_mesh=n_mesh, guess=nf.param_value,
                              param_range=(min(nearest, nf.param_value) - 1e-9,
                                           max(nearest, nf.param_value) + 1e-9),
                              max_steps=200)
        except ConvergenceError:
            br = None
        if br is not None and not br.special("cycle_fold"):
            return p, None
    res = fit_near_hopf(sys_, p, free, data.select(sel), output=output, param=param, nf=nf)
    return res.p, {"params": res.params, "alpha2": res.alpha2, "reason":
                   "supercritical start" if nf.alpha2 <= 0 else "unstable branch too short"}


def _schedule(data: LCOData, hopf: float | None) -> list[np.ndarray]:
    """Groups of LCO indices for the data homotopy (arclength order from the Hopf point)."""
    unstable = np.flatnonzero(data.stable == 0)
    if hopf is None:
        hopf = float(np.max(data.param))
    order_u = unstable[np.argsort(np.abs(data.param[unstable] - hopf))]
    n_u = order_u.size
    sizes = sorted({max(1, math.ceil(n_u / 2)), n_u}) if n_u else []
    groups = [order_u[:k] for k in sizes if k > 0]
    everything = np.arange(len(data))
    # LCOs at the lowest measured parameter sit next to the fold and exist only once the
    # fold is in place: fit the others first (the stable ones pull the fold), then all
    labelled = np.flatnonzero(data.stable >= 0)
    if labelled.size > 2 and n_u:
        near_fold = labelled[data.param[labelled] <= np.min(data.param[labelled]) + 1e-9]
        groups = [np.setdiff1d(g, near_fold) for g in groups]
        groups = [g for g in groups if g.size]
        pre = np.setdiff1d(everything, near_fold)
        if not groups or pre.size > groups[-1].size:
            groups.append(pre)
    if not groups or groups[-1].size < len(data):
        groups.append(everything)
    return groups


def _fit_orbits(orbits: OrbitSet, sys_: System, p: np.ndarray, free: tuple[str, ...],
                data: LCOData, outputs: tuple[str, ...], scale: np.ndarray, gradient: str,
                fd_step: float, max_iter: int, xtol: float) -> LMResult:
    """Levenberg–Marquardt on the matched orbits of ``data`` (one step of the schedule)."""
    idx = [sys_.index(nm) for nm in free]
    meas = np.column_stack([data.column(o) for o in outputs])
    theta0 = p[idx]
    logm = _log_mask(theta0)

    def p_of(phi):
        q = p.copy()
        q[idx] = _from_phi(phi, logm)
        return q

    trial: dict[str, Any] = {}

    def resid(ys):
        return ((orbits.amplitudes(ys) - meas) / scale).ravel()

    def fun(phi):
        # solve from the accepted orbits; commit only if the optimiser accepts the step
        ys = orbits.solve(p_of(phi))
        if ys is None:
            return None
        trial["phi"], trial["ys"] = phi.copy(), ys
        return resid(ys)

    def on_accept(phi):
        assert np.array_equal(trial["phi"], phi)
        orbits.ys = trial["ys"]
        orbits.p_ys = p_of(phi)

    def jac_implicit(phi):
        pp = p_of(phi)
        Jp = orbits.amplitude_jacobian(pp, free)  # (n_meas, n_out, n_free)
        Jp = Jp / scale[None, :, None]
        return Jp.reshape(-1, len(free)) * np.where(logm, pp[idx], 1.0)[None, :]

    def jac_fd(phi):
        # forward differences in log parameters; each column re-solves every orbit
        r0 = resid(orbits.ys)
        cols = []
        for k in range(len(free)):
            ph = phi.copy()
            ph[k] += fd_step
            ys = orbits.solve(p_of(ph))
            if ys is not None:
                cols.append((resid(ys) - r0) / fd_step)
                continue
            ph[k] -= 2 * fd_step
            ys = orbits.solve(p_of(ph))
            if ys is None:
                raise ConvergenceError("a finite-difference step lost an orbit; reduce fd_step.")
            cols.append(-(resid(ys) - r0) / fd_step)
        return np.column_stack(cols)

    phi0 = _to_phi(theta0, logm)
    r0 = resid(orbits.ys)

    def fun0(phi):
        if np.array_equal(phi, phi0):
            trial["phi"], trial["ys"] = phi.copy(), orbits.ys.copy()
            return r0
        return fun(phi)

    jac_fn = jac_implicit if gradient == "implicit" else jac_fd
    jac_time = [0.0]

    def timed_jac(phi):
        t = time.perf_counter()
        try:
            return jac_fn(phi)
        finally:
            jac_time[0] += time.perf_counter() - t

    lm = levenberg_marquardt(fun0, timed_jac, phi0, max_iter=max_iter, xtol=xtol,
                             on_accept=on_accept)
    lm.p = p_of(lm.x)
    lm.jac_time_s = jac_time[0]
    return lm


def _default_range(data: LCOData) -> tuple[float, float]:
    lo, hi = float(np.min(data.param)), float(np.max(data.param))
    span = max(hi - lo, 1e-3 * max(abs(hi), 1.0))
    # generous below: a start model may fold well below the measured range
    return lo - 3.0 * span, hi + 0.5 * span


def model_branch(
    system: System,
    p: np.ndarray,
    param: str,
    *,
    n_mesh: int = 32,
    guess: float | None = None,
    param_range: tuple[float, float] = (-math.inf, math.inf),
    max_steps: int = 400,
) -> Any:
    """The model's periodic-orbit branch from its Hopf point (lead's ``hopf_orbits``).

    The Hopf point is located by :func:`bifid.continuation.locate_hopf` from ``guess``
    (default: the current parameter value), so no equilibrium continuation is needed.
    """
    from bifid.continuation import ContinuationOptions, hopf_orbits, locate_hopf

    idx = system.index(param)
    lam0 = float(p[idx]) if guess is None else float(guess)
    sp = locate_hopf(system, param, np.zeros(system.n_states), lam0, jnp.asarray(p))
    lo, hi = param_range
    lo = min(lo, sp.param - 1e-6)
    hi = max(hi, sp.param + 1e-6)
    opts = ContinuationOptions(ds=1e-3, ds_max=0.25, ds_min=1e-9, p_min=lo, p_max=hi,
                               max_steps=max_steps)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return hopf_orbits(system, sp, p=jnp.asarray(p), n_mesh=n_mesh, options=opts)


# ============================================================================ model
class MechanisticModel:
    """Three-stage identification of a physical model with a Hopf bifurcation (thesis ch. 4).

    Parameters
    ----------
    system : str
        Registered system (``"flutter"``).
    free : sequence of str
        Nonlinear parameters of stages 2 and 3 (``("ka2", "ka3")``).
    param : str, optional
        Bifurcation parameter (default: the system's, ``U``).
    params : mapping, optional
        Values of the other parameters, and starting values of the free ones.
    outputs : sequence of str
        Outputs whose amplitudes are fitted (default ``("h",)``, eq. 4.15).
    stages : sequence of {"linear", "normal_form", "whole_diagram"}
        Stages to run, in this order. "linear" needs a free decay in :meth:`fit`.
    linear_free : sequence of str
        Parameters of the linear stage (``("Ia", "ca", "ch")``, as for system 1).
    linear_ratios : mapping, optional
        Tied parameters of the linear stage, e.g. ``{"ka": "Ia"}`` (measured ``omega_alpha``).
    linear_options : mapping, optional
        Extra keyword arguments of :class:`LinearPEM` (``decimate``, ``horizons``...).
    linear_param_value : float
        The bifurcation parameter during the free decay (0: no wind).
    param_ref : {"model", "data"} or float
        Reference of ``mu`` in the normal-form stage (see :func:`fit_near_hopf`).
    near_hopf : float, optional
        Use only unstable LCOs within this distance of the Hopf point in stage 2
        (default: all unstable LCOs).
    n_mesh : int
        Collocation points of stage 3 and of predictions.
    gradient : {"implicit", "fd"}
        Jacobian of stage 3.
    max_iter : int
        Iterations of stages 2 and 3.
    hopf_guess : float, optional
        Where to start looking for the Hopf point (default: the largest measured parameter).
    decay_start : "release" or float
        Start of the free decay used by the linear stage: "release" (the latest of the
        outputs' largest excursions, :func:`release_index`: before it the rig is still
        being excited) or a time in seconds.
    decay_stop : float, optional
        End of the free decay used [s] (default: the end of the record).
    """

    def __init__(
        self,
        system: str = "flutter",
        free: Sequence[str] = ("ka2", "ka3"),
        *,
        param: str | None = None,
        params: Mapping[str, float] | None = None,
        outputs: Sequence[str] = ("h",),
        stages: Sequence[str] = ("linear", "normal_form", "whole_diagram"),
        linear_free: Sequence[str] = ("Ia", "ca", "ch"),
        linear_ratios: Mapping[str, str] | None = None,
        linear_options: Mapping[str, Any] | None = None,
        linear_param_value: float = 0.0,
        param_ref: str | float = "model",
        near_hopf: float | None = None,
        n_mesh: int = 32,
        gradient: str = "implicit",
        max_iter: int = 40,
        hopf_guess: float | None = None,
        decay_start: str | float = "release",
        decay_stop: float | None = None,
    ) -> None:
        self.system = system
        self.free = tuple(free)
        self.param = param
        self.params = dict(params or {})
        self.outputs = tuple(outputs)
        self.stages = tuple(stages)
        self.linear_free = tuple(linear_free)
        self.linear_ratios = dict(linear_ratios or {})
        self.linear_options = dict(linear_options or {})
        self.linear_param_value = linear_param_value
        self.param_ref = param_ref
        self.near_hopf = near_hopf
        self.n_mesh = n_mesh
        self.gradient = gradient
        self.max_iter = max_iter
        self.hopf_guess = hopf_guess
        self.decay_start = decay_start
        self.decay_stop = decay_stop

    # -------------------------------------------------------------- helpers
    def get_params(self) -> dict[str, Any]:
        """Hyperparameters (JSON-able)."""
        return {
            "system": self.system, "free": list(self.free), "param": self.param,
            "params": dict(self.params), "outputs": list(self.outputs),
            "stages": list(self.stages), "linear_free": list(self.linear_free),
            "linear_ratios": dict(self.linear_ratios), "linear_options": dict(self.linear_options),
            "linear_param_value": self.linear_param_value, "param_ref": self.param_ref,
            "near_hopf": self.near_hopf, "n_mesh": self.n_mesh, "gradient": self.gradient,
            "max_iter": self.max_iter, "hopf_guess": self.hopf_guess,
            "decay_start": self.decay_start, "decay_stop": self.decay_stop,
        }

    def _validate(self) -> System:
        sys_ = get_system(self.system)
        for nm in self.free:
            sys_.index(nm)
        for o in self.outputs:
            sys_.state_index(o)
        unknown = set(self.stages) - {"linear", "normal_form", "whole_diagram"}
        if unknown or not self.stages:
            raise BifidInputError(
                f"stages must be a non-empty subset of linear, normal_form, whole_diagram; got "
                f"{list(self.stages)}."
            )
        if self.gradient not in ("implicit", "fd"):
            raise BifidInputError(f"gradient must be 'implicit' or 'fd', got {self.gradient!r}.")
        if not (isinstance(self.n_mesh, int) and self.n_mesh >= 8 and self.n_mesh % 2 == 0):
            raise BifidInputError(f"n_mesh must be an even integer >= 8, got {self.n_mesh!r}.")
        return sys_

    def _check_fitted(self) -> None:
        if not hasattr(self, "p_"):
            raise NotFittedError("This MechanisticModel is not fitted yet; call fit(data) first.")

    # ------------------------------------------------------------------ fit
    def fit(
        self,
        data: LCOData | Any,
        free_decay: tuple[np.ndarray, float] | Any | None = None,
    ) -> MechanisticModel:
        """Run the configured stages.

        Parameters
        ----------
        data : LCOData or xarray.Dataset
            Measured LCOs (a ``"lco"`` dataset is converted with
            :meth:`LCOData.from_dataset` for ``outputs``).
        free_decay : (y, sample_rate) or FreeDecay, optional
            Free-decay record for the linear stage: ``y`` of shape (n, 2) with columns
            heave, pitch (the outputs of the linear model ``("h", "alpha")`` for flutter),
            or a :class:`bifid.data.FreeDecay`.

        Returns
        -------
        self
            ``p_`` (full parameter vector), ``params_`` (identified values by name),
            ``stages_`` (per-stage summaries with the RMS amplitude error over all LCOs),
            ``hopf_`` (Hopf point of the final model), ``data_flutter_`` (squared-amplitude
            regression of the measured unstable LCOs), ``identifiability_``.
        """
        sys_ = self._validate()
        if not isinstance(data, LCOData):
            data = LCOData.from_dataset(data, self.outputs)
        for o in self.outputs:
            data.column(o)
        param = self.param or data.param_name or sys_.default_param
        sys_.index(param)
        p = np.array(sys_.param_vector(self.params), dtype=float)
        self.stages_: dict[str, Any] = {}
        self.params_: dict[str, float] = {}
        self.stage_p_: dict[str, np.ndarray] = {}
        diag_cache: dict[bytes, dict[str, Any]] = {}  # one branch per parameter vector
        hopf_guess = self.hopf_guess if self.hopf_guess is not None else float(np.max(data.param))
        out0 = self.outputs[0]
        unstable = data.stable == 0
        if np.sum(unstable) >= 2:
            reg = flutter_speed_regression(data.param[unstable], data.column(out0)[unstable],
                                           data.frequency[unstable])
            self.data_flutter_ = {**reg, "output": out0,
                                  "frequency_hz": reg.get("frequency", float("nan")) / TWO_PI}
        else:
            self.data_flutter_ = {}

        # -------- stage 1: linear
        if "linear" in self.stages:
            if free_decay is None:
                raise BifidInputError("the linear stage needs a free decay (free_decay=...).")
            y, fs = _free_decay_arrays(free_decay)
            if self.decay_start == "release":
                i0 = release_index(y)
            else:
                i0 = round(float(self.decay_start) * fs)
            i1 = y.shape[0] if self.decay_stop is None else round(self.decay_stop * fs)
            if not 0 <= i0 < i1 - 20:
                raise BifidInputError(
                    f"the free-decay window [{i0 / fs:g}, {i1 / fs:g}] s is empty or too short."
                )
            y = y[i0:i1]
            start = {**{k: float(v) for k, v in sys_.param_dict(p).items()},
                     param: self.linear_param_value}
            opts = {"decimate": 10, **self.linear_options}
            pem = LinearPEM(sys_, self.linear_free, ("h", "alpha") if sys_.name == "flutter"
                            else self.linear_options.get("outputs", self.outputs),
                            params=start, ratios=self.linear_ratios,
                            **{k: v for k, v in opts.items() if k != "outputs"})
            pem.fit(y, fs)
            for nm in (*self.linear_free, *self.linear_ratios):
                p[sys_.index(nm)] = pem.p_[sys_.index(nm)]
            self.linear_ = pem
            self.params_.update({nm: float(p[sys_.index(nm)]) for nm in self.linear_free})
            self.stages_["linear"] = {"parameters": dict(pem.params_), "stderr": pem.stderr_,
                                      "window_s": [i0 / fs, i1 / fs],
                                      "tied": pem.tied_, "fit_percent": pem.fit_percent_,
                                      "rmse": pem.rmse_, "modes": pem.modal_summary()}
            self.stage_p_["linear"] = p.copy()
        nf = hopf_normal_form(sys_, param, p=jnp.asarray(p), guess=hopf_guess)
        hopf_guess = nf.param_value
        if "linear" in self.stages:
            self.stages_["linear"].update(
                self._diagram_error(sys_, p, param, data, hopf_guess, diag_cache))
            self.stages_["linear"]["hopf"] = _hopf_summary(nf)

        # -------- stage 2: normal form
        if "normal_form" in self.stages:
            sel = unstable & (data.param < nf.param_value)
            if self.near_hopf is not None:
                sel &= np.abs(data.param - nf.param_value) <= self.near_hopf
            if np.sum(sel) < 1:
                raise BifidInputError(
                    "the normal-form stage needs unstable LCOs (stable = 0) below the Hopf point "
                    f"{param}={nf.param_value:.6g}."
                )
            res2 = fit_near_hopf(sys_, p, self.free, data.select(sel), output=out0, param=param,
                                 nf=nf, param_ref=self.param_ref, max_iter=self.max_iter)
            p = res2.p.copy()
            self.stage_p_["normal_form"] = p.copy()
            self.identifiability_ = {
                "statement": res2.statement,
                "identifiable_direction": res2.identifiable,
                "unidentifiable_direction": res2.unidentifiable,
                "singular_values": res2.singular_values.tolist(),
            }
            self.stages_["normal_form"] = {**res2.to_dict(), "n_lcos": int(np.sum(sel))}
            self.stages_["normal_form"].update(
                self._diagram_error(sys_, p, param, data, hopf_guess, diag_cache))
            self.near_hopf_ = res2

        # -------- stage 3: whole diagram
        if "whole_diagram" in self.stages:
            res3 = whole_diagram_update(sys_, p, self.free, data, param=param,
                                        outputs=self.outputs, n_mesh=self.n_mesh,
                                        gradient=self.gradient, max_iter=self.max_iter,
                                        hopf_guess=hopf_guess)
            p = res3.p.copy()
            self.stage_p_["whole_diagram"] = p.copy()
            self.stages_["whole_diagram"] = {**res3.to_dict(), "rms_all": res3.rms,
                                             "n_matched": len(data), "n_lcos": len(data),
                                             "predicted_amplitudes": res3.amplitudes[:, 0].tolist()}
            self.whole_diagram_ = res3
        self.params_.update({nm: float(p[sys_.index(nm)]) for nm in self.free})
        self.p_ = p
        nf = hopf_normal_form(sys_, param, p=jnp.asarray(p), guess=hopf_guess)
        self.normal_form_ = nf
        self.hopf_ = _hopf_summary(nf)
        final = self._diagram_error(sys_, p, param, data, nf.param_value, diag_cache)
        self.cycle_fold_ = final.get("cycle_fold")
        last = self.stages[-1]
        if last != "whole_diagram":
            self.stages_.setdefault(last, {}).update(
                {k: v for k, v in final.items() if k not in self.stages_.get(last, {})})
        self.stages_[last]["cycle_fold"] = self.cycle_fold_
        self.param_ = param
        self.data_ = data
        self.n_features_in_ = len(self.outputs)
        return self

    def _diagram_error(self, sys_: System, p: np.ndarray, param: str, data: LCOData,
                       hopf_guess: float, cache: dict[bytes, dict[str, Any]] | None = None
                       ) -> dict[str, Any]:
        """RMS amplitude error of the model's diagram at the measured LCOs (fixed parameters).

        LCOs the model has no orbit for (e.g. a stable LCO below the model's cycle fold)
        are listed in ``missing`` and left out of ``rms_all`` (``n_matched`` says how many
        entered it).
        """
        key = np.asarray(p, dtype=float).tobytes()
        if cache is not None and key in cache:
            return dict(cache[key])
        out = self._diagram_error_uncached(sys_, p, param, data, hopf_guess)
        if cache is not None:
            cache[key] = dict(out)
        return out

    def _diagram_error_uncached(self, sys_: System, p: np.ndarray, param: str, data: LCOData,
                                hopf_guess: float) -> dict[str, Any]:
        br = model_branch(sys_, p, param, n_mesh=self.n_mesh, guess=hopf_guess,
                          param_range=_default_range(data))
        folds = [sp.param for sp in br.special_points if sp.kind == "cycle_fold"]
        orbits = OrbitSet(sys_, param, self.n_mesh, self.outputs)
        try:
            matched = orbits.match(br, data, p, skip_missing=True)
        except ConvergenceError as exc:
            return {"rms_all": None, "n_matched": 0, "diagram_error": str(exc),
                    "cycle_fold": folds[0] if folds else None}
        amps = orbits.amplitudes()
        meas = np.column_stack([data.column(o) for o in self.outputs])[matched]
        missing = np.setdiff1d(np.arange(len(data)), matched)
        pred = np.full(len(data), np.nan)
        pred[matched] = amps[:, 0]
        return {"rms_all": float(np.sqrt(np.mean((amps - meas) ** 2))),
                "n_matched": len(matched),
                "missing": [{"param": float(data.param[i]), "stable": int(data.stable[i])}
                            for i in missing],
                "predicted_amplitudes": [None if np.isnan(v) else float(v) for v in pred],
                "cycle_fold": folds[0] if folds else None}

    # -------------------------------------------------------------- predict
    def predict_diagram(
        self, lo: float, hi: float, *, n_mesh: int | None = None, max_steps: int = 600
    ) -> tuple[Any, list[Any]]:
        """Equilibria over ``[lo, hi]`` and the LCO branches of the fitted model
        (:func:`bifid.continuation.continue_from_hopf`)."""
        self._check_fitted()
        from bifid.continuation import ContinuationOptions, continue_from_hopf

        sys_ = get_system(self.system)
        lo, hi = sorted((float(lo), float(hi)))
        opts = ContinuationOptions(ds=1e-3, ds_max=0.25, ds_min=1e-9, p_min=lo, p_max=hi,
                                   max_steps=max_steps)
        return continue_from_hopf(sys_, self.param_, lo, hi, p=jnp.asarray(self.p_),
                                  n_mesh=n_mesh or max(self.n_mesh, 32), orbit_options=opts)

    def predict_amplitudes(self, param: Sequence[float], stable: Sequence[int]) -> np.ndarray:
        """Model amplitudes (outputs) at given parameters on the given side of the fold."""
        self._check_fitted()
        sys_ = get_system(self.system)
        lam = np.asarray(param, dtype=float)
        data = LCOData(lam, np.zeros((lam.size, len(self.outputs))), np.asarray(stable),
                       self.outputs, np.full(lam.size, np.nan), self.param_)
        br = model_branch(sys_, self.p_, self.param_, n_mesh=self.n_mesh,
                          guess=self.hopf_["param"], param_range=_default_range(data))
        orbits = OrbitSet(sys_, self.param_, self.n_mesh, self.outputs)
        orbits.match(br, data, self.p_)
        return orbits.amplitudes()

    # ------------------------------------------------------------------- io
    def summary(self) -> dict[str, Any]:
        """JSON-able result."""
        self._check_fitted()
        return {
            "parameters": self.params_,
            "hopf": self.hopf_,
            "data_flutter": self.data_flutter_,
            "stages": self.stages_,
            "identifiability": getattr(self, "identifiability_", None),
            "cycle_fold": getattr(self, "cycle_fold_", None),
            "losses": {k: v.get("rms_all") for k, v in self.stages_.items()},
        }

    def save(self, directory: str | Path) -> Path:
        """Save as ``model.json`` + ``arrays.npz`` (:func:`bifid.io.save_model`)."""
        self._check_fitted()
        from bifid.io import save_model

        sys_ = get_system(self.system)
        d = self.data_
        return save_model(
            directory, "mechanistic",
            {**self.summary(), "param": self.param_,
             "all_parameters": sys_.param_dict(self.p_)},
            {"p": self.p_, "data_param": d.param, "data_amplitude": d.amplitude,
             "data_stable": d.stable, "data_frequency": d.frequency,
             **{f"p_stage_{k}": v for k, v in getattr(self, "stage_p_", {}).items()}},
            self.get_params(),
        )

    @classmethod
    def load(cls, directory: str | Path) -> MechanisticModel:
        """Load a model saved by :meth:`save`."""
        from bifid.io import load_model

        meta, arrays = load_model(directory)
        if meta.get("type") != "mechanistic":
            raise BifidInputError(
                f"{directory} holds a {meta.get('type')!r} model, not a 'mechanistic' one."
            )
        settings = dict(meta.get("settings", {}))
        model = cls(**settings)
        pr = meta["params"]
        model.p_ = np.asarray(arrays["p"], dtype=float)
        model.params_ = dict(pr["parameters"])
        model.hopf_ = pr["hopf"]
        model.data_flutter_ = pr.get("data_flutter", {})
        model.stages_ = pr.get("stages", {})
        if pr.get("identifiability") is not None:
            model.identifiability_ = pr["identifiability"]
        model.param_ = pr["param"]
        model.cycle_fold_ = pr.get("cycle_fold")
        model.data_ = LCOData(arrays["data_param"], arrays["data_amplitude"],
                              arrays["data_stable"], tuple(model.outputs),
                              arrays["data_frequency"], model.param_)
        model.stage_p_ = {k[len("p_stage_"):]: np.asarray(v, dtype=float)
                          for k, v in arrays.items() if k.startswith("p_stage_")}
        model.n_features_in_ = len(model.outputs)
        return model


def _hopf_summary(nf: HopfNormalForm) -> dict[str, Any]:
    return {"param": nf.param_value, "omega": nf.omega, "frequency_hz": nf.omega / TWO_PI,
            "lyapunov": nf.l1, "criticality": nf.criticality, "alpha1": nf.alpha1,
            "alpha2": nf.alpha2}


def _free_decay_arrays(fd: Any) -> tuple[np.ndarray, float]:
    if isinstance(fd, tuple) and len(fd) == 2:
        y, fs = fd
        return np.asarray(y, dtype=float), float(fs)
    if hasattr(fd, "heave") and hasattr(fd, "pitch"):
        y = np.column_stack([fd.heave, fd.pitch])
        return y, float(fd.sample_rate)
    raise BifidInputError(
        "free_decay must be (y, sample_rate) with y of shape (n, 2) [heave, pitch], or a "
        "bifid.data.FreeDecay."
    )


def release_index(y: np.ndarray) -> int:
    """Sample at which a free decay is released: the latest of the outputs' largest excursions.

    After release a free decay can only lose energy, so the largest excursion of each output
    comes after the excitation ends; starting the fit at the latest of them drops the part
    of the record where the rig was still being excited.
    """
    y = np.asarray(y, dtype=float)
    if y.ndim == 1:
        y = y[:, None]
    rest = np.median(y[-max(1, y.shape[0] // 4):], axis=0)
    return int(max(int(np.argmax(np.abs(y[:, c] - rest[c]))) for c in range(y.shape[1])))


def plot_diagram(
    branches: Sequence[Any],
    data: LCOData | None,
    path: str | Path,
    *,
    output: str = "h",
    title: str = "",
    label: str = "model",
    others: Sequence[Mapping[str, Any]] = (),
    scale: float = 1.0,
    unit: str = "m",
) -> Path:
    """Bifurcation diagram of LCO branches with measured LCOs (PNG/SVG, matplotlib Agg).

    Parameters
    ----------
    branches : sequence of Branch
        Periodic-orbit branches (solid where stable, dashed where unstable).
    data : LCOData, optional
        Measured LCOs: filled markers stable, open markers unstable.
    path : str or Path
        Output file (written atomically).
    output : str
        State whose amplitude is shown.
    others : sequence of mappings
        Extra curves: ``{"param": ..., "amplitude": ..., "label": ..., "style": "--"}``
        (e.g. other stages or the thesis's curves).
    scale, unit : float, str
        Amplitudes are multiplied by ``scale`` and labelled with ``unit``.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bifid.io import atomic_path

    fig, ax = plt.subplots(figsize=(7.5, 4.8), constrained_layout=True)
    first = True
    for br in branches:
        states = list(br.meta.get("states", []))
        col = states.index(output) if output in states else 0
        x = np.asarray(br.params)
        # centred like the measured signals (see OrbitSet.amplitudes)
        y = np.asarray(br.data.get("amplitude_centred", br.data["amplitude"]))[:, col] * scale
        st = np.asarray(br.stable, dtype=bool)
        for mask, ls in ((st, "-"), (~st, "--")):
            # extend each segment by one point so the curve is continuous
            edge = np.zeros_like(mask)
            edge[:-1] |= mask[1:] & ~mask[:-1]
            edge[1:] |= mask[:-1] & ~mask[1:]
            yy = np.where(mask | edge, y, np.nan)
            ax.plot(x, yy, ls, color="C0", lw=2,
                    label=(f"{label} (stable / unstable)" if first and ls == "-" else None))
        first = False
    for k, o in enumerate(others):
        ax.plot(np.asarray(o["param"]), np.asarray(o["amplitude"]) * scale,
                o.get("style", "-"), color=o.get("color", f"C{k + 2}"), lw=1.5,
                label=o.get("label"))
    if data is not None:
        a = data.column(output) * scale
        s = data.stable == 1
        u = data.stable == 0
        ax.plot(data.param[s], a[s], "o", color="k", ms=7, label="measured stable LCO")
        ax.plot(data.param[u], a[u], "o", mfc="white", mec="k", ms=7,
                label="measured unstable LCO")
    ax.set_xlabel(data.param_name if data is not None else "parameter")
    ax.set_ylabel(f"{output} amplitude max|x| [{unit}]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=120, format=path.suffix.lstrip(".") or "png")
    plt.close(fig)
    return path
