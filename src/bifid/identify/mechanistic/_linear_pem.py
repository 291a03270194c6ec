"""Prediction-error identification of a linearised physical model from a free decay (thesis §4.3.1).

The model is the linearisation of a registered :class:`~bifid.systems.System` at an
equilibrium :math:`x^*` (for ``flutter`` at zero airspeed, :math:`x^* = 0`):

.. math::

    A(\\theta) = \\frac{\\partial f}{\\partial x}(x^*, p(\\theta))      \\qquad \\text{(jax.jacfwd)}

sampled exactly with the transition matrix of eq. 4.8 and observed through the measured
states (eq. 4.7):

.. math::

    z(k+1) = A_d(\\theta) z(k),\\quad A_d = e^{A(\\theta) T_s},\\qquad
    \\hat y(k\\,|\\,\\theta) = C z(k) + y_0 .

The unknowns ``θ`` are any subset of the physical parameters (positive ones searched in log
space), the unmeasured initial states (for ``flutter``: the initial velocities
:math:`\\dot h(0), \\dot\\alpha(0)`), optionally the measured initial states and the static
offsets ``y0`` of the outputs. They minimise the output (simulation) error of eq. 4.9,

.. math::

    V(\\theta) = \\sum_c \\sigma_c^{-2}\\sum_k \\bigl(y_c(k) - \\hat y_c(k|\\theta)\\bigr)^2,

with per-output weights :math:`\\sigma_c` re-estimated from the residuals after a first pass
(for independent Gaussian output noise this is the maximum-likelihood criterion, which is
what the determinant criterion of MATLAB's ``pem`` reduces to for a diagonal noise
covariance). The optimiser is SciPy's trust-region reflective least squares fed with the
exact Jacobian :math:`\\partial\\varepsilon/\\partial\\theta` from ``jax.jacfwd`` through the
``lax.scan`` of eq. 4.7. Standard errors come from the Gauss–Newton covariance
:math:`\\hat s^2 (J^TJ)^{-1}`; they assume white residuals and are optimistic on real data
whose residuals are coloured by model error.

Parameters can be *tied*: ``ratios={"ka": "Ia"}`` keeps ``ka / Ia`` at its starting value,
which is how the thesis keeps a natural frequency
:math:`\\omega_\\alpha=\\sqrt{k_\\alpha/I_\\alpha}` measured by a shaker test fixed while
:math:`I_\\alpha` is identified (Table 4.1:
:math:`k_\\alpha = \\omega_\\alpha^2 I_\\alpha`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp
import numpy as np
import scipy.linalg
import scipy.optimize

from bifid.errors import BifidInputError, ConvergenceError
from bifid.identify._base import Estimator
from bifid.identify._persistence import register_model_type
from bifid.identify.mechanistic._discrete import (
    discrete_outputs,
    jacobian_and_field,
    n_squarings_for,
    output_error_kernels,
    state_matrix,
)
from bifid.systems import System, get_system

Array = jnp.ndarray

__all__ = ["LinearPEM"]


@dataclass(frozen=True)
class _Structure:
    """Indices and starting values of one identification problem."""

    out_idx: tuple[int, ...]
    free_idx: tuple[int, ...]
    ratio_pairs: tuple[tuple[int, int], ...]
    ratio_base: list[float]
    log_mask: tuple[bool, ...]
    z0_idx: tuple[int, ...]
    p0: np.ndarray
    x_eq: Array
    A0: np.ndarray


@register_model_type
class LinearPEM(Estimator):
    """Output-error identification of a linearised system from a free-decay record.

    Parameters
    ----------
    system : str or System
        The physical model (a registered system or a system file).
    free : sequence of str
        Physical parameters to identify (e.g. ``("Ia", "ca", "ch")`` of ``flutter``).
    outputs : sequence of str
        Measured states, in the column order of the data (e.g. ``("h", "alpha")``).
    params : mapping, optional
        Values of the other parameters and starting values of the free ones (defaults: the
        system's nominal values). For a free decay of ``flutter`` set ``U = 0``.
    ratios : mapping, optional
        ``{dependent: source}``: the dependent parameter follows the source one with the
        ratio it has in ``params`` (keeps a measured natural frequency fixed).
    initial_states : sequence of str or None
        States whose initial value is estimated. ``None`` (default): every state that is
        not measured and is observable from the outputs (for ``flutter`` at ``U = 0``:
        ``hd, alphad``; the aerodynamic lag states are unobservable there and stay 0).
    estimate_measured_initial : bool
        Also estimate the initial values of the measured states (otherwise they are the
        first samples minus the offsets). Estimating them removes the bias that noise on
        the first sample would cause; the thesis fixes them.
    fit_offset : bool
        Estimate a static offset per output (the measured rest position).
    log_params : sequence of str or None
        Free parameters searched in log space; default: those with a positive start.
    x_eq : array, optional
        Equilibrium to linearise at (zeros by default; checked to be an equilibrium).
    decimate : int
        Use every ``decimate``-th sample (the transition matrix is taken over
        ``decimate * Ts``); 1 keeps all samples.
    max_nfev : int
        Budget of residual evaluations of the optimiser.
    reweight : bool
        Second pass with output weights from the residuals of the first.
    horizons : sequence of float
        Fractions of the record fitted in turn, each pass starting from the previous
        optimum ("growing horizon"). Output-error criteria of lightly damped oscillators
        have many local minima (a model whose frequency is a few per cent off drifts by
        whole periods over a long record); fitting the first cycles first avoids them.
    """

    model_type = "linear_pem"
    _fitted_attribute = "p_"

    def __init__(
        self,
        system: str | System,
        free: Sequence[str],
        outputs: Sequence[str],
        *,
        params: Mapping[str, float] | None = None,
        ratios: Mapping[str, str] | None = None,
        initial_states: Sequence[str] | None = None,
        estimate_measured_initial: bool = True,
        fit_offset: bool = True,
        log_params: Sequence[str] | None = None,
        x_eq: Sequence[float] | None = None,
        decimate: int = 1,
        max_nfev: int = 200,
        reweight: bool = True,
        horizons: Sequence[float] = (0.1, 0.25, 0.5, 1.0),
    ) -> None:
        self.system = system
        self.free = tuple(free)
        self.outputs = tuple(outputs)
        self.params = dict(params or {})
        self.ratios = dict(ratios or {})
        self.initial_states = None if initial_states is None else tuple(initial_states)
        self.estimate_measured_initial = estimate_measured_initial
        self.fit_offset = fit_offset
        self.log_params = None if log_params is None else tuple(log_params)
        self.x_eq = None if x_eq is None else tuple(float(v) for v in x_eq)
        self.decimate = decimate
        self.max_nfev = max_nfev
        self.reweight = reweight
        self.horizons = tuple(float(h) for h in horizons)

    # ------------------------------------------------------------------ helpers
    def _system(self) -> System:
        return get_system(self.system) if isinstance(self.system, str) else self.system

    # ---------------------------------------------------------------------- fit
    def fit(
        self,
        y: np.ndarray,
        sample_rate: float,
        *,
        x0: Mapping[str, float] | None = None,
    ) -> LinearPEM:
        """Identify the free parameters from the free decay ``y``.

        Parameters
        ----------
        y : array of shape (n_samples, n_outputs)
            Measured outputs in the order of ``outputs`` (physical units, offsets allowed).
        sample_rate : float
            Sampling rate [Hz]; ``Ts = 1 / sample_rate``.
        x0 : mapping, optional
            Starting guesses of initial states by name (default: measured first samples and
            velocities by finite differences of the first samples).

        Returns
        -------
        self
            With ``params_`` (identified values), ``stderr_``, ``correlation_``,
            ``initial_state_``, ``offset_``, ``p_`` (full parameter vector), ``A_`` (state
            matrix), ``eigenvalues_``, ``rmse_`` and ``fit_percent_`` per output (MATLAB's
            NRMSE fit ``100 (1 - |y - ŷ| / |y - mean y|)``), ``cost_``, ``nfev_``.

        Raises
        ------
        BifidInputError
            On malformed data or names.
        ConvergenceError
            If the optimiser fails or the result is not finite.
        """
        sys_ = self._system()
        y = self._check_data(y, sample_rate)
        st = self._structure(sys_)
        d = self.decimate
        yd = y[::d]
        dt = d / float(sample_rate)
        # starting values: offsets from the settled tail, positions from the first sample
        off0 = (
            yd[-max(5, yd.shape[0] // 10) :].mean(axis=0)
            if self.fit_offset
            else np.zeros(len(self.outputs))
        )
        z_base = self._initial_state(sys_, st, y, off0, sample_rate, x0)
        theta0 = np.concatenate(
            [
                [
                    math.log(st.p0[i]) if lm else st.p0[i]
                    for i, lm in zip(st.free_idx, st.log_mask, strict=True)
                ],
                z_base[list(st.z0_idx)],
                off0 if self.fit_offset else np.zeros(0),
            ]
        )
        residual, jac, pred, _ = output_error_kernels(
            sys_.field,
            sys_.n_states,
            st.out_idx,
            st.free_idx,
            st.log_mask,
            st.ratio_pairs,
            st.z0_idx,
            self.fit_offset,
            n_squarings_for(st.A0 * dt),
        )
        consts = (
            jnp.asarray(st.p0),
            jnp.asarray(z_base),
            jnp.asarray(np.array(st.ratio_base, dtype=float)),
            st.x_eq,
            jnp.asarray(dt),
        )
        sol, nfev, w = self._optimise(residual, jac, consts, yd, theta0)
        J = np.asarray(
            jac(jnp.asarray(sol.x), *consts, yd.shape[0], jnp.asarray(yd), jnp.asarray(w))
        )
        cov = float(sol.fun @ sol.fun) / max(J.shape[0] - J.shape[1], 1) * np.linalg.pinv(J.T @ J)
        yhat = np.asarray(pred(jnp.asarray(sol.x), *consts, yd.shape[0]))
        self._store(sys_, st, sol, cov, z_base, yd, yhat, w)
        self.sample_rate_ = float(sample_rate)
        self.nfev_ = nfev
        self._dt = dt
        return self

    def _check_data(self, y: np.ndarray, sample_rate: float) -> np.ndarray:
        y = np.asarray(y, dtype=np.float64)
        if y.ndim == 1:
            y = y[:, None]
        n_out = len(self.outputs)
        if y.ndim != 2 or y.shape[1] != n_out:
            raise BifidInputError(
                f"y must have shape (n_samples, {n_out}) with columns {self.outputs}; "
                f"got {y.shape}. Transpose it if the outputs are rows."
            )
        if y.shape[0] < 20:
            raise BifidInputError(f"y needs at least 20 samples, got {y.shape[0]}.")
        if not np.all(np.isfinite(y)):
            raise BifidInputError("y contains NaN or inf; crop or clean the record first.")
        if not (math.isfinite(sample_rate) and sample_rate > 0):
            raise BifidInputError(f"sample_rate must be a positive number, got {sample_rate!r}.")
        if not (isinstance(self.decimate, int) and self.decimate >= 1):
            raise BifidInputError(f"decimate must be a positive integer, got {self.decimate!r}.")
        if not self.free:
            raise BifidInputError("free must name at least one parameter to identify.")
        return y

    def _structure(self, sys_: System) -> _Structure:
        """Indices of the outputs, free and tied parameters and estimated initial states;
        which free parameters are searched in log space; the equilibrium (checked)."""
        out_idx = tuple(sys_.state_index(s) for s in self.outputs)
        free_idx = tuple(sys_.index(n) for n in self.free)
        if len(set(free_idx)) != len(free_idx):
            raise BifidInputError(f"free has duplicated names: {self.free}.")
        p0 = np.asarray(sys_.param_vector(self.params))
        ratio_pairs, ratio_base = [], []
        for dep, src in self.ratios.items():
            i_dep, i_src = sys_.index(dep), sys_.index(src)
            if dep in self.free:
                raise BifidInputError(f"{dep!r} is tied to {src!r} by ratios; it cannot be free.")
            if p0[i_src] == 0:
                raise BifidInputError(f"ratio {dep}/{src}: {src} must not start at 0.")
            ratio_pairs.append((i_dep, i_src))
            ratio_base.append(p0[i_dep] / p0[i_src])
        log_names = (
            [n for n in self.free if p0[sys_.index(n)] > 0]
            if self.log_params is None
            else list(self.log_params)
        )
        for n in log_names:
            if n not in self.free:
                raise BifidInputError(f"log_params name {n!r} is not in free {self.free}.")
            if not p0[sys_.index(n)] > 0:
                raise BifidInputError(
                    f"{n!r} is searched in log space but starts at {p0[sys_.index(n)]}."
                )
        x_eq = jnp.zeros(sys_.n_states) if self.x_eq is None else jnp.asarray(self.x_eq)
        f_eq = np.asarray(jacobian_and_field(sys_.field)[1](x_eq, jnp.asarray(p0)))
        if np.max(np.abs(f_eq)) > 1e-8 * max(1.0, float(np.max(np.abs(x_eq)))):
            raise BifidInputError(
                f"x_eq is not an equilibrium of {sys_.name!r} at these parameters "
                f"(|f(x_eq)| = {np.max(np.abs(f_eq)):.3g}); pass the equilibrium as x_eq."
            )
        A0 = np.asarray(state_matrix(sys_, p0, x_eq))
        if self.initial_states is None:  # the unmeasured states the outputs observe
            C0 = np.zeros((len(out_idx), sys_.n_states))
            C0[np.arange(len(out_idx)), out_idx] = 1.0
            O = np.vstack([C0 @ np.linalg.matrix_power(A0, k) for k in range(sys_.n_states)])
            col = np.linalg.norm(O, axis=0) / max(np.linalg.norm(O), 1e-300)
            unmeasured = [i for i in range(sys_.n_states) if i not in out_idx and col[i] > 1e-10]
        else:
            unmeasured = [sys_.state_index(s) for s in self.initial_states]
        z0_idx = tuple(
            sorted(set(unmeasured) | (set(out_idx) if self.estimate_measured_initial else set()))
        )
        return _Structure(
            out_idx,
            free_idx,
            tuple(ratio_pairs),
            ratio_base,
            tuple(n in log_names for n in self.free),
            z0_idx,
            p0,
            x_eq,
            A0,
        )

    def _initial_state(
        self,
        sys_: System,
        st: _Structure,
        y: np.ndarray,
        off0: np.ndarray,
        sample_rate: float,
        x0: Mapping[str, float] | None,
    ) -> np.ndarray:
        """Measured positions from the first sample, their velocities (states named
        ``<name>d``) by a 5-point finite difference, then the given ``x0``."""
        z = np.zeros(sys_.n_states)
        names = sys_.states
        for c, i in enumerate(st.out_idx):
            z[i] = y[0, c] - off0[c]
            if names[i] + "d" in names:
                k = min(4, y.shape[0] - 1)
                z[names.index(names[i] + "d")] = (y[k, c] - y[0, c]) * float(sample_rate) / k
        for nm, v in (x0 or {}).items():
            z[sys_.state_index(nm)] = float(v)
        return z

    def _optimise(
        self, residual: Any, jac: Any, consts: tuple, yd: np.ndarray, theta0: np.ndarray
    ) -> tuple[Any, int, np.ndarray]:
        """Growing-horizon trust-region least squares, then (``reweight``) a pass with the
        output weights of the residuals; returns the SciPy result, the evaluations, the
        weights."""
        n, n_out = yd.shape
        Y = jnp.asarray(yd)

        def run(theta_start, w):
            wj = jnp.asarray(w)
            return scipy.optimize.least_squares(
                lambda th: np.asarray(residual(jnp.asarray(th), *consts, n, Y, wj)),
                theta_start,
                jac=lambda th: np.asarray(jac(jnp.asarray(th), *consts, n, Y, wj)),
                method="trf",
                x_scale="jac",
                xtol=1e-12,
                ftol=1e-12,
                gtol=1e-10,
                max_nfev=self.max_nfev,
            )

        # growing horizon: fit the first part of the record, then more of it, so that the
        # phase of a badly-started model never drifts by whole periods (local minima)
        w_out = 1.0 / np.maximum(yd.std(axis=0), 1e-300)
        sol, nfev, theta = None, 0, theta0
        for frac in self.horizons:
            mask = (np.arange(n) < max(10, round(frac * n))).astype(float)
            sol = run(theta, mask[:, None] * w_out[None, :])
            nfev += int(sol.nfev)
            theta = sol.x
        w = np.ones(n)[:, None] * w_out[None, :]
        if self.reweight:
            r = np.asarray(residual(jnp.asarray(theta), *consts, n, Y, jnp.ones((n, n_out))))
            sigma = np.sqrt(np.mean(r.reshape(n, n_out) ** 2, axis=0))
            w = np.ones(n)[:, None] / np.maximum(sigma, 1e-300)[None, :]
            sol = run(theta, w)
            nfev += int(sol.nfev)
        assert sol is not None
        if not np.all(np.isfinite(sol.x)) or sol.status < 0:
            raise ConvergenceError(f"Linear PEM optimiser failed: {sol.message}")
        if sol.status == 0:
            raise ConvergenceError(
                f"Linear PEM did not converge within max_nfev={self.max_nfev}; raise max_nfev "
                "or start closer (e.g. from modal-test values)."
            )
        return sol, nfev, w

    def _store(
        self,
        sys_: System,
        st: _Structure,
        sol: Any,
        cov: np.ndarray,
        z_base: np.ndarray,
        yd: np.ndarray,
        yhat: np.ndarray,
        w: np.ndarray,
    ) -> None:
        """Fitted attributes from the solution and its Gauss–Newton covariance."""
        theta = sol.x
        se_theta = np.sqrt(np.maximum(np.diag(cov), 0.0))
        p_fit = st.p0.copy()
        stderr = {}
        for k, (i, lm) in enumerate(zip(st.free_idx, st.log_mask, strict=True)):
            p_fit[i] = math.exp(theta[k]) if lm else theta[k]
            stderr[self.free[k]] = float(p_fit[i] * se_theta[k] if lm else se_theta[k])
        for (i_dep, i_src), rb in zip(st.ratio_pairs, st.ratio_base, strict=True):
            p_fit[i_dep] = rb * p_fit[i_src]
        nf, nz = len(st.free_idx), len(st.z0_idx)
        z0 = z_base.copy()
        z0[list(st.z0_idx)] = theta[nf : nf + nz]
        dstd = np.sqrt(np.maximum(np.diag(cov), 1e-300))
        self.n_features_in_ = len(self.outputs)
        self.p_ = p_fit
        self.params_ = {nm: float(p_fit[sys_.index(nm)]) for nm in self.free}
        self.tied_ = {dep: float(p_fit[sys_.index(dep)]) for dep in self.ratios}
        self.stderr_ = stderr
        self.correlation_ = (cov / np.outer(dstd, dstd))[:nf, :nf]
        self.initial_state_ = z0
        self.estimated_initial_states_ = tuple(sys_.states[i] for i in st.z0_idx)
        self.offset_ = np.asarray(
            theta[nf + nz :] if self.fit_offset else np.zeros(len(self.outputs)), dtype=float
        )
        self.A_ = np.asarray(state_matrix(sys_, p_fit, st.x_eq))
        self.eigenvalues_ = np.linalg.eigvals(self.A_)
        err = yd - yhat
        self.rmse_ = {
            o: float(np.sqrt(np.mean(err[:, c] ** 2))) for c, o in enumerate(self.outputs)
        }
        self.fit_percent_ = {
            o: float(
                100.0 * (1 - np.linalg.norm(err[:, c]) / np.linalg.norm(yd[:, c] - yd[:, c].mean()))
            )
            for c, o in enumerate(self.outputs)
        }
        self.output_sigma_ = {o: float(1.0 / w[0, c]) for c, o in enumerate(self.outputs)}
        self.cost_ = float(0.5 * sol.fun @ sol.fun)
        self.converged_ = bool(sol.status > 0)
        self.x_eq_ = np.asarray(st.x_eq)

    # ------------------------------------------------------------------ predict
    def predict(self, n_samples: int, *, with_offset: bool = True) -> np.ndarray:
        """Model outputs :math:`C A_d^k z_0 (+ y_0)` at the fitted sample rate (undecimated).

        Returns
        -------
        ndarray of shape (n_samples, n_outputs)
        """
        self._check_fitted()
        sys_ = self._system()
        out_idx = [sys_.state_index(s) for s in self.outputs]
        C = np.zeros((len(out_idx), sys_.n_states))
        C[np.arange(len(out_idx)), out_idx] = 1.0
        A_d = scipy.linalg.expm(self.A_ / self.sample_rate_)
        ys = np.asarray(
            discrete_outputs(
                jnp.asarray(A_d), jnp.asarray(C), jnp.asarray(self.initial_state_), int(n_samples)
            )
        )
        return ys + (self.offset_ if with_offset else 0.0)

    def modal_summary(self) -> list[dict[str, float]]:
        """Oscillatory modes of the identified state matrix: frequency [Hz] and damping ratio."""
        self._check_fitted()
        out = []
        for lam in self.eigenvalues_:
            if lam.imag > 1e-9:
                wn = abs(lam)
                out.append(
                    {
                        "frequency_hz": float(lam.imag / (2 * math.pi)),
                        "damping_ratio": float(-lam.real / wn),
                    }
                )
        return sorted(out, key=lambda m: m["frequency_hz"])

    def summary(self) -> dict[str, Any]:
        """JSON-able result: ``parameters``, ``standard_errors`` (Gauss–Newton), tied
        parameters, initial state, offsets, fit quality and the modes."""
        self._check_fitted()
        sys_ = self._system()
        return {
            "parameters": self.params_,
            "standard_errors": self.stderr_,
            "tied": self.tied_,
            "initial_state": dict(zip(sys_.states, map(float, self.initial_state_), strict=True)),
            "offset": dict(zip(self.outputs, map(float, self.offset_), strict=True)),
            "rmse": self.rmse_,
            "fit_percent": self.fit_percent_,
            "modes": self.modal_summary(),
            "nfev": self.nfev_,
        }

    _SCALARS = (
        "params_",
        "tied_",
        "stderr_",
        "estimated_initial_states_",
        "rmse_",
        "fit_percent_",
        "output_sigma_",
        "cost_",
        "nfev_",
        "converged_",
        "sample_rate_",
        "n_features_in_",
        "_dt",
    )
    _ARRAYS = ("p_", "initial_state_", "offset_", "A_", "correlation_", "x_eq_")

    def _state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        if not isinstance(self.system, str):
            raise BifidInputError(
                "a LinearPEM is saved with its system's name: build it with system='name' "
                "(a registered system or a system file), not a System object."
            )
        return (
            {k: getattr(self, k) for k in self._SCALARS},
            {k: np.asarray(getattr(self, k)) for k in self._ARRAYS},
        )

    def _restore(self, state: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        for k in self._SCALARS:
            setattr(self, k, state[k])
        self.estimated_initial_states_ = tuple(self.estimated_initial_states_)
        for k in self._ARRAYS:
            setattr(self, k, np.asarray(arrays[k]))
        self.eigenvalues_ = np.linalg.eigvals(self.A_)
