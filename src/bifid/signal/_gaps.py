"""Repair of records with invalid samples (sensor wraps, dropouts)."""

from __future__ import annotations

import numpy as np

from bifid.errors import BifidInputError
from bifid.signal._series import evaluate_series, fourier_project, usable_harmonics

__all__ = ["fill_gaps"]


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
    least-squares Fourier series at ``omega`` of the good samples, since the signal is
    periodic.

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
    n_harmonics = usable_harmonics(int((~bad).sum()), omega, sample_rate, n_harmonics)
    need_fit = any(
        (e - s) > max_linear or s == 0 or e == n for s, e in zip(starts, ends, strict=True)
    )
    if need_fit:
        theta = omega * np.arange(n) / sample_rate
        coef = fourier_project(x[good_idx], theta[good_idx], n_harmonics)
        model = evaluate_series(coef, theta)
    for s, e in zip(starts, ends, strict=True):
        if (e - s) <= max_linear and s > 0 and e < n:
            x[s:e] = np.interp(np.arange(s, e), [s - 1, e], [x[s - 1], x[e]])
        else:
            x[s:e] = model[s:e]
    return x, int((ends - starts).max())
