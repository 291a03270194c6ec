r"""Hybrid normal-form + neural-network models of Hopf systems (thesis ch. 5).

A normal-form-like model fixes the bifurcation structure; learned maps make it match the
measured limit cycles, stable **and** unstable:

.. math::

    \dot r = (\mu - \mu_0) r + a_2 r^3 - q_5 r^5,\qquad \dot\theta = \Omega(r, \theta, \mu)
    \qquad\text{(eq. 5.3)}

    (\hat z_1, \hat z_2) = \mathbf U_{12}(u_1, u_2, \mu) = T_L(u, \mu) + T_s
        + \mathrm{NN}_{\Theta_U}(u, \mu)\qquad\text{(eqs. 5.8–5.9)}

    \Omega = \omega_0 + \mathrm{NN}_{\Theta_\Omega}(r, \mu)^{\mathsf T}[1, \cos\theta, \dots,
        \sin n\theta]\qquad\text{(eq. 5.10)}

and the other observed signals :math:`z_3 \dots z_m` by regression on :math:`(u_1, u_2, \mu)`
(§5.3.1). The Hopf point is :math:`\mu_0`, the fold of cycles :math:`\mu_0 - a_2^2/4`
(subcritical with quintic term), and the cycle radii are closed-form.

Training follows §5.3.4 — (1) :math:`T_L, T_s` on the polar Fourier representation of the
orbits (eqs. 5.4–5.7) with :math:`\mu_0, a_2` at a regression guess; (2) the network with
:math:`\mu_0, a_2`; (3) :math:`\Omega` by integrating only the phase equation from
phase-matched initial conditions (eqs. 5.12–5.13) — and adds what the thesis tuned by hand:
the L2 weight of the network and the stopping iteration are chosen by leave-one-orbit-out
cross-validation, an ensemble over seeds gives a band on the predicted diagram, and
:meth:`HopfHybridModel.cross_validate` reports the held-out error of every orbit.

Example
-------
>>> model = HopfHybridModel(n_ensemble=3).fit(records)            # doctest: +SKIP
>>> model.hopf_point()["param"], model.cycle_fold()["param"]     # doctest: +SKIP
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError, ConvergenceError, ConvergenceWarning, NotFittedError
from bifid.identify import _hopf_map as hm
from bifid.identify import _hopf_speed as hs
from bifid.identify._hopf_data import LCOData, as_lco_data
from bifid.identify._hopf_normal_form import (
    UNSTABLE,
    growth_derivative,
    lco_radius2,
    raw_a2,
)
from bifid.identify._hopf_observe import POINTS_PER_ORBIT, ObservationModel, fit_observation
from bifid.identify._hopf_prepare import Prepared, choose_harmonics, prepare

Array = jnp.ndarray

MODEL_TYPE = "hopf_hybrid"
__all__ = ["MODEL_TYPE", "HopfHybridModel"]

_N_GRID_INVERSE = 2048  # phases for the inversion of eq. 5.12
_N_CYCLE = 512  # phases per predicted cycle (amplitudes = max over them)


def _stack(trees):
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *trees)


def _index(tree, i):
    return jax.tree_util.tree_map(lambda x: x[i], tree)


def _to_numpy(tree):
    return jax.tree_util.tree_map(lambda x: np.asarray(x), tree)


_COMPILED: dict = {}


class _Timer:
    """Wall-clock per stage, compile time apart (AOT ``lower().compile()``)."""

    def __init__(self) -> None:
        self.times: dict[str, float] = {}

    def add(self, name: str, seconds: float) -> None:
        self.times[name] = self.times.get(name, 0.0) + seconds

    def run(self, name: str, fn, *args):
        t0 = time.perf_counter()
        leaves, tdef = jax.tree_util.tree_flatten(args)
        key = (fn, tdef, tuple((np.shape(x), np.asarray(x).dtype.str) for x in leaves))
        compiled = _COMPILED.get(key)
        if compiled is None:
            compiled = _COMPILED[key] = fn.lower(*args).compile()
        t1 = time.perf_counter()
        out = jax.block_until_ready(compiled(*args))
        t2 = time.perf_counter()
        self.add(f"compile_{name}", t1 - t0)
        self.add(name, t2 - t1)
        return out


def _blas_single_thread():
    """One BLAS thread while fitting: the linear algebra here is small, and multithreaded
    BLAS on a loaded 2-core machine is up to 20× slower than one thread (oversubscription)."""
    import contextlib

    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # optional
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def _progress(enabled: bool):
    import contextlib

    if not enabled:
        return contextlib.nullcontext(None)
    from rich.console import Console
    from rich.progress import Progress

    return Progress(console=Console(stderr=True), transient=True)


class HopfHybridModel:
    r"""Hybrid mechanistic/machine-learnt model of a system with a Hopf bifurcation.

    Parameters
    ----------
    criticality : {"auto", "subcritical", "supercritical"}
        Sign of :math:`a_2`. ``"auto"``: subcritical if any record is labelled unstable.
    quintic : bool, optional
        Keep the :math:`-r^5` term (needed for a fold of cycles). Default: on for
        subcritical, off for supercritical (then :math:`a_2 = -1` is fixed, §5.4.1).
    plane : pair of str or int, optional
        The two signals :math:`(z_1, z_2)` whose orbits are closed curves around a centre
        (default: the first two signals).
    n_harmonics : int or "auto"
        Harmonics of the polar representation (eq. 5.5). ``"auto"``: the smallest number
        representing every measured orbit to 0.3 % of its radius above the noise floor
        (:func:`~bifid.identify._hopf_prepare.choose_harmonics`).
    n_points : int or "auto"
        Points per model cycle in the map loss (``"auto"``: ``max(64, 4 n_harmonics + 8)``).
    width, depth : int
        Hidden width and layers of :math:`\mathrm{NN}_{\Theta_U}`.
    n_linear : int
        L-BFGS iterations of stage 1 (linear part).
    n_adam, n_lbfgs : int
        Adam then L-BFGS iterations of stage 2 (network, :math:`\mu_0`, :math:`a_2`). The
        default skips Adam: on the flutter and Van der Pol benchmarks L-BFGS alone reaches
        the same loss 3–4× faster from the zero-initialised network output, and both stages
        then share one compiled loop.
    learning_rate : float
        Peak Adam learning rate (cosine decay) of stage 2.
    regularization : "cv" or float
        L2 weight :math:`\lambda` on the network's weight matrices; ``"cv"`` picks it from
        ``regularization_grid`` by leave-one-orbit-out cross-validation.
    regularization_grid : sequence of float
    stopping : {"cv", "final"} or int
        ``"cv"``: return the stage-2 parameters at the iteration with the smallest
        leave-one-out error (early stopping); ``"final"``: after all iterations; an int:
        after that many iterations.
    cv_score : {"median", "mean"}
        How the held-out losses of the folds are combined. The mean is dominated by the
        folds that extrapolate (leaving out the orbit nearest the fold or the Hopf point moves
        that point, so the left-out orbit may not even exist in the fold's model); the median
        scores the typical orbit. On the real rig data the median gives leave-one-out errors
        two to five times smaller at the interior orbits (see BENCHMARKS.md).
    n_ensemble : int
        Members trained from different network initialisations; predictions use the
        medoid member, the others give the band.
    omega_harmonics : int
        :math:`n_\Omega` of eq. 5.10.
    omega_form : {"log", "additive"}
        ``"additive"``: eq. 5.10 as printed; ``"log"`` (default): the Fourier series gives
        :math:`\log\Omega`, so the speed is positive by construction (see
        :class:`~bifid.identify._hopf_speed.SpeedConfig`).
    omega_width, omega_depth : int
        Shape of :math:`\mathrm{NN}_{\Theta_\Omega}`.
    omega_fit_iterations, omega_iterations : int
        Adam iterations fitting the network to the measured speed profiles, then L-BFGS
        iterations on eq. 5.13 (time series through the phase equation).
    omega_learning_rate : float
    omega_regularization : "cv" or float
        L2 weight on :math:`\mathrm{NN}_{\Theta_\Omega}` (``"cv"``: leave-one-orbit-out).
    omega_regularization_grid : sequence of float
    omega_samples : int
        At most this many samples per record in eq. 5.13 (records are decimated).
    omega_periods : float
        At most this many periods per record in eq. 5.13.
    seed : int
        Seed of every random initialisation.
    progress : bool
        Show progress on stderr.
    """

    def __init__(
        self,
        *,
        criticality: str = "auto",
        quintic: bool | None = None,
        plane: tuple[str | int, str | int] | None = None,
        n_harmonics: int | str = "auto",
        n_points: int | str = "auto",
        width: int = 16,
        depth: int = 2,
        n_linear: int = 100,
        n_adam: int = 0,
        n_lbfgs: int = 600,
        learning_rate: float = 3e-3,
        regularization: str | float = "cv",
        regularization_grid: Sequence[float] = (1e-6, 1e-5, 1e-4),
        stopping: str = "cv",
        cv_score: str = "median",
        n_ensemble: int = 5,
        omega_harmonics: int = 6,
        omega_form: str = "log",
        omega_width: int = 16,
        omega_depth: int = 2,
        omega_fit_iterations: int = 400,
        omega_iterations: int = 100,
        omega_learning_rate: float = 3e-3,
        omega_regularization: str | float = "cv",
        omega_regularization_grid: Sequence[float] = (1e-6, 1e-4, 1e-2),
        omega_samples: int = 500,
        omega_periods: float = 10.0,
        seed: int = 0,
        progress: bool = False,
    ) -> None:
        self.criticality = criticality
        self.quintic = quintic
        self.plane = plane
        self.n_harmonics = n_harmonics
        self.n_points = n_points
        self.width = width
        self.depth = depth
        self.n_linear = n_linear
        self.n_adam = n_adam
        self.n_lbfgs = n_lbfgs
        self.learning_rate = learning_rate
        self.regularization = regularization
        self.regularization_grid = regularization_grid
        self.stopping = stopping
        self.cv_score = cv_score
        self.n_ensemble = n_ensemble
        self.omega_harmonics = omega_harmonics
        self.omega_form = omega_form
        self.omega_width = omega_width
        self.omega_depth = omega_depth
        self.omega_fit_iterations = omega_fit_iterations
        self.omega_iterations = omega_iterations
        self.omega_learning_rate = omega_learning_rate
        self.omega_regularization = omega_regularization
        self.omega_regularization_grid = omega_regularization_grid
        self.omega_samples = omega_samples
        self.omega_periods = omega_periods
        self.seed = seed
        self.progress = progress

    # ------------------------------------------------------------------ hyperparameters
    _HYPER = (
        "criticality", "quintic", "plane", "n_harmonics", "n_points", "width", "depth",
        "n_linear", "n_adam", "n_lbfgs", "learning_rate", "regularization",
        "regularization_grid", "stopping", "cv_score", "n_ensemble", "omega_harmonics",
        "omega_form", "omega_width", "omega_depth", "omega_fit_iterations",
        "omega_iterations", "omega_learning_rate", "omega_regularization",
        "omega_regularization_grid", "omega_samples", "omega_periods", "seed",
    )

    def get_params(self) -> dict[str, Any]:
        """Hyperparameters (scikit-learn convention)."""
        out = {k: getattr(self, k) for k in self._HYPER}
        out["plane"] = list(self.plane) if self.plane is not None else None
        out["regularization_grid"] = [float(v) for v in self.regularization_grid]
        out["omega_regularization_grid"] = [float(v) for v in self.omega_regularization_grid]
        return out

    def _validate_hyper(self) -> None:
        def need(cond: bool, name: str, what: str) -> None:
            if not cond:
                raise BifidInputError(
                    f"The {name!r} parameter of HopfHybridModel must be {what}; "
                    f"got {getattr(self, name)!r}."
                )

        need(self.criticality in ("auto", "subcritical", "supercritical"), "criticality",
             "'auto', 'subcritical' or 'supercritical'")
        need(self.quintic in (None, True, False), "quintic", "True, False or None")
        need(self.n_harmonics == "auto" or (isinstance(self.n_harmonics, int)
             and self.n_harmonics >= 1), "n_harmonics", "'auto' or an int >= 1")
        need(self.n_points == "auto" or (isinstance(self.n_points, int) and self.n_points >= 16),
             "n_points", "'auto' or an int >= 16")
        for name, lo in (("width", 1), ("depth", 1),
                         ("n_ensemble", 1), ("omega_width", 1), ("omega_depth", 1),
                         ("omega_samples", 32)):
            need(isinstance(getattr(self, name), int) and getattr(self, name) >= lo, name,
                 f"an int >= {lo}")
        for name in ("n_linear", "n_adam", "n_lbfgs", "omega_harmonics",
                     "omega_fit_iterations", "omega_iterations"):
            need(isinstance(getattr(self, name), int) and getattr(self, name) >= 0, name,
                 "an int >= 0")
        need(self.n_adam + self.n_lbfgs >= 1, "n_adam", "> 0 when n_lbfgs is 0")
        for name in ("learning_rate", "omega_learning_rate", "omega_periods"):
            v = getattr(self, name)
            need(isinstance(v, (int, float)) and math.isfinite(v) and v > 0, name,
                 "a positive number")
        for name in ("regularization", "omega_regularization"):
            v = getattr(self, name)
            need(v == "cv" or (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0),
                 name, "'cv' or a number >= 0")
        for name in ("regularization_grid", "omega_regularization_grid"):
            v = getattr(self, name)
            need(len(v) >= 1 and all(math.isfinite(float(x)) and float(x) >= 0 for x in v),
                 name, "a non-empty sequence of numbers >= 0")
        need(self.omega_form in ("log", "additive"), "omega_form", "'log' or 'additive'")
        need(self.cv_score in ("mean", "median"), "cv_score", "'mean' or 'median'")
        need(self.stopping in ("cv", "final") or (
            isinstance(self.stopping, int) and not isinstance(self.stopping, bool)
            and self.stopping >= 0), "stopping", "'cv', 'final' or an iteration count >= 0")

    # --------------------------------------------------------------------------- fit
    def fit(self, data: Any, signal_names: Sequence[str] | None = None) -> HopfHybridModel:
        """Train on limit-cycle records (stable and unstable).

        Parameters
        ----------
        data
            An LCO dataset (xarray or path), a list of them, or records
            ``(param, signals (n, m), sample_rate, stable)`` / ``bifid.data.LCORecord``.
        signal_names : sequence of str, optional
            Names of the signals when ``data`` are bare records.

        Returns
        -------
        self

        Raises
        ------
        BifidInputError
            Invalid data or hyperparameters.
        ConvergenceError
            If no ensemble member produces finite parameters.
        """
        self._validate_hyper()
        with _blas_single_thread():
            return self._fit(data, signal_names)

    def _fit(
        self, data: Any, signal_names: Sequence[str] | None, active: np.ndarray | None = None
    ) -> HopfHybridModel:
        """Fit on the records ``active`` (all by default). Inactive records keep their place in
        every array (weight 0), so leave-one-out folds reuse the compiled training loops."""
        t_start = time.perf_counter()
        d = as_lco_data(data, signal_names)
        active = np.ones(d.n_records, dtype=bool) if active is None else np.asarray(active)
        self._active = active
        self._setup(d)
        prep = prepare(d, self.plane_, self.map_config_.n_harmonics)
        self.mu_c_, self.mu_s_, self.z_scale_ = prep.mu_c, prep.mu_s, prep.z_scale
        self.white_ = prep.white
        self.direction_ = prep.direction
        timer = _Timer()
        with _progress(self.progress) as bar:
            task = bar.add_task("hopf_hybrid", total=4) if bar else None

            def tick(msg: str) -> None:
                if bar:
                    bar.update(task, advance=1, description=msg)

            lam, stop, cv = self._select_map_hyper(prep, timer, active)
            tick("map: cross-validation")
            losses = self._train_members(prep, lam, stop, timer, active)
            tick("map: ensemble")
            self._fit_speed(prep, timer, active)
            tick("oscillation speed")
            self._fit_observation(prep, timer, active)
            tick("other signals")
        self.regularization_ = lam
        self.n_iterations_ = int(stop)
        self.cv_ = cv
        self.map_losses_ = losses
        self.timings_ = {k: float(v) for k, v in timer.times.items()}
        self.timings_["total"] = time.perf_counter() - t_start
        self._training_summary(prep, d, active)
        return self

    def _setup(self, d: LCOData) -> None:
        m = len(d.signal_names)
        plane = self.plane if self.plane is not None else (0, 1)
        idx = []
        for p in plane:
            if isinstance(p, str):
                if p not in d.signal_names:
                    raise BifidInputError(
                        f"plane signal {p!r} is not in the data; signals: {list(d.signal_names)}."
                    )
                idx.append(d.signal_names.index(p))
            else:
                idx.append(int(p))
        if len(idx) != 2 or idx[0] == idx[1] or not all(0 <= i < m for i in idx):
            raise BifidInputError(f"plane must name two different signals of {d.signal_names}.")
        self.plane_ = (idx[0], idx[1])
        self.others_ = tuple(k for k in range(m) if k not in idx)
        crit = self.criticality
        if crit == "auto":
            crit = "subcritical" if np.any(d.branch == UNSTABLE) else "supercritical"
        if crit == "supercritical" and np.any(d.branch == UNSTABLE):
            raise BifidInputError(
                "criticality='supercritical' but some records are labelled unstable; a "
                "supercritical Hopf bifurcation has no unstable limit cycles."
            )
        quintic = self.quintic if self.quintic is not None else crit == "subcritical"
        if crit == "subcritical" and not quintic:
            raise BifidInputError(
                "A subcritical model needs the quintic term (quintic=True) to have stable "
                "cycles and a fold; set quintic=True or criticality='supercritical'."
            )
        self.criticality_ = crit
        self.q5_ = 1.0 if quintic else 0.0
        self.a2_mode_ = (
            "fixed" if not quintic else ("positive" if crit == "subcritical" else "negative")
        )
        self.signal_names_ = d.signal_names
        self.param_name_ = d.param_name
        self.param_units_ = d.param_units
        self.signal_units_ = dict(d.signal_units)
        nh = (
            choose_harmonics(d, self.plane_) if self.n_harmonics == "auto" else self.n_harmonics
        )
        n_points = max(64, 8 * math.ceil((4 * nh + 8) / 8)) if self.n_points == "auto" \
            else self.n_points
        if n_points < 4 * nh + 2:
            raise BifidInputError(
                f"n_points ({n_points}) must be >= 4 * n_harmonics + 2 = {4 * nh + 2}."
            )
        self.n_harmonics_ = nh
        self.map_config_ = hm.MapConfig(
            n_harmonics=nh,
            n_points=n_points,
            width=self.width,
            depth=self.depth,
            q5=self.q5_,
            a2_mode=self.a2_mode_,
            n_linear=self.n_linear,
            n_adam=self.n_adam,
            n_lbfgs=self.n_lbfgs,
            learning_rate=float(self.learning_rate),
            unlabelled=bool(np.any(d.branch == 0)) and quintic,
        )

    # ------------------------------------------------------------------ map stage
    def _select_map_hyper(self, prep: Prepared, timer: _Timer, active: np.ndarray):
        cfg = self.map_config_
        total = cfg.n_adam + cfg.n_lbfgs
        grid = (
            [float(v) for v in self.regularization_grid]
            if self.regularization == "cv"
            else [float(self.regularization)]
        )
        n = len(prep.mu_t)
        if self.regularization != "cv" and self.stopping != "cv":
            stop = total if self.stopping == "final" else int(self.stopping)
            return grid[0], min(stop, total), {}
        folds = np.nonzero(active)[0]
        if len(folds) < 3:
            raise BifidInputError(
                f"Cross-validation needs at least 3 records, got {len(folds)}; pass a number "
                "as regularization and stopping='final'."
            )
        key = jax.random.key(self.seed)
        data = prep.arrays()
        train = hm.trainer(cfg)
        held = np.zeros((len(grid), len(folds), total))
        for fi, i in enumerate(folds):
            mask = active & (np.arange(n) != i)
            p0 = hm.initial_params(prep, mask, cfg, key, self.criticality_)
            for g, lam in enumerate(grid):
                _, hist, _ = timer.run(
                    "map_cv", train, p0, data, jnp.asarray(mask, dtype=float),
                    jnp.asarray(lam), jnp.asarray(total, dtype=jnp.int32),
                )
                held[g, fi] = np.asarray(hist)[:, i]
        held = np.where(np.isfinite(held), held, np.inf)
        agg = np.median if self.cv_score == "median" else np.mean
        score = agg(held, axis=1)  # (grid, T)
        if self.stopping == "cv":
            # candidate stopping points every 10 % of the budget: the held-out score is noisy
            # from one iteration to the next, a coarse choice is more reproducible
            cand = np.unique(np.clip(np.round(np.linspace(0.1, 1.0, 10) * total), 1, total))
            cand = cand.astype(int)
            sub = score[:, cand - 1]
            g, j = np.unravel_index(np.argmin(sub), sub.shape)
            stop = int(cand[j])
        else:
            stop = total if self.stopping == "final" else min(int(self.stopping), total)
            g = int(np.argmin(score[:, max(stop - 1, 0)]))
        cv = {
            "grid": grid,
            "score": score[:, :: max(1, total // 200)].tolist(),
            "score_stride": max(1, total // 200),
            "held_out": held[g, :, max(stop - 1, 0)].tolist(),
            "held_out_params": [float(prep.mu_t[i] * prep.mu_s + prep.mu_c) for i in folds],
            "selected_regularization": grid[g],
            "selected_iterations": stop,
            "best_score": float(score[g, max(stop - 1, 0)]),
            "aggregate": self.cv_score,
        }
        return grid[g], stop, cv

    def _train_members(
        self, prep: Prepared, lam: float, stop: int, timer: _Timer, active: np.ndarray
    ):
        cfg = self.map_config_
        S = self.n_ensemble
        keys = jax.random.split(jax.random.key(self.seed), S)
        data = prep.arrays()
        train, evaluate = hm.trainer(cfg), hm.loss_evaluator(cfg)
        members, finals, per_orbit, ok = [], [], [], []
        for s in range(S):
            p0 = hm.initial_params(prep, active, cfg, keys[s], self.criticality_)
            p, _, final = timer.run(
                "map_ensemble", train, p0, data, jnp.asarray(active, dtype=float),
                jnp.asarray(lam),
                jnp.asarray(stop, dtype=jnp.int32),
            )
            losses_s = np.asarray(evaluate(p, data))
            flat = np.concatenate([np.ravel(x) for x in jax.tree_util.tree_leaves(p)])
            members.append(_to_numpy(p))
            finals.append(float(final))
            per_orbit.append(losses_s)
            ok.append(bool(np.isfinite(final) and np.all(np.isfinite(losses_s[active]))
                           and np.all(np.isfinite(flat))))
        ok = np.asarray(ok)
        per_orbit = np.asarray(per_orbit)
        final = np.asarray(finals)
        if not np.any(ok):
            raise ConvergenceError(
                "The coordinate-map training diverged for every ensemble member; try a smaller "
                "learning_rate or more n_linear iterations."
            )
        if not np.all(ok):
            warnings.warn(
                f"{int(np.sum(~ok))} of {S} ensemble members diverged and were dropped.",
                ConvergenceWarning,
                stacklevel=3,
            )
        idx = np.nonzero(ok)[0]
        self.map_params_ = _to_numpy(_stack([members[i] for i in idx]))
        self.n_members_ = len(idx)
        # medoid member: closest to the others in (Hopf, fold, orbit sizes)
        sig = []
        for s in range(self.n_members_):
            mp = _index(self.map_params_, s)
            mu0 = float(mp["mu0"])
            a2 = float(hm.a2_of(mp["alpha"], cfg.a2_mode))
            fold = mu0 - a2**2 / 4 if (cfg.q5 and a2 > 0) else mu0
            sizes = self._cycle_sizes(mp, prep.mu_t[active], prep.branch[active])
            sig.append(np.concatenate([[mu0, fold], sizes]))
        sig = np.asarray(sig)
        dist = np.sum(np.abs(sig[:, None, :] - sig[None, :, :]), axis=(1, 2))
        self.primary_ = int(np.argmin(dist))
        losses = {
            "map_final": [float(v) for v in np.asarray(final)[idx]],
            "map_per_orbit": per_orbit[idx][self.primary_][active].tolist(),
        }
        return losses

    def _cycle_sizes(self, mp, mu_t, branch):
        cfg = self.map_config_
        a2 = float(hm.a2_of(jnp.asarray(mp["alpha"]), cfg.a2_mode))
        phi = np.linspace(0, 2 * np.pi, cfg.n_points, endpoint=False)
        out = []
        for m, b in zip(mu_t, branch, strict=True):
            r2 = float(lco_radius2(m, float(mp["mu0"]), a2, cfg.q5, 1.0 if b >= 0 else -1.0))
            u = math.sqrt(max(r2, 1e-4)) * np.stack([np.cos(phi), np.sin(phi)], axis=1)
            pts = np.asarray(_u12_batch(mp, cfg.width, cfg.depth, u, m))
            out.append(float(np.mean(np.linalg.norm(pts - pts.mean(0), axis=1))))
        return np.asarray(out)

    # ------------------------------------------------------------- speed stage (Ω)
    def _member_rho(self, s: int, mu_t: np.ndarray, branch: np.ndarray) -> np.ndarray:
        mp = _index(self.map_params_, s)
        a2 = hm.a2_of(jnp.asarray(mp["alpha"]), self.a2_mode_)
        out = []
        for m, b in zip(mu_t, branch, strict=True):
            bb = 1.0 if b >= 0 else -1.0
            if b == 0 and self.q5_:  # unlabelled: the branch that fits better
                bb = self._best_branch(s, m)
            r2 = float(lco_radius2(jnp.asarray(m), mp["mu0"], a2, self.q5_, bb))
            out.append(math.sqrt(max(r2, 1e-4)))
        return np.asarray(out)

    def _best_branch(self, s: int, mu_t: float) -> float:
        i = int(np.argmin(np.abs(self._train_mu_t - mu_t)))
        coef, centre = self._train_coef[i], self._train_centre[i]
        mp = _index(self.map_params_, s)
        static = hm.mlp_static(3, 2, self.width, self.depth)
        losses = [
            float(hm.orbit_loss(mp, static, jnp.asarray(mu_t), b, jnp.asarray(coef),
                                jnp.asarray(centre), self.map_config_))
            for b in (1.0, -1.0)
        ]
        return 1.0 if losses[0] <= losses[1] else -1.0

    def _phases(self, s: int, i: int, prep: Prepared, rho: float, pts: np.ndarray) -> np.ndarray:
        """Normal-form phases of measured plane points of record ``i`` (eq. 5.12)."""
        mp = _index(self.map_params_, s)
        phi, ang = hm_angles(mp, self.width, self.depth, prep.mu_t[i], rho, prep.centre[i])
        d = pts - prep.centre[i][None, :]
        beta = np.arctan2(d[:, 1], d[:, 0])
        out, monotone = hs.invert_phase(phi, ang, beta)
        if not monotone:
            warnings.warn(
                f"The model cycle at {self.param_name_}={prep.mu_t[i] * self.mu_s_ + self.mu_c_:g}"
                " is not star-shaped about its centre; the phase matching of eq. 5.12 is "
                "approximate there.",
                ConvergenceWarning,
                stacklevel=4,
            )
        return out

    def _fit_speed(self, prep: Prepared, timer: _Timer, active: np.ndarray) -> None:
        S, n = self.n_members_, len(prep.mu_t)
        self._train_mu_t = prep.mu_t[active]
        self._train_coef, self._train_centre = prep.coef[active], prep.centre[active]
        weights = active.astype(float)
        d_params = prep.mu_t * self.mu_s_ + self.mu_c_
        nh = self.omega_harmonics
        # training windows: <= omega_periods periods, <= omega_samples samples per record
        windows, h, profile_windows = [], [], []
        for i in range(n):
            fs = 1.0 / (prep.times[i][1] - prep.times[i][0])
            n_per = 2 * np.pi / prep.omega[i] * fs
            n_take = int(min(len(prep.zn[i]), math.ceil(self.omega_periods * n_per) + 1))
            dec = max(1, math.ceil(n_take / self.omega_samples))
            windows.append(np.arange(0, n_take, dec))
            h.append(dec / fs)
            # speed profiles from the same span, sampled more finely (a least-squares fit)
            profile_windows.append(np.arange(0, n_take, max(1, math.ceil(n_take / 4000))))
        n_steps = max(len(w) for w in windows)
        n_sub = max(1, math.ceil(max(float(np.max(prep.omega)) * hh for hh in h) / 0.1))
        cfg = hs.SpeedConfig(
            n_harmonics=nh,
            width=self.omega_width,
            depth=self.omega_depth,
            n_fit=self.omega_fit_iterations,
            n_refine=self.omega_iterations,
            learning_rate=float(self.omega_learning_rate),
            n_sub=n_sub,
            form=self.omega_form,
            map_width=self.width,
            map_depth=self.depth,
        )
        self.speed_config_ = cfg
        self.omega_scale_ = float(np.mean(prep.omega[active]))
        # per member and orbit: radius, phase-matched initial phase (eq. 5.12), speed profile
        grid = np.linspace(0, 2 * np.pi, 256, endpoint=False)
        rho = np.zeros((S, n))
        theta0 = np.zeros((S, n))
        targets = np.zeros((S, n, 2 * nh + 1))
        t0 = time.perf_counter()
        for s in range(S):
            rho[s] = self._member_rho(s, prep.mu_t, prep.branch)
            for i in np.nonzero(active)[0]:
                win = profile_windows[i]
                ph = np.unwrap(self._phases(s, i, prep, rho[s, i], prep.plane_points(i, win)))
                theta0[s, i] = ph[0]
                per_period = 2 * np.pi / prep.omega[i] / (prep.times[i][win[1]] - prep.times[i][0])
                prof = hs.speed_from_phase(prep.times[i][win], ph, prep.omega[i], grid,
                                           n_time_harmonics=int(min(40, per_period / 3)))
                if np.sign(ph[-1] - ph[0]) < 0:
                    raise ConvergenceError(
                        f"The model cycle at {self.param_name_}={d_params[i]:g} turns against "
                        "the measured orbit; the coordinate map lost its orientation."
                    )
                g = np.log(prof / self.omega_scale_) if cfg.form == "log" else (
                    prof / self.omega_scale_)
                c = hs.project(g, grid, nh)
                # the truncated profile must keep the measured period 2 pi / omega_i
                B = np.asarray(hs.fourier_design(jnp.asarray(grid), nh))
                trunc = np.exp(B @ c) if cfg.form == "log" else B @ c
                ratio = np.mean(1.0 / trunc) * prep.omega[i] / self.omega_scale_
                if cfg.form == "log":
                    c[0] += np.log(ratio)
                else:
                    c *= ratio
                targets[s, i] = c
        timer.add("speed_phases", time.perf_counter() - t0)
        # regularisation of NN_Omega by leave-one-orbit-out CV on the profiles (primary member)
        grid_l = (
            [float(v) for v in self.omega_regularization_grid]
            if self.omega_regularization == "cv"
            else [float(self.omega_regularization)]
        )
        key = jax.random.key(self.seed + 1)
        pr = self.primary_
        fit = hs.profile_trainer(cfg)
        lam_o = grid_l[0]
        self.speed_cv_ = {}
        if len(grid_l) > 1 and np.sum(active) >= 3:
            score = []
            for lam in grid_l:
                held = []
                for i in np.nonzero(active)[0]:
                    w = weights * (np.arange(n) != i)
                    om0 = hs.init_speed_params(key, cfg, rho[pr], prep.mu_t, targets[pr], w)
                    _, hist = timer.run(
                        "speed_cv", fit, om0, jnp.asarray(rho[pr]), jnp.asarray(prep.mu_t),
                        jnp.asarray(targets[pr]), jnp.asarray(w), jnp.asarray(lam),
                    )
                    held.append(float(np.asarray(hist)[-1, i]))
                score.append(float(np.mean(held)))
            lam_o = grid_l[int(np.argmin(score))]
            self.speed_cv_ = {"grid": grid_l, "score": score, "selected": lam_o}
        self.speed_regularization_ = lam_o
        # fit each member's network to its profiles, then refine on eq. 5.13
        z = np.zeros((n, n_steps, 2))
        mask = np.zeros((n, n_steps))
        for i in range(n):
            w = windows[i]
            z[i, : len(w)] = prep.plane_points(i, w)
            mask[i, : len(w)] = weights[i]
        refine = hs.series_trainer(cfg, n_steps) if cfg.n_refine > 0 else None
        members, losses = [], []
        for s, k in enumerate(jax.random.split(key, S)):
            om0 = hs.init_speed_params(k, cfg, rho[s], prep.mu_t, targets[s], weights)
            om, _ = timer.run(
                "speed_profiles", fit, om0, jnp.asarray(rho[s]), jnp.asarray(prep.mu_t),
                jnp.asarray(targets[s]), jnp.asarray(weights), jnp.asarray(lam_o),
            )
            if refine is not None:
                om_r, res0, res1 = timer.run(
                    "speed_series", refine, om, _index(self.map_params_, s), jnp.asarray(rho[s]),
                    jnp.asarray(prep.mu_t), jnp.asarray(theta0[s]), jnp.asarray(h),
                    jnp.asarray(z), jnp.asarray(mask), jnp.asarray(lam_o),
                    jnp.asarray(self.omega_scale_),
                )
                start = float(np.mean(np.asarray(res0)))
                end_ = float(np.mean(np.asarray(res1)))
                # keep the refinement only if it improved eq. 5.13 (it starts from the profiles)
                if np.isfinite(end_) and end_ <= start:
                    om = om_r
                losses.append({"series_start": start, "series_end": end_})
            members.append(om)
        self.speed_params_ = _to_numpy(_stack(members))
        self.speed_losses_ = losses
        self._speed_targets = targets

    # ------------------------------------------------------- other signals (U_3..m)
    def _fit_observation(self, prep: Prepared, timer: _Timer, active: np.ndarray) -> None:
        self.observation_ = []
        if not self.others_:
            return
        t0 = time.perf_counter()
        hyper = None
        models: list[ObservationModel | None] = [None] * self.n_members_
        order = [self.primary_] + [s for s in range(self.n_members_) if s != self.primary_]
        for s in order:
            rho = self._member_rho(s, prep.mu_t, prep.branch)
            xs, ys, gs = [], [], []
            for i in np.nonzero(active)[0]:
                zn = prep.zn[i]
                take = _one_period(prep, i, POINTS_PER_ORBIT)
                ph = self._phases(s, i, prep, rho[i], prep.plane_points(i, take))
                u = rho[i] * np.stack([np.cos(ph), np.sin(ph)], axis=1)
                xs.append(np.column_stack([u, np.full(len(ph), prep.mu_t[i])]))
                ys.append(zn[take][:, list(self.others_)])
                gs.append(np.full(len(ph), i))
            x, y, g = np.concatenate(xs), np.concatenate(ys), np.concatenate(gs)
            if hyper is None:
                model = fit_observation(x, y, g)
                hyper = (model.length, model.ridge)
            else:
                model = fit_observation(x, y, g, *hyper)
            models[s] = model
        self.observation_ = models
        timer.add("observation", time.perf_counter() - t0)

    def _training_summary(self, prep: Prepared, d: LCOData, active: np.ndarray) -> None:
        idx = np.nonzero(active)[0]
        self.training_params_ = d.params[idx].copy()
        self.training_branch_ = d.branch[idx].copy()
        self.training_amplitude_ = np.array(
            [_measured_amplitude(d.signals[i], prep.omega[i], d.sample_rates[i]) for i in idx]
        )
        self.training_frequency_ = prep.omega[idx].copy()

    # ---------------------------------------------------------------- predictions
    def _check_fitted(self) -> None:
        if not hasattr(self, "map_params_"):
            raise NotFittedError(
                "This HopfHybridModel is not fitted yet; call fit(data) or load a saved model."
            )

    def _mu_t(self, mu):
        return (np.asarray(mu, dtype=float) - self.mu_c_) / self.mu_s_

    def _a2(self, s: int) -> float:
        return float(hm.a2_of(jnp.asarray(self.map_params_["alpha"][s]), self.a2_mode_))

    def _mu0_t(self, s: int) -> float:
        return float(self.map_params_["mu0"][s])

    def hopf_point(self, member: int | None = None) -> dict[str, Any]:
        r"""The Hopf point :math:`\mu_0` with its frequency and criticality.

        Returns
        -------
        dict
            ``param`` (raw units), ``omega`` (rad/s, :math:`2\pi/T` at :math:`r \to 0`),
            ``lyapunov`` (:math:`a_2` in raw units: the normal form's cubic coefficient;
            its sign gives the criticality), ``criticality``.
        """
        self._check_fitted()
        s = self.primary_ if member is None else member
        mu0_t = self._mu0_t(s)
        T = self._period(s, np.array([0.0]), np.array([mu0_t]))[0]
        a2 = raw_a2(self._a2(s), self.mu_s_, self.q5_)
        return {
            "param": mu0_t * self.mu_s_ + self.mu_c_,
            "omega": 2 * math.pi / T,
            "lyapunov": a2,
            "criticality": "subcritical" if a2 > 0 else "supercritical",
        }

    def cycle_fold(self, member: int | None = None) -> dict[str, Any] | None:
        r"""The fold of cycles :math:`\mu_0 - a_2^2/4` (``None`` if the model has none)."""
        self._check_fitted()
        s = self.primary_ if member is None else member
        a2 = self._a2(s)
        if not self.q5_ or a2 <= 0:
            return None
        mu_t = self._mu0_t(s) - a2**2 / 4
        rho = math.sqrt(a2 / 2)
        T = self._period(s, np.array([rho]), np.array([mu_t]))[0]
        amp = self._amplitudes(s, np.array([mu_t]), np.array([rho]))[0]
        return {
            "param": mu_t * self.mu_s_ + self.mu_c_,
            "period": T,
            "amplitude": dict(zip(self.signal_names_, amp.tolist(), strict=True)),
        }

    @property
    def mu0_(self) -> float:
        """Hopf point (raw units) of the primary member."""
        self._check_fitted()
        return self._mu0_t(self.primary_) * self.mu_s_ + self.mu_c_

    @property
    def a2_(self) -> float:
        """:math:`a_2` of eq. 5.3 in raw parameter units (primary member)."""
        self._check_fitted()
        return raw_a2(self._a2(self.primary_), self.mu_s_, self.q5_)

    @property
    def omega0_(self) -> float:
        """:math:`\\omega_0` of eq. 5.10 [rad/s]: the speed's constant term (primary member)."""
        self._check_fitted()
        w0 = float(self.speed_params_["w0"][self.primary_])
        return self.omega_scale_ * (math.exp(w0) if self.speed_config_.form == "log" else w0)

    def _speed_grid(self, s: int, rho: np.ndarray, mu_t: np.ndarray) -> np.ndarray:
        """:math:`\\Omega` on 512 uniform phases for each ``(rho, mu_t)``, shape ``(n, 512)``."""
        om = _index(self.speed_params_, s)
        return np.asarray(
            hs.speed_on_grid_fn(self.speed_config_)(
                om, jnp.asarray(rho, dtype=float), jnp.asarray(mu_t, dtype=float),
                jnp.asarray(self.omega_scale_),
            )
        )

    def _period(self, s: int, rho: np.ndarray, mu_t: np.ndarray) -> np.ndarray:
        """Period :math:`T = \\int_0^{2\\pi} \\mathrm d\\theta/\\Omega` (NaN where
        :math:`\\Omega` is not positive)."""
        v = self._speed_grid(s, np.atleast_1d(rho), np.atleast_1d(mu_t))
        with np.errstate(divide="ignore"):
            T = 2 * np.pi * np.mean(1.0 / v, axis=1)
        return np.where(np.min(v, axis=1) > 0, T, np.nan)

    def _cycle_points(self, s: int, mu_t: float, rho: float, phi: np.ndarray) -> np.ndarray:
        """All signals (data units) at normal-form phases ``phi`` of the cycle ``rho``."""
        mp = _index(self.map_params_, s)
        u = rho * np.stack([np.cos(phi), np.sin(phi)], axis=1)
        plane = np.asarray(_u12_batch(mp, self.width, self.depth, u, mu_t))
        out = np.zeros((len(phi), len(self.signal_names_)))
        out[:, list(self.plane_)] = plane @ np.linalg.inv(self.white_)
        if self.others_:
            x = np.column_stack([u, np.full(len(phi), mu_t)])
            out[:, list(self.others_)] = self.observation_[s].predict(x)
        return out * self.z_scale_[None, :]

    def _amplitudes(self, s: int, mu_t: np.ndarray, rho: np.ndarray) -> np.ndarray:
        phi = np.linspace(0, 2 * np.pi, _N_CYCLE, endpoint=False)
        return np.array(
            [np.max(np.abs(self._cycle_points(s, m, r, phi)), axis=0) for m, r in
             zip(mu_t, rho, strict=True)]
        )

    def _branch_samples(self, s: int, lo_t: float, hi_t: float, n: int):
        """Points ``(mu_t, rho, root)`` along the model's cycle branch within ``[lo, hi]``.

        The branch is the graph :math:`\\tilde\\mu(\\rho) = \\tilde\\mu_0 - a_2\\rho^2 +
        q_5\\rho^4`, sampled uniformly in :math:`\\rho` so the fold is passed smoothly.
        """
        mu0, a2, q5 = self._mu0_t(s), self._a2(s), self.q5_
        # largest radius with mu(rho) <= hi (outer branch rises with rho beyond the fold)
        if q5:
            r2_hi = (a2 + math.sqrt(max(a2**2 + 4 * (hi_t - mu0), 0.0))) / 2 \
                if a2**2 + 4 * (hi_t - mu0) >= 0 else 0.0
        else:
            r2_hi = max(-(hi_t - mu0) / a2, 0.0)
        rho = np.linspace(0.0, math.sqrt(max(r2_hi, 0.0)), n)[1:]
        mu = mu0 - a2 * rho**2 + q5 * rho**4
        keep = (mu >= lo_t - 1e-12) & (mu <= hi_t + 1e-12)
        rho, mu = rho[keep], mu[keep]
        deriv = growth_derivative(rho**2, mu, mu0, a2, q5)
        return mu, rho, deriv

    def predict_diagram(
        self,
        param_range: tuple[float, float] | None = None,
        n_points: int = 100,
        member: int | None = None,
    ) -> dict[str, Any]:
        """The bifurcation diagram: Hopf point, fold of cycles and the cycle branch.

        Parameters
        ----------
        param_range : (lo, hi), optional
            Parameter interval (default: the training range widened by 25 %).
        n_points : int
            Points along the branch (before clipping to the interval).
        member : int, optional
            Ensemble member (default: the primary, medoid member).

        Returns
        -------
        dict
            ``hopf``, ``cycle_folds`` (lists as in ``bifid continue``), ``orbits``: one entry
            per branch point with ``param``, ``period``, ``stable``, ``floquet_max``
            (:math:`\\exp(T\\,\\partial_r\\dot r)` of the normal form: > 1 unstable),
            ``amplitude`` {signal: max_t |z|}; ``band``: the ensemble's min/max amplitude of
            each signal on a parameter grid, per branch.
        """
        self._check_fitted()
        s = self.primary_ if member is None else int(member)
        lo, hi = self._range(param_range)
        lo_t, hi_t = float(self._mu_t(lo)), float(self._mu_t(hi))
        mu, rho, deriv = self._branch_samples(s, lo_t, hi_t, max(int(n_points), 3))
        T = self._period(s, rho, mu) if len(rho) else np.zeros(0)
        amps = self._amplitudes(s, mu, rho) if len(rho) else np.zeros((0, len(self.signal_names_)))
        orbits = []
        for k in range(len(rho)):
            # multiplier of the radial direction over one period, normal-form time units
            fm = math.exp(float(np.clip(deriv[k] * self.mu_s_ * T[k], -700, 700))) \
                if np.isfinite(T[k]) else float("nan")
            orbits.append(
                {
                    # back from normal-form units; clipped: the round trip can land an
                    # ulp outside the interval the samples were taken in
                    "param": float(np.clip(mu[k] * self.mu_s_ + self.mu_c_, lo, hi)),
                    "period": float(T[k]),
                    "stable": bool(deriv[k] < 0),
                    "floquet_max": fm,
                    "amplitude": dict(zip(self.signal_names_, amps[k].tolist(), strict=True)),
                }
            )
        hopf = self.hopf_point(s)
        fold = self.cycle_fold(s)
        return {
            "hopf": [hopf] if lo <= hopf["param"] <= hi else [],
            "cycle_folds": [fold] if fold is not None and lo <= fold["param"] <= hi else [],
            "secondary": [],
            "orbits": orbits,
            "band": self.diagram_band((lo, hi), n_points=max(int(n_points) // 2, 10)),
        }

    def diagram_band(self, param_range: tuple[float, float], n_points: int = 50) -> dict:
        """Ensemble band: per branch, parameter grid and min/median/max amplitude per signal."""
        self._check_fitted()
        lo, hi = param_range
        grid = np.linspace(lo, hi, n_points)
        out: dict[str, Any] = {"param": grid.tolist(), "branches": {}}
        roots = (1.0, -1.0) if self.q5_ else (1.0,)
        for root in roots:
            name = "outer" if root > 0 else "inner"
            vals = np.full((self.n_members_, n_points, len(self.signal_names_)), np.nan)
            for s in range(self.n_members_):
                a2, mu0 = self._a2(s), self._mu0_t(s)
                for k, m in enumerate(self._mu_t(grid)):
                    r2 = self._radius2(m, mu0, a2, root)
                    if r2 is not None:
                        vals[s, k] = self._amplitudes(
                            s, np.array([m]), np.array([math.sqrt(r2)])
                        )[0]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                out["branches"][name] = {
                    sig: {
                        "min": _nan_list(np.nanmin(vals[:, :, j], axis=0)),
                        "median": _nan_list(np.nanmedian(vals[:, :, j], axis=0)),
                        "max": _nan_list(np.nanmax(vals[:, :, j], axis=0)),
                        "count": np.sum(np.isfinite(vals[:, :, j]), axis=0).tolist(),
                    }
                    for j, sig in enumerate(self.signal_names_)
                }
        hopfs = [self.hopf_point(s)["param"] for s in range(self.n_members_)]
        folds = [f["param"] for s in range(self.n_members_) if (f := self.cycle_fold(s))]
        out["hopf_param"] = _spread(hopfs)
        out["fold_param"] = _spread(folds) if folds else None
        return out

    def _radius2(self, mu_t: float, mu0: float, a2: float, root: float) -> float | None:
        if self.q5_:
            disc = a2**2 + 4 * (mu_t - mu0)
            if disc < 0:
                return None
            r2 = 0.5 * (a2 + root * math.sqrt(disc))
        else:
            r2 = -(mu_t - mu0) / a2
        return r2 if r2 > 0 else None

    def _range(self, param_range):
        if param_range is None:
            lo, hi = float(np.min(self.training_params_)), float(np.max(self.training_params_))
            pad = 0.25 * (hi - lo)
            lo, hi = lo - pad, hi + pad
            hopf = self.mu0_
            lo, hi = min(lo, hopf - pad), max(hi, hopf + pad)
            return lo, hi
        lo, hi = (float(v) for v in param_range)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise BifidInputError(f"param_range must be finite with lo < hi, got {param_range}.")
        return lo, hi

    def _cycle(self, param: float, branch: str, member: int | None):
        self._check_fitted()
        s = self.primary_ if member is None else int(member)
        if branch not in ("stable", "unstable"):
            raise BifidInputError(f"branch must be 'stable' or 'unstable', got {branch!r}.")
        if not math.isfinite(float(param)):
            raise BifidInputError(f"param must be finite, got {param!r}.")
        mu_t = float(self._mu_t(param))
        a2, mu0 = self._a2(s), self._mu0_t(s)
        found = None
        for root in ((1.0, -1.0) if self.q5_ else (1.0,)):
            r2 = self._radius2(mu_t, mu0, a2, root)
            if r2 is None:
                continue
            stable = growth_derivative(r2, mu_t, mu0, a2, self.q5_) < 0
            if stable == (branch == "stable"):
                found = r2
                break
        if found is None:
            raise BifidInputError(
                f"The model has no {branch} limit cycle at {self.param_name_}={param:g} "
                f"(Hopf point {self.hopf_point(s)['param']:.4g}"
                + (f", fold {fold['param']:.4g}" if (fold := self.cycle_fold(s)) else "")
                + ")."
            )
        return s, mu_t, math.sqrt(found)

    def predict_amplitude(
        self, params: Sequence[float], branch: str = "stable", member: int | None = None
    ) -> np.ndarray:
        """Amplitudes ``max_t |z_k(t)|`` of every signal, shape ``(len(params), n_signals)``.

        Raises
        ------
        BifidInputError
            Where the model has no cycle on ``branch``.
        """
        out = []
        for p in np.atleast_1d(np.asarray(params, dtype=float)):
            s, mu_t, rho = self._cycle(float(p), branch, member)
            out.append(self._amplitudes(s, np.array([mu_t]), np.array([rho]))[0])
        return np.asarray(out)

    def predict_frequency(
        self, params: Sequence[float], branch: str = "stable", member: int | None = None
    ) -> np.ndarray:
        """Angular frequency :math:`2\\pi/T` [rad/s] of the cycles at ``params``."""
        out = []
        for p in np.atleast_1d(np.asarray(params, dtype=float)):
            s, mu_t, rho = self._cycle(float(p), branch, member)
            out.append(2 * math.pi / self._period(s, np.array([rho]), np.array([mu_t]))[0])
        return np.asarray(out)

    def _phase_of_time(self, s, mu_t, rho, times, theta0):
        """:math:`\\theta(t)` of the phase equation, exactly by inverting
        :math:`t(\\theta) = \\int \\mathrm d\\theta/\\Omega` on a fine grid (no ODE solve)."""
        speed = self._speed_grid(s, np.array([rho]), np.array([mu_t]))[0]
        if np.any(speed <= 0):
            raise ConvergenceError(
                "The learnt oscillation speed vanishes on this cycle; the model cannot produce "
                "a time series here."
            )
        n = len(speed)
        grid = np.linspace(0, 2 * np.pi, n + 1)
        inv = 1.0 / np.concatenate([speed, speed[:1]])
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(grid))])
        T = cum[-1]
        tau = np.interp(np.mod(theta0, 2 * np.pi), grid, cum) + (np.asarray(times) - times[0])
        k = np.floor(tau / T)
        return np.interp(tau - k * T, cum, grid) + 2 * np.pi * k, T

    def predict_time_series(
        self,
        param: float,
        times: np.ndarray,
        branch: str = "stable",
        *,
        initial: np.ndarray | None = None,
        initial_phase: float = 0.0,
        member: int | None = None,
    ) -> np.ndarray:
        """Time series of every signal on the cycle at ``param``, shape ``(len(times), m)``.

        Parameters
        ----------
        param : float
        times : array of shape (n,)
            Increasing times [s].
        branch : {"stable", "unstable"}
        initial : array of shape (m,), optional
            A measured sample at ``times[0]``; the initial phase is matched to its polar angle
            in the plane (eq. 5.12). Otherwise ``initial_phase`` (normal-form phase) is used.
        """
        s, mu_t, rho = self._cycle(float(param), branch, member)
        times = np.asarray(times, dtype=float)
        if times.ndim != 1 or len(times) < 1 or np.any(np.diff(times) <= 0):
            raise BifidInputError("times must be a 1-D increasing array.")
        th0 = float(initial_phase)
        if initial is not None:
            z0 = np.asarray(initial, dtype=float) / self.z_scale_
            mp = _index(self.map_params_, s)
            ring = rho * np.stack([np.cos(np.linspace(0, 2 * np.pi, 256, endpoint=False)),
                                   np.sin(np.linspace(0, 2 * np.pi, 256, endpoint=False))], 1)
            centre = np.mean(np.asarray(_u12_batch(mp, self.width, self.depth, ring, mu_t)), 0)
            phi, ang = hm_angles(mp, self.width, self.depth, mu_t, rho, centre)
            d = z0[list(self.plane_)] @ self.white_ - centre
            th0 = float(hs.invert_phase(phi, ang, np.array([math.atan2(d[1], d[0])]))[0][0])
        theta, _ = self._phase_of_time(s, mu_t, rho, times, th0)
        return self._cycle_points(s, mu_t, rho, theta)

    def predict_orbit(
        self, param: float, branch: str = "stable", n_points: int = 256,
        member: int | None = None,
    ) -> dict[str, Any]:
        """One period of the cycle (phase portrait): ``{"t", "signals", "period"}``."""
        s, mu_t, rho = self._cycle(float(param), branch, member)
        T = float(self._period(s, np.array([rho]), np.array([mu_t]))[0])
        t = np.linspace(0.0, T, int(n_points), endpoint=False)
        z = self.predict_time_series(param, t, branch, member=s)
        return {"t": t, "signals": z, "period": T}

    # ------------------------------------------------------------ cross-validation
    def cross_validate(self, data: Any, signal_names: Sequence[str] | None = None) -> dict:
        """Leave-one-orbit-out validation with the fitted hyperparameters.

        For every record: retrain without it (all stages, one ensemble member, the selected
        regularisation and stopping of this model) and predict the held-out orbit's
        amplitudes and frequency. The hyperparameters were chosen on all records, so the
        errors are slightly optimistic. (The left-out record keeps its slot with weight 0,
        so every fold reuses the compiled training loops; only the normalisation constants
        of the parameter and signals see it.)

        Returns
        -------
        dict
            ``folds``: per record ``param``, ``stable``, measured and predicted ``amplitude``
            {signal}, relative ``amplitude_error`` {signal}, ``frequency`` and its error,
            the fold model's ``hopf`` and ``fold`` parameters (``error`` set when the held-out
            cycle does not exist in the fold model); ``summary``: mean/max errors.
        """
        self._check_fitted()
        d = as_lco_data(data, signal_names)
        hyper = self.get_params()
        hyper.update(
            regularization=float(self.regularization_),
            stopping=int(self.n_iterations_),
            n_ensemble=1,
            omega_regularization=float(self.speed_regularization_),
            criticality=self.criticality_,
            quintic=bool(self.q5_),
            plane=tuple(self.signal_names_[i] for i in self.plane_),
            progress=False,
        )
        folds = []
        prep_all = prepare(d, self.plane_, self.map_config_.n_harmonics, mu_c=self.mu_c_,
                           mu_s=self.mu_s_, z_scale=self.z_scale_, white=self.white_)
        for i in range(d.n_records):
            active = np.arange(d.n_records) != i
            model = HopfHybridModel(**hyper)
            model._validate_hyper()
            with _blas_single_thread(), warnings.catch_warnings():
                warnings.simplefilter("ignore", ConvergenceWarning)
                model._fit(d, None, active)
            omega_i = float(prep_all.omega[i])
            meas = _measured_amplitude(d.signals[i], omega_i, d.sample_rates[i])
            branch = "unstable" if d.branch[i] == UNSTABLE else "stable"
            entry: dict[str, Any] = {
                "param": float(d.params[i]),
                "stable": bool(d.branch[i] != UNSTABLE),
                "measured_amplitude": dict(zip(d.signal_names, meas.tolist(), strict=True)),
                "measured_frequency": omega_i,
                "hopf": model.hopf_point()["param"],
                "fold": (f["param"] if (f := model.cycle_fold()) else None),
            }
            try:
                amp = model.predict_amplitude([d.params[i]], branch)[0]
                freq = float(model.predict_frequency([d.params[i]], branch)[0])
                entry["amplitude"] = dict(zip(d.signal_names, amp.tolist(), strict=True))
                entry["amplitude_error"] = {
                    k: float(abs(a - b) / b)
                    for k, a, b in zip(d.signal_names, amp, meas, strict=True)
                }
                entry["frequency"] = freq
                entry["frequency_error"] = abs(freq - omega_i) / omega_i
            except BifidInputError as exc:
                entry["error"] = str(exc)
            folds.append(entry)
        ok = [f for f in folds if "amplitude_error" in f]
        summary = {
            "n_folds": len(folds),
            "n_missing": len(folds) - len(ok),
            "amplitude_error_mean": {
                k: float(np.mean([f["amplitude_error"][k] for f in ok])) if ok else None
                for k in d.signal_names
            },
            "amplitude_error_max": {
                k: float(np.max([f["amplitude_error"][k] for f in ok])) if ok else None
                for k in d.signal_names
            },
            "frequency_error_max": float(np.max([f["frequency_error"] for f in ok]))
            if ok else None,
        }
        return {"folds": folds, "summary": summary}

    # ---------------------------------------------------------------- persistence
    def parameters(self) -> dict[str, Any]:
        """Fitted values by name (what ``bifid fit hopf --json`` reports as ``parameters``)."""
        self._check_fitted()
        fold = self.cycle_fold()
        hopf = self.hopf_point()
        band = {
            "mu0": _spread([self.hopf_point(s)["param"] for s in range(self.n_members_)]),
            "a2": _spread(
                [raw_a2(self._a2(s), self.mu_s_, self.q5_) for s in range(self.n_members_)]
            ),
        }
        folds = [f["param"] for s in range(self.n_members_) if (f := self.cycle_fold(s))]
        if folds:
            band["fold"] = _spread(folds)
        return {
            "mu0": self.mu0_,
            "a2": self.a2_,
            "q5": self.q5_,
            "omega0": self.omega0_,
            "hopf_omega": hopf["omega"],
            "fold": fold["param"] if fold else None,
            "criticality": self.criticality_,
            "param_name": self.param_name_,
            "regularization": self.regularization_,
            "n_iterations": self.n_iterations_,
            "omega_regularization": self.speed_regularization_,
            "n_members": self.n_members_,
            "primary_member": self.primary_,
            "ensemble": band,
        }

    def save(self, directory: str | Path, settings: dict | None = None) -> Path:
        """Save as ``model.json`` + ``arrays.npz`` (:func:`bifid.io.save_model`; no pickle)."""
        from bifid.io import save_model

        self._check_fitted()
        arrays: dict[str, np.ndarray] = {}
        for j, leaf in enumerate(jax.tree_util.tree_leaves(self.map_params_)):
            arrays[f"map_{j}"] = np.asarray(leaf)
        for j, leaf in enumerate(jax.tree_util.tree_leaves(self.speed_params_)):
            arrays[f"speed_{j}"] = np.asarray(leaf)
        for s, obs in enumerate(self.observation_):
            arrays.update(obs.arrays(f"obs{s}_"))
        arrays.update(
            z_scale=self.z_scale_,
            white=self.white_,
            training_params=self.training_params_,
            training_branch=self.training_branch_,
            training_amplitude=self.training_amplitude_,
            training_frequency=self.training_frequency_,
        )
        params = {
            "hyperparameters": self.get_params(),
            "fitted": self.parameters(),
            "state": {
                "plane": list(self.plane_),
                "others": list(self.others_),
                "mu_c": self.mu_c_,
                "mu_s": self.mu_s_,
                "direction": self.direction_,
                "criticality": self.criticality_,
                "q5": self.q5_,
                "a2_mode": self.a2_mode_,
                "signal_names": list(self.signal_names_),
                "param_name": self.param_name_,
                "param_units": self.param_units_,
                "signal_units": self.signal_units_,
                "map_config": dict(self.map_config_.__dict__),
                "speed_config": dict(self.speed_config_.__dict__),
                "omega_scale": self.omega_scale_,
                "n_members": self.n_members_,
                "primary": self.primary_,
                "regularization": self.regularization_,
                "n_iterations": self.n_iterations_,
                "speed_regularization": self.speed_regularization_,
                "cv": self.cv_,
                "speed_cv": self.speed_cv_,
                "map_losses": self.map_losses_,
                "speed_losses": self.speed_losses_,
                "timings": self.timings_,
            },
        }
        return save_model(directory, MODEL_TYPE, params, arrays, settings or {})

    @classmethod
    def load(cls, directory: str | Path) -> HopfHybridModel:
        """Load a model saved by :meth:`save`.

        Raises
        ------
        BifidInputError
            If the directory is not a ``hopf_hybrid`` model or is malformed.
        """
        from bifid.io import load_model

        meta, arrays = load_model(directory)
        if meta.get("type") != MODEL_TYPE:
            raise BifidInputError(
                f"{str(directory)!r} holds a {meta.get('type')!r} model, not {MODEL_TYPE!r}."
            )
        try:
            p = meta["params"]
            hyper = dict(p["hyperparameters"])
            if hyper.get("plane") is not None:
                hyper["plane"] = tuple(hyper["plane"])
            model = cls(**hyper)
            st = p["state"]
            model.plane_ = tuple(st["plane"])
            model.others_ = tuple(st["others"])
            model.mu_c_, model.mu_s_ = float(st["mu_c"]), float(st["mu_s"])
            model.direction_ = float(st["direction"])
            model.criticality_ = st["criticality"]
            model.q5_ = float(st["q5"])
            model.a2_mode_ = st["a2_mode"]
            model.signal_names_ = tuple(st["signal_names"])
            model.param_name_ = st["param_name"]
            model.param_units_ = st["param_units"]
            model.signal_units_ = dict(st["signal_units"])
            model.map_config_ = hm.MapConfig(**st["map_config"])
            model.speed_config_ = hs.SpeedConfig(**st["speed_config"])
            model.omega_scale_ = float(st["omega_scale"])
            model.n_members_ = int(st["n_members"])
            model.primary_ = int(st["primary"])
            model.regularization_ = float(st["regularization"])
            model.n_iterations_ = int(st["n_iterations"])
            model.speed_regularization_ = float(st["speed_regularization"])
            model.cv_ = st["cv"]
            model.speed_cv_ = st["speed_cv"]
            model.map_losses_ = st["map_losses"]
            model.speed_losses_ = st["speed_losses"]
            model.timings_ = st["timings"]
            model.z_scale_ = arrays["z_scale"]
            model.white_ = _checked(arrays["white"], (2, 2))
            model.training_params_ = arrays["training_params"]
            model.training_branch_ = arrays["training_branch"]
            model.training_amplitude_ = arrays["training_amplitude"]
            model.training_frequency_ = arrays["training_frequency"]
            S = model.n_members_
            cfg = model.map_config_
            skel_map = _stack([_map_skeleton(cfg)] * S)
            leaves, tdef = jax.tree_util.tree_flatten(skel_map)
            model.map_params_ = jax.tree_util.tree_unflatten(
                tdef, [_checked(arrays[f"map_{j}"], leaf.shape) for j, leaf in enumerate(leaves)]
            )
            scfg = model.speed_config_
            skel_speed = _stack([hs.init_speed_params(jax.random.key(0), scfg)] * S)
            leaves, tdef = jax.tree_util.tree_flatten(skel_speed)
            model.speed_params_ = jax.tree_util.tree_unflatten(
                tdef,
                [_checked(arrays[f"speed_{j}"], leaf.shape) for j, leaf in enumerate(leaves)],
            )
            model.observation_ = (
                [ObservationModel.from_arrays(arrays, f"obs{s}_") for s in range(S)]
                if model.others_ else []
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise BifidInputError(
                f"{str(directory)!r} is not a valid {MODEL_TYPE} model: {exc!r}"
            ) from None
        return model


# ----------------------------------------------------------------------------- helpers
def _checked(arr: np.ndarray, shape) -> np.ndarray:
    if tuple(arr.shape) != tuple(shape):
        raise ValueError(f"array of shape {arr.shape} where {tuple(shape)} was expected")
    return arr


def _map_skeleton(cfg: hm.MapConfig):
    net = hm.mlp(jax.random.key(0), 3, 2, cfg.width, cfg.depth, 0.0)
    return {
        "L": jnp.zeros((2, 3)),
        "s": jnp.zeros(2),
        "nn": eqx.filter(net, eqx.is_array),
        "mu0": jnp.asarray(0.0),
        "alpha": jnp.asarray(0.0),
    }


def _spread(values) -> dict[str, float]:
    v = np.asarray(values, dtype=float)
    return {
        "median": float(np.median(v)),
        "min": float(np.min(v)),
        "max": float(np.max(v)),
        "std": float(np.std(v)),
    }


def _nan_list(v: np.ndarray) -> list:
    return [float(x) if np.isfinite(x) else None for x in v]


def _one_period(prep: Prepared, i: int, n: int) -> np.ndarray:
    """``n`` sample indices spread evenly over the first period of record ``i``."""
    fs = 1.0 / (prep.times[i][1] - prep.times[i][0])
    n_per = min(len(prep.zn[i]) - 1, round(2 * np.pi / prep.omega[i] * fs))
    return np.unique(np.linspace(0, n_per, n, endpoint=False).astype(int))


def _measured_amplitude(sig: np.ndarray, omega: float, fs: float) -> np.ndarray:
    """Noise-robust ``max_t |z_k|`` of a record: maximum of its 20-harmonic Fourier series at
    the record's frequency (offset kept: amplitudes are about the signals' zero)."""
    from bifid.signal import evaluate_series, fourier_fit

    out = []
    theta = np.linspace(0, 2 * np.pi, 2048, endpoint=False)
    nh = int(max(1, min(20, (len(sig) - 1) // 8)))
    for k in range(sig.shape[1]):
        val = evaluate_series(fourier_fit(sig[:, k], omega, fs, nh), theta)
        out.append(np.max(np.abs(val)))
    return np.asarray(out)


def _u12_batch(mp, width: int, depth: int, u: np.ndarray, mu_t: float) -> Array:
    return _u12_compiled(width, depth)(mp, jnp.asarray(u), jnp.asarray(mu_t))


def hm_angles(mp, width: int, depth: int, mu_t: float, rho: float, centre) -> tuple:
    phi = np.linspace(0.0, 2 * np.pi, _N_GRID_INVERSE, endpoint=False)
    u = rho * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    pts = np.asarray(_u12_batch(mp, width, depth, u, mu_t))
    d = pts - np.asarray(centre)[None, :]
    return phi, np.arctan2(d[:, 1], d[:, 0])


_U12_CACHE: dict = {}


def _u12_compiled(width: int, depth: int):
    key = (width, depth)
    if key not in _U12_CACHE:
        static = hm.mlp_static(3, 2, width, depth)
        _U12_CACHE[key] = jax.jit(
            lambda mp, u, m: jax.vmap(lambda ui: hm.u12(mp, static, ui, m))(u)
        )
    return _U12_CACHE[key]
