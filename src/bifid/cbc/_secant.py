"""Accelerated Picard iteration of Fourier coefficients (target updates of CBC)."""

from __future__ import annotations

import numpy as np

__all__ = ["HarmonicSecant"]


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
