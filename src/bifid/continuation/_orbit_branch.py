"""A branch of periodic orbits from an adaptive run: Floquet multipliers, special points,
and why it ended.

Branch ends are events, recorded in ``Branch.status`` (``END_REASONS``):

* ``"hopf"`` — the orbits shrink into an equilibrium: the run stops when the centred
  amplitude falls below :data:`HOPF_END_FRACTION` of the branch's largest while still
  decreasing (or a step crosses zero amplitude), the Hopf point is located and verified
  from the last orbit's mean (``locate_hopf``), and it is the branch's last point (a
  zero-amplitude orbit, like the first point of a branch born at a Hopf point);
* ``"homoclinic"`` — the period grows without bound: it exceeds
  :data:`HOMOCLINIC_PERIOD_FACTOR` times the branch's smallest period, or it keeps
  growing while the parameter has settled (:func:`homoclinic_signature`), also when the
  branch cannot go on (mesh limit, step budget, corrector failure); the largest period
  is in the message and in ``meta["max_period"]``;
* ``"range"`` — a bound of the parameter range.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np

from bifid.continuation._branch import Branch, SpecialPoint
from bifid.continuation._density import (
    density_of,
    export_samples,
    integration_samples,
    time_mean,
)
from bifid.continuation._floquet import Floquet, autonomous_rhs, collocation_floquet, floquet
from bifid.continuation._mesh import (
    AdaptiveRun,
    MeshPolicy,
    Stage,
    on_common_mesh,
    run_residuals,
)
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._orbit_bifurcations import (
    BracketContext,
    collocation_operator,
    find_orbit_special_points,
)
from bifid.continuation._verify import LOCATION_ERRORS, Findings
from bifid.signal import max_abs
from bifid.systems import System

#: the run ends at a Hopf point when the centred amplitude falls below this fraction of
#: the branch's largest while decreasing
HOPF_END_FRACTION = 0.02
#: the run ends as a homoclinic approach when the period exceeds this multiple of the
#: branch's smallest period
HOMOCLINIC_PERIOD_FACTOR = 50.0
#: relative change of the parameter over the window below which it has settled
HOMOCLINIC_SETTLED = 1e-8
#: the periods examined by :func:`homoclinic_convergence`: the top part of the branch's
#: period range, from the largest period divided by this
HOMOCLINIC_SPAN = 1.2
#: the decay of ``|d lambda / dT|`` over that part, at least (a factor of e^2.3 = 10)
HOMOCLINIC_DECAY = math.log(10.0)
#: the parameter's remaining change, extrapolated, at most this (relative to its range or
#: its size, the larger) to end a running branch ...
HOMOCLINIC_REMAINING = 1e-8
#: ... and to name the reason of a branch that could not go on (its corrector failed, the
#: mesh limit or the step budget was reached)
HOMOCLINIC_REMAINING_AT_END = 1e-5
#: differences of the parameter below this (relative to max(1, |lambda|)) are rounding
HOMOCLINIC_NOISE = 1e-11
#: points examined for the signature of a homoclinic approach
_HOMOCLINIC_WINDOW = 6
#: a parameter that settles while it oscillates (a saddle-focus: Shilnikov's spiral of
#: folds) names a homoclinic approach only once the period exceeds this multiple of the
#: branch's smallest
HOMOCLINIC_SETTLED_FACTOR = 10.0
#: a step from an orbit larger than this fraction of the branch's largest to one smaller
#: than ``COLLAPSE_TO`` of it has fallen onto the equilibrium (a constant solves the
#: collocation equations): the step is rejected and retried shorter
COLLAPSE_FROM = 0.2
COLLAPSE_TO = 0.1


def _centred(V: np.ndarray, M: int | None = None) -> float:
    """``max |x - mean_t x|`` of mesh values (on the mesh ``M``, which may be rescaled)."""
    mean = V.mean(axis=0) if M is None else time_mean(V, M)
    return float(np.max(np.abs(V - mean)))


@dataclass
class OrbitEnds:
    """Stopping rules of an orbit branch (module docstring); ``stop`` is the hook of
    :func:`bifid.continuation._mesh.run_adaptive`."""

    first_amplitude: float
    first_period: float
    n_states: int
    from_hopf: bool = True
    amplitudes: list[float] = field(default_factory=list)
    periods: list[float] = field(default_factory=list)
    params: list[float] = field(default_factory=list)

    def stop(self, y, M, ys, meshes) -> str | None:
        n = self.n_states
        a = _centred(np.asarray(y[: M * n]).reshape(M, n), M)
        T = float(y[M * n])
        self.amplitudes.append(a)
        self.periods.append(T)
        self.params.append(float(y[M * n + 1]))
        peak = max([*self.amplitudes, self.first_amplitude])
        prev = self.amplitudes[-2] if len(self.amplitudes) > 1 else self.first_amplitude
        if peak > 10 * self.first_amplitude and a < HOPF_END_FRACTION * peak and a < prev:
            return "hopf"
        if T > HOMOCLINIC_PERIOD_FACTOR * min(
            [*self.periods, self.first_period]
        ) or homoclinic_signature(np.array(self.params), np.array(self.periods)):
            return "homoclinic"
        return None

    def monitor(self, y, y_new, M) -> float:
        """Step control of :func:`bifid.continuation._mesh.run_adaptive`: a step that takes a
        sizeable orbit onto (nearly) the equilibrium jumped to the trivial solution of the
        collocation equations, not along the branch; it is rejected (factor 0.25); any other
        step is accepted with no limit on the next one (``inf``)."""
        n = self.n_states
        a_prev = _centred(np.asarray(y[: M * n]).reshape(M, n), M)
        a_new = _centred(np.asarray(y_new[: M * n]).reshape(M, n), M)
        peak = max([*self.amplitudes, self.first_amplitude])
        if a_prev > COLLAPSE_FROM * peak and a_new < COLLAPSE_TO * a_prev:
            return 0.25
        return math.inf


def homoclinic_signature(
    params: np.ndarray, periods: np.ndarray, remaining: float = HOMOCLINIC_REMAINING
) -> bool:
    """The last points of a branch look like an approach to a homoclinic orbit: over
    the last :data:`_HOMOCLINIC_WINDOW` points the period grew monotonically by at least
    2 % to at least twice the branch's smallest, while the parameter settled to
    :data:`HOMOCLINIC_SETTLED` of its range (at a fold the parameter turns instead, and
    its change over steps that change the period by 2 % is far larger); or the parameter
    converges geometrically in the period (:func:`homoclinic_convergence`, with
    ``remaining``)."""
    params, periods = np.asarray(params, dtype=float), np.asarray(periods, dtype=float)
    if homoclinic_convergence(params, periods, remaining) or homoclinic_settled(
        params, periods, remaining
    ):
        return True
    k = _HOMOCLINIC_WINDOW
    if len(periods) < k + 1:
        return False
    T, lam = periods[-k:], params[-k:]
    if not np.all(np.diff(T) > 0) or T[-1] < 2.0 * np.min(periods) or T[-1] < 1.02 * T[0]:
        return False
    scale = max(float(np.ptp(params)), abs(float(lam[-1])), 1e-300)
    return bool(abs(lam[-1] - lam[0]) <= HOMOCLINIC_SETTLED * scale)


def _top_records(
    params: np.ndarray, periods: np.ndarray, factor: float
) -> tuple[np.ndarray, np.ndarray] | tuple[None, None]:
    """The points where the period reached a new maximum, over the periods from
    ``T_max / HOMOCLINIC_SPAN`` to ``T_max``: their periods and parameters, or ``None``
    with fewer than 6 of them or ``T_max`` below ``factor`` times the smallest period."""
    if len(periods) < 8:
        return None, None
    record = [0]
    for i in range(1, len(periods)):
        if periods[i] > periods[record[-1]]:
            record.append(i)
    T, lam = periods[record], params[record]
    keep = T >= T[-1] / HOMOCLINIC_SPAN
    if np.count_nonzero(keep) < 6 or T[-1] < factor * float(np.min(periods)):
        return None, None
    return T[keep], lam[keep]


def homoclinic_settled(
    params: np.ndarray, periods: np.ndarray, remaining: float = HOMOCLINIC_REMAINING
) -> bool:
    """The parameter has settled while the period grew far: on the points where the
    period reached a new maximum, over the periods from ``T_max / HOMOCLINIC_SPAN`` to
    ``T_max`` (at least 6 points, ``T_max`` at least ``HOMOCLINIC_SETTLED_FACTOR`` times
    the branch's smallest period), the parameter spreads by at most ``remaining`` times
    its range (or size). Towards a homoclinic orbit of a saddle-focus the parameter
    oscillates about its limit with a decaying amplitude (a spiral of cycle folds), which
    :func:`homoclinic_convergence` (a monotone parameter) does not take."""
    T, lam = _top_records(params, periods, HOMOCLINIC_SETTLED_FACTOR)
    if T is None:
        return False
    scale = max(float(np.ptp(params)), float(np.max(np.abs(lam))), 1e-300)
    return bool(np.ptp(lam) <= remaining * scale)


def homoclinic_convergence(
    params: np.ndarray, periods: np.ndarray, remaining: float = HOMOCLINIC_REMAINING
) -> bool:
    """The parameter converges geometrically as the period grows, as it does towards a
    homoclinic orbit of a saddle (``|lambda - lambda_h| ~ C e^{-T/tau}``, so
    ``|d lambda / dT| = |lambda - lambda_h| / tau``).

    On the points where the period reached a new maximum, over the periods from
    ``T_max / HOMOCLINIC_SPAN`` to ``T_max`` (at least 6 points, ``T_max`` at least twice
    the branch's smallest period): the parameter moves monotonically, ``log |d lambda /
    dT|`` falls linearly in ``T`` (least squares, every residual within a factor of 3,
    ``HOMOCLINIC_DECAY`` over the span), and the remaining change extrapolated to
    ``T = inf`` is below ``remaining`` times the parameter's range (or size). A fold (the
    parameter turns) or a branch that merely steepens (no geometric decay) fails it.
    Differences of the parameter at the level of rounding (``HOMOCLINIC_NOISE``) are left
    out.
    """
    T, lam = _top_records(params, periods, 2.0)
    if T is None:
        return False
    dlam, dT = np.diff(lam), np.diff(T)
    scale = max(float(np.ptp(params)), float(np.max(np.abs(lam))), 1e-300)
    real = np.abs(dlam) > HOMOCLINIC_NOISE * max(1.0, float(np.max(np.abs(lam))))
    if np.count_nonzero(real) < 5 or not (np.all(dlam[real] > 0) or np.all(dlam[real] < 0)):
        return False
    mid = 0.5 * (T[1:] + T[:-1])[real]
    logs = np.log(np.abs(dlam[real]) / dT[real])
    b, a = np.polyfit(mid, logs, 1)
    if not (b < 0 and -b * (mid[-1] - mid[0]) >= HOMOCLINIC_DECAY):
        return False
    if np.max(np.abs(logs - (a + b * mid))) > math.log(3.0):
        return False
    return bool(math.exp(a + b * T[-1]) / -b <= remaining * scale)


def orbit_branch(
    system: System,
    param: str,
    p,
    run: AdaptiveRun,
    options: ContinuationOptions,
    policy: MeshPolicy,
    start: SpecialPoint,
    stage_of: Callable[[int], Stage],
    stability: str = "integrated",
) -> Branch:
    """Assemble the :class:`Branch` of an adaptive orbit run (``start`` is the Hopf point
    the branch was born at, or a ``kind="start"`` placeholder; ``stage_of(M)`` the
    collocation problem on ``M`` points; ``stability`` where the Floquet multipliers come
    from, :data:`~bifid.continuation._orbit_bifurcations.STABILITY_SOURCES`)."""
    n = system.n_states
    idx = system.index(param)
    meta: dict = {}
    status, message = _branch_end(system, param, p, run, meta)
    meshes = np.asarray(run.meshes, dtype=int)
    fl = _branch_floquet(system, p, idx, run, n, stage_of, stability)
    ys, M, orbits, amps, centred_states = _exported_orbits(run, n, policy.tol, meta)
    periods = ys[:, M * n]
    params = ys[:, M * n + 1]
    centred = centred_states.max(axis=1) if len(orbits) else np.zeros(0)
    zero = centred <= 1e-12 * max(1.0, float(np.max(np.abs(orbits))))
    findings = Findings()
    ctx = BracketContext(
        system=system,
        param=param,
        p=p,
        idx=idx,
        run=run,
        stage_of=stage_of,
        floquet=fl,
        zero=zero,
        stability=stability,
    )
    find_orbit_special_points(findings, ctx, params)
    label = fl.stable()
    if start.kind == "hopf" and zero[0]:
        label[0] = float(start.data.get("criticality") == "supercritical")
    if zero[-1] and len(zero) > 1 and status == "hopf":
        label[-1] = label[-2] if np.isfinite(label[-2]) else np.nan
    stable = np.nan_to_num(label, nan=0.0).astype(bool) if np.all(np.isfinite(label)) else label
    residual = run_residuals(run, stage_of)
    meta.update(
        {
            "n_mesh": int(M),
            "states": list(system.states),
            "start_param": start.param,
            "start_kind": start.kind,
            "max_mesh": policy.max_mesh,
            "stability": stability,
            "resolution_tol": policy.tol,
            "work": dict(run.work),
        }
    )
    return Branch(
        kind="periodic",
        system=system.name,
        param=param,
        params=params,
        solutions=ys[:, : M * n + 1],
        stable=stable,
        special_points=findings.sorted_points(),
        data={
            "period": periods,
            "amplitude": amps,
            # about the orbit's mean, as a rig measures it (offsets removed)
            "amplitude_centred": centred_states,
            "floquet": fl.multipliers,
            "floquet_log": fl.log_moduli,
            "floquet_max": fl.floquet_max,
            "spectral_tail": np.asarray(run.tails),
            "n_mesh": meshes,
        },
        p=np.asarray(p),
        status=status,
        message=message,
        options=options,
        signals=tuple(system.states),
        meta=meta,
        verification={"residual": residual, "spectral_tail": np.asarray(run.tails)},
        candidates=findings.candidates,
    )


def _branch_end(system: System, param: str, p, run: AdaptiveRun, meta: dict) -> tuple[str, str]:
    """The branch's status and message from how its run ended: a Hopf end (an orbit
    shrinking into an equilibrium, the run cut there), a homoclinic approach (the period
    growing without bound; ``meta["max_period"]``), else the run's own."""
    n = system.n_states
    status, message = run.status, run.message
    # a step across zero amplitude shows up as a "fold" at a vanishing orbit: a Hopf end
    cut = _zero_amplitude_fold(run, n)
    if cut is not None:
        _truncate(run, cut + 1)
        run.stop_reason = "hopf"
    if run.stop_reason == "hopf":
        # the last step, into the Hopf point, may cross zero amplitude: not a fold
        last = len(run.ys) - 2
        run.events = [e for e in run.events if not (e[1] == "fold" and e[0] >= last)]
        status, message = _hopf_end(system, param, p, run, n, meta)
        if status == "failed":
            _truncate(run, len(run.ys) - 1)  # the last point is the equilibrium, no orbit
    else:
        params_ = np.array([y[m * n + 1] for y, m in zip(run.ys, run.meshes, strict=True)])
        periods_ = np.array([y[m * n] for y, m in zip(run.ys, run.meshes, strict=True)])
        if run.stop_reason == "homoclinic" or (
            status in ("unresolved", "steps", "failed")
            and homoclinic_signature(params_, periods_, HOMOCLINIC_REMAINING_AT_END)
        ):
            k = int(np.argmax(periods_))
            status = "homoclinic"
            message = (
                f"the period grows without bound (largest {periods_[k]:.8g} at "
                f"{param}={params_[k]:.10g}): a homoclinic orbit near "
                f"{param} ≈ {params_[-1]:.8g}"
            )
            meta["max_period"] = float(periods_[k])
    return status, message


def _exported_orbits(run: AdaptiveRun, n: int, tol: float, meta: dict):
    """``(ys, M, orbits, amplitudes, centred amplitudes)`` of a run: every orbit on one
    mesh of ``M`` uniform times (the run's common mesh, or, when some orbits were computed
    in a rescaled time, samples resolved to ``tol`` taken from each orbit's own mesh;
    ``meta["rescaled"]``)."""
    if any(density_of(m) is not None for m in run.meshes):
        # some orbits were computed in a rescaled time: every orbit leaves as samples at
        # uniform times, resolved, taken from its own mesh
        own = [
            np.asarray(y[: m * n]).reshape(m, n) for y, m in zip(run.ys, run.meshes, strict=True)
        ]
        # peaks are those of the mesh values' interpolant in any time; the mean is in time
        amps = np.array([max_abs(V) for V in own])
        # per state, about the orbit's mean (as a rig measures it)
        centred_states = np.array(
            [max_abs(V - time_mean(V, m)) for V, m in zip(own, run.meshes, strict=True)]
        )
        orbits = export_samples(own, run.meshes, tol)
        extras = np.array([y[m * n :] for y, m in zip(run.ys, run.meshes, strict=True)])
        ys = np.column_stack([orbits.reshape(len(orbits), -1), extras])
        M = orbits.shape[1]
        meta["rescaled"] = True
    else:
        ys, M = on_common_mesh(run.ys, run.meshes, n)
        orbits = ys[:, : M * n].reshape(-1, M, n)
        amps = np.array([max_abs(o) for o in orbits])
        centred_states = np.array([max_abs(o - o.mean(axis=0)) for o in orbits])
    return ys, M, orbits, amps, centred_states


def _branch_floquet(
    system, p, idx, run: AdaptiveRun, n: int, stage_of: Callable[[int], Stage], stability: str
) -> Floquet:
    """Multipliers of every orbit, each on its own mesh, in one batch (zero-amplitude
    orbits: NaN)."""
    N = len(run.ys)
    mults = np.full((N, n), np.nan, dtype=complex)
    logm = np.full((N, n), np.nan)
    trivial = np.zeros(N, int)
    ok = np.zeros(N, bool)
    V = [np.asarray(y[: m * n]).reshape(m, n) for y, m in zip(run.ys, run.meshes, strict=True)]
    rows = [i for i in range(N) if _centred(V[i]) > 0]
    if rows:
        if stability == "collocation":
            fl = collocation_floquet(
                [collocation_operator(stage_of(run.meshes[i]), run.ys[i]) for i in rows], n
            )
        else:
            ps = np.repeat(np.asarray(p)[None, :], len(rows), axis=0)
            ps[:, idx] = [run.ys[i][run.meshes[i] * n + 1] for i in rows]
            periods = np.array([run.ys[i][run.meshes[i] * n] for i in rows])
            # the variational equation is integrated in time from samples at uniform times
            fl = floquet(
                autonomous_rhs(system.field),
                [integration_samples(V[i], run.meshes[i]) for i in rows],
                periods,
                ps,
                autonomous=True,
            )
        mults[rows], logm[rows], trivial[rows], ok[rows] = (
            fl.multipliers,
            fl.log_moduli,
            fl.trivial,
            fl.ok,
        )
    return Floquet(mults, logm, trivial, ok)


def _zero_amplitude_fold(run: AdaptiveRun, n: int) -> int | None:
    """Index of a "fold" event whose located orbit has (nearly) vanished."""
    peak = max(
        _centred(np.asarray(y[: m * n]).reshape(m, n), m)
        for y, m in zip(run.ys, run.meshes, strict=True)
    )
    for i, kind, y_e, _, M in run.events:
        if kind == "fold" and y_e is not None:
            a = _centred(np.asarray(y_e[: M * n]).reshape(M, n), M)
            if a < 1e-3 * peak:
                return i
    return None


def _truncate(run: AdaptiveRun, k: int) -> None:
    for name in ("ys", "meshes", "tangents", "tails", "args"):
        setattr(run, name, getattr(run, name)[:k])
    run.events = [e for e in run.events if e[0] < k - 1]


def _hopf_end(system, param, p, run: AdaptiveRun, n: int, meta: dict) -> tuple[str, str]:
    """Locate the Hopf point the orbits shrink into and append it as the last point."""
    from bifid.continuation._hopf import locate_hopf

    M = run.meshes[-1]
    y = run.ys[-1]
    V = np.asarray(y[: M * n]).reshape(M, n)
    lam = float(y[M * n + 1])
    try:
        h = locate_hopf(
            system,
            param,
            time_mean(V, M),
            lam,
            jnp.asarray(p),
            omega_guess=2 * np.pi / float(y[M * n]),
        )
    except LOCATION_ERRORS as exc:
        return "hopf", (
            f"the orbits shrink into an equilibrium near {param}={lam:.8g} "
            f"(its Hopf point could not be located: {exc})"
        )
    lams = [float(yy[m * n + 1]) for yy, m in zip(run.ys[-3:], run.meshes[-3:], strict=True)]
    slack = 2.0 * max(np.ptp(lams), 1e-9 * max(1.0, abs(lam)))
    if abs(h.param - lam) > slack:
        # the orbits collapsed, but not into a Hopf point there: never report a point
        # that is not where the branch ends
        return "failed", (
            f"the orbits collapsed onto the equilibrium near {param}={lam:.8g}, "
            f"where it has no Hopf point (the nearest is at {h.param:.8g})"
        )
    x_h = np.asarray(h.solution, dtype=float)
    run.ys.append(np.concatenate([np.tile(x_h, M), [2 * np.pi / h.data["omega"], h.param]]))
    run.meshes.append(M)
    run.tangents.append(run.tangents[-1])
    run.tails.append(0.0)
    run.args.append(run.args[-1])
    meta["end_hopf"] = {
        "param": float(h.param),
        "omega": float(h.data["omega"]),
        "verification": dict(h.verification),
    }
    return "hopf", (
        f"the orbits shrink into the equilibrium at the Hopf point {param}={h.param:.10g}"
    )
