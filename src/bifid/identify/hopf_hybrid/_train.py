r"""Training of the coordinate map :math:`\mathbf U_{12}` (thesis §5.3.4) and of the maps
to the other signals (§5.3.1), as functions of the prepared data (:mod:`._prepare`).

The L2 weight of the network and the stopping iteration are chosen by leave-one-orbit-out
cross-validation (:func:`select_map_hyper`); an ensemble over seeds is trained with them
(:func:`train_members`) and its medoid — the member closest to the others in Hopf point,
fold and orbit sizes — predicts.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError, ConvergenceError, ConvergenceWarning
from bifid.identify._records import LCOData
from bifid.identify.hopf_hybrid import _map as hm
from bifid.identify.hopf_hybrid._normal_form import INNER, lco_radius2
from bifid.identify.hopf_hybrid._observe import POINTS_PER_ORBIT, ObservationModel, fit_observation
from bifid.identify.hopf_hybrid._prepare import Prepared, Preprocessing
from bifid.identify.hopf_hybrid._state import member, stack, u12_batch
from bifid.identify.hopf_hybrid._timing import StageTimer

__all__ = ["Setup", "configure", "select_map_hyper", "train_members"]


@dataclass(frozen=True)
class Setup:
    """What the data and hyperparameters fix before training."""

    plane: tuple[int, int]
    others: tuple[int, ...]
    criticality: str
    q5: float
    a2_mode: str
    n_harmonics: int
    map_config: hm.MapConfig


def configure(
    data: LCOData,
    *,
    plane: Sequence[str | int] | None,
    criticality: str,
    quintic: bool | None,
    n_harmonics: int | str,
    n_points: int | str,
    width: int,
    depth: int,
    n_linear: int,
    n_adam: int,
    n_lbfgs: int,
    learning_rate: float,
    preprocessing: Preprocessing | None = None,
) -> Setup:
    """The plane, criticality, quintic term and map configuration for ``data``
    (``n_harmonics="auto"``: chosen by ``preprocessing``, the data's :class:`Preprocessing`).

    Raises
    ------
    BifidInputError
        A plane that is not two different signals, an impossible criticality.
    """
    m = len(data.signal_names)
    if m < 2:
        raise BifidInputError(
            f"the hybrid Hopf model needs at least two signals to form a plane; the data have "
            f"{m} ({', '.join(data.signal_names)})."
        )
    idx = []
    for p in plane if plane is not None else (0, 1):
        if isinstance(p, str):
            if p not in data.signal_names:
                raise BifidInputError(
                    f"plane signal {p!r} is not in the data; signals: {list(data.signal_names)}."
                )
            idx.append(data.signal_names.index(p))
        else:
            idx.append(int(p))
    if len(idx) != 2 or idx[0] == idx[1] or not all(0 <= i < m for i in idx):
        raise BifidInputError(f"plane must name two different signals of {data.signal_names}.")
    unstable = bool(np.any(data.stable == 0))
    crit = (
        ("subcritical" if unstable else "supercritical") if criticality == "auto" else criticality
    )
    if crit == "supercritical" and unstable:
        raise BifidInputError(
            "criticality='supercritical' but some records are labelled unstable; a "
            "supercritical Hopf bifurcation has no unstable limit cycles."
        )
    q = quintic if quintic is not None else crit == "subcritical"
    if crit == "subcritical" and not q:
        raise BifidInputError(
            "A subcritical model needs the quintic term (quintic=True) to have stable "
            "cycles and a fold; set quintic=True or criticality='supercritical'."
        )
    plane_ = (idx[0], idx[1])
    if n_harmonics == "auto":
        nh = (preprocessing or Preprocessing(data)).harmonics(plane_)
    else:
        nh = int(n_harmonics)
    npts = max(64, 8 * math.ceil((4 * nh + 8) / 8)) if n_points == "auto" else int(n_points)
    if npts < 4 * nh + 2:
        raise BifidInputError(f"n_points ({npts}) must be >= 4 * n_harmonics + 2 = {4 * nh + 2}.")
    a2_mode = "fixed" if not q else ("positive" if crit == "subcritical" else "negative")
    cfg = hm.MapConfig(
        n_harmonics=nh,
        n_points=npts,
        width=width,
        depth=depth,
        q5=1.0 if q else 0.0,
        a2_mode=a2_mode,
        n_linear=n_linear,
        n_adam=n_adam,
        n_lbfgs=n_lbfgs,
        learning_rate=float(learning_rate),
        unlabelled=bool(np.any(data.stable == -1)) and q,
    )
    return Setup(
        plane=plane_,
        others=tuple(k for k in range(m) if k not in idx),
        criticality=crit,
        q5=cfg.q5,
        a2_mode=a2_mode,
        n_harmonics=nh,
        map_config=cfg,
    )


def select_map_hyper(
    prep: Prepared,
    setup: Setup,
    active: np.ndarray,
    *,
    grid: Sequence[float],
    choose_lambda: bool,
    stopping: str | int,
    cv_score: str,
    seed: int,
    timer: StageTimer,
) -> tuple[float, int, dict[str, Any]]:
    """L2 weight and stopping iteration of the map, by leave-one-orbit-out CV.

    Every fold trains on all active orbits but one with each weight of ``grid`` (or the one
    given); the held-out loss along the iterations is combined over folds by ``cv_score``
    (median or mean), and the pair with the smallest score at one of ten checkpoints (every
    10 % of the budget) is chosen — or the given stopping iteration.

    Returns
    -------
    lam, stop, cv : float, int, dict
    """
    cfg = setup.map_config
    total = cfg.n_adam + cfg.n_lbfgs
    grid = [float(v) for v in grid]
    if not choose_lambda and stopping != "cv":
        stop = total if stopping == "final" else int(stopping)
        return grid[0], min(stop, total), {}
    folds = np.nonzero(active)[0]
    if len(folds) < 3:
        raise BifidInputError(
            f"Cross-validation needs at least 3 records, got {len(folds)}; pass a number as "
            "regularization and stopping='final'."
        )
    key = jax.random.key(seed)
    data = prep.arrays()
    train = hm.trainer(cfg)
    n = len(prep.mu_t)
    held = np.zeros((len(grid), len(folds), total))
    for fi, i in enumerate(folds):
        mask = active & (np.arange(n) != i)
        p0 = hm.initial_params(prep, mask, cfg, key, setup.criticality)
        for g, lam in enumerate(grid):
            _, hist, _ = _run_map(timer, "map_cv", train, p0, data, mask, lam, total)
            held[g, fi] = np.asarray(hist)[:, i]
    held = np.where(np.isfinite(held), held, np.inf)
    score = (np.median if cv_score == "median" else np.mean)(held, axis=1)  # (grid, T)
    if stopping == "cv":
        # candidate stopping points every 10 % of the budget: the held-out score is noisy
        # from one iteration to the next, a coarse choice is more reproducible
        cand = np.unique(np.clip(np.round(np.linspace(0.1, 1.0, 10) * total), 1, total))
        cand = cand.astype(int)
        g, j = np.unravel_index(np.argmin(score[:, cand - 1]), (len(grid), len(cand)))
        stop = int(cand[j])
    else:
        stop = total if stopping == "final" else min(int(stopping), total)
        g = int(np.argmin(score[:, max(stop - 1, 0)]))
    stride = max(1, total // 200)
    cv = {
        "grid": grid,
        "score": score[:, ::stride].tolist(),
        "score_stride": stride,
        "held_out": held[g, :, max(stop - 1, 0)].tolist(),
        "held_out_params": [float(prep.mu_t[i] * prep.mu_s + prep.mu_c) for i in folds],
        "selected_regularization": grid[g],
        "selected_iterations": stop,
        "best_score": float(score[g, max(stop - 1, 0)]),
        "aggregate": cv_score,
    }
    return grid[g], stop, cv


def _run_map(
    timer: StageTimer,
    stage: str,
    train: Any,
    p0: Any,
    data: Any,
    weights: np.ndarray,
    lam: float,
    n_iter: int,
) -> Any:
    """One timed run of the compiled map trainer (orbit ``weights``, L2 weight ``lam``)."""
    return timer.run(
        stage,
        train,
        p0,
        data,
        jnp.asarray(weights, dtype=float),
        jnp.asarray(lam),
        jnp.asarray(n_iter, dtype=jnp.int32),
    )


def cycle_sizes(mp: Any, cfg: hm.MapConfig, mu_t: np.ndarray, root: np.ndarray) -> np.ndarray:
    """Mean distance from their centre of the model cycles of one member (medoid choice)."""
    a2 = float(hm.a2_of(jnp.asarray(mp["alpha"]), cfg.a2_mode))
    phi = np.linspace(0, 2 * np.pi, cfg.n_points, endpoint=False)
    out = []
    for m, b in zip(mu_t, root, strict=True):
        r2 = float(lco_radius2(m, float(mp["mu0"]), a2, cfg.q5, 1.0 if b >= 0 else -1.0))
        u = math.sqrt(max(r2, 1e-4)) * np.stack([np.cos(phi), np.sin(phi)], axis=1)
        pts = u12_batch(mp, cfg, u, m)
        out.append(float(np.mean(np.linalg.norm(pts - pts.mean(0), axis=1))))
    return np.asarray(out)


def train_members(
    prep: Prepared,
    setup: Setup,
    lam: float,
    stop: int,
    active: np.ndarray,
    *,
    n_members: int,
    seed: int,
    timer: StageTimer,
    init: dict[str, Any] | None = None,
) -> tuple[dict[str, Any], int, dict[str, Any]]:
    """Train ``n_members`` maps from different initialisations with ``(lam, stop)``, or
    every member from the parameters ``init`` (a warm start).

    Returns the stacked parameters of the members that stayed finite, the medoid member and
    the losses.

    Raises
    ------
    ConvergenceError
        If every member diverged.
    """
    cfg = setup.map_config
    keys = jax.random.split(jax.random.key(seed), n_members)
    data = prep.arrays()
    train, evaluate = hm.trainer(cfg), hm.loss_evaluator(cfg)
    members, finals, per_orbit, ok = [], [], [], []
    for s in range(n_members):
        p0 = init or hm.initial_params(prep, active, cfg, keys[s], setup.criticality)
        p, _, final = _run_map(timer, "map_ensemble", train, p0, data, active, lam, stop)
        losses = np.asarray(evaluate(p, data))
        flat = np.concatenate([np.ravel(x) for x in jax.tree_util.tree_leaves(p)])
        members.append(jax.tree_util.tree_map(np.asarray, p))
        finals.append(float(final))
        per_orbit.append(losses)
        ok.append(
            bool(
                np.isfinite(final)
                and np.all(np.isfinite(losses[active]))
                and np.all(np.isfinite(flat))
            )
        )
    good = np.nonzero(ok)[0]
    if not len(good):
        raise ConvergenceError(
            "The coordinate-map training diverged for every ensemble member; try a smaller "
            "learning_rate or more n_linear iterations."
        )
    if len(good) < n_members:
        warnings.warn(
            f"{n_members - len(good)} of {n_members} ensemble members diverged and were dropped.",
            ConvergenceWarning,
            stacklevel=3,
        )
    params = stack([members[i] for i in good])
    signature = []
    for s in range(len(good)):
        mp = member(params, s)
        mu0 = float(mp["mu0"])
        a2 = float(hm.a2_of(mp["alpha"], cfg.a2_mode))
        fold = mu0 - a2**2 / 4 if (cfg.q5 and a2 > 0) else mu0
        sizes = cycle_sizes(mp, cfg, prep.mu_t[active], prep.root[active])
        signature.append(np.concatenate([[mu0, fold], sizes]))
    sig = np.asarray(signature)
    primary = int(np.argmin(np.sum(np.abs(sig[:, None, :] - sig[None, :, :]), axis=(1, 2))))
    losses = {
        "map_final": [finals[i] for i in good],
        "map_per_orbit": np.asarray(per_orbit)[good][primary][active].tolist(),
    }
    return params, primary, losses


def one_period(prep: Prepared, i: int, n: int) -> np.ndarray:
    """``n`` sample indices spread evenly over the first period of record ``i``."""
    fs = 1.0 / (prep.times[i][1] - prep.times[i][0])
    n_per = min(len(prep.zn[i]) - 1, round(2 * np.pi / prep.omega[i] * fs))
    return np.unique(np.linspace(0, n_per, n, endpoint=False).astype(int))


def train_observation(
    prep: Prepared,
    others: tuple[int, ...],
    members: Sequence[int],
    rho: np.ndarray,
    phases: Any,
    active: np.ndarray,
    timer: StageTimer,
) -> list[ObservationModel]:
    """The regression of the other signals on the normal-form points, per member (§5.3.1).

    ``rho[s, i]`` is the cycle radius of orbit ``i`` for member ``s``; ``phases(s, i, pts)``
    the normal-form phases of plane points (eq. 5.12). The hyperparameters are chosen by
    leave-one-orbit-out CV for the first member of ``members`` and reused by the others.
    """
    if not others:
        return []
    t0 = time.perf_counter()
    hyper = None
    models: dict[int, ObservationModel] = {}
    for s in members:
        xs, ys, gs = [], [], []
        for i in np.nonzero(active)[0]:
            take = one_period(prep, i, POINTS_PER_ORBIT)
            ph = phases(s, i, prep.plane_points(i, take))
            u = rho[s, i] * np.stack([np.cos(ph), np.sin(ph)], axis=1)
            xs.append(np.column_stack([u, np.full(len(ph), prep.mu_t[i])]))
            ys.append(prep.zn[i][take][:, list(others)])
            gs.append(np.full(len(ph), i))
        x, y, g = np.concatenate(xs), np.concatenate(ys), np.concatenate(gs)
        models[s] = fit_observation(x, y, g, *(hyper or (None, None)))
        hyper = hyper or (models[s].length, models[s].ridge)
    timer.add("observation", time.perf_counter() - t0)
    return [models[s] for s in sorted(models)]


def root_of_record(prep: Prepared, i: int) -> float:
    """+1 (outer root) unless the record is labelled unstable."""
    return -1.0 if prep.root[i] == INNER else 1.0
