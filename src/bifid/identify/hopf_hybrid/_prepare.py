"""From validated records to the arrays the hybrid Hopf model trains on.

Per record: the signals are scaled by a per-signal scale (their RMS over all records), the
plane :math:`(z_1, z_2)` is truncated to whole periods, and its area centroid, polar Fourier
coefficients (eqs. 5.4–5.6), covariance, mean radius, angular frequency (slope of the
unwrapped polar angle) and direction of rotation are computed. The parameter is normalised,
:math:`\\tilde\\mu = (\\mu - \\mu_c)/\\mu_s`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError, ConvergenceWarning
from bifid.identify._records import LCOData
from bifid.identify.hopf_hybrid._normal_form import root_of
from bifid.identify.hopf_hybrid._polar import (
    polar_coefficients,
    polygon_centroid_np,
    unwrapped_angle,
    whole_turns,
)
from bifid.signal import evaluate_series, fourier_fit


@dataclass
class Prepared:
    """Arrays derived from :class:`LCOData` (see module docstring)."""

    mu_c: float
    mu_s: float
    z_scale: np.ndarray  # (m,)
    plane: tuple[int, int]
    mu_t: np.ndarray  # (n,)
    root: np.ndarray  # (n,) root codes of the orbits (OUTER, INNER, EITHER)
    coef: np.ndarray  # (n, 2nh+1)
    centre: np.ndarray  # (n, 2)
    size: np.ndarray  # (n,) mean polar radius a0
    cov: np.ndarray  # (n, 2, 2)
    omega: np.ndarray  # (n,) rad/s, > 0
    direction: float  # +1 counter-clockwise, -1 clockwise in the plane
    white: np.ndarray  # (2, 2) whitening of the plane (symmetric): working = zn[:, plane] @ white
    zn: list[np.ndarray]  # normalised signals, whole records
    times: list[np.ndarray]  # sample times of zn [s]
    n_whole: np.ndarray  # (n,) samples spanning whole periods (used for the geometry)

    def plane_points(self, i: int, rows=slice(None)) -> np.ndarray:
        """Working plane coordinates of record ``i`` (normalised, whitened)."""
        return self.zn[i][rows][:, list(self.plane)] @ self.white

    def arrays(self) -> dict[str, jnp.ndarray]:
        """The per-orbit arrays of the map stage (JAX)."""
        return {
            "mu_t": jnp.asarray(self.mu_t, dtype=jnp.float64),
            "branch": jnp.asarray(self.root, dtype=jnp.float64),
            "coef": jnp.asarray(self.coef, dtype=jnp.float64),
            "centre": jnp.asarray(self.centre, dtype=jnp.float64),
        }


def prepare(
    data: LCOData,
    plane: tuple[int, int],
    n_harmonics: int,
    *,
    mu_c: float | None = None,
    mu_s: float | None = None,
    z_scale: np.ndarray | None = None,
    white: np.ndarray | None = None,
) -> Prepared:
    """Compute :class:`Prepared` (normalisation constants may be imposed, e.g. for CV folds).

    Raises
    ------
    BifidInputError
        If fewer than two distinct parameter values are given, a record holds less than one
        period in the plane, or records rotate in opposite directions.
    """
    i1, i2 = plane
    m = len(data.signal_names)
    if not (0 <= i1 < m and 0 <= i2 < m and i1 != i2):
        raise BifidInputError(f"plane must be two different signal indices < {m}, got {plane}.")
    params = data.param
    if len(np.unique(params)) < 2:
        raise BifidInputError(
            "The hybrid Hopf model needs records at two or more parameter values; got "
            f"{sorted(set(params.tolist()))}."
        )
    if mu_c is None:
        mu_c = float(0.5 * (params.max() + params.min()))
    if mu_s is None:
        mu_s = float(0.5 * (params.max() - params.min()))
    if z_scale is None:
        allsig = np.concatenate(data.signals, axis=0)
        z_scale = np.sqrt(np.mean(allsig**2, axis=0))
        z_scale = np.where(z_scale > 0, z_scale, 1.0)
    if white is None:
        white = whitening(data, plane, z_scale)
    coefs, centres, sizes, covs, omegas, dirs, zns, times = [], [], [], [], [], [], [], []
    wholes = []
    for i, sig in enumerate(data.signals):
        zn = sig / z_scale[None, :]
        pts = zn[:, [i1, i2]] @ white
        n_whole, turns, direction = whole_turns(pts, pts.mean(axis=0))
        if turns < 1:
            raise BifidInputError(
                f"Record {i} (param {params[i]:g}) holds less than one period in the plane "
                f"({data.signal_names[i1]}, {data.signal_names[i2]}); record longer time series."
            )
        t_all = np.arange(len(zn)) / data.sample_rate[i]
        pts = pts[:n_whole]
        c = polygon_centroid_np(pts)
        # frequency: time of `turns` whole revolutions about the centroid (interpolated)
        ang = unwrapped_angle(zn[:, [i1, i2]] @ white, c)
        travel = direction * (ang - ang[0])
        k = int(np.searchsorted(travel, turns * 2 * np.pi))
        k = min(max(k, 1), len(travel) - 1)
        frac = (turns * 2 * np.pi - travel[k - 1]) / max(travel[k] - travel[k - 1], 1e-300)
        slope = turns * 2 * np.pi / ((k - 1 + frac) / data.sample_rate[i])
        coef = polar_coefficients(pts, c, n_harmonics)
        d = pts - c[None, :]
        coefs.append(coef)
        centres.append(c)
        sizes.append(coef[0])
        covs.append(d.T @ d / len(d))
        omegas.append(abs(slope))
        dirs.append(direction)
        zns.append(zn)
        times.append(t_all)
        wholes.append(n_whole)
    dirs = np.asarray(dirs)
    direction = 1.0 if np.sum(dirs) >= 0 else -1.0
    if np.any(dirs != direction):
        bad = [float(params[i]) for i in np.nonzero(dirs != direction)[0]]
        warnings.warn(
            f"Records at {bad} rotate the other way in the plane; check the signals' signs.",
            ConvergenceWarning,
            stacklevel=3,
        )
    return Prepared(
        mu_c=mu_c,
        mu_s=mu_s,
        z_scale=np.asarray(z_scale, dtype=float),
        plane=(i1, i2),
        mu_t=(params - mu_c) / mu_s,
        root=root_of(data.stable),
        coef=np.asarray(coefs),
        centre=np.asarray(centres),
        size=np.asarray(sizes),
        cov=np.asarray(covs),
        omega=np.asarray(omegas),
        direction=direction,
        white=np.asarray(white, dtype=float),
        zn=zns,
        times=times,
        n_whole=np.asarray(wholes),
    )


def whitening(data: LCOData, plane: tuple[int, int], z_scale: np.ndarray) -> np.ndarray:
    r"""Symmetric :math:`W = \bar C^{-1/2}` of the mean plane covariance of the records.

    Orbits whose two signals move nearly in phase are thin ellipses, whose polar radius
    :math:`R(\theta)` needs many harmonics; in whitened coordinates they are close to
    circles. :math:`W` is symmetric positive definite (orientation is kept) and is undone
    when predictions are returned.
    """
    i1, i2 = plane
    covs = []
    for sig in data.signals:
        pts = sig[:, [i1, i2]] / z_scale[[i1, i2]]
        d = pts - pts.mean(axis=0)
        covs.append(d.T @ d / len(d))
    C = np.mean(covs, axis=0)
    w, V = np.linalg.eigh(0.5 * (C + C.T))
    if not np.all(w > 1e-12 * max(float(w.max()), 1e-300)):
        return np.eye(2)  # degenerate plane: leave it (the prepare step will complain)
    W = (V / np.sqrt(w)) @ V.T
    return W / np.sqrt(abs(np.linalg.det(W)))  # unit determinant: only the shape changes


def choose_harmonics(
    data: LCOData, plane: tuple[int, int], n_max: int = 32, tol: float = 2e-3
) -> int:
    r"""Number of polar harmonics that represents every orbit: the highest harmonic whose
    amplitude exceeds ``tol`` of the mean radius :math:`a_0` and four times the noise level
    (the median amplitude of the top quarter of harmonics).

    Each orbit's polar series (eq. 5.5) is fitted with ``n_max`` harmonics in the whitened
    plane; harmonics below that threshold (noise, or a truncation error of order ``tol``)
    are dropped. Returns a value in ``[4, n_max]``.
    """
    i1, i2 = plane
    allsig = np.concatenate(data.signals, axis=0)
    z_scale = np.sqrt(np.mean(allsig**2, axis=0))
    z_scale = np.where(z_scale > 0, z_scale, 1.0)
    white = whitening(data, plane, z_scale)
    best = 4
    for sig in data.signals:
        pts = (sig[:, [i1, i2]] / z_scale[[i1, i2]]) @ white
        n_whole, turns, _ = whole_turns(pts, pts.mean(axis=0))
        if turns < 1:
            continue
        pts = pts[:n_whole]
        nmax = int(min(n_max, (len(pts) - 1) // 6))
        if nmax <= 4:
            continue
        c = polygon_centroid_np(pts)
        coef = polar_coefficients(pts, c, nmax)
        amp = np.sqrt(0.5 * (coef[1 : nmax + 1] ** 2 + coef[nmax + 1 :] ** 2))  # per harmonic
        floor = float(np.median(amp[-max(2, nmax // 4) :]))  # noise level per harmonic
        above = np.nonzero(amp > max(tol * coef[0], 4.0 * floor))[0]
        n = int(above[-1]) + 1 if len(above) else 4
        best = max(best, n)
    return int(best)


def measured_amplitude(signals: np.ndarray, omega: float, sample_rate: float) -> np.ndarray:
    """Noise-robust ``max_t |z_k|`` of a record: the maximum of its 20-harmonic Fourier
    series at the record's frequency (offset kept: amplitudes about the signals' zero, as the
    model predicts them)."""
    theta = np.linspace(0, 2 * np.pi, 2048, endpoint=False)
    nh = int(max(1, min(20, (len(signals) - 1) // 8)))
    return np.array(
        [
            np.max(
                np.abs(evaluate_series(fourier_fit(signals[:, k], omega, sample_rate, nh), theta))
            )
            for k in range(signals.shape[1])
        ]
    )
