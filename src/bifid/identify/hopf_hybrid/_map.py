r"""The coordinate map :math:`\mathbf U_{12}` and its staged training (thesis §5.3.1–5.3.4).

.. math::

    \mathbf U_{12}(u_1, u_2, \tilde\mu) = T_L(u_1, u_2, \tilde\mu) + T_s
        + \mathrm{NN}_{\Theta_U}(u_1, u_2, \tilde\mu)\qquad\text{(eqs. 5.8–5.9)}

maps normal-form coordinates to the (normalised) measured plane :math:`(z_1, z_2)`. The loss
(eq. 5.7, squared, with Parseval weights — evaluated by quadrature, see
:func:`~._polar.polar_mismatch` — plus the centroid match of :mod:`._polar`) is

.. math::

    \Xi_U = \frac{\sum_i w_i\bigl(\lVert\Phi(R_i) - \Phi(\hat R_i)\rVert_P^2
            + \lVert\mathbf c_i - \hat{\mathbf c}_i\rVert^2\bigr)}{\sum_i w_i}
            + \beta\sum_i \text{existence}_i + \lambda\lVert\Theta_U\rVert^2 ,

where :math:`\hat R_i` is the polar representation of the model cycle of orbit :math:`i`: the
circle of radius :math:`\rho_i(\tilde\mu_i;\tilde\mu_0, a_2)` (on the branch of the orbit's
stability label; for an unlabelled orbit, the better of the two) mapped by
:math:`\mathbf U_{12}`. Stage 1 trains :math:`T_L, T_s` with :math:`\tilde\mu_0, a_2` fixed at
their initial guess; stage 2 trains :math:`\Theta_U, \tilde\mu_0, a_2` with :math:`T_L, T_s`
fixed (§5.3.4). Everything is a pure function of arrays so that cross-validation folds,
regularisation strengths and ensemble seeds train together under one ``vmap``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from bifid.identify.hopf_hybrid._normal_form import (
    existence_violation,
    initial_guess,
    lco_radius2,
)
from bifid.identify.hopf_hybrid._optim import minimise
from bifid.identify.hopf_hybrid._polar import polar_mismatch, polygon_centroid

Array = jnp.ndarray

EXISTENCE_WEIGHT = 1e3


@dataclass(frozen=True)
class MapConfig:
    """Static settings of the map stage (hashable: keys the compiled trainers).

    Attributes
    ----------
    n_harmonics : int
        Harmonics of the polar representation :math:`R(\\theta)` (eq. 5.5).
    n_points : int
        Points per model cycle mapped by :math:`\\mathbf U_{12}`.
    width, depth : int
        Hidden width and number of hidden layers of :math:`\\mathrm{NN}_{\\Theta_U}` (tanh).
    q5 : float
        Quintic coefficient (1.0 on, 0.0 off).
    a2_mode : {"positive", "negative", "fixed"}
        Sign constraint of :math:`a_2` (sub-/supercritical), or fixed at -1 (no quintic).
    n_linear : int
        L-BFGS iterations of stage 1.
    n_adam, n_lbfgs : int
        Adam and L-BFGS iterations of stage 2.
    learning_rate : float
        Peak Adam learning rate of stage 2.
    unlabelled : bool
        Some orbits have no stability label: evaluate both branches and keep the better.
    """

    n_harmonics: int = 8
    n_points: int = 64
    width: int = 16
    depth: int = 2
    q5: float = 1.0
    a2_mode: str = "positive"
    n_linear: int = 100
    n_adam: int = 300
    n_lbfgs: int = 300
    learning_rate: float = 3e-3
    unlabelled: bool = False


# ----------------------------------------------------------------------------- network
def mlp(
    key: Array, in_size: int, out_size: int, width: int, depth: int, scale: float
) -> eqx.Module:
    """An equinox tanh MLP whose output layer is scaled by ``scale`` (a small correction)."""
    net = eqx.nn.MLP(in_size, out_size, width, depth, activation=jnp.tanh, key=key)
    last = net.layers[-1]
    net = eqx.tree_at(lambda m: m.layers[-1].weight, net, last.weight * scale)
    return eqx.tree_at(lambda m: m.layers[-1].bias, net, last.bias * scale)


@functools.lru_cache(maxsize=32)
def mlp_static(in_size: int, out_size: int, width: int, depth: int):
    """The non-array part of an MLP of this shape (to rebuild it from its arrays)."""
    net = eqx.nn.MLP(in_size, out_size, width, depth, activation=jnp.tanh, key=jax.random.key(0))
    return eqx.partition(net, eqx.is_array)[1]


def mlp_apply(arrays, static, x: Array) -> Array:
    """Evaluate the MLP given its arrays and static part, one input ``x``."""
    return eqx.combine(arrays, static)(x)


def l2(tree) -> Array:
    """Sum of squares of the weight matrices of an MLP's arrays (biases not penalised)."""
    return sum(jnp.sum(layer.weight**2) for layer in tree.layers)


def a2_of(alpha: Array, mode: str) -> Array:
    """:math:`a_2` from its unconstrained parameter: softplus with the sign of ``mode``."""
    if mode == "positive":
        return jax.nn.softplus(alpha)
    if mode == "negative":
        return -jax.nn.softplus(alpha)
    return -1.0 + 0.0 * alpha


def alpha_of(a2: float, mode: str) -> float:
    """Inverse of :func:`a2_of` (for initialisation)."""
    if mode == "fixed":
        return 0.0
    v = abs(a2)
    return float(v + np.log(-np.expm1(-v)))  # softplus^{-1}


# --------------------------------------------------------------------------- the map
def u12(params, static, u: Array, mu_t: Array) -> Array:
    r""":math:`\mathbf U_{12}` at one point ``u`` (shape (2,)) and parameter (eq. 5.8)."""
    x = jnp.concatenate([u, mu_t[None]])
    return params["L"] @ x + params["s"] + mlp_apply(params["nn"], static, x)


def model_cycle(params, static, mu_t: Array, branch: Array, config: MapConfig) -> Array:
    """The model cycle at ``mu_t`` mapped to the measured plane, shape ``(n_points, 2)``."""
    a2 = a2_of(params["alpha"], config.a2_mode)
    rho2 = jnp.maximum(lco_radius2(mu_t, params["mu0"], a2, config.q5, branch), 1e-4)
    rho = jnp.sqrt(rho2)
    phi = jnp.linspace(0.0, 2 * jnp.pi, config.n_points, endpoint=False)
    u = rho * jnp.stack([jnp.cos(phi), jnp.sin(phi)], axis=1)
    return jax.vmap(lambda ui: u12(params, static, ui, mu_t))(u)


def orbit_loss(params, static, mu_t, branch, coef, centre, config: MapConfig) -> Array:
    """Shape + centroid mismatch of one orbit on one branch (eq. 5.7, squared, Parseval)."""
    pts = model_cycle(params, static, mu_t, branch, config)
    c_hat = polygon_centroid(pts)
    a2 = a2_of(params["alpha"], config.a2_mode)
    exist = existence_violation(mu_t, params["mu0"], a2, config.q5, branch)
    return (
        polar_mismatch(pts, c_hat, coef, config.n_harmonics)
        + jnp.sum((c_hat - centre) ** 2)
        + EXISTENCE_WEIGHT * exist
    )


def orbit_losses(params, static, data, config: MapConfig) -> Array:
    """Loss of every orbit, shape ``(n_orbits,)``; unlabelled orbits take the better branch."""

    def one(mu_t, code, coef, centre):
        if config.q5 == 0.0:
            return orbit_loss(params, static, mu_t, 1.0, coef, centre, config)
        if not config.unlabelled:
            return orbit_loss(
                params, static, mu_t, jnp.where(code < 0, -1.0, 1.0), coef, centre, config
            )
        lp = orbit_loss(params, static, mu_t, 1.0, coef, centre, config)
        lm = orbit_loss(params, static, mu_t, -1.0, coef, centre, config)
        return jnp.where(code > 0, lp, jnp.where(code < 0, lm, jnp.minimum(lp, lm)))

    return jax.vmap(one)(data["mu_t"], data["branch"], data["coef"], data["centre"])


# ------------------------------------------------------------------------- training
def _masks(params):
    """Stage masks: stage 1 trains ``L, s``; stage 2 the network, ``mu0`` and ``alpha``."""
    zeros = jax.tree_util.tree_map(jnp.zeros_like, params)
    ones = jax.tree_util.tree_map(jnp.ones_like, params)
    lin = {**zeros, "L": ones["L"], "s": ones["s"]}
    net = {**zeros, "nn": ones["nn"], "mu0": ones["mu0"], "alpha": ones["alpha"]}
    return lin, net


@functools.lru_cache(maxsize=16)
def trainer(config: MapConfig):
    """Compiled two-stage training ``(params, data, weights, lam, stop_at)`` of one model.

    ``weights`` (per orbit; 0 leaves an orbit out), ``lam`` and ``stop_at`` (the number of
    stage-2 iterations after which the parameters are returned: early stopping) are traced,
    so cross-validation folds, regularisation strengths and ensemble seeds all reuse one
    executable. Returns the parameters, the per-orbit losses along stage 2 (shape
    ``(n_adam + n_lbfgs, n_orbits)``) and the training loss.

    Without Adam both stages run through **one** compiled L-BFGS loop (a ``scan`` over the two
    stages with their masks and iteration budgets), which halves the compilation time. (A
    ``vmap`` over folds was tried: on CPU it gives no throughput gain for problems this small,
    and every batch size costs a new compilation.)
    """
    static = mlp_static(3, 2, config.width, config.depth)

    def make_loss(data, weights, lam):
        wsum = jnp.maximum(jnp.sum(weights), 1e-12)

        def loss(theta):
            losses = orbit_losses(theta, static, data, config)
            return jnp.sum(weights * losses) / wsum + lam * l2(theta["nn"]), losses

        return loss

    def run(params, data, weights, lam, stop_at):
        mask_lin, mask_net = _masks(params)
        if config.n_adam == 0:
            n = max(config.n_linear, config.n_lbfgs)
            specs = (
                _stack_trees([mask_lin, mask_net]),
                jnp.array([config.n_linear, config.n_lbfgs]),
                jnp.stack([jnp.zeros_like(lam), lam]),
                jnp.stack([jnp.asarray(config.n_linear), jnp.asarray(stop_at)]),
            )

            def stage(p, spec):
                mask, limit, lam_s, stop = spec
                p_new, hist, (final, _) = minimise(
                    make_loss(data, weights, lam_s),
                    p,
                    n_adam=0,
                    n_lbfgs=n,
                    learning_rate=config.learning_rate,
                    stop_at=stop,
                    mask=mask,
                    lbfgs_limit=limit,
                )
                return p_new, (hist, final)

            p2, (hists, finals) = jax.lax.scan(stage, params, specs)
            return p2, hists[1, : config.n_lbfgs], finals[1]
        p1, _, _ = minimise(
            make_loss(data, weights, 0.0),
            params,
            n_adam=0,
            n_lbfgs=config.n_linear,
            learning_rate=config.learning_rate,
            mask=mask_lin,
        )
        p2, hist, (final, _) = minimise(
            make_loss(data, weights, lam),
            p1,
            n_adam=config.n_adam,
            n_lbfgs=config.n_lbfgs,
            learning_rate=config.learning_rate,
            stop_at=stop_at,
            mask=mask_net,
        )
        return p2, hist, final

    return jax.jit(run)


def _stack_trees(trees):
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *trees)


@functools.lru_cache(maxsize=16)
def loss_evaluator(config: MapConfig):
    """Compiled per-orbit losses: ``(params, data) -> (n_orbits,)``."""
    static = mlp_static(3, 2, config.width, config.depth)
    return jax.jit(lambda p, d: orbit_losses(p, static, d, config))


# --------------------------------------------------------------------- initialisation
def _sqrtm_spd(S):
    w, V = np.linalg.eigh(0.5 * (S + S.T))
    return (V * np.sqrt(np.maximum(w, 1e-12))) @ V.T


def initial_params(prep, train_mask, config: MapConfig, key: Array, criticality: str):
    r"""Initial :math:`T_L, T_s, \tilde\mu_0, a_2` and network from the training orbits.

    :math:`\tilde\mu_0, a_2` from :func:`~._normal_form.initial_guess`; then, with
    :math:`\rho_i` the model radii, :math:`T_L[:, :2] = \sqrt{2\,\overline{\Sigma_i/\rho_i^2}}`
    (an ellipse with the orbits' mean covariance; its orientation sign makes the model rotate
    the way the data do, so that :math:`\omega_0 > 0`), and
    :math:`T_L[:, 2]\tilde\mu + T_s` the least-squares line through the centroids.
    """
    idx = np.nonzero(train_mask)[0]
    mu_t = prep.mu_t[idx]
    branch = prep.root[idx]
    mu0, a2, kappa = initial_guess(mu_t, prep.size[idx], branch, criticality, config.q5)
    rho2 = []
    for mt, b, size in zip(mu_t, branch, prep.size[idx], strict=True):
        if config.q5 == 0.0:
            r2 = max(-(mt - mu0) / a2, 1e-4)
        else:
            disc = max(a2**2 + 4 * (mt - mu0), 0.0)
            rp, rm = 0.5 * (a2 + np.sqrt(disc)), 0.5 * (a2 - np.sqrt(disc))
            if b == 0:
                target = (size / kappa) ** 2
                r2 = rp if abs(rp - target) <= abs(rm - target) else rm
            else:
                r2 = rp if b > 0 else rm
            r2 = max(r2, 1e-4)
        rho2.append(r2)
    rho2 = np.asarray(rho2)
    S = np.mean(prep.cov[idx] / rho2[:, None, None], axis=0)
    E = _sqrtm_spd(2.0 * S) @ np.diag([1.0, prep.direction])
    X = np.stack([np.ones_like(mu_t), mu_t], axis=1)
    cc, *_ = np.linalg.lstsq(X, prep.centre[idx], rcond=None)  # (2, 2): rows s, l3
    L = np.concatenate([E, cc[1][:, None]], axis=1)
    net = mlp(key, 3, 2, config.width, config.depth, 0.0)
    return {
        "L": jnp.asarray(L),
        "s": jnp.asarray(cc[0]),
        "nn": eqx.filter(net, eqx.is_array),
        "mu0": jnp.asarray(mu0),
        "alpha": jnp.asarray(alpha_of(a2, config.a2_mode)),
    }
