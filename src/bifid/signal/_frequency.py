"""Frequency of a sampled periodic signal, and the noise floor of its Fourier coefficients."""

from __future__ import annotations

import math

import numpy as np

from bifid.errors import BifidInputError

__all__ = ["band_noise", "coefficient_noise", "estimate_frequency"]


def estimate_frequency(x: np.ndarray, sample_rate: float, *, method: str = "spectrum") -> float:
    """Dominant angular frequency of a uniformly sampled signal [rad/s]; NaN when none.

    Two estimators, for two situations:

    ``"spectrum"`` (default)
        Hann-windowed FFT of the mean-removed signal, zero-padded ×4, the peak bin refined
        by parabolic interpolation of the log magnitude (resolution about
        ``0.1 · 2π fs / n`` for a clean sinusoid). Robust to noise and to harmonics:
        what importers of measured records use.
    ``"crossings"``
        Upward crossings of the mean with a hysteresis of 20 % of the standard deviation,
        located by linear interpolation; ``ω = 2π (n − 1) / (t_n − t_1)``. Exact for a
        periodic signal over a few periods: what CBC uses between target updates.
    """
    if method == "spectrum":
        return _spectrum_frequency(x, sample_rate)
    if method == "crossings":
        return _crossings_frequency(x, sample_rate)
    raise BifidInputError(f"method must be 'spectrum' or 'crossings', got {method!r}.")


def _spectrum_frequency(x: np.ndarray, sample_rate: float) -> float:
    """Dominant angular frequency of ``x`` [rad/s] from its spectrum.

    Hann-windowed FFT of the mean-removed signal, zero-padded ×4; the peak bin is refined
    by parabolic interpolation of the log magnitude. Resolution is about
    ``0.1 · 2π fs / n`` for a clean sinusoid. Returns NaN for a constant signal.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    if n < 8:
        return float("nan")
    y = (x - x.mean()) * np.hanning(n)
    nfft = 4 * int(2 ** np.ceil(np.log2(n)))
    mag = np.abs(np.fft.rfft(y, nfft))
    mag[0] = 0.0
    k = int(np.argmax(mag))
    if mag[k] == 0.0:
        return float("nan")
    if 0 < k < mag.shape[0] - 1:
        a, b, c = np.log(mag[k - 1 : k + 2] + 1e-300)
        denom = a - 2 * b + c
        delta = 0.5 * (a - c) / denom if denom != 0 else 0.0
    else:
        delta = 0.0
    return float(2 * np.pi * (k + delta) * sample_rate / nfft)


def _crossings_frequency(x: np.ndarray, sample_rate: float) -> float:
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
