"""Converged CBC points as dataset records (:mod:`bifid.data`).

Besides the signals, a record keeps per point the centred amplitudes and offsets
(``amp_<signal>``, ``offset_<signal>``), the quality of the measurement (invasiveness,
residual, iterations, stability growth) and, as JSON strings, the converged target
(``target``, see :func:`target_from_json`) and for forced points the response's Fourier
coefficients (``response``, eq. 3.4 ordering).
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np

from bifid.cbc._controllers import EllipticTarget, FourierTarget, PolarTarget, target_to_json
from bifid.cbc._forced_measure import ForcedPoint
from bifid.cbc._ppcbc import LCOPoint

__all__ = ["forced_record", "lco_record", "target_from_json"]


def target_from_json(d: dict[str, Any] | None) -> Any:
    """Rebuild a target from :func:`~bifid.cbc._controllers.target_to_json` (or None)."""
    if not d:
        return None
    if d["kind"] == "polar":
        T = [[float(v) for v in row] for row in d["transform"]]
        return PolarTarget(
            np.array(d["coefficients"], dtype=float),
            transform=((T[0][0], T[0][1]), (T[1][0], T[1][1])),
            origin=(float(d["origin"][0]), float(d["origin"][1])),
        )
    if d["kind"] == "elliptic":
        return EllipticTarget(
            float(d["amplitude"]), float(d["omega"]), (float(d["offset"][0]), float(d["offset"][1]))
        )
    if d["kind"] == "fourier":
        return FourierTarget(np.array(d["coefficients"], dtype=float))
    return None


def _finite(v: float) -> float:
    return float(v) if v is not None and math.isfinite(float(v)) else float("nan")


def lco_record(pt: LCOPoint, protocol: str):
    """An :class:`bifid.data.LCORecord` of a PP-CBC point.

    Signals are centred (the offsets go to ``extra["offset_<signal>"]``); the
    Fourier-filtered amplitudes (robust to noise) go to ``extra["amp_<signal>"]``.
    """
    from bifid.data import LCORecord

    m = pt.measurement
    names = m.output_names
    offsets = np.array([pt.offset[n] for n in names])
    extra: dict[str, Any] = {
        "protocol": protocol,
        "branch": pt.branch,
        "invasiveness": _finite(pt.invasiveness),
        "invasiveness_periodic": _finite(pt.invasiveness_periodic),
        "tracking_error": _finite(pt.tracking_error),
        "residual": _finite(pt.residual),
        "iterations": int(pt.iterations),
        "growth": _finite(pt.growth),
        "t_start": float(m.time[0]),
    }
    for n in names:
        extra[f"offset_{n}"] = float(pt.offset[n])
        extra[f"amp_{n}"] = float(pt.amplitude[n])
    extra["target"] = json.dumps(target_to_json(pt.target))
    target = None
    if np.all(np.isfinite(m.target)):
        # the target is x1*: centre it like x1 (when x1 is an output)
        target = m.target - float(pt.offset.get(pt.signal, 0.0))
    return LCORecord(
        param=pt.param,
        signals=m.outputs - offsets[None, :],
        sample_rate=m.sample_rate,
        stable=pt.stable,
        control=m.control,
        target=target,
        frequency=pt.frequency,
        extra=extra,
    )


def forced_record(pt: ForcedPoint, protocol: str, curve: int = 0):
    """A :class:`bifid.data.ForcedRecord` of a forced-CBC point."""
    from bifid.data import ForcedRecord

    m = pt.measurement
    extra: dict[str, Any] = {
        "protocol": protocol,
        "force_phase": float(pt.force_phase),
        "invasiveness": _finite(pt.invasiveness),
        "residual": _finite(pt.residual),
        "iterations": int(pt.iterations),
        "growth": _finite(pt.growth),
        "t_start": float(m.time[0]),
    }
    extra["target"] = json.dumps(target_to_json(pt.target))
    extra["response"] = json.dumps([float(c) for c in pt.coefficients])
    return ForcedRecord(
        omega=pt.omega,
        forcing=pt.forcing,
        signals=m.outputs,
        sample_rate=m.sample_rate,
        stable=pt.stable,
        force=m.force,
        control=m.control,
        target=m.target,
        amplitude=pt.amplitude,
        phase=pt.phase,
        curve=curve,
        extra=extra,
    )
