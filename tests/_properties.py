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

The orbit check compares every orbit branch (and, for the forced built-ins, the FRC)
with Floquet multipliers computed independently: the variational equation integrated by
SciPy (DOP853, rtol 1e-10) over one period from the orbit's first mesh value, on a dense
sample of the orbits and on both neighbours of every located point. The stability label
of every sampled orbit must agree with them; wherever the independent label changes
between two sampled orbits a located orbit bifurcation (or a candidate) must lie between
them (no missed point); and every located cycle fold, branch point, period doubling or
torus point must have its multiplier on the unit circle where its kind says (+1, -1, a
complex pair) by the independent computation (no false point).
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import root

from bifid.continuation import Diagram, bifurcation_diagram, frc
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
    return Variant(
        "hopf",
        "mu",
        start,
        end,
        {
            "mu0": rng.uniform(-0.5, 0.5),
            "a2": rng.uniform(-1.5, 1.5),
            "omega0": float(np.exp(rng.uniform(np.log(0.05), np.log(3.0)))),
            "q5": rng.uniform(0.0, 2.0),
        },
    )


def _vanderpol(rng: np.random.Generator) -> Variant:
    if rng.random() < 0.25:  # ranges without the Hopf point
        start, end = _range(rng, (0.2, 1.5), (2.0, 6.0))
    else:
        start, end = _range(rng, (-4.0, -0.2), (0.2, 6.0))
    return Variant("vanderpol", "mu", start, end)


def _scaled(rng: np.random.Generator, system: System, skip: str, spread: float = 0.2):
    return {
        p.name: p.default * rng.uniform(1 - spread, 1 + spread)
        for p in system.parameters
        if p.name != skip and p.default != 0.0
    }


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


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def _duffing(rng: np.random.Generator) -> Variant:
    """A hardening or softening Duffing FRC round its primary resonance (softening kept
    below the escape amplitude ``1/sqrt(|gamma|)``)."""
    hardening = rng.random() < 0.6
    gamma = rng.uniform(0.1, 1.0) if hardening else -rng.uniform(0.05, 0.3)
    F = _log_uniform(rng, 0.005, 0.03 if hardening else 0.01)
    start, end = _range(rng, (0.6, 0.85), (1.15, 1.6))
    return Variant(
        "duffing",
        "Omega",
        start,
        end,
        {"zeta": _log_uniform(rng, 0.005, 0.05), "gamma": gamma, "F": F},
    )


def _shaw_pierre(rng: np.random.Generator) -> Variant:
    """An FRC of both modes (near 1 and sqrt(3))."""
    over = _scaled(rng, get_system("shaw_pierre"), "Omega")
    over["F"] = _log_uniform(rng, 0.003, 0.02)
    start, end = _range(rng, (0.8, 0.95), (1.8, 2.0))
    return Variant("shaw_pierre", "Omega", start, end, over)


#: how to draw a random variant of each built-in system (other autonomous ones: generic)
SAMPLERS: dict[str, Callable[[np.random.Generator], Variant]] = {
    "hopf": _hopf,
    "vanderpol": _vanderpol,
    "flutter": _flutter,
    "duffing": _duffing,
    "shaw_pierre": _shaw_pierre,
}


def autonomous_builtins() -> list[str]:
    """Every built-in autonomous system."""
    out = []
    for name in list_systems():
        s = get_system(name)
        if s.kind == "autonomous" and getattr(s, "source", "built-in") == "built-in":
            out.append(name)
    return out


def forced_builtins() -> list[str]:
    """Every built-in forced system."""
    return [
        name
        for name in list_systems()
        if get_system(name).kind == "forced"
        and getattr(get_system(name), "source", "built-in") == "built-in"
    ]


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
    sol = root(
        lambda x: np.asarray(f(x, pl)),
        guess,
        jac=lambda x: np.asarray(jac(x, pl)),
        method="hybr",
        tol=1e-13,
    )
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


def equilibrium_scan(
    system: System,
    param: str,
    lo: float,
    hi: float,
    p,
    x0=None,
    n_grid: int = 2001,
    omega_min: float = 1e-6,
) -> Scan:
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
#: name -> (check, needs_orbits, kinds of system it applies to)
CHECKS: dict[str, tuple[Callable[[Variant, System, Diagram], list[str]], bool, tuple[str, ...]]]
CHECKS = {}


def register_check(name: str, needs_orbits: bool = False, kinds: tuple[str, ...] = ("autonomous",)):
    """Register a property check (decorator) for systems of the given ``kinds``."""

    def deco(fn):
        CHECKS[name] = (fn, needs_orbits, kinds)
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
    scan = equilibrium_scan(system, variant.param, lo, hi, eq.p, eq.solutions[0], n_grid=2001)
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
            min(a, b) - dp <= f.param <= max(a, b) + dp for f in folds
        )
        if not ok:
            out.append(f"missed real crossing in [{a:.8g}, {b:.8g}] (no fold, no candidate)")
    for f in folds[1 if turns.size else 0 :]:
        if f.index < end and covered[0] <= f.param <= covered[1]:
            out.append(f"false fold at {f.param:.10g}")
    for c in eq.candidates:
        if c.kind == "hopf":
            out.append(f"Hopf candidate in {c.bracket}: {c.reason}")
    return out


# ------------------------------------------------------------ orbits: multipliers
_VARIATIONAL: dict[Callable, Callable] = {}


def _variational(system: System) -> Callable:
    """Jitted ``(t, [x, vec Phi], p) -> [f, vec(J Phi)]`` of the full right-hand side."""
    key = system.field
    if key not in _VARIATIONAL:
        n = system.n_states

        def rhs(t, z, p):
            x, phi = z[:n], z[n:].reshape(n, n)
            f = system.rhs(x, t, p)
            J = jax.jacfwd(lambda y: system.rhs(y, t, p))(x)
            return jnp.concatenate([f, (J @ phi).ravel()])

        _VARIATIONAL[key] = jax.jit(rhs)
    return _VARIATIONAL[key]


def independent_multipliers(system: System, p, x0, period: float) -> np.ndarray:
    """Eigenvalues of the monodromy matrix from ``x0`` over ``period``: the variational
    equation integrated by SciPy (DOP853, rtol 1e-10), independent of bifid's Floquet
    code."""
    n = system.n_states
    rhs, pj = _variational(system), jnp.asarray(np.asarray(p, dtype=float))
    z0 = np.concatenate([np.asarray(x0, dtype=float), np.eye(n).ravel()])
    sol = solve_ivp(
        lambda t, z: np.asarray(rhs(t, z, pj)),
        (0.0, period),
        z0,
        method="DOP853",
        rtol=1e-10,
        atol=1e-12,
    )
    return np.linalg.eigvals(sol.y[n:, -1].reshape(n, n))


def _orbit_of(system: System, br, sol: np.ndarray, param: float, M: int, data_i=None):
    """(parameter vector, first mesh value, period) of an orbit or forced response."""
    n = system.n_states
    p = np.array(br.p, dtype=float)
    p[system.index(br.param)] = param
    if br.kind == "periodic":
        return p, sol[:n], float(sol[M * n])
    if data_i is not None:
        p[system.index("Omega")], p[system.index("F")] = data_i
    return p, sol[:n], 2 * np.pi / float(p[system.index("Omega")])


def _nontrivial(mults: np.ndarray, autonomous: bool) -> np.ndarray:
    if not autonomous:
        return mults
    return np.delete(mults, int(np.argmin(np.abs(mults - 1.0))))


def _label(mults: np.ndarray, tol: float = 1e-6) -> float:
    """1 stable, 0 unstable, NaN within ``tol`` of the unit circle."""
    top = float(np.max(np.abs(mults))) if mults.size else 0.0
    return 1.0 if top < 1 - tol else 0.0 if top > 1 + tol else float("nan")


def _on_circle(kind: str, mults: np.ndarray, autonomous: bool) -> bool:
    """The located point's multipliers as its kind says (independent computation)."""
    if kind in ("cycle_fold", "fold", "branch_point"):
        near = np.sort(np.abs(mults - 1.0))
        # autonomous: trivial and critical multiplier (a Jordan block splits ~sqrt(eps))
        return bool(near[1 if autonomous else 0] <= 1e-3)
    if kind == "period_doubling":
        return bool(np.min(np.abs(mults + 1.0)) <= 1e-5)
    if kind == "torus":
        pair = mults[np.abs(mults.imag) > 1e-3]
        return bool(pair.size and np.min(np.abs(np.abs(pair) - 1.0)) <= 1e-5)
    return True  # peaks and others: no multiplier condition


ORBIT_KINDS = ("cycle_fold", "fold", "branch_point", "period_doubling", "torus")


def check_orbit_branch(system: System, br, n_sample: int = 12) -> list[str]:
    """One orbit branch (or forced response) against independent multipliers."""
    autonomous = br.kind == "periodic"
    M = int(br.meta["n_mesh"])
    forced = None if autonomous else np.column_stack([br.data["omega"], br.data["forcing"]])
    pts = [sp for sp in br.special_points if sp.kind in ORBIT_KINDS]
    zero = np.zeros(len(br), bool)
    if autonomous:  # the zero-amplitude orbits at Hopf points have no multipliers to check
        zero = np.max(np.reshape(br.data["amplitude_centred"], (len(br), -1)), axis=1) <= 1e-8
    idx = set(np.linspace(0, len(br) - 1, n_sample).astype(int).tolist())
    idx |= {j for sp in pts for j in (sp.index, sp.index + 1) if 0 <= j < len(br)}
    idx = sorted(i for i in idx if not zero[i])
    out, labels = [], {}
    for i in idx:
        p, x0, T = _orbit_of(
            system, br, br.solutions[i], br.params[i], M, None if forced is None else forced[i]
        )
        mu = _nontrivial(independent_multipliers(system, p, x0, T), autonomous)
        labels[i] = _label(mu)
        if np.isfinite(labels[i]) and bool(labels[i]) != bool(br.stable[i]):
            out.append(
                f"orbit {i} at {br.params[i]:.8g}: labelled "
                f"{'stable' if br.stable[i] else 'unstable'}, independent "
                f"max|mu| = {np.max(np.abs(mu)):.8g}"
            )
    known = [i for i in idx if np.isfinite(labels[i])]
    brackets = [c.bracket for c in br.candidates]
    for i, j in itertools.pairwise(known):
        if labels[i] == labels[j]:
            continue
        lo, hi = sorted((float(br.params[i]), float(br.params[j])))
        if not (
            any(i <= sp.index < j for sp in pts)
            or any(min(c) <= hi and lo <= max(c) for c in brackets)
        ):
            out.append(
                f"missed orbit bifurcation between orbits {i} and {j} "
                f"({br.params[i]:.8g} .. {br.params[j]:.8g}): stability changes"
            )
    for sp in pts:
        Ms = int(sp.data.get("n_mesh", M))
        data_i = (
            None
            if autonomous
            else (
                (sp.param, br.data["forcing"][sp.index])
                if br.param == "Omega"
                else (br.data["omega"][sp.index], sp.param)
            )
        )
        p, x0, T = _orbit_of(system, br, np.asarray(sp.solution), sp.param, Ms, data_i)
        mults = independent_multipliers(system, p, x0, T)
        if not _on_circle(sp.kind, mults, autonomous):
            out.append(
                f"false {sp.kind} at {sp.param:.10g}: independent multipliers "
                f"{np.round(mults, 8).tolist()}"
            )
    return out


@register_check("orbits", needs_orbits=True, kinds=("autonomous", "forced"))
def check_orbits(variant: Variant, system: System, diagram: Diagram) -> list[str]:
    """Every orbit branch (every FRC) against independent Floquet multipliers."""
    out = []
    for k, br in enumerate(diagram.branches):
        if br.kind != "equilibrium" and len(br) >= 2:
            out += [f"branch {k}: {m}" for m in check_orbit_branch(system, br)]
    return out


def run_variant(variant: Variant, *, orbits: bool = False) -> tuple[Diagram, list[str]]:
    """The variant's diagram and the failures of every applicable check (forced systems:
    the FRC over the variant's range, always with the orbit checks)."""
    system = get_system(variant.system)
    p = system.param_vector(variant.overrides)
    if system.kind == "forced":
        br = frc(system, float(p[system.index("F")]), (variant.start, variant.end), p=p)
        diagram, orbits = (
            Diagram(kind="frc", system=system.name, param="Omega", branches=[br]),
            True,
        )
    else:
        diagram = bifurcation_diagram(
            system, variant.param, variant.start, variant.end, p=p, x0=variant.x0, orbits=orbits
        )
    failures = []
    for name, (check, needs_orbits, kinds) in CHECKS.items():
        if (needs_orbits and not orbits) or system.kind not in kinds:
            continue
        failures += [f"{name}: {msg}" for msg in check(variant, system, diagram)]
    return diagram, failures
