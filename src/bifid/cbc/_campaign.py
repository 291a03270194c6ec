"""CBC campaigns: what they measure, their state, and how a branch is followed and retried.

A campaign (:class:`CampaignSpec`) is one of

- ``ppcbc`` with ``values``: the amplitude scan (§3.3.3.2) at each value in turn;
- ``ppcbc`` with ``continuation = N``: the scan at the first value of the range, then each
  LCO found there followed in the parameter by pseudo-arclength continuation on the
  measured PP-CBC zero problem (Example 3.3), round its folds, until the range ends or
  ``N`` points are measured (LCOs of the scan already on a followed branch are skipped);
- ``scurve`` / ``frc``: the response at the start of the range, then pseudo-arclength
  continuation of the forced zero problem in ``γ`` / ``Ω`` through the folds (§3.2).

Continuation runs on :class:`bifid.continuation.Continuation` with the Broyden corrector
of :mod:`bifid.cbc._measured` (secant predictor, no fold location on the rig: folds are
read off the measured curve). Step control: the driver halves a step that fails; a step
whose secant turns by more than ``max_turn`` degrees halves the next one, one that turns
by less than half that and converged easily grows it, so folds are resolved without gaps.

**Retries.** A step that fails even at the smallest arclength step, or trips the rig (or,
in PP-CBC, is noise-limited: next to a cycle fold the Jacobian estimate decides), is
retried before a failure is recorded: (1) back to the last recorded point (the rig
re-settled there, the oscillation restarted from rest when the rig tripped, a fresh
finite-difference Jacobian) with twice the smallest step; (2) the same with the
controller gains doubled (the controller lost lock). A scan with failures is repeated with
other controllers (``_retry.other_controllers``: one designed on the system's
model, then the bootstrap gains in ``(x1, ẋ1)`` where the protocol's plane is another,
else doubled gains); a failure another scan of the value answered is dropped. What still
fails is recorded with its reason and ends the branch; the campaign is then incomplete.

**Records and resume.** Every recorded point is written to the dataset at once, with the
campaign's checkpoint (:mod:`bifid.cbc._checkpoint`). The rig is re-seeded before every
step from ``(seed, checkpoint, attempt)`` and its state is saved with the checkpoint
(where the rig can save it, as a virtual rig does), so a resumed campaign measures
exactly what the uninterrupted one would have measured.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from bifid.cbc._checkpoint import CampaignFile, digest, to_json
from bifid.cbc._measured import BroydenCorrector, Failure, NoiseLimited
from bifid.cbc._ppcbc import Invasive
from bifid.cbc._records import forced_record, lco_record
from bifid.cbc._rig import AbstractRig
from bifid.continuation import Continuation, ContinuationOptions, ContinuationState
from bifid.errors import BifidInputError, ConvergenceError, ConvergenceWarning

__all__ = ["Campaign", "CampaignResult", "CampaignSpec"]

PROTOCOLS = ("ppcbc", "scurve", "frc")


@dataclass(frozen=True)
class CampaignSpec:
    """What a campaign measures; all of it is checked when a file is resumed.

    Parameters
    ----------
    system : str
        The system's name (or file).
    protocol : {"ppcbc", "scurve", "frc"}
    parameters : dict
        Every parameter of the system, by name.
    param : str
        The continuation parameter (``ppcbc``: the bifurcation parameter; ``scurve``:
        ``F``; ``frc``: ``Omega``).
    range : (float, float)
        Start and end of the parameter's range (travel from the first to the second).
    options : dict
        :class:`~bifid.cbc.PPCBCOptions` or :class:`~bifid.cbc.ForcedCBCOptions` fields.
    rig : dict
        The rig's description (``AbstractRig.describe``).
    values : tuple of float
        ``ppcbc`` scan mode: the parameter values.
    continuation : int
        ``ppcbc``: points to measure by continuation (0: scan at ``values``).
    fixed : float
        ``scurve``: ``Ω``; ``frc``: ``γ``.
    amplitudes : tuple of float
        ``ppcbc``: the scan's grid of target amplitudes.
    seed : int
        Seed of the per-step noise streams.
    ds, param_scale : float
        Arclength step and the parameter's scale in its metric.
    omega_guess : float
        Frequency guess [rad/s] of the first PP-CBC scan.
    max_points : int
        Largest number of points of the continuation branches (all of them).
    """

    system: str
    protocol: str
    parameters: Mapping[str, float]
    param: str
    range: tuple[float, float]
    options: Mapping[str, Any]
    rig: Mapping[str, Any]
    values: tuple[float, ...] = ()
    continuation: int = 0
    fixed: float = math.nan
    amplitudes: tuple[float, ...] = ()
    seed: int = 0
    ds: float = 0.5
    param_scale: float = 1.0
    omega_guess: float = 1.0
    max_points: int = 200

    def __post_init__(self) -> None:
        if self.protocol not in PROTOCOLS:
            raise BifidInputError(
                f"protocol must be one of {', '.join(PROTOCOLS)}, got {self.protocol!r}."
            )
        lo, hi = (float(v) for v in self.range)
        scan = self.protocol == "ppcbc" and not self.continuation
        if not (math.isfinite(lo) and math.isfinite(hi)) or (lo == hi and not scan):
            raise BifidInputError(
                f"the range must be two distinct finite numbers, got {self.range!r}."
            )
        if self.protocol == "ppcbc" and not self.continuation and not self.values:
            raise BifidInputError("a PP-CBC campaign needs values, or continuation > 0.")
        if self.continuation < 0 or self.max_points < 1:
            raise BifidInputError("continuation and max_points must be positive.")
        if not (self.ds > 0 and self.param_scale > 0):
            raise BifidInputError("ds and param_scale must be positive.")

    def identity(self) -> dict[str, Any]:
        """The settings a resumed file must share (everything but the frequency guess)."""
        d = asdict(self)
        d["rig"] = {k: v for k, v in dict(self.rig).items() if k not in ("seed",)}
        return d


@dataclass
class CampaignResult:
    """What a campaign measured: the diagram (the CLI's JSON), the dataset, the points
    measured in this run, and every failure with its reason."""

    diagram: Any
    dataset: Any
    points: list[Any]
    failures: list[Failure]
    resumed_from: int = 0

    @property
    def complete(self) -> bool:
        return bool(self.diagram.complete)


@dataclass
class _Branch:
    """A continuation branch in progress: problem, corrector, driver and state."""

    problem: Any
    corrector: BroydenCorrector
    driver: Continuation
    state: ContinuationState
    make_point: Callable[[Any, int], Any]
    retries: int = 0


def _seed_of(seed: int, unit: int, sub: int) -> int:
    return int(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, unit, sub]).generate_state(1)[0])


class Campaign:
    """State and bookkeeping of a running campaign (:func:`run_campaign` drives it)."""

    def __init__(
        self,
        spec: CampaignSpec,
        rig: AbstractRig,
        file: CampaignFile | None,
        dataset_kwargs: Mapping[str, Any],
        on_point: Callable[[Any], None] | None,
        on_evaluation: Callable[[int], None] | None,
    ) -> None:
        self.spec, self.rig, self.file = spec, rig, file
        self.dataset_kwargs = dict(dataset_kwargs)
        self.on_point, self.on_evaluation = on_point, on_evaluation
        self.records: list[Any] = []
        self.points: list[Any] = []
        self.failures: list[Failure] = []
        self.warnings: list[str] = []
        self.branches: list[dict[str, Any]] = []
        self.rec_branch: list[int] = []
        self.cursor: dict[str, Any] = {
            "task": 0,
            "unit": 0,
            "done": False,
            "branch": None,
            "omega": spec.omega_guess,
            "starts": [],
            "gains": None,
        }
        self.sub = 0
        self.rig_restored = False  # a resumed rig is in the state of the checkpoint
        self.fresh = False  # the last record waits for the checkpoint taken after it
        self.digest = digest(spec.identity())
        self.checkpoint_state: dict[str, Any] = self._state()

    # ------------------------------------------------------------------ bookkeeping
    def seed_rig(self) -> None:
        """Restart the rig's noise stream from (seed, checkpoint, attempt)."""
        self.rig.seed(_seed_of(self.spec.seed, int(self.cursor["unit"]), self.sub))
        self.sub += 1

    def new_branch(self, label: str) -> int:
        self.branches.append({"label": label, "status": "completed", "message": ""})
        return len(self.branches) - 1

    def end_branch(self, b: int, status: str, message: str) -> None:
        self.branches[b]["status"], self.branches[b]["message"] = status, message

    def fail(self, where: Mapping[str, float], reason: str, **data: Any) -> None:
        """Record a failure (and warn: :class:`~bifid.errors.ConvergenceWarning`)."""
        text = ", ".join(f"{k}={v:.6g}" for k, v in where.items())
        warnings.warn(f"CBC at {text}: {reason}", ConvergenceWarning, stacklevel=2)
        self.failures.append(Failure(dict(where), str(reason), dict(data)))

    def record(self, point: Any, branch: int, write: bool = True) -> None:
        """Keep a measured point and write it to the file with the last checkpoint (unless
        ``write`` is False: a checkpoint follows at once, and the point carries it)."""

        if self.spec.protocol == "ppcbc":
            rec = lco_record(point, "ppcbc")
            rec.extra["segment"] = float(branch)
        else:
            rec = forced_record(point, self.spec.protocol, curve=branch)
        rec.extra["cbc_state"] = json.dumps(to_json(self.checkpoint_state))
        self.records.append(rec)
        self.rec_branch.append(branch)
        self.fresh = not write
        self.points.append(point)
        if self.file is not None and write:
            self.file.write(self.records, self.checkpoint_state)
        if self.on_point is not None:
            self.on_point(point)

    def _state(self) -> dict[str, Any]:
        snap = getattr(self.rig, "snapshot", None)
        return {
            "digest": self.digest,
            "identity": self.spec.identity(),
            "cursor": dict(self.cursor),
            "n_records": len(self.records),
            "rec_branch": list(self.rec_branch),
            "branches": list(self.branches),
            "failures": [f.to_json() for f in self.failures],
            "warnings": list(self.warnings),
            "rig": snap() if callable(snap) else None,
        }

    def checkpoint(self) -> None:
        """A new checkpoint: the campaign continues exactly from here after a resume."""
        self.cursor["unit"] = int(self.cursor["unit"]) + 1
        self.sub = 0
        self.checkpoint_state = self._state()
        if self.fresh:  # the point just recorded carries the state taken after it
            self.records[-1].extra["cbc_state"] = json.dumps(to_json(self.checkpoint_state))
            self.fresh = False
        if self.file is not None:
            self.file.write(self.records, self.checkpoint_state)

    def restore(self, records: list[Any], state: Mapping[str, Any]) -> None:
        """Continue from a checkpoint read from a file (records after it are dropped)."""
        n = int(state["n_records"])
        self.records = list(records[:n])
        self.rec_branch = [int(b) for b in state["rec_branch"]][:n]
        self.branches = [dict(b) for b in state["branches"]]
        self.failures = [
            Failure({k: v for k, v in f.items() if k != "reason"}, f["reason"])
            for f in state["failures"]
        ]
        self.warnings = list(state["warnings"])
        self.cursor = dict(state["cursor"])
        self.checkpoint_state = dict(state)
        restore = getattr(self.rig, "restore", None)
        if state.get("rig") is not None and callable(restore):
            restore(state["rig"])
            self.rig_restored = True

    # ------------------------------------------------------------------ branches
    def follow(
        self,
        br: _Branch,
        b: int,
        save: Callable[[_Branch], dict[str, Any]],
        recover: Callable[[_Branch, bool], None],
        after: Callable[[_Branch, Any], None] | None = None,
    ) -> None:
        """Step ``br`` until it ends, recording each point and checkpointing after it
        (``after(br, evaluation)`` first: e.g. the problem's frame moved to the point)."""
        opts = br.driver.options
        max_turn = float(self.spec.options.get("max_turn", 20.0))
        br.corrector.follow_secant = True
        while br.state.running:
            if self.budget_left() <= 0:
                br.state.status, br.state.message = (
                    "completed",
                    (f"{self.spec.max_points} points measured"),
                )
                break
            self.seed_rig()
            before, c_before = br.state, br.corrector.state()
            s = br.driver.step(br.state)
            if s.point is not None:
                try:
                    pt = br.make_point(
                        s.point.info["evaluation"], int(s.point.info.get("evaluations", 0))
                    )
                except Invasive as exc:
                    br.corrector.restore(c_before)
                    br.state = replace(before, ds=max(before.ds / 2.0, opts.ds_min))
                    br.corrector.last_reason = str(exc)
                    if before.ds <= opts.ds_min * 1.0001 and not self._retry(br, b, recover):
                        break
                    continue
                br.state = self._step_control(s.state, before, max_turn, opts, br.problem.weights)
                br.retries = 0
                br.problem.rescale(br.state.y)
                if after is not None:
                    after(br, s.point.info["evaluation"])
                self.record(pt, b, write=False)
                self.cursor["branch"] = save(br)
                self.checkpoint()
                continue
            br.state = s.state
            if (
                br.corrector.tripped
                or br.state.status == "failed"
                or isinstance(br.corrector.last_reason, NoiseLimited)
            ):
                if not self._retry(br, b, recover):
                    break
        status = br.state.status if br.state.status != "running" else "completed"
        self.end_branch(b, status, br.state.message)

    def budget_left(self) -> int:
        """Points the continuation branches may still record (``max_points`` in all)."""
        labels = [b["label"] for b in self.branches]
        used = sum(1 for k in self.rec_branch if labels[k] != "scan")
        return self.spec.max_points - used

    def points_of(self, b: int) -> list[int]:
        return [i for i, k in enumerate(self.rec_branch) if k == b]

    def _step_control(
        self,
        new: ContinuationState,
        before: ContinuationState,
        max_turn: float,
        opts: ContinuationOptions,
        w: np.ndarray,
    ) -> ContinuationState:
        """The next arclength step: halved (not below an eighth of the initial step) where
        the secant turned by more than ``max_turn`` degrees, grown by ``opts.growth``
        where it turned by less than half of that, else kept. (Halving further would put
        noisy points closer than their scatter: spurious folds.)"""
        turn = 0.0
        if before.y_prev is not None and new.y_prev is not None:
            a, c = before.y - before.y_prev, new.y - new.y_prev
            den = math.sqrt(float(a @ (w * a)) * float(c @ (w * c)))
            if den > 0:
                turn = math.degrees(math.acos(max(-1.0, min(1.0, float(a @ (w * c)) / den))))
        ds = before.ds
        if turn > max_turn:
            ds = max(ds / 2.0, self.spec.ds / 8.0)
        elif turn < max_turn / 2.0:
            ds = ds * opts.growth
        return replace(new, ds=min(max(ds, opts.ds_min), opts.ds_max))

    def _retry(self, br: _Branch, b: int, recover: Callable[[_Branch, bool], None]) -> bool:
        """The retry policy (module docstring); False when the branch must end."""
        reason = br.corrector.last_reason or br.state.message
        where = {self.spec.param: float(br.state.y[br.driver.param_index])}
        final = isinstance(reason, NoiseLimited) and not br.problem.retry_noise_limited
        if final or br.retries >= 2:
            self.fail(where, reason or "the corrector failed", retries=br.retries)
            br.state.status = "failed"
            br.state.message = str(reason)
            return False
        br.retries += 1
        try:
            recover(br, br.retries >= 2)
        except ConvergenceError as exc:  # the rig could not be brought back: recorded
            self.fail(where, f"{reason}; then back on the last point: {exc}", retries=br.retries)
            br.state.status, br.state.message = "failed", str(exc)
            return False
        # the tangent again from the fresh Jacobian (the branch's start has no secant)
        br.corrector.follow_secant = False
        t, _ = br.corrector.tangent(br.state.y, br.state.t, br.problem.weights, None)
        br.corrector.follow_secant = True
        br.state = replace(
            br.state, t=t, status="running", message="", ds=2.0 * br.driver.options.ds_min
        )
        return True
