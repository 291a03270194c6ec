"""Periodic orbits of autonomous systems by Fourier spectral collocation (thesis eqs. 4.12–4.14).

Unknowns ``y = [v_1 .. v_M, T, lambda]`` (mesh values on ``tau_k = 2 pi k / M``, the
period and the parameter); equations

.. math::

    D_M v - \\frac{T}{2\\pi} f(v_k, \\lambda) = 0 \\quad (k = 1..M),\\qquad
    \\frac1M\\sum_k \\langle v_k, (D_M v^{\\rm ref})_k\\rangle = 0,

the second being the integral phase condition against the previous point of the
branch. Pseudo-arclength continuation (``_palc``) adds the arclength equation. The
Jacobian is assembled explicitly — ``kron(D_M, I) - T/2pi blockdiag(f_x(v_k))`` plus two
columns — which is far cheaper than differentiating the whole residual.

The mesh follows the orbits (``_mesh``: refined where the spectral tail exceeds the
tolerance, coarsened again where the orbits are smooth, up to ``max_mesh``); the
branch's Floquet multipliers, special points and end are worked out in
``_orbit_branch``.

**Rescaled time** (``ContinuationOptions.rescale``, ``_density``; by default "auto": only
once a uniform mesh would grow large, ``_mesh``): the mesh points may
sit at the physical times ``t(tau) = (T / 2 pi) int_0^tau h`` of a smooth positive
density ``h`` of mean 1, fixed between mesh updates (``args["h"]``); the equations become

.. math::

    D_M v - \\frac{T}{2\\pi} h_k f(v_k, \\lambda) = 0,

with the phase condition and the arclength unchanged in ``tau`` and ``h_k`` in the
Jacobian's block diagonal and its ``T`` and ``lambda`` columns. At every mesh event the
density is chosen to equidistribute the orbit's arclength, so a relaxation oscillation
that needs thousands of uniform points is resolved on a few hundred. Everything that
reads an orbit in time accounts for ``h`` (``_density`` module docstring); the branch's
``solutions`` are samples at uniform times either way.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from bifid.continuation._branch import Branch, SpecialPoint
from bifid.continuation._density import convert_values, density_values, equidistributing_mesh
from bifid.continuation._fourier import fourier_differentiation_matrix, fourier_grid, resample_orbit
from bifid.continuation._mesh import (
    MeshPolicy,
    Stage,
    mesh_tail,
    run_adaptive,
)
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._orbit_bifurcations import STABILITY_SOURCES
from bifid.continuation._orbit_branch import OrbitEnds, orbit_branch
from bifid.continuation._palc import ZeroProblem, correct
from bifid.errors import BifidInputError, ConvergenceError
from bifid.signal import spectral_tail
from bifid.systems import System

Array = jnp.ndarray
TWO_PI = 2.0 * np.pi

__all__ = ["hopf_orbits", "orbit_problem", "periodic_orbits", "resample_orbit"]


@functools.lru_cache(maxsize=32)
def orbit_problem(field: Callable, n_mesh: int, n_states: int) -> ZeroProblem:
    """Collocation zero problem of autonomous periodic orbits (see module docstring).

    ``args = {"p": parameter vector, "idx": index of lambda, "dref": (M*n,) flattened
    D_M v_ref}`` and optionally ``"h"``: (M,) the mesh density (default ones, the uniform
    mesh; see ``_density``). ``y`` has ``M*n + 2`` components: mesh values (row-major ``(M, n)``),
    then ``T``, then ``lambda``.
    """
    M, n = n_mesh, n_states
    D = jnp.asarray(fourier_differentiation_matrix(M))
    vfield = jax.vmap(field, in_axes=(0, None))
    vjac = jax.vmap(jax.jacfwd(field), in_axes=(0, None))

    def _density_column(args, M):
        return args["h"][:, None] if "h" in args else jnp.ones((M, 1))

    def split(y, args):
        V = y[: M * n].reshape(M, n)
        T, lam = y[M * n], y[M * n + 1]
        return V, T, lam, args["p"].at[args["idx"]].set(lam)

    def residual(y, args):
        V, T, _, p = split(y, args)
        h = _density_column(args, M)
        R = D @ V - T / TWO_PI * h * vfield(V, p)
        phase = jnp.sum(y[: M * n] * args["dref"]) / M
        return jnp.concatenate([R.ravel(), phase[None]])

    def jacobian(y, args):
        V, T, lam, p = split(y, args)
        h = _density_column(args, M)
        Jk = vjac(V, p) * h[:, :, None]  # (M, n, n): h_k f_x(v_k)
        block = jnp.einsum("kij,kl->kilj", Jk, jnp.eye(M)).reshape(M * n, M * n)
        # kron(D, I) built at run time: as a compile-time constant XLA would fold a
        # (Mn)^2 array, which takes seconds for large meshes
        KD = jnp.kron(jax.lax.optimization_barrier(D), jnp.eye(n))
        dV = KD - T / TWO_PI * block
        dT = -(h * vfield(V, p)).ravel() / TWO_PI

        def f_of_lam(l):
            return (h * vfield(V, args["p"].at[args["idx"]].set(l))).ravel()

        dlam = -T / TWO_PI * jax.jvp(f_of_lam, (lam,), (jnp.ones_like(lam),))[1]
        top = jnp.concatenate([dV, dT[:, None], dlam[:, None]], axis=1)
        bottom = jnp.concatenate([args["dref"] / M, jnp.zeros(2)])[None, :]
        return jnp.concatenate([top, bottom], axis=0)

    return ZeroProblem(residual=residual, param_index=-1, jacobian=jacobian)


def orbit_weights(M: int, n: int) -> np.ndarray:
    """Arclength weights: mesh values as an average over the orbit (mesh-independent)."""
    return np.concatenate([np.full(M * n, 1.0 / M), [1.0, 1.0]])


def orbit_stage(system: System, p: Array, idx: int, M: int) -> Stage:
    """The collocation problem of ``system``'s orbits on the mesh ``M`` (``_mesh.Stage``; a
    :class:`~bifid.continuation._density.Mesh` carries its density)."""
    n = system.n_states
    D = fourier_differentiation_matrix(int(M))
    h = jnp.asarray(density_values(M))

    def args_of(y, _prev=None):
        V = np.asarray(y[: M * n]).reshape(M, n)
        return {"p": p, "idx": jnp.asarray(idx), "dref": jnp.asarray((D @ V).ravel()), "h": h}

    return Stage(
        problem=orbit_problem(system.field, int(M), n),
        weights=orbit_weights(M, n),
        args=args_of,
        update_args=lambda y, args: args_of(y),
    )


def hopf_orbits(
    system: System,
    hopf: SpecialPoint,
    *,
    p: Array | None = None,
    n_mesh: int = 64,
    max_mesh: int | None = None,
    adapt: bool = True,
    options: ContinuationOptions | None = None,
    amplitude0: float | None = None,
    progress: Callable[[int, float], None] | None = None,
    resolution_tol: float = 1e-9,
    stability: str = "integrated",
) -> Branch:
    """Continue the branch of periodic orbits born at a Hopf point.

    The first orbit is ``x_H + eps Re(q e^{i tau})`` (``q`` the critical eigenvector)
    corrected with its projection on ``q`` fixed; continuation then proceeds by
    pseudo-arclength, the mesh following the orbits, until a parameter bound (status
    ``"range"``), the orbits shrink into an equilibrium (``"hopf"``, the Hopf point
    located and recorded as the branch's last point), the period grows without bound
    (``"homoclinic"``), the mesh limit is reached (``"unresolved"``) or ``max_steps``.

    Parameters
    ----------
    system : System
    hopf : SpecialPoint
        A located Hopf point (from :func:`equilibria` or :func:`locate_hopf`).
    p : array, optional
        Parameter vector (defaults to the one stored with the Hopf point).
    n_mesh : int
        Starting (and smallest) number of collocation points M (even).
    max_mesh : int, optional
        Largest mesh (default: the largest ``n_mesh * 2^k`` with at most 4096 unknowns
        ``M * n``).
    adapt : bool
        Adapt the mesh (False keeps ``n_mesh``; an unresolved orbit then ends the branch).
    options : ContinuationOptions
        ``ds`` is the first amplitude step (RMS norm over the orbit).
    amplitude0 : float, optional
        Size of the first orbit (default ``options.ds``).
    resolution_tol : float
        Largest spectral tail of a reported orbit.
    stability : {"integrated", "collocation"}
        Source of the Floquet multipliers: the variational equation integrated with error
        control (default; any contraction; compiled once per process), or the eigenvalues
        of the collocation operator (``_floquet.collocation_floquet``: nothing to compile;
        smooth orbits resolved on their mesh). Special points are verified either way.

    Returns
    -------
    Branch
        ``kind="periodic"``; ``solutions[:, :M*n+1]`` the orbits at the uniform times
        ``T k / M`` and the period, ``M = meta["n_mesh"]``: the largest mesh of the branch
        (orbits computed on coarser meshes are interpolated exactly), or, for a branch
        computed (in part) in a rescaled time (``options.rescale``), the fewest uniform samples
        ``M_max 2^j`` that resolve every orbit (at most
        ``_density.MAX_EXPORT_SAMPLES``; ``meta["rescaled"]``); ``data`` has ``period``,
        ``amplitude`` (n_points, n) = max_t|x_s(t)|, ``n_mesh`` (the mesh of each orbit),
        ``floquet`` (n_points, n), ``floquet_log``, ``floquet_max``, ``spectral_tail``;
        verified special points "cycle_fold", "period_doubling", "torus" (candidates
        for what could not be verified).
    """
    if hopf.kind != "hopf" or "eigenvector" not in hopf.data:
        raise BifidInputError("hopf_orbits needs a located Hopf point (kind 'hopf' with data).")
    _check_stability(stability)
    options = options or ContinuationOptions()
    policy = MeshPolicy.of(
        n_mesh, max_mesh, resolution_tol, adapt, system.n_states, rescale=options.rescale
    )
    param = hopf.data.get("param_name") or system.default_param
    idx = system.index(param)
    p = jnp.asarray(hopf.data["p"] if p is None else p, dtype=jnp.float64)
    M, n = n_mesh, system.n_states
    stage = orbit_stage(system, p, idx, M)
    eps = options.ds if amplitude0 is None else float(amplitude0)
    y_h, y1, t0, args = _first_orbit(hopf, param, stage, p, idx, M, n, eps, options, resolution_tol)
    omega = float(hopf.data["omega"])
    ends = OrbitEnds(
        first_amplitude=_centred_amplitude(y1, M, n), first_period=TWO_PI / omega, n_states=n
    )
    stage_of, run = _continue_orbits(system, p, idx, y1, t0, policy, options, ends, progress)
    run.ys.insert(0, y_h)
    run.meshes.insert(0, M)
    run.tangents.insert(0, t0)
    run.tails.insert(0, 0.0)
    run.args.insert(0, args)
    run.events = [(i + 1, *rest) for i, *rest in run.events]
    return orbit_branch(system, param, p, run, options, policy, hopf, stage_of, stability)


def _first_orbit(hopf, param, stage, p, idx, M, n, eps, options, resolution_tol):
    """``(y_H, y_1, t_0, args)``: the Hopf point as a constant orbit, the first orbit
    ``x_H + eps Re(q e^{i tau})`` corrected with its projection on the critical eigenvector
    ``q`` fixed, the tangent between them and the problem's arguments."""
    tau = fourier_grid(M)
    q = np.asarray(hopf.data["eigenvector"], dtype=complex)
    q = q / np.max(np.abs(q))
    direction = np.real(np.outer(np.exp(1j * tau), q))  # (M, n)
    omega = float(hopf.data["omega"])
    x_h = np.asarray(hopf.solution, dtype=float)
    y_h = np.concatenate([np.tile(x_h, M), [TWO_PI / omega, hopf.param]])
    t0 = np.concatenate([direction.ravel(), [0.0, 0.0]])
    t0 = t0 / np.sqrt(t0 @ (stage.weights * t0))
    D = fourier_differentiation_matrix(M)
    args = {
        "p": p,
        "idx": jnp.asarray(idx),
        "dref": jnp.asarray((D @ direction).ravel()),
        "h": jnp.ones(M),
    }
    y_pred = y_h + eps * t0
    row = stage.weights * t0
    y1, ok, _, res = correct(
        stage.problem,
        y_pred,
        row,
        float(row @ y_pred),
        args,
        tol=options.newton_tol,
        max_iter=options.newton_max_iter,
    )
    if not ok or mesh_tail(y1, M, n) > resolution_tol:
        raise ConvergenceError(
            f"Could not converge the first periodic orbit next to the Hopf point at "
            f"{param}={hopf.param:.8g} (residual {res:.1e}); try a smaller first step (ds)."
        )
    return y_h, y1, t0, args


def periodic_orbits(
    system: System,
    param: str,
    orbit: np.ndarray,
    period: float,
    *,
    p: Array | None = None,
    n_mesh: int | None = None,
    max_mesh: int | None = None,
    adapt: bool = True,
    options: ContinuationOptions | None = None,
    progress: Callable[[int, float], None] | None = None,
    resolution_tol: float = 1e-9,
    stability: str = "integrated",
) -> Branch:
    """Continue periodic orbits from an approximate orbit.

    Parameters
    ----------
    system : System
    param : str
        Continuation parameter; its start value is ``p[param]``.
    orbit : array of shape (M0, n)
        Approximate orbit on an equispaced grid over one period (resampled to ``n_mesh``).
    period : float
        Approximate period.
    n_mesh, max_mesh, adapt, resolution_tol, stability
        The mesh and the multipliers (as in :func:`hopf_orbits`; ``n_mesh`` defaults to
        ``M0``).
    options : ContinuationOptions
        ``direction`` sets the initial direction of the parameter.

    Raises
    ------
    ConvergenceError
        If the initial orbit cannot be corrected at the start parameter.
    """
    options = options or ContinuationOptions(ds=1e-2, ds_max=0.25, ds_min=1e-9)
    _check_stability(stability)
    idx = system.index(param)
    p = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    orbit = np.asarray(orbit, dtype=float)
    if orbit.ndim != 2 or orbit.shape[1] != system.n_states:
        raise BifidInputError(f"orbit must have shape (M, {system.n_states}), got {orbit.shape}.")
    M = n_mesh or orbit.shape[0]
    policy = MeshPolicy.of(M, max_mesh, resolution_tol, adapt, system.n_states, options.rescale)
    V = resample_orbit(orbit, M) if orbit.shape[0] != M else orbit
    if (
        policy.rescale is not False
        and policy.adapt
        and np.ptp(V) > 0
        and spectral_tail(V) > resolution_tol
    ):
        # an orbit with fast phases: its points redistributed along its arclength
        M = equidistributing_mesh(orbit, orbit.shape[0], M)
        V = convert_values(orbit, orbit.shape[0], M)
    n = system.n_states
    lam0 = float(p[idx])
    y0 = np.concatenate([V.ravel(), [period, lam0]])
    stage = orbit_stage(system, p, idx, M)
    e = np.zeros_like(y0)
    e[-1] = 1.0
    y0, ok, _, res = correct(
        stage.problem, y0, e, lam0, stage.args(y0), tol=options.newton_tol, max_iter=30
    )
    if not ok:
        raise ConvergenceError(
            f"The starting orbit of {system.name!r} at {param}={lam0:.8g} did not converge "
            f"(residual {res:.1e})."
        )
    if mesh_tail(y0, M, n) > resolution_tol:
        raise ConvergenceError(
            f"The starting orbit of {system.name!r} at {param}={lam0:.8g} is not resolved on "
            f"{M} collocation points (spectral tail {mesh_tail(y0, M, n):.1e}); pass a larger "
            "n_mesh."
        )
    t0 = np.zeros_like(y0)
    t0[-1] = float(options.direction)
    ends = OrbitEnds(
        first_amplitude=_centred_amplitude(y0, M, n),
        first_period=float(y0[M * n]),
        n_states=n,
        from_hopf=False,
    )
    stage_of, run = _continue_orbits(system, p, idx, y0, t0, policy, options, ends, progress, M0=M)
    start = SpecialPoint(
        kind="start", param=lam0, index=0, bracket=(lam0, lam0), solution=y0, data={}
    )
    return orbit_branch(system, param, p, run, options, policy, start, stage_of, stability)


def _continue_orbits(system, p, idx, y0, t0, policy, options, ends, progress, M0=None):
    """Follow the orbits in parameter ``idx`` from the corrected orbit ``y0`` along ``t0``
    (:func:`~bifid.continuation._mesh.run_adaptive`, ended and monitored by the
    :class:`OrbitEnds` ``ends``); ``(stage_of, run)``."""
    stage_of = functools.partial(orbit_stage, system, p, idx)
    run = run_adaptive(
        stage_of,
        y0,
        t0,
        policy,
        options,
        system.n_states,
        M0=M0,
        stop=ends.stop,
        monitor=ends.monitor,
        progress=progress,
    )
    return stage_of, run


def _check_stability(stability: str) -> None:
    if stability not in STABILITY_SOURCES:
        raise BifidInputError(
            f"stability must be one of {', '.join(map(repr, STABILITY_SOURCES))}; "
            f"got {stability!r}."
        )


def _centred_amplitude(y: np.ndarray, M: int, n: int) -> float:
    V = np.asarray(y[: M * n]).reshape(M, n)
    return float(np.max(np.abs(V - V.mean(axis=0))))
