"""Fourier spectral collocation helpers on an equispaced periodic grid (Trefethen,
*Spectral Methods in MATLAB*, ch. 3), as used in thesis eqs. 4.12–4.14.

The grid is ``tau_k = 2 pi k / M``, ``k = 0..M-1`` (M even); a periodic function is
represented by its values there, its derivative by ``D_M v``. Coefficients, amplitudes
and spectra of mesh values are in :mod:`bifid.signal`.
"""

from __future__ import annotations

import functools

import numpy as np

from bifid.errors import BifidInputError


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


def resample_orbit(values: np.ndarray, n_mesh: int) -> np.ndarray:
    """Trigonometric interpolation of periodic mesh values ``(M, n)`` onto ``n_mesh`` points.

    Exact for the interpolant when refining; drops the harmonics above ``n_mesh/2`` when
    coarsening (the Nyquist harmonic is split evenly, so real data stay real).
    """
    v = np.asarray(values, dtype=float)
    M = v.shape[0]
    if n_mesh == M:
        return v.copy()
    c = np.fft.rfft(v, axis=0)
    if M % 2 == 0 and n_mesh > M:
        c[M // 2] *= 0.5  # the Nyquist harmonic of the coarse mesh is a cosine: split it
    if n_mesh < M:
        c = c[: n_mesh // 2 + 1].copy()
        c[-1] = 2.0 * c[-1].real  # the new Nyquist harmonic: its cosine, sampled
    return np.fft.irfft(c, n=n_mesh, axis=0) * (n_mesh / M)
