"""The retry policy of PP-CBC scans (:mod:`bifid.cbc._campaign_tasks`): the controllers a
failed scan is repeated with, the model's LCOs held directly, the LCOs of the model that
lie outside the rig's safety envelope (refused before the scan reaches them), and one
failure per LCO of the model left unmeasured.

With a model of the campaign's system (a virtual rig's, or the system the campaign
names), the LCOs a scan at a value asks for are the model's cycles there
(:func:`~bifid.cbc._derive.cycles_at`): a failure is recorded per such LCO that no scan
or retry measured, with the last reason that can be about it.
"""

from __future__ import annotations

import json
import math
import warnings
from dataclasses import replace
from typing import Any

import numpy as np

from bifid.cbc._campaign import Campaign
from bifid.cbc._campaign_result import ANSWER_TOL, amplitudes_of, unanswered
from bifid.cbc._derive import cycles_at, linearisation, retry_controller
from bifid.cbc._measured import Failure
from bifid.cbc._ppcbc import PPCBCOptions
from bifid.cbc._ppcbc_scan import ScanResult, hold_orbit
from bifid.cbc._stability import orbit_polar_target
from bifid.errors import BifidInputError
from bifid.systems import System, get_system

__all__ = [
    "GAIN_FACTOR",
    "all_measured",
    "keeper",
    "model_lcos",
    "model_orbits",
    "other_controllers",
    "per_lco",
    "raised",
    "refused",
    "unmatched",
    "with_gains",
]

GAIN_FACTOR = 2.0  # controller gains are multiplied by this on loss of lock


def with_gains(opts: Any, gains: list[float] | dict[str, Any] | None) -> Any:
    """``opts`` with the controller saved in the cursor: ``[kp, kd]`` or option fields."""
    if gains is None:
        return opts
    if isinstance(gains, dict):
        return replace(
            opts, **{k: tuple(v) if isinstance(v, list) else v for k, v in gains.items()}
        )
    return replace(opts, kp=float(gains[0]), kd=float(gains[1]))


def raised(opts: Any) -> Any:
    """``opts`` with both gains multiplied by :data:`GAIN_FACTOR` (the controller lost
    lock)."""
    return replace(opts, kp=GAIN_FACTOR * opts.kp, kd=GAIN_FACTOR * opts.kd)


def other_controllers(camp: Campaign, opts: PPCBCOptions, value: float):
    """The controllers a failed PP-CBC scan at ``value`` is repeated with, in turn, as
    option fields. With a model of the campaign's system, first the one designed on its
    cycles at ``value`` (:func:`~bifid.cbc._derive.retry_controller`, e.g. against the
    period doubling of a large flutter LCO). Then, where the protocol's plane is not
    ``(x1, ẋ1)`` and the system has bootstrap gains (they hold its rig in that plane:
    they start every oscillation), the polar target in ``(x1, ẋ1)`` with those gains;
    else the gains raised (the controller lost lock)."""
    derivative = f"{opts.x1}_dot"
    d = _design(camp, opts, value)
    if d is not None and (d["x2"], d["kp"], d["kd"]) != (opts.x2, opts.kp, opts.kd):
        yield _fields(d, opts, *_model(camp))
    if opts.bootstrap_gains is not None and opts.x2 != derivative:
        kp, kd = (float(g) for g in opts.bootstrap_gains)
        centre = [float(opts.centre[0]), 0.0]
        yield {"x2": derivative, "kp": kp, "kd": kd, "filter_hz": None, "centre": centre}
    else:
        yield {"kp": GAIN_FACTOR * opts.kp, "kd": GAIN_FACTOR * opts.kd}


def _model(camp: Campaign) -> tuple[System, Any] | None:
    """The campaign's system and parameter vector: the virtual rig's, else the system
    the campaign names; None without one (or for a forced system)."""
    system = getattr(camp.rig, "system", None)
    try:
        if not isinstance(system, System):
            system = get_system(camp.spec.system)
        if system.kind != "autonomous":
            return None
        return system, system.param_vector(dict(camp.spec.parameters))
    except (BifidInputError, OSError, KeyError, ValueError):
        return None


def _design(
    camp: Campaign, opts: PPCBCOptions, value: float, orbit: int | None = None
) -> dict[str, Any] | None:
    """The retry controller designed on the model (:func:`retry_controller`, for all its
    cycles at ``value`` or the ``orbit``-th; None without a model)."""
    model = _model(camp)
    if model is None:
        return None
    system, p = model
    outputs = tuple(camp.rig.output_names)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return retry_controller(
            system, p, camp.spec.param, value, camp.spec.range, opts.x1, opts.x2, outputs, orbit
        )


def _fields(d: dict[str, Any], opts: PPCBCOptions, system: System, p) -> dict[str, Any]:
    """A designed controller as option fields (the bootstrap's centre in its plane)."""
    x2 = str(d["x2"])
    if x2 == opts.x2:
        centre = [float(c) for c in opts.centre]
    elif x2.endswith("_dot"):
        centre = [float(opts.centre[0]), 0.0]
    else:  # another output: its value at the model's equilibrium
        x_eq, _ = linearisation(system, p)
        centre = [float(opts.centre[0]), float(x_eq[system.state_index(x2)])]
    return {"x1": opts.x1, "x2": x2, "kp": float(d["kp"]), "kd": float(d["kd"]), "centre": centre}


def keeper(camp: Campaign, opts: PPCBCOptions, branch: int, known: list[tuple[float, float]]):
    """Records a point unless ``known`` holds it already, with the controller it was
    measured with (in the file from the checkpoint that ends the value on)."""
    c = opts.controller
    controller = json.dumps(
        {"x1": c.x1, "x2": c.x2, "kp": c.kp, "kd": c.kd, "filter_hz": c.filter_hz}
    )

    def keep(pt) -> None:
        a = float(pt.amplitude[opts.x1])
        if any(
            abs(v - pt.param) <= 1e-9 * max(1.0, abs(v)) and abs(b - a) <= 0.02 * a
            for v, b in known
        ):
            return  # two brackets (or a repeated scan) converged to the same LCO
        known.append((float(pt.param), a))
        camp.record(pt, branch)
        camp.records[-1].extra["controller"] = controller

    return keep


# ------------------------------------------------------------- the model's LCOs at a value
def model_lcos(camp: Campaign, opts: PPCBCOptions, value: float) -> list[dict[str, Any]]:
    """The model's LCOs at ``value`` (:func:`cycles_at`), each as ``{"k", "lam", "orbit",
    "period", "a_star", "outside"}``: its index, the cycle, its ``A*`` (mean radius of
    its polar target in ``(x1, x2)``, the scan's amplitude) and, when its peak of a state
    leaves the rig's safety envelope, that state's ``(name, peak, (min, max))`` (else
    None). Empty without a model."""
    model = _model(camp)
    if model is None:
        return []
    system, p = model
    spec = camp.spec
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        orbits = cycles_at(system, p, spec.param, value, spec.range)
    env = (spec.rig or {}).get("envelope") or (
        None if system.envelope is None else system.envelope.to_json()
    )
    limits = {} if env is None else dict(env.get("states", {}))
    out = []
    for k, (lam, orbit, period) in enumerate(orbits):
        pv = np.asarray(system.param_vector({**spec.parameters, spec.param: lam}))
        a = float(orbit_polar_target(orbit, system, opts.x1, opts.x2, 1, p=pv).coefficients[0])
        outside = None
        for name, (lo, hi) in limits.items():
            x = np.asarray(orbit)[:, system.state_index(name)]
            if x.min() < lo or x.max() > hi:
                peak = float(x.max() if x.max() > hi else x.min())
                outside = (name, peak, (float(lo), float(hi)))
                break
        out.append(
            {"k": k, "lam": lam, "orbit": orbit, "period": period, "a_star": a, "outside": outside}
        )
    return out


def refused(camp: Campaign, value: float, lcos: list[dict[str, Any]]) -> list[Failure]:
    """A failure for every LCO of the model at ``value`` outside the rig's safety
    envelope: holding it would trip the safety gate, on a real rig as on a virtual one."""
    out = []
    for c in lcos:
        if c["outside"] is None:
            continue
        name, peak, (lo, hi) = c["outside"]
        out.append(
            Failure(
                {"param": float(value)},
                f"not measured: the model's LCO of A* = {c['a_star']:.4g} at "
                f"{camp.spec.param}={value:g} reaches {name} = {peak:.4g}, outside the rig's "
                f"safety envelope [{lo:g}, {hi:g}] (holding it would trip the safety gate)",
                {"lco": c["a_star"], "envelope": name},
            )
        )
    return out


def _concerns(f: Failure, a: float) -> bool:
    """Whether the failure ``f`` can be about the LCO of amplitude ``A* = a``."""
    d = f.data
    if "bracket" in d:
        lo, hi = sorted(float(v) for v in d["bracket"])
        return (1 - ANSWER_TOL) * lo <= a <= (1 + ANSWER_TOL) * hi
    if "lco" in d:
        return abs(a - float(d["lco"])) <= ANSWER_TOL * float(d["lco"])
    if "a_star" in d:
        return a >= (1 - ANSWER_TOL) * float(d["a_star"])
    return True


def per_lco(
    failures: list[Failure], missing: list[float], value: float, held: dict[float, str]
) -> tuple[list[Failure], list[Failure]]:
    """One failure per LCO of the model left unmeasured (``missing``: their ``A*``): the
    last of ``failures`` that can be about it (a failed bracket round it, a rejected LCO
    near it, a scan stopped below it), with why holding it from the model's orbit failed
    (``held``); ``(kept, dropped)``, ``dropped`` the failures about no missing LCO (e.g.
    one the model says is not there, or a second failure of the same LCO)."""
    kept, used = [], set()
    for a in missing:
        about = [f for f in failures if _concerns(f, a)]
        extra = f"; held from the model's orbit: {held[a]}" if a in held else ""
        if about:
            f = about[-1]
            used.add(id(f))
            kept.append(replace(f, reason=f"{f.reason}{extra}", data={**f.data, "model": a}))
        else:
            last = f" (the last failure there: {failures[-1].reason})" if failures else ""
            why = f"the model's LCO of A* = {a:.4g} was not measured{last}{extra}"
            kept.append(Failure({"param": float(value)}, why, {"lco": a}))
    return kept, [f for f in failures if id(f) not in used]


def unmatched(wanted: list[float], measured: list[float]) -> list[float]:
    """The amplitudes of ``wanted`` (the model's LCOs, ``A*``) that no ``measured`` one
    matches within :data:`ANSWER_TOL`, each measured LCO matching one wanted at most,
    the closest pairs first (two LCOs near a cycle fold are within the tolerance of
    each other: one measured LCO is not both)."""
    pairs = sorted(
        (abs(b - a) / a, i, j)
        for i, a in enumerate(wanted)
        for j, b in enumerate(measured)
        if abs(b - a) <= ANSWER_TOL * a
    )
    used_a, used_b = set(), set()
    for _, i, j in pairs:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
    return [a for i, a in enumerate(wanted) if i not in used_a]


def all_measured(res: ScanResult, lcos: list[dict[str, Any]] | None, x1: str) -> bool:
    """Whether the scan ``res`` measured every LCO of the model inside the envelope
    (``lcos``, :func:`model_lcos`; False without them): its other failures need no
    retry."""
    inside = [c["a_star"] for c in lcos or [] if c["outside"] is None]
    return bool(lcos) and not unmatched(inside, amplitudes_of(res.points, x1))


def model_orbits(
    camp: Campaign,
    opts: PPCBCOptions,
    value: float,
    branch: int,
    known,
    res: ScanResult,
    lcos: list[dict[str, Any]],
) -> None:
    """The LCOs the scans left unmeasured, each held from the model's orbit at ``value``
    (``lcos``, :func:`model_lcos`; those outside the envelope are not) with a controller
    designed on that orbit (:func:`~bifid.cbc._ppcbc_scan.hold_orbit`); then
    ``res.failures`` are one per LCO of the model still unmeasured (:func:`per_lco`), none
    once every one is measured. Without the model's LCOs, the failures another scan
    answered are dropped (:func:`unanswered`)."""
    spec = camp.spec
    got = ScanResult()
    held: dict[float, str] = {}
    inside = [c for c in lcos if c["outside"] is None]
    left = unmatched([c["a_star"] for c in inside], amplitudes_of(res.points, opts.x1))
    for c in inside:
        a, orbit = c["a_star"], c["orbit"]
        if a not in left:
            continue  # measured by a scan
        d = _design(camp, opts, value, c["k"])
        if d is None:
            held[a] = "no controller designed on the model holds it"
            camp.warnings.append(
                f"PP-CBC at {spec.param}={value:g}: no controller holds "
                f"the model's orbit of A* = {a:.4g}"
            )
            continue
        system, p = _model(camp)
        new = with_gains(opts, _fields(d, opts, system, p))
        pv = np.asarray(system.param_vector({**spec.parameters, spec.param: c["lam"]}))
        target = orbit_polar_target(orbit, system, new.x1, new.x2, new.n_harmonics, p=pv)
        camp.seed_rig()
        om = 2.0 * math.pi / c["period"]
        pt, why = hold_orbit(camp.rig, spec.param, value, target, new, om, camp.on_evaluation)
        if pt is None:
            held[a] = why
            camp.warnings.append(f"PP-CBC at {spec.param}={value:g}, orbit A* = {a:.4g}: {why}")
            continue
        keeper(camp, new, branch, known)(pt)
        got.points.append(pt)
    res.points += got.points
    if not lcos:
        res.failures = unanswered(res, got, opts.x1)
        return
    missing = unmatched([c["a_star"] for c in inside], amplitudes_of(res.points, opts.x1))
    res.failures, dropped = per_lco(res.failures, missing, value, held)
    for f in dropped:
        camp.warnings.append(
            f"PP-CBC at {spec.param}={value:g}: {f.reason} (not a failure: an LCO of the "
            "model there is measured, or this one failed again later)"
        )
