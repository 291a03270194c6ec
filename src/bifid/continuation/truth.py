"""Ground truth of a known system, for checking measurements and models against it.

What tests, benchmarks and the demos need from a system whose equations are known:

- :func:`correct_orbit` — the exact periodic orbit of the *uncontrolled* system at a given
  parameter value, by Newton's method on the collocation equations (thesis eqs.
  4.12–4.14) from any nearby orbit (a continuation point, a rig's true states): the
  corrected orbit does not depend on the start, so it is an independent reference for a
  CBC point; :func:`correct_forced` does the same for a forced response at ``(F, Ω)``;
- :func:`orbit_from_samples` — one period of a sampled trajectory on a collocation mesh;
- :class:`ContinuationTruth` — a system's whole cycle branch by continuation (equilibria →
  Hopf point → orbits), with the exact orbit, amplitude and frequency at any parameter on
  the stable or unstable side, and cycles sampled as measured records (thesis §5.4.2);
- :func:`simulated_records` — stable cycles by time integration after a transient (§5.4.1).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from bifid.continuation._collocation import hopf_orbits, orbit_problem, resample_orbit
from bifid.continuation._equilibria import equilibria
from bifid.continuation._forced import forced_problem
from bifid.continuation._fourier import fourier_differentiation_matrix
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._palc import correct
from bifid.errors import BifidInputError, ConvergenceError
from bifid.signal import (
    evaluate_fourier,
    evaluate_series,
    fourier_coefficients,
    fourier_project,
    max_abs,
)
from bifid.simulate import simulate
from bifid.systems import System, get_system

__all__ = [
    "ContinuationTruth",
    "centred_amplitudes",
    "correct_forced",
    "correct_orbit",
    "orbit_from_samples",
    "simulated_records",
]

Record = tuple[float, np.ndarray, float, bool]


def orbit_from_samples(
    states: np.ndarray,
    phase: np.ndarray | float,
    sample_rate: float,
    n_mesh: int = 64,
    n_harmonics: int = 15,
) -> np.ndarray:
    """One period of a sampled periodic trajectory on ``n_mesh`` equispaced phases.

    Parameters
    ----------
    states : array of shape (n_samples, n)
    phase : float or array of shape (n_samples,)
        The angular frequency ω [rad/s] of the trajectory (phases ``ω t``), or the phase of
        each sample (e.g. a forcing generator's ``θ − ψ``, so the mesh is in the system's
        forcing phase ``τ``).
    sample_rate : float
        [Hz].

    Returns
    -------
    ndarray of shape (n_mesh, n)
        The least-squares Fourier series (``n_harmonics``) of each state at
        ``τ_k = 2πk/M``.
    """
    states = np.asarray(states, dtype=float)
    theta = np.asarray(phase, dtype=float)
    if theta.ndim == 0:
        theta = float(theta) * np.arange(states.shape[0]) / sample_rate
    coef = fourier_project(states, theta, n_harmonics)
    return evaluate_series(coef, 2.0 * np.pi * np.arange(n_mesh) / n_mesh)


def _on_mesh(system: System, orbit: np.ndarray, n_mesh: int) -> np.ndarray:
    V = np.asarray(orbit, dtype=float)
    if V.ndim != 2 or V.shape[1] != system.n_states:
        raise BifidInputError(f"orbit must have shape (M, {system.n_states}), got {V.shape}.")
    return resample_orbit(V, n_mesh) if V.shape[0] != n_mesh else V


def correct_orbit(
    system: System,
    param: str,
    value: float,
    orbit: np.ndarray,
    period: float,
    p: Sequence[float] | None = None,
    n_mesh: int = 64,
    tol: float = 1e-11,
) -> tuple[np.ndarray, float]:
    """Newton-correct an approximate orbit of the uncontrolled ``system`` at ``param=value``.

    Parameters
    ----------
    orbit : array of shape (M, n)
        Approximate orbit over one period on an equispaced grid (resampled to ``n_mesh``).
    period : float
        Approximate period.
    p : parameter vector, optional
        Defaults to the system's nominal parameters (``param`` is set to ``value``).

    Returns
    -------
    orbit : ndarray of shape (n_mesh, n)
    period : float

    Raises
    ------
    ConvergenceError
        If Newton's method does not converge.
    """
    V, n, pv = _guess(system, orbit, n_mesh, p)
    D = fourier_differentiation_matrix(n_mesh)
    idx = system.index(param)
    args = {
        "p": pv.at[idx].set(value),
        "idx": jnp.asarray(idx),
        "dref": jnp.asarray((D @ V).ravel()),
    }
    y = _newton(
        orbit_problem(system.field, n_mesh, n),
        np.concatenate([V.ravel(), [period, value]]),
        args,
        tol,
        f"the orbit of {system.name!r} at {param}={value:g}",
    )
    return np.asarray(y[: n_mesh * n]).reshape(n_mesh, n), float(y[n_mesh * n])


def correct_forced(
    system: System,
    omega: float,
    forcing: float,
    orbit: np.ndarray,
    p: Sequence[float] | None = None,
    n_mesh: int = 64,
    tol: float = 1e-11,
) -> np.ndarray:
    """Newton-correct a forced response of ``system`` at ``(F, Ω) = (forcing, omega)``.

    ``orbit`` (M, n) is a guess on ``τ_k = 2πk/M`` with the force ``F cos τ``.

    Raises
    ------
    ConvergenceError
        If Newton's method does not converge.
    """
    V, n, pv = _guess(system, orbit, n_mesh, p)
    iF, iOm = system.index("F"), system.index("Omega")
    args = {
        "p": pv.at[iOm].set(omega).at[iF].set(forcing),
        "idx": jnp.asarray([iF]),
        "obs": jnp.asarray(system.state_index(system.observed)),
    }
    y = _newton(
        forced_problem(system, n_mesh, 1),
        np.concatenate([V.ravel(), [forcing]]),
        args,
        tol,
        f"the forced response of {system.name!r} at F={forcing:g}, Omega={omega:g}",
    )
    return np.asarray(y[: n_mesh * n]).reshape(n_mesh, n)


def _guess(system: System, orbit: np.ndarray, n_mesh: int, p) -> tuple[np.ndarray, int, object]:
    """The guess on the mesh, the number of states and the parameter vector."""
    pv = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    return _on_mesh(system, orbit, n_mesh), system.n_states, pv


def _newton(problem, y0: np.ndarray, args: dict, tol: float, what: str) -> np.ndarray:
    """Newton at the fixed last unknown of ``y0`` (the parameter); raises on failure."""
    e = np.zeros_like(y0)
    e[-1] = 1.0
    y, ok, _, res = correct(problem, y0, e, float(y0[-1]), args, tol=tol, max_iter=40)
    if not ok:
        raise ConvergenceError(f"Newton did not converge on {what} (residual {res:.1e}).")
    return y


def centred_amplitudes(orbit: np.ndarray) -> np.ndarray:
    """``max_t |x_s(t) − x̄_s|`` per state of a periodic orbit on an equispaced mesh (the
    convention of measured data)."""
    V = np.asarray(orbit, dtype=float)
    return np.atleast_1d(max_abs(V - V.mean(axis=0)))


def _resolve(system: System | str) -> System:
    return get_system(system) if isinstance(system, str) else system


def simulated_records(
    system: System | str,
    params: Sequence[float],
    *,
    duration: float,
    dt: float,
    transient: float = 60.0,
    x0: Sequence[float] | None = None,
    signals: Sequence[str] | None = None,
) -> list[Record]:
    """Stable limit cycles by integration: ``transient`` seconds first, then the record.

    Returns
    -------
    list of (param, signals (n, m), sample_rate, stable=True)
    """
    system = _resolve(system)
    names = list(signals or system.states)
    idx = [system.state_index(s) for s in names]
    start = np.asarray(x0 if x0 is not None else [0.5] + [0.0] * (system.n_states - 1))
    out: list[Record] = []
    for value in params:
        p = system.param_vector({system.default_param: float(value)})
        x = simulate(system, jnp.asarray(start), jnp.linspace(0.0, transient, 2), p)[-1]
        ts = np.arange(round(duration / dt)) * dt
        ys = simulate(system, x, jnp.asarray(ts), p)
        out.append((float(value), np.asarray(ys)[:, idx], 1.0 / dt, True))
    return out


@dataclass
class ContinuationTruth:
    """A system's cycle branch by continuation, with exact orbits anywhere on it.

    Build with :meth:`compute`; then :meth:`orbit` gives the exact cycle at any parameter on
    either side of the fold, :meth:`records` samples cycles as measured records.
    """

    system: System
    param: str
    hopf_param: float
    hopf_omega: float
    fold_param: float | None
    params: np.ndarray  # branch points
    stable: np.ndarray
    orbits: np.ndarray  # (n_points, M, n)
    periods: np.ndarray
    n_mesh: int
    p: np.ndarray

    @classmethod
    def compute(
        cls,
        system: System | str,
        param: str | None = None,
        *,
        p_range: tuple[float, float],
        n_mesh: int = 48,
        ds: float = 0.01,
        max_steps: int = 400,
    ) -> ContinuationTruth:
        """Equilibria over ``p_range``, the first Hopf point and its cycle branch.

        Raises
        ------
        ConvergenceError
            If there is no Hopf point in the range.
        """
        system = _resolve(system)
        param = param or system.default_param
        lo, hi = p_range
        eq = equilibria(
            system,
            param,
            start=lo,
            options=ContinuationOptions(p_min=lo, p_max=hi, ds=0.05, ds_max=0.5, max_steps=500),
        )
        hopfs = eq.special("hopf")
        if not hopfs:
            raise ConvergenceError(f"No Hopf point of {system.name!r} in {param} ∈ {p_range}.")
        hp = hopfs[0]
        br = hopf_orbits(
            system,
            hp,
            n_mesh=n_mesh,
            options=ContinuationOptions(p_min=lo, p_max=hi, ds=ds, ds_max=0.2, max_steps=max_steps),
        )
        folds = br.special("cycle_fold")
        M = int(br.meta.get("n_mesh", n_mesh))
        n = system.n_states
        sol = np.asarray(br.solutions)
        return cls(
            system=system,
            param=param,
            hopf_param=float(hp.param),
            hopf_omega=float(hp.data["omega"]),
            fold_param=float(folds[0].param) if folds else None,
            params=np.asarray(br.params),
            stable=np.asarray(br.stable, dtype=bool),
            orbits=sol[:, : M * n].reshape(-1, M, n),
            periods=sol[:, M * n],
            n_mesh=M,
            p=np.asarray(hp.data["p"]),
        )

    def orbit(self, value: float, stable: bool) -> tuple[np.ndarray, float]:
        """The exact cycle at ``param = value`` on the stable / unstable side.

        Returns
        -------
        V : ndarray (n_mesh, n_states)
            Mesh values on ``t_k = T k / M``.
        T : float
            Period.

        Raises
        ------
        BifidInputError
            If the branch has no cycle of that stability at ``value``.
        """
        for a in np.flatnonzero(self.stable == stable):
            b = a + 1
            if (
                b < len(self.params)
                and self.stable[b] == stable
                and min(self.params[a], self.params[b])
                <= value
                <= max(self.params[a], self.params[b])
            ):
                w = (value - self.params[a]) / (self.params[b] - self.params[a])
                guess = (1 - w) * self.orbits[a] + w * self.orbits[b]
                period = (1 - w) * self.periods[a] + w * self.periods[b]
                return correct_orbit(
                    self.system,
                    self.param,
                    float(value),
                    guess,
                    float(period),
                    p=self.p,
                    n_mesh=self.n_mesh,
                )
        raise BifidInputError(
            f"No {'stable' if stable else 'unstable'} cycle of "
            f"{self.system.name} at {self.param}={value}."
        )

    def amplitude(self, value: float, stable: bool, states: Sequence[str]) -> np.ndarray:
        """``max_t |x_s(t)|`` of ``states`` on the exact cycle."""
        V, _ = self.orbit(value, stable)
        return np.atleast_1d(max_abs(V[:, [self.system.state_index(s) for s in states]]))

    def frequency(self, value: float, stable: bool) -> float:
        """Angular frequency ``2π/T`` of the exact cycle [rad/s]."""
        return 2 * np.pi / self.orbit(value, stable)[1]

    def records(
        self,
        stable_params: Sequence[float],
        unstable_params: Sequence[float],
        states: Sequence[str],
        *,
        duration: float = 1.0,
        sample_rate: float = 1000.0,
        noise: float = 0.0,
        seed: int = 0,
    ) -> list[Record]:
        """Cycles sampled as records (random initial phase); ``noise`` is Gaussian with
        standard deviation ``noise × RMS`` of each signal over all records (absolute, as a
        sensor's)."""
        idx = [self.system.state_index(s) for s in states]
        rng = np.random.default_rng(seed)
        t = np.arange(round(duration * sample_rate)) / sample_rate
        out: list[Record] = []
        for values, stable in ((stable_params, True), (unstable_params, False)):
            for v in values:
                V, T = self.orbit(float(v), stable)
                tau = 2 * np.pi * t / T + rng.uniform(0, 2 * np.pi)
                sig = evaluate_fourier(*fourier_coefficients(V), tau)[:, idx]
                out.append((float(v), sig, sample_rate, stable))
        if noise > 0:
            rms = np.sqrt(np.mean(np.concatenate([r[1] for r in out]) ** 2, axis=0))
            out = [
                (v, s + noise * rms[None, :] * rng.standard_normal(s.shape), fs, st)
                for v, s, fs, st in out
            ]
        return out
