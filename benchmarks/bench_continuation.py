#!/usr/bin/env python
"""Benchmark: the flutter periodic-orbit branch from the Hopf point through the cycle fold.

Task (identical for every method): start at the subcritical Hopf point of the
``flutter`` model (U_H ≈ 18.2748 m/s), follow the unstable orbits down to the fold of
cycles (U ≈ 14.9378 m/s), turn there and follow the stable orbits back up to
U = 18.3 m/s (parameter window ``p_min=14, p_max=18.3``), with Floquet stability of
every orbit and the fold located.

* bifid: ``locate_hopf`` + ``hopf_orbits(n_mesh=M)`` (Fourier collocation, PALC).
  Compile time = first call − warm median; warm time = median of ``--repeats`` runs.
* baseline (same run): single shooting with ``scipy.integrate.solve_ivp`` (DOP853) +
  ``scipy.optimize.root`` with pseudo-arclength in ``(x0, T, U)``
  (``benchmarks/_shooting.py``), on a NumPy version of the same vector field.
* accuracy: the fold speed of each method against bifid at M = 128.
* jaxcont (PyPI): the same task attempted with its periodic-orbit collocation.

Run ``python benchmarks/bench_continuation.py`` (or ``make bench``); writes the
"continuation" section of BENCHMARKS.md. ``--repeats`` sets the warm runs (≥ 3).
"""

from __future__ import annotations

import argparse
import functools
import os
import statistics
import sys
import time
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import jax
import numpy as np

import _shooting
import bifid  # noqa: F401  (enables float64)
from _report import write_section
from bifid.continuation import (
    ContinuationOptions,
    hopf_orbits,
    locate_hopf,
    periodic_orbits,
)
from bifid.systems import flutter_matrices, get_system

P_MIN, P_MAX = 14.0, 18.3
ORBIT_OPTIONS = ContinuationOptions(
    ds=1e-3, ds_min=1e-9, ds_max=0.25, p_min=P_MIN, p_max=P_MAX, max_steps=600
)
REF_MESH = 128
# bifid meshes timed. Fold error against M = 128 (this model): M=20 3e-8, M=24 7e-11,
# M=32 4e-15 (round-off); 48 is a comfortable everyday mesh (no ResolutionWarning).
MESHES = (24, 32, 48)
# Shooting tolerances, tuned by hand so that the fold errors bracket bifid's:
# rtol=1e-10 gives 3e-11 (~ bifid M=24), rtol=1e-12 gives 3e-13 (bifid M>=32 is better).
BASELINE_RTOLS = (1e-10, 1e-12)
# "comparable accuracy": bifid's fold error at most this factor above the baseline's
COMPARABLE = 3.0


def shooting_options(rtol: float) -> _shooting.ShootingOptions:
    """Same step control as ``ORBIT_OPTIONS``; DOP853 rtol, root xtol = rtol, atol = rtol/100."""
    return _shooting.ShootingOptions(
        ds=ORBIT_OPTIONS.ds,
        ds_min=ORBIT_OPTIONS.ds_min,
        ds_max=ORBIT_OPTIONS.ds_max,
        p_min=P_MIN,
        p_max=P_MAX,
        max_steps=ORBIT_OPTIONS.max_steps,
        rtol=rtol,
        atol=rtol * 1e-2,
        xtol=rtol,
        ftol=max(100 * rtol, 1e-10),
    )


def log(msg: str) -> None:
    print(f"[bench_continuation {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def timed(fn: Callable, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


# ----------------------------------------------------------------------------- bifid
def bifid_task(system, p, M):
    """The benchmark task with bifid: Hopf point, then the orbit branch at mesh M."""
    h = locate_hopf(system, "U", x_guess=np.zeros(system.n_states), lam_guess=18.0, p=p)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        br = hopf_orbits(system, h, n_mesh=M, options=ORBIT_OPTIONS)
    return h, br, sorted({type(w.message).__name__ for w in caught})


def fold_of(br) -> tuple[float, int]:
    """Parameter of the single cycle fold of a bifid branch and the index before it."""
    folds = br.special("cycle_fold")
    if len(folds) != 1:
        raise RuntimeError(f"expected exactly one cycle fold, found {len(folds)}")
    return float(folds[0].param), int(folds[0].index)


def split_ok(params: np.ndarray, stable: np.ndarray) -> bool:
    """True if every orbit before the turn (lowest U) is unstable and every one after is
    stable (the orbit at the turn itself is not judged)."""
    i = int(np.argmin(params))
    stable = np.asarray(stable, dtype=bool)
    return bool(not np.any(stable[:i]) and np.all(stable[i + 1 :]))


def reference_fold(system, p, br, M_from: int, M_ref: int = REF_MESH):
    """bifid's fold speed at ``M_ref`` points, continued locally through the fold.

    Starts from the orbit of ``br`` (mesh ``M_from``) just before its fold, resampled to
    ``M_ref`` points, and follows it through the fold (a short branch; the full branch at
    M = 128 gives the same fold to ~1e-14 but costs a minute more).
    """
    _, i = fold_of(br)
    n = system.n_states
    V = br.solutions[i, : M_from * n].reshape(M_from, n)
    U_i = float(br.params[i])
    opts = ContinuationOptions(
        ds=0.01,
        ds_min=1e-9,
        ds_max=0.05,
        p_min=U_i - 1.0,
        p_max=U_i + 0.1,
        direction=-1,
        max_steps=200,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = periodic_orbits(
            system,
            "U",
            V,
            float(br.data["period"][i]),
            p=p.at[system.index("U")].set(U_i),
            n_mesh=M_ref,
            options=opts,
        )
    return fold_of(ref)[0], len(ref)


# -------------------------------------------------------------------------- baseline
def flutter_numpy_setup(system, p):
    """NumPy field of the flutter model, ``f(x) = A(U) x + c g(alpha)`` (see below).

    ``A`` (linear part), ``dA/dU`` and ``c`` come from ``bifid.systems.flutter_matrices``
    (the same model as bifid; ``dA/dU`` by forward-mode AD); the only nonlinearity is
    ``g(alpha) = ka2 alpha^2 + ka3 alpha^3`` in the pitch equation. Returns
    ``make() -> setup`` where ``setup(U) -> (f, f_x, f_U)`` caches the matrices per U;
    call ``make()`` once per run so no run profits from another's cache.
    """
    p = np.asarray(p, dtype=float)
    iU = system.index("U")
    ka2, ka3 = float(p[system.index("ka2")]), float(p[system.index("ka3")])
    mats = jax.jit(lambda pv: (flutter_matrices(pv), jax.jacfwd(flutter_matrices)(pv)))
    qi, vi = np.array([0, 2, 4]), np.array([1, 3, 5])

    def build(lam: float):
        pv = p.copy()
        pv[iU] = lam
        (M, D, K), (dM, dD, dK) = (tuple(np.asarray(a) for a in g) for g in mats(pv))
        if np.any(dM[..., iU] != 0):
            raise ValueError("the mass matrix depends on U; the baseline assumes it does not")
        Minv = np.linalg.inv(M)
        A = np.zeros((6, 6))
        A[qi, vi] = 1.0
        A[np.ix_(vi, qi)] = -Minv @ K
        A[np.ix_(vi, vi)] = -Minv @ D
        AU = np.zeros((6, 6))
        AU[np.ix_(vi, qi)] = -Minv @ dK[..., iU]
        AU[np.ix_(vi, vi)] = -Minv @ dD[..., iU]
        c = np.zeros(6)
        c[vi] = -Minv[:, 1]

        def f(x):
            a = x[2]
            return A @ x + c * (a * a * (ka2 + ka3 * a))

        def fx(x):
            a = x[2]
            J = A.copy()
            J[:, 2] += c * (a * (2.0 * ka2 + 3.0 * ka3 * a))
            return J

        def fU(x):
            return AU @ x

        return f, fx, fU

    def make():
        cached = functools.lru_cache(maxsize=512)(build)
        return lambda lam: cached(float(lam))

    return make


def check_numpy_field(system, p, make) -> float:
    """Largest relative difference of the NumPy field/Jacobians from bifid's JAX field."""
    rng = np.random.default_rng(0)
    setup = make()
    iU = system.index("U")
    worst = 0.0
    for U in (14.0, 16.0, 18.3):
        pv = p.at[iU].set(U)
        f, fx, fU = setup(U)
        for _ in range(4):
            x = rng.normal(size=system.n_states) * 0.2
            pairs = (
                (f(x), system.field(x, pv)),
                (fx(x), jax.jacfwd(system.field)(x, pv)),
                (fU(x), jax.jacfwd(system.field, argnums=1)(x, pv)[:, iU]),
            )
            for a, b in pairs:
                b = np.asarray(b)
                worst = max(worst, float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300)))
    return worst


def shooting_task(make, rtol: float):
    setup = make()
    hopf = _shooting.locate_hopf(setup, lambda lam: np.zeros(6), 16.0, 20.0)
    return hopf, _shooting.continue_from_hopf(setup, 6, hopf, shooting_options(rtol))


# --------------------------------------------------------------------------- jaxcont
JAXCONT_MESH = (20, 4)  # ntst intervals x ncol Gauss points: 601 unknowns, like bifid M=100
JAXCONT_STEPS = 36  # its steps are deterministic: fold after step 23, U > 18.3 at step 35


def jaxcont_attempt(system, p, seed_branch, M_seed: int, ref_fold: float, refine_fold: bool):
    """Periodic-orbit continuation with jaxcont, seeded with bifid's first orbit.

    jaxcont cannot start at a Hopf point (``periodic_orbit_problem`` needs a trajectory
    guess "from the caller's own simulation"), and the orbits next to this subcritical
    Hopf point are unstable, so no simulation gives them: we hand it the first orbit of
    bifid's branch (amplitude ~1e-3, next to the Hopf point).
    """
    import jax.numpy as jnp
    import jaxcont as jc
    from jaxcont.core.collocation import Collocation
    from jaxcont.core.scan_continuation import pseudo_arclength_scan
    from jaxcont.problems.periodic import periodic_orbit_problem
    from jaxcont.solvers.protocols import Dense
    from jaxcont.stability.floquet import branch_floquet_multipliers, floquet_stable

    out: dict = {"version": jc.__version__}
    n = system.n_states
    V = seed_branch.solutions[1, : M_seed * n].reshape(M_seed, n)
    T = float(seed_branch.data["period"][1])
    U0 = float(seed_branch.params[1])
    traj = np.vstack([V, V[:1]])
    tt = np.linspace(0.0, T, M_seed + 1)
    iU = system.index("U")

    def f(u, lam, _args):
        return system.field(u, p.at[iU].set(lam))

    ntst, ncol = JAXCONT_MESH
    mesh = Collocation(ntst=ntst, ncol=ncol)
    settings = jc.ContinuationPar(
        ds=0.01,
        ds_min=1e-8,
        ds_max=0.5,
        max_steps=JAXCONT_STEPS,
        newton_tol=1e-9,
        newton_max_iter=10,
    )
    out["settings"] = (
        f"ntst={ntst}, ncol={ncol}, ds=0.01, ds_max=0.5, "
        f"max_steps={JAXCONT_STEPS}, newton_tol=1e-9, float64"
    )
    prob, out["t_build"] = timed(
        periodic_orbit_problem, f, jnp.asarray(traj), jnp.asarray(tt), T, U0, mesh
    )
    # jc.continuation() builds a new ``rhs2`` lambda on every call and passes it as a
    # *static* argument of the jitted engine, so every call recompiles; time the engine
    # it wraps with one fixed rhs (compile once, then warm), then the same Floquet
    # post-pass continuation() runs
    args = prob.args

    def rhs2(u, lam):
        return prob.f(u, lam, args)

    dt = jnp.float64

    def engine():
        r = pseudo_arclength_scan(
            rhs2,
            prob.u0,
            jnp.asarray(U0, dt),
            jnp.asarray(P_MIN, dt),
            jnp.asarray(settings.ds, dt),
            jnp.asarray(settings.ds_min, dt),
            jnp.asarray(settings.ds_max, dt),
            jnp.asarray(settings.newton_tol, dt),
            settings.max_steps,
            jnp.asarray(settings.newton_max_iter),
            Dense(),
            jnp.asarray(True),
        )
        return jax.block_until_ready(r)

    scan, out["t_first"] = timed(engine)
    scan, out["t_scan"] = timed(engine)
    k = int(scan.n_valid)
    states, params = scan.states[:k], scan.params[:k]

    def floquet():
        mults = branch_floquet_multipliers(args[2], mesh, states, params)
        return np.asarray(floquet_stable(mults))

    stable, out["t_floquet_first"] = timed(floquet)  # eager vmap: compiles its primitives
    stable, out["t_floquet"] = timed(floquet)
    out["t_warm"] = out["t_scan"] + out["t_floquet"]
    P = np.asarray(params)
    out["n_points"] = len(P)
    out["p_min_reached"] = float(P.min())
    out["p_last"] = float(P[-1])
    i = int(np.argmin(P))
    out["n_stable"] = int(np.sum(stable))
    out["stable_split_ok"] = split_ok(P, stable)
    above = np.nonzero(P[i:] > P_MAX)[0]
    out["reached_p_max"] = bool(above.size)
    out["n_task_points"] = int(i + above[0] + 1) if above.size else len(P)
    if 0 < i < len(P) - 1:  # parabola through the three points around the turn
        s = np.concatenate(
            [
                [0.0],
                np.cumsum(
                    np.linalg.norm(np.diff(np.asarray(states)[i - 1 : i + 2], axis=0), axis=1)
                ),
            ]
        )
        c = np.polyfit(s, P[i - 1 : i + 2], 2)
        out["fold_parabola"] = float(np.polyval(c, -c[1] / (2 * c[0])))
    if refine_fold:  # through the public API: compile + run + Floquet + Fold() refinement
        res, out["t_fold"] = timed(
            jc.continuation, prob, p_span=(U0, P_MIN), settings=settings, events=[jc.Fold()]
        )
        out["folds"] = [
            (float(e.p), bool(e.info.get("converged"))) for e in res.events if e.kind == "fold"
        ]
    return out


# ------------------------------------------------------------------------------ main
def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="warm runs per method (>= 3)")
    ap.add_argument(
        "--quick", action="store_true", help="skip the tight baseline (rtol=1e-12) and jaxcont"
    )
    ap.add_argument("--no-jaxcont", action="store_true", help="skip the jaxcont attempt")
    ap.add_argument(
        "--jaxcont-fold",
        action="store_true",
        help="also run jaxcont's Fold() refinement (slow: minutes)",
    )
    ap.add_argument("--no-write", action="store_true", help="print, do not write BENCHMARKS.md")
    a = ap.parse_args(argv)
    repeats = max(3, a.repeats)
    load0 = os.getloadavg()
    t_start = time.perf_counter()
    system = get_system("flutter")
    p = system.param_vector()

    log("bifid: locate_hopf (first call = compile + run)")
    h, t_hopf_first = timed(locate_hopf, system, "U", np.zeros(6), 18.0, p)
    hopf_warm = statistics.median(
        timed(locate_hopf, system, "U", np.zeros(6), 18.0, p)[1] for _ in range(repeats)
    )

    rows: dict[int, dict] = {}
    branches = {}
    for M in MESHES:
        log(f"bifid: M={M} first call (compile + run)")
        (_, br, _), t_first = timed(bifid_task, system, p, M)
        times = []
        for r in range(repeats):
            (_, br, warns), dt = timed(bifid_task, system, p, M)
            times.append(dt)
            log(f"bifid: M={M} warm run {r + 1}: {dt:.2f} s, {len(br)} orbits")
        branches[M] = br
        rows[M] = dict(
            first=t_first,
            warm=statistics.median(times),
            times=times,
            n=len(br),
            n_stable=int(np.sum(br.stable)),
            fold=fold_of(br)[0],
            split=split_ok(br.params, br.stable),
            status=br.status,
            warnings=warns,
            p_end=float(br.params[-1]),
            p_lo=float(np.min(br.params)),
        )

    log(f"bifid: reference fold at M={REF_MESH}")
    M_top = MESHES[-1]
    (ref_fold, n_ref), t_ref = timed(reference_fold, system, p, branches[M_top], M_top)
    for r in rows.values():
        r["err"] = r["fold"] - ref_fold

    make = flutter_numpy_setup(system, p)
    field_err = check_numpy_field(system, p, make)
    if field_err > 1e-12:
        raise RuntimeError(f"NumPy flutter field differs from bifid's by {field_err:.1e}")
    base: dict[float, dict] = {}
    for rtol in BASELINE_RTOLS:
        runs = repeats if rtol == BASELINE_RTOLS[0] else 1
        if a.quick and rtol != BASELINE_RTOLS[0]:
            continue
        times = []
        for r in range(runs):
            (sh_hopf, sh), dt = timed(shooting_task, make, rtol)
            times.append(dt)
            log(
                f"shooting rtol={rtol:g}: run {r + 1}: {dt:.2f} s ({len(sh)} orbits, "
                f"{sh.n_integrations} integrations)"
            )
        if len(sh.folds) != 1:
            raise RuntimeError(f"shooting: expected one cycle fold, found {len(sh.folds)}")
        base[rtol] = dict(
            warm=statistics.median(times),
            times=times,
            n=len(sh),
            n_stable=int(np.sum(sh.stable)),
            fold=sh.folds[0][0],
            split=split_ok(sh.params, sh.stable),
            err=sh.folds[0][0] - ref_fold,
            status=sh.status,
            n_int=sh.n_integrations,
            hopf=sh_hopf.lam,
            p_end=float(sh.params[-1]),
            p_lo=float(np.min(sh.params)),
        )

    jx: dict | None = None
    if not (a.no_jaxcont or a.quick):
        log("jaxcont: periodic-orbit continuation attempt")
        try:
            jx = jaxcont_attempt(
                system, p, branches[MESHES[0]], MESHES[0], ref_fold, a.jaxcont_fold
            )
        except Exception as exc:  # record precisely what failed
            jx = {"error": f"{type(exc).__name__}: {exc}".splitlines()[0][:300]}
            traceback.print_exc()
    load1 = os.getloadavg()
    total = time.perf_counter() - t_start

    md = render(
        rows,
        base,
        ref_fold,
        n_ref,
        t_ref,
        h,
        t_hopf_first,
        hopf_warm,
        field_err,
        jx,
        load0,
        load1,
        total,
    )
    print(md)
    if not a.no_write:
        write_section("continuation", md)
        log("wrote the 'continuation' section of BENCHMARKS.md")
    return 0


def _yn(flag: bool) -> str:
    return "yes" if flag else "**no**"


def _fmt_times(ts) -> str:
    return ", ".join(f"{t:.2f}" for t in ts)


def pairs(rows: dict, base: dict) -> list[tuple[float, int]]:
    """For each baseline tolerance the cheapest bifid mesh at least as accurate (within
    ``COMPARABLE``) — the "equal accuracy of the fold speed" comparison."""
    out = []
    for rtol, b in base.items():
        ok = [M for M, r in rows.items() if abs(r["err"]) <= COMPARABLE * abs(b["err"])]
        if ok:
            out.append((rtol, min(ok, key=lambda M: rows[M]["warm"])))
    return out


def render(
    rows,
    base,
    ref_fold,
    n_ref,
    t_ref,
    h,
    t_hopf_first,
    hopf_warm,
    field_err,
    jx,
    load0,
    load1,
    total,
) -> str:
    L = ["## Continuation: flutter orbit branch through the cycle fold", ""]
    L.append(
        "**Task.** From the subcritical Hopf point of `flutter` (U_H = "
        f"{h.param:.6f} m/s) follow the periodic orbits down through the fold of cycles "
        f"(U = {ref_fold:.10f} m/s) and back up the stable side to U = {P_MAX:g} m/s "
        f"(`ContinuationOptions(p_min={P_MIN:g}, p_max={P_MAX:g})`), with Floquet "
        "stability of every orbit and the fold located. The lower bound 14 m/s "
        "is below the fold: this model puts the fold at 14.94 > 14, so the branch "
        "never reaches U = 14, it "
        f"turns at the fold and the stable orbits climb back up; we stop them at "
        f"{P_MAX:g} (just above U_H).\n"
    )
    L.append(
        "**Methods.** bifid: `locate_hopf` + `hopf_orbits(n_mesh=M)` (Fourier collocation, "
        "pseudo-arclength, Floquet multipliers of every orbit, fold located by a secant "
        "on the tangent). Baseline, measured in the same run: single shooting with "
        "`scipy.integrate.solve_ivp` (DOP853, with the variational equations for an exact "
        "Jacobian and the monodromy matrix) + `scipy.optimize.root` (hybr), "
        "pseudo-arclength in (x0, T, U), Poincaré phase condition, same step control "
        "(ds=1e-3, ds_max=0.25, ×1.5 growth), fold by the same tangent-sign secant "
        "(`benchmarks/_shooting.py`); Hopf point by `brentq` on the eigenvalues; the vector "
        f"field in NumPy from the same `flutter_matrices` (equal to bifid's to "
        f"{field_err:.0e}).\n"
    )
    L.append(
        f"**Accuracy** = fold speed minus bifid's at M = {REF_MESH} ({ref_fold:.13f}; "
        f"continued through the fold from the M = {MESHES[-1]} branch, {n_ref} orbits, "
        f"{t_ref:.0f} s incl. compile). The baseline's tolerance is the knob: rtol "
        "1e-10 matches bifid at M = 24, rtol 1e-12 is the tightest practical one "
        "(DOP853 near round-off) and is still less accurate than bifid at M ≥ 32.\n"
    )
    L.append(
        "| method | compile [s] | warm median [s] (runs) | orbits (stable) | "
        "stability split right | fold U [m/s] | fold error |"
    )
    L.append("|---|---|---|---|---|---|---|")
    for M, r in rows.items():
        L.append(
            f"| bifid, Fourier M = {M} | {r['first'] - r['warm']:.1f} | **{r['warm']:.2f}** "
            f"({_fmt_times(r['times'])}) | {r['n']} ({r['n_stable']}) | {_yn(r['split'])} | "
            f"{r['fold']:.12f} | "
            f"{r['err']:+.1e} |"
        )
    for rtol, b in base.items():
        L.append(
            f"| shooting, rtol = {rtol:g} | — | **{b['warm']:.2f}** ({_fmt_times(b['times'])}) "
            f"| {b['n']} ({b['n_stable']}) | {_yn(b['split'])} | {b['fold']:.12f} | "
            f"{b['err']:+.1e} |"
        )
    L.append("")
    L.append(
        "(*Stability split right*: every orbit before the turn is unstable and every one "
        "after it stable, by the Floquet multipliers.)\n"
    )
    L.append(
        "**Speed-up at equal accuracy** (baseline warm median / bifid warm median; "
        f"bifid's mesh = the cheapest whose fold error is ≤ {COMPARABLE:g}× the "
        "baseline's):\n"
    )
    for rtol, M in pairs(rows, base):
        b, r = base[rtol], rows[M]
        L.append(
            f"- shooting rtol = {rtol:g} (fold error {abs(b['err']):.0e}) vs bifid M = {M} "
            f"({abs(r['err']):.0e}): **{b['warm'] / r['warm']:.1f}×** "
            f"({b['warm']:.2f} s / {r['warm']:.2f} s"
            + (", baseline timed once" if len(b["times"]) == 1 else "")
            + ")"
        )
    for rtol, b in base.items():
        others = ", ".join(f"M = {M}: {b['warm'] / r['warm']:.1f}×" for M, r in rows.items())
        L.append(f"- all ratios against shooting rtol = {rtol:g}: {others}")
    L.append("")
    L.append(
        f"Compile = first call − warm median: the Hopf kernels once "
        f"({t_hopf_first - hopf_warm:.1f} s; `locate_hopf` warm {hopf_warm * 1e3:.0f} ms, "
        "included in the warm times), then per mesh size the collocation residual/Jacobian "
        "and the vmapped monodromy integrator. Ends: "
        + "; ".join(
            f"bifid M={M} {r['status']} (U {r['p_lo']:.4f} … {r['p_end']:.4f})"
            + (f" with {', '.join(r['warnings'])}" if r["warnings"] else "")
            for M, r in rows.items()
        )
        + "; "
        + "; ".join(
            f"shooting rtol={rtol:g} {b['status']} (U {b['p_lo']:.4f} … "
            f"{b['p_end']:.4f}, {b['n_int']} flow integrations of 48 ODEs)"
            for rtol, b in base.items()
        )
        + ".\n"
    )
    if any(r["warnings"] for r in rows.values()):
        L.append(
            "bifid's `ResolutionWarning` at small M says the orbits' Fourier spectra have not "
            "decayed to 1e-9 of their peak (orbit shapes resolved to ~1e-5 at M = 24); the "
            "fold speed converges much faster, as the errors show.\n"
        )
    L.append(render_jaxcont(jx, ref_fold, rows))
    L.append(
        f"Load average (1/5/15 min) {load0[0]:.1f}/{load0[1]:.1f}/{load0[2]:.1f} at the start "
        f"and {load1[0]:.1f}/{load1[1]:.1f}/{load1[2]:.1f} at the end, {os.cpu_count()} "
        "cores shared with other jobs: absolute times are inflated and noisy; compare the "
        f"ratios, which come from the same run. Whole script {total:.0f} s. Reproduce: "
        "`.venv/bin/python benchmarks/bench_continuation.py` (or `make bench`)."
    )
    return "\n".join(L)


def render_jaxcont(jx, ref_fold, rows) -> str:
    if jx is None:
        return "**jaxcont**: skipped (`--no-jaxcont` / `--quick`).\n"
    head = f"**jaxcont {jx.get('version', '?')}** (PyPI) on the same task. "
    limits = (
        "What it cannot do (from its source: `jaxcont/problems/periodic.py`, "
        "`core/scan_continuation.py`, `api.py`): it cannot start a periodic branch at a "
        'Hopf point — `periodic_orbit_problem` takes a trajectory guess "from the '
        "caller's own simulation\" and the orbits next to this subcritical Hopf point are "
        "unstable, so no simulation gives them (we seeded it with bifid's first orbit); "
        "the integral phase condition keeps the *initial* orbit as reference for the "
        "whole branch; there is no upper parameter bound (the loop stops when U reaches "
        "`p_span[1]` = 14, which this branch never does, or at `max_steps`, so the step "
        "count has to be tuned by hand to end just past U = 18.3); the arclength norm is "
        "unweighted over all collocation unknowns; every Newton step forms the Jacobian "
        "by `jacfwd` of the whole residual and solves densely inside XLA; `Fold()` "
        "refines with the generic extended system (tolerance fixed at 1e-6 by "
        "`continuation()`; an extended system twice the size, its Jacobian by nested AD, "
        "`jax.jacobian` of a `jacfwd`); no period-doubling/torus "
        "detection for orbits yet. "
    )
    if "error" in jx:
        return head + limits + f"\n\nThe attempt failed: `{jx['error']}`.\n"
    M0 = min(rows)
    res = (
        f"Result ({jx['settings']}): {jx['n_points']} points, lowest U "
        f"{jx['p_min_reached']:.6f}, last U {jx['p_last']:.3f}, {jx['n_stable']} stable "
        f"(unstable before the turn and stable after it: {jx['stable_split_ok']}); the task "
        "part (Hopf to U = 18.3 on the way back) "
        + ("was covered" if jx["reached_p_max"] else "was **not** covered")
        + f" in {jx['n_task_points']} points. Times: problem build (seed refinement, "
        f"compile) {jx['t_build']:.1f} s; its whole-loop jitted engine "
        f"(`pseudo_arclength_scan`, called directly with one fixed right-hand side) "
        f"{jx['t_first']:.1f} s on the first call (compile + run) and {jx['t_scan']:.1f} s "
        f"warm, plus {jx['t_floquet']:.1f} s for its Floquet post-pass (un-jitted vmap; "
        f"{jx['t_floquet_first']:.1f} s the first time): **{jx['t_warm']:.1f} s** warm in all, "
        f"{jx['t_warm'] / rows[M0]['warm']:.0f}× bifid at M = {M0} and less accurate. "
        "Through its public `jaxcont.continuation()` every call pays the compile again: "
        "`api._run_scan` wraps the problem in a new `rhs2` lambda on each call and passes "
        "it as a static argument of the jitted engine (`static_argnums=(0, 8, 10)`), so "
        "the jit cache misses every time."
    )
    if "fold_parabola" in jx:
        res += (
            f" Fold estimate from a parabola through its three points around the turn: "
            f"{jx['fold_parabola']:.6f} (error {jx['fold_parabola'] - ref_fold:+.1e})."
        )
    if "folds" in jx:
        res += (
            " `Fold()` refinement: "
            + (
                ", ".join(
                    f"{u:.10f} (converged={c}, error {u - ref_fold:+.1e})" for u, c in jx["folds"]
                )
                or "none"
            )
            + (f"; the whole `continuation(..., events=[Fold()])` call took {jx['t_fold']:.0f} s.")
        )
    else:
        res += " Its `Fold()` refinement is not run by default (minutes; `--jaxcont-fold`)."
    return head + limits + "\n\n" + res + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
