"""Backbone curves: the locus of phase quadrature of one mode (thesis §6.2.3.4).

The backbone of mode ``k`` is followed as the forced responses whose observed
coordinate lags the force by π/2 (``a_1(v_obs) = 0``), with ``Omega`` and ``F`` both
free. The force is **appropriated to the mode** (phase-resonance testing): it acts on the
same states as the system's forcing, with the pattern of the linear mode's shape there
(for one forced coordinate this is the system's own forcing), so a mode the system's
forcing cannot excite — the antisymmetric mode of ``shaw_pierre`` under its symmetric
force — is followed as well.

The run starts at the linear resonance ``omega_k`` at the lower amplitude of the range
and stops exactly at its upper amplitude (both located by a secant search), so every
point lies in the requested range. Each point is checked to follow the requested mode:
the share of mode ``k`` in the first harmonic of the response, in the linear modal
coordinates, must stay above :data:`MODE_SHARE_MIN`; where it does not, the branch ends
there (status ``"failed"``, the reason in the message).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from bifid.continuation._branch import Branch
from bifid.continuation._forced import check_range, forced_branch, forced_stage
from bifid.continuation._fourier import fourier_grid
from bifid.continuation._mesh import Arc, MeshPolicy, mesh_tail, run_adaptive, secant_zero
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._palc import correct
from bifid.errors import BifidInputError, ConvergenceError
from bifid.signal import max_abs
from bifid.systems import System

Array = jnp.ndarray

#: smallest share of the requested mode in the first harmonic of a backbone point
MODE_SHARE_MIN = 0.5


def linear_modes(system: System, p: Array) -> tuple[np.ndarray, np.ndarray]:
    """Oscillatory linear modes about ``x = 0``: frequencies ``omega_k`` (ascending) and
    eigenvectors ``q_k`` (columns, ``J q_k = (sigma_k + i omega_k) q_k``)."""
    J = np.asarray(jax.jacfwd(system.field)(jnp.zeros(system.n_states), p))
    ev, Q = np.linalg.eig(J)
    keep = ev.imag > 1e-12
    order = np.argsort(ev.imag[keep])
    return ev.imag[keep][order], Q[:, keep][:, order]


def appropriated_forcing(system: System, p: Array, q: np.ndarray) -> np.ndarray:
    """The force pattern of mode ``q`` on the states the system's forcing acts on
    (made real by the best phase, scaled like the system's forcing direction)."""
    b_sys = np.asarray(system.forcing_direction(p), dtype=float)
    on = np.abs(b_sys) > 0
    qs = np.where(on, q, 0.0)
    qs = qs * np.exp(-0.5j * np.angle(np.sum(qs**2)))  # the most nearly real phase
    b = np.real(qs)
    if not np.any(np.abs(b) > 1e-12 * np.max(np.abs(qs))):
        b = np.imag(qs)
    b = b / np.linalg.norm(b) * np.linalg.norm(b_sys)
    lead = b[np.flatnonzero(np.abs(b) > 1e-12)[0]]
    return b * np.sign(b @ b_sys if abs(b @ b_sys) > 1e-12 * np.linalg.norm(b_sys) else lead)


def mode_share(orbits: np.ndarray, J: np.ndarray, omega: float) -> np.ndarray:
    """Share of the linear mode of frequency ``omega`` (with its conjugate) in the first
    harmonic of each orbit, in the modal coordinates of ``J`` (``(n_orbits,)``)."""
    V = np.asarray(orbits, dtype=float)
    X1 = np.fft.fft(V, axis=1)[:, 1, :]  # complex first harmonic, (n_orbits, n)
    ev, Q = np.linalg.eig(J)
    power = np.abs(np.linalg.solve(Q, X1.T).T) ** 2
    mine = np.abs(np.abs(ev.imag) - omega) <= 1e-8 * max(1.0, omega)
    total = np.sum(power, axis=1)
    return np.sum(power[:, mine], axis=1) / np.where(total > 0, total, 1.0)


def backbone(
    system: System,
    amplitude_range: tuple[float, float],
    *,
    p: Array | None = None,
    n_mesh: int = 64,
    max_mesh: int | None = None,
    adapt: bool = True,
    mode: int = 0,
    options: ContinuationOptions | None = None,
    observed: str | None = None,
    progress: Callable[[int, float], None] | None = None,
    resolution_tol: float = 1e-9,
) -> Branch:
    """Backbone curve of mode ``mode`` (0 = lowest frequency) over an amplitude range of
    the observed coordinate (module docstring).

    Returns
    -------
    Branch
        ``kind="backbone"``, ``param="F"``; data ``omega``, ``forcing``,
        ``observed_amplitude``, ``mode_share``; ``meta`` ``mode``, ``linear_frequency``,
        ``forcing_direction``.
    """
    if system.kind != "forced":
        raise BifidInputError(
            f"{system.name!r} is autonomous: forced responses need a forced system "
            "(parameters F and Omega)."
        )
    a_lo, a_hi = check_range("amplitude range", *amplitude_range)
    a_lo, a_hi = min(a_lo, a_hi), max(a_lo, a_hi)
    if a_lo <= 0:
        raise BifidInputError(f"the amplitude range must be positive, got {amplitude_range}.")
    p = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    n = system.n_states
    obs_name = observed or system.observed
    obs = system.state_index(obs_name)
    freqs, Q = linear_modes(system, p)
    if not 0 <= mode < len(freqs):
        raise BifidInputError(f"{system.name!r} has {len(freqs)} oscillatory modes; mode={mode}.")
    Om0 = float(freqs[mode])
    b = appropriated_forcing(system, p, Q[:, mode])
    forcing = tuple(float(v) for v in b)
    J = np.asarray(jax.jacfwd(system.field)(jnp.zeros(n), p))
    X = np.linalg.solve(1j * Om0 * np.eye(n) - J, b)
    if abs(X[obs]) == 0:
        raise BifidInputError(f"mode {mode} of {system.name!r} does not move {obs_name!r}.")
    iF, iOm = system.index("F"), system.index("Omega")
    args = {"p": p, "idx": jnp.asarray([iF, iOm]), "obs": jnp.asarray(obs)}
    policy = MeshPolicy.of(n_mesh, max_mesh, resolution_tol, adapt, n)
    options = options or ContinuationOptions(
        ds=a_lo,
        ds_min=a_lo * 1e-8,
        ds_max=(a_hi - a_lo) / 20,
        max_steps=2000,
        detect_folds=False,
    )

    def stage_of(M):
        return forced_stage(system, M, 2, args, 1.0, forcing)

    def amplitude(y, M):
        return float(max_abs(np.asarray(y[: M * n]).reshape(M, n)[:, obs]))

    M = n_mesh
    F0 = a_lo / abs(X[obs])
    V0 = np.real(np.outer(np.exp(1j * fourier_grid(M)), X * F0))
    y0 = np.concatenate([V0.ravel(), [F0, Om0]])
    e = np.zeros_like(y0)
    e[M * n] = 1.0
    for _ in range(8):  # start exactly at the lower amplitude (amplitude ~ F there)
        y0, ok, _, res = correct(
            stage_of(M).problem, y0, e, F0, args, tol=options.newton_tol, max_iter=30
        )
        if not ok:
            raise ConvergenceError(
                f"Could not start the backbone of {system.name!r} at amplitude {a_lo:g} "
                f"(residual {res:.1e}); try a smaller start amplitude."
            )
        ratio = a_lo / amplitude(y0, M)
        if abs(ratio - 1.0) < 1e-12:
            break
        F0 = F0 * ratio
        y0 = y0.copy()
        y0[: M * n] *= ratio
    if mesh_tail(y0, M, n) > resolution_tol:
        raise ConvergenceError(
            f"The backbone start of {system.name!r} is not resolved on {M} "
            "points; pass a larger n_mesh."
        )
    t0 = np.zeros_like(y0)
    t0[M * n] = 1.0

    def stop(y, M_, ys, meshes):
        return "completed" if amplitude(y, M_) > a_hi else None

    run = run_adaptive(stage_of, y0, t0, policy, options, n, stop=stop, progress=progress)
    if run.stop_reason is not None:
        _end_at(run, a_hi, stage_of, amplitude, n)
        run.status, run.message = "range", f"reached the amplitude bound {a_hi:g}"
    br = forced_branch(
        system, "backbone", "F", run, p, [iF, iOm], options, policy, obs_name, stage_of, forcing
    )
    share = mode_share(br.solutions.reshape(len(br), -1, n), J, Om0)
    br.data["mode_share"] = share
    br.verification["mode_share"] = share
    bad = np.flatnonzero(share < MODE_SHARE_MIN)
    if bad.size:
        _cut(br, int(bad[0]))
        br.status = "failed"
        br.message = (
            f"the backbone left mode {mode} at amplitude "
            f"{br.data['observed_amplitude'][-1]:.6g}: beyond it the share of mode "
            f"{mode} in the response fell below {MODE_SHARE_MIN:g}"
        )
    br.meta.update(mode=mode, linear_frequency=Om0, forcing_direction=list(forcing))
    return br


def _end_at(run, target: float, stage_of, amplitude, n: int) -> None:
    """Replace the last point (beyond ``target``) by the point where the amplitude is
    exactly ``target`` on the arc from the point before."""
    i = len(run.ys) - 2
    M = max(run.meshes[i], run.meshes[i + 1])
    arc = Arc(stage_of(M), run.ys[i], run.meshes[i], run.ys[i + 1], run.meshes[i + 1], n)

    def f(s):
        y = arc.point(s)
        return (math.nan, None) if y is None else (amplitude(y, M) - target, y)

    found = secant_zero(f, 0.0, arc.length, xtol=1e-15)
    if found is None:
        del run.ys[-1], run.meshes[-1], run.tangents[-1], run.tails[-1], run.args[-1]
        return
    run.ys[-1], run.meshes[-1], run.tails[-1] = found[0], M, mesh_tail(found[0], M, n)


def _cut(br: Branch, k: int) -> None:
    """Keep the first ``k`` points of a branch."""
    N = len(br)
    br.params = br.params[:k]
    br.solutions = br.solutions[:k]
    br.stable = br.stable[:k]
    br.data = {key: v[:k] if np.ndim(v) and len(v) == N else v for key, v in br.data.items()}
    br.verification = {key: v[:k] for key, v in br.verification.items()}
    br.special_points = [sp for sp in br.special_points if sp.index < k - 1]
