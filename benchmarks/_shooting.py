"""Baseline for the continuation benchmark: periodic orbits by single shooting with SciPy.

A small, self-contained pseudo-arclength continuation (PALC) of periodic orbits of an
autonomous ODE ``x' = f(x, lam)``, written the way a careful SciPy user would:

* unknowns ``z = (x0, T, lam)`` (start point, period, parameter);
* shooting residual ``phi_T(x0; lam) - x0 = 0`` with the flow ``phi`` from
  ``scipy.integrate.solve_ivp`` (DOP853), integrated together with the variational
  equations ``Phi' = f_x Phi, Phi(0) = I`` and ``psi' = f_x psi + f_lam, psi(0) = 0``,
  so the Jacobian ``[Phi - I, f(x(T)), psi]`` is exact up to the integration tolerance
  and the Floquet multipliers (eigenvalues of the monodromy ``Phi``) come for free;
* Poincaré phase condition ``<f(x_ref), x0 - x_ref> = 0`` against the previous point;
* pseudo-arclength equation ``<W t, z - z_pred> = 0``, solved with
  ``scipy.optimize.root`` (MINPACK ``hybr`` with the analytic Jacobian);
* tangent from ``[G_z; (W t_prev)^T] t = [0; 1]``, adaptive step (grow ×1.5 after an
  easy corrector, halve on failure or on a sharp turn), bounds hit exactly;
* cycle folds detected by a sign change of the parameter component of the tangent and
  located by an Illinois secant on the arclength, the same idea as ``bifid``'s ``palc``.

The start is the Hopf point: ``x_H + eps Re q`` with period ``2 pi / omega``, the
Hopf point itself located by ``scipy.optimize.brentq`` on the largest real part of the
eigenvalues of the Jacobian at the equilibrium.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
from scipy.integrate import solve_ivp
from scipy.optimize import brentq, root

# setup(lam) -> (f(x), f_x(x), f_lam(x)), NumPy callables specialised at the parameter value
Setup = Callable[[float], tuple[Callable, Callable, Callable]]


@dataclass(frozen=True)
class ShootingOptions:
    """Numbers of the shooting continuation (step control mirrors ``ContinuationOptions``).

    ``ds, ds_min, ds_max, max_steps, p_min, p_max, growth`` as in bifid; ``rtol, atol,
    method`` go to ``solve_ivp``; ``xtol`` to ``root`` (hybr); a corrected point is
    accepted when ``max|F| <= ftol * max(1, max|x0|)``; ``weight_x`` weighs ``x0`` in the
    arclength norm (``T`` and the parameter weigh 1); a step grows after at most
    ``easy_nfev`` flow integrations, halves after ``2 * easy_nfev``; ``max_nfev`` caps the
    integrations of one ``root`` call.
    """

    ds: float = 1e-3
    ds_min: float = 1e-9
    ds_max: float = 0.25
    max_steps: int = 600
    p_min: float = -math.inf
    p_max: float = math.inf
    growth: float = 1.5
    rtol: float = 1e-10
    atol: float = 1e-12
    method: str = "DOP853"
    xtol: float = 1e-12
    ftol: float = 1e-8
    weight_x: float = 0.5
    easy_nfev: int = 5
    max_nfev: int = 12


@dataclass
class HopfStart:
    """A Hopf point: parameter, equilibrium, frequency and critical eigenvector."""

    lam: float
    x: np.ndarray
    omega: float
    q: np.ndarray


@dataclass
class ShootingBranch:
    """Points ``z = (x0, T, lam)`` of the branch with Floquet multipliers and folds."""

    z: np.ndarray
    multipliers: np.ndarray
    stable: np.ndarray
    folds: list[tuple[float, np.ndarray, float]] = field(default_factory=list)
    status: str = "max_steps"
    message: str = ""
    n_integrations: int = 0

    @property
    def params(self) -> np.ndarray:
        return self.z[:, -1]

    @property
    def periods(self) -> np.ndarray:
        return self.z[:, -2]

    def __len__(self) -> int:
        return int(self.z.shape[0])


def locate_hopf(
    setup: Setup, x_eq: Callable[[float], np.ndarray], lo: float, hi: float, xtol: float = 1e-13
) -> HopfStart:
    """Hopf point in ``[lo, hi]``: zero of the largest real part of the eigenvalues."""

    def jac(lam: float) -> np.ndarray:
        return setup(lam)[1](x_eq(lam))

    def growth(lam: float) -> float:
        return float(np.max(np.linalg.eigvals(jac(lam)).real))

    lam = brentq(growth, lo, hi, xtol=xtol, rtol=4 * np.finfo(float).eps)
    w, V = np.linalg.eig(jac(lam))
    k = int(np.argmax(np.where(w.imag > 0, w.real, -np.inf)))
    return HopfStart(
        lam=float(lam), x=np.asarray(x_eq(lam), float), omega=float(w[k].imag), q=V[:, k]
    )


class _Shooter:
    """Flow with variational equations and the bordered shooting system."""

    def __init__(self, setup: Setup, n: int, o: ShootingOptions):
        self.setup, self.n, self.o = setup, n, o
        self.n_integrations = 0

    def flow(self, x0: np.ndarray, T: float, lam: float):
        """``x(T)``, ``f(x(T))``, ``[Phi(T) | psi(T)]`` (n, n+1)."""
        n = self.n
        f, fx, flam = self.setup(lam)

        def rhs(_t, y):
            x = y[:n]
            W = y[n:].reshape(n, n + 1)
            dW = fx(x) @ W
            dW[:, n] += flam(x)
            return np.concatenate([f(x), dW.ravel()])

        y0 = np.concatenate([x0, np.hstack([np.eye(n), np.zeros((n, 1))]).ravel()])
        sol = solve_ivp(rhs, (0.0, T), y0, method=self.o.method, rtol=self.o.rtol, atol=self.o.atol)
        self.n_integrations += 1
        if not sol.success:
            raise FloatingPointError(sol.message)
        yT = sol.y[:, -1]
        xT = yT[:n]
        return xT, f(xT), yT[n:].reshape(n, n + 1)

    def system(self, z, x_ref, f_ref, row, c):
        """Residual and Jacobian of ``[phi_T(x0) - x0; phase; row . z - c]`` and ``Phi``."""
        n = self.n
        x0, T, lam = z[:n], z[n], z[n + 1]
        xT, fT, W = self.flow(x0, T, lam)
        F = np.concatenate([xT - x0, [f_ref @ (x0 - x_ref), row @ z - c]])
        J = np.zeros((n + 2, n + 2))
        J[:n, :n] = W[:, :n] - np.eye(n)
        J[:n, n] = fT
        J[:n, n + 1] = W[:, n]
        J[n, :n] = f_ref
        J[n + 1] = row
        return F, J, W[:, :n]

    def solve(self, z_guess, x_ref, f_ref, row, c):
        """Corrector: ``scipy.optimize.root`` (hybr, analytic Jacobian).

        Returns ``(z, ok, n_calls, J, Phi)`` (``n_calls`` = integrations of the flow) with
        ``J``/``Phi`` evaluated at the returned ``z`` (reused from the last evaluation when
        ``root`` returns that point).
        """
        last: dict = {"n": 0}

        def fun(z):
            F, J, Phi = self.system(z, x_ref, f_ref, row, c)
            last.update(z=z.copy(), F=F, J=J, Phi=Phi, n=last["n"] + 1)
            return F, J

        try:
            sol = root(
                fun,
                z_guess,
                jac=True,
                method="hybr",
                options={"xtol": self.o.xtol, "maxfev": self.o.max_nfev},
            )
        except FloatingPointError:
            return z_guess, False, 0, None, None
        z = sol.x
        if not np.array_equal(z, last["z"]):
            fun(z)
        scale = max(1.0, float(np.max(np.abs(z[: self.n]))))
        F = last["F"]
        ok = bool(np.all(np.isfinite(F)) and np.max(np.abs(F)) <= self.o.ftol * scale)
        return z, ok, int(last["n"]), last["J"], last["Phi"]


def _tangent(J: np.ndarray, t_prev: np.ndarray, w: np.ndarray, f0: np.ndarray) -> np.ndarray:
    """Unit tangent: ``[G_z; (W t_prev)^T] t = [0; 1]``.

    ``G_z`` is the shooting block of ``J`` with the phase row re-anchored at the point
    itself (``f0 = f(x0)``), i.e. the phase condition the *next* step will use; with the
    previous anchor the tangent would carry a spurious phase-shift component that does
    not vanish as the step goes to zero.
    """
    n = f0.shape[0]
    A = np.vstack([J[:-1], (w * t_prev)[None, :]])
    A[n, :n] = f0
    rhs = np.zeros(A.shape[0])
    rhs[-1] = 1.0
    t = scipy.linalg.solve(A, rhs, check_finite=False)
    return t / np.sqrt(t @ (w * t))


def _stable(Phi: np.ndarray) -> tuple[np.ndarray, bool]:
    m = np.linalg.eigvals(Phi)
    m = m[np.argsort(-np.abs(m))]
    nontrivial = np.delete(m, int(np.argmin(np.abs(m - 1.0))))
    return m, bool(np.max(np.abs(nontrivial)) < 1.0)


def continue_from_hopf(
    setup: Setup, n: int, hopf: HopfStart, options: ShootingOptions
) -> ShootingBranch:
    """Pseudo-arclength continuation of the orbits born at ``hopf`` (see module docstring).

    The branch ends on a parameter bound (``status="bounds"``), at ``max_steps`` or when
    a step fails at ``ds_min`` (``status="failed"``).
    """
    o = options
    sh = _Shooter(setup, n, o)
    w = np.concatenate([np.full(n, o.weight_x), [1.0, 1.0]])
    f_at = setup
    pi = n + 1

    def phase_ref(z):
        x = z[:n]
        return x, f_at(float(z[pi]))[0](x)

    # first orbit: x_H + ds Re(q) with the Hopf period, corrected on the arclength plane
    q = hopf.q / np.max(np.abs(hopf.q))
    z_h = np.concatenate([hopf.x, [2 * np.pi / hopf.omega, hopf.lam]])
    t = np.concatenate([q.real, [0.0, 0.0]])
    t = t / np.sqrt(t @ (w * t))
    z_pred = z_h + o.ds * t
    x_ref, f_ref = phase_ref(z_pred)
    row = w * t
    z, ok, _, J, Phi = sh.solve(z_pred, x_ref, f_ref, row, row @ z_pred)
    if not ok:
        raise RuntimeError("shooting: the first orbit next to the Hopf point did not converge")
    t = _tangent(J, t, w, phase_ref(z)[1])
    if t[:n] @ (w[:n] * q.real) < 0:
        t = -t
    m, st = _stable(Phi)
    zs, ms, sts = [z], [m], [st]
    folds: list[tuple[float, np.ndarray, float]] = []
    ds = o.ds
    status, message = "max_steps", f"maximum number of steps ({o.max_steps}) reached"

    while len(zs) < o.max_steps:
        x_ref, f_ref = phase_ref(z)
        z_pred = z + ds * t
        row = w * t
        z_new, ok, nfev, J, Phi = sh.solve(z_pred, x_ref, f_ref, row, row @ z_pred)
        t_new = None
        if ok:
            t_new = _tangent(J, t, w, phase_ref(z_new)[1])
            ok = float(t_new @ (w * t)) > 0.8 or ds <= o.ds_min * 1.0001
        if not ok:
            if ds <= o.ds_min * 1.0001:
                status, message = "failed", f"no convergence near lam={z[pi]:.8g} at ds_min"
                break
            ds = max(ds / 2.0, o.ds_min)
            continue

        lam_new = float(z_new[pi])
        hit = o.p_max if lam_new > o.p_max else (o.p_min if lam_new < o.p_min else None)
        if hit is not None:
            frac = (hit - float(z[pi])) / (lam_new - float(z[pi]))
            guess = z + frac * (z_new - z)
            e = np.zeros(n + 2)
            e[pi] = 1.0
            z_b, ok_b, _, _, Phi_b = sh.solve(guess, x_ref, f_ref, e, hit)
            if ok_b:
                m, st = _stable(Phi_b)
                zs.append(z_b)
                ms.append(m)
                sts.append(st)
                status, message = "bounds", f"reached the parameter bound {hit:g}"
            else:
                status, message = "failed", f"could not converge on the bound {hit:g}"
            break

        if float(t[pi]) * float(t_new[pi]) < 0:
            fold = _locate_fold(sh, z, t, ds, w, x_ref, f_ref, pi, phase_ref)
            if fold is not None:
                folds.append(fold)

        z, t = z_new, t_new
        m, st = _stable(Phi)
        zs.append(z)
        ms.append(m)
        sts.append(st)
        if nfev <= o.easy_nfev:
            ds = min(ds * o.growth, o.ds_max)
        elif nfev >= 2 * o.easy_nfev:
            ds = max(ds / 2.0, o.ds_min)

    return ShootingBranch(
        z=np.array(zs),
        multipliers=np.array(ms),
        stable=np.array(sts),
        folds=folds,
        status=status,
        message=message,
        n_integrations=sh.n_integrations,
    )


def _locate_fold(sh: _Shooter, z_a, t_a, ds, w, x_ref, f_ref, pi, phase_ref):
    """Illinois secant for the zero of ``t(z(s))[lam]`` on ``s in [0, ds]``."""
    row = w * t_a
    c0 = float(row @ z_a)

    def f(s):
        z_s, ok, _, J, _ = sh.solve(z_a + s * t_a, x_ref, f_ref, row, c0 + s)
        if not ok:
            return None, None
        return float(_tangent(J, t_a, w, phase_ref(z_s)[1])[pi]), z_s

    a, fa = 0.0, float(t_a[pi])
    b = ds
    fb, zb = f(b)
    if fb is None or fa * fb > 0:
        return None
    z_best = zb
    for _ in range(60):
        s = (a * fb - b * fa) / (fb - fa)
        fs, z_s = f(s)
        if fs is None:
            break
        z_best = z_s
        if fs * fb < 0:
            a, fa = b, fb
        else:
            fa = fa / 2.0
        b, fb = s, fs
        if abs(fs) < 1e-12 or abs(b - a) < 1e-12 * max(1.0, ds):
            break
    return float(z_best[pi]), z_best, abs(b - a) ** 2
