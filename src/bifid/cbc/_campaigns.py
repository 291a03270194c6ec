"""Whole CBC campaigns in one call: system → rig → protocol → dataset and diagram.

:func:`ppcbc_campaign` (self-excited systems, §3.3) and :func:`forced_campaign`
(S-curves and FRCs, §3.2) build the virtual rig and the protocol's options from the
system's CBC settings (:func:`bifid.cbc.defaults_for`: derived from the system,
overridden by ``System.cbc``, then by the caller), and run the campaign with the one
runner (:func:`bifid.cbc.run_campaign`). ``bifid cbc`` and ``bifid demo`` call these.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bifid.cbc._campaign import CampaignResult, CampaignSpec
from bifid.cbc._defaults import CBCDefaults, defaults_for
from bifid.cbc._forced_measure import ForcedCBCOptions, ForcedPoint
from bifid.cbc._rig import AbstractRig
from bifid.cbc._runner import run_campaign
from bifid.errors import BifidInputError
from bifid.io import run_info
from bifid.systems import System, get_system

__all__ = ["forced_campaign", "frc_cbc", "noise_levels", "ppcbc_campaign", "scurve_cbc"]


def _system(system: System | str, kind: str) -> System:
    s = get_system(system) if isinstance(system, str) else system
    if s.kind != kind:
        raise BifidInputError(
            f"{s.name!r} is {s.kind}; this campaign needs a {kind} system "
            f"({'ppcbc' if kind == 'autonomous' else 'scurve or frc'})."
        )
    return s


def noise_levels(
    noise: float | Mapping[str, float] | None,
    fraction: float | None,
    reference: Mapping[str, float],
    outputs: Sequence[str],
) -> dict[str, float] | None:
    """Noise standard deviation per output: absolute (one number or per output), or a
    ``fraction`` of the system's reference amplitudes."""
    if noise is not None and fraction is not None:
        raise BifidInputError("give noise (absolute std per signal) or noise_fraction, not both.")
    if fraction is not None:
        if not (math.isfinite(fraction) and fraction >= 0):
            raise BifidInputError(f"noise_fraction must be >= 0, got {fraction!r}.")
        missing = [n for n in outputs if n not in reference]
        if missing:
            raise BifidInputError(
                f"noise_fraction needs reference amplitudes of {missing}; "
                "give noise={signal: std} instead."
            )
        return {n: fraction * float(reference[n]) for n in outputs} if fraction > 0 else None
    if noise is None:
        return None
    if isinstance(noise, Mapping):
        unknown = sorted(set(noise) - set(outputs))
        if unknown:
            raise BifidInputError(
                f"noise names {unknown} are not outputs of the rig ({', '.join(outputs)})."
            )
        return {str(k): float(v) for k, v in noise.items()}
    return {n: float(noise) for n in outputs}


def _seed(seed: int | None, rig: AbstractRig) -> int:
    """The campaign's seed: the one given, else the rig's own."""
    return int(seed) if seed is not None else int(dict(rig.describe()).get("seed", 0) or 0)


def _provenance(command: str, **kw: Any) -> dict[str, Any]:
    return run_info(command, **kw)


def _values_and_span(
    values: Sequence[float] | None, span: tuple[float, float] | None, continuation: int
) -> tuple[tuple[float, ...], tuple[float, float]]:
    """The scan's values (none for a continuation) and the span ``(start, end)``."""
    if continuation:
        if span is None:
            if not values:
                raise BifidInputError("a PP-CBC continuation needs a range (start, end).")
            span = (float(values[0]), float(values[-1]))
        return (), (float(span[0]), float(span[1]))
    if not values:
        raise BifidInputError("a PP-CBC scan needs parameter values.")
    vals = tuple(float(v) for v in values)
    return vals, (vals[0], vals[-1])


def _default_step(lo: float, hi: float, param_scale: float) -> float:
    """The arclength step of a PP-CBC continuation over ``[lo, hi]`` by default: a fifth of
    the range in the weighted norm (the parameter over ``param_scale``, the target relative
    to the starting LCO), at most 0.5 — a narrow range (a short unstable branch between the
    start and the cycle fold) gets points along it, not one step across it."""
    return min(0.5, 0.2 * (hi - lo) / abs(float(param_scale))) if hi > lo else 0.5


def ppcbc_campaign(
    system: System | str,
    *,
    param: str | None = None,
    values: Sequence[float] | None = None,
    span: tuple[float, float] | None = None,
    continuation: int = 0,
    overrides: Mapping[str, float] | None = None,
    amplitudes: Sequence[float] | None = None,
    ds: float | None = None,
    param_scale: float = 1.0,
    noise: float | Mapping[str, float] | None = None,
    noise_fraction: float | None = None,
    seed: int | None = None,
    options: Mapping[str, Any] | None = None,
    rig: AbstractRig | None = None,
    rig_options: Mapping[str, Any] | None = None,
    out: str | Path | None = None,
    resume: bool = False,
    on_point: Callable[[Any], None] | None = None,
    on_evaluation: Callable[[int], None] | None = None,
    defaults: CBCDefaults | None = None,
) -> CampaignResult:
    """PP-CBC campaign on a virtual rig of ``system`` (thesis §3.3).

    Parameters
    ----------
    system : System or str
        An autonomous system.
    param : str, optional
        Bifurcation parameter (default: the system's).
    values : sequence of float
        Scan mode: the amplitude scan at each value in turn.
    span : (float, float)
        Continuation mode (``continuation > 0``): start at the first value, follow the
        branches towards the second, which with the first bounds them.
    continuation : int
        Points to measure by continuation (0: scan at ``values``).
    overrides : dict, optional
        Parameter values of the system.
    amplitudes : sequence of float, optional
        The scan's grid of target amplitudes (default: the system's CBC defaults).
    ds, param_scale : float
        Arclength step (weighted norm) and the parameter's scale in it; default ``ds``:
        a fifth of the range in that norm, at most 0.5.
    noise, noise_fraction
        Measurement noise: absolute std (one number or per output), or a fraction of the
        system's reference amplitudes (the smallest limit cycle of the range). With noise
        the records are four times longer.
    seed : int, optional
        Seed of the measurement noise (each step re-seeded from it); default: the rig's
        own seed (``rig.describe()["seed"]``), else 0.
    options : dict, optional
        Overrides of :class:`~bifid.cbc.PPCBCOptions` fields.
    rig : AbstractRig, optional
        Run on this rig instead of a virtual one built from the defaults.
    rig_options : dict, optional
        Extra keyword arguments of :class:`~bifid.cbc.VirtualRig`.
    out : path, optional
        Dataset written point by point; ``resume`` continues the campaign in it.

    Returns
    -------
    CampaignResult
    """
    s = _system(system, "autonomous")
    param = param or s.default_param
    s.index(param)
    over = dict(overrides or {})
    s.param_vector(over)
    vals, span = _values_and_span(values, span, continuation)
    lo, hi = sorted(span)
    ds = _default_step(lo, hi, param_scale) if ds is None else ds
    dflt = defaults or defaults_for(
        s, over, param=param, param_range=(lo, hi), noise_reference=noise_fraction is not None
    )
    nz = noise_levels(
        noise, noise_fraction, dflt.noise_reference, list(dflt.outputs or s.states[:1])
    )
    if rig is None:
        rig_kw = dict(noise=nz, seed=seed or 0, **dict(rig_options or {}))
        rig = dflt.rig(s, {**over, param: span[0]}, **rig_kw)
    seed = _seed(seed, rig)
    noisy = bool(nz) and any(v > 0 for v in nz.values())
    # with noise, four times the records: the random motion that the controller's noise
    # injects scatters an LCO's amplitude by ~0.5 % over 8 flutter periods near the Hopf
    # point (0.2 % over 16), more than its batch-means floor says
    kw: dict[str, Any] = dict(
        n_harmonics=10, measure_periods=(4.0 if noisy else 1.0) * dflt.measure_periods
    )
    kw.update(dict(options or {}))
    opts = dflt.ppcbc_options(**kw)
    grid = np.asarray(
        amplitudes
        if amplitudes is not None
        else np.linspace(*dflt.amplitude_range, dflt.n_amplitudes),
        dtype=float,
    )
    spec = CampaignSpec(
        system=s.name,
        protocol="ppcbc",
        parameters=s.param_dict(s.param_vector(over)),
        param=param,
        range=(float(span[0]), float(span[1])),
        options=opts.to_json(),
        rig=dict(rig.describe()),
        values=vals,
        continuation=int(continuation),
        amplitudes=tuple(float(a) for a in grid),
        seed=int(seed),
        ds=float(ds),
        param_scale=float(param_scale),
        omega_guess=float(dflt.omega_guess),
        max_points=int(continuation) if continuation else 200,
    )
    units = next((q.unit for q in s.parameters if q.name == param), "")
    kwargs = dict(signal_names=list(rig.output_names), param_name=param, param_units=units)
    kwargs.update(system=s.name, source=f"bifid PP-CBC campaign on {type(rig).__name__}")
    io = dict(out=out, resume=resume, on_point=on_point, on_evaluation=on_evaluation)
    return _run(spec, rig, dflt, kwargs, **io)


def forced_campaign(
    system: System | str,
    protocol: str = "scurve",
    *,
    omega: float | None = None,
    forcing: float | None = None,
    span: tuple[float, float] | None = None,
    options: Mapping[str, Any] | None = None,
    overrides: Mapping[str, float] | None = None,
    defaults: CBCDefaults | None = None,
    rig: AbstractRig | None = None,
    rig_options: Mapping[str, Any] | None = None,
    noise: float | Mapping[str, float] | None = None,
    seed: int | None = None,
    out: str | Path | None = None,
    resume: bool = False,
    on_point: Callable[[Any], None] | None = None,
    on_evaluation: Callable[[int], None] | None = None,
) -> CampaignResult:
    """Forced CBC on a virtual rig of ``system``: an S-curve at ``omega`` over the forcing
    ``span``, or an FRC at ``forcing`` over the frequency ``span`` (thesis §3.2).

    With noise the system's ``noisy_options`` apply (e.g. lower gains) before
    ``options``. Other parameters as :func:`ppcbc_campaign`.
    """
    s = _system(system, "forced")
    if protocol not in ("scurve", "frc"):
        raise BifidInputError(f"forced protocol must be scurve or frc, got {protocol!r}.")
    fixed = omega if protocol == "scurve" else forcing
    what = "omega" if protocol == "scurve" else "forcing"
    if fixed is None or not (math.isfinite(float(fixed)) and float(fixed) > 0):
        raise BifidInputError(f"{protocol} needs a positive {what}, got {fixed!r}.")
    if span is None:
        raise BifidInputError(
            f"{protocol} needs the range of the "
            f"{'forcing' if protocol == 'scurve' else 'frequency'}."
        )
    r0, r1 = (float(v) for v in span)
    if not (r0 > 0 and r1 > 0 and r0 != r1 and math.isfinite(r0) and math.isfinite(r1)):
        raise BifidInputError(f"the range must be two distinct positive numbers, got {span}.")
    if protocol == "scurve":
        r0, r1 = sorted((r0, r1))
    over = dict(overrides or {})
    s.param_vector(over)
    dflt = defaults or defaults_for(s, over)
    signal = (options or {}).get("signal") or dflt.signal or s.observed
    outputs = tuple(dict.fromkeys([signal, *(dflt.outputs or ())]))
    nz = noise_levels(noise, None, {}, outputs)
    if rig is None:
        rig = dflt.rig(
            s,
            over,
            **{"outputs": outputs, "noise": nz, "seed": seed or 0, **dict(rig_options or {})},
        )
    seed = _seed(seed, rig)
    noisy = bool(nz) and any(v > 0 for v in nz.values())
    opts = dflt.forced_options(noisy=noisy, **{"signal": signal, **dict(options or {})})
    scale = max(abs(r0), abs(r1)) if protocol == "scurve" else abs(r1 - r0)
    spec = CampaignSpec(
        system=s.name,
        protocol=protocol,
        parameters=s.param_dict(s.param_vector(over)),
        param="F" if protocol == "scurve" else "Omega",
        range=(r0, r1),
        options=opts.to_json(),
        rig=dict(rig.describe()),
        fixed=float(fixed),
        seed=int(seed),
        ds=float(opts.ds),
        param_scale=float(scale),
        max_points=int(opts.max_points),
    )
    kwargs = dict(
        signal_names=list(rig.output_names),
        observed=signal,
        system=s.name,
        source=f"bifid {protocol} CBC campaign on {type(rig).__name__}",
    )
    io = dict(out=out, resume=resume, on_point=on_point, on_evaluation=on_evaluation)
    return _run(spec, rig, dflt, kwargs, **io)


def _run(
    spec: CampaignSpec, rig: AbstractRig, dflt: CBCDefaults, kwargs: dict[str, Any], **io: Any
) -> CampaignResult:
    """:func:`run_campaign` with the dataset's units and the provenance of the settings."""
    kwargs["signal_units"] = {k: v for k, v in dflt.signal_units.items() if k in rig.output_names}
    return run_campaign(
        spec,
        rig,
        dataset_kwargs=kwargs,
        settings=_provenance("cbc", defaults_origin=dflt.origin),
        **io,
    )


def _on_rig(
    rig: AbstractRig,
    protocol: str,
    fixed: dict[str, float],
    span: tuple,
    options: ForcedCBCOptions | None,
) -> tuple[list[ForcedPoint], list]:
    r = forced_campaign(
        rig.system,
        protocol,
        span=span,
        rig=rig,
        options=(options or ForcedCBCOptions()).to_json(),
        **fixed,
    )
    return r.points, r.failures


def scurve_cbc(
    rig: AbstractRig,
    omega: float,
    forcing_range: tuple[float, float],
    options: ForcedCBCOptions | None = None,
) -> tuple[list[ForcedPoint], list]:
    """An S-curve on a virtual ``rig`` (:func:`forced_campaign`): ``(points, failures)``."""
    return _on_rig(rig, "scurve", {"omega": omega}, forcing_range, options)


def frc_cbc(
    rig: AbstractRig,
    forcing: float,
    omega_range: tuple[float, float],
    options: ForcedCBCOptions | None = None,
) -> tuple[list[ForcedPoint], list]:
    """An FRC on a virtual ``rig`` (:func:`forced_campaign`): ``(points, failures)``."""
    return _on_rig(rig, "frc", {"forcing": forcing}, omega_range, options)
