r"""Maps to the other measured signals :math:`\mathbf U_{3\dots m}` (thesis §5.3.1, last part).

Once :math:`\mathbf U_{12}` is trained, every measured sample has a normal-form point
:math:`(u_1, u_2, \tilde\mu) = (\rho_i\cos\phi, \rho_i\sin\phi, \tilde\mu_i)` (phase :math:`\phi`
from the inversion of eq. 5.12), so the remaining signals are an ordinary regression problem.
bifid uses a linear model plus kernel ridge regression of its residual,

.. math::

    \hat z_k(\mathbf x) = \mathbf f(\mathbf x)^{\mathsf T}\boldsymbol\beta_k
        + \sum_n \alpha_{kn}
          \exp\!\Bigl(-\tfrac12\lVert(\mathbf x - \mathbf x_n)/\ell\rVert^2\Bigr),
    \qquad \mathbf f = [1, u_1, u_2, \tilde\mu, u_1\tilde\mu, u_2\tilde\mu],

(the linear part carries the near-elliptic, parameter-scaled response and the extrapolation; the
kernel part the nonlinear corrections). The length scale :math:`\ell` and ridge :math:`\lambda`
are chosen by leave-one-orbit-out cross-validation over a small grid — points of one orbit are
strongly correlated, so leaving out single points would reward overfitting.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

LENGTH_GRID = (0.5, 1.0, 2.0, 4.0)
POINTS_PER_ORBIT = 32
RIDGE_GRID = (1e-6, 1e-4, 1e-2)


def features(x: np.ndarray) -> np.ndarray:
    """Linear-model features of inputs ``x`` (shape ``(n, 3)``: u1, u2, mu_t)."""
    u1, u2, m = x[:, 0], x[:, 1], x[:, 2]
    return np.stack([np.ones_like(u1), u1, u2, m, u1 * m, u2 * m], axis=1)


def _kernel(a: np.ndarray, b: np.ndarray, ell: float) -> np.ndarray:
    d2 = np.sum(a**2, 1)[:, None] + np.sum(b**2, 1)[None, :] - 2 * a @ b.T
    return np.exp(-0.5 * np.maximum(d2, 0.0) / ell**2)


@dataclass
class ObservationModel:
    """Fitted linear + kernel ridge regression of the other signals (normalised units)."""

    x_train: np.ndarray  # (n, 3)
    beta: np.ndarray  # (6, k)
    alpha: np.ndarray  # (n, k)
    length: float
    ridge: float
    cv_error: float

    def predict(self, x: np.ndarray) -> np.ndarray:
        """Signals at normal-form inputs ``x`` (shape ``(n, 3)``) → ``(n, k)``."""
        out = features(x) @ self.beta
        if self.alpha.size:
            out = out + _kernel(x, self.x_train, self.length) @ self.alpha
        return out

    def arrays(self, prefix: str) -> dict[str, np.ndarray]:
        return {
            f"{prefix}x": self.x_train,
            f"{prefix}beta": self.beta,
            f"{prefix}alpha": self.alpha,
            f"{prefix}hyper": np.array([self.length, self.ridge, self.cv_error]),
        }

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str) -> ObservationModel:
        hyper = arrays[f"{prefix}hyper"]
        return cls(
            x_train=arrays[f"{prefix}x"],
            beta=arrays[f"{prefix}beta"],
            alpha=arrays[f"{prefix}alpha"],
            length=float(hyper[0]),
            ridge=float(hyper[1]),
            cv_error=float(hyper[2]),
        )


def _fit(x, y, ell, lam):
    F = features(x)
    beta, *_ = np.linalg.lstsq(F, y, rcond=None)
    res = y - F @ beta
    K = _kernel(x, x, ell)
    alpha = cho_solve(cho_factor(K + lam * len(x) * np.eye(len(x))), res)
    return beta, alpha


def fit_observation(
    x: np.ndarray,
    y: np.ndarray,
    groups: np.ndarray,
    length: float | None = None,
    ridge: float | None = None,
) -> ObservationModel:
    """Fit the regression; hyperparameters by leave-one-orbit-out CV unless both are given.

    Parameters
    ----------
    x : array of shape (n, 3)
        Normal-form inputs ``(u1, u2, mu_t)``.
    y : array of shape (n, k)
        Normalised signals to predict.
    groups : int array of shape (n,)
        Orbit index of each sample (the CV folds).
    """
    candidates = (
        [(length, ridge)]
        if length is not None and ridge is not None
        else [(ell, lam) for ell in LENGTH_GRID for lam in RIDGE_GRID]
    )
    ug = np.unique(groups)
    best = (np.inf, candidates[0])
    if len(candidates) > 1 and len(ug) >= 3:
        for ell, lam in candidates:
            err = 0.0
            for g in ug:
                tr, te = groups != g, groups == g
                beta, alpha = _fit(x[tr], y[tr], ell, lam)
                pred = features(x[te]) @ beta + _kernel(x[te], x[tr], ell) @ alpha
                err += np.mean((pred - y[te]) ** 2)
            err /= len(ug)
            if err < best[0]:
                best = (err, (ell, lam))
    err, (ell, lam) = best
    beta, alpha = _fit(x, y, ell, lam)
    return ObservationModel(x, beta, alpha, float(ell), float(lam), float(err))
