"""The bifurcation diagram of a fitted hybrid model, and the spread of its ensemble."""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from bifid.continuation import Branch, Diagram, SpecialPoint
from bifid.identify.hopf_hybrid._cycles import (
    amplitudes,
    branch_samples,
    cycle_fold,
    hopf_point,
    period,
    radius2,
)
from bifid.identify.hopf_hybrid._state import HybridState

__all__ = ["ensemble_spread", "hybrid_diagram"]


def _special(
    kind: str, param: float, index: int, solution: Any, data: dict[str, Any]
) -> SpecialPoint:
    return SpecialPoint(
        kind=kind,
        param=param,
        index=index,
        bracket=(param, param),
        solution=np.asarray(solution, dtype=float),
        precision=0.0,
        status="converged",
        data=data,
        verification={"method": "closed form of eq. 5.3"},
    )


def hybrid_diagram(
    state: HybridState, s: int, lo: float, hi: float, n_points: int, source: str
) -> Diagram:
    """The cycle branch of member ``s`` over ``[lo, hi]`` with its Hopf point and fold.

    One branch, sampled uniformly in the normal-form radius from the Hopf point (so the
    fold is passed smoothly); ``floquet_max`` is :math:`\\exp(T\\,\\partial_\\rho\\dot\\rho)`
    of the normal form (> 1 unstable). The Hopf point and the fold are closed-form
    (``precision`` 0).
    """
    mu, rho, deriv = branch_samples(
        state, s, float(state.mu_t(lo)), float(state.mu_t(hi)), max(int(n_points), 3)
    )
    m = len(state.signal_names)
    T = period(state, s, rho, mu) if len(rho) else np.zeros(0)
    amps = amplitudes(state, s, mu, rho) if len(rho) else np.zeros((0, m))
    with np.errstate(over="ignore", invalid="ignore"):
        fm = np.exp(np.clip(deriv * state.mu_s * T, -700, 700))
    # back from normal-form units; clipped: the round trip can land an ulp outside
    params = np.clip(state.raw(mu), lo, hi)
    specials = []
    h = hopf_point(state, s)
    if lo <= h["param"] <= hi:
        specials.append(
            _special(
                "hopf",
                h["param"],
                0,
                h["state"],
                {k: h[k] for k in ("omega", "lyapunov", "criticality")},
            )
        )
    fold = cycle_fold(state, s)
    if fold is not None and lo <= fold["param"] <= hi and len(rho):
        i = int(np.clip(np.searchsorted(rho, fold["rho"]) - 1, 0, max(len(rho) - 1, 0)))
        specials.append(
            _special(
                "cycle_fold",
                fold["param"],
                i,
                np.zeros(0),
                {"period": fold["period"], "amplitude": fold["amplitude"]},
            )
        )
    branch = Branch(
        kind="periodic",
        system=source,
        param=state.param_name,
        params=params,
        solutions=np.zeros((len(rho), 0)),
        stable=deriv < 0,
        special_points=specials,
        data={"period": T, "amplitude": amps, "floquet_max": fm, "radius": rho},
        p=np.zeros(0),
        status="range",
        message="",
        signals=tuple(state.signal_names),
        meta={"member": s},
    )
    units = {state.param_name: state.param_units, **state.signal_units}
    return Diagram(
        kind="bifurcation",
        system=source,
        param=state.param_name,
        branches=[branch],
        source=source,
        units=units,
    )


def ensemble_spread(state: HybridState, lo: float, hi: float, n_points: int = 50) -> dict[str, Any]:
    """Spread of the ensemble over training seeds (not a confidence interval).

    Per branch ("outer", and "inner" with the quintic term), on a parameter grid: the
    minimum, median and maximum over the members of each signal's amplitude, and how many
    members have a cycle there; the spread of the Hopf and fold parameters.
    """
    grid = np.linspace(lo, hi, n_points)
    out: dict[str, Any] = {"param": grid.tolist(), "branches": {}}
    for root in (1.0, -1.0) if state.q5 else (1.0,):
        vals = np.full((state.n_members, n_points, len(state.signal_names)), np.nan)
        for s in range(state.n_members):
            for k, m in enumerate(state.mu_t(grid)):
                r2 = radius2(state, s, float(m), root)
                if r2 is not None:
                    vals[s, k] = amplitudes(state, s, np.array([m]), np.array([math.sqrt(r2)]))[0]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            out["branches"]["outer" if root > 0 else "inner"] = {
                sig: {
                    "min": _nan_list(np.nanmin(vals[:, :, j], axis=0)),
                    "median": _nan_list(np.nanmedian(vals[:, :, j], axis=0)),
                    "max": _nan_list(np.nanmax(vals[:, :, j], axis=0)),
                    "count": np.sum(np.isfinite(vals[:, :, j]), axis=0).tolist(),
                }
                for j, sig in enumerate(state.signal_names)
            }
    folds = [f["param"] for s in range(state.n_members) if (f := cycle_fold(state, s))]
    out["hopf_param"] = spread([hopf_point(state, s)["param"] for s in range(state.n_members)])
    out["fold_param"] = spread(folds) if folds else None
    return out


def spread(values: Any) -> dict[str, float]:
    """Median, minimum, maximum and standard deviation over ensemble members."""
    v = np.asarray(values, dtype=float)
    return {
        "median": float(np.median(v)),
        "min": float(np.min(v)),
        "max": float(np.max(v)),
        "std": float(np.std(v)),
    }


def _nan_list(v: np.ndarray) -> list:
    return [float(x) if np.isfinite(x) else None for x in v]
