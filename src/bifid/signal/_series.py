"""Fourier series of sampled signals (thesis eqs. 3.3, 3.24).

Two kinds of input, one set of tools:

- *records*: uniformly sampled signals ``x_k = x(k / fs)`` of any length, as a rig or an
  importer gives them; coefficients by least squares at a known frequency
  (:func:`fourier_project` on given phases, :func:`fourier_fit` on a record,
  :func:`fourier_project_segments` period by period, :func:`fourier_project_batch` for
  many records at once), trimmed to whole periods where the discrete projection must
  equal the integral of eq. 3.3 (:func:`whole_periods`);
- *one period on a uniform grid* (collocation meshes, resampled orbits):
  :func:`fourier_coefficients` by FFT and :func:`evaluate_fourier`.

Coefficient vectors of records are ``[c0, a_1..a_q, b_1..b_q]`` for
``x ≈ c0 + Σ a_j cos jθ + b_j sin jθ`` (eq. 3.3 writes the mean as ``A0/2``: ``A0 = 2 c0``).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from bifid.errors import BifidInputError

__all__ = [
    "evaluate_fourier",
    "evaluate_series",
    "fourier_basis",
    "fourier_coefficients",
    "fourier_fit",
    "fourier_project",
    "fourier_project_batch",
    "fourier_project_segments",
    "polar_project",
    "uniform_basis",
    "usable_harmonics",
    "whole_periods",
]


def whole_periods(
    n_samples: int, omega: float, sample_rate: float, max_periods: int | None = None
) -> int:
    """Number of trailing samples spanning the largest whole number of periods.

    Parameters
    ----------
    n_samples : int
        Samples available.
    omega : float
        Angular frequency [rad/s].
    sample_rate : float
        [Hz].
    max_periods : int, optional
        Use at most this many periods.

    Raises
    ------
    BifidInputError
        If the record is shorter than one period.
    """
    if not (omega > 0 and math.isfinite(omega)):
        raise BifidInputError(f"omega must be a positive frequency, got {omega!r}.")
    per = 2.0 * math.pi / omega * sample_rate  # samples per period
    m = math.floor(n_samples / per + 1e-9)
    if max_periods is not None:
        m = min(m, int(max_periods))
    if m < 1:
        raise BifidInputError(
            f"the record ({n_samples} samples) is shorter than one period ({per:.0f} samples)."
        )
    return min(n_samples, round(m * per))


def _basis(theta: np.ndarray, n_harmonics: int) -> np.ndarray:
    """``[1, cos θ..cos qθ, sin θ..sin qθ]`` per sample.

    Powers of ``e^{iθ}`` by repeated multiplication (error ~k·1e-16) instead of ``2qn``
    transcendentals: the projections run thousands of times per campaign on records of
    10^4-10^5 samples, and the trigonometric functions were most of their cost.
    """
    n = theta.shape[0]
    Bt = np.empty((2 * n_harmonics + 1, n))  # rows written contiguously, returned transposed
    Bt[0] = 1.0
    if n_harmonics == 0:
        return Bt.T
    c1, s1 = np.cos(theta), np.sin(theta)
    Bt[1], Bt[n_harmonics + 1] = c1, s1
    for k in range(2, n_harmonics + 1):
        c, s = Bt[k - 1], Bt[n_harmonics + k - 1]
        np.subtract(c * c1, s * s1, out=Bt[k])
        np.add(s * c1, c * s1, out=Bt[n_harmonics + k])
    return Bt.T


def fourier_basis(theta: np.ndarray, n_harmonics: int) -> np.ndarray:
    """The design matrix ``[1, cos jθ, sin jθ]`` of :func:`fourier_project` (to reuse it)."""
    return _basis(np.asarray(theta, dtype=float), int(n_harmonics))


@functools.lru_cache(maxsize=16)
def uniform_basis(n_points: int, n_harmonics: int) -> np.ndarray:
    """:func:`fourier_basis` on ``n_points`` uniform angles of ``[0, 2π)`` (cached, read-only)."""
    B = _basis(np.linspace(0.0, 2.0 * np.pi, n_points, endpoint=False), n_harmonics)
    B = np.ascontiguousarray(B)
    B.setflags(write=False)
    return B


def fourier_project(
    x: np.ndarray,
    theta: np.ndarray,
    n_harmonics: int,
    weights: np.ndarray | None = None,
    *,
    basis: np.ndarray | None = None,
) -> np.ndarray:
    """Coefficients ``[c0, a_1..a_q, b_1..b_q]`` of ``x ≈ c0 + Σ a_j cos jθ + b_j sin jθ``.

    ``theta`` is the phase of each sample (``Ω t`` or the forcing generator's phase).
    Note that eq. 3.3 writes the mean as ``A0/2``: ``A0 = 2 c0``.

    Parameters
    ----------
    x : array of shape (n,) or (n, m)
    theta : array of shape (n,)
    n_harmonics : int
    weights : array of shape (n,), optional
        Quadrature weights (e.g. ``|Δφ|`` for projections over an angle).
    basis : array of shape (n, 2q+1), optional
        ``fourier_basis(theta, n_harmonics)`` computed before (e.g. rows of a longer
        record's basis); ``theta`` is then not used.

    Returns
    -------
    ndarray of shape (2q+1,) or (2q+1, m)
    """
    x = np.asarray(x, dtype=float)
    B = _basis(np.asarray(theta, dtype=float), int(n_harmonics)) if basis is None else basis
    if weights is not None:
        w = np.sqrt(np.asarray(weights, dtype=float))
        B = B * w[:, None]
        x = x * (w if x.ndim == 1 else w[:, None])
    return _solve_normal(B, x)


def fourier_project_batch(
    x: np.ndarray, basis: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """:func:`fourier_project` of ``p`` independent records at once (e.g. the periods of
    one record, each fitted on its own): one stacked normal-equation solve.

    Records of unequal lengths are padded to a common length with rows of zeros in both
    ``x`` and ``basis`` (a zero row adds nothing to the normal equations).

    Parameters
    ----------
    x : array of shape (p, n) or (p, n, m)
    basis : array of shape (p, n, 2q+1)
        :func:`fourier_basis` of each record's phases.
    weights : array of shape (p, n), optional
        Quadrature weights, as in :func:`fourier_project`.

    Returns
    -------
    ndarray of shape (p, 2q+1) or (p, 2q+1, m)
    """
    x = np.asarray(x, dtype=float)
    B = np.asarray(basis, dtype=float)
    if weights is not None:
        w = np.sqrt(np.asarray(weights, dtype=float))
        B = B * w[..., None]
        x = x * (w if x.ndim == 2 else w[..., None])
    if x.ndim == 2:
        return _solve_normal(B, x[..., None])[..., 0]
    return _solve_normal(B, x)


def fourier_project_segments(
    x: np.ndarray, theta: np.ndarray, edges: np.ndarray, n_harmonics: int
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fourier_project` of each segment ``[edges[k], edges[k+1])`` of one record on
    its own (e.g. period by period), with their residuals.

    The phases must advance by a constant step (a uniformly sampled record at a fixed
    frequency): every segment's basis is then one basis ``B0`` of the step rotated by the
    segment's first phase, so the fits share one normal matrix per segment length, and the
    coefficients on ``B0`` are rotated back (``a_j, b_j`` by the angle ``j θ_lo``).

    Parameters
    ----------
    x : array of shape (n,) or (n, m)
    theta : array of shape (n,)
        Phase of each sample, ``θ_0 + k Δθ``.
    edges : sequence of int
        Increasing sample indices; segment ``k`` is ``[edges[k], edges[k+1])``.
    n_harmonics : int

    Returns
    -------
    coef : ndarray of shape (p, 2q+1) or (p, 2q+1, m)
        One row ``[c0, a_1..a_q, b_1..b_q]`` per segment.
    residual : ndarray of shape (edges[-1] - edges[0],) or (.., m)
        Samples minus their segment's fitted series, segments in order.

    Raises
    ------
    BifidInputError
        If the phases do not advance by a constant step.
    """
    x = np.asarray(x, dtype=float)
    X = x[:, None] if x.ndim == 1 else x
    theta = np.asarray(theta, dtype=float)
    step = (theta[-1] - theta[0]) / max(theta.shape[0] - 1, 1)
    if np.ptp(np.diff(theta)) > 1e-9 * abs(step):
        raise BifidInputError("segment fits need phases that advance by a constant step.")
    q, m = int(n_harmonics), X.shape[1]
    edges = np.asarray(edges, dtype=int)
    lo, size = edges[:-1], np.diff(edges)
    B0 = _basis(step * np.arange(int(np.max(size))), q)
    c = np.empty((lo.shape[0], 2 * q + 1, m))
    for length in np.unique(size):  # one normal matrix per segment length
        sel = np.flatnonzero(size == length)
        rhs = np.stack([X[k : k + length] for k in lo[sel]], axis=1).reshape(length, -1)
        c[sel] = _solve_normal(B0[:length], rhs).reshape(2 * q + 1, -1, m).transpose(1, 0, 2)
    fit = (B0 @ c.transpose(1, 0, 2).reshape(2 * q + 1, -1)).reshape(B0.shape[0], -1, m)
    residual = np.empty((edges[-1] - edges[0], m))
    for k, (start, length) in enumerate(zip(lo - edges[0], size, strict=True)):
        residual[start : start + length] = X[lo[k] : lo[k] + length] - fit[:length, k]
    # rotate back: the basis of segment k is B0 at phases shifted by θ_lo
    jt = np.multiply.outer(theta[lo], np.arange(1, q + 1))[..., None]
    cos, sin = np.cos(jt), np.sin(jt)
    a, b = c[:, 1 : q + 1].copy(), c[:, q + 1 :].copy()
    c[:, 1 : q + 1] = a * cos - b * sin
    c[:, q + 1 :] = a * sin + b * cos
    return (c[..., 0], residual[:, 0]) if x.ndim == 1 else (c, residual)


def _solve_normal(B: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Least-squares ``B c = x`` for one design matrix ``(n, k)`` or a stack ``(p, n, k)``.

    Normal equations: the Fourier basis is near-orthogonal on whole periods, so ``BᵀB`` is
    well conditioned and this is ~50x cheaper than an SVD-based lstsq on long records.
    Systems whose condition number exceeds 1e10 (short or gappy records) fall back to
    lstsq; the test uses the eigenvalues of the symmetric ``BᵀB`` (half the cost of the
    SVD of ``np.linalg.cond``)."""
    Bt = np.swapaxes(B, -1, -2)
    BtB = Bt @ B
    try:
        ev = np.linalg.eigvalsh(BtB)
    except np.linalg.LinAlgError:
        ev = np.zeros(BtB.shape[:-1])
        ev[..., -1] = 1.0
    good = ev[..., 0] > 1e-10 * ev[..., -1]
    if B.ndim == 2:
        if good:
            return np.linalg.solve(BtB, Bt @ x)
        return np.linalg.lstsq(B, x, rcond=None)[0]
    c = np.empty(B.shape[:1] + B.shape[2:] + x.shape[2:])
    if np.any(good):
        c[good] = np.linalg.solve(BtB[good], Bt[good] @ x[good])
    for i in np.flatnonzero(~good):
        c[i] = np.linalg.lstsq(B[i], x[i], rcond=None)[0]
    return c


def evaluate_series(
    coef: np.ndarray, theta: np.ndarray, *, basis: np.ndarray | None = None
) -> np.ndarray:
    """``c0 + Σ a_j cos jθ + b_j sin jθ`` for ``coef = [c0, a_1..a_q, b_1..b_q]``
    (``basis``: ``fourier_basis(theta, q)`` computed before)."""
    coef = np.asarray(coef, dtype=float)
    q = (coef.shape[0] - 1) // 2
    B = _basis(np.asarray(theta, dtype=float), q) if basis is None else basis
    return B @ coef


def polar_project(phi: np.ndarray, r: np.ndarray, n_harmonics: int) -> np.ndarray:
    """Fourier coefficients of ``r(φ)`` from samples along a closed curve, eq. 3.24.

    Samples come uniformly in *time*, not in ``φ``; the integral over ``φ`` is
    discretised with the weights ``|Δφ_k|`` (central differences of the unwrapped angle),
    so that ``a0 = (1/2π) ∫ r dφ`` etc. over the whole turns contained in the record.

    Returns
    -------
    ndarray of shape (2 n_h + 1,)
        ``[a0, a_1..a_nh, b_1..b_nh]``.
    """
    phi = np.asarray(phi, dtype=float)
    un = np.unwrap(phi)
    d = np.gradient(un)
    return fourier_project(r, phi, n_harmonics, weights=np.abs(d))


def usable_harmonics(n: int, omega: float, sample_rate: float, n_harmonics: int) -> int:
    """At most ``n_harmonics``, fewer when ``kω`` nears Nyquist or samples are few (≥ 1).

    Raises
    ------
    BifidInputError
        For a non-positive frequency or sample rate, or a frequency above Nyquist.
    """
    if not (np.isfinite(omega) and omega > 0 and np.isfinite(sample_rate) and sample_rate > 0):
        raise BifidInputError(
            f"Fourier fit needs a finite frequency > 0 and sample rate > 0, got omega={omega!r}, "
            f"sample_rate={sample_rate!r}."
        )
    k_nyquist = int(0.9 * np.pi * sample_rate / omega)
    if k_nyquist < 1:
        raise BifidInputError(
            f"frequency {omega / (2 * np.pi):g} Hz is above the Nyquist frequency "
            f"{sample_rate / 2:g} Hz of the samples."
        )
    return max(1, min(n_harmonics, k_nyquist, (n - 1) // 4))


def fourier_fit(x: np.ndarray, omega: float, sample_rate: float, n_harmonics: int) -> np.ndarray:
    """Least-squares truncated Fourier series of a record at the known frequency ``omega``.

    Fits ``x(t) ≈ c0 + Σ_{k=1..K} (a_k cos kωt + b_k sin kωt)`` on ``t_j = j / fs``
    (any record length; whole periods not required), with ``K`` from
    :func:`usable_harmonics`.

    Returns
    -------
    ndarray, shape (2K + 1,)
        ``[c0, a_1..a_K, b_1..b_K]``.

    Raises
    ------
    BifidInputError
        For non-finite samples, or a frequency the samples cannot resolve.
    """
    coefs, _ = fourier_fit_columns(
        np.asarray(x, dtype=float)[:, None], omega, sample_rate, n_harmonics
    )
    return coefs[0]


def fourier_fit_columns(
    x: np.ndarray, omega: float, sample_rate: float, n_harmonics: int
) -> tuple[list[np.ndarray], np.ndarray]:
    """:func:`fourier_fit` of every signal (column) of a record ``(n, m)`` on one design
    matrix: the coefficients per signal and the matrix (rows: samples; pass it as
    ``basis`` to :func:`evaluate_series` at the samples).

    Raises
    ------
    BifidInputError
        For non-finite samples, or a frequency the samples cannot resolve.
    """
    x = np.asarray(x, dtype=float)
    if not np.all(np.isfinite(x)):
        raise BifidInputError("cannot fit a Fourier series to non-finite samples.")
    K = usable_harmonics(x.shape[0], omega, sample_rate, n_harmonics)
    theta = omega * np.arange(x.shape[0]) / sample_rate
    B = fourier_basis(theta, K)
    return list(fourier_project(x, theta, K, basis=B).T), B


def fourier_coefficients(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Real Fourier coefficients of mesh values.

    Parameters
    ----------
    values : array of shape (M, ...) on the grid ``tau_k``.

    Returns
    -------
    a0 : array of shape (...)
        Mean.
    a, b : arrays of shape (M//2, ...)
        ``x(tau) = a0 + sum_k a[k-1] cos(k tau) + b[k-1] sin(k tau)``, ``k = 1..M/2``
        (the Nyquist term is halved so the interpolant is the symmetric one).
    """
    v = np.asarray(values, dtype=float)
    M = v.shape[0]
    c = np.fft.rfft(v, axis=0) / M
    a0 = c[0].real
    a = 2.0 * c[1:].real
    b = -2.0 * c[1:].imag
    a[-1] = a[-1] / 2.0  # Nyquist
    b[-1] = 0.0
    return a0, a, b


def evaluate_fourier(a0, a, b, tau):
    """Evaluate ``a0 + sum a_k cos k tau + b_k sin k tau`` at ``tau`` (any shape)."""
    tau = np.asarray(tau, dtype=float)
    k = np.arange(1, a.shape[0] + 1)
    ang = np.multiply.outer(tau, k)  # (..., K)
    return a0 + np.cos(ang) @ a + np.sin(ang) @ b
