r"""Intervals of a fitted mechanistic model: Gauss–Newton covariance of the free parameters
and the delta method through implicit-function Jacobians of the located points.

**Covariance.** At the fitted parameters every measured LCO :math:`(\lambda_j, h_j)` is
matched by a model orbit (the whole-diagram residuals of eq. 4.15, scaled per output as in
the fit); their exact amplitude Jacobian
(:meth:`~bifid.identify.mechanistic.OrbitSet.amplitude_jacobian`) gives the Gauss–Newton
covariance :math:`\hat\sigma^2 (J^\mathsf{T}J)^{+}` with the noise variance
:math:`\hat\sigma^2` estimated from the residuals (:mod:`bifid.identify._intervals`). It
carries the uncertainty of a linear stage's parameters (fitted on the free decay) by the
two-stage propagation of :func:`parameter_covariance`; other fixed parameters are exact.

**Hopf point.** :math:`z = (x, \lambda, v_r, v_i, \omega)` solves
:math:`f(x,\lambda) = 0,\ J v_r + \omega v_i = 0,\ J v_i - \omega v_r = 0,\
v_{r,k} = 1,\ v_{i,k} = 0` (the critical eigenvector normalised at its largest entry
:math:`k`); :math:`dz/d\theta = -H_z^{-1}H_\theta` gives :math:`d\lambda_H/d\theta` and
:math:`d\omega/d\theta`.

**Cycle fold.** With the collocation residual :math:`G(y,\lambda)` of eq. 4.14 (phase
condition included, :func:`bifid.continuation.orbit_problem`), the fold solves
:math:`G = 0,\ G_y\varphi = 0,\ \varphi_0^\mathsf{T}\varphi = 1`; its implicit Jacobian
moves the whole orbit, so the fold's speed, period and amplitude all get gradients.

**Branch band.** At each orbit of the branch, at fixed :math:`\lambda`,
:math:`[G_y;\,e_\lambda^\mathsf{T}]\,dy/d\theta = -[G_\theta;\,0]` and the amplitude's
derivative follows by the envelope theorem (the maximiser does not move to first order). Near
a cycle fold this derivative grows without bound and the linearisation fails; within the
fold's own parameter interval the orbit may not exist at all at that parameter, so the band
is left undefined (NaN) there.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from bifid.continuation import (
    Branch,
    Diagram,
    SpecialPoint,
    fourier_differentiation_matrix,
    orbit_problem,
)
from bifid.errors import ConvergenceError
from bifid.identify._intervals import Covariance, gauss_newton_covariance, implicit_sensitivity
from bifid.identify._records import LCOData
from bifid.identify.mechanistic._branch import data_branch
from bifid.identify.mechanistic._orbits import (
    OrbitSet,
    _full_jacobian,
    _param_jacobian,
    max_abs_with_weights,
)
from bifid.systems import System

__all__ = ["add_intervals", "parameter_covariance"]


def parameter_covariance(
    system: System,
    p: np.ndarray,
    param: str,
    data: LCOData,
    outputs: tuple[str, ...],
    free: tuple[str, ...],
    n_mesh: int,
    hopf_guess: float,
    linear_errors: Mapping[str, float] | None = None,
    ties: Mapping[str, str] | None = None,
) -> Covariance:
    r"""Covariance of the fitted parameters at ``p`` (module docstring).

    ``linear_errors``: standard errors of parameters fitted beforehand on other data (the
    linear stage), treated as independent of the LCO noise; the free parameters' fit then
    inherits their uncertainty through :math:`B = d\hat\theta_f/d\theta_l =
    -(J_f^\mathsf{T}J_f)^{+}J_f^\mathsf{T}J_l` (two-stage covariance,
    :math:`C_f + B C_l B^\mathsf{T}`). ``ties``: ``{dependent: source}`` parameters kept in
    a fixed ratio (they move together).

    Raises
    ------
    BifidInputError
        With no more matched amplitudes than free parameters.
    ConvergenceError
        If the model's orbits cannot be matched to the data at ``p``.
    """
    linear = {k: float(v) for k, v in (linear_errors or {}).items() if k not in free}
    names = (*linear, *free)
    dirs = np.zeros((len(names), np.asarray(p).size))
    for i, nm in enumerate(names):
        dirs[i, system.index(nm)] = 1.0
        for dep, src in (ties or {}).items():
            if src == nm and p[system.index(src)] != 0:
                dirs[i, system.index(dep)] = p[system.index(dep)] / p[system.index(src)]
    used = np.flatnonzero(np.any(dirs != 0, axis=0))
    branch = data_branch(system, p, param, data.param, n_mesh=n_mesh, guess=hopf_guess)
    orbits = OrbitSet(system, param, n_mesh, outputs)
    matched = orbits.match(branch, data, p, skip_missing=True)
    meas_all = np.column_stack([data.column(o) for o in outputs])
    scale = np.where(np.max(meas_all, axis=0) > 0, np.max(meas_all, axis=0), 1.0)
    r = ((orbits.amplitudes() - meas_all[matched]) / scale).ravel()
    jac = orbits.amplitude_jacobian(p, [system.parameter_names[k] for k in used])
    J = (jac / scale[None, :, None]).reshape(-1, used.size) @ dirs[:, used].T
    nl = len(linear)
    cf = gauss_newton_covariance(free, J[:, nl:], r)
    if not nl:
        return Covariance(cf.names, cf.cov, cf.dof, cf.sigma, dirs)
    Jf, Jl = J[:, nl:], J[:, :nl]
    B = -np.linalg.pinv(Jf.T @ Jf) @ Jf.T @ Jl
    Cl = np.diag(np.array(list(linear.values())) ** 2)
    cov = np.block([[Cl, Cl @ B.T], [B @ Cl, cf.cov + B @ Cl @ B.T]])
    return Covariance(names, cov, cf.dof, cf.sigma, dirs)


# ------------------------------------------------------------------- located points
@functools.lru_cache(maxsize=16)
def _hopf_jacobians(field: Callable, n: int) -> Callable:
    """Jitted ``(H_z, H_p)`` of the Hopf extended system (module docstring)."""

    def H(z, p, idx, k):
        x, lam = z[:n], z[n]
        vr, vi, om = z[n + 1 : 2 * n + 1], z[2 * n + 1 : 3 * n + 1], z[3 * n + 1]
        q = p.at[idx].set(lam)
        A = jax.jacfwd(field)(x, q)
        return jnp.concatenate(
            [field(x, q), A @ vr + om * vi, A @ vi - om * vr, (vr[k] - 1.0)[None], vi[k][None]]
        )

    return jax.jit(lambda *a: (jax.jacfwd(H)(*a), jax.jacfwd(H, 1)(*a)))


def hopf_gradients(
    system: System, p: np.ndarray, idx: int, sp: SpecialPoint
) -> tuple[np.ndarray, np.ndarray]:
    """``d lambda_H / dp`` and ``d omega / dp`` of a located Hopf point, each (n_params,)."""
    n = system.n_states
    x = np.asarray(sp.solution, dtype=float)[:n]
    q = np.asarray(p, dtype=float).copy()
    q[idx] = sp.param
    A = np.asarray(jax.jacfwd(system.field)(jnp.asarray(x), jnp.asarray(q)))
    mu, vecs = np.linalg.eig(A)
    j = int(np.argmin(np.abs(mu - 1j * abs(float(sp.data.get("omega", abs(mu.imag).max()))))))
    v = vecs[:, j] if mu[j].imag >= 0 else np.conj(vecs[:, j])
    k = int(np.argmax(np.abs(v)))
    v = v / v[k]
    z = np.concatenate([x, [sp.param], v.real, v.imag, [abs(mu[j].imag)]])
    Hz, Hp = _hopf_jacobians(system.field, n)(jnp.asarray(z), jnp.asarray(q), idx, k)
    dz = implicit_sensitivity(np.asarray(Hz), np.asarray(Hp))
    dz[:, idx] = 0.0  # the bifurcation parameter is the unknown, not a parameter
    return dz[n], dz[3 * n + 1]


@functools.lru_cache(maxsize=16)
def _fold_jacobians(problem) -> Callable:
    """Jitted ``(H_z, H_p)`` of the cycle-fold extended system (module docstring)."""

    def H(z, p, idx, dref, ell):
        N = ell.shape[0]
        y, phi = z[: N + 1], z[N + 1 :]
        args = {"p": p, "idx": idx, "dref": dref}
        G = problem.residual(y, args)
        _, Gphi = jax.jvp(
            lambda u: problem.residual(jnp.concatenate([u, y[N:]]), args), (y[:N],), (phi,)
        )
        return jnp.concatenate([G, Gphi, (ell @ phi - 1.0)[None]])

    return jax.jit(lambda *a: (jax.jacfwd(H)(*a), jax.jacfwd(H, 1)(*a)))


def _orbit_args(p: np.ndarray, idx: int, V: np.ndarray) -> dict:
    D = fourier_differentiation_matrix(V.shape[0])
    return {"p": jnp.asarray(p), "idx": jnp.asarray(idx), "dref": jnp.asarray((D @ V).ravel())}


def fold_gradients(
    system: System, p: np.ndarray, idx: int, sp: SpecialPoint
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gradients (in ``p``) of a cycle fold's parameter, period and amplitude
    ``max_t |x_s(t)|`` of every state: shapes (n_p,), (n_p,), (n_states, n_p)."""
    n = system.n_states
    sol = np.asarray(sp.solution, dtype=float)
    M = (sol.size - 1) // n
    V = sol[: M * n].reshape(M, n)
    problem = orbit_problem(system.field, M, n)
    args = _orbit_args(p, idx, V)
    y = jnp.asarray(np.concatenate([sol[: M * n + 1], [sp.param]]))
    Gy = np.asarray(_full_jacobian(problem)(y, args))[:, : M * n + 1]
    phi = np.linalg.svd(Gy)[2][-1]
    z = np.concatenate([np.asarray(y), phi])
    Hz, Hp = _fold_jacobians(problem)(
        jnp.asarray(z), args["p"], args["idx"], args["dref"], jnp.asarray(phi)
    )
    dz = implicit_sensitivity(np.asarray(Hz), np.asarray(Hp))
    dz[:, idx] = 0.0
    return dz[M * n + 1], dz[M * n], _amplitude_gradients(V, dz[: M * n].reshape(M, n, -1))


def _amplitude_gradients(V: np.ndarray, dV: np.ndarray) -> np.ndarray:
    """``d max_t|x_s| / dp`` of each state from ``dV`` (M, n, n_p): (n, n_p)."""
    return np.stack([max_abs_with_weights(V[:, s])[1] @ dV[:, s, :] for s in range(V.shape[1])])


def branch_amplitude_gradients(
    system: System, p: np.ndarray, idx: int, branch: Branch
) -> np.ndarray:
    """``d max_t|x_s| / dp`` at fixed parameter on every orbit of a periodic branch,
    (n_points, n_states, n_p)."""
    n = system.n_states
    sols = np.asarray(branch.solutions, dtype=float)
    # every orbit of a branch is stored on its common (largest) mesh, whatever mesh it
    # was computed on; the interpolant there is exact
    M = int(branch.meta["n_mesh"])
    problem = orbit_problem(system.field, M, n)
    out = np.empty((len(branch), n, np.asarray(p).size))
    for i in range(len(branch)):
        V = sols[i, : M * n].reshape(M, n)
        q = np.asarray(p, dtype=float).copy()
        q[idx] = branch.params[i]
        args = _orbit_args(q, idx, V)
        y = jnp.asarray(np.concatenate([sols[i, : M * n + 1], [branch.params[i]]]))
        A = np.vstack([np.asarray(_full_jacobian(problem)(y, args)), np.eye(M * n + 2)[-1]])
        Gp = np.array(_param_jacobian(problem)(y, args))
        Gp[:, idx] = 0.0
        try:
            dy = np.linalg.solve(A, -np.vstack([Gp, np.zeros((1, Gp.shape[1]))]))
        except np.linalg.LinAlgError:  # the Hopf end (no phase) or exactly at a fold
            out[i] = np.nan
            continue
        out[i] = _amplitude_gradients(V, dy[: M * n].reshape(M, n, -1))
    return out


# ------------------------------------------------------------------------- diagram
def add_intervals(
    diagram: Diagram,
    system: System,
    p: np.ndarray,
    param: str,
    cov: Covariance,
    level: float,
) -> None:
    """Fill ``intervals`` of the diagram's Hopf points, cycle folds and orbit branches
    (``param``, ``period``, ``amplitude``) at ``level`` and set ``diagram.level``."""
    idx = system.index(param)
    for b in diagram.branches:
        for sp in b.special_points:
            for key, (value, grad) in _point_gradients(system, p, idx, sp).items():
                lo, hi = cov.interval(value, cov.project(grad), level)
                sp.intervals[key] = (lo.tolist(), hi.tolist())
        if b.kind == "periodic" and len(b) and "amplitude" in b.data:
            grads = cov.project(branch_amplitude_gradients(system, p, idx, b))
            lo, hi = cov.interval(np.asarray(b.data["amplitude"]), grads, level)
            # within a cycle fold's interval the orbit may not exist at that parameter: no
            # amplitude interval at fixed parameter there
            for sp in diagram.special("cycle_fold"):
                if "param" in sp.intervals:
                    a, c = sp.intervals["param"]
                    lo[(b.params >= a) & (b.params <= c)] = np.nan
                    hi[(b.params >= a) & (b.params <= c)] = np.nan
            b.intervals["amplitude"] = (lo, hi)
    diagram.level = level


def _point_gradients(
    system: System, p: np.ndarray, idx: int, sp: SpecialPoint
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{quantity: (value, gradient in p)}`` of a Hopf point or cycle fold (empty for other
    kinds, or where the located point is degenerate)."""
    try:
        if sp.kind == "hopf":
            dlam, dom = hopf_gradients(system, p, idx, sp)
            out = {"param": (sp.param, dlam), "omega": (sp.data.get("omega"), dom)}
        elif sp.kind == "cycle_fold":
            dlam, dT, dA = fold_gradients(system, p, idx, sp)
            out = {
                "param": (sp.param, dlam),
                "period": (sp.data.get("period"), dT),
                "amplitude": (sp.data.get("amplitude"), dA),
            }
        else:
            return {}
    except ConvergenceError:
        return {}
    return {
        k: (np.asarray(v, dtype=float), g)
        for k, (v, g) in out.items()
        if v is not None and np.shape(v) == np.shape(g)[:-1]
    }
