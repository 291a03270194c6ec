r"""Polar Fourier representation of closed planar curves (thesis eqs. 5.4–5.6).

A closed curve :math:`(z_1, z_2)` is described about its **area centroid**
:math:`\mathbf c` by the radius as a function of the polar angle,

.. math::

    R = \lVert \mathbf z - \mathbf c\rVert,\quad
    \theta = \operatorname{atan2}(z_2 - c_2, z_1 - c_1),
    \quad R(\theta) = a_0 + \sum_{k=1}^{n_h} a_k\cos k\theta + b_k \sin k\theta ,

with the coefficients computed in the least-squares sense (the pseudo-inverse variant of
eq. 5.6). The thesis uses one common origin for all curves; bifid uses each curve's own area
centroid (a purely geometric point, insensitive to how fast the curve is traversed and to
zero-mean noise) and matches the centroids separately, so that small orbits whose centre drifts
with the parameter (as on the real rig) still have their origin inside.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from bifid.signal import fourier_project

Array = jnp.ndarray


def fourier_design(theta: Array, n_harmonics: int) -> Array:
    """Rows ``[1, cos θ, …, cos nθ, sin θ, …, sin nθ]`` (eq. 5.5), shape ``(len(θ), 2n+1)``."""
    k = jnp.arange(1, n_harmonics + 1, dtype=jnp.float64)
    kt = theta[:, None] * k[None, :]
    return jnp.concatenate([jnp.ones_like(theta)[:, None], jnp.cos(kt), jnp.sin(kt)], axis=1)


def _design_from(c1: Array, s1: Array, n_harmonics: int) -> Array:
    """``[1, cos kθ…, sin kθ…]`` from ``cos θ, sin θ`` by the angle-addition recurrence
    (exact to rounding and stable: each step is a rotation). Worth it on long arrays of
    angles; for a handful of angles the vectorised :func:`fourier_design` is faster."""
    cos, sin = [c1], [s1]
    for _ in range(1, n_harmonics):
        c, s = cos[-1], sin[-1]
        cos.append(c * c1 - s * s1)
        sin.append(s * c1 + c * s1)
    parts = [jnp.ones_like(c1)[:, None]]
    if n_harmonics > 0:
        parts += [jnp.stack(cos, axis=1), jnp.stack(sin, axis=1)]
    return jnp.concatenate(parts, axis=1)


def parseval_weights(n_harmonics: int) -> Array:
    r"""Weights making
    :math:`\sum_j w_j \Delta\Phi_j^2 = \frac1{2\pi}\int_0^{2\pi}\Delta R^2\,d\theta`."""
    return jnp.concatenate([jnp.ones(1), 0.5 * jnp.ones(2 * n_harmonics)])


def polygon_centroid(pts: Array) -> Array:
    r"""Area centroid of the closed polygon ``pts`` (shape ``(K, 2)``), either orientation.

    .. math::

        A = \tfrac12\sum_k (x_k y_{k+1} - x_{k+1} y_k),\qquad
        \mathbf c = \frac{1}{6A}\sum_k (\mathbf p_k + \mathbf p_{k+1})(x_k y_{k+1} - x_{k+1} y_k).

    A polygon traced ``n`` times has ``n`` times the area and moment, so the ratio is the same.
    """
    nxt = jnp.roll(pts, -1, axis=0)
    cross = pts[:, 0] * nxt[:, 1] - nxt[:, 0] * pts[:, 1]
    area = 0.5 * jnp.sum(cross)
    return jnp.sum((pts + nxt) * cross[:, None], axis=0) / (6.0 * area)


def polygon_centroid_np(pts: np.ndarray) -> np.ndarray:
    """:func:`polygon_centroid` in NumPy (data preparation: no per-shape compilation)."""
    pts = np.asarray(pts, dtype=float)
    nxt = np.roll(pts, -1, axis=0)
    cross = pts[:, 0] * nxt[:, 1] - nxt[:, 0] * pts[:, 1]
    area = 0.5 * np.sum(cross)
    return np.sum((pts + nxt) * cross[:, None], axis=0) / (6.0 * area)


def polar_coefficients(
    d: np.ndarray, n_harmonics: int, theta: np.ndarray | None = None
) -> np.ndarray:
    r"""Least-squares Fourier coefficients :math:`\Phi(R)` of :math:`R(\theta)` (the
    pseudo-inverse variant of eq. 5.6, :func:`bifid.signal.fourier_project`).

    Parameters
    ----------
    d : array of shape (K, 2)
        Points on the curve minus the centre (any number of turns, any spacing).
    n_harmonics : int
    theta : array of shape (K,), optional
        The polar angles ``arctan2(d[:, 1], d[:, 0])`` if computed before.

    Returns
    -------
    ndarray of shape (2 * n_harmonics + 1,)
        ``[a0, a1..an, b1..bn]``.
    """
    d = np.asarray(d, dtype=float)
    if theta is None:
        theta = np.arctan2(d[:, 1], d[:, 0])
    return fourier_project(np.hypot(d[:, 0], d[:, 1]), theta, n_harmonics)


def polar_mismatch(pts: Array, centre: Array, coef: Array, n_harmonics: int) -> Array:
    r"""Mean-square polar distance between the curve ``pts`` and the series ``coef``.

    .. math::

        \frac{1}{2\pi}\int_0^{2\pi} (\hat R(\theta) - R(\theta))^2\,d\theta
        \approx \frac{1}{2\pi}\sum_k \lvert\Delta\hat\theta_k\rvert
            \bigl(\hat R_k - R(\hat\theta_k)\bigr)^2 ,

    with :math:`(\hat\theta_k, \hat R_k)` the polar coordinates of ``pts`` about ``centre``
    and :math:`\Delta\hat\theta_k` half the angle between its neighbours. By Parseval this is
    :math:`\lVert\Phi(R) - \Phi(\hat R)\rVert^2` of eq. 5.7 (Parseval weights) whenever
    :math:`\hat R` has no harmonics above ``n_harmonics``; evaluating it by quadrature on the
    model's points avoids a least-squares projection (eq. 5.6) per orbit and iteration, and
    additionally penalises harmonics of :math:`\hat R` beyond the truncation.
    """
    d = pts - centre[None, :]
    R_hat = jnp.sqrt(jnp.sum(d**2, axis=1))
    R = polar_design(d, R_hat, n_harmonics) @ coef
    # half the angle between the neighbours of each point, |atan2(prev x next, prev . next)|/2
    prv, nxt = jnp.roll(d, 1, axis=0), jnp.roll(d, -1, axis=0)
    cross = prv[:, 0] * nxt[:, 1] - prv[:, 1] * nxt[:, 0]
    dth = jnp.abs(jnp.arctan2(cross, jnp.sum(prv * nxt, axis=1))) / 2
    return jnp.sum(dth * (R_hat - R) ** 2) / (2 * jnp.pi)


def polar_design(d: Array, r: Array, n_harmonics: int) -> Array:
    r""":func:`fourier_design` at the polar angles of the vectors ``d`` (norms ``r``) without
    evaluating an angle: :math:`\cos\theta = d_1/r`, :math:`\sin\theta = d_2/r`, then
    the recurrence (about twice as fast as ``atan2`` + ``cos``/``sin`` with their
    derivatives, in the innermost loop of the map training)."""
    return _design_from(d[:, 0] / r, d[:, 1] / r, n_harmonics)


def unwrapped_angle(pts: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Continuous polar angle of ``pts`` about ``centre`` (numpy)."""
    d = pts - centre[None, :]
    return np.unwrap(np.arctan2(d[:, 1], d[:, 0]))


def whole_turns(pts: np.ndarray, centre: np.ndarray) -> tuple[int, int, float]:
    """Number of samples spanning whole turns about ``centre``, the turns and the direction.

    Returns
    -------
    n_samples : int
        Samples ``pts[:n_samples]`` cover ``turns`` whole revolutions (0 when less than one).
    turns : int
    direction : float
        +1 counter-clockwise, -1 clockwise.
    """
    ang = unwrapped_angle(pts, centre)
    travel = ang - ang[0]
    direction = 1.0 if travel[-1] >= 0 else -1.0
    travel = direction * travel
    turns = int(np.floor(travel[-1] / (2 * np.pi)))
    if turns < 1:
        return 0, 0, direction
    # first sample at or beyond `turns` revolutions (include it to close the curve)
    idx = int(np.searchsorted(travel, turns * 2 * np.pi))
    return min(idx + 1, len(pts)), turns, direction
