"""Amplitudes and spectra of periodic signals (thesis eq. 6.5)."""

from __future__ import annotations

import math

import numpy as np

from bifid.signal._series import (
    evaluate_series,
    fourier_coefficients,
    fourier_fit,
    fourier_project,
    whole_periods,
)

__all__ = [
    "aligned_orbit_error",
    "first_harmonic",
    "max_abs",
    "periodic_amplitude",
    "phase_lag",
    "spectral_tail",
]


def max_abs(values: np.ndarray) -> np.ndarray:
    """Amplitude ``max_t |x(t)|`` (thesis eq. 6.5) of each column of periodic mesh values.

    The maximum of the trigonometric interpolant is found on a 16× finer grid and
    refined by Newton's method on its derivative, so the result is accurate to the
    collocation accuracy, not to the mesh spacing.

    Parameters
    ----------
    values : array of shape (M,) or (M, n)

    Returns
    -------
    float or array of shape (n,)
    """
    v = np.asarray(values, dtype=float)
    squeeze = v.ndim == 1
    if squeeze:
        v = v[:, None]
    M, n = v.shape
    a0, a, b = fourier_coefficients(v)
    fine = np.fft.irfft(np.fft.rfft(v, axis=0), n=16 * M, axis=0) * 16
    k = np.arange(1, a.shape[0] + 1)
    out = np.empty(n)
    for j in range(n):
        i = int(np.argmax(np.abs(fine[:, j])))
        t = 2.0 * np.pi * i / (16 * M)
        for _ in range(8):
            c, s = np.cos(k * t), np.sin(k * t)
            d1 = np.sum(k * (-a[:, j] * s + b[:, j] * c))
            d2 = np.sum(k**2 * (-a[:, j] * c - b[:, j] * s))
            if d2 == 0.0:
                break
            step = d1 / d2
            t -= float(np.clip(step, -np.pi / M, np.pi / M))
            if abs(step) < 1e-15:
                break
        val = a0[j] + np.sum(a[:, j] * np.cos(k * t) + b[:, j] * np.sin(k * t))
        out[j] = max(abs(val), float(np.max(np.abs(fine[:, j]))))
    return out[0] if squeeze else out


def spectral_tail(values: np.ndarray) -> float:
    """Relative size of the top quarter of the Fourier spectrum of periodic mesh values.

    ``max |c_k|, k >= 3M/8`` divided by ``max |c_k|, k >= 1``, over all columns. A
    well-resolved smooth orbit gives round-off level (< 1e-10); a large value means the
    mesh is too coarse or the collocation shows a spurious (aliasing) resonance.
    """
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        v = v[:, None]
    c = np.abs(np.fft.rfft(v - v.mean(axis=0), axis=0))
    M = v.shape[0]
    top = c[int(3 * M / 8) :].max()
    ref = c[1:].max()
    return float(top / ref) if ref > 0 else 0.0


def periodic_amplitude(
    x: np.ndarray,
    omega: float,
    sample_rate: float,
    n_harmonics: int = 10,
    *,
    trim: bool = True,
    n_grid: int = 2048,
) -> tuple[float, float]:
    """Noise-robust amplitude ``max_t |x(t) − x̄|`` of a sampled periodic signal (eq. 6.5,
    about the mean, as a rig measures it).

    The record (trimmed to whole periods when ``trim``) is replaced by its least-squares
    Fourier series with ``n_harmonics`` harmonics at ``omega``, whose centred maximum is
    taken on ``n_grid`` phases: measurement noise, which inflates a raw ``max |x|``, is
    filtered out; harmonics above ``n_harmonics`` are lost.

    Returns
    -------
    amplitude : float
    mean : float
        ``c0``, the offset of the orbit.
    """
    x = np.asarray(x, dtype=float)
    if trim:
        n = whole_periods(x.shape[0], omega, sample_rate)
        x = x[-n:]
        coef = fourier_project(x, omega * np.arange(n) / sample_rate, n_harmonics)
    else:
        coef = fourier_fit(x, omega, sample_rate, n_harmonics)
    grid = np.linspace(0.0, 2.0 * np.pi, n_grid, endpoint=False)
    centred = coef.copy()
    centred[0] = 0.0
    return float(np.max(np.abs(evaluate_series(centred, grid)))), float(coef[0])


def first_harmonic(
    x: np.ndarray, omega: float, sample_rate: float, n_harmonics: int = 7
) -> complex:
    """Complex first-harmonic coefficient ``c`` of ``x(t) ≈ x0 + Re(c e^{iωt}) + ...``.

    Least-squares fit (:func:`~bifid.signal.fourier_fit`) with ``n_harmonics`` harmonics
    (fewer for short records or near Nyquist), so that higher harmonics do not leak into
    the first even when the record is not a whole number of periods; ``c = a_1 − i b_1``,
    ``|c|`` is the amplitude and ``arg c`` the phase of the first harmonic.
    """
    coef = fourier_fit(np.asarray(x, dtype=float), omega, sample_rate, n_harmonics)
    K = (coef.shape[0] - 1) // 2
    return complex(coef[1], -coef[K + 1])


def phase_lag(x: np.ndarray, force: np.ndarray, omega: float, sample_rate: float) -> float:
    """Lag of the first harmonic of ``x`` behind that of ``force`` [rad].

    ``lag = arg F₁ − arg X₁`` wrapped to ``[−π/2, 3π/2)``, so that the usual range of a
    forced oscillator, 0 (below resonance) → π/2 (at resonance) → π (above), never wraps.
    NaN if either harmonic vanishes.
    """
    cx = first_harmonic(x, omega, sample_rate)
    cf = first_harmonic(force, omega, sample_rate)
    if abs(cx) == 0.0 or abs(cf) == 0.0:
        return float("nan")
    lag = math.atan2(cf.imag, cf.real) - math.atan2(cx.imag, cx.real)
    return float((lag + math.pi / 2) % (2 * math.pi) - math.pi / 2)


def aligned_orbit_error(orbit: np.ndarray, reference: np.ndarray) -> float:
    """Largest relative RMS error over the signals of one period, after the best time shift.

    Parameters
    ----------
    orbit, reference : ndarray of shape (n, s) and (m, s)
        One period of ``s`` signals each, on uniform grids of any sizes.

    Returns
    -------
    float
        ``max_j ||orbit_j - ref_j|| / ||ref_j||`` (RMS norms), where ``ref`` is the reference
        trigonometrically resampled to the orbit's grid and circularly shifted so that its
        first signal best matches the orbit's (the phase of a periodic orbit is arbitrary).
    """
    orbit, reference = np.asarray(orbit, dtype=float), np.asarray(reference, dtype=float)
    n = orbit.shape[0]
    c = np.fft.rfft(reference, axis=0)
    k = min(c.shape[0], n // 2 + 1)
    ref = np.fft.irfft(c[:k], n=n, axis=0) * (n / reference.shape[0])
    best = np.argmax([np.dot(np.roll(ref[:, 0], s), orbit[:, 0]) for s in range(n)])
    ref = np.roll(ref, best, axis=0)
    rms = np.sqrt(np.mean(ref**2, axis=0))
    return float(np.max(np.sqrt(np.mean((orbit - ref) ** 2, axis=0)) / rms))
