r"""Stage 3 of the mechanistic identification: the whole-diagram update (thesis §4.3.3).

All measured LCOs, stable and unstable, are matched by the periodic orbits of the model
(:class:`~bifid.identify.mechanistic._orbits.OrbitSet`) with the cost of eq. 4.15,
:math:`c(\theta) = \sum_j (\|v_j^\theta\|_h - h_j)^2`. Levenberg–Marquardt steps on the log
parameters with the exact implicit Jacobian (:func:`~bifid.identify._least_squares.least_squares`)
replace the thesis's finite-difference gradient descent (eq. 4.16); a step after which an
orbit cannot be found (it moved past a fold) or lands on the wrong side of the fold is
rejected by the trust region.

The cost over the whole diagram has spurious local minima where the cycle fold jumps
between the two folds of an S-shaped branch; a homotopy in the data keeps the iterates in
the basin of the data: the unstable LCOs nearest the Hopf point first (their amplitudes
depend on the parameters almost only through the normal-form coefficient), then all
unstable LCOs, then everything, the branch recomputed and the orbits re-matched between
steps.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.continuation import Branch
from bifid.continuation._blas import one_blas_thread
from bifid.errors import BifidInputError, ConvergenceError, ConvergenceWarning
from bifid.identify._least_squares import LeastSquaresResult, least_squares
from bifid.identify._records import LCOData
from bifid.identify.mechanistic._branch import (
    INTERNAL_STABILITY,
    data_range,
    model_branch,
)
from bifid.identify.mechanistic._cubic import nonlinear_only
from bifid.identify.mechanistic._near_hopf import LogParameters, fit_near_hopf
from bifid.identify.mechanistic._normal_form import hopf_normal_form
from bifid.identify.mechanistic._orbits import OrbitSet
from bifid.systems import System

__all__ = ["WholeDiagramResult", "whole_diagram_update"]


@dataclass
class WholeDiagramResult:
    """Result of :func:`whole_diagram_update`."""

    params: dict[str, float]
    p: np.ndarray
    amplitudes: np.ndarray
    residuals: np.ndarray
    rms: float
    rms_start: float
    lm: LeastSquaresResult
    gradient: str
    time_s: float
    orbits: OrbitSet
    singular_values: np.ndarray
    jac_time_s: float = 0.0
    n_jev: int = 0
    branch_time_s: float = 0.0
    history: list[dict[str, Any]] | None = None

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
            "cost_history": [h["cost"] for h in self.history or [] if "cost" in h],
        }


class _OrbitResiduals:
    """Residuals and Jacobians of one step of the schedule (matched orbits of ``data``).

    Every evaluation solves the orbits from those of the nearest feasible earlier
    evaluation (warm start), so the result does not depend on which trial steps the
    solver accepted.
    """

    def __init__(
        self,
        orbits: OrbitSet,
        lp: LogParameters,
        free: tuple[str, ...],
        meas: np.ndarray,
        scale: np.ndarray,
        gradient: str,
        fd_step: float,
    ) -> None:
        self.orbits, self.lp, self.free = orbits, lp, free
        self.meas, self.scale = meas, scale
        self.gradient, self.fd_step = gradient, fd_step
        assert orbits.ys is not None
        self.solved: list[tuple[np.ndarray, np.ndarray]] = [(lp.phi(), orbits.ys.copy())]
        self.jac_time = 0.0

    def _resid(self, ys: np.ndarray) -> np.ndarray:
        return ((self.orbits.amplitudes(ys) - self.meas) / self.scale).ravel()

    def solve(self, phi: np.ndarray) -> np.ndarray | None:
        """Orbits at ``φ`` (None when infeasible), from the nearest solved ``φ``."""
        near_phi, near_ys = min(self.solved, key=lambda s: float(np.sum((s[0] - phi) ** 2)))
        if np.array_equal(near_phi, phi):
            return near_ys
        ys = self.orbits.solve(self.lp.p_of(phi), start=near_ys, p_start=self.lp.p_of(near_phi))
        if ys is not None:
            self.solved.append((phi.copy(), ys))
        return ys

    def residual(self, phi: np.ndarray) -> np.ndarray | None:
        ys = self.solve(phi)
        return None if ys is None else self._resid(ys)

    def jacobian(self, phi: np.ndarray) -> np.ndarray:
        t0 = time.perf_counter()
        try:
            ys = self.solve(phi)
            if ys is None:
                return np.full((self.meas.size, len(self.free)), np.nan)
            if self.gradient == "implicit":
                return self._implicit(phi, ys)
            return self._finite_differences(phi, ys)
        finally:
            self.jac_time += time.perf_counter() - t0

    def _implicit(self, phi: np.ndarray, ys: np.ndarray) -> np.ndarray:
        p = self.lp.p_of(phi)
        self.orbits.ys, self.orbits.p_ys = ys, p
        jp = self.orbits.amplitude_jacobian(p, self.free) / self.scale[None, :, None]
        return jp.reshape(-1, len(self.free)) * self.lp.chain(p)[None, :]

    def _finite_differences(self, phi: np.ndarray, ys: np.ndarray) -> np.ndarray:
        """Forward differences in log parameters; each column re-solves every orbit."""
        r0 = self._resid(ys)
        p = self.lp.p_of(phi)
        cols = []
        for k in range(len(self.free)):
            for sign in (1.0, -1.0):
                ph = phi.copy()
                ph[k] += sign * self.fd_step
                yk = self.orbits.solve(self.lp.p_of(ph), start=ys, p_start=p)
                if yk is not None:
                    cols.append(sign * (self._resid(yk) - r0) / self.fd_step)
                    break
            else:
                raise ConvergenceError("a finite-difference step lost an orbit; reduce fd_step.")
        return np.column_stack(cols)

    def commit(self, phi: np.ndarray) -> None:
        """Keep the orbits of ``φ`` in the orbit set."""
        ys = self.solve(phi)
        assert ys is not None
        self.orbits.ys, self.orbits.p_ys = ys, self.lp.p_of(phi)


def _fit_orbits(
    orbits: OrbitSet,
    system: System,
    p: np.ndarray,
    free: tuple[str, ...],
    data: LCOData,
    outputs: tuple[str, ...],
    scale: np.ndarray,
    gradient: str,
    fd_step: float,
    max_iter: int,
    xtol: float,
) -> tuple[LeastSquaresResult, np.ndarray, float]:
    """Levenberg–Marquardt on the matched orbits of ``data`` (one step of the schedule).

    Returns the solver's result, the fitted parameter vector and the Jacobian time.
    """
    meas = np.column_stack([data.column(o) for o in outputs])
    lp = LogParameters(system, p, free)
    problem = _OrbitResiduals(orbits, lp, free, meas, scale, gradient, fd_step)
    lm = least_squares(
        problem.residual, problem.jacobian, lp.phi(), max_iter=max_iter, rtol=xtol, atol=1e-14
    )
    problem.commit(lm.x)
    return lm, lp.p_of(lm.x), problem.jac_time


def _normal_form_start(
    system: System,
    p: np.ndarray,
    free: tuple[str, ...],
    data: LCOData,
    param: str,
    output: str,
    hopf_guess: float | None,
    n_mesh: int,
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
        nf = hopf_normal_form(system, param, p=jnp.asarray(p), guess=hopf_guess)
    except ConvergenceError:
        return p, None
    if not nonlinear_only(system, nf, free):
        return p, None
    sel = unstable & (data.param < nf.param_value) if nf.alpha1 > 0 else unstable
    if not np.any(sel):
        return p, None
    nearest = float(data.param[sel][np.argmin(np.abs(data.param[sel] - nf.param_value))])
    if nf.alpha2 > 0:
        # subcritical: does the unstable branch reach the nearest unstable LCO?
        try:
            br = model_branch(
                system,
                p,
                param,
                n_mesh=n_mesh,
                guess=nf.param_value,
                param_range=(
                    min(nearest, nf.param_value) - 1e-9,
                    max(nearest, nf.param_value) + 1e-9,
                ),
                max_steps=200,
                stability=INTERNAL_STABILITY,
            )
        except ConvergenceError:
            br = None
        if br is not None and not br.special("cycle_fold"):
            return p, None
    res = fit_near_hopf(system, p, free, data.select(sel), output=output, param=param, nf=nf)
    return res.p, {
        "params": res.params,
        "alpha2": res.alpha2,
        "reason": "supercritical start" if nf.alpha2 <= 0 else "unstable branch too short",
    }


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


class _Homotopy:
    """The data homotopy of :func:`whole_diagram_update`: one Levenberg–Marquardt run per
    group of LCOs, the branch recomputed and the orbits re-matched before each."""

    def __init__(
        self,
        system: System,
        param: str,
        free: tuple[str, ...],
        data: LCOData,
        outputs: tuple[str, ...],
        n_mesh: int,
        gradient: str,
        fd_step: float,
        max_iter: int,
        xtol: float,
        history: list[dict[str, Any]],
    ) -> None:
        self.system, self.param, self.free, self.data = system, param, free, data
        self.outputs, self.n_mesh, self.gradient, self.fd_step = outputs, n_mesh, gradient, fd_step
        self.max_iter, self.xtol, self.history = max_iter, xtol, history
        meas = np.column_stack([data.column(o) for o in outputs])
        self.meas = meas
        self.scale = np.where(np.max(meas, axis=0) > 0, np.max(meas, axis=0), 1.0)
        self.lm: LeastSquaresResult | None = None
        self.orbits: OrbitSet | None = None
        self.rms_start: float | None = None
        self.jac_time, self.n_jev, self.branch_time = 0.0, 0, 0.0

    def follow(
        self,
        groups: list[np.ndarray],
        p: np.ndarray,
        branch: Branch | None,
        hopf_guess: float | None,
        skip_missing: bool,
    ) -> np.ndarray:
        """Fit every group in turn from ``p``; returns the final parameters.

        Raises
        ------
        ConvergenceError
            If the last group cannot be matched after four attempts.
        """
        data, system, param = self.data, self.system, self.param
        for g, members in enumerate(groups):
            sub = data.select(np.isin(np.arange(len(data)), members))
            for attempt in range(4):
                if branch is None or g > 0 or attempt > 0:
                    tb = time.perf_counter()
                    branch = model_branch(
                        system,
                        p,
                        param,
                        n_mesh=self.n_mesh,
                        guess=hopf_guess,
                        param_range=data_range(data.param),
                        stability=INTERNAL_STABILITY,
                    )
                    self.branch_time += time.perf_counter() - tb
                hopf_guess = float(
                    branch.meta.get("start_param", hopf_guess or p[system.index(param)])
                )
                orbits = OrbitSet(system, param, self.n_mesh, self.outputs)
                matched = orbits.match(branch, sub, p, skip_missing=skip_missing)
                sub_m = sub.select(matched)
                if self.rms_start is None and len(sub_m) == len(data):
                    self.rms_start = float(np.sqrt(np.mean((orbits.amplitudes() - self.meas) ** 2)))
                lm, p, jt = _fit_orbits(
                    orbits,
                    system,
                    p,
                    self.free,
                    sub_m,
                    self.outputs,
                    self.scale,
                    self.gradient,
                    self.fd_step,
                    self.max_iter,
                    self.xtol,
                )
                self.lm, self.orbits = lm, orbits
                self.jac_time += jt
                self.n_jev += lm.n_jev
                self.history += [{**h, "group": g, "n_lcos": len(sub_m)} for h in lm.history]
                if len(matched) == len(sub):
                    break
            else:
                if g < len(groups) - 1:
                    continue  # an intermediate step of the homotopy: go on with what matched
                raise ConvergenceError(
                    f"After {attempt + 1} attempts the model still lacks "
                    f"{len(sub) - len(matched)} of the measured LCOs at {param} = "
                    f"{np.setdiff1d(sub.param, sub_m.param).tolist()}; the diagram cannot be "
                    "matched from this start."
                )
        return p


@one_blas_thread
def whole_diagram_update(
    system: System,
    p: np.ndarray,
    free: Sequence[str],
    data: LCOData,
    *,
    param: str | None = None,
    outputs: Sequence[str] | None = None,
    n_mesh: int = 32,
    branch: Branch | None = None,
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
    system : System
    p : array
        Parameter vector (start).
    free : sequence of str
        Parameters to update; searched in log space if positive.
    data : LCOData
        Measured LCOs with stability labels (1/0, or -1 unknown).
    param : str, optional
        Bifurcation parameter (default: the data's, else the system's).
    outputs : sequence of str, optional
        Outputs in the cost (default: the data's signals; eq. 4.15 uses heave). Residuals
        are divided by each output's largest measured amplitude so units can be mixed.
    n_mesh : int
        Collocation points per orbit.
    branch : Branch, optional
        A periodic-orbit branch (``hopf_orbits``) for the initial matching, of the model at
        ``p`` or of a nearby model (its orbits are then followed from ``branch.p`` to
        ``p``); used for the first step of the schedule, computed if not given.
    gradient : {"implicit", "fd"}
        Exact implicit-differentiation Jacobian, or forward finite differences (each
        column re-solves every orbit) — the baseline the thesis used.
    fd_step : float
        Step of the finite differences in log-parameter units.
    max_iter, xtol : int, float
        Step budget and tolerance of each Levenberg–Marquardt run.
    hopf_guess : float, optional
        Where to look for the model's Hopf point.
    schedule : {"arclength", "all"}
        "all": one Levenberg–Marquardt run on every LCO; "arclength" (default): the data
        homotopy of the module docstring.

    Returns
    -------
    WholeDiagramResult

    Raises
    ------
    BifidInputError
        Bad options or names.
    ConvergenceError
        If the model's diagram cannot be matched to the data from this start.
    """
    param = param or (
        data.param_name if data.param_name in system.parameter_names else system.default_param
    )
    outputs = tuple(outputs or data.signal_names)
    if gradient not in ("implicit", "fd"):
        raise BifidInputError(f"gradient must be 'implicit' or 'fd', got {gradient!r}.")
    if schedule not in ("arclength", "all"):
        raise BifidInputError(f"schedule must be 'arclength' or 'all', got {schedule!r}.")
    free = tuple(free)
    if not free:
        raise BifidInputError("free must name at least one parameter.")
    p = np.asarray(p, dtype=float).copy()
    t_start = time.perf_counter()
    meas_all = np.column_stack([data.column(o) for o in outputs])
    groups = _schedule(data, hopf_guess) if schedule == "arclength" else [np.arange(len(data))]
    history: list[dict[str, Any]] = []
    if schedule == "arclength":
        p, nf_init = _normal_form_start(
            system, p, free, data, param, outputs[0], hopf_guess, n_mesh
        )
        if nf_init is not None:
            branch = None
            history.append({"iter": 0, "group": -1, "normal_form_start": nf_init})
    run = _Homotopy(
        system, param, free, data, outputs, n_mesh, gradient, fd_step, max_iter, xtol, history
    )
    p = run.follow(groups, p, branch, hopf_guess, skip_missing=schedule == "arclength")
    lm, orbits, rms_start = run.lm, run.orbits, run.rms_start
    jac_time, n_jev, branch_time = run.jac_time, run.n_jev, run.branch_time
    assert lm is not None and orbits is not None
    amps = orbits.amplitudes()
    res = amps - meas_all
    if not lm.converged:
        warnings.warn(  # stacklevel 3: the caller, past the one_blas_thread wrapper
            f"whole-diagram update did not converge: {lm.message}", ConvergenceWarning, stacklevel=3
        )
    return WholeDiagramResult(
        params={nm: float(p[system.index(nm)]) for nm in free},
        p=p,
        amplitudes=amps,
        residuals=res,
        rms=float(np.sqrt(np.mean(res**2))),
        rms_start=float("nan") if rms_start is None else rms_start,
        lm=lm,
        gradient=gradient,
        time_s=time.perf_counter() - t_start,
        orbits=orbits,
        singular_values=np.linalg.svd(lm.jac, compute_uv=False),
        jac_time_s=jac_time,
        n_jev=n_jev,
        branch_time_s=branch_time,
        history=history,
    )
