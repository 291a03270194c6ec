r"""Collocation orbits of a model at the parameters of measured limit cycles (thesis §4.3.3).

Each measurement :math:`(\lambda_j, h_j)` is matched to an orbit of the model's branch born
at the Hopf point and re-solved at fixed :math:`\lambda_j` by Newton
(:func:`bifid.continuation.correct`) on the Fourier collocation equations (eq. 4.14,
:func:`bifid.continuation.orbit_problem`). Exact derivatives of the orbit amplitudes follow
by implicit differentiation at the converged orbit :math:`y_j = (v_j, T_j, \lambda_j)`:

.. math::

    \begin{bmatrix} G_y \\ e_\lambda^T \end{bmatrix} \frac{dy_j}{d\theta}
    = -\begin{bmatrix} G_\theta \\ 0 \end{bmatrix},\qquad
    \frac{d\|v_j\|_h}{d\theta} = \mathrm{sign}(v_h(t^*))\, w(t^*)^T \frac{dv_{j,h}}{d\theta},

where :math:`G` is the collocation residual with its phase-condition row, :math:`t^*` the
time of the maximum of the trigonometric interpolant and :math:`w(t^*)` its interpolation
weights (the maximum is stationary in :math:`t`: :math:`t^*` does not move to first order).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

from bifid.continuation import (
    NewtonCorrector,
    fourier_differentiation_matrix,
    orbit_problem,
    resample_orbit,
)
from bifid.errors import ConvergenceError
from bifid.identify._records import UNKNOWN, LCOData
from bifid.identify.mechanistic._branch import collapse_index
from bifid.signal import evaluate_fourier, fourier_coefficients, max_abs
from bifid.systems import System

TWO_PI = 2.0 * math.pi

__all__ = ["OrbitSet", "max_abs_with_weights"]


def _interp_weights(M: int, t: float) -> np.ndarray:
    """Trigonometric-interpolation weights ``w_j(t)`` on the grid ``t_j = 2 pi j / M`` (M even).

    ``x(t) = sum_j w_j(t) x_j`` with
    ``w_j = (1/M) [1 + 2 sum_{k=1}^{M/2-1} cos k(t - t_j) + cos (M/2)(t - t_j)]``.
    """
    d = t - TWO_PI * np.arange(M) / M
    k = np.arange(1, M // 2)
    return (1.0 + 2.0 * np.cos(np.outer(d, k)).sum(axis=1) + np.cos(M / 2 * d)) / M


def max_abs_with_weights(v: np.ndarray) -> tuple[float, np.ndarray]:
    """``max_t |x(t)|`` of the trigonometric interpolant of ``v`` and ``d max / d v``.

    The maximiser ``t*`` is bracketed on a 16× finer grid and located by Brent's method
    (:func:`scipy.optimize.minimize_scalar`); by stationarity ``d max/d v = sign(x(t*))
    w(t*)``.
    """
    v = np.asarray(v, dtype=float)
    M = v.shape[0]
    a0, a, b = fourier_coefficients(v)
    fine = np.fft.irfft(np.fft.rfft(v), n=16 * M) * 16
    i = int(np.argmax(np.abs(fine)))
    h = TWO_PI / (16 * M)
    res = scipy.optimize.minimize_scalar(
        lambda t: -abs(float(evaluate_fourier(a0, a, b, t))),
        bounds=(i * h - h, i * h + h),
        method="bounded",
        options={"xatol": 1e-13},
    )
    w = _interp_weights(M, float(res.x))
    val = float(w @ v)
    return abs(val), math.copysign(1.0, val) * w


@functools.lru_cache(maxsize=16)
def _param_jacobian(problem: Any) -> Callable:
    """Jitted ``dG/dp`` of a collocation problem (residual differentiated in ``args['p']``)."""

    def gp(y, args):
        return jax.jacfwd(lambda pp: problem.residual(y, {**args, "p": pp}))(args["p"])

    return jax.jit(gp)


@functools.lru_cache(maxsize=16)
def _full_jacobian(problem: Any) -> Callable:
    """``(y, args) -> G_y`` from the corrector's compiled ``(G, G_y)`` (one program for
    the corrections and the derivatives)."""
    evaluate = NewtonCorrector(problem).evaluate
    return lambda y, args: evaluate(y, args)[1]


class OrbitSet:
    """Collocation orbits of a model at the parameters of measured LCOs (fixed ``lambda_j``).

    Solves, differentiates and keeps the orbits warm between parameter updates.

    Parameters
    ----------
    system : System
    param : str
        The bifurcation parameter.
    n_mesh : int
        Collocation points per orbit.
    outputs : tuple of str
        States whose amplitudes are matched (the first decides the branch matching).

    Attributes
    ----------
    ys : ndarray of shape (n_meas, M*n + 2)
        Orbits: mesh values, period, parameter.
    sides : ndarray of int
        +1 stable side of the cycle fold (``d lambda / dA > 0``), -1 Hopf side.
    p_ys : ndarray
        Parameter vector the orbits ``ys`` solve.
    """

    def __init__(self, system: System, param: str, n_mesh: int, outputs: Sequence[str]) -> None:
        self.system = system
        self.param = param
        self.n_mesh = n_mesh
        self.outputs = tuple(outputs)
        self.ys: np.ndarray | None = None
        self.sides: np.ndarray | None = None
        self.p_ys: np.ndarray | None = None
        self.problem = orbit_problem(system.field, n_mesh, system.n_states)
        self._D = fourier_differentiation_matrix(n_mesh)
        self._idx = system.index(param)
        self._out = [system.state_index(o) for o in self.outputs]

    # ---------------------------------------------------------------- initial match
    def _candidates(
        self,
        branch: Any,
        lam: float,
        label: int,
        target: float,
        amps: np.ndarray,
        fold_i: int | None,
    ) -> list[tuple[int, float, float]]:
        params = np.asarray(branch.params)[: len(amps)]
        stab = np.asarray(branch.stable, dtype=bool)
        cands = []
        for i in range(len(params) - 1):
            a, b = params[i], params[i + 1]
            if (a - lam) * (b - lam) <= 0 and a != b:
                s = (lam - a) / (b - a)
                cands.append((i, s, (1 - s) * amps[i] + s * amps[i + 1]))
        if label != UNKNOWN and fold_i is not None:
            # subcritical branch: unstable between the Hopf point and the first cycle fold,
            # stable beyond it (arclength order, as in the thesis)
            return [c for c in cands if (c[0] < fold_i) == (label == 0)]
        if label != UNKNOWN:
            return [c for c in cands if stab[c[0]] == bool(label) and stab[c[0] + 1] == bool(label)]
        return sorted(cands, key=lambda c: abs(c[2] - target))

    def match(
        self, branch: Any, data: LCOData, p: np.ndarray, *, skip_missing: bool = False
    ) -> np.ndarray:
        """Initial orbits for each measurement from a continued branch (``hopf_orbits``).

        On a subcritical branch (unstable cycles born at the Hopf point, turning at a
        cycle fold) a measurement labelled unstable is matched between the Hopf point and
        the first cycle fold, a stable one beyond that fold — the thesis's arclength
        ordering; this holds even where a poor start model has other stability changes.
        Otherwise a label is matched to a segment whose end points have that Floquet
        stability. If several segments qualify, the first in arclength order wins. An
        unknown label takes the orbit of nearest amplitude. The guess is the linear
        interpolation of the two bracketing branch points, corrected at the measured
        parameter; the side of the cycle fold (sign of ``d lambda / d A``) found there is
        then kept through every later update.

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
        # only the orbits before a collapse onto the equilibrium are on the branch
        end = collapse_index(branch, n) or len(branch.params)
        params = np.asarray(branch.params)[:end]
        sols = self._on_mesh(branch)[:end]
        V0 = sols[:, : M * n].reshape(-1, M, n)[:, :, self._out[0]]
        amps = np.atleast_1d(max_abs((V0 - V0.mean(axis=1, keepdims=True)).T))
        folds_i = sorted(
            sp.index for sp in branch.special_points if sp.kind == "cycle_fold" and sp.index < end
        )
        hopf_start = branch.meta.get("start_kind") == "hopf"
        stab = np.asarray(branch.stable, dtype=bool)
        fold_i = folds_i[0] if (folds_i and hopf_start and not stab[1]) else None
        target = data.column(self.outputs[0])
        ys, matched = [], []
        for j in range(len(data)):
            lam = data.param[j]
            cands = self._candidates(branch, lam, int(data.stable[j]), target[j], amps, fold_i)
            if not cands and skip_missing:
                continue
            if not cands:
                kind = {0: "unstable", 1: "stable"}.get(int(data.stable[j]), "any")
                folds = [
                    f"{sp.param:.6g}" for sp in branch.special_points if sp.kind == "cycle_fold"
                ]
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

    def _on_mesh(self, branch: Any) -> np.ndarray:
        """Branch points ``(V, T)`` on this set's mesh (a branch may hold a finer one)."""
        M, n = self.n_mesh, self.system.n_states
        Mb = int(branch.meta.get("n_mesh", M))
        sols = np.asarray(branch.solutions)[:, : Mb * n + 1]
        if Mb == M:
            return sols
        V = [resample_orbit(y[: Mb * n].reshape(Mb, n), M).ravel() for y in sols]
        return np.column_stack([np.asarray(V), sols[:, Mb * n]])

    # ------------------------------------------------------------------- solving
    def _args(self, p: np.ndarray, y: np.ndarray) -> dict[str, Any]:
        M, n = self.n_mesh, self.system.n_states
        V = y[: M * n].reshape(M, n)
        return {
            "p": jnp.asarray(p),
            "idx": jnp.asarray(self._idx),
            "dref": jnp.asarray((self._D @ V).ravel()),
        }

    def solve(
        self,
        p: np.ndarray,
        *,
        start: np.ndarray | None = None,
        p_start: np.ndarray | None = None,
        tol: float = 1e-11,
        max_substeps: int = 8,
    ) -> np.ndarray | None:
        """Re-solve every orbit at its fixed parameter from warm starts.

        Starts from ``start`` (orbits solving ``p_start``), by default the stored ones. If
        Newton fails from the start, the orbit is followed along the straight path from
        ``p_start`` to ``p`` in 2, 4, ... ``max_substeps`` steps (a natural-parameter
        homotopy in the model parameters; the measured ``lambda_j`` stays fixed).

        Returns the new orbits (not stored), or None if an orbit fails to converge or has
        moved to the other side of a cycle fold.
        """
        ys0 = self.ys if start is None else start
        p0 = self.p_ys if start is None else p_start
        assert ys0 is not None
        p = np.asarray(p, dtype=float)
        new = np.empty_like(ys0)
        for j, y0 in enumerate(ys0):
            y = self._correct(y0, p, tol)
            n_sub = 2
            while y is None and p0 is not None and n_sub <= max_substeps:
                y = y0
                for k in range(1, n_sub + 1):
                    y = self._correct(y, p0 + (p - p0) * (k / n_sub), tol)
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
        """Newton correction of one orbit at fixed ``lambda`` (None if it fails, or if it
        collapsed onto the equilibrium: a constant is a solution of the collocation
        equations for any period)."""
        row = np.zeros(y0.shape[0])
        row[-1] = 1.0
        # the corrector itself, not bifid.continuation.correct: that limits the BLAS threads
        # per call, whose library scan costs more than a correction of these small orbits
        r = NewtonCorrector(self.problem, tol=tol, max_iter=15).correct(
            np.asarray(y0, dtype=float), row, float(y0[-1]), self._args(p, y0)
        )
        y = np.asarray(r.y)
        if not r.converged or not np.all(np.isfinite(y)):
            return None
        M, n = self.n_mesh, self.system.n_states
        size = np.ptp(np.asarray(y[: M * n]).reshape(M, n), axis=0).max()
        if size < 1e-3 * np.ptp(y0[: M * n].reshape(M, n), axis=0).max():
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
        _, dA = max_abs_with_weights(y[: M * n].reshape(M, n)[:, self._out[0]])
        growth = float(dA @ t[: M * n].reshape(M, n)[:, self._out[0]])
        return int(np.sign(t[-1] * np.sign(growth))) or 1

    def amplitudes(self, ys: np.ndarray | None = None) -> np.ndarray:
        """``max_t |v_s(t) - mean(v_s)|`` of each output at each orbit, (n_meas, n_outputs).

        Centred like the measured signals (a rig's offsets are removed, and the LCOs of a
        model with even nonlinearities are not symmetric about the equilibrium: without
        centring the fit is biased by the orbit's mean shift).
        """
        ys = self.ys if ys is None else ys
        assert ys is not None
        M, n = self.n_mesh, self.system.n_states
        out = np.empty((ys.shape[0], len(self._out)))
        for j, y in enumerate(ys):
            V = y[: M * n].reshape(M, n)
            for c, s in enumerate(self._out):
                out[j, c] = max_abs_with_weights(V[:, s] - V[:, s].mean())[0]
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
            dy = np.linalg.solve(A, -np.vstack([Gp, np.zeros((1, len(cols)))]))
            V = y[: M * n].reshape(M, n)
            dV = dy[: M * n].reshape(M, n, len(cols))
            for c, s in enumerate(self._out):
                _, w = max_abs_with_weights(V[:, s] - V[:, s].mean())
                out[j, c] = w @ (dV[:, s, :] - dV[:, s, :].mean(axis=0))
        return out
