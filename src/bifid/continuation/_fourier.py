"""Fourier spectral collocation helpers on an equispaced periodic grid (Trefethen,
*Spectral Methods in MATLAB*, ch. 3), as used in thesis eqs. 4.12–4.14.

The grid is ``tau_k = 2 pi k / M``, ``k = 0..M-1`` (M even); a periodic function is
represented by its values there, its derivative by ``D_M v``.
"""

from __future__ import annotations

import functools
import warnings

import numpy as np

from bifid.errors import BifidInputError, ResolutionWarning


@functools.lru_cache(maxsize=32)
def fourier_grid(n_mesh: int) -> np.ndarray:
    """Equispaced grid ``tau_k = 2 pi k / M`` on ``[0, 2 pi)``."""
    _check_mesh(n_mesh)
    return 2.0 * np.pi * np.arange(n_mesh) / n_mesh


@functools.lru_cache(maxsize=32)
def fourier_differentiation_matrix(n_mesh: int) -> np.ndarray:
    r"""Spectral differentiation matrix ``D_M`` for 2π-periodic functions, M even.

    .. math:: (D_M)_{ij} = \tfrac12 (-1)^{i-j} \cot\!\big(\tfrac{\tau_i-\tau_j}{2}\big),
              \quad (D_M)_{ii} = 0 .

    The matrix is skew-symmetric and differentiates trigonometric polynomials of degree
    < M/2 exactly.
    """
    _check_mesh(n_mesh)
    tau = fourier_grid(n_mesh)
    i, j = np.meshgrid(np.arange(n_mesh), np.arange(n_mesh), indexing="ij")
    with np.errstate(divide="ignore", invalid="ignore"):
        D = 0.5 * (-1.0) ** (i - j) / np.tan((tau[i] - tau[j]) / 2.0)
    D[i == j] = 0.0
    # checked when built: exact on sin(tau)
    assert np.allclose(D @ np.sin(tau), np.cos(tau), atol=1e-10 * n_mesh)
    return D


def _check_mesh(n_mesh: int) -> None:
    if not isinstance(n_mesh, (int, np.integer)) or n_mesh < 8 or n_mesh % 2:
        raise BifidInputError(f"n_mesh must be an even integer >= 8, got {n_mesh!r}.")


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


def first_harmonic(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients ``(a1, b1)`` of ``cos tau`` and ``sin tau`` of mesh values (axis 0)."""
    _, a, b = fourier_coefficients(values)
    return a[0], b[0]


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


def check_resolution(tails: np.ndarray, n_mesh: int, tol: float, what: str) -> None:
    """Warn (ResolutionWarning) when a branch's spectral tail exceeds ``tol``."""
    worst = float(np.max(tails)) if len(tails) else 0.0
    if worst > tol:
        warnings.warn(
            f"{what}: the top of the Fourier spectrum is {worst:.1e} of its peak on "
            f"{n_mesh} collocation points (tolerance {tol:.0e}); the mesh is too coarse "
            "or the collocation shows a spurious resonance. Increase n_mesh "
            f"(e.g. --mesh {2 * n_mesh}).",
            ResolutionWarning,
            stacklevel=3,
        )
