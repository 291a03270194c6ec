r"""Gaussian-process (kernel ridge) regression with squared-exponential ARD kernels.

The regression model of thesis §6.2.3 (eqs. 6.16–6.18) is kernel ridge regression,
``f(x) = Σ_j α_j k(x, x_j)`` with ``α = (K + nλ I)^{-1} y``; it is the posterior mean of a
Gaussian process with noise variance ``σ_n² = nλ``. We use the GP reading because it gives
what kernel ridge regression lacks: a criterion for the hyperparameters that does not
reward over-fitting, and a predictive distribution.

Model
-----
With inputs scaled per dimension, ``u = x / s`` (``s`` = spread of the training inputs),

.. math::

    k(x, x') = σ² \exp\Big(-\tfrac12 \sum_d \frac{(u_d - u'_d)^2}{\ell_d^2}\Big)
               + \sum_m τ_m^2\, h_m(x)\, h_m(x'),
    \qquad y_i = f(x_i) + ε_i,\; ε_i \sim N(0, σ_n^2 + v_i),

a squared-exponential kernel with automatic relevance determination (one length scale
``ℓ_d`` per input; thesis §6.3.1, Rasmussen & Williams [81] §5.1) plus explicit basis
functions ``h_m`` (monomials of the centred, scaled inputs) whose coefficients have Gaussian
priors ``N(0, τ_m²)`` — the GP with explicit basis functions of Rasmussen & Williams §2.7.
The basis carries the known structure (e.g. ``a(ρ) ≈ α₁ρ + α₃ρ³``, eq. 6.9) so that
predictions *extrapolate* like the physics instead of decaying to zero; ``v_i`` are
known extra variances per point (pseudo-observations). A relative jitter of
``1e-10 × mean(diag K)`` is added to the noise so ``K_y`` stays positive definite at extreme
hyperparameters.

Targets are divided by their RMS (not centred, so odd bases stay odd).

Hyperparameters ``θ = (log σ, log ℓ_1..D, log τ_1..M, log σ_n)`` live in log space with
box bounds and are chosen by L-BFGS-B (``scipy.optimize``, gradients by JAX) minimising
either

* ``"ml"`` — the negative log marginal likelihood
  ``½ yᵀK_y⁻¹y + ½ log|K_y| + n/2 log 2π`` (R&W eq. 5.8), or
* ``"loo"`` — the closed-form leave-one-out negative log predictive probability
  ``Σ_i ½ log σ_i² + (y_i − μ_i)²/(2σ_i²)`` with ``μ_i = y_i − [K_y⁻¹y]_i/[K_y⁻¹]_ii`` and
  ``σ_i² = 1/[K_y⁻¹]_ii`` (R&W eqs. 5.10–5.12),

never the training loss (which the thesis's eq. 6.16 minimises and which rewards
interpolating noise). Random restarts are seeded.

Posterior: mean ``μ(x) = k(x, X) α`` with ``α = K_y⁻¹ y`` and latent variance
``k(x, x) − k(x, X) K_y⁻¹ k(X, x)``. :class:`GPState` is an equinox module holding
the precomputed arrays, so the mean and its derivatives are cheap, pure JAX functions
usable inside jitted Newton solvers and continuation.

Posterior *functions* (not only values at points) are drawn by pathwise conditioning
(Wilson et al., ICML 2020): a prior sample ``f̃`` is built from random Fourier features of
the SE kernel (``ω ~ N(0, ℓ⁻²)``, R features) plus basis coefficients ``β ~ N(0, τ²)``, and
updated by ``f(x) = f̃(x) + k(x, X) K_y⁻¹ (y − f̃(X) − ε)``, ``ε ~ N(0, σ_n² + v)``. Each
sample is a smooth function that can be continued like the mean — this is what puts an
uncertainty band around predicted bifurcation curves.

Compilation: training sets are padded to a few bucket sizes with masked rows (exactly
neutral: padded rows/columns of ``K_y`` are those of the identity and the targets 0), so the
objective compiles once per (bucket, basis, criterion), not once per data size. The fitted
:class:`GPState` keeps the padding (``mask``; ``α`` is exactly 0 on padded rows), so every
jitted function of a fitted model (means, variances, samples, and the continuation and
Newton solvers built on them) also compiles once per bucket.

Why not tinygp
--------------
tinygp (installed) provides the same kernels and ``GaussianProcess.log_probability``; our
tests check the marginal likelihood against it. The core is not built on it because it
lacks three things this module needs: the closed-form leave-one-out criterion (needs the
diagonal of ``K_y⁻¹``), posterior *function* samples that can be evaluated anywhere and
differentiated (tinygp samples at fixed points only), and a precomputed posterior mean that
a Newton/continuation loop can evaluate without refactorising ``K_y`` at every call.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize

from bifid.errors import BifidInputError, ConvergenceError, NotFittedError

Array = jnp.ndarray
_JITTER = 1e-10  # relative diagonal jitter of K_y (times the mean prior variance)
Monomials = tuple[tuple[int, ...], ...]
Criterion = Literal["ml", "loo"]

__all__ = [
    "GPRegressor",
    "GPSamples",
    "GPState",
    "HyperBounds",
    "basis_matrix",
    "gp_mean",
    "gp_var",
    "minimize_multistart",
    "neg_log_marginal_likelihood",
    "padded_args",
    "sample_eval",
]


# ---------------------------------------------------------------------------------------------
# pure functions
# ---------------------------------------------------------------------------------------------


def basis_matrix(ub: Array, monomials: Monomials) -> Array:
    """Monomial basis ``h_m(u) = Π_d u_d^{e_md}`` of centred scaled inputs ``ub`` (n, D).

    Exponents are static Python ints so derivatives are exact everywhere (also at 0).
    """
    n = ub.shape[0]
    cols = []
    for m in monomials:
        col = jnp.ones((n,), dtype=ub.dtype)
        for d, e in enumerate(m):
            if e:
                col = col * ub[:, d] ** int(e)
        cols.append(col)
    if not cols:
        return jnp.zeros((n, 0), dtype=ub.dtype)
    return jnp.stack(cols, axis=1)


def _split(theta: Array, n_dim: int, n_basis: int) -> tuple[Array, Array, Array, Array]:
    log_s = theta[0]
    log_l = theta[1 : 1 + n_dim]
    log_t = theta[1 + n_dim : 1 + n_dim + n_basis]
    log_n = theta[1 + n_dim + n_basis]
    return log_s, log_l, log_t, log_n


def _cov(
    theta: Array,
    x1: Array,
    x2: Array,
    x_scale: Array,
    x_center: Array,
    monomials: Monomials,
) -> Array:
    """Prior covariance ``k(x1, x2)`` (noise excluded), inputs in raw units."""
    n_dim = x1.shape[1]
    log_s, log_l, log_t, _ = _split(theta, n_dim, len(monomials))
    ls = x_scale * jnp.exp(log_l)
    d = (x1[:, None, :] - x2[None, :, :]) / ls
    k = jnp.exp(2.0 * log_s) * jnp.exp(-0.5 * jnp.sum(d * d, axis=-1))
    if monomials:
        h1 = basis_matrix((x1 - x_center) / x_scale, monomials)
        h2 = basis_matrix((x2 - x_center) / x_scale, monomials)
        k = k + (h1 * jnp.exp(2.0 * log_t)) @ h2.T
    return k


def _kdiag(theta: Array, x: Array, x_scale: Array, x_center: Array, monomials: Monomials):
    n_dim = x.shape[1]
    log_s, _, log_t, _ = _split(theta, n_dim, len(monomials))
    out = jnp.full((x.shape[0],), jnp.exp(2.0 * log_s))
    if monomials:
        h = basis_matrix((x - x_center) / x_scale, monomials)
        out = out + jnp.sum(h * h * jnp.exp(2.0 * log_t), axis=1)
    return out


def _masked_ky(theta, x, mask, extra_var, x_scale, x_center, monomials):
    """``K_y`` of the padded set: real block as usual, padded block the identity."""
    n_dim = x.shape[1]
    log_n = _split(theta, n_dim, len(monomials))[3]
    k = _cov(theta, x, x, x_scale, x_center, monomials)
    mm = mask[:, None] * mask[None, :]
    # relative jitter keeps K_y numerically positive definite at extreme hyperparameters
    jitter = _JITTER * jnp.sum(jnp.diag(k) * mask) / jnp.maximum(jnp.sum(mask), 1.0)
    noise = jnp.exp(2.0 * log_n) + extra_var + jitter
    return k * mm + jnp.diag(jnp.where(mask > 0, noise, 1.0))


@jax.custom_vjp
def _logdet_spd(k: Array) -> Array:
    """``log|K|`` of a symmetric positive definite matrix (Cholesky)."""
    return 2.0 * jnp.sum(jnp.log(jnp.diag(jnp.linalg.cholesky(k))))


def _logdet_fwd(k):
    chol = jnp.linalg.cholesky(k)
    kinv = jax.scipy.linalg.cho_solve((chol, True), jnp.eye(k.shape[0], dtype=k.dtype))
    return 2.0 * jnp.sum(jnp.log(jnp.diag(chol))), kinv


def _logdet_bwd(kinv, g):
    return (g * kinv,)


_logdet_spd.defvjp(_logdet_fwd, _logdet_bwd)


@jax.custom_vjp
def _inv_spd(k: Array) -> Array:
    """``K⁻¹`` of a symmetric positive definite matrix (Cholesky).

    Custom derivative ``d(K⁻¹) = −K⁻¹ dK K⁻¹``: JAX's generic Cholesky derivative costs
    ~100× the factorisation on CPU for the small matrices used here.
    """
    chol = jnp.linalg.cholesky(k)
    return jax.scipy.linalg.cho_solve((chol, True), jnp.eye(k.shape[0], dtype=k.dtype))


def _inv_fwd(k):
    kinv = _inv_spd(k)
    return kinv, kinv


def _inv_bwd(kinv, g):
    return (-kinv @ g @ kinv,)


_inv_spd.defvjp(_inv_fwd, _inv_bwd)


def neg_log_marginal_likelihood(
    theta: Array,
    x: Array,
    y: Array,
    x_scale: Array,
    x_center: Array,
    monomials: Monomials = (),
    extra_var: Array | None = None,
    mask: Array | None = None,
) -> Array:
    """``-log p(y | X, θ)`` of the (scaled) targets ``y`` (R&W eq. 5.8)."""
    mask = jnp.ones(x.shape[0]) if mask is None else mask
    extra_var = jnp.zeros(x.shape[0]) if extra_var is None else extra_var
    ky = _masked_ky(theta, x, mask, extra_var, x_scale, x_center, monomials)
    ym = y * mask
    n_eff = jnp.sum(mask)
    return (
        0.5 * ym @ (_inv_spd(ky) @ ym)
        + 0.5 * _logdet_spd(ky)
        + 0.5 * n_eff * jnp.log(2.0 * jnp.pi)
    )


def _loo_objective(theta, x, y, x_scale, x_center, monomials, extra_var, mask):
    """Closed-form leave-one-out negative log predictive probability (R&W eq. 5.10–5.12)."""
    ky = _masked_ky(theta, x, mask, extra_var, x_scale, x_center, monomials)
    kinv = _inv_spd(ky)
    alpha = kinv @ (y * mask)
    dinv = jnp.diag(kinv)
    var = 1.0 / dinv
    resid = alpha / dinv
    terms = 0.5 * jnp.log(var) + 0.5 * resid**2 / var + 0.5 * jnp.log(2.0 * jnp.pi)
    return jnp.sum(terms * mask)


@functools.lru_cache(maxsize=64)
def _objective(monomials: Monomials, criterion: str):
    if criterion == "ml":

        def f(theta, x, y, x_scale, x_center, extra_var, mask):
            return neg_log_marginal_likelihood(
                theta, x, y, x_scale, x_center, monomials, extra_var, mask
            )
    else:

        def f(theta, x, y, x_scale, x_center, extra_var, mask):
            return _loo_objective(theta, x, y, x_scale, x_center, monomials, extra_var, mask)

    return jax.jit(jax.value_and_grad(f))


def _bucket(n: int) -> int:
    """Padded size: 16, 32, 48, 64, then steps of an eighth of the power of two below."""
    if n <= 16:
        return 16
    step = max(16, 2 ** (math.floor(math.log2(n)) - 3))
    return int(math.ceil(n / step) * step)


# ---------------------------------------------------------------------------------------------
# fitted state (pure JAX evaluation)
# ---------------------------------------------------------------------------------------------


class GPState(eqx.Module):
    """Everything needed to evaluate a fitted GP posterior; a JAX pytree.

    Attributes are arrays in raw (unscaled) input units; ``y_scale`` multiplies the
    scaled outputs back; ``monomials`` is static (part of the tree structure).

    The training set is padded to a bucket size (:func:`padded_args`): ``mask`` is 1 on
    real rows and 0 on padded ones, whose ``alpha`` entries are exactly 0 and whose block
    of ``chol`` is the identity. Every function of the state compiles once per bucket,
    not once per training-set size.
    """

    theta: Array
    x: Array
    alpha: Array
    chol: Array
    x_scale: Array
    x_center: Array
    y_scale: Array
    mask: Array
    monomials: Monomials = eqx.field(static=True)

    @property
    def n_dim(self) -> int:
        return int(self.x.shape[1])


def gp_mean(state: GPState, x: Array) -> Array:
    """Posterior mean at ``x`` of shape (N, D) (or (D,) for one point → scalar)."""
    single = x.ndim == 1
    xx = x[None, :] if single else x
    ks = _cov(state.theta, xx, state.x, state.x_scale, state.x_center, state.monomials)
    out = (ks @ state.alpha) * state.y_scale
    return out[0] if single else out


def gp_var(state: GPState, x: Array, *, include_noise: bool = False) -> Array:
    """Posterior variance of the latent function (plus the noise if asked) at ``x``."""
    single = x.ndim == 1
    xx = x[None, :] if single else x
    ks = _cov(state.theta, xx, state.x, state.x_scale, state.x_center, state.monomials)
    ks = ks * state.mask[None, :]
    v = jax.scipy.linalg.solve_triangular(state.chol, ks.T, lower=True)
    kss = _kdiag(state.theta, xx, state.x_scale, state.x_center, state.monomials)
    var = jnp.maximum(kss - jnp.sum(v * v, axis=0), 0.0)
    if include_noise:
        n_dim = xx.shape[1]
        var = var + jnp.exp(2.0 * _split(state.theta, n_dim, len(state.monomials))[3])
    out = var * state.y_scale**2
    return out[0] if single else out


class GPSamples(eqx.Module):
    """Posterior function samples (pathwise conditioning); leading axis = sample.

    ``freq`` (S, R, D) random frequencies in scaled-input units already divided by the
    length scales, ``phase`` (S, R), ``weight`` (S, R) (includes σ√(2/R)), ``beta`` (S, M)
    basis coefficients (include τ), ``v`` (S, n) update weights ``K_y⁻¹(y − f̃(X) − ε)``.
    """

    freq: Array
    phase: Array
    weight: Array
    beta: Array
    v: Array

    @property
    def n_samples(self) -> int:
        return int(self.freq.shape[0])


def _prior_sample_eval(state: GPState, freq, phase, weight, beta, x: Array) -> Array:
    u = x / state.x_scale
    out = jnp.cos(u @ freq.T + phase) @ weight
    if state.monomials:
        h = basis_matrix((x - state.x_center) / state.x_scale, state.monomials)
        out = out + h @ beta
    return out


def sample_eval(state: GPState, sample: GPSamples, x: Array) -> Array:
    """Evaluate ONE posterior sample (leaves without the sample axis) at ``x`` (N, D) or (D,).

    Use ``jax.vmap(sample_eval, in_axes=(None, 0, None))`` to evaluate all samples.
    """
    single = x.ndim == 1
    xx = x[None, :] if single else x
    prior = _prior_sample_eval(state, sample.freq, sample.phase, sample.weight, sample.beta, xx)
    ks = _cov(state.theta, xx, state.x, state.x_scale, state.x_center, state.monomials)
    out = (prior + ks @ sample.v) * state.y_scale
    return out[0] if single else out


@functools.partial(jax.jit, static_argnames=("monomials",))
def _posterior(theta, x, y, x_scale, x_center, extra_var, mask, monomials):
    """Cholesky factor, ``α = K_y⁻¹y``, LOO residuals, fitted values and ``-log p(y)``
    of a padded training set (one compiled program per bucket and basis)."""
    ky = _masked_ky(theta, x, mask, extra_var, x_scale, x_center, monomials)
    chol = jnp.linalg.cholesky(ky)
    alpha = jax.scipy.linalg.cho_solve((chol, True), y * mask)
    kinv_diag = jnp.diag(jax.scipy.linalg.cho_solve((chol, True),
                                                    jnp.eye(x.shape[0], dtype=x.dtype)))
    loo = alpha / kinv_diag
    fit = _cov(theta, x, x, x_scale, x_center, monomials) @ alpha
    n_eff = jnp.sum(mask)
    nlml = (0.5 * (y * mask) @ alpha + jnp.sum(jnp.log(jnp.diag(chol)))
            + 0.5 * n_eff * jnp.log(2.0 * jnp.pi))
    return chol, alpha, loo, fit, nlml


@functools.partial(jax.jit, static_argnames=("n_samples", "n_features"))
def _draw_samples(state: GPState, y_scaled, extra_var, key, n_samples: int,
                  n_features: int) -> GPSamples:
    """Pathwise-conditioned posterior function samples (module docstring)."""
    d = state.n_dim
    m = len(state.monomials)
    log_s, log_l, log_t, log_n = _split(state.theta, d, m)
    k1, k2, k3, k4, k5 = jax.random.split(key, 5)
    freq = jax.random.normal(k1, (n_samples, n_features, d)) / jnp.exp(log_l)
    phase = jax.random.uniform(k2, (n_samples, n_features), maxval=2.0 * jnp.pi)
    weight = (jax.random.normal(k3, (n_samples, n_features))
              * jnp.exp(log_s) * jnp.sqrt(2.0 / n_features))
    beta = jax.random.normal(k4, (n_samples, m)) * jnp.exp(log_t)
    noise_sd = jnp.sqrt(jnp.exp(2.0 * log_n) + extra_var)
    eps = jax.random.normal(k5, (n_samples, state.x.shape[0])) * noise_sd
    prior_at_x = jax.vmap(
        lambda f, p, w, b: _prior_sample_eval(state, f, p, w, b, state.x)
    )(freq, phase, weight, beta)
    resid = (y_scaled[None, :] - prior_at_x - eps) * state.mask[None, :]
    v = jax.scipy.linalg.cho_solve((state.chol, True), resid.T).T
    return GPSamples(freq=freq, phase=phase, weight=weight, beta=beta, v=v)


# ---------------------------------------------------------------------------------------------
# the estimator
# ---------------------------------------------------------------------------------------------


def padded_args(
    x: np.ndarray, y_scaled: np.ndarray, extra_var_scaled: np.ndarray, x_scale: np.ndarray,
    x_center: np.ndarray,
) -> tuple[Array, ...]:
    """``(x, y, x_scale, x_center, extra_var, mask)`` padded to a bucket size.

    Padded rows are masked: their block of ``K_y`` is the identity and their targets 0,
    which leaves the marginal likelihood, the LOO criterion and their gradients unchanged.
    """
    n, d = x.shape
    n_pad = _bucket(n)
    xp = np.zeros((n_pad, d))
    xp[:n] = x
    xp[n:] = x[0]
    yp = np.zeros(n_pad)
    yp[:n] = y_scaled
    evp = np.zeros(n_pad)
    evp[:n] = extra_var_scaled
    mask = np.zeros(n_pad)
    mask[:n] = 1.0
    return tuple(jnp.asarray(a) for a in (xp, yp, x_scale, x_center, evp, mask))


def minimize_multistart(
    value_and_grad: Any,
    theta0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    *,
    n_restarts: int = 0,
    seed: int = 0,
    maxiter: int = 300,
    ftol: float = 1e-8,
) -> scipy.optimize.OptimizeResult:
    """L-BFGS-B from ``theta0`` and ``n_restarts`` seeded random starts; the best result.

    ``value_and_grad(theta) -> (value, grad)`` (JAX arrays are fine); ``ftol`` is
    L-BFGS-B's relative tolerance on the objective. Non-finite values
    are reported to the optimiser as a huge value (it then shortens the step).

    Raises
    ------
    ConvergenceError
        If every start ends without a finite objective.
    """

    def fun(th: np.ndarray) -> tuple[float, np.ndarray]:
        v, g = value_and_grad(th)
        v = float(v)
        g = np.asarray(g, dtype=float)
        if not (math.isfinite(v) and np.all(np.isfinite(g))):
            return 1e25, np.zeros_like(th)
        return v, g

    rng = np.random.default_rng(seed)
    starts = [np.clip(np.asarray(theta0, dtype=float), lo, hi)]
    mid_lo = np.maximum(lo, starts[0] - 1.5)
    mid_hi = np.minimum(hi, starts[0] + 1.5)
    for _ in range(max(0, int(n_restarts))):
        starts.append(rng.uniform(mid_lo, mid_hi))
    best = None
    nfev = 0
    for th0 in starts:
        res = scipy.optimize.minimize(
            fun, th0, jac=True, method="L-BFGS-B", bounds=list(zip(lo, hi, strict=True)),
            options={"maxiter": maxiter, "ftol": ftol},
        )
        nfev += int(res.nfev)
        if math.isfinite(res.fun) and res.fun < 1e24 and (best is None or res.fun < best.fun):
            best = res
    if best is None:
        raise ConvergenceError(
            "GP hyperparameter optimisation failed from every start (the kernel matrix "
            "was never positive definite); check the data for duplicates or outliers."
        )
    best.nfev_total = nfev
    return best


@dataclass(frozen=True)
class HyperBounds:
    """Box bounds of the hyperparameters (not logs), relative to the scaled data.

    ``length_scale`` in units of the input spread, ``signal``/``basis``/``noise`` in units
    of the RMS of the targets.
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
            raise BifidInputError(
                f"criterion must be 'ml' or 'loo', got {self.criterion!r}."
            )
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
    def _layout(self, d: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Initial θ and log-bounds (lo, hi) for D inputs."""
        b = self.bounds
        m = len(self.basis)
        theta0 = np.concatenate([
            [0.0],
            np.full(d, math.log(self.length_scale_init)),
            np.zeros(m),
            [math.log(self.noise_init)],
        ])
        lo = np.concatenate([
            [math.log(b.signal[0])], np.full(d, math.log(b.length_scale[0])),
            np.full(m, math.log(b.basis[0])), [math.log(b.noise[0])],
        ])
        hi = np.concatenate([
            [math.log(b.signal[1])], np.full(d, math.log(b.length_scale[1])),
            np.full(m, math.log(b.basis[1])), [math.log(b.noise[1])],
        ])
        theta0 = np.clip(theta0, lo, hi)
        return theta0, lo, hi

    def prepare(
        self, X: Any, y: Any, *, extra_var: Any = None, x_scale: Any = None,
        y_scale: float | None = None,
    ) -> dict[str, Any]:
        """Validate and scale the data; the initial ``θ`` and its log-bounds.

        Used by :meth:`fit` and by callers that optimise ``θ`` jointly with other
        quantities (e.g. a forcing scale in the targets) before calling
        ``fit(..., theta=...)``. Returns a dict with ``x``, ``y``, ``extra_var`` (raw),
        ``x_scale``, ``x_center``, ``y_scale``, ``theta0``, ``lo``, ``hi``, ``notes``.
        """
        xa, ya, ev = self._validate(X, y, extra_var)
        d = xa.shape[1]
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
            xc = np.array([xa[:, i].mean() if c is None else float(c)
                           for i, c in enumerate(self.basis_center)])
        ys = float(np.sqrt(np.mean(ya**2))) if y_scale is None else float(y_scale)
        if not (ys > 0 and math.isfinite(ys)):
            ys = 1.0
            notes.append("all targets are zero; y_scale set to 1")
        theta0, lo, hi = self._layout(d)
        fixed = [None] * d if self.fixed_length_scales is None else list(self.fixed_length_scales)
        for i in range(d):
            if constant[i] and fixed[i] is None:
                fixed[i] = self.bounds.length_scale[1]
                notes.append(f"input {i} is constant in the data: its length scale is held at "
                             f"the upper bound {self.bounds.length_scale[1]:g}")
            if fixed[i] is not None:
                v = math.log(float(fixed[i]))
                theta0[1 + i] = lo[1 + i] = hi[1 + i] = v
        return {"x": xa, "y": ya, "extra_var": ev, "x_scale": xs, "x_center": xc,
                "y_scale": ys, "theta0": theta0, "lo": lo, "hi": hi, "notes": notes}

    def fit(
        self,
        X: Any,
        y: Any,
        *,
        extra_var: Any = None,
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
            Known extra noise variance per point (raw units), e.g. tiny for
            pseudo-observations.
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
        prep = self.prepare(X, y, extra_var=extra_var, x_scale=x_scale, y_scale=y_scale)
        xa, ya, ev = prep["x"], prep["y"], prep["extra_var"]
        xs, xc, ys = prep["x_scale"], prep["x_center"], prep["y_scale"]
        n = xa.shape[0]
        if theta is not None:
            th = np.asarray(theta, dtype=float).reshape(-1)
            if th.shape != prep["theta0"].shape or not np.all(np.isfinite(th)):
                raise BifidInputError(
                    f"theta must be {prep['theta0'].shape[0]} finite values, got {th.shape}."
                )
            self._set_state(th, xa, ya / ys, ev / ys**2, xs, xc, ys)
            self.objective_ = float("nan")
            self.n_evaluations_ = 0
            self.optimizer_message_ = "hyperparameters given"
            self.notes_ = prep["notes"]
            self.n_train_ = n
            return self
        args = padded_args(xa, ya / ys, ev / ys**2, xs, xc)
        vg = _objective(self.basis, self.criterion)
        best = minimize_multistart(
            lambda th: vg(jnp.asarray(th), *args), prep["theta0"], prep["lo"], prep["hi"],
            n_restarts=self.n_restarts, seed=self.seed,
        )
        self._set_state(best.x, xa, ya / ys, ev / ys**2, xs, xc, ys)
        self.objective_ = float(best.fun)
        self.n_evaluations_ = int(best.nfev_total)
        self.optimizer_message_ = str(best.message)
        self.notes_ = prep["notes"]
        self.n_train_ = n
        return self

    def _set_state(self, theta, xa, ys_scaled, ev_scaled, xs, xc, ys) -> None:
        n = xa.shape[0]
        args = padded_args(np.asarray(xa), np.asarray(ys_scaled), np.asarray(ev_scaled),
                           np.asarray(xs), np.asarray(xc))
        xp, yp, xs_j, xc_j, evp, mask = args
        theta = jnp.asarray(theta, dtype=jnp.float64)
        chol, alpha, loo_scaled, fit_scaled, nlml = _posterior(theta, *args, self.basis)
        if not bool(jnp.all(jnp.isfinite(chol))):
            raise ConvergenceError(
                "the kernel matrix at the selected hyperparameters is not positive definite."
            )
        self.state_ = GPState(
            theta=theta, x=xp, alpha=alpha, chol=chol, x_scale=xs_j, x_center=xc_j,
            y_scale=jnp.asarray(float(ys)), mask=mask, monomials=self.basis,
        )
        # padded copies (sampling) and the raw training set (persistence, baselines)
        self._padded = {"y": yp, "extra_var": evp}
        self.x_train_ = np.asarray(xa, dtype=float)
        self.y_train_ = np.asarray(ys_scaled, dtype=float) * float(ys)
        self.extra_var_ = np.asarray(ev_scaled, dtype=float)
        # diagnostics in raw units
        loo_resid = np.asarray(loo_scaled)[:n] * ys
        self.loo_rmse_ = float(np.sqrt(np.mean(loo_resid**2)))
        resid = (np.asarray(fit_scaled)[:n] - np.asarray(ys_scaled)) * ys
        self.train_rmse_ = float(np.sqrt(np.mean(resid**2)))
        self.log_marginal_likelihood_ = -float(nlml) - n * math.log(ys)

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

    def predict(self, X: Any, *, return_std: bool = False) -> np.ndarray | tuple[np.ndarray, ...]:
        """Posterior mean (and latent standard deviation) at ``X`` (N, D)."""
        self._check()
        xa = np.asarray(X, dtype=float)
        if xa.ndim == 1:
            xa = xa[:, None] if self.state_.n_dim == 1 else xa[None, :]
        if xa.ndim != 2 or xa.shape[1] != self.state_.n_dim:
            raise BifidInputError(
                f"X must have shape (N, {self.state_.n_dim}), got {np.shape(X)}."
            )
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
        return _draw_samples(self.state_, self._padded["y"], self._padded["extra_var"],
                             jax.random.PRNGKey(seed), int(n_samples), int(n_features))

    # ------------------------------------------------------------------ persistence
    def to_arrays(self, prefix: str) -> dict[str, np.ndarray]:
        """Arrays that :meth:`from_arrays` needs (numeric only, for ``.npz``)."""
        self._check()
        st = self.state_
        return {
            f"{prefix}theta": np.asarray(st.theta), f"{prefix}x": self.x_train_,
            f"{prefix}y": self.y_train_ / float(st.y_scale), f"{prefix}extra_var":
            self.extra_var_, f"{prefix}x_scale": np.asarray(st.x_scale),
            f"{prefix}x_center": np.asarray(st.x_center),
            f"{prefix}y_scale": np.asarray(st.y_scale),
            f"{prefix}basis": np.asarray(self.basis, dtype=np.int64).reshape(
                len(self.basis), st.n_dim),
        }

    def get_params(self) -> dict[str, Any]:
        """Constructor hyperparameters (JSON-able)."""
        return {
            "basis": [list(m) for m in self.basis],
            "basis_center": None if self.basis_center is None else list(self.basis_center),
            "criterion": self.criterion, "n_restarts": self.n_restarts,
            "bounds": {k: list(getattr(self.bounds, k))
                       for k in ("length_scale", "signal", "basis", "noise")},
            "length_scale_init": self.length_scale_init, "noise_init": self.noise_init,
            "fixed_length_scales": None if self.fixed_length_scales is None
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
                basis_center=params["basis_center"], criterion=params["criterion"],
                n_restarts=int(params["n_restarts"]), bounds=bounds,
                length_scale_init=float(params["length_scale_init"]),
                noise_init=float(params["noise_init"]),
                fixed_length_scales=params["fixed_length_scales"], seed=int(params["seed"]),
            )
            a = {k: np.asarray(arrays[prefix + k], dtype=float) for k in
                 ("theta", "x", "y", "extra_var", "x_scale", "x_center", "y_scale")}
        except (KeyError, TypeError, ValueError) as exc:
            raise BifidInputError(f"malformed GP record {prefix!r} in the model file: {exc}") \
                from None
        basis_arr = np.asarray(arrays.get(prefix + "basis", np.zeros((0, 0))))
        if basis_arr.size and [list(map(int, r)) for r in basis_arr] != [list(m) for m in gp.basis]:
            raise BifidInputError(f"GP record {prefix!r}: basis arrays and parameters disagree.")
        n, d = a["x"].shape if a["x"].ndim == 2 else (0, 0)
        if (n < 1 or a["y"].shape != (n,) or a["theta"].shape != (2 + d + len(gp.basis),)
                or a["extra_var"].shape != (n,) or a["x_scale"].shape != (d,)
                or a["x_center"].shape != (d,) or a["y_scale"].size != 1):
            raise BifidInputError(f"GP record {prefix!r}: inconsistent array shapes.")
        if not (all(np.all(np.isfinite(v)) for v in a.values())
                and np.all(a["x_scale"] > 0) and float(a["y_scale"].reshape(-1)[0]) > 0
                and np.all(a["extra_var"] >= 0)):
            raise BifidInputError(f"GP record {prefix!r}: non-finite or out-of-range values.")
        gp._set_state(a["theta"], a["x"], a["y"], a["extra_var"], a["x_scale"],
                      a["x_center"], float(a["y_scale"].reshape(-1)[0]))
        gp.notes_ = []
        gp.n_train_ = n
        gp.objective_ = float("nan")
        return gp


_jit_mean = jax.jit(gp_mean)
_jit_var = jax.jit(gp_var)
