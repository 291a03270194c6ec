"""Mesh adaptation for Fourier collocation: the branch continues on the mesh its orbits need.

The unknowns of a collocation problem are ``y = [v (M*n mesh values), extras]``. The
resolution of an orbit is measured by its spectral tail (:func:`bifid.signal.spectral_tail`,
the top quarter of its Fourier spectrum relative to the peak). After every step of the
predictor–corrector driver:

* **refine** — a new point whose tail exceeds ``tol`` is not accepted: the last accepted
  point is interpolated onto the next mesh of the ladder (:func:`resample_orbit`, exact
  for the trigonometric interpolant), corrected there, and the step is retried on the
  finer mesh. The ladder is ``n_mesh * {1, 3/2, 2, 3, 4, 6, ...}`` (even sizes, up to
  ``max_mesh``): steps of 3/2 and 4/3 rather than doublings, so that a branch never uses
  more than 3/2 of the points it needs (the dense factorisation costs ``(M n)^3``);
* **coarsen** — when the accepted orbit, interpolated onto the next coarser mesh of the
  ladder, has a tail below ``tol * COARSEN_MARGIN``, the branch continues there (never
  below the starting mesh, and not within ``HOLD_STEPS`` steps of a refinement), so the
  cost follows the orbit's difficulty;
* **limit** — on the largest mesh (``max_mesh``, default :func:`default_max_mesh`: at most
  :data:`DEFAULT_MAX_UNKNOWNS` unknowns ``M * n``) an
  unresolved step is retried with smaller steps; when none is resolved the branch ends
  there with status ``"unresolved"`` and the reason.

* **rescale** — with ``MeshPolicy.rescale`` a mesh is a :class:`~bifid.continuation.
  _density.Mesh`: ``M`` points whose physical times follow a density chosen to
  equidistribute the orbit's arclength when the mesh is set (``_density``); an
  unresolved step first tries the same ``M`` redistributed along the last orbit, then
  the next rung with its own density; a coarser rung is tried with its density at most
  every ``HOLD_STEPS`` steps. ``rescale="auto"`` (the default of
  :class:`~bifid.continuation._options.ContinuationOptions`) keeps uniform meshes while
  the ladder stays within :data:`AUTO_RESCALE_UNKNOWNS` unknowns: an unresolved step
  whose next uniform rung would exceed it (or ``max_mesh``) redistributes the current
  points instead, and from then on every mesh of the run is rescaled. Smooth branches
  thus run exactly as on uniform meshes (the density search is never entered), and only
  orbits that would need a large uniform mesh pay for it. :func:`remesh` carries points
  between any two meshes at the same physical times, so arcs, common meshes and
  brackets work on rescaled runs unchanged.

No orbit whose tail exceeds ``tol`` is ever recorded. Every recorded point carries the
mesh it was computed on (``AdaptiveRun.meshes``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from bifid.continuation._blas import one_blas_thread
from bifid.continuation._density import convert_values, density_of, equidistributing_mesh
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._palc import (
    Continuation,
    ContinuationState,
    NewtonCorrector,
    ZeroProblem,
)
from bifid.continuation._verify import Check
from bifid.errors import BifidInputError
from bifid.signal import spectral_tail

#: default limit of an adaptive branch: the largest mesh ``M`` with ``M * n_states`` at
#: most this many unknowns (the dense collocation Jacobian is factorised at every Newton
#: iteration; 4096 unknowns take about a second)
DEFAULT_MAX_UNKNOWNS = 4096


def default_max_mesh(n_mesh: int, n_states: int) -> int:
    """The largest ``n_mesh * 2^k`` with at most :data:`DEFAULT_MAX_UNKNOWNS` unknowns
    (and never below ``n_mesh``)."""
    M = n_mesh
    while 2 * M * n_states <= DEFAULT_MAX_UNKNOWNS:
        M *= 2
    return M


def mesh_ladder(n_mesh: int, max_mesh: int) -> tuple[int, ...]:
    """The meshes a branch may use: ``n_mesh * 2^k`` and ``3/2 n_mesh * 2^k`` (rounded to
    even sizes) up to ``max_mesh``, and ``max_mesh`` itself (when even)."""
    rungs = {max_mesh} if max_mesh % 2 == 0 else set()
    M = n_mesh
    while M <= max_mesh:
        rungs.add(M)
        mid = 2 * round(0.75 * M)
        if mid <= max_mesh:
            rungs.add(mid)
        M *= 2
    return tuple(sorted(r for r in rungs if r >= n_mesh))


#: ``rescale="auto"``: the largest uniform mesh, in unknowns ``M * n_states``, before a
#: refinement goes to a rescaled mesh instead (where the corrector leaves dense
#: factorisations for Krylov solves and a uniform rung costs seconds per step)
AUTO_RESCALE_UNKNOWNS = 1024


def auto_rescale_from(n_mesh: int, max_mesh: int, n_states: int) -> int:
    """The largest rung of the ladder with at most :data:`AUTO_RESCALE_UNKNOWNS`
    unknowns (never below ``n_mesh``): the uniform meshes of ``rescale="auto"``."""
    fits = [r for r in mesh_ladder(n_mesh, max_mesh) if r * n_states <= AUTO_RESCALE_UNKNOWNS]
    return max(fits, default=n_mesh)


#: the mesh is coarsened when the orbit's tail on the next coarser mesh is below
#: tol * COARSEN_MARGIN
COARSEN_MARGIN = 1e-2
#: steps after a refinement during which the mesh is not coarsened again
HOLD_STEPS = 8
#: halvings of the step tried on the largest mesh before the branch ends unresolved
LIMIT_RETRIES = 4


def mesh_tail(y: np.ndarray, M: int, n: int) -> float:
    """Spectral tail of the mesh values of ``y`` (0 for a constant orbit)."""
    V = np.asarray(y[: M * n], dtype=float).reshape(M, n)
    return spectral_tail(V) if np.ptp(V) > 0 else 0.0


def remesh(y: np.ndarray, M: int, M_new: int, n: int) -> np.ndarray:
    """``y = [mesh values, extras]`` with the mesh values interpolated onto ``M_new`` (at
    the same physical times when either mesh is rescaled: ``_density.convert_values``)."""
    V = convert_values(np.asarray(y[: M * n]).reshape(M, n), M, M_new)
    return np.concatenate([V.ravel(), np.asarray(y[M * n :], dtype=float)])


@dataclass(frozen=True)
class MeshPolicy:
    """How the mesh follows the orbits.

    Parameters
    ----------
    n_mesh : int
        Starting mesh (even); the mesh is never coarsened below it.
    max_mesh : int
        Largest mesh; a branch that needs more ends with status ``"unresolved"``.
    tol : float
        Largest spectral tail of a recorded orbit.
    adapt : bool
        False keeps ``n_mesh`` throughout (an unresolved orbit then ends the branch).
    rescale : bool or "auto"
        Meshes in a rescaled time (``_density``): every new mesh gets the density that
        equidistributes the orbit's arclength, and an unresolved step first tries the same
        number of points redistributed (only with ``adapt``). "auto": uniform meshes up to
        ``rescale_from`` points, rescaled ones beyond (module docstring).
    rescale_from : int
        The largest uniform mesh of ``rescale="auto"`` (default: ``max_mesh``;
        :meth:`of` sets :func:`auto_rescale_from`).

    Attributes
    ----------
    ladder : tuple of int
        The meshes the branch may use (:func:`mesh_ladder`).
    """

    n_mesh: int
    max_mesh: int
    tol: float = 1e-9
    adapt: bool = True
    rescale: bool | Literal["auto"] = False
    rescale_from: int = 0
    ladder: tuple[int, ...] = field(init=False, repr=False, compare=False, default=())

    def __post_init__(self) -> None:
        if self.n_mesh < 8 or self.n_mesh % 2:
            raise BifidInputError(f"n_mesh must be an even integer >= 8, got {self.n_mesh!r}.")
        if not self.adapt:
            object.__setattr__(self, "max_mesh", self.n_mesh)
        if self.max_mesh < self.n_mesh:
            raise BifidInputError(
                f"max_mesh ({self.max_mesh}) must be at least n_mesh ({self.n_mesh})."
            )
        if not 0 < self.tol < 1:
            raise BifidInputError(f"the resolution tolerance must lie in (0, 1), got {self.tol}.")
        object.__setattr__(self, "ladder", mesh_ladder(self.n_mesh, self.max_mesh))
        if self.rescale_from <= 0:
            object.__setattr__(self, "rescale_from", self.max_mesh)

    @classmethod
    def of(
        cls,
        n_mesh: int,
        max_mesh: int | None,
        tol: float,
        adapt: bool,
        n_states: int,
        rescale: bool | Literal["auto"] = False,
    ) -> MeshPolicy:
        """The policy of a driver's arguments (``max_mesh`` default:
        :func:`default_max_mesh`; never below ``n_mesh``; ``rescale_from``:
        :func:`auto_rescale_from`)."""
        limit = max_mesh if max_mesh is not None else default_max_mesh(n_mesh, n_states)
        limit = max(limit, n_mesh)
        return cls(
            n_mesh=n_mesh,
            max_mesh=limit,
            tol=tol,
            adapt=adapt,
            rescale=rescale,
            rescale_from=auto_rescale_from(n_mesh, limit, n_states),
        )

    def rescaled(self, M: int, M_new: int) -> bool:
        """Whether the mesh of ``M_new`` points that follows ``M`` gets a density:
        always (``rescale=True``), never (False), or ("auto") when ``M`` has one or
        ``M_new`` exceeds ``rescale_from``."""
        if self.rescale == "auto":
            return density_of(M) is not None or int(M_new) > self.rescale_from
        return bool(self.rescale)

    def redistribute(self, M: int) -> bool:
        """Whether an unresolved step on ``M`` first tries the same number of points
        redistributed: with ``adapt``, when the next rung is rescaled or there is none."""
        if not self.adapt or self.rescale is False:
            return False
        finer = self.finer(M)
        return self.rescaled(M, finer if finer is not None else self.max_mesh + 1)

    def new_mesh(self, V: np.ndarray, M: int, M_new: int) -> int:
        """The mesh of ``M_new`` points for the orbit ``V`` on ``M``: uniform, or with the
        density that equidistributes its arclength (:meth:`rescaled`)."""
        return equidistributing_mesh(V, M, M_new) if self.rescaled(M, M_new) else M_new

    def finer(self, M: int) -> int | None:
        """The next mesh of the ladder above ``M`` (None at the limit)."""
        if not self.adapt:
            return None
        return next((r for r in self.ladder if r > M), None)

    def coarser(self, M: int) -> int | None:
        """The next mesh of the ladder below ``M`` (None at ``n_mesh``)."""
        if not self.adapt:
            return None
        below = [r for r in self.ladder if r < M]
        return below[-1] if below else None


@dataclass
class Stage:
    """What a collocation problem needs on one mesh ``M``."""

    problem: ZeroProblem
    weights: np.ndarray
    args: Callable[[np.ndarray, Any], Any]  # (y on this mesh, previous args or None) -> args
    update_args: Callable[[np.ndarray, Any], Any] | None = None


@dataclass
class AdaptiveRun:
    """Points of an adaptive run, each on its own mesh, and why it ended.

    ``events`` are ``(i, kind, y, precision, M)``: an event of the driver (``fold``,
    ``branch_point``) between points ``i`` and ``i + 1``, located on mesh ``M``.
    """

    ys: list[np.ndarray]
    meshes: list[int]
    tangents: list[np.ndarray]
    tails: list[float]
    events: list[tuple[int, str, np.ndarray | None, float, int]] = field(default_factory=list)
    status: str = "completed"
    message: str = ""
    stop_reason: str | None = None
    args: list[Any] = field(default_factory=list)
    work: dict[str, int] = field(default_factory=dict)


def run_adaptive(
    stage_of: Callable[[int], Stage],
    y0: np.ndarray,
    t0: np.ndarray,
    policy: MeshPolicy,
    options: ContinuationOptions,
    n_states: int,
    *,
    M0: int | None = None,
    stop: Callable[[np.ndarray, int, list[np.ndarray], list[int]], str | None] | None = None,
    monitor: Callable[[np.ndarray, np.ndarray, int], float] | None = None,
    progress: Callable[[int, float], None] | None = None,
) -> AdaptiveRun:
    """Follow a branch from the corrected point ``y0`` (on mesh ``M0``, default
    ``policy.n_mesh``) along ``t0``, adapting the mesh (module docstring).

    ``stop(y, M, ys, meshes)`` may end the branch after an accepted point by returning a
    reason (an end status such as ``"hopf"``); ``monitor(y, y_new, M)`` is the driver's
    step control (a factor < 1 rejects the step).
    """
    runner = _Runner(stage_of, policy, options, n_states, stop, monitor, progress)
    with one_blas_thread():
        out = runner.run(
            np.asarray(y0, dtype=float), np.asarray(t0, dtype=float), M0 or policy.n_mesh
        )
    for c in runner.correctors:
        for k, v in c.stats.items():
            out.work[k] = out.work.get(k, 0) + v
    return out


class _Runner:
    def __init__(self, stage_of, policy, options, n, stop, monitor, progress) -> None:
        self.stage_of, self.policy, self.options, self.n = stage_of, policy, options, n
        self.stop, self.monitor, self.progress = stop, monitor, progress
        self.M = 0
        self.driver: Continuation | None = None
        self.krylov = True
        self.correctors: list[NewtonCorrector] = []

    def _driver(self, M: int) -> Continuation:
        stage = self.stage_of(M)
        o = self.options
        corrector = NewtonCorrector(
            stage.problem, tol=o.newton_tol, max_iter=o.newton_max_iter, krylov=self.krylov
        )
        mon = None
        if self.monitor is not None:

            def mon(y, y_new, args, M=M):
                return self.monitor(y, y_new, M)

        self.stage = stage
        self.correctors.append(corrector)
        return Continuation(
            corrector,
            stage.problem.param_index,
            o,
            weights=stage.weights,
            update_args=stage.update_args,
            monitor=mon,
        )

    def _switch(self, state: ContinuationState, M_new: int) -> ContinuationState | None:
        """Continue from ``state`` on mesh ``M_new`` (interpolated and corrected)."""
        n = self.n
        y = remesh(state.y, self.M, M_new, n)
        t = remesh(state.t, self.M, M_new, n)
        driver = self._driver(M_new)
        w = self.stage.weights
        t = t / math.sqrt(float(t @ (w * t)))
        args = self.stage.args(y, None)
        r = driver.corrector.correct(y, w * t, float((w * t) @ y), args)
        if not r.converged or mesh_tail(r.y, M_new, n) > self.policy.tol:
            return None
        new = driver.start(r.y, t, args, correct_start=False)
        self.M, self.driver = M_new, driver
        return replace(new, ds=state.ds, n_points=state.n_points)

    def _new_mesh(self, state: ContinuationState, M_new: int) -> int:
        n = self.n
        V = np.asarray(state.y[: self.M * n]).reshape(self.M, n)
        return self.policy.new_mesh(V, self.M, M_new)

    def run(self, y0: np.ndarray, t0: np.ndarray, M0: int) -> AdaptiveRun:
        n, pol = self.n, self.policy
        self.M = M0
        self.driver = self._driver(M0)
        state = self.driver.start(y0, t0, self.stage.args(y0, None), correct_start=False)
        pi = self.stage.problem.param_index % y0.shape[0]
        out = AdaptiveRun(
            ys=[state.y],
            meshes=[M0],
            tangents=[state.t],
            tails=[mesh_tail(state.y, M0, n)],
            args=[state.args],
        )
        if self.progress is not None:
            self.progress(1, float(state.y[pi]))
        hold, retries, redistributed = 0, 0, False
        while state.running:
            step = self.driver.step(state)
            if step.point is None:
                state = step.state
                continue
            y_new = np.asarray(step.point.y)
            tail = mesh_tail(y_new, self.M, n)
            if tail > pol.tol:
                switched = None
                if pol.redistribute(self.M) and not redistributed:
                    # the same number of points, redistributed along the last orbit
                    redistributed = True
                    V = np.asarray(state.y[: self.M * n]).reshape(self.M, n)
                    mesh = equidistributing_mesh(V, self.M, int(self.M))
                    switched = self._switch(state, mesh)
                finer = pol.finer(self.M)
                if switched is None and finer:
                    switched = self._switch(state, self._new_mesh(state, finer))
                if switched is not None:
                    state, hold = switched, HOLD_STEPS
                    continue
                if retries < LIMIT_RETRIES and state.ds > 2 * self.options.ds_min:
                    retries += 1
                    state = replace(state, ds=state.ds / 4)
                    continue
                out.status = "unresolved"
                out.message = (
                    f"the orbit beyond {float(state.y[pi % state.y.shape[0]]):.8g} is not "
                    f"resolved on {self.M} collocation points (spectral tail {tail:.1e} > "
                    f"{pol.tol:.0e}); the mesh limit is {pol.max_mesh} (raise max_mesh)"
                )
                return out
            retries, redistributed = 0, False
            i = len(out.ys) - 1
            for kind, y_e, prec in step.events:
                out.events.append((i, kind, y_e, prec, self.M))
            state = step.state
            out.ys.append(y_new)
            out.meshes.append(self.M)
            out.tangents.append(np.asarray(step.tangent))
            out.tails.append(tail)
            out.args.append(state.args)
            pi = self.stage.problem.param_index % y_new.shape[0]
            if self.progress is not None:
                self.progress(len(out.ys), float(y_new[pi]))
            if state.running and self.stop is not None:
                reason = self.stop(y_new, self.M, out.ys, out.meshes)
                if reason is not None:
                    out.stop_reason = reason
                    state = replace(state, status="completed", message=reason)
                    break
            hold = max(hold - 1, 0)
            coarser = pol.coarser(self.M)
            if state.running and coarser and hold == 0:
                V = np.asarray(y_new[: self.M * n]).reshape(self.M, n)
                mesh = pol.new_mesh(V, self.M, coarser)
                half = convert_values(V, self.M, mesh)
                switched = None
                if np.ptp(half) == 0 or spectral_tail(half) < pol.tol * COARSEN_MARGIN:
                    switched = self._switch(state, mesh)
                    if switched is not None:
                        state = switched
                if switched is None and pol.rescaled(self.M, coarser):
                    hold = HOLD_STEPS  # a rescaled mesh is worked out: not at every step
        out.status, out.message = state.status, state.message
        return out


class Arc:
    """The solution curve between two points of a run, parametrised by the arclength
    ``s`` along their chord: ``point(s)`` is corrected onto the curve with ``W d . (y -
    y_a) = s`` (``d`` the unit chord). Interval searches (extrema, crossings) run on it.
    """

    def __init__(
        self, stage: Stage, y_a: np.ndarray, M_a: int, y_b: np.ndarray, M_b: int, n: int
    ) -> None:
        self.M = max(M_a, M_b)
        self.n = n
        self.stage = stage
        self.y_a = remesh(y_a, M_a, self.M, n)
        d = remesh(y_b, M_b, self.M, n) - self.y_a
        w = stage.weights
        self.length = math.sqrt(float(d @ (w * d)))
        self.d = d / self.length if self.length > 0 else d
        self.row = w * self.d
        self.c0 = float(self.row @ self.y_a)
        self.args = stage.args(self.y_a, None)
        self.corrector = NewtonCorrector(stage.problem)

    def point(self, s: float) -> np.ndarray | None:
        """The corrected point at arclength ``s`` (None when Newton fails)."""
        r = self.corrector.correct(self.y_a + s * self.d, self.row, self.c0 + s, self.args)
        return np.asarray(r.y) if r.converged else None


def residual_check(context: Any) -> Check:
    """The verification check "on the curve": ``max|G(y)| <= 1e-8 (1 + max|y|)`` for
    ``context["problem"]``, ``["args"]`` and ``["y"]``."""
    y = np.asarray(context["y"], dtype=float)
    G = NewtonCorrector(context["problem"]).residual(y, context["args"])
    return Check.at_most(
        "residual", float(np.max(np.abs(G))), 1e-8 * (1.0 + float(np.max(np.abs(y))))
    )


def secant_zero(
    f: Callable[[float], tuple[float, Any]],
    a: float,
    b: float,
    *,
    iters: int = 40,
    xtol: float = 1e-14,
) -> tuple[Any, float] | None:
    """Zero of ``f(s) -> (value, payload)`` in ``[a, b]`` by the Illinois secant method;
    the payload at the best point and the final bracket width (None without a sign
    change or when ``f`` fails)."""
    fa, pa = f(a)
    fb, pb = f(b)
    if not (math.isfinite(fa) and math.isfinite(fb)) or fa * fb > 0:
        return None
    best = (pa, abs(fa)) if abs(fa) < abs(fb) else (pb, abs(fb))
    same = 0
    for _ in range(iters):
        s = (a * fb - b * fa) / (fb - fa) if fb != fa else 0.5 * (a + b)
        fs, ps = f(s)
        if not math.isfinite(fs):
            return None
        if abs(fs) < best[1]:
            best = (ps, abs(fs))
        if fs * fb < 0:
            a, fa, same = b, fb, 0
        else:
            same += 1
            if same > 1:
                fa = fa / 2.0  # Illinois: keep the bracket shrinking on both sides
        b, fb = s, fs
        if fs == 0.0 or abs(b - a) < xtol * max(1.0, abs(a), abs(b)):
            break
    return best[0], abs(b - a)


def run_residuals(run: AdaptiveRun, stage_of: Callable[[int], Stage]) -> np.ndarray:
    """``max|G(y)|`` of every point of a run, each on its own mesh (the ``residual`` of a
    branch's ``verification``)."""
    return np.array(
        [
            float(np.max(np.abs(NewtonCorrector(stage_of(m).problem).residual(y, a))))
            for y, m, a in zip(run.ys, run.meshes, run.args, strict=True)
        ]
    )


def bracket_slack(y_a: np.ndarray, M_a: int, y_b: np.ndarray, M_b: int, n: int) -> float:
    """Largest change of any unknown between two points of a run (on the finer of their
    meshes): the ``slack`` of a fold located between them (``_verify.confirm``)."""
    M = max(M_a, M_b)
    return float(np.max(np.abs(remesh(y_b, M_b, M, n) - remesh(y_a, M_a, M, n))))


def on_common_mesh(ys: list[np.ndarray], meshes: list[int], n: int) -> tuple[np.ndarray, int]:
    """All points interpolated onto the largest mesh of the run (exact for the
    interpolants): ``(n_points, M_max * n + extras)`` and ``M_max``."""
    M = max(meshes)
    return np.array([remesh(y, m, M, n) for y, m in zip(ys, meshes, strict=True)]), M
