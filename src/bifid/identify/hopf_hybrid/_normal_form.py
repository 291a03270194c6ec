r"""The mechanistic part of the hybrid Hopf model: the normal-form-like equation 5.2/5.3.

In polar form (eq. 5.3), in *normalised* parameter units
:math:`\tilde\mu = (\mu - \mu_c)/\mu_s`,

.. math::

    \dot\rho = (\tilde\mu - \tilde\mu_0)\rho + a_2\rho^3 - q_5\rho^5,\qquad
    \dot\theta = \Omega(\rho, \theta, \mu),

with :math:`q_5 \in \{0, 1\}` (quintic term off/on). The limit cycles are the positive roots
of :math:`g(\rho) = \dot\rho/\rho = 0`:

.. math::

    q_5 = 1:\ \rho^2 = \frac{a_2 \pm \sqrt{a_2^2 + 4(\tilde\mu - \tilde\mu_0)}}{2},\qquad
    q_5 = 0:\ \rho^2 = -\frac{\tilde\mu - \tilde\mu_0}{a_2},

and a cycle is stable when :math:`\mathrm d\dot\rho/\mathrm d\rho < 0` there. With
:math:`a_2 > 0` and the quintic term the Hopf point :math:`\tilde\mu_0` is subcritical and the
two branches meet at the fold of cycles :math:`\tilde\mu_0 - a_2^2/4` (radius
:math:`\rho^2 = a_2/2`). The "+" root is the stable (outer) branch, the "−" root the unstable
(inner) one.

**Units.** The thesis writes eq. 5.3 in the raw parameter :math:`\mu`. The substitution
:math:`r = \mu_s^{1/4}\rho`, :math:`t' = t/\mu_s` maps the normalised form onto the raw one with
:math:`a_2^{\rm raw} = \sqrt{\mu_s}\,a_2`, so the fold :math:`\mu_0 - (a_2^{\rm raw})^2/4` is the
same point; :func:`raw_a2` converts. Working in normalised units keeps the network inputs
:math:`O(1)` whatever the units of the bifurcation parameter.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

Array = jnp.ndarray

# which root of g(rho) a measured orbit lies on (from its stability label 1 / 0 / -1)
OUTER = 1  # "+" root: the stable branch of a subcritical model with quintic term
INNER = -1  # "-" root: the unstable branch
EITHER = 0  # stability unknown: the root that fits better


def root_of(stable: np.ndarray) -> np.ndarray:
    """Root codes of orbits from their stability labels (1 stable, 0 unstable, -1 unknown)."""
    s = np.asarray(stable)
    return np.where(s == 1, OUTER, np.where(s == 0, INNER, EITHER)).astype(int)


_DISC_FLOOR = 1e-8  # keeps the square root differentiable at the fold
RHO2_FLOOR = 1e-4  # smallest orbit radius^2 used while training (orbit must exist)


def lco_radius2(mu_t: Array, mu0_t: Array, a2: Array, q5: float, branch: int | Array) -> Array:
    r"""Squared normal-form radius :math:`\rho^2` of the limit cycle at :math:`\tilde\mu`.

    Parameters
    ----------
    mu_t, mu0_t : array
        Normalised parameter and Hopf point.
    a2 : array
        Cubic coefficient (normalised units).
    q5 : {0.0, 1.0}
        Quintic coefficient.
    branch : +1 or -1
        "+" root (outer, stable for ``q5 = 1``) or "−" root (inner).

    Returns
    -------
    array
        :math:`\rho^2`; may be negative or NaN-free garbage where no cycle exists (see
        :func:`existence_violation`).
    """
    dmu = mu_t - mu0_t
    if q5 == 0.0:
        return -dmu / a2
    disc = jnp.maximum(a2**2 + 4.0 * dmu, _DISC_FLOOR)
    return 0.5 * (a2 + jnp.asarray(branch, dtype=jnp.float64) * jnp.sqrt(disc))


def existence_violation(
    mu_t: Array, mu0_t: Array, a2: Array, q5: float, branch: int | Array
) -> Array:
    """Non-negative measure of how far the cycle ``(mu_t, branch)`` is from existing.

    Zero when the model has a cycle of radius :math:`\\rho^2 \\ge` ``RHO2_FLOOR`` on the
    requested branch; grows quadratically outside (a penalty for training).
    """
    dmu = mu_t - mu0_t
    rho2 = lco_radius2(mu_t, mu0_t, a2, q5, branch)
    pen = jnp.maximum(RHO2_FLOOR - rho2, 0.0) ** 2
    if q5 != 0.0:
        pen = pen + jnp.maximum(-(a2**2 + 4.0 * dmu), 0.0) ** 2
    return pen


def growth_derivative(rho2: Array, mu_t: Array, mu0_t: Array, a2: Array, q5: float) -> Array:
    r""":math:`\partial\dot\rho/\partial\rho` at a cycle, :math:`2a_2\rho^2 - 4q_5\rho^4`.

    At a root of :math:`g = (\tilde\mu-\tilde\mu_0) + a_2\rho^2 - q_5\rho^4` one has
    :math:`\partial_\rho(\rho g) = g + \rho g' = 2a_2\rho^2 - 4q_5\rho^4`; negative means stable.
    """
    del mu_t, mu0_t
    return 2.0 * a2 * rho2 - 4.0 * q5 * rho2**2


def branch_mu(rho2: np.ndarray, mu0_t: float, a2: float, q5: float) -> np.ndarray:
    r"""The branch as a graph over the radius,
    :math:`\tilde\mu = \tilde\mu_0 - a_2\rho^2 + q_5\rho^4`."""
    return mu0_t - a2 * rho2 + q5 * rho2**2


def fold_mu(mu0_t: float, a2: float, q5: float) -> float | None:
    r"""Fold of cycles :math:`\tilde\mu_0 - a_2^2/4` (subcritical with quintic), else ``None``."""
    if q5 == 0.0 or a2 <= 0.0:
        return None
    return float(mu0_t - a2**2 / 4.0)


def raw_a2(a2: float, mu_scale: float, q5: float = 1.0) -> float:
    r""":math:`a_2` of eq. 5.3 written in the raw parameter (see module docstring).

    Without the quintic term :math:`a_2 = -1` in either scaling (it only fixes the unit of
    :math:`r`: :math:`r = \sqrt{\mu_s}\rho`).
    """
    if q5 == 0.0:
        return float(a2)
    return float(a2 * np.sqrt(mu_scale))


def initial_guess(
    mu_t: np.ndarray, size: np.ndarray, branch: np.ndarray, criticality: str, q5: float
) -> tuple[float, float, float]:
    r"""Hopf point, :math:`a_2` and radius scale :math:`\kappa` from measured orbit sizes.

    If the map to the measurements were linear, an orbit of size :math:`A = \kappa\rho`
    satisfies, from :math:`g = 0`,

    .. math::

        \tilde\mu = \tilde\mu_0 - a_2 A^2/\kappa^2 + q_5 A^4/\kappa^4 ,

    a linear least-squares problem in :math:`(\tilde\mu_0, -a_2/\kappa^2, q_5/\kappa^4)`.
    Without the quintic term :math:`a_2 = -1` is fixed (it only rescales :math:`\rho`).

    Returns
    -------
    mu0_t, a2, kappa : float
    """
    A2 = np.asarray(size, dtype=float) ** 2
    mu_t = np.asarray(mu_t, dtype=float)
    span = max(float(np.ptp(mu_t)), 1e-3)
    if q5 == 0.0:
        # mu = mu0 + A^2 / kappa^2 (supercritical: a2 = -1)
        X = np.stack([np.ones_like(A2), A2], axis=1)
        coef, *_ = np.linalg.lstsq(X, mu_t, rcond=None)
        mu0, c1 = float(coef[0]), float(coef[1])
        if not np.isfinite(c1) or c1 <= 0.0:  # amplitudes do not grow with mu
            c1 = max(span / max(float(np.ptp(A2)), 1e-12), 1e-12)
            mu0 = float(np.min(mu_t - c1 * A2))
        # keep every orbit inside the existence region
        mu0 = min(mu0, float(np.min(mu_t)) - 0.05 * span)
        return mu0, -1.0, float(1.0 / np.sqrt(c1))
    X = np.stack([np.ones_like(A2), A2, A2**2], axis=1)
    coef = None
    if len(np.unique(np.round(A2, 12))) >= 3:
        coef, *_ = np.linalg.lstsq(X, mu_t, rcond=None)
    if coef is not None and coef[2] > 0 and np.isfinite(coef).all():
        mu0, c1, c2 = (float(c) for c in coef)
        kappa2 = 1.0 / np.sqrt(c2)
        a2 = -c1 * kappa2
    else:  # fall back on a generic subcritical/supercritical shape through the data
        mu0, a2, kappa2 = float(np.max(mu_t) + 0.25 * span), 1.0, 1.0
        kappa2 = float(np.sqrt(np.max(A2)) / 1.2) ** 2
    if criticality == "subcritical" and a2 <= 0.05:
        a2 = 0.5
    if criticality == "supercritical" and a2 >= -0.05:
        a2 = -0.5
    # make every labelled orbit exist: fold below the lowest unstable/stable parameter
    if a2 > 0:
        fold = mu0 - a2**2 / 4
        lo = float(np.min(mu_t))
        if fold > lo - 0.05 * span:
            a2 = float(2.0 * np.sqrt(max(mu0 - lo + 0.05 * span, 1e-6)))
        unstable = branch == INNER
        if np.any(unstable) and mu0 < float(np.max(mu_t[unstable])) + 0.02 * span:
            mu0 = float(np.max(mu_t[unstable])) + 0.02 * span
    return float(mu0), float(a2), float(np.sqrt(kappa2))
