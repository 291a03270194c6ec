"""Fourier projections of sampled signals over whole periods (thesis eqs. 3.3, 3.24).

Everything here acts on measured samples as a protocol receives them from a rig: a
uniformly sampled record that is *trimmed to whole periods* before projecting, so that
the discrete projections are (up to sampling) the integrals of eqs. 3.3 and 3.24.
Projections are least-squares fits, which equal the integral projections on whole
periods and average white measurement noise down by ``sqrt(n_samples)``.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from bifid.errors import BifidInputError

__all__ = [
    "HarmonicSecant",
    "band_noise",
    "coefficient_noise",
    "estimate_frequency",
    "evaluate_series",
    "fourier_project",
    "periodic_amplitude",
    "polar_project",
    "whole_periods",
]


def coefficient_noise(residual: np.ndarray) -> float:
    """Noise floor (3σ) of a Fourier coefficient fitted to ``n`` samples with this residual.

    White measurement noise of standard deviation ``σ`` gives coefficients with standard
    deviation ``σ sqrt(2/n)``. ``σ`` is estimated from *first differences* of the residual
    (``std(Δe)/√2``), which white noise passes and a slow drift (an unfinished transient)
    does not: a response that has not settled must not be mistaken for noise and widen
    the convergence tolerance.
    """
    e = np.asarray(residual, dtype=float)
    if e.shape[0] < 3:
        return 0.0
    sigma = float(np.std(np.diff(e))) / math.sqrt(2.0)
    return 3.0 * sigma * math.sqrt(2.0 / e.shape[0])


def band_noise(residual: np.ndarray, omega: float, sample_rate: float) -> float:
    """Noise floor of the *fundamental* fitted to this residual: 3 × RMS of ``|(a_1, b_1)|``.

    :func:`coefficient_noise` assumes white noise. A control signal is not white: the
    derivative estimate in ``k_d ẋ`` differentiates the measurement noise, so nearly all
    of the control's noise power lies far above the forcing frequency, and its total
    variance overstates the uncertainty of the fundamental coefficient many times over
    (duffing, 1 % noise, ``k_p = k_d = 0.5`` at 100 Hz: 40-100×, the floor then equals the
    forcing itself). The variance of a fitted coefficient at ``Ω`` is the noise's power
    spectral density *near* ``Ω`` over the record length: here it is estimated from the
    periodogram of the residual (harmonics removed) on the bins of the band ``(0, 2Ω)``
    other than ``Ω``'s own -- ``2P - 2`` bins for a record of ``P`` periods: the pair
    ``(a, b) = (2/n)(Re X_k, -Im X_k)`` has ``E(a² + b²) = E|2X_k/n|²``. The magnitude of the
    pair, not each coefficient, is bounded: differentiated noise also leaks in through
    the record's ends (``e_n - e_0``, the same in every bin, comparable to the in-band
    part for short records), and that part falls on ``a`` or ``b`` depending on the phase
    at which the record ends. An unfinished transient raises these bins too: it widens
    the floor, which the caller must compare with the precision it needs (never read as
    "within noise, converged").

    Parameters
    ----------
    residual : array of shape (n,)
        Samples minus their fitted Fourier series (uniform sampling, whole periods).
    omega : float
        Forcing frequency [rad/s].
    sample_rate : float
        [Hz].
    """
    e = np.asarray(residual, dtype=float)
    n = e.shape[0]
    periods = n * omega / (2.0 * math.pi * sample_rate)
    if n < 8 or periods < 1.5:
        return float("inf")
    X = np.fft.rfft(e) * (2.0 / n)
    k = np.arange(X.shape[0])
    band = (k >= 1) & (k < 2.0 * periods - 0.5) & (np.abs(k - periods) >= 0.75)
    if not np.any(band):
        return float("inf")
    return 3.0 * math.sqrt(float(np.mean(np.abs(X[band]) ** 2)))


def whole_periods(n_samples: int, omega: float, sample_rate: float, max_periods: int | None = None
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
    x: np.ndarray, theta: np.ndarray, n_harmonics: int, weights: np.ndarray | None = None,
    *, basis: np.ndarray | None = None,
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
    # normal equations: the Fourier basis is near-orthogonal on whole periods, so B^T B is
    # well conditioned and this is ~50x cheaper than an SVD-based lstsq on long records
    BtB = B.T @ B
    try:
        coef = np.linalg.solve(BtB, B.T @ x)
    except np.linalg.LinAlgError:
        coef, *_ = np.linalg.lstsq(B, x, rcond=None)
    return coef


def evaluate_series(coef: np.ndarray, theta: np.ndarray, *,
                    basis: np.ndarray | None = None) -> np.ndarray:
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


def estimate_frequency(x: np.ndarray, sample_rate: float) -> float:
    """Angular frequency [rad/s] of a periodic signal from its mean crossings.

    Upward crossings of the mean, with a hysteresis of 20 % of the standard deviation
    against noise, located by linear interpolation; ``ω = 2π (n - 1) / (t_n - t_1)``.
    NaN when fewer than two crossings are found.
    """
    x = np.asarray(x, dtype=float)
    x = x - x.mean()
    sd = float(np.std(x))
    if sd == 0.0 or x.shape[0] < 4:
        return float("nan")
    h = 0.2 * sd
    z = np.where(x > h, 1, np.where(x < -h, -1, 0))
    idx = np.flatnonzero(z)
    if idx.size < 2:
        return float("nan")
    zz = z[idx]
    # transitions from below -h to above +h: the crossing lies between idx[i] and idx[i+1]
    ups = np.flatnonzero((zz[:-1] == -1) & (zz[1:] == 1))
    times = []
    for i in ups:
        lo, hi = idx[i], idx[i + 1]
        seg = x[lo : hi + 1]
        j = int(np.flatnonzero((seg[:-1] < 0) & (seg[1:] >= 0))[-1]) + lo
        frac = -x[j] / (x[j + 1] - x[j])
        times.append((j + frac) / sample_rate)
    if len(times) < 2:
        return float("nan")
    return float(2.0 * math.pi * (len(times) - 1) / (times[-1] - times[0]))


def periodic_amplitude(
    x: np.ndarray, omega: float, sample_rate: float, n_harmonics: int = 10, n_grid: int = 2048
) -> tuple[float, float]:
    """Noise-robust amplitude ``max_t |x(t) - x̄|`` of a periodic signal (eq. 6.5, centred).

    The record is trimmed to whole periods, replaced by its least-squares Fourier series
    with ``n_harmonics`` harmonics, and the maximum of the centred series is taken on a
    fine grid.

    Returns
    -------
    amplitude : float
    mean : float
    """
    x = np.asarray(x, dtype=float)
    n = whole_periods(x.shape[0], omega, sample_rate)
    xs = x[-n:]
    theta = omega * np.arange(n) / sample_rate
    coef = fourier_project(xs, theta, n_harmonics)
    grid = np.linspace(0.0, 2.0 * np.pi, n_grid, endpoint=False)
    centred = coef.copy()
    centred[0] = 0.0
    return float(np.max(np.abs(evaluate_series(centred, grid)))), float(coef[0])


class HarmonicSecant:
    """Picard iteration on Fourier coefficients, accelerated harmonic by harmonic.

    Used for the target updates ``c* ← c`` of eq. 3.8 (forced CBC) and of the polar
    target's shape (PP-CBC). For each harmonic ``k`` (complex ``z_k = a_k - i b_k``; the
    mean ``k = 0`` on its own) the response depends on the target roughly as
    ``z_k = M_k z_k^* + b_k``. Plain Picard (``z^* ← z``) converges like ``|M_k|^n`` and
    stalls where the controller makes the response follow the target closely
    (``|M_k| → 1``, e.g. near a lightly damped resonance at ``kΩ``). With ``M_k``
    estimated from the last two iterations, the secant step
    ``z^* ← z^* + (z - z^*) / (1 - M_k)`` solves the linear part exactly; it falls back to
    Picard (``M_k = 0``) where the estimate is unreliable (changes below the noise
    floor, or ``|M_k| > 1.5``) and keeps ``|1 - M_k| >= 0.1``.

    Parameters
    ----------
    q : int
        Harmonics in the coefficient vectors ``[c0, a_1..a_q, b_1..b_q]``.
    fixed : tuple of int
        Harmonics (0 = mean) that are not updated (e.g. the forced fundamental).
    """

    def __init__(self, q: int, fixed: tuple[int, ...] = ()):
        self.q = int(q)
        self.fixed = np.array(sorted(set(fixed)), dtype=int)
        self.prev: tuple[np.ndarray, np.ndarray] | None = None

    def _complex(self, p: np.ndarray) -> np.ndarray:
        q = self.q
        return np.concatenate([[p[0]], p[1 : q + 1] - 1j * p[q + 1 :]])

    def _real(self, z: np.ndarray) -> np.ndarray:
        return np.concatenate([[z[0].real], z[1:].real, -z[1:].imag])

    def step(self, pstar: np.ndarray, p: np.ndarray, floor: float) -> np.ndarray:
        """The next target from the current target ``pstar`` and response ``p``."""
        zs, z = self._complex(np.asarray(pstar, float)), self._complex(np.asarray(p, float))
        M = np.zeros_like(z)
        if self.prev is not None:
            zs0, z0 = self.prev
            dzs, dz = zs - zs0, z - z0
            ok = np.abs(dzs) > 10.0 * max(floor, 1e-300)
            M[ok] = dz[ok] / dzs[ok]
            M[np.abs(M) > 1.5] = 0.0
            near = np.abs(1.0 - M) < 0.1
            M[near] = 1.0 - 0.1 * (1.0 - M[near]) / np.maximum(np.abs(1.0 - M[near]), 1e-300)
        self.prev = (zs, z)
        new = zs + (z - zs) / (1.0 - M)
        if self.fixed.size:
            new[self.fixed] = zs[self.fixed]
        return self._real(new)
