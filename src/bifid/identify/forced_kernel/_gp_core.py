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

Pseudo-observations. Rows marked ``pseudo`` are values known by construction, not
measurements: for the kernel model's ``a`` the pseudo-observations ``a(0, Ω) = 0`` (eq. 6.9:
``a`` vanishes at ``ρ = 0``; ``a`` is learned from eq. 6.19 with them). They carry only
their known variance ``v_i``, not ``σ_n²``, and both criteria score the measurements
*given* them: ``-log p(y_meas | y_pseudo) = -log p(y) + log p(y_pseudo)`` (both from the
same ``K_y``), and the LOO sum runs over the measurements only. Scored like measurements, a
dozen exactly predictable zeros would reward ``σ_n → 0`` by about ``log(σ_true/σ_n)``
each, which can outweigh the measurements' evidence for their noise: ``σ_n`` then sits at
its floor while a short length scale takes up the noise, the posterior mean of ``a``
interpolates it, and predicted FRCs get spurious fold pairs (eq. 6.11 is very sensitive to
``a`` near the peak, where ``a ≈ −Γ``).

Length-scale floor. Every ``ℓ_d`` is bounded below by the data's spacing ``h``, the median
over the measurements of the distance to the nearest other input in scaled units
(:func:`input_spacing`), besides ``HyperBounds.length_scale``. At ``ℓ_d ≥ h`` a typical
measurement keeps a prior correlation of at least ``e^{-1/2}`` with its nearest neighbour
(``Σ_d (Δu_d/ℓ_d)² ≤ |Δu|²/h²``), so the SE part cannot act as independent noise. Below
``h`` the two are nearly indistinguishable at the data (the criteria are flat along
``σ² + σ_n² =`` const): ``σ_n`` could slide to its floor while the SE part reproduced the
noise with bumps of width ``ℓ`` between the training points — structure on scales the
data do not resolve.

Posterior: mean ``μ(x) = k(x, X) α`` with ``α = K_y⁻¹ y`` and latent variance
``k(x, x) − k(x, X) K_y⁻¹ k(X, x)``; the basis part of ``k(x, X) α`` is summed as
``h(x)ᵀ(τ² ∘ H(X)ᵀα)``, so that large basis variances (which the LOO criterion hardly
bounds) do not leave rounding noise in the mean that varies from one ``x`` to the next
(a Newton solver on the mean then stalls). :class:`GPState` is an equinox module holding
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
    "input_spacing",
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


def _cross(state: GPState, x: Array, w: Array) -> Array:
    """``k(x, X) w`` for weights ``w`` (n_pad,) or (n_pad, S), the basis part summed as
    ``h(x) · (τ² H(X)ᵀ w)``: with large basis variances the entries of ``k(x, X)`` are large
    and cancel in the product, which summed per point leaves rounding noise that varies
    from one ``x`` to the next (a Newton solver on the mean then stalls)."""
    theta, mono = state.theta, state.monomials
    n_dim = x.shape[1]
    log_s, log_l, log_t, _ = _split(theta, n_dim, len(mono))
    d = (x[:, None, :] - state.x[None, :, :]) / (state.x_scale * jnp.exp(log_l))
    out = (jnp.exp(2.0 * log_s) * jnp.exp(-0.5 * jnp.sum(d * d, axis=-1))) @ w
    if mono:
        h = basis_matrix((x - state.x_center) / state.x_scale, mono)
        hx = basis_matrix((state.x - state.x_center) / state.x_scale, mono)
        coef = jnp.exp(2.0 * log_t)[:, None] * (hx.T @ w.reshape(w.shape[0], -1))
        out = out + (h @ coef).reshape(out.shape)
    return out


def _kdiag(theta: Array, x: Array, x_scale: Array, x_center: Array, monomials: Monomials):
    n_dim = x.shape[1]
    log_s, _, log_t, _ = _split(theta, n_dim, len(monomials))
    out = jnp.full((x.shape[0],), jnp.exp(2.0 * log_s))
    if monomials:
        h = basis_matrix((x - x_center) / x_scale, monomials)
        out = out + jnp.sum(h * h * jnp.exp(2.0 * log_t), axis=1)
    return out


def _masked_ky(theta, x, mask, extra_var, x_scale, x_center, monomials, noisy=None):
    """``K_y`` of the padded set: real block as usual, padded block the identity; the
    noise ``σ_n²`` only on the ``noisy`` rows (measurements, not pseudo-observations)."""
    n_dim = x.shape[1]
    log_n = _split(theta, n_dim, len(monomials))[3]
    noisy = mask if noisy is None else noisy
    k = _cov(theta, x, x, x_scale, x_center, monomials)
    mm = mask[:, None] * mask[None, :]
    # relative jitter keeps K_y numerically positive definite at extreme hyperparameters
    jitter = _JITTER * jnp.sum(jnp.diag(k) * mask) / jnp.maximum(jnp.sum(mask), 1.0)
    noise = jnp.exp(2.0 * log_n) * noisy + extra_var + jitter
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
    noisy: Array | None = None,
) -> Array:
    """``-log p(y | X, θ)`` of the (scaled) targets ``y`` (R&W eq. 5.8); ``noisy`` (default
    ``mask``) marks the rows that carry the noise ``σ_n²``."""
    mask = jnp.ones(x.shape[0]) if mask is None else mask
    extra_var = jnp.zeros(x.shape[0]) if extra_var is None else extra_var
    ky = _masked_ky(theta, x, mask, extra_var, x_scale, x_center, monomials, noisy)
    ym = y * mask
    n_eff = jnp.sum(mask)
    return (
        0.5 * ym @ (_inv_spd(ky) @ ym) + 0.5 * _logdet_spd(ky) + 0.5 * n_eff * jnp.log(2.0 * jnp.pi)
    )


def _conditional_nlml(theta, x, y, x_scale, x_center, monomials, extra_var, mask, noisy):
    """``-log p(y_meas | y_pseudo, X, θ) = -log p(y) + log p(y_pseudo)``: the marginal
    likelihood of the measurements (``noisy`` rows) given the pseudo-observations (the
    other real rows), both from the same ``K_y``."""
    ky = _masked_ky(theta, x, mask, extra_var, x_scale, x_center, monomials, noisy)
    pseudo = mask * (1.0 - noisy)
    ky_p = ky * (pseudo[:, None] * pseudo[None, :]) + jnp.diag(1.0 - pseudo)
    ym, yp = y * mask, y * pseudo
    return (
        0.5 * ym @ (_inv_spd(ky) @ ym)
        - 0.5 * yp @ (_inv_spd(ky_p) @ yp)
        + 0.5 * (_logdet_spd(ky) - _logdet_spd(ky_p))
        + 0.5 * jnp.sum(noisy) * jnp.log(2.0 * jnp.pi)
    )


def _loo_objective(theta, x, y, x_scale, x_center, monomials, extra_var, mask, noisy):
    """Closed-form leave-one-out negative log predictive probability (R&W eq. 5.10–5.12)
    of the measurements (``noisy`` rows), each given all other rows."""
    ky = _masked_ky(theta, x, mask, extra_var, x_scale, x_center, monomials, noisy)
    kinv = _inv_spd(ky)
    alpha = kinv @ (y * mask)
    dinv = jnp.diag(kinv)
    var = 1.0 / dinv
    resid = alpha / dinv
    terms = 0.5 * jnp.log(var) + 0.5 * resid**2 / var + 0.5 * jnp.log(2.0 * jnp.pi)
    return jnp.sum(terms * noisy)


@functools.lru_cache(maxsize=64)
def _objective(monomials: Monomials, criterion: str, pseudo: bool = False):
    """Jitted value and gradient of a selection criterion in ``θ``; ``pseudo``: the data
    hold pseudo-observations (the marginal likelihood is then the conditional one)."""
    if criterion == "ml":

        def f(theta, x, y, x_scale, x_center, extra_var, mask, noisy):
            if not pseudo:
                return neg_log_marginal_likelihood(
                    theta, x, y, x_scale, x_center, monomials, extra_var, mask, noisy
                )
            return _conditional_nlml(
                theta, x, y, x_scale, x_center, monomials, extra_var, mask, noisy
            )
    else:

        def f(theta, x, y, x_scale, x_center, extra_var, mask, noisy):
            return _loo_objective(theta, x, y, x_scale, x_center, monomials, extra_var, mask, noisy)

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
    noisy: Array
    monomials: Monomials = eqx.field(static=True)

    @property
    def n_dim(self) -> int:
        return int(self.x.shape[1])


def gp_mean(state: GPState, x: Array) -> Array:
    """Posterior mean at ``x`` of shape (N, D) (or (D,) for one point → scalar)."""
    single = x.ndim == 1
    xx = x[None, :] if single else x
    out = _cross(state, xx, state.alpha) * state.y_scale
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
    out = (prior + _cross(state, xx, sample.v)) * state.y_scale
    return out[0] if single else out


@functools.partial(jax.jit, static_argnames=("monomials",))
def _posterior(theta, x, y, x_scale, x_center, extra_var, mask, noisy, monomials):
    """Cholesky factor, ``α = K_y⁻¹y``, LOO residuals, fitted values and
    ``-log p(y_meas | y_pseudo)`` of a padded training set (one compiled program per bucket
    and basis)."""
    ky = _masked_ky(theta, x, mask, extra_var, x_scale, x_center, monomials, noisy)
    chol = jnp.linalg.cholesky(ky)
    alpha = jax.scipy.linalg.cho_solve((chol, True), y * mask)
    kinv_diag = jnp.diag(
        jax.scipy.linalg.cho_solve((chol, True), jnp.eye(x.shape[0], dtype=x.dtype))
    )
    loo = alpha / kinv_diag
    fit = _cov(theta, x, x, x_scale, x_center, monomials) @ alpha
    nlml = _conditional_nlml(theta, x, y, x_scale, x_center, monomials, extra_var, mask, noisy)
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
    noise_sd = jnp.sqrt(jnp.exp(2.0 * log_n) * state.noisy + extra_var)
    eps = jax.random.normal(k5, (n_samples, state.x.shape[0])) * noise_sd
    prior_at_x = jax.vmap(lambda f, p, w, b: _prior_sample_eval(state, f, p, w, b, state.x))(
        freq, phase, weight, beta
    )
    resid = (y_scaled[None, :] - prior_at_x - eps) * state.mask[None, :]
    v = jax.scipy.linalg.cho_solve((state.chol, True), resid.T).T
    return GPSamples(freq=freq, phase=phase, weight=weight, beta=beta, v=v)


def input_spacing(u: np.ndarray, pseudo: np.ndarray | None = None) -> float:
    """Median distance from a measured input to its nearest other input (scaled units).

    The lower bound of every length scale (module docstring, "Length-scale floor"): at
    ``ℓ_d ≥`` this spacing a typical measurement keeps a prior correlation of at least
    ``e^{-1/2}`` with its nearest neighbour, so the squared-exponential part cannot act as
    independent noise.
    ``pseudo`` rows count as neighbours but not as measurements; duplicates are skipped.
    """
    u = np.asarray(u, dtype=float)
    meas = np.ones(u.shape[0], dtype=bool) if pseudo is None else ~np.asarray(pseudo, bool)
    if u.shape[0] < 2 or not meas.any():
        return 0.0
    dist = np.sqrt(np.sum((u[meas, None, :] - u[None, :, :]) ** 2, axis=-1))
    dist[dist <= 0.0] = np.inf  # itself and exact duplicates
    nearest = dist.min(axis=1)
    nearest = nearest[np.isfinite(nearest)]
    return float(np.median(nearest)) if nearest.size else 0.0


def padded_args(
    x: np.ndarray,
    y_scaled: np.ndarray,
    extra_var_scaled: np.ndarray,
    x_scale: np.ndarray,
    x_center: np.ndarray,
    pseudo: np.ndarray | None = None,
) -> tuple[Array, ...]:
    """``(x, y, x_scale, x_center, extra_var, mask, noisy)`` padded to a bucket size.

    Padded rows are masked: their block of ``K_y`` is the identity and their targets 0,
    which leaves the marginal likelihood, the LOO criterion and their gradients unchanged.
    ``noisy`` is ``mask`` without the ``pseudo`` rows (pseudo-observations).
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
    noisy = mask.copy()
    if pseudo is not None:
        noisy[:n] = np.where(np.asarray(pseudo, dtype=bool), 0.0, 1.0)
    return tuple(jnp.asarray(a) for a in (xp, yp, x_scale, x_center, evp, mask, noisy))
