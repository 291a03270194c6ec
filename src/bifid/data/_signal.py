"""Small signal-processing helpers used by the importers.

All act on one uniformly sampled 1-D signal ``x_k = x(k / fs)``.
"""

from __future__ import annotations

import numpy as np

from bifid.errors import BifidInputError

__all__ = ["estimate_frequency", "fill_gaps", "fourier_fit", "periodic_max_abs"]


def _basis(n: int, omega: float, sample_rate: float, n_harmonics: int) -> np.ndarray:
    t = np.arange(n) / sample_rate
    cols = [np.ones(n)]
    for k in range(1, n_harmonics + 1):
        cols += [np.cos(k * omega * t), np.sin(k * omega * t)]
    return np.stack(cols, axis=1)


def _usable_harmonics(n: int, omega: float, sample_rate: float, n_harmonics: int) -> int:
    """At most ``n_harmonics``, fewer when ``kω`` nears Nyquist or samples are few (≥ 1)."""
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


def _lstsq(basis: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Least squares by the normal equations (the Fourier basis is well conditioned over
    more than a period), falling back to SVD when they are singular."""
    if not (np.all(np.isfinite(basis)) and np.all(np.isfinite(x))):
        raise BifidInputError("cannot fit a Fourier series to non-finite samples or frequency.")
    gram = basis.T @ basis
    try:
        cond = np.linalg.cond(gram)
        if np.isfinite(cond) and cond < 1e10:
            return np.linalg.solve(gram, basis.T @ x)
    except np.linalg.LinAlgError:
        pass
    return np.linalg.lstsq(basis, x, rcond=None)[0]


def fourier_fit(x: np.ndarray, omega: float, sample_rate: float, n_harmonics: int) -> np.ndarray:
    """Least-squares truncated Fourier series of ``x`` at the known frequency ``omega``.

    Fits ``x(t) ≈ a_0 + Σ_{k=1..K} (a_k cos kωt + b_k sin kωt)`` on ``t_j = j / fs``
    (any record length; whole periods not required).

    Returns
    -------
    ndarray, shape (2K + 1,)
        ``[a_0, a_1, b_1, a_2, b_2, ...]``.
    """
    x = np.asarray(x, dtype=float)
    return _lstsq(_basis(x.shape[0], omega, sample_rate, _usable_harmonics(
        x.shape[0], omega, sample_rate, n_harmonics)), x)


def _evaluate(coef: np.ndarray, theta: np.ndarray) -> np.ndarray:
    out = np.full_like(theta, coef[0])
    for k in range(1, (coef.shape[0] - 1) // 2 + 1):
        out += coef[2 * k - 1] * np.cos(k * theta) + coef[2 * k] * np.sin(k * theta)
    return out


def periodic_max_abs(
    x: np.ndarray, omega: float, sample_rate: float, n_harmonics: int = 7, n_grid: int = 1024
) -> tuple[float, float]:
    """Noise-robust amplitude ``max_t |x(t) − x̄|`` of a periodic signal (thesis eq. 6.5).

    The signal is replaced by its least-squares Fourier series (:func:`fourier_fit`,
    ``n_harmonics`` harmonics at ``omega``), whose maximum over one period is taken on
    ``n_grid`` phases. Measurement noise (which inflates a raw ``max |x|``) is filtered
    out; harmonics above ``n_harmonics`` are lost.

    Returns
    -------
    amplitude : float
        ``max_θ |Σ_k (a_k cos kθ + b_k sin kθ)|`` (the mean ``a_0`` removed).
    mean : float
        ``a_0``.
    """
    coef = fourier_fit(x, omega, sample_rate, n_harmonics)
    theta = np.linspace(0.0, 2 * np.pi, n_grid, endpoint=False)
    centred = coef.copy()
    centred[0] = 0.0
    return float(np.max(np.abs(_evaluate(centred, theta)))), float(coef[0])


def estimate_frequency(x: np.ndarray, sample_rate: float) -> float:
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


def fill_gaps(
    x: np.ndarray,
    bad: np.ndarray,
    omega: float,
    sample_rate: float,
    max_linear: int = 25,
    n_harmonics: int = 7,
) -> tuple[np.ndarray, int]:
    """Replace the samples flagged ``bad`` (sensor wraps, dropouts) by estimates.

    Runs of at most ``max_linear`` bad samples are linearly interpolated between their
    good neighbours; longer runs (or runs at the ends of the record) take the value of the
    least-squares Fourier series (:func:`fourier_fit` at ``omega``) of the good samples,
    since the signal is periodic.

    Returns
    -------
    cleaned : ndarray
        A copy of ``x`` with the bad samples replaced.
    longest : int
        Length of the longest bad run (0 if none).

    Raises
    ------
    BifidInputError
        If more than half the samples are bad.
    """
    x = np.asarray(x, dtype=float).copy()
    bad = np.asarray(bad, dtype=bool)
    if not bad.any():
        return x, 0
    n = x.shape[0]
    if bad.sum() > n // 2:
        raise BifidInputError(
            f"{int(bad.sum())} of {n} samples are invalid; too many to reconstruct."
        )
    edges = np.diff(np.concatenate([[0], bad.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1)
    good_idx = np.flatnonzero(~bad)
    n_harmonics = _usable_harmonics(int((~bad).sum()), omega, sample_rate, n_harmonics)
    need_fit = any(
        (e - s) > max_linear or s == 0 or e == n for s, e in zip(starts, ends, strict=True)
    )
    if need_fit:
        basis = _basis(n, omega, sample_rate, n_harmonics)
        model = basis @ _lstsq(basis[good_idx], x[good_idx])
    for s, e in zip(starts, ends, strict=True):
        if (e - s) <= max_linear and s > 0 and e < n:
            x[s:e] = np.interp(np.arange(s, e), [s - 1, e], [x[s - 1], x[e]])
        else:
            x[s:e] = model[s:e]
    return x, int((ends - starts).max())
