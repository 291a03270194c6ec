"""Synthetic limit-cycle records for the hybrid Hopf model: tests, benchmark and docs.

* :func:`simulated_records` — stable cycles by time integration after a transient (§5.4.1);
* :class:`ContinuationTruth` — the exact cycle branch of a system by continuation (equilibria →
  Hopf point → :func:`bifid.continuation.hopf_orbits`), corrected at any parameter value on the
  stable or unstable branch, and sampled on a time grid by trigonometric interpolation of the
  collocation mesh (§5.4.2 uses four stable and four unstable orbits, 1 s at 1 kHz).

Both return records ``(param, signals (n, m), sample_rate, stable)`` as
:class:`~bifid.identify.HopfHybridModel` accepts them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError, ConvergenceError


def simulated_records(
    system_name: str,
    params: Sequence[float],
    *,
    duration: float,
    dt: float,
    transient: float = 60.0,
    x0: Sequence[float] | None = None,
    signals: Sequence[str] | None = None,
) -> list[tuple]:
    """Stable limit cycles by integration: ``transient`` seconds first, then the record."""
    from bifid.simulate import simulate
    from bifid.systems import get_system

    system = get_system(system_name)
    names = list(signals or system.states)
    idx = [system.state_index(s) for s in names]
    start = np.asarray(x0 if x0 is not None else [0.5] + [0.0] * (system.n_states - 1))
    out = []
    for value in params:
        p = system.param_vector({system.default_param: float(value)})
        x = simulate(system, jnp.asarray(start), jnp.linspace(0.0, transient, 2), p)[-1]
        ts = np.arange(round(duration / dt)) * dt
        ys = simulate(system, x, jnp.asarray(ts), p)
        out.append((float(value), ys[:, idx], 1.0 / dt, True))
    return out


def _trig_eval(V: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Trigonometric interpolant of mesh values ``V`` (M, n) on ``tau_k = 2πk/M`` at ``tau``."""
    M = V.shape[0]
    c = np.fft.rfft(V, axis=0) / M
    k = np.arange(c.shape[0])
    w = np.where((k == 0) | ((M % 2 == 0) & (k == M // 2)), 1.0, 2.0)
    phase = np.exp(1j * np.outer(tau, k))
    return np.real(phase @ (w[:, None] * c))


@dataclass
class ContinuationTruth:
    """Ground truth of a system's cycle branch, from continuation.

    Build with :meth:`compute`; then :meth:`orbit` gives the exact cycle at any parameter on
    either branch, :meth:`records` samples cycles as measured records.
    """

    system_name: str
    param: str
    hopf_param: float
    hopf_omega: float
    fold_param: float | None
    params: np.ndarray  # branch points
    stable: np.ndarray
    ys: np.ndarray  # (n_points, M*n + 2): mesh values, period, parameter
    n_mesh: int
    p: np.ndarray
    system: Any = None  # a System object when not a registry name

    def _system(self):
        from bifid.systems import get_system

        return self.system if self.system is not None else get_system(self.system_name)

    @classmethod
    def compute(
        cls,
        system_name: Any = "flutter",
        param: str | None = None,
        *,
        p_range: tuple[float, float] = (10.0, 25.0),
        n_mesh: int = 48,
        ds: float = 0.01,
        max_steps: int = 400,
    ) -> ContinuationTruth:
        from bifid.continuation import ContinuationOptions, equilibria, hopf_orbits
        from bifid.systems import get_system

        system = get_system(system_name) if isinstance(system_name, str) else system_name
        param = param or system.default_param
        lo, hi = p_range
        eq = equilibria(
            system, param, start=lo,
            options=ContinuationOptions(p_min=lo, p_max=hi, ds=0.05, ds_max=0.5, max_steps=500),
        )
        hopfs = [sp for sp in eq.special_points if sp.kind == "hopf"]
        if not hopfs:
            raise ConvergenceError(f"No Hopf point of {system_name!r} in {param} ∈ {p_range}.")
        hp = hopfs[0]
        br = hopf_orbits(
            system, hp, n_mesh=n_mesh,
            options=ContinuationOptions(p_min=lo, p_max=hi, ds=ds, ds_max=0.2, max_steps=max_steps),
        )
        folds = [sp.param for sp in br.special_points if sp.kind == "cycle_fold"]
        return cls(
            system_name=system.name,
            param=param,
            hopf_param=float(hp.param),
            hopf_omega=float(hp.data["omega"]),
            fold_param=float(folds[0]) if folds else None,
            params=np.asarray(br.params),
            stable=np.asarray(br.stable, dtype=bool),
            ys=np.column_stack([np.asarray(br.solutions)[:, : n_mesh * system.n_states + 1],
                                np.asarray(br.params)]),
            n_mesh=int(br.meta.get("n_mesh", n_mesh)),
            p=np.asarray(hp.data["p"]),
            system=None if isinstance(system_name, str) else system,
        )

    def orbit(self, value: float, stable: bool) -> tuple[np.ndarray, float]:
        """The exact cycle at ``param = value`` on the stable/unstable branch.

        Returns
        -------
        V : ndarray (n_mesh, n_states)
            Mesh values on ``t_k = T k / M``.
        T : float
            Period.
        """
        from bifid.continuation import correct, orbit_problem
        from bifid.continuation._fourier import fourier_differentiation_matrix

        system = self._system()
        M, n = self.n_mesh, system.n_states
        seg = np.nonzero(self.stable == stable)[0]
        best = None
        for a in seg:
            b = a + 1
            if b >= len(self.params) or self.stable[b] != stable:
                continue
            pa, pb = self.params[a], self.params[b]
            if min(pa, pb) <= value <= max(pa, pb):
                best = (a, b)
                break
        if best is None:
            raise BifidInputError(
                f"No {'stable' if stable else 'unstable'} cycle of {self.system_name} at "
                f"{self.param}={value}."
            )
        a, b = best
        w = (value - self.params[a]) / (self.params[b] - self.params[a])
        guess = (1 - w) * self.ys[a] + w * self.ys[b]
        Vref = self.ys[a][: M * n].reshape(M, n)
        D = fourier_differentiation_matrix(M)
        args = {
            "p": jnp.asarray(self.p),
            "idx": jnp.asarray(system.index(self.param)),
            "dref": jnp.asarray((D @ Vref).ravel()),
        }
        row = np.zeros(M * n + 2)
        row[-1] = 1.0
        y, ok, _, res = correct(orbit_problem(system.field, M, n), guess, row, float(value), args)
        if not ok:
            raise ConvergenceError(f"Cycle at {self.param}={value} did not converge ({res:.1e}).")
        return np.asarray(y[: M * n]).reshape(M, n), float(y[M * n])

    def amplitude(self, value: float, stable: bool, states: Sequence[str]) -> np.ndarray:
        """``max_t |x_s(t)|`` of ``states`` on the exact cycle (fine trigonometric grid)."""
        system = self._system()
        V, _ = self.orbit(value, stable)
        x = _trig_eval(V, np.linspace(0, 2 * np.pi, 4096, endpoint=False))
        return np.max(np.abs(x[:, [system.state_index(s) for s in states]]), axis=0)

    def frequency(self, value: float, stable: bool) -> float:
        """Angular frequency :math:`2\\pi/T` of the exact cycle [rad/s]."""
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
    ) -> list[tuple]:
        """Cycles sampled as records; ``noise`` is Gaussian with standard deviation
        ``noise × RMS`` of each signal over all records (absolute, as a sensor's)."""
        system = self._system()
        idx = [system.state_index(s) for s in states]
        rng = np.random.default_rng(seed)
        t = np.arange(round(duration * sample_rate)) / sample_rate
        out = []
        for values, stable in ((stable_params, True), (unstable_params, False)):
            for v in values:
                V, T = self.orbit(float(v), stable)
                tau = 2 * np.pi * t / T + rng.uniform(0, 2 * np.pi)
                out.append((float(v), _trig_eval(V, tau)[:, idx], sample_rate, stable))
        if noise > 0:
            rms = np.sqrt(np.mean(np.concatenate([r[1] for r in out]) ** 2, axis=0))
            out = [
                (v, s + noise * rms[None, :] * rng.standard_normal(s.shape), fs, st)
                for v, s, fs, st in out
            ]
        return out
