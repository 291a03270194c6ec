"""From validated records to the arrays the hybrid Hopf model trains on.

Per record: the signals are scaled by a per-signal scale (their RMS over all records), the
plane :math:`(z_1, z_2)` is truncated to whole periods, and its area centroid, polar Fourier
coefficients (eqs. 5.4–5.6), covariance, mean radius, angular frequency (slope of the
unwrapped polar angle) and direction of rotation are computed. The parameter is normalised,
:math:`\\tilde\\mu = (\\mu - \\mu_c)/\\mu_s`.

All of it is a function of the records' samples. :class:`Preprocessing` computes it once per
dataset and keeps it, keyed by the plane and the number of harmonics, so that the harmonic
choice and the preparation share each record's geometry (:class:`PlaneOrbit`) and a fit's
leave-one-orbit-out folds share everything. A bootstrap replicate has other samples, hence
its own :class:`Preprocessing`; it takes the number of harmonics from the fit
(:mod:`._uncertainty`).
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
    whole_turns,
)
from bifid.signal import evaluate_series, fourier_fit_columns


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
    """Compute :class:`Prepared` (normalisation constants may be imposed, e.g. for CV folds;
    without them, :meth:`Preprocessing.prepared` computes the same and keeps it).

    Raises
    ------
    BifidInputError
        If fewer than two distinct parameter values are given, a record holds less than one
        period in the plane, or records rotate in opposite directions.
    """
    _check_plane(data, plane)
    if z_scale is None:
        z_scale = signal_scale(data)
    if white is None:
        white = whitening(data, plane, z_scale)
    geometry = plane_geometry(data, plane, z_scale, white)
    return _prepared(data, plane, n_harmonics, geometry, mu_c, mu_s, z_scale, white)


def _check_plane(data: LCOData, plane: tuple[int, int]) -> None:
    i1, i2 = plane
    m = len(data.signal_names)
    if not (0 <= i1 < m and 0 <= i2 < m and i1 != i2):
        raise BifidInputError(f"plane must be two different signal indices < {m}, got {plane}.")
    if len(np.unique(data.param)) < 2:
        raise BifidInputError(
            "The hybrid Hopf model needs records at two or more parameter values; got "
            f"{sorted(set(data.param.tolist()))}."
        )


def signal_scale(data: LCOData) -> np.ndarray:
    """The per-signal scale: the RMS over all records (1 for a signal that is zero)."""
    allsig = np.concatenate(data.signals, axis=0)
    z_scale = np.sqrt(np.mean(allsig**2, axis=0))
    return np.where(z_scale > 0, z_scale, 1.0)


@dataclass(frozen=True)
class PlaneOrbit:
    """One record in the working plane (normalised, whitened) about its area centroid."""

    zn: np.ndarray  # (N, m) normalised signals
    n_whole: int  # samples spanning whole turns about the points' mean
    turns: int
    direction: float  # +1 counter-clockwise, -1 clockwise
    centre: np.ndarray  # (2,) area centroid of the whole turns
    d: np.ndarray  # (N, 2) pts - centre
    theta: np.ndarray  # (N,) polar angle of d (wrapped)

    def polar_coefficients(self, n_harmonics: int) -> np.ndarray:
        """:func:`~._polar.polar_coefficients` of the whole turns about the centroid."""
        n = self.n_whole
        return polar_coefficients(self.d[:n], n_harmonics, self.theta[:n])


def plane_geometry(
    data: LCOData, plane: tuple[int, int], z_scale: np.ndarray, white: np.ndarray
) -> list[PlaneOrbit | None]:
    """Per record its :class:`PlaneOrbit` (None when it holds less than one turn): what the
    harmonic choice and the preparation share."""
    out: list[PlaneOrbit | None] = []
    for sig in data.signals:
        zn = sig / z_scale[None, :]
        pts = zn[:, list(plane)] @ white
        n_whole, turns, direction = whole_turns(pts, pts.mean(axis=0))
        if turns < 1:
            out.append(None)
            continue
        c = polygon_centroid_np(pts[:n_whole])
        d = pts - c[None, :]
        theta = np.arctan2(d[:, 1], d[:, 0])
        out.append(PlaneOrbit(zn, n_whole, turns, direction, c, d, theta))
    return out


def _prepared(
    data: LCOData,
    plane: tuple[int, int],
    n_harmonics: int,
    geometry: list[PlaneOrbit | None],
    mu_c: float | None,
    mu_s: float | None,
    z_scale: np.ndarray,
    white: np.ndarray,
) -> Prepared:
    """:func:`prepare` from the records' geometry (module docstring)."""
    params = data.param
    if mu_c is None:
        mu_c = float(0.5 * (params.max() + params.min()))
    if mu_s is None:
        mu_s = float(0.5 * (params.max() - params.min()))
    coefs, centres, covs, omegas, dirs, orbits = [], [], [], [], [], []
    for i, g in enumerate(geometry):
        if g is None:
            raise BifidInputError(
                f"Record {i} (param {params[i]:g}) holds less than one period in the plane "
                f"({data.signal_names[plane[0]]}, {data.signal_names[plane[1]]}); record "
                "longer time series."
            )
        # frequency: time of `turns` whole revolutions about the centroid (interpolated)
        travel = g.direction * (np.unwrap(g.theta) - g.theta[0])
        k = int(np.searchsorted(travel, g.turns * 2 * np.pi))
        k = min(max(k, 1), len(travel) - 1)
        frac = (g.turns * 2 * np.pi - travel[k - 1]) / max(travel[k] - travel[k - 1], 1e-300)
        slope = g.turns * 2 * np.pi / ((k - 1 + frac) / data.sample_rate[i])
        d = g.d[: g.n_whole]
        coefs.append(g.polar_coefficients(n_harmonics))
        centres.append(g.centre)
        covs.append(d.T @ d / len(d))
        omegas.append(abs(slope))
        dirs.append(g.direction)
        orbits.append(g)
    dirs = np.asarray(dirs)
    direction = 1.0 if np.sum(dirs) >= 0 else -1.0
    if np.any(dirs != direction):
        bad = [float(params[i]) for i in np.nonzero(dirs != direction)[0]]
        warnings.warn(
            f"Records at {bad} rotate the other way in the plane; check the signals' signs.",
            ConvergenceWarning,
            stacklevel=4,
        )
    coef = np.asarray(coefs)
    return Prepared(
        mu_c=mu_c,
        mu_s=mu_s,
        z_scale=np.asarray(z_scale, dtype=float),
        plane=(plane[0], plane[1]),
        mu_t=(params - mu_c) / mu_s,
        root=root_of(data.stable),
        coef=coef,
        centre=np.asarray(centres),
        size=coef[:, 0].copy(),
        cov=np.asarray(covs),
        omega=np.asarray(omegas),
        direction=direction,
        white=np.asarray(white, dtype=float),
        zn=[g.zn for g in orbits],
        times=[np.arange(len(g.zn)) / fs for g, fs in zip(orbits, data.sample_rate, strict=True)],
        n_whole=np.asarray([g.n_whole for g in orbits]),
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


#: bounds of the harmonic choice (:func:`choose_harmonics`): at most this many harmonics,
#: dropped below this fraction of the mean radius
MAX_HARMONICS, HARMONIC_TOL = 32, 2e-3


def choose_harmonics(
    data: LCOData, plane: tuple[int, int], n_max: int = MAX_HARMONICS, tol: float = HARMONIC_TOL
) -> int:
    r"""Number of polar harmonics that represents every orbit: the highest harmonic whose
    amplitude exceeds ``tol`` of the mean radius :math:`a_0` and four times the noise level
    (the median amplitude of the top quarter of harmonics).

    Each orbit's polar series (eq. 5.5) is fitted with ``n_max`` harmonics in the whitened
    plane; harmonics below that threshold (noise, or a truncation error of order ``tol``)
    are dropped. Returns a value in ``[4, n_max]``.
    """
    z_scale = signal_scale(data)
    geometry = plane_geometry(data, plane, z_scale, whitening(data, plane, z_scale))
    return _harmonics(geometry, n_max, tol)


def _harmonics(geometry: list[PlaneOrbit | None], n_max: int, tol: float) -> int:
    """:func:`choose_harmonics` from the records' geometry."""
    best = 4
    for g in geometry:
        if g is None:
            continue
        nmax = int(min(n_max, (g.n_whole - 1) // 6))
        if nmax <= 4:
            continue
        coef = g.polar_coefficients(nmax)
        amp = np.sqrt(0.5 * (coef[1 : nmax + 1] ** 2 + coef[nmax + 1 :] ** 2))  # per harmonic
        floor = float(np.median(amp[-max(2, nmax // 4) :]))  # noise level per harmonic
        above = np.nonzero(amp > max(tol * coef[0], 4.0 * floor))[0]
        n = int(above[-1]) + 1 if len(above) else 4
        best = max(best, n)
    return int(best)


class Preprocessing:
    """The per-orbit preprocessing of one dataset, computed on first use and kept.

    Everything here is a function of the records and the plane (and of the number of
    harmonics for :meth:`prepared`) and is keyed by them: the normalisation and whitening,
    each record's working-plane points, whole turns, centroid and polar angles
    (:class:`PlaneOrbit`), the harmonic choice and the prepared arrays. A fit and its
    leave-one-orbit-out folds, which train on the same records, compute it once. The
    records are not copied: the instance belongs to the one dataset it was built from,
    and lives as long as the fit that uses it.
    """

    def __init__(self, data: LCOData) -> None:
        self.data = data
        self._geometry: dict[tuple[int, int], list[PlaneOrbit | None]] = {}
        self._frames: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
        self._harmonics: dict[tuple[int, int], int] = {}
        self._prepared: dict[tuple[tuple[int, int], int], Prepared] = {}

    def geometry(self, plane: tuple[int, int]) -> list[PlaneOrbit | None]:
        """:func:`plane_geometry` at the data's own normalisation and whitening."""
        plane = (int(plane[0]), int(plane[1]))
        if plane not in self._geometry:
            _check_plane(self.data, plane)
            z_scale = signal_scale(self.data)
            self._frames[plane] = (z_scale, whitening(self.data, plane, z_scale))
            self._geometry[plane] = plane_geometry(self.data, plane, *self._frames[plane])
        return self._geometry[plane]

    def harmonics(self, plane: tuple[int, int]) -> int:
        """:func:`choose_harmonics` (default bounds)."""
        plane = (int(plane[0]), int(plane[1]))
        if plane not in self._harmonics:
            self._harmonics[plane] = _harmonics(self.geometry(plane), MAX_HARMONICS, HARMONIC_TOL)
        return self._harmonics[plane]

    def prepared(self, plane: tuple[int, int], n_harmonics: int) -> Prepared:
        """:func:`prepare` without imposed constants."""
        key = ((int(plane[0]), int(plane[1])), int(n_harmonics))
        if key not in self._prepared:
            geometry = self.geometry(key[0])
            z_scale, white = self._frames[key[0]]
            self._prepared[key] = _prepared(
                self.data, key[0], key[1], geometry, None, None, z_scale, white
            )
        return self._prepared[key]


def measured_amplitude(signals: np.ndarray, omega: float, sample_rate: float) -> np.ndarray:
    """Noise-robust ``max_t |z_k|`` of a record: the maximum of its 20-harmonic Fourier
    series at the record's frequency (offset kept: amplitudes about the signals' zero, as the
    model predicts them)."""
    theta = np.linspace(0, 2 * np.pi, 2048, endpoint=False)
    nh = int(max(1, min(20, (len(signals) - 1) // 8)))
    coefs, _ = fourier_fit_columns(signals, omega, sample_rate, nh)
    return np.array([np.max(np.abs(evaluate_series(c, theta))) for c in coefs])


def measured_amplitudes(data: LCOData, omega: np.ndarray) -> np.ndarray:
    """:func:`measured_amplitude` of every record at its frequency ``omega``, ``(n, m)``."""
    return np.array(
        [
            measured_amplitude(x, w, fs)
            for x, w, fs in zip(data.signals, omega, data.sample_rate, strict=True)
        ]
    )
