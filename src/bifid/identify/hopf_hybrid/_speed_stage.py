r"""Training of the oscillation speed :math:`\Omega` (thesis §5.3.3, eqs. 5.10–5.13).

Under each member's trained map, every measured sample gets a normal-form phase by the
inversion of eq. 5.12 (:class:`PhaseMatcher`); each orbit's phases give its speed profile,
whose Fourier coefficients are the targets of :math:`\mathrm{NN}_{\Theta_\Omega}` (its L2
weight by leave-one-orbit-out CV); the network is then refined on eq. 5.13, integrating only
the phase equation on each orbit's model cycle (:func:`~._speed.series_trainer`).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from bifid.errors import ConvergenceError, ConvergenceWarning
from bifid.identify.hopf_hybrid import _map as hm
from bifid.identify.hopf_hybrid import _speed as hs
from bifid.identify.hopf_hybrid._normal_form import EITHER, lco_radius2
from bifid.identify.hopf_hybrid._prepare import Prepared
from bifid.identify.hopf_hybrid._state import member, plane_angles, stack
from bifid.identify.hopf_hybrid._timing import StageTimer
from bifid.signal import evaluate_series, fourier_project

__all__ = ["PhaseMatcher", "SpeedFit", "speed_stage", "train_speed"]


class PhaseMatcher:
    """Cycle radius and normal-form phases of the measured orbits under each member's map.

    Parameters
    ----------
    map_params : dict
        Stacked parameters of the members.
    config : MapConfig
    prep : Prepared
    active : ndarray of bool
        Orbits that take part in training.
    param_name : str
        For messages.
    """

    def __init__(
        self,
        map_params: Any,
        config: hm.MapConfig,
        prep: Prepared,
        active: np.ndarray,
        param_name: str,
    ) -> None:
        self.map_params, self.config, self.prep = map_params, config, prep
        self.active, self.param_name = active, param_name

    def rho(self, s: int) -> np.ndarray:
        """Cycle radius of every orbit for member ``s`` (an unlabelled orbit: the root whose
        model cycle fits it better)."""
        mp = member(self.map_params, s)
        a2 = hm.a2_of(jnp.asarray(mp["alpha"]), self.config.a2_mode)
        out = []
        for i, (m, b) in enumerate(zip(self.prep.mu_t, self.prep.root, strict=True)):
            root = 1.0 if b >= 0 else -1.0
            if b == EITHER and self.config.q5:
                root = self._better_root(mp, i)
            r2 = float(lco_radius2(jnp.asarray(m), mp["mu0"], a2, self.config.q5, root))
            out.append(math.sqrt(max(r2, 1e-4)))
        return np.asarray(out)

    def _better_root(self, mp: Any, i: int) -> float:
        prep = self.prep
        train = np.nonzero(self.active)[0]
        j = train[int(np.argmin(np.abs(prep.mu_t[train] - prep.mu_t[i])))]
        static = hm.mlp_static(3, 2, self.config.width, self.config.depth)
        losses = [
            float(
                hm.orbit_loss(
                    mp,
                    static,
                    jnp.asarray(prep.mu_t[i]),
                    b,
                    jnp.asarray(prep.coef[j]),
                    jnp.asarray(prep.centre[j]),
                    self.config,
                )
            )
            for b in (1.0, -1.0)
        ]
        return 1.0 if losses[0] <= losses[1] else -1.0

    def phases(self, s: int, i: int, rho: float, pts: np.ndarray) -> np.ndarray:
        """Normal-form phases of plane points ``pts`` of orbit ``i`` (eq. 5.12)."""
        prep = self.prep
        phi, ang = plane_angles(
            member(self.map_params, s), self.config, prep.mu_t[i], rho, prep.centre[i]
        )
        d = pts - prep.centre[i][None, :]
        out, monotone = hs.invert_phase(phi, ang, np.arctan2(d[:, 1], d[:, 0]))
        if not monotone:
            warnings.warn(
                f"The model cycle at {self.param_name}="
                f"{prep.mu_t[i] * prep.mu_s + prep.mu_c:g} is not star-shaped about its "
                "centre; the phase matching of eq. 5.12 is approximate there.",
                ConvergenceWarning,
                stacklevel=4,
            )
        return out


@dataclass
class SpeedFit:
    """Result of :func:`train_speed`."""

    config: hs.SpeedConfig
    params: dict[str, Any]
    omega_scale: float
    regularization: float
    cv: dict[str, Any]
    losses: list[dict[str, float]]


def _windows(prep: Prepared, periods: float, samples: int) -> tuple[list, list, list]:
    """Training windows of eq. 5.13 (<= ``periods`` periods, <= ``samples`` samples per
    record, sample intervals ``h``) and the finer windows of the speed profiles."""
    windows, h, profile = [], [], []
    for i in range(len(prep.mu_t)):
        fs = 1.0 / (prep.times[i][1] - prep.times[i][0])
        n_take = int(min(len(prep.zn[i]), math.ceil(periods * 2 * np.pi / prep.omega[i] * fs) + 1))
        dec = max(1, math.ceil(n_take / samples))
        windows.append(np.arange(0, n_take, dec))
        h.append(dec / fs)
        profile.append(np.arange(0, n_take, max(1, math.ceil(n_take / 4000))))
    return windows, h, profile


def _targets(
    prep: Prepared,
    matcher: PhaseMatcher,
    s: int,
    rho: np.ndarray,
    i: int,
    window: np.ndarray,
    config: hs.SpeedConfig,
    omega_scale: float,
) -> tuple[np.ndarray, float]:
    """Fourier coefficients of orbit ``i``'s speed profile (log or additive form) and its
    initial phase, for member ``s``."""
    nh = config.n_harmonics
    grid = np.linspace(0, 2 * np.pi, 256, endpoint=False)
    ph = np.unwrap(matcher.phases(s, i, rho[i], prep.plane_points(i, window)))
    if np.sign(ph[-1] - ph[0]) < 0:
        raise ConvergenceError(
            f"The model cycle at {matcher.param_name}={prep.mu_t[i] * prep.mu_s + prep.mu_c:g}"
            " turns against the measured orbit; the coordinate map lost its orientation."
        )
    per_period = 2 * np.pi / prep.omega[i] / (prep.times[i][window[1]] - prep.times[i][0])
    prof = hs.speed_from_phase(
        prep.times[i][window],
        ph,
        prep.omega[i],
        grid,
        n_time_harmonics=int(min(40, per_period / 3)),
    )
    log = config.form == "log"
    c = fourier_project(np.log(prof / omega_scale) if log else prof / omega_scale, grid, nh)
    # the truncated profile must keep the measured period 2 pi / omega_i
    trunc = evaluate_series(c, grid)
    ratio = np.mean(1.0 / (np.exp(trunc) if log else trunc)) * prep.omega[i] / omega_scale
    if log:
        c[0] += np.log(ratio)
    else:
        c *= ratio
    return c, float(ph[0])


def train_speed(
    prep: Prepared,
    matcher: PhaseMatcher,
    active: np.ndarray,
    primary: int,
    *,
    config: hs.SpeedConfig,
    periods: float,
    samples: int,
    regularization_grid: Sequence[float],
    seed: int,
    timer: StageTimer,
) -> SpeedFit:
    """Fit :math:`\\Omega` of every member (module docstring)."""
    n_members = int(np.asarray(matcher.map_params["mu0"]).shape[0])
    n = len(prep.mu_t)
    weights = active.astype(float)
    windows, h, profile = _windows(prep, periods, samples)
    omega_scale = float(np.mean(prep.omega[active]))
    rho = np.zeros((n_members, n))
    theta0 = np.zeros((n_members, n))
    targets = np.zeros((n_members, n, 2 * config.n_harmonics + 1))
    t0 = time.perf_counter()
    for s in range(n_members):
        rho[s] = matcher.rho(s)
        for i in np.nonzero(active)[0]:
            targets[s, i], theta0[s, i] = _targets(
                prep, matcher, s, rho[s], i, profile[i], config, omega_scale
            )
    timer.add("speed_phases", time.perf_counter() - t0)
    key = jax.random.key(seed + 1)
    fit = hs.profile_trainer(config)

    def fit_profiles(stage, k, rho_s, targets_s, w, lam):
        """Initialise one member's speed network and fit it to the profiles ``targets_s``."""
        om0 = hs.init_speed_params(k, config, rho_s, prep.mu_t, targets_s, w)
        args = (rho_s, prep.mu_t, targets_s, w, lam)
        return timer.run(stage, fit, om0, *(jnp.asarray(a) for a in args))

    grid = [float(v) for v in regularization_grid]
    lam, cv = grid[0], {}
    if len(grid) > 1 and np.sum(active) >= 3:
        score = []
        for value in grid:
            held = []
            for i in np.nonzero(active)[0]:
                w = weights * (np.arange(n) != i)
                _, hist = fit_profiles("speed_cv", key, rho[primary], targets[primary], w, value)
                held.append(float(np.asarray(hist)[-1, i]))
            score.append(float(np.mean(held)))
        lam = grid[int(np.argmin(score))]
        cv = {"grid": grid, "score": score, "selected": lam}
    n_steps = max(len(w) for w in windows)
    z = np.zeros((n, n_steps, 2))
    mask = np.zeros((n, n_steps))
    for i in range(n):
        z[i, : len(windows[i])] = prep.plane_points(i, windows[i])
        mask[i, : len(windows[i])] = weights[i]
    refine = hs.series_trainer(config, n_steps) if config.n_refine > 0 else None
    members, losses = [], []
    for s, k in enumerate(jax.random.split(key, n_members)):
        om, _ = fit_profiles("speed_profiles", k, rho[s], targets[s], weights, lam)
        if refine is not None:
            om_r, res0, res1 = timer.run(
                "speed_series",
                refine,
                om,
                member(matcher.map_params, s),
                jnp.asarray(rho[s]),
                jnp.asarray(prep.mu_t),
                jnp.asarray(theta0[s]),
                jnp.asarray(h),
                jnp.asarray(z),
                jnp.asarray(mask),
                jnp.asarray(lam),
                jnp.asarray(omega_scale),
            )
            start, end = float(np.mean(np.asarray(res0))), float(np.mean(np.asarray(res1)))
            # keep the refinement only if it improved eq. 5.13 (it starts from the profiles)
            if np.isfinite(end) and end <= start:
                om = om_r
            losses.append({"series_start": start, "series_end": end})
        members.append(jax.tree_util.tree_map(np.asarray, om))
    return SpeedFit(
        config=config,
        params=stack(members),
        omega_scale=omega_scale,
        regularization=lam,
        cv=cv,
        losses=losses,
    )


def speed_config(
    omega_harmonics: int,
    width: int,
    depth: int,
    fit_iterations: int,
    iterations: int,
    learning_rate: float,
    form: str,
    map_config: hm.MapConfig,
    prep: Prepared,
    periods: float,
    samples: int,
) -> hs.SpeedConfig:
    """The speed stage's static settings; RK4 substeps so that ``Ω h / n_sub <= 0.1``."""
    _, h, _ = _windows(prep, periods, samples)
    n_sub = max(1, math.ceil(max(float(np.max(prep.omega)) * hh for hh in h) / 0.1))
    return hs.SpeedConfig(
        n_harmonics=omega_harmonics,
        width=width,
        depth=depth,
        n_fit=fit_iterations,
        n_refine=iterations,
        learning_rate=float(learning_rate),
        n_sub=n_sub,
        form=form,
        map_width=map_config.width,
        map_depth=map_config.depth,
    )


def speed_stage(
    hyper: Mapping[str, Any],
    prep: Prepared,
    map_config: hm.MapConfig,
    matcher: PhaseMatcher,
    active: np.ndarray,
    primary: int,
    timer: StageTimer,
) -> SpeedFit:
    """The oscillation-speed stage (eqs. 5.10–5.13) with the ``omega_*`` hyperparameters
    and ``seed`` of an estimator (``hyper``: its ``get_params()``)."""
    scfg = speed_config(
        hyper["omega_harmonics"],
        hyper["omega_width"],
        hyper["omega_depth"],
        hyper["omega_fit_iterations"],
        hyper["omega_iterations"],
        hyper["omega_learning_rate"],
        hyper["omega_form"],
        map_config,
        prep,
        hyper["omega_periods"],
        hyper["omega_samples"],
    )
    lam = hyper["omega_regularization"]
    return train_speed(
        prep,
        matcher,
        active,
        primary,
        config=scfg,
        periods=hyper["omega_periods"],
        samples=hyper["omega_samples"],
        regularization_grid=hyper["omega_regularization_grid"] if lam == "cv" else (lam,),
        seed=hyper["seed"],
        timer=timer,
    )
