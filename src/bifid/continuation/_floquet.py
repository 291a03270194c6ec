"""Floquet multipliers from the variational equation, stable for any contraction.

For a periodic orbit ``x_s(t)`` of period ``T`` (thesis eq. 3.26)

.. math:: \\dot\\Phi = \\partial_x f(x_s(t), t, p)\\,\\Phi,\\qquad \\Phi(0) = I,

and the multipliers are the eigenvalues of the monodromy matrix ``Phi(T)``. On strongly
contracting or expanding orbits ``Phi(T)`` spans hundreds of orders of magnitude (a
multiplier ``e^{-1325}`` is below the smallest double), so it is never formed:

1. **Factors.** The period is cut into ``K`` sub-intervals ``[t_j, t_{j+1}]`` and on each
   the variational equation is integrated from the identity with error control
   (diffrax, 8th-order Dormand–Prince, relative tolerance ``1e-11``), in balanced
   coordinates: ``Psi_j = D^{-1} Phi_j D`` with ``Psi' = (D^{-1} f_x D) Psi`` and ``D`` the
   diagonal scaling (powers of two, exact) that balances the orbit's mean ``|f_x|``
   (``scipy.linalg.matrix_balance``; ``D = I`` where that bounds better). ``K`` (a power
   of two) is chosen so that no factor can be worse conditioned than ``e^4``:
   ``T * max_t (l_max(S) - l_min(S)) / K <= 4`` with ``S`` the symmetric part of
   ``D^{-1} f_x D`` (a bound from the logarithmic norm). Unscaled, the bound counts the
   states' units: on the flutter orbits (velocities ``omega`` times displacements) it
   asked for 256 factors, the balanced one for 8, with the same ``log|mu|`` to ``1e-12``.
2. **Periodic orthogonal iteration.** ``Psi_j Q_j = Q_{j+1} R_j`` (QR) around the period,
   repeated with ``Q_0 <- Q_K`` until the leading invariant subspaces of the product
   stop moving (subspace angle ``<= 1e-9``); the triangular product ``R = R_{K-1} ...
   R_0`` is kept with a logarithmic scale per column. With ``Q_0^T Q_K = B``,
   ``Q_0^T Psi Q_0 = B R`` is block upper triangular across every converged subspace,
   so the multipliers are the eigenvalues of its diagonal blocks, each computed from
   well-scaled numbers: ``log|mu|`` is exact to rounding even for ``e^{-10^4}``. Blocks are
   1x1 for well-separated real multipliers and 2x2 for complex pairs; where convergence
   is slow (close moduli) neighbouring blocks are merged, which is always valid.
3. **Trivial multiplier.** For autonomous orbits the first column of ``Q_0`` is
   ``D^{-1} f(x_s(0))``, which the flow maps onto itself: the trivial multiplier is
   deflated exactly, and the others are those of the complementary block (so a fold's
   second multiplier at +1 is not confused with the trivial one).

Written by hand: SciPy has no periodic Schur decomposition and SLICOT's (``slycot``) is a
heavy binary dependency with a documented failure for long products. The sub-intervals
of a batch are integrated in ``vmap``-ed, compiled calls over chunks of a fixed number
of sub-intervals, their ends passed as values, so every branch reuses one compiled
program per right-hand side (tracing and compiling the integrator costs tens of seconds,
a call milliseconds).

**From the collocation operator** (:func:`collocation_floquet`, the orbit branches'
``stability="collocation"``): the Floquet solutions ``e^{rho tau} q(tau)`` (``tau = 2 pi
t / T``, ``q`` 2pi-periodic) solve ``q' - (T / 2 pi) A(tau) q = -rho q``, so the
eigenvalues ``nu`` of the collocation operator ``L = D_M (x) I - (T / 2 pi)
blockdiag(f_x(v_k))`` (the mesh block of the collocation Jacobian) are ``-rho - i k`` for
every integer ``k`` and ``mu = exp(-2 pi nu)`` (no over- or underflow). Each multiplier
has one eigenvalue in the strip ``-1/2 < Im nu <= 1/2``; the resolved ones are recognised
by their aliases ``nu +- i``, which a spurious eigenvalue of the discretisation (the
Nyquist mode) does not have: the ``n`` strip eigenvalues with the closest aliases are the
multipliers, and an orbit whose ``n``-th alias misses by more than :data:`ALIAS_TOL` is
not resolved (``ok`` False). One dense eigenvalue problem of ``M n`` unknowns per orbit,
nothing to compile; the trivial multiplier is the eigenvalue nearest 0.

Stability tolerance: multipliers are accurate to about ``1e-9`` relative; an orbit is
labelled stable when its largest non-trivial modulus is below ``1 - STABILITY_TOL``,
unstable above ``1 + STABILITY_TOL``, and takes the label of its neighbours in between
(:data:`STABILITY_TOL` = 1e-7).
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

from bifid.continuation._blas import one_blas_thread
from bifid.errors import BifidInputError
from bifid.signal import evaluate_fourier, fourier_coefficients

Array = jnp.ndarray

#: a non-trivial multiplier within this distance of the unit circle does not decide
#: stability on its own (the multipliers' accuracy is ~1e-9)
STABILITY_TOL = 1e-7
#: largest growth ``log cond(Phi_j)`` allowed in one sub-interval
_FACTOR_GROWTH = 4.0
_MIN_FACTORS, _MAX_FACTORS = 4, 4096
_RTOL, _ATOL = 1e-11, 1e-13
_SUBSPACE_TOL = 1e-9
_MAX_SWEEPS = 12
#: points of each orbit at which the growth bound of the factors is evaluated
_SPREAD_SAMPLES = 64


@dataclass
class Floquet:
    """Floquet multipliers of a batch of orbits.

    Attributes
    ----------
    multipliers : complex array of shape (n_orbits, n)
        By decreasing modulus (moduli below the smallest double are 0).
    log_moduli : array of shape (n_orbits, n)
        ``log|mu|`` of the same multipliers (finite where the multipliers underflow).
    trivial : int array of shape (n_orbits,)
        Column of the trivial multiplier (autonomous orbits), -1 for forced ones.
    ok : bool array of shape (n_orbits,)
        The integration succeeded and everything is finite.
    """

    multipliers: np.ndarray
    log_moduli: np.ndarray
    trivial: np.ndarray
    ok: np.ndarray

    def nontrivial(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Multipliers and log-moduli of orbit ``i`` without the trivial one."""
        m, lm = self.multipliers[i], self.log_moduli[i]
        j = int(self.trivial[i])
        if j < 0:
            return m, lm
        return np.delete(m, j), np.delete(lm, j)

    @property
    def log_max(self) -> np.ndarray:
        """Largest non-trivial ``log|mu|`` of each orbit (NaN where it failed)."""
        out = np.array(
            [np.max(self.nontrivial(i)[1], initial=-np.inf) for i in range(len(self.ok))]
        )
        out[~self.ok] = np.nan
        return out

    @property
    def floquet_max(self) -> np.ndarray:
        """Largest non-trivial modulus (0 where it underflows, NaN where it failed)."""
        with np.errstate(over="ignore"):
            return np.exp(self.log_max)

    def stable(self, tol: float = STABILITY_TOL) -> np.ndarray:
        """Stability labels: the largest non-trivial modulus against ``1 ± tol``; orbits
        within the band take the label of the nearest decided orbit (NaN when none)."""
        lm = self.log_max
        label = np.where(lm < -tol, 1.0, np.where(lm > tol, 0.0, np.nan))
        decided = np.flatnonzero(np.isfinite(label))
        if decided.size and decided.size < label.size:
            for i in np.flatnonzero(~np.isfinite(label)):
                if np.isfinite(lm[i]):
                    label[i] = label[decided[np.argmin(np.abs(decided - i))]]
        return label


# ----------------------------------------------------------------------- factors
@functools.lru_cache(maxsize=32)
def _segments_fn(rhs: Callable) -> Callable:
    """Compiled ``(x0, t0, t1, p, d) -> (Psi, ok, f(x0, t0) / d)`` for a batch of
    sub-intervals: the variational equation in the coordinates scaled by ``D = diag(d)``,
    ``Psi = D^{-1} Phi D``, from the identity over ``[t0, t1]``. The number of factors of
    an orbit and the number of orbits are run-time values (a batch of sub-intervals of any
    orbits), so one program serves every branch."""
    import diffrax  # here: importing it costs 1-2 s that commands without Floquet skip

    def one(x0, t0, t1, p, d):
        n = x0.shape[0]

        def vf(t, state, args):
            x, phi = state
            J = jax.jacfwd(rhs, argnums=0)(x, t, p)
            return rhs(x, t, p), (J * d[None, :] / d[:, None]) @ phi

        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(vf),
            diffrax.Dopri8(),
            t0=t0,
            t1=t1,
            dt0=(t1 - t0) / 4,
            y0=(x0, jnp.eye(n)),
            stepsize_controller=diffrax.PIDController(rtol=_RTOL, atol=_ATOL),
            max_steps=4096,
            throw=False,
        )
        ok = sol.result == diffrax.RESULTS.successful
        return sol.ys[1][-1], ok, rhs(x0, t0, p) / d

    return jax.jit(jax.vmap(one))


@functools.lru_cache(maxsize=32)
def _jacobians_fn(rhs: Callable) -> Callable:
    """Compiled ``(V, T, p) -> f_x`` at the points ``V`` of an orbit (times ``T k / len(V)``)."""

    def one(V, T, p):
        ts = T * jnp.arange(V.shape[0]) / V.shape[0]
        return jax.vmap(jax.jacfwd(rhs, argnums=0), in_axes=(0, 0, None))(V, ts, p)

    return jax.jit(jax.vmap(one))


def _balancing(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per orbit (``J`` of shape ``(n_orbits, n_points, n, n)``), the scaling ``d`` of the
    balanced coordinates and the bound ``max_k (l_max(S_k) - l_min(S_k))``, ``S_k`` the
    symmetric part of ``D^{-1} J_k D`` (module docstring); ``d = 1`` where the scaling does
    not lower the bound or ``J`` is not finite."""

    def spread(A: np.ndarray) -> np.ndarray:
        ev = np.linalg.eigvalsh(0.5 * (A + np.swapaxes(A, -1, -2)))
        return np.max(ev[..., -1] - ev[..., 0], axis=-1)

    d = np.ones((J.shape[0], J.shape[-1]))
    with np.errstate(invalid="ignore"):
        bound = spread(J)
    for i in np.flatnonzero(np.all(np.isfinite(J), axis=(1, 2, 3))):
        mean = np.mean(np.abs(J[i]), axis=0)
        scale = scipy.linalg.matrix_balance(mean, permute=False, separate=True)[1][0]
        balanced = spread(J[i] * scale[None, None, :] / scale[None, :, None])
        if balanced < bound[i]:
            d[i], bound[i] = scale, balanced
    return d, bound


_CHUNK = 8  # orbits per compiled call
_SEGMENT_CHUNK = 32  # sub-intervals per compiled call


def _in_chunks(fn: Callable, *arrays: np.ndarray, chunk: int = _CHUNK) -> tuple[np.ndarray, ...]:
    """``fn`` over a batch in chunks of ``chunk`` items (the last one padded by repeating
    its last item): one compiled shape for every batch size; the outputs concatenated and
    cut to the batch."""
    n = len(arrays[0])
    parts = []
    for start in range(0, max(n, 1), chunk):
        idx = np.minimum(np.arange(start, start + chunk), max(n - 1, 0))
        out = fn(*(jnp.asarray(a[idx]) for a in arrays))
        parts.append(out if isinstance(out, tuple) else (out,))
    return tuple(
        np.concatenate([np.asarray(o[k]) for o in parts])[:n] for k in range(len(parts[0]))
    )


def _samples(orbits: Sequence[np.ndarray], n_samples: int) -> np.ndarray:
    """Each orbit's trigonometric interpolant at ``t_j = T j / n_samples``."""
    tau = 2.0 * np.pi * np.arange(n_samples) / n_samples
    return np.stack(
        [evaluate_fourier(*fourier_coefficients(np.asarray(o, dtype=float)), tau) for o in orbits]
    )


def monodromy_factors(
    rhs: Callable, orbits: np.ndarray | Sequence[np.ndarray], periods: np.ndarray, ps: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The factors of the monodromy matrices of a batch of orbits (each orbit ``(M_i, n)``
    on its own mesh), in the balanced coordinates of each orbit (module docstring).

    Returns
    -------
    factors : array of shape (n_orbits, K, n, n)
        ``Psi_j = D^{-1} Phi_j D``: ``Phi = D factors[:, K-1] @ ... @ factors[:, 0] D^{-1}``.
    ok : bool array of shape (n_orbits,)
    f0 : array of shape (n_orbits, n)
        ``D^{-1} f`` at each orbit's first point (the trivial Floquet vector of ``Psi``).
    scale : array of shape (n_orbits, n)
        The diagonal of ``D``.
    """
    periods = np.asarray(periods, dtype=float)
    ps = np.asarray(ps, dtype=float)
    n_orb = len(orbits)
    coarse = _samples(orbits, _SPREAD_SAMPLES)
    (J,) = _in_chunks(_jacobians_fn(rhs), coarse, periods, ps)
    scale, spread = _balancing(J)
    need = float(np.nanmax(np.abs(periods) * spread)) / _FACTOR_GROWTH if n_orb else 1.0
    if not math.isfinite(need):
        need = _MAX_FACTORS
    n_factors = int(min(max(_MIN_FACTORS, 1 << math.ceil(math.log2(max(need, 1.0)))), _MAX_FACTORS))
    # each factor integrates the orbit with its variational equation from the orbit's
    # trigonometric interpolant at t_j (cheap for any mesh; the sub-intervals are short)
    starts = _samples(orbits, n_factors)  # (n_orb, K, n)
    n = starts.shape[-1]
    K = n_factors
    t0 = periods[:, None] * np.arange(K)[None, :] / K
    t1 = periods[:, None] * np.arange(1, K + 1)[None, :] / K
    Psi, ok, f = _in_chunks(
        _segments_fn(rhs),
        starts.reshape(-1, n),
        t0.ravel(),
        t1.ravel(),
        np.repeat(ps, K, axis=0),
        np.repeat(scale, K, axis=0),
        chunk=_SEGMENT_CHUNK,
    )
    Psi = Psi.reshape(n_orb, K, n, n)
    ok = np.all(ok.reshape(n_orb, K), axis=1) & np.all(np.isfinite(Psi), axis=(1, 2, 3))
    return Psi, ok, f.reshape(n_orb, K, n)[:, 0], scale


# ------------------------------------------------------------ periodic eigenvalues
def _sweep(factors: np.ndarray, Q0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One periodic QR sweep ``Phi_j Q_j = Q_{j+1} R_j``: ``Q_K`` and the ``R_j``
    (diagonals made positive)."""
    K = factors.shape[1]
    Q = Q0
    Rs = np.empty_like(factors)
    for j in range(K):
        Q, R = np.linalg.qr(factors[:, j] @ Q)
        sgn = np.where(np.diagonal(R, axis1=1, axis2=2) < 0, -1.0, 1.0)
        Q = Q * sgn[:, None, :]
        Rs[:, j] = R * sgn[:, :, None]
    return Q, Rs


def _boundaries(Q0: np.ndarray, QK: np.ndarray) -> np.ndarray:
    """Angle between ``span Q0[:, :k]`` and ``span QK[:, :k]`` for k = 1..n-1."""
    n = Q0.shape[-1]
    out = np.empty((*Q0.shape[:-2], n - 1))
    for k in range(1, n):
        C = np.swapaxes(Q0[..., :, k:], -1, -2) @ QK[..., :, :k]
        out[..., k - 1] = np.sqrt(np.sum(C**2, axis=(-1, -2)))
    return out


def _scaled_product(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``blocks[:, K-1] @ ... @ blocks[:, 0]`` as ``P * exp(s)`` (columns of ``P`` scaled
    to max-abs 1, ``s`` their log scales): no over- or underflow of the scales."""
    n_orb, K, m, _ = blocks.shape
    P = np.broadcast_to(np.eye(m), (n_orb, m, m)).copy()
    s = np.zeros((n_orb, m))
    for j in range(K):
        P = blocks[:, j] @ P
        scale = np.max(np.abs(P), axis=1)
        scale = np.where(scale > 0, scale, 1.0)
        P = P / scale[:, None, :]
        s = s + np.log(scale)
    return P, s


def _cluster_eigenvalues(
    B: np.ndarray, Rs: np.ndarray, a: int, b: int
) -> tuple[np.ndarray, np.ndarray]:
    """Log-moduli and phases of the eigenvalues of the diagonal block ``[a, b)`` of
    ``B R`` for a batch of orbits (the block of a product of triangular matrices is the
    product of their blocks)."""
    if b - a == 1:
        with np.errstate(divide="ignore"):
            logm = np.sum(np.log(Rs[:, :, a, a]), axis=1)
        return logm[:, None], np.sign(B[:, a, a])[:, None].astype(complex)
    P, s = _scaled_product(Rs[:, :, a:b, a:b])
    ref = np.max(s, axis=1)
    block = B[:, a:b, a:b] @ (P * np.exp(s - ref[:, None])[:, None, :])
    ev = np.linalg.eigvals(block)
    mod = np.abs(ev)
    with np.errstate(divide="ignore"):
        logm = np.log(mod) + ref[:, None]
    phase = np.where(mod > 0, ev / np.where(mod > 0, mod, 1.0), 1.0)
    return logm, phase


def periodic_eigenvalues(
    factors: np.ndarray, first: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eigenvalues of products ``factors[:, K-1] @ ... @ factors[:, 0]`` without forming
    them (periodic orthogonal iteration, module docstring).

    Parameters
    ----------
    factors : array of shape (n_orbits, K, n, n)
    first : array of shape (n_orbits, n), optional
        A known invariant direction (the trivial Floquet vector): kept as the first
        Schur vector, its eigenvalue is returned in column 0.

    Returns
    -------
    log_moduli : array of shape (n_orbits, n)
    phases : complex array of shape (n_orbits, n)
        ``mu / |mu|``.
    converged : bool array of shape (n_orbits, n-1)
        Which Schur-vector boundaries converged (the others were merged into blocks).
    """
    factors = np.asarray(factors, dtype=float)
    n_orb, _, n, _ = factors.shape
    Q0 = np.broadcast_to(np.eye(n), (n_orb, n, n)).copy()
    if first is not None:
        start = np.concatenate([np.asarray(first, dtype=float)[:, :, None], Q0], axis=2)
        Q0 = np.linalg.qr(start)[0][:, :, :n]
    done = np.zeros(n_orb, bool)
    final: list = [None] * 4
    for sweep in range(_MAX_SWEEPS):
        QK, Rs = _sweep(factors, Q0)
        conv = _boundaries(Q0, QK) < _SUBSPACE_TOL
        if first is not None and n > 1:
            conv[:, 0] = True  # invariant by construction (the flow maps f onto itself)
        newly = (np.all(conv, axis=1) | (sweep == _MAX_SWEEPS - 1)) & ~done
        if sweep == 0:
            final = [Q0.copy(), QK.copy(), Rs.copy(), conv.copy()]
        for arr, new in zip(final, (Q0, QK, Rs, conv), strict=True):
            arr[~done] = new[~done]
        done |= newly
        if np.all(done):
            break
        Q0 = QK
    Q0, QK, Rs, conv = final
    B = np.swapaxes(Q0, 1, 2) @ QK
    logm = np.empty((n_orb, n))
    phase = np.empty((n_orb, n), dtype=complex)
    cuts_of = [tuple([0] + [k + 1 for k in range(n - 1) if c[k]] + [n]) for c in conv]
    for cuts in set(cuts_of):
        rows = np.array([c == cuts for c in cuts_of])
        for a, b in itertools.pairwise(cuts):
            logm[rows, a:b], phase[rows, a:b] = _cluster_eigenvalues(B[rows], Rs[rows], a, b)
    return logm, phase, conv


def floquet(
    rhs: Callable,
    orbits: np.ndarray,
    periods: np.ndarray,
    ps: np.ndarray,
    *,
    autonomous: bool,
) -> Floquet:
    """Floquet multipliers of a batch of orbits (module docstring).

    Parameters
    ----------
    rhs : callable ``(x, t, p) -> dx``
        Right-hand side (time enters for forced systems; the orbit starts at t = 0).
    orbits : array of shape (n_orbits, M, n), or a sequence of ``(M_i, n)`` arrays
        Collocation values on ``t_k = T k / M`` (each orbit on its own mesh).
    periods : array of shape (n_orbits,)
    ps : array of shape (n_orbits, n_params)
    autonomous : bool
        Deflate the trivial multiplier (autonomous orbits).
    """
    n_orb = len(orbits)
    n = int(np.shape(orbits[0])[1]) if n_orb else 0
    if n_orb == 0:
        return Floquet(
            np.empty((0, n), complex), np.empty((0, n)), np.empty(0, int), np.empty(0, bool)
        )
    factors, ok, f0, _ = monodromy_factors(rhs, orbits, periods, ps)
    good = ok & np.all(np.isfinite(f0), axis=1)
    if autonomous:
        good &= np.linalg.norm(f0, axis=1) > 0
    safe = np.where(good[:, None, None, None], factors, np.eye(n))
    f_start = np.where(good[:, None], f0, np.eye(n)[0]) if autonomous else None
    with np.errstate(all="ignore"):
        logm, phase, _ = periodic_eigenvalues(safe, f_start)
    trivial = np.zeros(n_orb, int) if autonomous else np.full(n_orb, -1)
    order = np.argsort(-logm, axis=1, kind="stable")
    logm = np.take_along_axis(logm, order, axis=1)
    phase = np.take_along_axis(phase, order, axis=1)
    if autonomous:
        trivial = np.argmax(order == 0, axis=1)
    with np.errstate(over="ignore", under="ignore"):
        mults = np.exp(logm) * phase
    logm[~good] = np.nan
    mults[~good] = np.nan
    return Floquet(mults, logm, trivial, good)


#: largest distance (relative to ``max(1, |nu|)``) between an eigenvalue ``nu +- i`` of the
#: collocation operator and its nearest eigenvalue for ``nu`` to count as a resolved
#: Floquet exponent (:func:`collocation_floquet`)
ALIAS_TOL = 1e-6
#: the strip ``-1/2 + _STRIP_SHIFT < Im nu <= 1/2 + _STRIP_SHIFT`` holds one eigenvalue of
#: every multiplier (the shift keeps the two aliases of a real negative one apart)
_STRIP_SHIFT = 1e-6


def collocation_floquet(operators: Sequence[np.ndarray], n: int) -> Floquet:
    """Floquet multipliers of autonomous orbits from their collocation operators (module
    docstring).

    Parameters
    ----------
    operators : sequence of arrays of shape (M_i n, M_i n)
        ``L = D_M (x) I - (T / 2 pi) blockdiag(f_x(v_k))`` of each orbit: the mesh block
        of the collocation Jacobian (thesis eq. 4.14).
    n : int
        Number of states.

    Returns
    -------
    Floquet
        Multipliers by decreasing modulus with the trivial one (the eigenvalue nearest 0)
        marked; ``ok`` False where fewer than ``n`` eigenvalues have their aliases to
        :data:`ALIAS_TOL`.
    """
    N = len(operators)
    mults = np.full((N, n), np.nan, dtype=complex)
    logm = np.full((N, n), np.nan)
    trivial = np.zeros(N, int)
    ok = np.zeros(N, bool)
    with one_blas_thread(user_api=None):
        for i, L in enumerate(operators):
            L = np.asarray(L, dtype=float)
            if not np.all(np.isfinite(L)):
                continue
            nu = np.linalg.eigvals(L)
            strip = nu[(nu.imag > -0.5 + _STRIP_SHIFT) & (nu.imag <= 0.5 + _STRIP_SHIFT)]
            if strip.size < n:
                continue
            up = np.min(np.abs(nu[None, :] - (strip[:, None] + 1j)), axis=1)
            down = np.min(np.abs(nu[None, :] - (strip[:, None] - 1j)), axis=1)
            miss = np.maximum(up, down) / np.maximum(1.0, np.abs(strip))
            keep = np.argsort(miss, kind="stable")[:n]
            if miss[keep[-1]] > ALIAS_TOL:
                continue
            sel = strip[keep]
            lm = -2.0 * np.pi * sel.real
            order = np.argsort(-lm, kind="stable")
            sel, lm = sel[order], lm[order]
            trivial[i] = int(np.argmin(np.abs(sel)))
            with np.errstate(over="ignore", under="ignore"):
                mults[i] = np.exp(lm) * np.exp(-2j * np.pi * sel.imag)
            logm[i] = lm
            ok[i] = True
    return Floquet(mults, logm, trivial, ok)


def monodromy(
    rhs: Callable,
    orbits: np.ndarray,
    periods: np.ndarray,
    ps: np.ndarray,
    *,
    steps_per_mesh: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Monodromy matrices of a batch of orbits, formed as the product of the factors
    of :func:`monodromy_factors` (they over- or underflow on strongly contracting or
    expanding orbits: use :func:`floquet_multipliers` for the multipliers).
    ``steps_per_mesh`` is ignored (the integration is error-controlled).

    Returns
    -------
    Phi : array of shape (n_orbits, n, n)
    ok : bool array of shape (n_orbits,)
    """
    factors, ok, _, scale = monodromy_factors(rhs, orbits, periods, ps)
    Psi = np.broadcast_to(np.eye(factors.shape[-1]), factors.shape[:1] + factors.shape[2:]).copy()
    with np.errstate(all="ignore"):
        for j in range(factors.shape[1]):
            Psi = factors[:, j] @ Psi
        Phi = scale[:, :, None] * Psi / scale[:, None, :]
    return Phi, ok & np.all(np.isfinite(Phi), axis=(1, 2))


@functools.lru_cache(maxsize=64)
def autonomous_rhs(field: Callable) -> Callable:
    """The right-hand side ``(x, t, p) -> field(x, p)`` of an autonomous system, in the form
    :func:`floquet` and :func:`monodromy` take it.

    One object per field (cached), so that repeated calls reuse the compiled integrator.
    """

    def rhs(x, t, p):
        return field(x, p)

    return rhs


def floquet_multipliers(
    rhs: Callable,
    orbits: np.ndarray,
    periods: np.ndarray,
    ps: np.ndarray,
    *,
    autonomous: bool,
    steps_per_mesh: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Floquet multipliers, stability and the largest non-trivial modulus.

    The multipliers are computed stably for any contraction (module docstring); for
    autonomous orbits the trivial multiplier is deflated exactly and excluded from the
    stability decision, which uses the tolerance :data:`STABILITY_TOL`.
    ``steps_per_mesh`` is accepted for compatibility and ignored (the integration is
    error-controlled).

    Returns
    -------
    multipliers : complex array of shape (n_orbits, n), sorted by decreasing modulus
        (moduli below the smallest double are 0; see :func:`floquet` for ``log|mu|``)
    stable : bool array of shape (n_orbits,)
    floquet_max : array of shape (n_orbits,)
        Largest modulus among the non-trivial multipliers (NaN where it failed).
    """
    orbits, periods, ps = np.asarray(orbits), np.asarray(periods), np.asarray(ps)
    if (
        orbits.ndim != 3
        or periods.shape != orbits.shape[:1]
        or ps.ndim != 2
        or ps.shape[0] != orbits.shape[0]
    ):
        raise BifidInputError(
            "floquet_multipliers expects orbits (K, M, n), periods (K,) and parameter "
            f"vectors (K, P); got shapes {orbits.shape}, {periods.shape}, {ps.shape}."
        )
    if not (np.all(np.isfinite(orbits)) and np.all(np.isfinite(periods)) and np.all(periods > 0)):
        raise BifidInputError(
            "floquet_multipliers needs finite orbits and positive finite periods."
        )
    fl = floquet(rhs, orbits, periods, ps, autonomous=autonomous)
    label = fl.stable()
    return fl.multipliers, np.nan_to_num(label, nan=0.0).astype(bool), fl.floquet_max
