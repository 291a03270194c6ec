"""The Gaussian-process regressor of the kernel models (thesis §6.2.3): hyperparameter
selection by marginal likelihood or closed-form leave-one-out, and the fitted posterior.

The model, criteria and posterior are stated in :mod:`._gp_core`; this module is the
estimator around them: inputs validated and scaled, hyperparameters searched in log space
within bounds (the length scales' lower bound raised to the data spacing; pseudo-observations
conditioned on rather than scored: :mod:`._gp_core`) by L-BFGS-B
(:func:`._search.minimize_multistart`, gradients by JAX) from seeded starts, the fitted
:class:`~._gp_core.GPState` kept for pure-JAX evaluation.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import jax
import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError, ConvergenceError, NotFittedError
from bifid.identify.forced_kernel._gp_core import (
    GPSamples,
    GPState,
    Monomials,
    _draw_samples,
    _objective,
    _posterior,
    _split,
    gp_mean,
    gp_var,
    input_spacing,
    padded_args,
)
from bifid.identify.forced_kernel._search import laplace_log_errors, minimize_multistart

__all__ = ["GPRegressor", "HyperBounds"]

Criterion = Literal["ml", "loo"]


@dataclass(frozen=True)
class HyperBounds:
    """Box bounds of the hyperparameters (not logs), relative to the scaled data.

    ``length_scale`` in units of the input spread (its lower bound is raised to the data
    spacing, :func:`~._gp_core.input_spacing`, where that is larger),
    ``signal``/``basis``/``noise`` in units of the RMS of the targets.
    """

    length_scale: tuple[float, float] = (0.05, 50.0)
    signal: tuple[float, float] = (1e-4, 1e2)
    basis: tuple[float, float] = (1e-4, 1e3)
    noise: tuple[float, float] = (1e-6, 1.0)

    def __post_init__(self) -> None:
        for name in ("length_scale", "signal", "basis", "noise"):
            lo, hi = getattr(self, name)
            if not (0 < lo <= hi and math.isfinite(hi)):
                raise BifidInputError(
                    f"HyperBounds.{name} must be 0 < low <= high < inf, got ({lo}, {hi})."
                )


class GPRegressor:
    """GP / kernel ridge regression with an SE-ARD kernel and explicit monomial basis.

    Parameters
    ----------
    basis : tuple of tuple of int
        Monomial exponents, one tuple of length D per basis function, e.g.
        ``((1, 0), (3, 0))`` for ``h = (ũ₁, ũ₁³)`` with ``ũ = (x − c)/s``. Empty: pure SE.
    basis_center : sequence of float or None
        Centre ``c`` per input; ``None`` entries (or ``None`` altogether) use the mean of
        the training inputs. Use 0 for an input whose sign structure matters (amplitudes).
    criterion : {"ml", "loo"}
        Hyperparameter selection: log marginal likelihood or closed-form LOO log
        predictive probability. Never the training loss.
    n_restarts : int
        Extra L-BFGS-B starts from seeded random points in a central box.
    bounds : HyperBounds
    length_scale_init : float
        Initial ARD length scale (units of the input spread).
    noise_init : float
        Initial noise standard deviation (units of the target RMS).
    fixed_length_scales : sequence of float or None
        Per input, a length scale to hold fixed (units of the input spread), or None.
    seed : int
        Seed of the restarts.
    """

    def __init__(
        self,
        *,
        basis: Monomials = (),
        basis_center: Sequence[float | None] | None = None,
        criterion: Criterion = "ml",
        n_restarts: int = 2,
        bounds: HyperBounds = HyperBounds(),
        length_scale_init: float = 1.0,
        noise_init: float = 1e-2,
        fixed_length_scales: Sequence[float | None] | None = None,
        seed: int = 0,
    ) -> None:
        self.basis = tuple(tuple(int(e) for e in m) for m in basis)
        self.basis_center = None if basis_center is None else tuple(basis_center)
        self.criterion = criterion
        self.n_restarts = n_restarts
        self.bounds = bounds
        self.length_scale_init = length_scale_init
        self.noise_init = noise_init
        self.fixed_length_scales = (
            None if fixed_length_scales is None else tuple(fixed_length_scales)
        )
        self.seed = seed

    # ------------------------------------------------------------------ validation
    def _validate(self, x: Any, y: Any, extra_var: Any) -> tuple[np.ndarray, ...]:
        if self.criterion not in ("ml", "loo"):
            raise BifidInputError(f"criterion must be 'ml' or 'loo', got {self.criterion!r}.")
        try:
            xa = np.asarray(x, dtype=float)
            ya = np.asarray(y, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise BifidInputError("X and y must be numeric arrays.") from None
        if xa.ndim == 1:
            xa = xa[:, None]
        if xa.ndim != 2 or xa.shape[0] != ya.shape[0]:
            raise BifidInputError(
                f"X must be (n, D) and y (n,); got X {xa.shape} and y {ya.shape}."
            )
        if xa.shape[0] < 2:
            raise BifidInputError(f"need at least 2 training points, got {xa.shape[0]}.")
        if not (np.all(np.isfinite(xa)) and np.all(np.isfinite(ya))):
            raise BifidInputError("X and y must be finite (remove NaN/inf points first).")
        d = xa.shape[1]
        for m in self.basis:
            if len(m) != d or any(e < 0 for e in m):
                raise BifidInputError(
                    f"each basis monomial needs {d} non-negative exponents, got {m}."
                )
        if self.fixed_length_scales is not None and len(self.fixed_length_scales) != d:
            raise BifidInputError(
                f"fixed_length_scales needs {d} entries, got {len(self.fixed_length_scales)}."
            )
        if extra_var is None:
            ev = np.zeros(xa.shape[0])
        else:
            ev = np.asarray(extra_var, dtype=float).reshape(-1)
            if ev.shape != ya.shape or np.any(ev < 0) or not np.all(np.isfinite(ev)):
                raise BifidInputError("extra_var must be finite, >= 0, one value per point.")
        return xa, ya, ev

    # ------------------------------------------------------------------ fit
    def _layout(self, d: int, spacing: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Initial θ and log-bounds (lo, hi) for D inputs; the length scales' lower bound
        is raised to ``spacing`` (:func:`input_spacing`) where that is larger."""
        b = self.bounds
        m = len(self.basis)
        theta0 = np.concatenate(
            [
                [0.0],
                np.full(d, math.log(self.length_scale_init)),
                np.zeros(m),
                [math.log(self.noise_init)],
            ]
        )
        lo = np.concatenate(
            [
                [math.log(b.signal[0])],
                np.full(d, math.log(b.length_scale[0])),
                np.full(m, math.log(b.basis[0])),
                [math.log(b.noise[0])],
            ]
        )
        hi = np.concatenate(
            [
                [math.log(b.signal[1])],
                np.full(d, math.log(b.length_scale[1])),
                np.full(m, math.log(b.basis[1])),
                [math.log(b.noise[1])],
            ]
        )
        floor = math.log(min(max(spacing, b.length_scale[0]), b.length_scale[1]))
        lo[1 : 1 + d] = floor
        theta0 = np.clip(theta0, lo, hi)
        return theta0, lo, hi

    def prepare(
        self,
        X: Any,
        y: Any,
        *,
        x_scale: Any = None,
        y_scale: float | None = None,
        extra_var: Any = None,
        pseudo: Any = None,
    ) -> dict[str, Any]:
        """Validate and scale the data; the initial ``θ`` and its log-bounds.

        Used by :meth:`fit` and by callers that optimise ``θ`` jointly with other
        quantities (e.g. a forcing scale in the targets) before calling
        ``fit(..., theta=...)``. Returns a dict with ``x``, ``y``, ``extra_var`` (raw),
        ``pseudo`` (bool), ``x_scale``, ``x_center``, ``y_scale``, ``theta0``, ``lo``,
        ``hi``, ``notes``.
        """
        xa, ya, ev = self._validate(X, y, extra_var)
        n, d = xa.shape
        ps = np.zeros(n, dtype=bool) if pseudo is None else np.asarray(pseudo, dtype=bool)
        if ps.shape != (n,) or ps.all():
            raise BifidInputError(
                f"pseudo must be {n} booleans (one per point), not all of them True."
            )
        notes: list[str] = []
        if x_scale is None:
            xs = xa.std(axis=0)
        else:
            xs = np.asarray(x_scale, dtype=float).reshape(-1)
            if xs.shape != (d,):
                raise BifidInputError(f"x_scale needs {d} entries, got {xs.shape}.")
        constant = ~(xs > 1e-12 * np.maximum(1.0, np.abs(xa).max(axis=0)))
        xs = np.where(constant, np.maximum(np.abs(xa.mean(axis=0)), 1.0), xs)
        if self.basis_center is None:
            xc = xa.mean(axis=0)
        else:
            if len(self.basis_center) != d:
                raise BifidInputError(f"basis_center needs {d} entries.")
            xc = np.array(
                [
                    xa[:, i].mean() if c is None else float(c)
                    for i, c in enumerate(self.basis_center)
                ]
            )
        ys = float(np.sqrt(np.mean(ya**2))) if y_scale is None else float(y_scale)
        if not (ys > 0 and math.isfinite(ys)):
            ys = 1.0
            notes.append("all targets are zero; y_scale set to 1")
        theta0, lo, hi = self._layout(d, input_spacing(xa / xs, ps))
        fixed = [None] * d if self.fixed_length_scales is None else list(self.fixed_length_scales)
        for i in range(d):
            if constant[i] and fixed[i] is None:
                fixed[i] = self.bounds.length_scale[1]
                notes.append(
                    f"input {i} is constant in the data: its length scale is held at "
                    f"the upper bound {self.bounds.length_scale[1]:g}"
                )
            if fixed[i] is not None:
                v = math.log(float(fixed[i]))
                theta0[1 + i] = lo[1 + i] = hi[1 + i] = v
        return {
            "x": xa,
            "y": ya,
            "extra_var": ev,
            "pseudo": ps,
            "x_scale": xs,
            "x_center": xc,
            "y_scale": ys,
            "theta0": theta0,
            "lo": lo,
            "hi": hi,
            "notes": notes,
        }

    def fit(
        self,
        X: Any,
        y: Any,
        *,
        extra_var: Any = None,
        pseudo: Any = None,
        x_scale: Any = None,
        y_scale: float | None = None,
        theta: Any = None,
    ) -> GPRegressor:
        """Fit hyperparameters and the posterior.

        Parameters
        ----------
        X : array (n, D)
        y : array (n,)
        extra_var : array (n,), optional
            Known extra noise variance per point (raw units).
        pseudo : array of bool (n,), optional
            Pseudo-observations: values known by construction (e.g. ``a(0, Ω) = 0``), which
            carry only ``extra_var``, not the fitted noise ``σ_n²``, and which the selection
            criterion conditions on instead of scoring (module docstring of
            :mod:`._gp_core`).
        x_scale : array (D,), optional
            Input spreads (default: standard deviation per column; a constant column gets
            ``max(|mean|, 1)`` and its length scale is held at the upper bound, since the
            data say nothing about it).
        y_scale : float, optional
            Target scale (default: RMS of ``y``).
        theta : array, optional
            Hyperparameters (log, scaled units, layout of the module docstring) to use as
            they are, skipping the optimisation.

        Returns
        -------
        self
        """
        prep = self.prepare(
            X, y, extra_var=extra_var, pseudo=pseudo, x_scale=x_scale, y_scale=y_scale
        )
        xa, ya, ev, ps = prep["x"], prep["y"], prep["extra_var"], prep["pseudo"]
        xs, xc, ys = prep["x_scale"], prep["x_center"], prep["y_scale"]
        n = xa.shape[0]
        if theta is not None:
            th = np.asarray(theta, dtype=float).reshape(-1)
            if th.shape != prep["theta0"].shape or not np.all(np.isfinite(th)):
                raise BifidInputError(
                    f"theta must be {prep['theta0'].shape[0]} finite values, got {th.shape}."
                )
            self._set_state(th, xa, ya / ys, ev / ys**2, xs, xc, ys, ps)
            self.objective_ = float("nan")
            self.n_evaluations_ = 0
            self.optimizer_message_ = "hyperparameters given"
            self.notes_ = prep["notes"]
            self.n_train_ = n
            return self
        args = padded_args(xa, ya / ys, ev / ys**2, xs, xc, ps)
        vg = _objective(self.basis, self.criterion, bool(ps.any()))
        best = minimize_multistart(
            lambda th: vg(jnp.asarray(th), *args),
            prep["theta0"],
            prep["lo"],
            prep["hi"],
            n_restarts=self.n_restarts,
            seed=self.seed,
        )
        self._set_state(best.x, xa, ya / ys, ev / ys**2, xs, xc, ys, ps)
        self.objective_ = float(best.fun)
        self.n_evaluations_ = int(best.nfev_total)
        self.optimizer_message_ = str(best.message)
        self.notes_ = prep["notes"]
        self.n_train_ = n
        return self

    def _set_state(self, theta, xa, ys_scaled, ev_scaled, xs, xc, ys, pseudo) -> None:
        n = xa.shape[0]
        args = padded_args(
            np.asarray(xa),
            np.asarray(ys_scaled),
            np.asarray(ev_scaled),
            np.asarray(xs),
            np.asarray(xc),
            pseudo,
        )
        xp, yp, xs_j, xc_j, evp, mask, noisy = args
        theta = jnp.asarray(theta, dtype=jnp.float64)
        chol, alpha, loo_scaled, fit_scaled, nlml = _posterior(theta, *args, self.basis)
        if not bool(jnp.all(jnp.isfinite(chol))):
            raise ConvergenceError(
                "the kernel matrix at the selected hyperparameters is not positive definite."
            )
        self.state_ = GPState(
            theta=theta,
            x=xp,
            alpha=alpha,
            chol=chol,
            x_scale=xs_j,
            x_center=xc_j,
            y_scale=jnp.asarray(float(ys)),
            mask=mask,
            noisy=noisy,
            monomials=self.basis,
        )
        # padded copies (sampling) and the raw training set (persistence, baselines)
        self._padded = {"y": yp, "extra_var": evp}
        self._errors: dict[str, Any] | None = None
        self.x_train_ = np.asarray(xa, dtype=float)
        self.y_train_ = np.asarray(ys_scaled, dtype=float) * float(ys)
        self.extra_var_ = np.asarray(ev_scaled, dtype=float)
        self.pseudo_ = np.asarray(pseudo, dtype=bool)
        # diagnostics in raw units, over the measurements
        meas = ~self.pseudo_
        loo_resid = np.asarray(loo_scaled)[:n][meas] * ys
        self.loo_rmse_ = float(np.sqrt(np.mean(loo_resid**2)))
        resid = (np.asarray(fit_scaled)[:n] - np.asarray(ys_scaled))[meas] * ys
        self.train_rmse_ = float(np.sqrt(np.mean(resid**2)))
        self.log_marginal_likelihood_ = -float(nlml) - int(meas.sum()) * math.log(ys)

    # ------------------------------------------------------------------ accessors
    def _check(self) -> None:
        if not hasattr(self, "state_"):
            raise NotFittedError("this GPRegressor is not fitted yet; call fit(X, y) first.")

    @property
    def hyperparameters_(self) -> dict[str, Any]:
        """Hyperparameters in raw units (length scales in input units)."""
        self._check()
        st = self.state_
        d = st.n_dim
        log_s, log_l, log_t, log_n = _split(st.theta, d, len(self.basis))
        ys = float(st.y_scale)
        return {
            "signal_std": float(jnp.exp(log_s)) * ys,
            "length_scales": (np.exp(np.asarray(log_l)) * np.asarray(st.x_scale)).tolist(),
            "basis_std": (np.exp(np.asarray(log_t)) * ys).tolist(),
            "noise_std": float(jnp.exp(log_n)) * ys,
        }

    @property
    def hyperparameter_errors_(self) -> dict[str, Any]:
        """Standard errors of :attr:`hyperparameters_` (same keys, raw units).

        Laplace approximation of the marginal likelihood at the selected hyperparameters
        (R&W §5.4.1, :func:`laplace_log_errors` of ``-log p(y | X, θ)``, eq. 5.8), carried
        to raw units by the delta method (``σ_raw = value · σ_log``). With
        ``criterion="loo"`` the curvature is still the marginal likelihood's (an
        approximation: the selected θ is not its maximum).
        """
        self._check()
        if self._errors is None:  # once per fit: ``summary()`` and ``save`` both ask
            self._errors = self._laplace_errors()
        return self._errors

    def _laplace_errors(self) -> dict[str, Any]:
        st = self.state_
        d, m = st.n_dim, len(self.basis)
        theta = np.asarray(st.theta, dtype=float)
        spacing = input_spacing(self.x_train_ / np.asarray(st.x_scale), self.pseudo_)
        _, lo, hi = self._layout(d, spacing)
        grad = _objective(self.basis, "ml", bool(self.pseudo_.any()))
        args = (st.x, self._padded["y"], st.x_scale, st.x_center, self._padded["extra_var"])
        se_log = laplace_log_errors(lambda th: grad(th, *args, st.mask, st.noisy)[1], theta, lo, hi)
        raw = self.hyperparameters_
        se = se_log * np.concatenate(
            [
                [raw["signal_std"]],
                raw["length_scales"],
                raw["basis_std"],
                [raw["noise_std"]],
            ]
        )
        return {
            "signal_std": float(se[0]),
            "length_scales": se[1 : 1 + d].tolist(),
            "basis_std": se[1 + d : 1 + d + m].tolist(),
            "noise_std": float(se[1 + d + m]),
        }

    def predict(self, X: Any, *, return_std: bool = False) -> np.ndarray | tuple[np.ndarray, ...]:
        """Posterior mean (and latent standard deviation) at ``X`` (N, D)."""
        self._check()
        xa = np.asarray(X, dtype=float)
        if xa.ndim == 1:
            xa = xa[:, None] if self.state_.n_dim == 1 else xa[None, :]
        if xa.ndim != 2 or xa.shape[1] != self.state_.n_dim:
            raise BifidInputError(f"X must have shape (N, {self.state_.n_dim}), got {np.shape(X)}.")
        mu = np.asarray(_jit_mean(self.state_, jnp.asarray(xa)))
        if not return_std:
            return mu
        var = np.asarray(_jit_var(self.state_, jnp.asarray(xa)))
        return mu, np.sqrt(var)

    def sample_functions(
        self, n_samples: int, *, seed: int = 0, n_features: int = 1024
    ) -> GPSamples:
        """Draw posterior function samples by pathwise conditioning (see module docstring).

        Parameters
        ----------
        n_samples : int
        seed : int
        n_features : int
            Random Fourier features of the prior sample (accuracy of its covariance
            ~ 1/sqrt(n_features)).
        """
        self._check()
        if n_samples < 1 or n_features < 1:
            raise BifidInputError("n_samples and n_features must be positive.")
        return _draw_samples(
            self.state_,
            self._padded["y"],
            self._padded["extra_var"],
            jax.random.PRNGKey(seed),
            int(n_samples),
            int(n_features),
        )

    # ------------------------------------------------------------------ persistence
    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """Arrays that :meth:`from_arrays` needs (numeric only, for ``.npz``)."""
        self._check()
        st = self.state_
        return {
            f"{prefix}theta": np.asarray(st.theta),
            f"{prefix}x": self.x_train_,
            f"{prefix}y": self.y_train_ / float(st.y_scale),
            f"{prefix}extra_var": self.extra_var_,
            f"{prefix}pseudo": self.pseudo_.astype(float),
            f"{prefix}x_scale": np.asarray(st.x_scale),
            f"{prefix}x_center": np.asarray(st.x_center),
            f"{prefix}y_scale": np.asarray(st.y_scale),
            f"{prefix}basis": np.asarray(self.basis, dtype=np.int64).reshape(
                len(self.basis), st.n_dim
            ),
        }

    def get_params(self) -> dict[str, Any]:
        """Constructor hyperparameters (JSON-able)."""
        return {
            "basis": [list(m) for m in self.basis],
            "basis_center": None if self.basis_center is None else list(self.basis_center),
            "criterion": self.criterion,
            "n_restarts": self.n_restarts,
            "bounds": {
                k: list(getattr(self.bounds, k))
                for k in ("length_scale", "signal", "basis", "noise")
            },
            "length_scale_init": self.length_scale_init,
            "noise_init": self.noise_init,
            "fixed_length_scales": None
            if self.fixed_length_scales is None
            else list(self.fixed_length_scales),
            "seed": self.seed,
        }

    @classmethod
    def from_arrays(
        cls, params: dict[str, Any], arrays: dict[str, np.ndarray], prefix: str
    ) -> GPRegressor:
        """Rebuild a fitted regressor from :meth:`get_params` and :meth:`to_arrays` output."""
        try:
            bounds = HyperBounds(**{k: tuple(v) for k, v in params["bounds"].items()})
            gp = cls(
                basis=tuple(tuple(int(e) for e in m) for m in params["basis"]),
                basis_center=params["basis_center"],
                criterion=params["criterion"],
                n_restarts=int(params["n_restarts"]),
                bounds=bounds,
                length_scale_init=float(params["length_scale_init"]),
                noise_init=float(params["noise_init"]),
                fixed_length_scales=params["fixed_length_scales"],
                seed=int(params["seed"]),
            )
            a = {
                k: np.asarray(arrays[prefix + k], dtype=float)
                for k in ("theta", "x", "y", "extra_var", "x_scale", "x_center", "y_scale")
            }
        except (KeyError, TypeError, ValueError) as exc:
            raise BifidInputError(
                f"malformed GP record {prefix!r} in the model file: {exc}"
            ) from None
        basis_arr = np.asarray(arrays.get(prefix + "basis", np.zeros((0, 0))))
        if basis_arr.size and [list(map(int, r)) for r in basis_arr] != [list(m) for m in gp.basis]:
            raise BifidInputError(f"GP record {prefix!r}: basis arrays and parameters disagree.")
        n, d = a["x"].shape if a["x"].ndim == 2 else (0, 0)
        if (
            n < 1
            or a["y"].shape != (n,)
            or a["theta"].shape != (2 + d + len(gp.basis),)
            or a["extra_var"].shape != (n,)
            or a["x_scale"].shape != (d,)
            or a["x_center"].shape != (d,)
            or a["y_scale"].size != 1
        ):
            raise BifidInputError(f"GP record {prefix!r}: inconsistent array shapes.")
        if not (
            all(np.all(np.isfinite(v)) for v in a.values())
            and np.all(a["x_scale"] > 0)
            and float(a["y_scale"].reshape(-1)[0]) > 0
            and np.all(a["extra_var"] >= 0)
        ):
            raise BifidInputError(f"GP record {prefix!r}: non-finite or out-of-range values.")
        # files written before pseudo-observations were marked: every point is measured
        pseudo = np.asarray(arrays.get(prefix + "pseudo", np.zeros(n)), dtype=float)
        if pseudo.shape != (n,):
            raise BifidInputError(f"GP record {prefix!r}: inconsistent array shapes.")
        gp._set_state(
            a["theta"],
            a["x"],
            a["y"],
            a["extra_var"],
            a["x_scale"],
            a["x_center"],
            float(a["y_scale"].reshape(-1)[0]),
            pseudo > 0.5,
        )
        gp.notes_ = []
        gp.n_train_ = n
        gp.objective_ = float("nan")
        return gp


_jit_mean = jax.jit(gp_mean)
_jit_var = jax.jit(gp_var)
