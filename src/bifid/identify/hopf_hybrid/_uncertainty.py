r"""Intervals of a fitted hybrid model: bootstrap of the measurement noise at the measured
orbits combined with the ensemble over training seeds.

**What varies.** The measured orbits sit at parameter values the experimenter chose; what
changes from one campaign at those values to the next is the noise on every sample (and,
through the optimiser, where training stops). So the replicates resample the noise and keep
the orbits (a residual bootstrap for a fixed design, Efron & Tibshirani 1993, §9.5). Each
record :math:`x_i(t_j)` of orbit :math:`i` (all signals, samples :math:`j = 1..N_i`) is
split into its periodic part, the least-squares Fourier series of
:data:`NOISE_HARMONICS` harmonics at the record's frequency :math:`\omega_i`
(:func:`bifid.signal.fourier_fit`, :func:`bifid.signal.fourier_fit_columns`), and the residual:

.. math:: x_i(t_j) = \hat p_i(t_j) + \hat e_{ij},\qquad
    x^{*b}_i(t_j) = \hat p_i(t_j) + \sqrt{\frac{N_i}{N_i - P}}\;\hat e_{i J_{ij}^b},\qquad
    J_{ij}^b \sim \mathcal U\{1..N_i\},

a bootstrap record draws the residuals of the same record with replacement (one draw per
sample, all signals of a sample together, so their correlation is kept; the noise is
taken as white over time), inflated for the :math:`P = 2K + 1` coefficients of the
series fitted to them (modified residuals, Davison & Hinkley 1997, eq. 6.9, with the
leverage :math:`P/N_i` of a Fourier basis on uniform samples; 12 % on a record of 200
samples, nothing on the rig's thousands). The model is retrained on every bootstrap dataset
:math:`b = 1..B` (:data:`N_BOOTSTRAP`) with the hyperparameters the fit selected held fixed
(L2 weight, stopping iteration, criticality, quintic term, plane, number of polar
harmonics; one ensemble member, :func:`~._cv.refit` on all orbits), and a quantity
:math:`q` (Hopf speed and frequency, cycle-fold speed, period and amplitudes, the
amplitude of a branch at fixed parameter, :math:`\mu_0`, :math:`a_2`, :math:`\omega_0`) is
read off every replicate, :math:`q^{*b}`, and off the ensemble members of the full fit,
:math:`q^{(s)}`.

**What a replicate recomputes.** Everything that reads the resampled samples: the
normalisation and whitening of the plane, each orbit's whole turns, centroid, polar
coefficients, covariance and frequency (:mod:`._prepare`), and all training stages. A
replicate is therefore the fit a from-scratch training with those hyperparameters would
compute on the resampled records, with one exception by design: the number of polar
harmonics (``n_harmonics="auto"``) is the fit's. Chosen afresh it reads the noise floor
of the resampled records and jumps (on the flutter calibration datasets 8 for the fit, 7
or 15 for some replicates; on noisy analytic cycles anywhere from 4 to 20), so such a
replicate would be another model, not the same estimator on other noise. The records'
measured amplitudes, which only the reported model keeps, are not recomputed.

**Why not the orbits.** A jackknife over the orbits (refits without one orbit each)
measures how the estimate depends on *which* orbits were measured: its
variance :math:`\frac{n-1}{n}\sum_i (q_{(i)} - \bar q_{(\cdot)})^2` scales every
replicate's shift by :math:`n - 1`, and without the orbit nearest to the Hopf point the
Hopf point is an extrapolation. On the flutter model (eight orbits, records of 2 s at
5 kHz, 1 % noise) that shift is real but deterministic — the refit without the stable
orbit nearest the Hopf point put it 0.02–0.06 m/s below the other refits on every one of
ten datasets (on one, −0.044 m/s from the fit, and −0.032 m/s after three times the
iterations: not an optimiser artefact) — while the noise moves the estimate by a few mm/s, and the
jackknife's 95 % intervals were 13 to 100 times as wide as the median errors
(``bench_calibration.py --tune-hybrid``). The bootstrap keeps the design and varies what
does vary.

**Replicates measure the data, not the optimiser.** The estimator is a local minimiser
:math:`\hat\theta` of the training loss of the coordinate map; a refit from a random
initialisation may land in another local minimum, and one such replicate would set the
variance alone. Every refit therefore starts from the full fit's reported member and
trains with the full fit's own iteration budget (L-BFGS) on the resampled records: a
descent from :math:`\hat\theta` that stays in its basin (the oscillation-speed and
observation stages are refitted as in the full fit). Likewise the seed term counts only
the members in the best optimum: a member whose final training loss exceeds
:math:`(1 + \tau)` times the best member's (:data:`LOSS_TOLERANCE`, :math:`\tau = 1`) is a
different local minimum, not seed variability of the reported estimator, and is left out
(the reported member always counts).

**Variance.** The bootstrap variance of the noise and the variance over training seeds
add:

.. math::

    \hat v_B = \frac{1}{B-1}\sum_{b=1}^{B}\bigl(q^{*b} - \bar q^{*}\bigr)^2,\qquad
    \hat v_S = \frac{1}{S-1}\sum_{s=1}^{S}\bigl(q^{(s)} - \bar q\bigr)^2,\qquad
    \mathrm{se}(q) = \sqrt{\hat v_B + \hat v_S}.

**Interval.** Around the prediction :math:`\hat q` of the primary member,

.. math:: \hat q \pm c\, t_{(1+\ell)/2,\,\nu}\,\mathrm{se}(q),\qquad
    \nu = \frac{B - 1}{2},

Student's :math:`t` with half the bootstrap variance's :math:`B - 1` degrees of freedom
(:data:`DOF_FRACTION`) and a calibration factor :math:`c` (:data:`SCALE`), both read off
tuning seeds of ``benchmarks/bench_calibration.py`` (simulated diagrams with known truth,
seeds not used to report coverage; docs/uncertainty.md): the standardised errors
:math:`|\hat q - q|/\mathrm{se}` have heavier tails than :math:`t_{B-1}` (the seed term
rests on two or three members, the bootstrap variance on eight refits), and their
quantiles at 50, 80, 90, 95 and 99 % are those of :math:`c\,t_{(B-1)/2}` with factors
between 0.86 and 1.21; :math:`c` is the one at 95 %.

**Limits.** The bootstrap does not see a bias of the model (the coordinate map's
approximation error, the extrapolation beyond the measured orbits): on the flutter model
the cycle fold's speed is 0.01–0.04 m/s low on most datasets, up to four bootstrap
standard errors. Nor does it see noise that is correlated over time (drift, coloured
noise), which the white resampling treats as independent. A replicate without the
quantity (no fold, no cycle at that parameter) is left out; with fewer than two replicates
left, or where a replicate has no cycle on the branch at that parameter (near a fold,
within its interval), the interval is undefined (NaN).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any

import numpy as np

from bifid.continuation import Diagram
from bifid.errors import ConvergenceError, ConvergenceWarning
from bifid.identify._intervals import critical_value
from bifid.identify._records import LCOData
from bifid.identify.hopf_hybrid import _cycles as cy
from bifid.identify.hopf_hybrid._cv import refit
from bifid.identify.hopf_hybrid._normal_form import raw_a2
from bifid.identify.hopf_hybrid._state import HybridState, states_from_json, states_to_json
from bifid.signal import fourier_fit_columns

__all__ = [
    "DOF_FRACTION",
    "LOSS_TOLERANCE",
    "NOISE_HARMONICS",
    "N_BOOTSTRAP",
    "SCALE",
    "add_intervals",
    "bootstrap",
    "named_standard_errors",
    "noise_split",
    "omega0",
    "point_quantities",
    "seed_members",
    "standard_errors",
]

#: calibration factor of the intervals (module docstring), read off the tuning seeds of the
#: calibration benchmark at 95 %, validated on other seeds
SCALE = 1.05

#: the Student-t degrees of freedom of an interval are this fraction of the bootstrap's
#: B - 1 (module docstring): the standardised errors of the tuning seeds follow t_{(B-1)/2}
DOF_FRACTION = 0.5

#: bootstrap replicates: refits on resampled noise (module docstring)
N_BOOTSTRAP = 8

#: harmonics of a record's periodic part, as in its measured amplitude
NOISE_HARMONICS = 20

#: an ensemble member whose final training loss exceeds the best member's by more than this
#: fraction sits in another optimum and is left out of the seed term (module docstring)
LOSS_TOLERANCE = 1.0


def noise_split(data: LCOData) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per record, its periodic part :math:`\\hat p_i` (Fourier series at the record's
    frequency) and its residual :math:`\\hat e_i` inflated by :math:`\\sqrt{N_i/(N_i - P)}`
    (module docstring); a record without a frequency is kept as it is (zero residual)."""
    out = []
    for x, w, fs in zip(data.signals, data.frequency, data.sample_rate, strict=True):
        if not (math.isfinite(w) and w > 0):
            out.append((x, np.zeros_like(x)))
            continue
        coefs, basis = fourier_fit_columns(x, w, fs, NOISE_HARMONICS)
        p = np.stack([basis @ c for c in coefs], axis=1)  # the series at the samples
        n, n_coef = len(x), len(coefs[0])
        inflate = math.sqrt(n / (n - n_coef)) if n > n_coef else 1.0
        out.append((p, inflate * (x - p)))
    return out


def resample_noise(
    data: LCOData, split: list[tuple[np.ndarray, np.ndarray]], rng: np.random.Generator
) -> LCOData:
    """``data`` with every record's residuals drawn with replacement from its own
    (:func:`noise_split`; the samples of all signals at one time together)."""
    signals = tuple(p + e[rng.integers(len(e), size=len(e))] for p, e in split)
    return dataclasses.replace(data, signals=signals)


def bootstrap(model: Any, data: LCOData, n: int = N_BOOTSTRAP) -> list[HybridState]:
    """The replicates: ``model`` retrained on ``n`` resamplings of the noise of ``data``,
    warm from the full fit (:func:`~._cv.refit`, module docstring), seeded by the
    model's ``seed``. A refit that does not converge is left out, with a warning."""
    rng = np.random.default_rng(model.seed)
    split = noise_split(data)
    out = []
    for b in range(n):
        try:
            out.append(refit(model, resample_noise(data, split, rng), warm=True).state_)
        except ConvergenceError as exc:
            warnings.warn(
                f"the refit on bootstrap sample {b} did not converge and is left out of the "
                f"intervals ({exc}).",
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


def _se(boot: np.ndarray, seeds: np.ndarray) -> tuple[np.ndarray, int]:
    """Standard error :math:`\\sqrt{\\hat v_B + \\hat v_S}` along axis 0 and the bootstrap's
    degrees of freedom :math:`B - 1`; NaN where fewer than two replicates are finite."""
    boot = np.asarray(boot, dtype=float)
    n = np.sum(np.isfinite(boot), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # fewer than two finite: NaN below
        vb = np.nanvar(np.where(np.isfinite(boot), boot, np.nan), axis=0, ddof=1)
    seeds = np.asarray(seeds, dtype=float)
    vs = np.zeros_like(vb)
    if seeds.shape[0] > 1:
        ok = np.all(np.isfinite(seeds), axis=0)
        vs = np.where(ok, np.var(np.where(np.isfinite(seeds), seeds, 0.0), axis=0, ddof=1), 0.0)
    se = np.where(n >= 2, np.sqrt(vb + vs), np.nan)
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
    boot = _collect([(r, 0) for r in replicates], m)
    members = list(range(state.n_members)) if members is None else members
    seeds = _collect([(state, s) for s in members], m)
    out = {}
    for k in keys:
        se, _ = _se(boot[k], seeds[k])
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
    boot = _collect([(r, 0) for r in replicates], m)
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
                se, dof = _se(boot[q], seeds[q])
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


def replicates_to_json(
    states: list[HybridState],
) -> tuple[dict[str, list[dict[str, Any]]], dict[str, np.ndarray]]:
    """The bootstrap replicates as a saved model holds them (``{"bootstrap": settings}``
    and arrays ``bootstrap{i}_*``; read back by :func:`saved_replicates`)."""
    settings, arrays = states_to_json(states, "bootstrap")
    return {"bootstrap": settings}, arrays


def saved_replicates(state: dict[str, Any], arrays: dict[str, np.ndarray]) -> list[HybridState]:
    """The bootstrap replicates of a saved model (``state["bootstrap"]``). A model saved
    with the orbit-jackknife replicates of earlier versions loads without them (their
    variance is another formula: reading them as bootstrap replicates would give wrong
    intervals), with a warning: refit it with ``uncertainty=True`` for intervals."""
    if "jackknife" in state:
        warnings.warn(
            "this model was saved with jackknife replicates, which this version does not "
            "read (its intervals come from a bootstrap of the records' noise): it loads "
            "without intervals; refit it with intervals (`bifid fit hopf ... --level`).",
            ConvergenceWarning,
            stacklevel=4,
        )
    return states_from_json(state.get("bootstrap", []), arrays, "bootstrap")
