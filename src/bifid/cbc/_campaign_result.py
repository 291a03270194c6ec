"""A campaign's records as a :class:`~bifid.continuation.Diagram` and a dataset, and the
merge of the scans of one value (:func:`unanswered`: a failure another scan answered).

The diagram is the one result type of bifid (``source = "measurement"``): one branch of
kind ``"measured"`` per scan or continuation branch, with the measured amplitudes
(``max_t |x - x̄|``, the measured convention), offsets, frequencies, control RMS and
stability labels per point; folds (S-curves, FRCs) and cycle folds (PP-CBC continuation)
located on the measured curve; every failure with its reason.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bifid.cbc._campaign import Campaign, CampaignResult
from bifid.cbc._forced_measure import fold_points
from bifid.cbc._measured import Failure
from bifid.cbc._ppcbc import _first_harmonic_amplitude
from bifid.cbc._ppcbc_scan import ScanResult
from bifid.continuation import Branch, Diagram, SpecialPoint
from bifid.data import forced_dataset, lco_dataset

__all__ = ["amplitudes_of", "result_of", "retry_grid", "unanswered"]


def _stable(records: list[Any]) -> np.ndarray:
    return np.array([math.nan if r.stable is None else float(r.stable) for r in records])


def _rms(x: np.ndarray | None) -> float:
    return 0.0 if x is None else float(np.sqrt(np.mean(np.asarray(x, dtype=float) ** 2)))


def _folds(
    kind: str, params: np.ndarray, amps: np.ndarray, extra: dict[str, np.ndarray]
) -> list[SpecialPoint]:
    """Folds of the measured curve, located by splines through its points."""
    out = []
    for v, a, i in fold_points(params, amps):
        j = min(i + 1, len(params) - 1)
        data: dict[str, Any] = {"amplitude": a}
        for k, arr in extra.items():
            data[k] = float(np.interp(0.5, [0.0, 1.0], [arr[i], arr[j]]))
        out.append(
            SpecialPoint(
                kind=kind,
                param=v,
                index=i,
                bracket=(float(params[i]), float(params[j])),
                solution=np.zeros(0),
                precision=abs(float(params[j]) - float(params[i])) / 2.0,
                status="converged",
                data=data,
                verification={"method": "spline through measured points"},
            )
        )
    return out


def _lco_branch(
    camp: Campaign, records: list[Any], info: dict[str, Any], p: np.ndarray, signals: list[str]
) -> Branch:
    x1 = str(camp.spec.options.get("x1", signals[0]))
    n = len(records)
    amp = np.array([[r.extra.get(f"amp_{s}", math.nan) for s in signals] for r in records])
    off = np.array([[r.extra.get(f"offset_{s}", math.nan) for s in signals] for r in records])
    amp = amp.reshape(n, len(signals))
    params = np.array([r.param for r in records], dtype=float)
    freq = np.array([r.frequency for r in records], dtype=float)
    data = {
        "amplitude": amp,
        "offset": off.reshape(n, len(signals)),
        "frequency": freq,
        "period": 2.0 * np.pi / freq,
        "control_rms": np.array([_rms(r.control) for r in records]),
    }
    specials = []
    if info["label"] == "continuation" and n >= 4 and x1 in signals:
        specials = _folds(
            "cycle_fold", params, amp[:, signals.index(x1)], {"period": data["period"]}
        )
    return _branch(camp, info, params, records, specials, data, p, signals)


def _forced_branch(
    camp: Campaign, records: list[Any], info: dict[str, Any], p: np.ndarray
) -> Branch:
    n = len(records)
    key = "forcing" if camp.spec.protocol == "scurve" else "omega"
    params = np.array([getattr(r, key) for r in records], dtype=float)
    amp = np.array([r.amplitude for r in records], dtype=float)
    data = {
        "amplitude": amp,
        "phase": np.array([r.phase for r in records], dtype=float),
        "control_rms": np.array([_rms(r.control) for r in records]),
        "omega": np.array([r.omega for r in records], dtype=float),
        "forcing": np.array([r.forcing for r in records], dtype=float),
    }
    specials = _folds("fold", params, amp, {}) if n >= 4 else []
    return _branch(camp, info, params, records, specials, data, p, [])


def _branch(
    camp: Campaign,
    info: dict[str, Any],
    params: np.ndarray,
    records: list[Any],
    specials: list[SpecialPoint],
    data: dict[str, np.ndarray],
    p: np.ndarray,
    signals: list[str],
) -> Branch:
    """A measured branch (no unknowns: its points are records)."""
    return Branch(
        kind="measured",
        system=camp.spec.system,
        param=camp.spec.param,
        params=params,
        solutions=np.zeros((len(records), 0)),
        stable=_stable(records),
        special_points=specials,
        data=data,
        p=p,
        status=info["status"],
        message=info["message"],
        meta={"label": info["label"]},
        signals=tuple(signals),
    )


def result_of(camp: Campaign, resumed: int) -> CampaignResult:
    """The :class:`CampaignResult` of a finished (or stopped) campaign."""
    spec = camp.spec
    kw = dict(camp.dataset_kwargs)
    signals = [str(s) for s in kw.get("signal_names", [])]
    p = np.array([float(v) for v in spec.parameters.values()])
    branches = []
    infos = camp.branches or [
        {"label": spec.protocol, "status": "failed", "message": "nothing was measured"}
    ]
    for b, info in enumerate(infos):
        recs = [camp.records[i] for i in camp.points_of(b)]
        branches.append(
            _lco_branch(camp, recs, info, p, signals)
            if spec.protocol == "ppcbc"
            else _forced_branch(camp, recs, info, p)
        )
    kind = "bifurcation" if spec.protocol == "ppcbc" else spec.protocol
    units = dict(kw.get("signal_units") or {})
    if kw.get("param_units"):
        units[spec.param] = str(kw["param_units"])
    info: dict[str, Any] = {
        "protocol": spec.protocol,
        "n_points": len(camp.records),
        "resumed_from": resumed,
    }
    if spec.protocol != "ppcbc":
        info["observed"] = kw.get("observed")
        info["omega" if spec.protocol == "scurve" else "forcing"] = spec.fixed
    if camp.file is not None:
        info["out"] = str(camp.file.path)
    diagram = Diagram(
        kind=kind,
        system=spec.system,
        param=spec.param,
        branches=branches,
        source="measurement",
        units=units,
        settings=dict(kw.get("settings", {})),
        failures=[f.to_json() for f in camp.failures],
        warnings=list(camp.warnings),
        info=info,
    )
    dataset = None
    if camp.records:
        builder = lco_dataset if spec.protocol == "ppcbc" else forced_dataset
        dataset = builder(list(camp.records), **kw)
    return CampaignResult(diagram, dataset, list(camp.points), list(camp.failures), resumed)


# ------------------------------------------------------------- scans of one value
def retry_grid(grid: tuple[float, ...], failures: list[Failure]) -> tuple[float, ...]:
    """The amplitude grid of a repeated scan: from the grid point below the smallest
    amplitude where the first scan failed (a failed bracket, a rejected LCO, the target
    where it stopped) upwards, so that the other controller starts next to the LCOs the
    first did not measure (and need not hold the smaller targets it held); the whole grid
    when a failure has no amplitude."""
    where = []
    for f in failures:
        d = f.data
        if "bracket" in d:
            where.append(min(float(v) for v in d["bracket"]))
        elif "lco" in d:
            where.append(0.9 * float(d["lco"]))
        elif "a_star" in d:
            where.append(float(d["a_star"]))
        else:
            return tuple(grid)
    k = int(np.searchsorted(np.asarray(grid), min(where), side="right")) - 1
    return tuple(grid[max(min(k, len(grid) - 2), 0) :])


#: relative tolerance of the amplitude match between a failure and an LCO that answers it
ANSWER_TOL = 0.05


def unanswered(res: ScanResult, other: ScanResult, x1: str) -> list[Failure]:
    """The failures of the scan ``res`` (with ``x1`` its amplitude signal) that the other
    scan at the same value did not answer by measuring the LCO there: an LCO of ``other``
    whose first-harmonic amplitude of ``x1`` (the scan's ``A*``) lies in a failed bracket,
    within :data:`ANSWER_TOL` of a rejected LCO, or above the ``A*`` where the scan
    stopped (the rig tripped or the controller lost lock: the larger targets were not
    scanned); a failure without an amplitude (no oscillation started) is answered by an
    ``other`` that measured LCOs without failing."""
    amps = amplitudes_of(other.points, x1)
    out = []
    for f in res.failures:
        d = f.data
        if "bracket" in d:
            lo, hi = sorted(float(v) for v in d["bracket"])
            hit = any((1 - ANSWER_TOL) * lo <= a <= (1 + ANSWER_TOL) * hi for a in amps)
        elif "lco" in d:
            hit = any(abs(a - float(d["lco"])) <= ANSWER_TOL * float(d["lco"]) for a in amps)
        elif "a_star" in d:
            hit = any(a >= (1 - ANSWER_TOL) * float(d["a_star"]) for a in amps)
        else:
            hit = bool(amps) and not other.failures
        if not hit:
            out.append(f)
    return out


def amplitudes_of(points: list[Any], x1: str) -> list[float]:
    """The first-harmonic amplitude of ``x1`` of measured LCOs (a scan's ``A*``)."""
    return [
        _first_harmonic_amplitude(
            pt.measurement.signal(x1), pt.frequency, pt.measurement.sample_rate
        )
        for pt in points
    ]
