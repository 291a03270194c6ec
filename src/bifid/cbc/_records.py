"""Converged CBC points as dataset records (:mod:`bifid.data`), and back for ``--resume``."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from bifid.cbc._controllers import EllipticTarget, FourierTarget, PolarTarget
from bifid.cbc._forced import ForcedPoint
from bifid.cbc._ppcbc import LCOPoint

__all__ = ["forced_record", "lco_record", "target_from_extra"]


def _target_extra(target: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if isinstance(target, PolarTarget):
        out["target_kind"] = "polar"
        T = target.matrix
        out["target_T11"], out["target_T12"] = float(T[0, 0]), float(T[0, 1])
        out["target_T21"], out["target_T22"] = float(T[1, 0]), float(T[1, 1])
        out["target_origin1"], out["target_origin2"] = target.origin
        for i, c in enumerate(target.coefficients):
            out[f"target_c{i}"] = float(c)
    elif isinstance(target, EllipticTarget):
        out["target_kind"] = "elliptic"
        out["target_amplitude"] = target.amplitude
        out["target_omega"] = target.omega
        out["target_origin1"], out["target_origin2"] = target.offset
    elif isinstance(target, FourierTarget):
        out["target_kind"] = "fourier"
        for i, c in enumerate(target.coefficients):
            out[f"target_c{i}"] = float(c)
    return out


def target_from_extra(extra: dict[str, Any]) -> Any:
    """Rebuild a target saved by :func:`lco_record` / :func:`forced_record` (or None)."""
    kind = extra.get("target_kind")
    coef = []
    i = 0
    while f"target_c{i}" in extra:
        coef.append(float(extra[f"target_c{i}"]))
        i += 1
    if kind == "polar" and coef:
        T = ((float(extra["target_T11"]), float(extra["target_T12"])),
             (float(extra["target_T21"]), float(extra["target_T22"])))
        return PolarTarget(np.array(coef), transform=T,
                           origin=(float(extra["target_origin1"]),
                                   float(extra["target_origin2"])))
    if kind == "elliptic":
        return EllipticTarget(float(extra["target_amplitude"]), float(extra["target_omega"]),
                              (float(extra["target_origin1"]), float(extra["target_origin2"])))
    if kind == "fourier" and coef:
        return FourierTarget(np.array(coef))
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
    extra.update(_target_extra(pt.target))
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
    extra.update(_target_extra(pt.target))
    q = (pt.coefficients.shape[0] - 1) // 2
    for i, c in enumerate(pt.coefficients):
        name = "A" if i <= q else "B"
        k = i if i <= q else i - q
        extra[f"response_{name}{k}"] = float(c)
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
