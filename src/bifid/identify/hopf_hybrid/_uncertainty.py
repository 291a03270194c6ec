r"""Intervals of a fitted hybrid model: jackknife over the measured orbits combined with the
ensemble over training seeds.

**Replicates.** With the hyperparameters the fit selected held fixed (L2 weight, stopping
iteration, criticality, quintic term, plane), the model is retrained :math:`n` times, each
time without one of the :math:`n` measured orbits (:func:`~._cv.refit_without`, one
ensemble member each). A quantity :math:`q` (Hopf speed and frequency, cycle-fold speed,
period and amplitudes, the amplitude of a branch at fixed parameter, :math:`\mu_0`,
:math:`a_2`, :math:`\omega_0`) is read off every replicate, :math:`q_{(i)}`, and off every
ensemble member of the full fit, :math:`q^{(s)}`.

**Variance.** The jackknife variance of the data (Efron & Stein) and the variance over
training seeds add:

.. math::

    \hat v_J = \frac{n-1}{n}\sum_{i=1}^{n}\bigl(q_{(i)} - \bar q_{(\cdot)}\bigr)^2,\qquad
    \hat v_S = \frac{1}{S-1}\sum_{s=1}^{S}\bigl(q^{(s)} - \bar q\bigr)^2,\qquad
    \mathrm{se}(q) = \sqrt{\hat v_J + \hat v_S}.

**Interval.** Around the prediction :math:`\hat q` of the primary member,

.. math:: \hat q \pm c\, t_{(1+\ell)/2,\,n-1}\,\mathrm{se}(q),

Student's :math:`t` with the :math:`n-1` degrees of freedom of the jackknife, and a
calibration factor :math:`c = 0.85` (:data:`SCALE`): the jackknife variance is biased
upwards (Efron–Stein), and without the factor the intervals over-covered at every level on
simulated diagrams with known truth (``benchmarks/bench_calibration.py --method hybrid``,
docs/uncertainty.md, where the factor is checked on fresh replications). A
replicate without the quantity (no fold, no cycle at that parameter) is left out; with
fewer than two replicates left, or where a replicate has no cycle on the branch at that
parameter (near a fold, within its interval), the interval is undefined (NaN).
"""

from __future__ import annotations

import math
import warnings
from typing import Any

import numpy as np

from bifid.continuation import Diagram
from bifid.errors import ConvergenceError
from bifid.identify._intervals import critical_value
from bifid.identify._records import LCOData
from bifid.identify.hopf_hybrid import _cycles as cy
from bifid.identify.hopf_hybrid._cv import refit_without
from bifid.identify.hopf_hybrid._normal_form import raw_a2
from bifid.identify.hopf_hybrid._state import HybridState

__all__ = [
    "SCALE",
    "add_intervals",
    "jackknife",
    "named_standard_errors",
    "omega0",
    "point_quantities",
    "standard_errors",
]

#: calibration factor of the jackknife intervals (module docstring): the jackknife variance
#: is biased upwards (Efron–Stein), and with t quantiles the intervals over-covered at every
#: level on the calibration benchmark's first 54 replications; validated on fresh seeds
SCALE = 0.85


def jackknife(model: Any, data: LCOData) -> list[HybridState]:
    """The replicates: ``model`` retrained without each record of ``data`` in turn
    (:func:`~._cv.refit_without`). A refit that does not converge is left out, with a
    warning."""
    out = []
    for i in range(len(data)):
        try:
            out.append(refit_without(model, data, i).state_)
        except ConvergenceError as exc:
            warnings.warn(
                f"the refit without record {i} ({data.param_name}={data.param[i]:g}) did not "
                f"converge and is left out of the intervals ({exc}).",
                UserWarning,
                stacklevel=3,
            )
    return out


def omega0(state: HybridState, s: int) -> float:
    """:math:`\\omega_0` of eq. 5.10 [rad/s] of member ``s``: the speed's constant term."""
    w0 = float(state.speed_params["w0"][s])
    return state.omega_scale * (math.exp(w0) if state.speed_config.form == "log" else w0)


def point_quantities(state: HybridState, s: int, n_signals: int) -> dict[str, np.ndarray]:
    """Hopf point, cycle fold and normal-form coefficients of member ``s`` (NaN where the
    member has no fold)."""
    h = cy.hopf_point(state, s)
    f = cy.cycle_fold(state, s)
    nan = np.full(n_signals, np.nan)
    return {
        "hopf.param": np.asarray(h["param"]),
        "hopf.omega": np.asarray(h["omega"]),
        "fold.param": np.asarray(f["param"] if f else np.nan),
        "fold.period": np.asarray(f["period"] if f else np.nan),
        "fold.amplitude": np.asarray(f["amplitude"] if f else nan, dtype=float),
        "mu0": np.asarray(h["param"]),
        "a2": np.asarray(raw_a2(state.a2(s), state.mu_s, state.q5)),
        "omega0": np.asarray(omega0(state, s)),
    }


def _se(jack: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, int]:
    """Standard error :math:`\\sqrt{\\hat v_J + \\hat v_S}` along axis 0 and the jackknife's
    degrees of freedom; NaN where fewer than two replicates are finite."""
    jack = np.asarray(jack, dtype=float)
    n = np.sum(np.isfinite(jack), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.nanmean(np.where(np.isfinite(jack), jack, np.nan), axis=0)
        vj = (n - 1) / n * np.nansum((jack - mean) ** 2, axis=0)
    seeds = np.asarray(seeds, dtype=float)
    vs = np.zeros_like(vj)
    if seeds.shape[0] > 1:
        ok = np.all(np.isfinite(seeds), axis=0)
        vs = np.where(ok, np.var(np.where(np.isfinite(seeds), seeds, 0.0), axis=0, ddof=1), 0.0)
    se = np.where(n >= 2, np.sqrt(vj + vs), np.nan)
    return se, int(np.max(n)) - 1 if np.size(n) else 0


def _collect(states: list[tuple[HybridState, int]], m: int) -> dict[str, np.ndarray]:
    rows = [point_quantities(st, s, m) for st, s in states]
    return {k: np.stack([r[k] for r in rows]) for k in rows[0]}


def standard_errors(
    state: HybridState, replicates: list[HybridState], keys: tuple[str, ...]
) -> dict[str, float]:
    """``se`` of the named scalar quantities of :func:`point_quantities` (module docstring)."""
    m = len(state.signal_names)
    jack = _collect([(r, 0) for r in replicates], m)
    seeds = _collect([(state, s) for s in range(state.n_members)], m)
    out = {}
    for k in keys:
        se, _ = _se(jack[k], seeds[k])
        out[k] = float(se)
    return out


def named_standard_errors(model: Any) -> dict[str, float]:
    """Standard errors by name of a fitted model's ``mu0``, ``a2``, ``omega0``,
    ``hopf_omega`` and, with a fold of cycles, ``fold`` (its :attr:`replicates_`)."""
    keys = {"mu0": "mu0", "a2": "a2", "omega0": "omega0", "hopf_omega": "hopf.omega"}
    if model.cycle_fold() is not None:
        keys["fold"] = "fold.param"
    se = standard_errors(model.state_, model.replicates_, tuple(keys.values()))
    return {k: se[v] for k, v in keys.items()}


def _interval(value: Any, se: np.ndarray, dof: int, level: float) -> tuple[Any, Any]:
    if dof < 1:
        half = np.full(np.shape(se), np.nan)
    else:
        half = SCALE * critical_value(level, dof) * np.asarray(se)
    v = np.asarray(value, dtype=float)
    return (v - half).tolist(), (v + half).tolist()


def _branch_amplitudes(
    state: HybridState, s: int, params: np.ndarray, stable: np.ndarray
) -> np.ndarray:
    """Amplitudes ``(n, m)`` of member ``s`` on the cycles at ``params`` with the given
    stability (NaN where the member has no such cycle)."""
    mu_t = state.mu_t(params)
    rho = cy.cycle_radii(state, s, mu_t, stable)
    out = np.full((len(params), len(state.signal_names)), np.nan)
    ok = np.isfinite(rho)
    out[ok] = cy.amplitudes(state, s, mu_t[ok], rho[ok])
    return out


def add_intervals(
    diagram: Diagram, state: HybridState, replicates: list[HybridState], level: float
) -> None:
    """Fill ``intervals`` of the diagram's Hopf point (``param``, ``omega``), cycle fold
    (``param``, ``period``, ``amplitude``) and cycle branch (``amplitude``) at ``level``
    and set ``diagram.level`` (module docstring)."""
    m = len(state.signal_names)
    jack = _collect([(r, 0) for r in replicates], m)
    seeds = _collect([(state, s) for s in range(state.n_members)], m)
    for b in diagram.branches:
        for sp in b.special_points:
            if sp.kind == "hopf":
                values = {"param": sp.param, "omega": sp.data["omega"]}
            elif sp.kind == "cycle_fold":
                values = {
                    "param": sp.param,
                    "period": sp.data["period"],
                    "amplitude": sp.data["amplitude"],
                }
            else:
                continue
            for key, value in values.items():
                q = f"{'hopf' if sp.kind == 'hopf' else 'fold'}.{key}"
                se, dof = _se(jack[q], seeds[q])
                sp.intervals[key] = _interval(value, se, dof, level)
        if b.kind != "periodic" or not len(b):
            continue
        amp = np.asarray(b.data["amplitude"], dtype=float)
        stable = np.asarray(b.stable, dtype=bool)
        jb = np.stack([_branch_amplitudes(r, 0, b.params, stable) for r in replicates])
        sb = np.stack(
            [_branch_amplitudes(state, s, b.params, stable) for s in range(state.n_members)]
        )
        se, dof = _se(jb, sb)
        # a replicate without the cycle there: the orbit may not exist at that parameter
        se = np.where(np.all(np.isfinite(jb), axis=0), se, np.nan)
        lo, hi = _interval(amp, se, dof, level)
        b.intervals["amplitude"] = (np.asarray(lo), np.asarray(hi))
    diagram.level = level
