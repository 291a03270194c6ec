"""The tasks of the campaign runner (:mod:`bifid.cbc._campaign`), one function per protocol.

Each task function advances the campaign's cursor and checkpoints after every unit of
work (a recorded continuation point, a scanned value), so that it can be re-entered from
any checkpoint: a continuation branch is rebuilt from its saved state (driver, Broyden
Jacobian, problem, gains) instead of being started again.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from bifid.cbc._campaign import Campaign, _Branch
from bifid.cbc._campaign_result import retry_grid, unanswered
from bifid.cbc._forced import ForcedProblem, open_loop
from bifid.cbc._forced_measure import ForcedCBCOptions
from bifid.cbc._measured import BroydenCorrector
from bifid.cbc._ppcbc import PPCBCOptions, PPCBCProblem, make_point
from bifid.cbc._ppcbc_family import TargetFamily, bootstrap
from bifid.cbc._ppcbc_scan import ScanResult, scan
from bifid.cbc._retry import (
    all_measured,
    keeper,
    model_lcos,
    model_orbits,
    other_controllers,
    raised,
    refused,
    with_gains,
)
from bifid.continuation import Continuation, ContinuationOptions, ContinuationState
from bifid.errors import ConvergenceError

__all__ = ["run_tasks"]


def run_tasks(camp: Campaign) -> None:
    """Run the campaign's remaining tasks."""
    if camp.spec.protocol != "ppcbc":
        _forced(camp)
    elif camp.spec.continuation:
        _ppcbc_continuation(camp)
    else:
        _scan_values(camp)


# ------------------------------------------------------------------------------ helpers
def _driver_options(camp: Campaign, newton_max: int, ds_max: float) -> ContinuationOptions:
    spec = camp.spec
    lo, hi = sorted(float(v) for v in spec.range)
    return ContinuationOptions(
        ds=spec.ds,
        ds_min=spec.ds / 16.0,
        ds_max=max(ds_max, spec.ds),
        max_steps=10**6,
        p_min=lo,
        p_max=hi,
        newton_max_iter=newton_max,
        growth=1.3,
        detect_folds=False,
        detect_bifurcations=False,
    )


def _direction(camp: Campaign) -> float:
    a, b = (float(v) for v in camp.spec.range)
    return 1.0 if b > a else -1.0


def _save(br: _Branch, extra: dict[str, Any]) -> dict[str, Any]:
    st = br.state
    return {
        "driver": {
            "y": st.y,
            "t": st.t,
            "ds": st.ds,
            "sign": st.sign,
            "n_points": st.n_points,
            "y_prev": st.y_prev,
            "status": st.status,
            "message": st.message,
        },
        "corrector": br.corrector.state(),
        "problem": br.problem.state(),
        "retries": br.retries,
        **extra,
    }


def _driver_state(saved: dict[str, Any]) -> ContinuationState:
    d = saved["driver"]
    return ContinuationState(
        y=np.asarray(d["y"], float),
        t=np.asarray(d["t"], float),
        ds=float(d["ds"]),
        sign=float(d["sign"]),
        n_points=int(d["n_points"]),
        y_prev=None if d["y_prev"] is None else np.asarray(d["y_prev"], float),
        status=str(d["status"]),
        message=str(d["message"]),
    )


def _start_branch(
    corrector: BroydenCorrector, driver: Continuation, y0: np.ndarray, direction: float
):
    """Correct ``y0`` at fixed parameter, a finite-difference Jacobian there, and the
    tangent from it; ``(state, correction)`` (state None when it failed)."""
    pi = driver.param_index
    e_p = np.zeros(y0.shape[0])
    e_p[pi] = 1.0
    r = corrector.correct(y0, e_p, float(y0[pi]), None)
    if not r.converged:
        return None, r
    corrector.accept(r)
    corrector.bootstrap(r.info["evaluation"])
    state = driver.start(r.y, direction * e_p, None, correct_start=False)
    return state, r


# -------------------------------------------------------------------------- PP-CBC scans
def _ppcbc_options(camp: Campaign) -> PPCBCOptions:
    return with_gains(PPCBCOptions(**dict(camp.spec.options)), camp.cursor.get("gains"))


def _scan_once(
    camp: Campaign,
    value: float,
    opts: PPCBCOptions,
    branch: int,
    known: list[tuple[float, float]],
    amplitudes: tuple[float, ...] | None = None,
    a_max: float = math.inf,
):
    """One scan at ``value`` (on the campaign's amplitude grid, or ``amplitudes``; no
    target at or above ``a_max``); points already recorded there (``known``) are not
    again."""
    spec = camp.spec
    camp.seed_rig()
    return scan(
        camp.rig,
        spec.param,
        value,
        spec.amplitudes if amplitudes is None else amplitudes,
        opts,
        omega_guess=float(camp.cursor["omega"]),
        on_point=keeper(camp, opts, branch, known),
        on_evaluation=camp.on_evaluation,
        a_max=a_max,
    )


#: a scan stops below this fraction of the ``A*`` of an LCO outside the envelope
REFUSED_MARGIN = 0.8


def _may_leave_envelope(camp: Campaign, opts: PPCBCOptions) -> bool:
    """Whether the scan's targets reach half the rig's envelope of ``x1`` (then the
    model's LCOs are checked against the envelope before the scan, else only when it
    fails: they cost a continuation of the model's cycles)."""
    env = (camp.spec.rig or {}).get("envelope") or {}
    lo, hi = env.get("states", {}).get(opts.x1, (-math.inf, math.inf))
    return max(camp.spec.amplitudes) >= 0.5 * min(-float(lo), float(hi))


def _below_refused(
    grid: tuple[float, ...], lcos: list[dict[str, Any]]
) -> tuple[tuple[float, ...] | None, float]:
    """The amplitude grid without the targets at and above :data:`REFUSED_MARGIN` times
    the smallest LCO of the model outside the envelope (the controlled transients to a
    target overshoot it), and that bound (the grid as it is and no bound
    when none is, or an LCO inside lies above it; no grid when fewer than two targets
    are left)."""
    out = [c["a_star"] for c in lcos if c["outside"] is not None]
    if not out or any(c["a_star"] > min(out) for c in lcos if c["outside"] is None):
        return grid, math.inf
    a_max = REFUSED_MARGIN * min(out)
    cut = tuple(a for a in grid if a < a_max)
    return (cut if len(cut) >= 2 else None), a_max


def _scan_value(camp: Campaign, value: float, branch: int):
    """Scan at ``value``; a scan with failures is repeated with other controllers
    (:func:`~bifid.cbc._retry.other_controllers`) while failures remain, from where it
    failed upwards (:func:`retry_grid`); the following values keep a controller that did
    better. With a model, its LCOs outside the rig's safety envelope are refused up
    front (:func:`~bifid.cbc._retry.refused`: the grid stops below them), the LCOs of
    the model the scans missed (with or without a failure) are held from its orbits, and
    the failures left are one per LCO of the model unmeasured
    (:func:`~bifid.cbc._retry.model_orbits`); without one, a failure that another scan
    answered (it measured the LCO there, :func:`unanswered`) is dropped."""
    opts = _ppcbc_options(camp)
    known: list[tuple[float, float]] = []
    lcos = model_lcos(camp, opts, value) if _may_leave_envelope(camp, opts) else None
    grid, a_max = _below_refused(camp.spec.amplitudes, lcos or [])
    res = (
        ScanResult() if grid is None else _scan_once(camp, value, opts, branch, known, grid, a_max)
    )
    if res.failures and lcos is None:  # (the model's LCOs asked for when needed)
        lcos = model_lcos(camp, opts, value)
    first = len(res.failures)
    retry = bool(res.failures) and not all_measured(res, lcos, opts.x1)
    for other in other_controllers(camp, opts, value) if retry else ():
        new = with_gains(opts, other)
        again = _scan_once(camp, value, new, branch, known, retry_grid(grid, res.failures), a_max)
        retry = f"after a retry with kp = {new.kp:.4g}, kd = {new.kd:.4g} on ({new.x1}, {new.x2})"
        failures = unanswered(res, again, opts.x1) + [
            replace(f, reason=f"{f.reason} ({retry})") for f in unanswered(again, res, new.x1)
        ]
        if len(again.failures) < first:
            first = len(again.failures)
            camp.cursor["gains"] = {**(_saved_controller(camp)), **other}
            camp.warnings.append(
                f"PP-CBC at {camp.spec.param}={value:g}: controller changed to kp = "
                f"{new.kp:g}, kd = {new.kd:g} on ({new.x1}, {new.x2}) (the scan failed "
                "with the other)"
            )
        again.points = res.points + again.points
        again.found = res.found + again.found
        again.warnings = res.warnings + again.warnings
        again.failures = failures
        res = again
        if not res.failures:
            break
    if res.failures or (lcos and (grid is None or not all_measured(res, lcos, opts.x1))):
        # (a scan can also pass an LCO by without a failure, e.g. near a cycle fold)
        model_orbits(camp, opts, value, branch, known, res, lcos or [])
    out = refused(camp, value, lcos or [])
    camp.failures += out + res.failures
    camp.warnings += res.warnings
    if res.points:
        camp.cursor["omega"] = float(res.points[-1].frequency)
    elif not res.failures and not out:
        camp.fail(
            {"param": value},
            "no zero of the control error on the amplitude grid "
            "(no LCO in the range of target amplitudes?)",
        )
    return res


def _saved_controller(camp: Campaign) -> dict[str, Any]:
    g = camp.cursor.get("gains")
    if isinstance(g, dict):
        return dict(g)
    return {} if g is None else {"kp": float(g[0]), "kd": float(g[1])}


def _scan_values(camp: Campaign) -> None:
    if not camp.branches:
        camp.new_branch("scan")
    values = camp.spec.values
    while int(camp.cursor["task"]) < len(values):
        _scan_value(camp, float(values[int(camp.cursor["task"])]), 0)
        camp.cursor["task"] = int(camp.cursor["task"]) + 1
        camp.checkpoint()
    if camp.failures:
        camp.end_branch(0, "failed", camp.failures[0].reason)


# --------------------------------------------------------------------- PP-CBC branches
def _ppcbc_continuation(camp: Campaign) -> None:
    spec = camp.spec
    if int(camp.cursor["task"]) == 0:
        camp.new_branch("scan")
        res = _scan_value(camp, float(spec.range[0]), 0)
        x1 = _ppcbc_options(camp).x1
        starts: list[dict[str, Any]] = []
        # (LCOs held from the model's orbits, last, have no scan to continue from)
        for (fam, ev, cor), pt in zip(res.found, res.points, strict=False):
            a = float(pt.amplitude[x1])
            if all(abs(s["amp"] - a) > 0.02 * a for s in starts):
                starts.append(
                    {
                        "y": ev.y,
                        "frame": fam.frame(),
                        "jacobian": cor.jacobian,
                        "omega": cor.problem.omega,
                        "amp": a,
                    }
                )
        # an LCO only held from the model's orbit (the scan did not converge to it) has
        # no scan to continue from: a failure unless another branch reaches it
        camp.cursor["held"] = [
            {"y": [float(pt.param)], "amp": float(pt.amplitude[x1])}
            for pt in res.points[len(res.found) :]
            if all(abs(s["amp"] - pt.amplitude[x1]) > 0.02 * pt.amplitude[x1] for s in starts)
        ]
        camp.cursor["starts"] = starts
        camp.cursor["task"] = 1
        camp.checkpoint()
    starts = camp.cursor["starts"]
    while int(camp.cursor["task"]) <= len(starts):
        k = int(camp.cursor["task"]) - 1
        saved = camp.cursor.get("branch")
        if saved is None and (_covered(camp, starts[k]) or camp.budget_left() <= 0):
            camp.cursor["task"] = k + 2
            camp.checkpoint()
            continue
        _ppcbc_branch(camp, starts[k], saved)
        camp.cursor["task"] = k + 2
        camp.cursor["branch"] = None
        camp.checkpoint()
    for h in camp.cursor.pop("held", None) or []:
        if not _covered(camp, h):
            camp.fail(
                {spec.param: float(h["y"][-1])},
                f"the LCO of amplitude {h['amp']:.4g} was held from the model's orbit, not "
                "found by the scan, and no branch reached it (no scan to continue from)",
            )


def _covered(camp: Campaign, start: dict[str, Any]) -> bool:
    """Whether an LCO of the start scan lies on a branch followed already."""
    lam, amp = float(start["y"][-1]), float(start["amp"])
    key = f"amp_{_ppcbc_options(camp).x1}"
    return any(
        b > 0
        and abs(rec.param - lam) <= 1e-9 * max(1.0, abs(lam))
        and abs(rec.extra.get(key, math.nan) - amp) <= 0.02 * amp
        for rec, b in zip(camp.records, camp.rec_branch, strict=True)
    )


def _ppcbc_branch(camp: Campaign, start: dict[str, Any], saved: dict[str, Any] | None) -> None:
    spec = camp.spec
    opts = _ppcbc_options(camp)
    state = (
        saved["problem"]
        if saved is not None
        else {
            "omega": start["omega"],
            "frame": start["frame"],
            "vec_ref": start["y"][:-1],
            "param_scale": spec.param_scale,
        }
    )
    family = TargetFamily.from_frame(opts, state["frame"])
    problem = PPCBCProblem(
        camp.rig,
        opts,
        family,
        spec.param,
        float(state["omega"]),
        np.asarray(state["vec_ref"], float),
        float(state["param_scale"]),
    )
    if state.get("vec_now") is not None:
        problem.rescale(np.asarray(state["vec_now"], float))

    corrector = BroydenCorrector(
        problem,
        max_iter=opts.newton_max,
        trust=0.5,
        min_radius=0.1,
        on_evaluation=camp.on_evaluation,
    )
    driver = Continuation(
        corrector,
        problem.param_index,
        _driver_options(camp, opts.newton_max, spec.ds),
        weights=problem.weights,
        predictor="secant",
    )

    def point(ev, evaluations: int):
        pt = make_point(camp.rig, problem.opts, problem.family, ev, evaluations, "continuation")
        if pt.stable is False:
            _relock(camp, problem, float(ev.y[0]), float(pt.amplitude[problem.opts.x1]))
        return pt

    if saved is not None:
        b = int(saved["branch"])
        corrector.restore(saved["corrector"])
        br = _Branch(problem, corrector, driver, _driver_state(saved), point, int(saved["retries"]))
        if not camp.rig_restored:  # a rig that cannot restore its state starts from rest
            a0 = float(br.state.y[0])
            bootstrap(camp.rig, opts, 0.8 * a0, problem.omega, a_max=a0)
    else:
        b = camp.new_branch("continuation")
        # (a zero the scan's secant found has no Jacobian: a fresh one at the start)
        jac = None if start.get("jacobian") is None else np.asarray(start["jacobian"], float)
        ok = jac is not None and jac.shape == (problem.n, problem.n + 1)
        corrector.jacobian = jac if ok else None
        camp.seed_rig()
        # from whatever the rig held last (another LCO, or rest after a trip): the
        # oscillation started near this LCO first
        camp.rig.set_parameter(spec.param, float(start["y"][-1]))
        a0 = float(start["y"][0])
        try:
            bootstrap(camp.rig, opts, 0.8 * a0, float(start["omega"]), a_max=a0)
        except ConvergenceError as exc:  # recorded; the campaign goes on
            camp.fail({spec.param: float(start["y"][-1])}, f"the LCO could not be started: {exc}")
            camp.end_branch(b, "failed", str(exc))
            return
        st, r = _start_branch(corrector, driver, np.asarray(start["y"], float), _direction(camp))
        if st is None:
            camp.fail(
                {spec.param: float(start["y"][-1])},
                f"the LCO of the scan could not be held again: {r.info.get('reason', '')}",
            )
            camp.end_branch(b, "failed", r.info.get("reason", ""))
            return
        br = _Branch(problem, corrector, driver, st, point)

    def recover(br: _Branch, raise_gains: bool) -> None:
        if raise_gains:
            new = _stronger(camp, br.problem.opts, float(br.state.y[-1]))
            br.problem.opts = new
            br.problem.family = br.problem.family.with_options(new)
            camp.cursor["gains"] = {**_saved_controller(camp), "kp": new.kp, "kd": new.kd}
        # wherever the failed attempts left the rig (at rest after a trip, or far from the
        # branch): start the oscillation again, then hold the last target
        camp.rig.set_parameter(spec.param, float(br.state.y[-1]))
        a0 = float(br.state.y[0])
        bootstrap(camp.rig, br.problem.opts, 0.8 * a0, br.problem.omega, a_max=a0)
        camp.seed_rig()
        ev = br.corrector.evaluate(br.state.y)
        br.corrector.jacobian = None
        br.corrector.bootstrap(ev)

    camp.cursor["branch"] = _save(br, {"branch": b})
    camp.follow(br, b, lambda x: _save(x, {"branch": b}), recover, _reframe)


def _stronger(camp: Campaign, opts: PPCBCOptions, value: float) -> PPCBCOptions:
    """The controller of a branch's last retry at ``value``: the one designed on the
    model's cycles there (:func:`~bifid.cbc._retry.other_controllers`, first) where it
    acts in the branch's plane (the target's unknowns keep their meaning), else the
    gains raised."""
    other = next(iter(other_controllers(camp, opts, value)), None)
    if other is not None and other.get("x2", opts.x2) == opts.x2:
        return with_gains(opts, other)
    return raised(opts)


REFRAME_SHAPE = 0.3  #: harmonics / a0* of a polar target (~0.1 in its orbit's frame)


def _reframe(br: _Branch, ev) -> None:
    """Move a polar target's frame to the orbit just measured once the branch has left
    the frame's orbit (harmonics above :data:`REFRAME_SHAPE` of ``a0*``; e.g. past a
    cycle fold, where ``r*(φ)`` of few harmonics cannot follow the orbit: a zero of the
    control error would be an invasively controlled orbit). State and Broyden Jacobian
    are carried over by the conversion of the unknowns (``TargetFamily.convert``) and
    its linearisation ``C``: ``J ← [C J_c C⁻¹, C J_λ]``; no rig time is spent."""
    prob = br.problem
    old = prob.family
    y, n = br.state.y, prob.n
    if not old.polar or np.linalg.norm(y[1:n]) <= REFRAME_SHAPE * abs(float(y[0])):
        return
    try:
        new = old.reframed(ev.info.m, prob.omega)
    except ConvergenceError:
        return
    h = 1e-6 * abs(float(y[0]))
    C = np.empty((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = h
        C[:, j] = (old.convert(y[:n] + e, new) - old.convert(y[:n] - e, new)) / (2.0 * h)
    try:
        C_inv = np.linalg.inv(C)
    except np.linalg.LinAlgError:
        return

    def convert(v: np.ndarray) -> np.ndarray:
        return np.concatenate([old.convert(v[:n], new), v[n:]])

    st, cor = br.state, br.corrector
    t = np.concatenate([C @ st.t[:n], st.t[n:]])
    t = t / math.sqrt(float(t @ (prob.weights * t)))
    y_prev = None if st.y_prev is None else convert(st.y_prev)
    br.state = replace(st, y=convert(y), y_prev=y_prev, t=t)
    if cor.jacobian is not None and cor.jacobian.shape == (n, n + 1):
        J = cor.jacobian
        cor.jacobian = np.hstack([C @ J[:, :n] @ C_inv, C @ J[:, n:]])
    if cor.y_accepted is not None:
        cor.y_accepted = convert(cor.y_accepted)
    prob.family = new
    prob.rescale(br.state.y)


RELOCK_FRACTION = 0.5  #: of an unstable LCO's amplitude after its switch-off test


def _relock(camp: Campaign, problem: PPCBCProblem, a_star: float, amplitude: float) -> None:
    """After the switch-off test of an unstable LCO (the rig left it; a controller in a
    plane that cannot self-excite, e.g. heave and pitch of flutter, does not bring it
    back from near rest): below :data:`RELOCK_FRACTION` of its amplitude over two
    periods, the oscillation is started again (:func:`bootstrap`, as after a trip).
    A failure here is left to the next step's retry policy."""
    rig, opts = camp.rig, problem.opts
    m = rig.run(2.0 * 2.0 * math.pi / problem.omega)
    x1 = m.signal(opts.x1)
    tail = x1[-max(2, round(2.0 * math.pi / problem.omega * rig.sample_rate)) :]
    if m.status == "ok" and 0.5 * float(np.ptp(tail)) >= RELOCK_FRACTION * amplitude:
        return
    try:
        bootstrap(rig, opts, 0.8 * a_star, problem.omega, a_max=a_star)
    except ConvergenceError:
        return


# -------------------------------------------------------------------------------- forced
def _forced(camp: Campaign) -> None:
    spec = camp.spec
    opts = with_gains(ForcedCBCOptions(**dict(spec.options)), camp.cursor.get("gains"))
    saved = camp.cursor.get("branch")
    lam0 = float(spec.range[0])
    if saved is None and int(camp.cursor["task"]) > 0:
        return  # finished (its end was recorded)
    if saved is not None:
        st = saved["problem"]
        problem = ForcedProblem(
            camp.rig,
            opts,
            spec.protocol,
            spec.fixed,
            float(st["a_ref"]),
            float(st["param_scale"]),
            float(st["a_first"]),
            np.asarray(st["pstar"], float),
        )
        problem.periods = float(st["periods"])
    else:
        camp.seed_rig()
        gamma, om = (lam0, spec.fixed) if spec.protocol == "scurve" else (spec.fixed, lam0)
        try:
            p0 = open_loop(camp.rig, opts, gamma, om)
        except ConvergenceError as exc:
            camp.new_branch(spec.protocol)
            camp.fail({spec.param: lam0}, f"the open-loop response could not be measured: {exc}")
            camp.end_branch(0, "failed", str(exc))
            return
        q = opts.n_harmonics
        a_first = max(math.hypot(p0[1], p0[q + 1]), 1e-12)
        # S-curve: half the first amplitude extrapolated linearly to the top of the range;
        # FRC: 20 times the first amplitude
        a_ref = (
            0.5 * a_first * max(spec.range) / lam0 if spec.protocol == "scurve" else 20.0 * a_first
        )
        problem = ForcedProblem(
            camp.rig, opts, spec.protocol, spec.fixed, a_ref, spec.param_scale, a_first, p0
        )
    corrector = BroydenCorrector(
        problem,
        max_iter=opts.newton_max,
        trust=2.0,
        radius=2.0 * opts.ds_max,
        on_evaluation=camp.on_evaluation,
    )
    driver = Continuation(
        corrector,
        2,
        _driver_options(camp, opts.newton_max, opts.ds_max),
        weights=problem.weights,
        predictor="secant",
    )
    driver.options = driver.options.with_(ds=opts.ds, ds_min=opts.ds / 16.0)

    def point(ev, evaluations: int):
        return problem.point(ev, evaluations)

    if saved is not None:
        corrector.restore(saved["corrector"])
        br = _Branch(problem, corrector, driver, _driver_state(saved), point, int(saved["retries"]))
    else:
        b = camp.new_branch(spec.protocol)
        p0 = problem.pstar
        y0 = problem.unknowns(float(p0[1]), float(p0[opts.n_harmonics + 1]), lam0)
        if spec.protocol == "scurve":  # the target's fundamental along cos θ
            problem.pstar = np.zeros_like(p0)
        st, r = _start_branch(corrector, driver, y0, _direction(camp))
        if st is None:
            camp.fail({spec.param: lam0}, f"first point: {r.info.get('reason', '')}")
            camp.end_branch(b, "failed", r.info.get("reason", ""))
            camp.cursor["task"] = 1
            return
        camp.record(point(r.info["evaluation"], int(r.info.get("evaluations", 0))), b, write=False)
        br = _Branch(problem, corrector, driver, st, point)
        camp.cursor["task"] = 1
        camp.cursor["branch"] = _save(br, {"branch": 0})
        camp.checkpoint()

    def recover(br: _Branch, raise_gains: bool) -> None:
        if raise_gains:
            br.problem.opts = raised(br.problem.opts)
            camp.cursor["gains"] = [br.problem.opts.kp, br.problem.opts.kd]
        camp.seed_rig()
        ev = br.corrector.evaluate(br.state.y)
        br.corrector.jacobian = None
        br.corrector.bootstrap(ev)

    camp.follow(br, 0, lambda x: _save(x, {"branch": 0}), recover)
    camp.cursor["branch"] = None
