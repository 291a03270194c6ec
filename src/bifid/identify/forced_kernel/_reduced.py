r"""The learned reduced dynamics on the forced SSM as pure JAX functions (thesis eqs. 6.10–6.21).

A model holds the posterior means of ``a(ρ, Ω)`` and ``b(ρ, Ω)`` (:class:`ReducedModel`) and
optionally posterior function samples (:class:`ReducedSamples`). Fixed points of eq. 6.10,

.. math::  a(ρ, Ω) + Γ \sin ψ = 0,\qquad (b(ρ, Ω) - Ω)ρ + Γ \cos ψ = 0,

their stability (eigenvalues of the Jacobian of eq. 6.10 in ``(ρ, ψ)``), the S-curve
``Γ(ρ) = sqrt(a² + (b − Ω)²ρ²)`` (eq. 6.11) and the backbone ``b(ρ, Ω) = Ω`` (eq. 6.21) are
evaluated in batches; the nonlinear solves are :mod:`optimistix` root finders (Newton for
the samples' FRC points and the backbone, bisection for roots bracketed on a grid), jitted
once per batch size (:func:`pad_call` keeps the number of sizes small).

Against the hand-written fixed-iteration Newton and bisection loops they replace, measured in
one run on the ``shaw_pierre`` model of ``benchmarks/bench_forced_kernel.py`` (F = 0.009,
109 points, medians of 7 and 3 calls): the same FRC and folds to all printed digits, one FRC
0.40 s against 0.44 s, an FRC with a 32-sample band 1.55 s against 1.77 s; the first call
compiles longer (3.9 s against 1.6 s for the FRC).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from bifid.continuation import ZeroProblem
from bifid.identify.forced_kernel._gp_core import (
    GPSamples,
    GPState,
    bucket,
    gp_mean,
    sample_eval,
)

Array = jnp.ndarray

__all__ = [
    "FRC_PROBLEM",
    "ReducedModel",
    "ReducedSamples",
    "ab_grid",
    "ab_grid_samples",
    "backbone_mean",
    "backbone_samples",
    "dgamma_drho",
    "eigs_mean_g",
    "fold_radii",
    "frc_samples_at_psi",
    "frequency_factor",
    "pad_call",
    "response_radii",
    "sgamma",
    "wrap_lag",
]


def wrap_lag(psi: np.ndarray) -> np.ndarray:
    """Phase lag ``π − ψ`` wrapped to ``[−π/2, 3π/2)`` (the datasets' convention)."""
    lag = np.pi - np.asarray(psi)
    return (lag + np.pi / 2) % (2 * np.pi) - np.pi / 2


class ReducedModel(eqx.Module):
    """The learned ``a``, ``b`` (posterior means), the offset added to ``b`` (also the
    reference frequency Ω̄ of the forcing term) and how the forcing term varies with Ω
    (:func:`frequency_factor`)."""

    a: GPState
    b: GPState
    omega_c: Array
    forcing_frequency: str = eqx.field(static=True, default="constant")


def frequency_factor(kind: str, omega_ref, omega):
    r"""``Γ / (κF)`` at the forcing frequency Ω: 1 for ``kind="constant"`` (the thesis's
    ``Γ = κF``), ``Ω̄/Ω`` for ``"inverse"`` (``Γ = κF Ω̄/Ω``: the forcing of
    ``ẍ + … = F cos Ωt`` reaches the first-order averaged amplitude equation as
    ``F/(2Ω)``, so ``κ`` is the forcing scale at ``Ω = Ω̄``). NumPy or JAX arrays."""
    if kind == "inverse":
        return omega_ref / omega
    return 1.0


class ReducedSamples(eqx.Module):
    """Posterior function samples of ``a`` and ``b`` (leading axis = sample)."""

    a: GPSamples
    b: GPSamples


def _ab_mean(m: ReducedModel, rho: Array, omega: Array) -> tuple[Array, Array]:
    x = jnp.stack([rho, omega])
    return gp_mean(m.a, x), gp_mean(m.b, x) + m.omega_c


def _ab_sample(m: ReducedModel, s: ReducedSamples, rho: Array, omega: Array):
    x = jnp.stack([rho, omega])
    return sample_eval(m.a, s.a, x), sample_eval(m.b, s.b, x) + m.omega_c


def _fixed_point_residual(ab, y: Array, gamma: Array) -> Array:
    """Eq. 6.10 at a fixed point: ``[a + Γ sin ψ, (b − Ω)ρ + Γ cos ψ]`` (⇔ eq. 6.11)."""
    rho, psi, omega = y[0], y[1], y[2]
    a, b = ab(rho, omega)
    return jnp.stack([a + gamma * jnp.sin(psi), (b - omega) * rho + gamma * jnp.cos(psi)])


def _frc_residual(y: Array, args: dict) -> Array:
    """Eq. 6.10 at ``y = (ρ, ψ, Ω)``; ``args["gamma"]`` is ``κF`` (Γ varies with Ω as
    :func:`frequency_factor` says)."""
    m = args["model"]
    gamma = args["gamma"] * frequency_factor(m.forcing_frequency, m.omega_c, y[2])
    return _fixed_point_residual(lambda r, o: _ab_mean(m, r, o), y, gamma)


FRC_PROBLEM = ZeroProblem(_frc_residual, param_index=2)


def _polar_field(ab, rho_psi: Array, omega: Array, gamma: Array) -> Array:
    """Right-hand side of eq. 6.10 in ``(ρ, ψ)``."""
    rho, psi = rho_psi[0], rho_psi[1]
    a, b = ab(rho, omega)
    return jnp.stack([a + gamma * jnp.sin(psi), b - omega + gamma / rho * jnp.cos(psi)])


@jax.jit
def _eigs_mean(m: ReducedModel, rho: Array, psi: Array, omega: Array, gamma: Array) -> Array:
    """Eigenvalues (complex, shape (N, 2)) of the Jacobian of eq. 6.10 at each point."""

    def one(r, p, o):
        jac = jax.jacfwd(lambda u: _polar_field(lambda rr, oo: _ab_mean(m, rr, oo), u, o, gamma))(
            jnp.stack([r, p])
        )
        tr = jac[0, 0] + jac[1, 1]
        det = jac[0, 0] * jac[1, 1] - jac[0, 1] * jac[1, 0]
        disc = jnp.sqrt((tr * tr / 4.0 - det).astype(jnp.complex128))
        return jnp.stack([tr / 2.0 + disc, tr / 2.0 - disc])

    return jax.vmap(one)(rho, psi, omega)


@jax.jit
def _eigs_mean_g_jit(m: ReducedModel, rho, psi, omega, gamma) -> Array:
    """As :func:`_eigs_mean` with one Γ per point."""
    return jax.vmap(lambda r, p, o, g: _eigs_mean(m, r[None], p[None], o[None], g)[0])(
        rho, psi, omega, gamma
    )


@jax.jit
def _ab_grid_jit(m: ReducedModel, rho: Array, omega: Array) -> tuple[Array, Array]:
    return jax.vmap(lambda r, o: _ab_mean(m, r, o))(rho, omega)


@jax.jit
def _ab_grid_samples_jit(m: ReducedModel, s: ReducedSamples, rho: Array, omega: Array):
    """(S, N) values of a and b of every sample at the points."""

    def per_sample(si):
        return jax.vmap(lambda r, o: _ab_sample(m, si, r, o))(rho, omega)

    return jax.vmap(per_sample)(s)


def _newton(fun, u0: Array, n_iter: int) -> tuple[Array, Array]:
    """At most ``n_iter`` steps of :class:`optimistix.Newton` on ``fun(u) = 0`` from ``u0``;
    returns ``(u, max|fun(u)|)`` (a failure shows in the residual, never as an exception,
    so a ``vmap`` over samples and points carries on)."""
    sol = optx.root_find(
        lambda u, _: fun(u), optx.Newton(rtol=1e-13, atol=1e-14), u0, max_steps=n_iter, throw=False
    )
    return sol.value, jnp.max(jnp.abs(fun(sol.value)))


@jax.jit
def _frc_samples_at_psi_jit(m, s, gamma, psi, rho0, omega0):
    """Each sample's FRC point at each phase ψ_i: Newton in (ρ, Ω) from the mean point
    (``gamma`` is ``κF``; Γ varies with Ω as :func:`frequency_factor` says)."""

    def per_sample(si):
        def per_point(p, r0, o0):
            def fun(u):
                g = gamma * frequency_factor(m.forcing_frequency, m.omega_c, u[1])
                return _fixed_point_residual(
                    lambda rr, oo: _ab_sample(m, si, rr, oo), jnp.stack([u[0], p, u[1]]), g
                )

            return _newton(fun, jnp.stack([r0, o0]), 6)

        return jax.vmap(per_point)(psi, rho0, omega0)

    return jax.vmap(per_sample)(s)


def _backbone_scan(bfun, rho: Array, omega0: Array) -> tuple[Array, Array]:
    """Solve ``b(ρ, Ω) = Ω`` (eq. 6.21) along the ρ grid, each from the previous solution."""

    def step(o_prev, r):
        o, res = _newton(lambda oo: bfun(r, oo) - oo, o_prev, 8)
        return o, (o, res)

    _, (om, res) = jax.lax.scan(step, omega0, rho)
    return om, res


@jax.jit
def _backbone_mean_jit(m: ReducedModel, rho: Array, omega0: Array):
    return _backbone_scan(lambda r, o: gp_mean(m.b, jnp.stack([r, o])) + m.omega_c, rho, omega0)


@jax.jit
def _backbone_samples_jit(m: ReducedModel, s: ReducedSamples, rho: Array, omega0: Array):
    def one(sb):
        return _backbone_scan(
            lambda r, o: sample_eval(m.b, sb, jnp.stack([r, o])) + m.omega_c, rho, omega0
        )

    return jax.vmap(one)(s.b)


_HALVINGS = 64  # a bracket of the grid halved to round-off


def _bisect(fun, lo: Array, hi: Array) -> Array:
    """The root of ``fun`` in ``[lo, hi]`` (opposite signs at the ends) by
    :class:`optimistix.Bisection`, to round-off.

    Bisection stops early only when both the bracket and ``|fun|`` are below its tolerance,
    and ``|fun|`` has no fixed scale here; so it runs a fixed number of halvings (without
    the cap a vectorised call ran its whole step budget: the FRC took 1.6x longer)."""
    sol = optx.root_find(
        lambda r, _: fun(r),
        optx.Bisection(rtol=0.0, atol=0.0),
        0.5 * (lo + hi),
        options={"lower": lo, "upper": hi},
        max_steps=_HALVINGS,
        throw=False,
    )
    return sol.value


@jax.jit
def _response_radii_jit(m: ReducedModel, omega: Array, gamma: Array, lo: Array, hi: Array):
    def residual(r):
        a, b = _ab_mean(m, r, omega)
        return a * a + (b - omega) ** 2 * r * r - gamma**2

    return jax.vmap(lambda a, b: _bisect(residual, a, b))(lo, hi)


@jax.jit
def _fold_radii_jit(m: ReducedModel, omega: Array, lo: Array, hi: Array):
    def gam(r):
        a, b = _ab_mean(m, r, omega)
        return sgamma(a, b, r, omega)[0]

    return jax.vmap(lambda a, b: _bisect(jax.grad(gam), a, b))(lo, hi)


def sgamma(a: Array, b: Array, rho: Array, omega: Array) -> tuple[Array, Array]:
    """Eq. 6.11 at fixed Ω: ``Γ = sqrt(a² + (b−Ω)²ρ²)`` and ``ψ`` of the fixed point."""
    gamma = jnp.sqrt(a * a + (b - omega) ** 2 * rho * rho)
    psi = jnp.arctan2(-a, -(b - omega) * rho)
    return gamma, psi


@jax.jit
def _dgamma_drho_jit(m: ReducedModel, rho: Array, omega: Array) -> Array:
    def gam(r, o):
        a, b = _ab_mean(m, r, o)
        return sgamma(a, b, r, o)[0]

    return jax.vmap(jax.grad(gam), in_axes=(0, None))(rho, omega)


_CHUNK = 128


def pad_call(fn, *arrays, axis_out: int = 0, chunked: bool = True):
    """Call a jitted vectorised ``fn`` on 1-D arrays in fixed-size chunks.

    Every call sees arrays of length ``_CHUNK`` (the last chunk padded with its last
    value), so each function compiles once whatever the number of points; outputs are
    concatenated along ``axis_out`` and trimmed. With ``chunked=False`` the arrays are
    padded to a bucket length instead and ``fn`` is called once (for sequential scans).
    """
    arrs = [np.atleast_1d(np.asarray(a, dtype=float)) for a in arrays]
    n = arrs[0].shape[0]
    size = _CHUNK if chunked else bucket(n)
    n_pad = int(math.ceil(n / size) * size)
    padded = [np.concatenate([a, np.full(n_pad - n, a[-1])]) for a in arrs]
    outs = [fn(*(jnp.asarray(a[k : k + size]) for a in padded)) for k in range(0, n_pad, size)]

    def cat(*vs):
        v = np.concatenate([np.asarray(x) for x in vs], axis=axis_out)
        return v[(slice(None),) * axis_out + (slice(0, n),)]

    return jax.tree_util.tree_map(cat, *outs)


# ---- batched entry points (few compiled shapes) ------------------------------------------


def ab_grid(m, rho, omega):
    """Posterior means ``(a, b)`` at the points ``(rho_i, omega_i)``."""
    return pad_call(lambda r, o: _ab_grid_jit(m, r, o), rho, omega)


def eigs_mean_g(m, rho, psi, omega, gamma):
    """Eigenvalues (N, 2) of the Jacobian of eq. 6.10 at fixed points, one Γ per point."""
    return pad_call(lambda r, p, o, g: _eigs_mean_g_jit(m, r, p, o, g), rho, psi, omega, gamma)


def ab_grid_samples(m, s, rho, omega):
    """``(a, b)`` of every posterior sample at the points, each (S, N)."""
    return pad_call(lambda r, o: _ab_grid_samples_jit(m, s, r, o), rho, omega, axis_out=1)


def frc_samples_at_psi(m, s, gamma, psi, rho0, omega0):
    """Every sample's FRC point ``(ρ, Ω)`` at the phases ``psi`` and its residual
    (``gamma``: ``κF``)."""
    return pad_call(
        lambda p, r, o: _frc_samples_at_psi_jit(m, s, gamma, p, r, o), psi, rho0, omega0, axis_out=1
    )


def backbone_mean(m, rho, omega0):
    """Backbone frequencies along ``rho`` and their residuals (from ``omega0``)."""
    return pad_call(lambda r: _backbone_mean_jit(m, r, omega0), rho, chunked=False)


def backbone_samples(m, s, rho, omega0):
    """Every sample's backbone along ``rho`` (S, N) and the residuals."""
    return pad_call(
        lambda r: _backbone_samples_jit(m, s, r, omega0), rho, axis_out=1, chunked=False
    )


def dgamma_drho(m, rho, omega):
    """``dΓ/dρ`` along the S-curve at frequency ``omega``."""
    return pad_call(lambda r: _dgamma_drho_jit(m, r, jnp.asarray(float(omega))), rho)


def response_radii(m, omega: float, gamma: float, lo, hi) -> np.ndarray:
    """Amplitudes of the fixed points at ``(Ω, Γ)`` in the brackets ``[lo_i, hi_i]``."""
    return pad_call(
        lambda a, b: _response_radii_jit(
            m, jnp.asarray(float(omega)), jnp.asarray(float(gamma)), a, b
        ),
        lo,
        hi,
    )


def fold_radii(m, omega: float, lo, hi) -> np.ndarray:
    """Amplitudes of the S-curve's folds (``dΓ/dρ = 0``) in the brackets ``[lo_i, hi_i]``."""
    return pad_call(lambda a, b: _fold_radii_jit(m, jnp.asarray(float(omega)), a, b), lo, hi)
