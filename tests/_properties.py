"""Property checks of bifurcation diagrams against independent computations.

A *variant* is a built-in autonomous system with random parameter values and a random
range; :func:`run_variant` computes its diagram with
:func:`bifid.continuation.bifurcation_diagram` (what ``bifid continue`` prints) and applies
every registered check. A check is ``(variant, system, diagram) -> list of failures`` (an
empty list when it holds), registered in :data:`CHECKS` under a name; checks of orbits
(multipliers, orbit bifurcations) are added the same way, with ``needs_orbits=True``.

The equilibrium check compares the diagram with a dense scan written for the test: the
equilibrium followed by Newton (``scipy.optimize.root``) on a uniform grid of the
parameter, the eigenvalues of its Jacobian at every grid point, a Hopf point wherever an
eigenvalue with ``Im > 0`` (followed to its nearest neighbour on the next grid point)
changes the sign of its real part — refined by bisection — and a real crossing wherever
``det J`` changes sign. No false point (every located Hopf point and fold is in the scan)
and no missed point (every Hopf point of the scan is located; every real crossing is a
located fold or a branch-point candidate).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import root

from bifid.continuation import Diagram, bifurcation_diagram
from bifid.systems import System, get_system, list_systems


@dataclass(frozen=True)
class Variant:
    """A system with parameter overrides and a range (``start`` towards ``end``)."""

    system: str
    param: str
    start: float
    end: float
    overrides: dict[str, float] = field(default_factory=dict)
    x0: tuple[float, ...] | None = None

    @property
    def label(self) -> str:
        sets = ", ".join(f"{k}={v:.4g}" for k, v in self.overrides.items())
        return f"{self.system} {self.param} {self.start:.4g}->{self.end:.4g} [{sets}]"


def _range(rng: np.random.Generator, lo: tuple[float, float], hi: tuple[float, float]):
    a, b = rng.uniform(*lo), rng.uniform(*hi)
    return (a, b) if rng.random() < 0.5 else (b, a)


def _hopf(rng: np.random.Generator) -> Variant:
    start, end = _range(rng, (-1.5, -0.6), (0.6, 1.5))
    return Variant("hopf", "mu", start, end, {
        "mu0": rng.uniform(-0.5, 0.5), "a2": rng.uniform(-1.5, 1.5),
        "omega0": float(np.exp(rng.uniform(np.log(0.05), np.log(3.0)))),
        "q5": rng.uniform(0.0, 2.0)})


def _vanderpol(rng: np.random.Generator) -> Variant:
    if rng.random() < 0.25:  # ranges without the Hopf point
        start, end = _range(rng, (0.2, 1.5), (2.0, 6.0))
    else:
        start, end = _range(rng, (-4.0, -0.2), (0.2, 6.0))
    return Variant("vanderpol", "mu", start, end)


def _scaled(rng: np.random.Generator, system: System, skip: str, spread: float = 0.2):
    return {p.name: p.default * rng.uniform(1 - spread, 1 + spread)
            for p in system.parameters if p.name != skip and p.default != 0.0}


def _flutter(rng: np.random.Generator) -> Variant:
    start, end = _range(rng, (3.0, 10.0), (25.0, 40.0))
    return Variant("flutter", "U", start, end, _scaled(rng, get_system("flutter"), "U"))


def _generic(name: str) -> Callable[[np.random.Generator], Variant]:
    def sample(rng: np.random.Generator) -> Variant:
        s = get_system(name)
        p0 = next(p.default for p in s.parameters if p.name == s.default_param)
        w = max(1.0, abs(p0))
        start, end = _range(rng, (p0 - w, p0 - 0.2 * w), (p0 + 0.2 * w, p0 + w))
        return Variant(name, s.default_param, start, end, _scaled(rng, s, s.default_param))

    return sample


#: how to draw a random variant of each built-in autonomous system (others: generic)
SAMPLERS: dict[str, Callable[[np.random.Generator], Variant]] = {
    "hopf": _hopf, "vanderpol": _vanderpol, "flutter": _flutter,
}


def autonomous_builtins() -> list[str]:
    """Every built-in autonomous system."""
    out = []
    for name in list_systems():
        s = get_system(name)
        if s.kind == "autonomous" and getattr(s, "source", "built-in") == "built-in":
            out.append(name)
    return out


def variants(name: str, n: int, seed: int) -> list[Variant]:
    """``n`` random variants of system ``name`` (reproducible from ``seed``)."""
    rng = np.random.default_rng(seed)
    sample = SAMPLERS.get(name) or _generic(name)
    return [sample(rng) for _ in range(n)]


# ----------------------------------------------------------------------- the scan
@dataclass
class Scan:
    params: np.ndarray
    eigs: np.ndarray
    hopf: list[tuple[float, float]]  # (param, omega)
    real: list[tuple[float, float]]  # brackets where det J changed sign
    failed_at: float | None = None  # where Newton lost the equilibrium


@functools.lru_cache(maxsize=16)
def _kernels(field: Callable):
    jac = jax.jit(jax.jacfwd(field))
    return jax.jit(field), jac, jax.jit(jax.vmap(jax.jacfwd(field), in_axes=(0, 0)))


def _equilibrium(system: System, p: np.ndarray, idx: int, lam: float, guess: np.ndarray):
    """Newton from ``guess`` (SciPy's hybrid method when Newton does not converge)."""
    f, jac, _ = _kernels(system.field)
    pl = np.array(p, dtype=float)
    pl[idx] = lam
    x = np.asarray(guess, dtype=float)
    for _ in range(20):
        dx = np.linalg.lstsq(np.asarray(jac(x, pl)), -np.asarray(f(x, pl)), rcond=None)[0]
        x = x + dx
        if np.max(np.abs(dx)) <= 1e-13 * (1 + np.max(np.abs(x))):
            return x
    sol = root(lambda x: np.asarray(f(x, pl)), guess, jac=lambda x: np.asarray(jac(x, pl)),
               method="hybr", tol=1e-13)
    return sol.x if sol.success else None


def _crit_re(system, p, idx, lam, x_guess, target: complex) -> tuple[float, complex, np.ndarray]:
    x = _equilibrium(system, p, idx, lam, x_guess)
    x = x_guess if x is None else x
    _, jac, _ = _kernels(system.field)
    pl = np.array(p, dtype=float)
    pl[idx] = lam
    e = np.linalg.eigvals(np.asarray(jac(x, pl)))
    k = int(np.argmin(np.abs(e - target)))
    return float(e[k].real), complex(e[k]), x


def equilibrium_scan(system: System, param: str, lo: float, hi: float, p, x0=None,
                     n_grid: int = 2001, omega_min: float = 1e-6) -> Scan:
    """The dense, independent scan of the equilibrium from ``lo`` (state ``x0``) to ``hi``
    (``hi < lo`` scans downwards); it stops where Newton loses the equilibrium (a fold)."""
    idx = system.index(param)
    p = np.asarray(p, dtype=float)
    grid = np.linspace(lo, hi, n_grid)
    x = np.zeros(system.n_states) if x0 is None else np.asarray(x0, dtype=float)
    states, failed = [], None
    for lam in grid:
        xs = _equilibrium(system, p, idx, lam, x)
        if xs is None:
            failed = float(lam)
            break
        states.append(xs)
        x = xs
    grid = grid[: len(states)]
    ps = np.repeat(p[None, :], len(grid), axis=0)
    ps[:, idx] = grid
    _, _, batched = _kernels(system.field)
    J = np.asarray(batched(jnp.asarray(np.array(states)), jnp.asarray(ps)))
    eigs = np.linalg.eigvals(J)
    hopf, real = [], []
    for k in range(len(grid) - 1):
        if np.sign(np.linalg.det(J[k])) != np.sign(np.linalg.det(J[k + 1])):
            real.append((float(grid[k]), float(grid[k + 1])))
        for a in eigs[k][eigs[k].imag > omega_min]:
            up = eigs[k + 1][eigs[k + 1].imag > 0]
            if up.size == 0:
                continue
            b = up[int(np.argmin(np.abs(up - a)))]
            if (a.real > 0) == (b.real > 0):
                continue
            hopf.append(_bisect(system, p, idx, grid[k], grid[k + 1], a, states[k]))
    return Scan(grid, eigs, hopf, real, failed)


def _bisect(system, p, idx, la, lb, a: complex, x: np.ndarray) -> tuple[float, float]:
    ra, target = a.real, a
    for _ in range(60):
        lm = 0.5 * (la + lb)
        rm, target, x = _crit_re(system, p, idx, lm, x, target)
        if (rm > 0) == (ra > 0):
            la, ra = lm, rm
        else:
            lb = lm
        if abs(lb - la) <= 1e-14 * max(1.0, abs(la)):
            break
    return 0.5 * (la + lb), abs(target.imag)


# ----------------------------------------------------------------------- the checks
#: name -> (check, needs_orbits)
CHECKS: dict[str, tuple[Callable[[Variant, System, Diagram], list[str]], bool]] = {}


def register_check(name: str, needs_orbits: bool = False):
    """Register a property check (decorator)."""

    def deco(fn):
        CHECKS[name] = (fn, needs_orbits)
        return fn

    return deco


@register_check("equilibria")
def check_equilibria(variant: Variant, system: System, diagram: Diagram) -> list[str]:
    """Hopf points, folds and branch points of the equilibrium branch against the scan,
    along the branch up to its first fold (a uniform scan in the parameter cannot follow
    a branch further); the scan must lose the equilibrium at that fold."""
    eq = diagram.branches[0]
    if len(eq) < 2:
        return [f"the equilibrium branch has {len(eq)} point(s): {eq.message}"]
    step = np.sign(np.diff(eq.params))
    turns = np.nonzero(step != step[0])[0]
    end = int(turns[0]) if turns.size else len(eq) - 1  # last point before the first turn
    lo, hi = float(eq.params[0]), float(eq.params[end])
    folds = [sp for sp in eq.special("fold")]
    if turns.size:  # scan up to the last point before the fold's interval
        if not folds or folds[0].index not in (end - 1, end):
            return [f"the branch turns after {hi:.10g} without a located fold there"]
        end = folds[0].index
        hi = float(eq.params[end])
    scan = equilibrium_scan(system, variant.param, lo, hi, eq.p, eq.solutions[0],
                            n_grid=2001)
    out = []
    if scan.failed_at is not None and not turns.size:
        return [f"the scan lost the equilibrium at {scan.failed_at:.6g}"]
    dp = abs(float(scan.params[1] - scan.params[0]))
    covered = (min(lo, hi) - dp, max(lo, hi) + dp)
    found = [(sp.param, sp.data["omega"]) for sp in eq.special("hopf") if sp.index < end]
    for lam, om in found:
        near = [h for h in scan.hopf if abs(h[0] - lam) <= 1e-7 * max(1.0, abs(lam))]
        if not near:
            out.append(f"false Hopf point at {lam:.10g} (scan: {scan.hopf})")
        elif abs(near[0][1] - om) > 1e-6 * max(1.0, om):
            out.append(f"Hopf at {lam:.10g}: omega {om:.10g}, scan {near[0][1]:.10g}")
    for lam, _ in scan.hopf:
        if not any(abs(f[0] - lam) <= 1e-7 * max(1.0, abs(lam)) for f in found):
            out.append(f"missed Hopf point at {lam:.10g}")
    bps = [c.bracket for c in eq.candidates if c.kind == "branch_point"]
    for a, b in scan.real:
        ok = any(min(c) - dp <= max(a, b) and min(a, b) <= max(c) + dp for c in bps) or any(
            min(a, b) - dp <= f.param <= max(a, b) + dp for f in folds)
        if not ok:
            out.append(f"missed real crossing in [{a:.8g}, {b:.8g}] (no fold, no candidate)")
    for f in folds[1 if turns.size else 0:]:
        if f.index < end and covered[0] <= f.param <= covered[1]:
            out.append(f"false fold at {f.param:.10g}")
    for c in eq.candidates:
        if c.kind == "hopf":
            out.append(f"Hopf candidate in {c.bracket}: {c.reason}")
    return out


def run_variant(variant: Variant, *, orbits: bool = False) -> tuple[Diagram, list[str]]:
    """The variant's diagram and the failures of every applicable check."""
    system = get_system(variant.system)
    p = system.param_vector(variant.overrides)
    diagram = bifurcation_diagram(system, variant.param, variant.start, variant.end, p=p,
                                  x0=variant.x0, orbits=orbits)
    failures = []
    for name, (check, needs_orbits) in CHECKS.items():
        if needs_orbits and not orbits:
            continue
        failures += [f"{name}: {msg}" for msg in check(variant, system, diagram)]
    return diagram, failures
