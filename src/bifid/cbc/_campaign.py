"""Whole virtual CBC campaigns in one call: rig, protocol, dataset (``bifid demo`` uses these).

- :func:`lco_campaign` -- PP-CBC on a self-excited system (thesis §3.3): the amplitude
  scan (§3.3.3.2) at one parameter value stops at the first (smallest) LCO on its grid
  (for ``flutter`` at ``U = 17.5`` m/s the unstable one), then Newton–Broyden +
  pseudo-arclength in the parameter (Example 3.3) follows the branch from it, round the
  cycle fold and back along the stable branch. This is far cheaper per LCO than scanning
  at every parameter value (one finite-difference Jacobian for the whole branch, two to
  five rig evaluations per point): 14 flutter LCOs in ~2 min against ~5 min for 11 by
  scans (``BENCHMARKS.md``, "cbc").
- :func:`scurve_campaign` -- forced CBC S-curves (§3.2.1) at one or more frequencies.

Both build the virtual rig from :func:`bifid.cbc.defaults_for` (gains, signals, sample
rate), write every converged point to ``out`` as soon as it exists (if given) and return
the :mod:`bifid.data` dataset with the points and failures. Failures are never recorded.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bifid.cbc._defaults import defaults_for
from bifid.errors import BifidInputError, ConvergenceError

__all__ = ["lco_campaign", "scurve_campaign"]


def _noise_map(noise: float | Mapping[str, float] | None, fraction: float | None,
               reference: Mapping[str, float], outputs: Sequence[str]) -> dict | None:
    if noise is not None and fraction is not None:
        raise BifidInputError("give noise (absolute std per signal) or noise_fraction, not both.")
    if fraction is not None:
        if not (math.isfinite(fraction) and fraction >= 0):
            raise BifidInputError(f"noise_fraction must be >= 0, got {fraction!r}.")
        missing = [n for n in outputs if n not in reference]
        if missing:
            raise BifidInputError(f"noise_fraction needs reference amplitudes of {missing}; "
                                  "give noise={signal: std} instead.")
        return {n: fraction * reference[n] for n in outputs} if fraction > 0 else None
    if noise is None:
        return None
    if isinstance(noise, Mapping):
        return {str(k): float(v) for k, v in noise.items()}
    return {n: float(noise) for n in outputs}


def lco_campaign(
    system: str = "flutter",
    param: str | None = None,
    start: float = 17.5,
    *,
    overrides: Mapping[str, float] | None = None,
    amplitudes: Sequence[float] | None = None,
    n_points: int = 10,
    ds: float = 0.8,
    direction: int = -1,
    bounds: tuple[float, float] | None = None,
    param_scale: float = 1.0,
    noise: float | Mapping[str, float] | None = None,
    noise_fraction: float | None = None,
    seed: int = 0,
    n_harmonics: int = 10,
    options: Mapping[str, Any] | None = None,
    rig_options: Mapping[str, Any] | None = None,
    out: str | Path | None = None,
    on_point: Callable[[Any], None] | None = None,
):
    """PP-CBC campaign on a virtual rig: scan at ``start``, then continuation in ``param``.

    Parameters
    ----------
    system : str
        Registered autonomous system with PP-CBC defaults (``flutter``, ``hopf``).
    param : str, optional
        Bifurcation parameter (default: the system's default parameter).
    start : float
        Parameter value of the amplitude scan. The scan stops at the first (smallest)
        LCO on the grid and the continuation starts from it.
    amplitudes : sequence of float, optional
        Scan grid of target amplitudes (default: the system's CBC defaults); it needs
        to bracket one LCO only (e.g. ``np.linspace(0.005, 0.011, 4)`` for the unstable
        flutter LCO at 17.5 m/s).
    n_points : int
        LCOs in all: the scan's first one plus ``n_points - 1`` continuation points
        (``n_points = 1``: scan only, every LCO on the grid).
    ds, direction, bounds, param_scale
        Pseudo-arclength step (weighted norm), initial direction of the parameter, range
        the branch must stay in, and the parameter's scale in the arclength norm
        (:func:`bifid.cbc.ppcbc_continuation`).
    noise, noise_fraction
        Measurement noise: absolute standard deviation (one number or per signal), or a
        fraction of the system's reference amplitudes (for ``flutter``: the smallest LCO
        of the U = 15-17.5 m/s diagram, h = 7.43 mm, α = 0.0216 rad).
    seed : int
        Seed of the measurement noise.
    n_harmonics : int
        ``n_h`` of the polar target.
    options : mapping, optional
        Overrides of :class:`~bifid.cbc.PPCBCOptions` fields.
    rig_options : mapping, optional
        Extra keyword arguments of :class:`~bifid.cbc.VirtualRig` (e.g.
        ``record_states=True`` to keep the true states in ``measurement.extra``).
    out : path, optional
        netCDF file to append each point to as soon as it converges (must not exist).

    Returns
    -------
    dataset : xarray.Dataset
        ``bifid_kind = "lco"`` dataset of every converged LCO, sorted by branch order.
    points : list of LCOPoint
    failures : list of PPCBCFailure
    """
    from bifid.cbc._ppcbc import PPCBCFailure, ppcbc_continuation, ppcbc_scan
    from bifid.cbc._records import lco_record
    from bifid.data import append_record, lco_dataset

    s, dflt = _system(system, "autonomous")
    param = param or s.default_param
    s.index(param)
    over = {**dict(overrides or {}), param: float(start)}
    s.param_vector(over)  # validates names and values
    if out is not None and Path(out).exists():
        raise BifidInputError(f"{out} exists; choose another out (campaigns never overwrite).")
    if direction not in (-1, 1):
        raise BifidInputError(f"direction must be +1 or -1, got {direction!r}.")
    if int(n_points) < 1:
        raise BifidInputError(f"n_points must be >= 1, got {n_points!r}.")
    outputs = dflt.outputs or tuple(st.name for st in s.states[:2])
    nz = _noise_map(noise, noise_fraction, dflt.extra.get("noise_reference", {}), outputs)
    rig = dflt.rig(s, over, noise=nz, seed=seed, **dict(rig_options or {}))
    kw: dict[str, Any] = dict(n_harmonics=int(n_harmonics),
                              measure_periods=2.0 * dflt.measure_periods if nz
                              else dflt.measure_periods)
    kw.update(dict(options or {}))
    opts = dflt.ppcbc_options(**kw)
    grid = np.asarray(amplitudes if amplitudes is not None
                      else np.linspace(*dflt.amplitude_range, dflt.n_amplitudes), dtype=float)
    lo_b, hi_b = bounds if bounds is not None else (-math.inf, math.inf)
    units = next((q.unit for q in s.parameters if q.name == param), "")
    settings = _settings(protocol="ppcbc-campaign", system=system, param=param, start=start,
                         amplitude_grid=grid.tolist(), n_points=n_points, ds=ds,
                         direction=direction, bounds=[lo_b, hi_b], param_scale=param_scale,
                         options=opts.to_json(), rig=rig.describe(), noise=nz, seed=seed,
                         parameters=s.param_dict(s.param_vector(over)))
    ds_kwargs = dict(signal_names=list(rig.output_names), param_name=param, param_units=units,
                     system=system, settings=settings,
                     source=f"bifid.cbc.lco_campaign({system!r}) on a virtual rig",
                     signal_units={k: v for k, v in dflt.signal_units.items()
                                   if k in rig.output_names})
    points: list[Any] = []

    def keep(pt) -> None:
        points.append(pt)
        if out is not None:
            append_record(out, lco_record(pt, "ppcbc"), **ds_kwargs)
        if on_point is not None:
            on_point(pt)

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        # the scan stops at the first (smallest) LCO with the rig holding it: the
        # continuation starts from there (larger amplitudes are reached round the fold)
        found, failures = ppcbc_scan(rig, param, float(start), grid, opts,
                                     omega_guess=dflt.omega_guess, on_point=keep,
                                     max_points=1 if n_points > 1 else None)
        if not found:
            failures.append(PPCBCFailure(float(start), "the scan found no LCO to start the "
                                         "continuation from (amplitude grid too narrow?)"))
        elif n_points > 1:
            first = found[0]
            _more, fails = ppcbc_continuation(
                rig, param, first, opts, ds=ds, n_points=int(n_points), direction=direction,
                bounds=(lo_b, hi_b), param_scale=param_scale, on_point=keep)
            failures += fails
    recs = [lco_record(p, "ppcbc") for p in points]
    data = lco_dataset(recs, **ds_kwargs)
    return data, points, failures


def scurve_campaign(
    system: str = "shaw_pierre",
    omegas: float | Sequence[float] = 1.005,
    forcing_range: tuple[float, float] = (0.001, 0.02),
    *,
    overrides: Mapping[str, float] | None = None,
    noise: float | Mapping[str, float] | None = None,
    seed: int = 0,
    options: Mapping[str, Any] | None = None,
    rig_options: Mapping[str, Any] | None = None,
    out: str | Path | None = None,
    on_point: Callable[[Any], None] | None = None,
    scale_to_range: bool = False,
):
    """Forced CBC S-curves (thesis §3.2.1) on a virtual rig, one per frequency.

    Parameters
    ----------
    system : str
        Registered forced system (``shaw_pierre``, ``duffing``).
    omegas : float or sequence of float
        Forcing frequencies [rad/s]; one S-curve each (``curve`` id = its index).
    forcing_range : (float, float)
        Forcing amplitudes ``γ`` the S-curves span.
    noise : float or mapping, optional
        Measurement noise std (one number or per output). With noise the system's
        ``noisy_options`` (:func:`bifid.cbc.defaults_for`; e.g. lower gains on
        ``shaw_pierre``) apply before ``options``.
    options : mapping, optional
        Overrides of :class:`~bifid.cbc.ForcedCBCOptions` fields (e.g. ``precision``,
        ``max_measure_periods``: how precisely each point must be verified against the
        noise, and the longest record allowed for it).
    rig_options : mapping, optional
        Extra keyword arguments of :class:`~bifid.cbc.VirtualRig`.
    out : path, optional
        netCDF file to append each point to as soon as it converges (must not exist).
    scale_to_range : bool
        Arclength steps scaled to the forcing range rather than to the first point
        (:func:`~bifid.cbc.scurve_cbc`): noisy S-curves start high in their range and
        otherwise cross the lower branch in few steps (shaw_pierre, 1 % noise: 5-8
        points below the first fold instead of 2, for up to 2× the points and wall time;
        off by default, see ``notes/issue-3.md``, session 3b).

    Returns
    -------
    dataset : xarray.Dataset
        ``bifid_kind = "forced"`` dataset (``curve`` = index of the frequency).
    points : list of list of ForcedPoint
        Per frequency.
    failures : list of ForcedFailure

    Raises
    ------
    ConvergenceError
        If not a single point converged (the failures are in the message).
    """
    from bifid.cbc._forced import scurve_cbc
    from bifid.cbc._records import forced_record
    from bifid.data import append_record, forced_dataset

    s, dflt = _system(system, "forced")
    over = dict(overrides or {})
    s.param_vector(over)
    if out is not None and Path(out).exists():
        raise BifidInputError(f"{out} exists; choose another out (campaigns never overwrite).")
    oms = [float(omegas)] if np.isscalar(omegas) else [float(w) for w in omegas]
    if not oms or not all(w > 0 and math.isfinite(w) for w in oms):
        raise BifidInputError(f"omegas must be positive numbers, got {omegas!r}.")
    signal = dflt.signal or s.observed
    outputs = tuple(dict.fromkeys([signal, *(dflt.outputs or ())]))
    nz = _noise_map(noise, None, {}, outputs)
    rig = dflt.rig(s, over, **{"outputs": outputs, "noise": nz, "seed": seed,
                               **dict(rig_options or {})})
    opts = dflt.forced_options(noisy=bool(nz) and any(v > 0 for v in nz.values()),
                               **{"signal": signal, **dict(options or {})})
    settings = _settings(protocol="scurve-campaign", system=system, omegas=oms,
                         forcing_range=list(forcing_range), options=opts.to_json(),
                         rig=rig.describe(), noise=nz, seed=seed,
                         parameters=s.param_dict(s.param_vector(over)))
    ds_kwargs = dict(signal_names=list(rig.output_names), observed=signal, system=system,
                     settings=settings,
                     source=f"bifid.cbc.scurve_campaign({system!r}) on a virtual rig")
    curves: list[list[Any]] = []
    recs: list[Any] = []
    failures: list[Any] = []
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        for k, w in enumerate(oms):
            pts: list[Any] = []

            def keep(pt, _k=k, _pts=pts) -> None:
                _pts.append(pt)
                rec = forced_record(pt, "scurve", curve=_k)
                recs.append(rec)
                if out is not None:
                    append_record(out, rec, **ds_kwargs)
                if on_point is not None:
                    on_point(pt)

            _p, fails = scurve_cbc(rig, w, tuple(forcing_range), opts, on_point=keep,
                                   scale_to_range=scale_to_range)
            failures += fails
            curves.append(pts)
    if not recs:
        why = "; ".join(f"Ω={f.omega:g}: {f.reason}" for f in failures) or "no reason given"
        raise ConvergenceError(f"the S-curve campaign on {system!r} converged no point ({why}).")
    data = forced_dataset(recs, **ds_kwargs)
    return data, curves, failures


def _system(name: str, kind: str):
    from bifid.systems import get_system

    s = get_system(name)
    if s.kind != kind:
        raise BifidInputError(f"{name!r} is {s.kind}; this campaign needs a {kind} system.")
    return s, defaults_for(name)


def _settings(**kw: Any) -> dict[str, Any]:
    try:
        from bifid.io import run_info

        return run_info("cbc-campaign", **kw)
    except Exception:  # the CLI is optional: settings without its run info
        return dict(kw)
