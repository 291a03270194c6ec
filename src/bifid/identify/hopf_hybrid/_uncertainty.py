r"""Intervals of a fitted hybrid model: jackknife over the measured orbits combined with the
ensemble over training seeds.

**Replicates.** With the hyperparameters the fit selected held fixed (L2 weight, stopping
iteration, criticality, quintic term, plane), the model is retrained :math:`n` times, each
time without one of the :math:`n` measured orbits (:func:`~._cv.refit_without`, one
ensemble member each). A quantity :math:`q` (Hopf speed and frequency, cycle-fold speed,
period and amplitudes, the amplitude of a branch at fixed parameter, :math:`\mu_0`,
:math:`a_2`, :math:`\omega_0`) is read off every replicate, :math:`q_{(i)}`, and off the
ensemble members of the full fit, :math:`q^{(s)}`.

**Replicates measure the data, not the optimiser.** The estimator is a local minimiser
:math:`\hat\theta` of the training loss :math:`L(\theta) = \sum_j w_j \ell_j(\theta) +
\lambda\|\theta_{NN}\|^2` of the coordinate map, and the jackknife linearises it around
:math:`\hat\theta`: with orbit :math:`i` left out, the minimiser in the same basin is

.. math:: \hat\theta_{(i)} \approx \hat\theta + w_i H^{-1}\nabla\ell_i(\hat\theta),
    \qquad H = \nabla^2 L(\hat\theta),

the influence of orbit :math:`i`. A cold start from a random initialisation may instead
land in another local minimum, and one such replicate then sets the sum of squares below
alone (on the flutter model, refits 0.16–0.48 m/s away from five others that agree within
0.006 m/s). Every refit therefore starts from the full fit's reported member and trains
the map with the full fit's own iteration budget (L-BFGS) on the loss without orbit
:math:`i`: a descent from :math:`\hat\theta` that stays in its basin and converges to
:math:`\hat\theta_{(i)}` (the oscillation-speed and observation stages are refitted as
in the full fit, on the refit's phases). A shorter run does not get there: with 100
iterations instead of 540 the jackknife standard error of the flutter model's Hopf speed
was two thirds of the converged one (0.0084 against 0.0128 m/s on one dataset).
Likewise the seed term counts only the members in the best optimum: a member whose final
training loss exceeds :math:`(1 + \tau)` times the best member's (:data:`LOSS_TOLERANCE`,
:math:`\tau = 1`) is a different local minimum, not seed variability of the reported
estimator, and is left out (the reported member always counts; on that flutter dataset,
the member left out had 700 times the loss of the other two, which differ by 6 %).

**Variance.** The jackknife variance of the data (Efron & Stein) and the variance over
training seeds add:

.. math::

    \hat v_J = \frac{n-1}{n}\sum_{i=1}^{n}\bigl(q_{(i)} - \bar q_{(\cdot)}\bigr)^2,\qquad
    \hat v_S = \frac{1}{S-1}\sum_{s=1}^{S}\bigl(q^{(s)} - \bar q\bigr)^2,\qquad
    \mathrm{se}(q) = \sqrt{\hat v_J + \hat v_S}.

**Interval.** Around the prediction :math:`\hat q` of the primary member,

.. math:: \hat q \pm c\, t_{(1+\ell)/2,\,\nu}\,\mathrm{se}(q),\qquad \nu = \frac{n-1}{2},

Student's :math:`t` with half the :math:`n-1` degrees of freedom of the jackknife
(:data:`DOF_FRACTION`) and a calibration factor :math:`c = 1.03` (:data:`SCALE`), both
read off a tuning run of ``benchmarks/bench_calibration.py --tune-hybrid`` (simulated
diagrams with known truth, seeds not used to report coverage): the standardised errors
:math:`|\hat q - q|/\mathrm{se}` have heavier tails than :math:`t_{n-1}` (the jackknife
variance of eight replicates is itself a noisy estimate), and their quantiles at 50, 80,
90, 95 and 99 % are those of :math:`c\,t_{(n-1)/2}` with :math:`c` between 0.94 and 1.03
at every level, where :math:`t_{n-1}` would need factors rising from 1.02 to 1.39;
:math:`c` is the ratio at 95 %. The reported coverage is measured on other seeds
(docs/uncertainty.md). A replicate without the quantity (no fold, no cycle at that
parameter) is left out; with fewer than two replicates left, or where a replicate has no
cycle on the branch at that parameter (near a fold, within its interval), the interval is
undefined (NaN).
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
    "DOF_FRACTION",
    "LOSS_TOLERANCE",
    "SCALE",
    "add_intervals",
    "jackknife",
    "named_standard_errors",
    "omega0",
    "point_quantities",
    "seed_members",
    "standard_errors",
]

#: calibration factor of the jackknife intervals (module docstring), read off the tuning run
#: of the calibration benchmark (seeds 0..17 per case) at 95 %, validated on other seeds
SCALE = 1.03

#: the Student-t degrees of freedom of an interval are this fraction of the jackknife's
#: n - 1 (module docstring): the standardised errors of the tuning run follow t_{(n-1)/2}
DOF_FRACTION = 0.5

#: an ensemble member whose final training loss exceeds the best member's by more than this
#: fraction sits in another optimum and is left out of the seed term (module docstring)
LOSS_TOLERANCE = 1.0


def jackknife(model: Any, data: LCOData) -> list[HybridState]:
    """The replicates: ``model`` retrained without each record of ``data`` in turn, warm
    from the full fit (:func:`~._cv.refit_without`, module docstring). A refit that does
    not converge is left out, with a warning."""
    out = []
    for i in range(len(data)):
        try:
            out.append(refit_without(model, data, i, warm=True).state_)
        except ConvergenceError as exc:
            warnings.warn(
                f"the refit without record {i} ({data.param_name}={data.param[i]:g}) did not "
                f"converge and is left out of the intervals ({exc}).",
                UserWarning,
                stacklevel=3,
            )
    return out


def seed_members(model: Any) -> list[int]:
    """The ensemble members of the seed term: those whose final training loss of the map is
    within :data:`LOSS_TOLERANCE` of the best member's (module docstring); all members when
    the losses are not known."""
    n = model.state_.n_members
    final = np.asarray(getattr(model, "losses_", {}).get("map_final", []), dtype=float)
    if final.shape != (n,) or not np.all(np.isfinite(final)):
        return list(range(n))
    best = float(np.min(final))
    keep = [s for s in range(n) if final[s] <= best + LOSS_TOLERANCE * abs(best)]
    if model.state_.primary not in keep:  # the reported member always counts
        keep.append(model.state_.primary)
    return sorted(keep)


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
    state: HybridState,
    replicates: list[HybridState],
    keys: tuple[str, ...],
    members: list[int] | None = None,
) -> dict[str, float]:
    """``se`` of the named scalar quantities of :func:`point_quantities` (module docstring),
    the seed term over ``members`` (default: all)."""
    m = len(state.signal_names)
    jack = _collect([(r, 0) for r in replicates], m)
    members = list(range(state.n_members)) if members is None else members
    seeds = _collect([(state, s) for s in members], m)
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
    se = standard_errors(model.state_, model.replicates_, tuple(keys.values()), seed_members(model))
    return {k: se[v] for k, v in keys.items()}


def _interval(value: Any, se: np.ndarray, dof: int, level: float) -> tuple[Any, Any]:
    if dof < 1:
        half = np.full(np.shape(se), np.nan)
    else:
        half = SCALE * critical_value(level, DOF_FRACTION * dof) * np.asarray(se)
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


def add_intervals(diagram: Diagram, model: Any, level: float) -> None:
    """Fill ``intervals`` of the diagram's Hopf point (``param``, ``omega``), cycle fold
    (``param``, ``period``, ``amplitude``) and cycle branch (``amplitude``) of a model
    fitted with ``uncertainty=True`` at ``level`` and set ``diagram.level`` (module
    docstring)."""
    state, replicates = model.state_, model.replicates_
    members = seed_members(model)
    m = len(state.signal_names)
    jack = _collect([(r, 0) for r in replicates], m)
    seeds = _collect([(state, s) for s in members], m)
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
        sb = np.stack([_branch_amplitudes(state, s, b.params, stable) for s in members])
        se, dof = _se(jb, sb)
        # a replicate without the cycle there: the orbit may not exist at that parameter
        se = np.where(np.all(np.isfinite(jb), axis=0), se, np.nan)
        lo, hi = _interval(amp, se, dof, level)
        b.intervals["amplitude"] = (np.asarray(lo), np.asarray(hi))
    diagram.level = level
