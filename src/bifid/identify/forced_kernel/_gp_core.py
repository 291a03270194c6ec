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
from typing import Literal

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

Array = jnp.ndarray
_JITTER = 1e-10  # relative diagonal jitter of K_y (times the mean prior variance)
Monomials = tuple[tuple[int, ...], ...]
Criterion = Literal["ml", "loo"]

__all__ = [
    "GPSamples",
    "GPState",
    "basis_matrix",
    "bucket",
    "gp_mean",
    "gp_var",
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
        0.5 * ym @ (_inv_spd(ky) @ ym) + 0.5 * _logdet_spd(ky) + 0.5 * n_eff * jnp.log(2.0 * jnp.pi)
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


def bucket(n: int) -> int:
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
    kinv_diag = jnp.diag(
        jax.scipy.linalg.cho_solve((chol, True), jnp.eye(x.shape[0], dtype=x.dtype))
    )
    loo = alpha / kinv_diag
    fit = _cov(theta, x, x, x_scale, x_center, monomials) @ alpha
    n_eff = jnp.sum(mask)
    nlml = (
        0.5 * (y * mask) @ alpha
        + jnp.sum(jnp.log(jnp.diag(chol)))
        + 0.5 * n_eff * jnp.log(2.0 * jnp.pi)
    )
    return chol, alpha, loo, fit, nlml


@functools.partial(jax.jit, static_argnames=("n_samples", "n_features"))
def _draw_samples(
    state: GPState, y_scaled, extra_var, key, n_samples: int, n_features: int
) -> GPSamples:
    """Pathwise-conditioned posterior function samples (module docstring)."""
    d = state.n_dim
    m = len(state.monomials)
    log_s, log_l, log_t, log_n = _split(state.theta, d, m)
    k1, k2, k3, k4, k5 = jax.random.split(key, 5)
    freq = jax.random.normal(k1, (n_samples, n_features, d)) / jnp.exp(log_l)
    phase = jax.random.uniform(k2, (n_samples, n_features), maxval=2.0 * jnp.pi)
    weight = (
        jax.random.normal(k3, (n_samples, n_features)) * jnp.exp(log_s) * jnp.sqrt(2.0 / n_features)
    )
    beta = jax.random.normal(k4, (n_samples, m)) * jnp.exp(log_t)
    noise_sd = jnp.sqrt(jnp.exp(2.0 * log_n) + extra_var)
    eps = jax.random.normal(k5, (n_samples, state.x.shape[0])) * noise_sd
    prior_at_x = jax.vmap(lambda f, p, w, b: _prior_sample_eval(state, f, p, w, b, state.x))(
        freq, phase, weight, beta
    )
    resid = (y_scaled[None, :] - prior_at_x - eps) * state.mask[None, :]
    v = jax.scipy.linalg.cho_solve((state.chol, True), resid.T).T
    return GPSamples(freq=freq, phase=phase, weight=weight, beta=beta, v=v)


def padded_args(
    x: np.ndarray,
    y_scaled: np.ndarray,
    extra_var_scaled: np.ndarray,
    x_scale: np.ndarray,
    x_center: np.ndarray,
) -> tuple[Array, ...]:
    """``(x, y, x_scale, x_center, extra_var, mask)`` padded to a bucket size.

    Padded rows are masked: their block of ``K_y`` is the identity and their targets 0,
    which leaves the marginal likelihood, the LOO criterion and their gradients unchanged.
    """
    n, d = x.shape
    n_pad = bucket(n)
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
