#!/usr/bin/env python
"""Benchmark: the AUTO-07p demo suite through ``bifid continue``, against AUTO's own output.

The demos ``ab``, ``abc``, ``lrz``, ``pp2``, ``pp3``, ``plp`` and ``tor`` are bifid system
files in ``benchmarks/auto_demos/`` (equations and reference values transcribed from
AUTO-07p, with attribution and the commit, in each file). Every AUTO run of equilibria is
run as a user would: ``bifid continue SYSTEM --param P --range A B [--x0 …] [--set …]
--json`` (in-process, through ``bifid.cli.main``), and the JSON is compared with AUTO's
printed special points:

* every Hopf point (HB), fold (LP) and cycle fold that AUTO prints must be located by
  bifid and agree to AUTO's printed precision (6 significant digits; ``Δ`` is the
  difference in units of the last printed digit — AUTO locates its points to a relative
  arclength tolerance ``EPSS = 1e-5``, so its last digit can be off by one or two, which the
  closed forms of ``ab`` and ``lrz`` show);
* bifid must report no located point of a kind AUTO looked for (its ``ILP`` / ``ISP``
  settings) that AUTO does not list, within the part of each branch AUTO computed
  (orbit branches are cut where AUTO stopped: a parameter value, a period, or its step
  budget); branch points are only flagged by bifid (candidates), and AUTO's branch points
  are checked against those candidates;
* the periods of the orbits AUTO prints are compared with bifid's orbit through AUTO's
  point: the nearest orbit of the branch (saved with ``--out``) Newton-corrected at AUTO's
  parameter (``bifid.continuation.truth.correct_orbit``), and at AUTO's period with the
  parameter free; Δ is the smaller of the period mismatch of the one and the parameter
  mismatch of the other (the second decides where the branch is steep in the period,
  near a homoclinic orbit).

Run ``python benchmarks/bench_auto.py`` (or ``make bench``); writes the "auto" section of
BENCHMARKS.md. ``--demos ab lrz`` runs a subset; ``--no-write`` only prints.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "tests"))

from _properties import equilibrium_scan  # noqa: E402
from _report import write_section  # noqa: E402

DEMOS = ("ab", "abc", "lrz", "pp2", "pp3", "plp", "tor")
AUTO_COMMIT = "44cc1c42a888179bdbd608a40613caee9cbc4675"
AGREE_UNITS = 2.0  # |Δ| in units of AUTO's last printed digit that counts as agreement


def log(msg: str) -> None:
    print(f"[bench_auto {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def load_demo(name: str):
    """Import ``auto_demos/<name>.py`` (it registers its system) and return the module."""
    path = HERE / "auto_demos" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"auto_demo_{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def run_cli(args: list[str]) -> tuple[int, dict | None, str, float]:
    """``bifid ARGS`` in-process: exit status, the JSON object, stderr, wall time."""
    from bifid.cli import main

    out, err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main(args)
            code = 0
        except SystemExit as exc:
            code = int(exc.code or 0)
    dt = time.perf_counter() - t0
    text = out.getvalue().strip()
    return code, json.loads(text) if text else None, err.getvalue(), dt


def continue_args(
    run: dict, system: str, orbits: bool = True, out: Path | None = None
) -> list[str]:
    a, b = run["range"]
    args = [
        "continue",
        system,
        "--param",
        run["param"],
        "--range",
        repr(a),
        repr(b),
        "--json",
        "--quiet",
        "--orbits" if orbits else "--no-orbits",
    ]
    for k, v in run["set"].items():
        args += ["--set", f"{k}={v!r}"]
    if run["x0"] is not None:
        args += ["--x0", ",".join(repr(float(v)) for v in run["x0"])]
    if out is not None:
        args += ["--out", str(out), "--force"]
    return args


def attach_orbits(data: dict, path: Path) -> None:
    """Attach to each JSON orbit the orbit itself (``--out``: every orbit sampled over one
    period, in the order of the JSON's ``orbits``) as ``data["orbits"][i]["samples"]``."""
    from bifid.data import lco_records, load_dataset

    if not path.exists():
        return
    recs = lco_records(load_dataset(path))
    orbits = data.get("orbits", [])
    if len(recs) != len(orbits):
        return
    for o, r in zip(orbits, recs, strict=True):
        if abs(r.param - o["param"]) <= 1e-12 * max(1.0, abs(o["param"])):
            o["samples"] = np.asarray(r.signals, dtype=float)


def corrected(system, run: dict, orbit: dict, param: float, period: float) -> dict:
    """bifid's orbit through AUTO's printed point ``(param, period)``, Newton-corrected
    from the nearest orbit of the branch on that orbit's mesh (in a rescaled time, its
    density worked out from the orbit, where the uniform mesh does not resolve it): at
    AUTO's parameter (its period) and at AUTO's period (its parameter, where the branch is
    steep in the period)."""
    out: dict = {}
    if "samples" not in orbit:
        return out
    M = max(64, int(orbit.get("n_mesh") or 64))
    pv = system.param_vector(run["set"])
    S = np.asarray(orbit["samples"], dtype=float)
    at_param = _newton_orbit(system, run["param"], pv, S, orbit["period"], param, M, fix="param")
    if at_param is not None:
        out["period"] = at_param[0]
    at_period = _newton_orbit(system, run["param"], pv, S, period, orbit["param"], M, fix="period")
    if at_period is not None:
        out["param"] = at_period[1]
    return out


def _newton_orbit(system, name, pv, samples, period, value, M, fix, passes=3):
    """``(period, parameter)`` of the orbit corrected from ``samples`` (uniform times) on
    ``M`` collocation points with the parameter (``fix="param"``) or the period fixed;
    the mesh redistributed along the corrected orbit until it is resolved (None when
    Newton fails or the orbit stays unresolved)."""
    import jax.numpy as jnp

    from bifid.continuation import correct, fourier_differentiation_matrix, orbit_problem
    from bifid.continuation._density import convert_values, density_values
    from bifid.continuation._mesh import MeshPolicy
    from bifid.signal import spectral_tail

    n = system.n_states
    idx = system.index(name)
    policy = MeshPolicy(n_mesh=M, max_mesh=M, rescale=True)
    V0 = np.asarray(samples, dtype=float)
    mesh = policy.new_mesh(V0, len(V0), M)
    V = convert_values(V0, len(V0), mesh)
    y = np.concatenate([V.ravel(), [period, value]])
    k = M * n if fix == "period" else M * n + 1
    for _ in range(passes):
        V = y[: M * n].reshape(M, n)
        args = {
            "p": pv,
            "idx": jnp.asarray(idx),
            "dref": jnp.asarray((fourier_differentiation_matrix(M) @ V).ravel()),
            "h": jnp.asarray(density_values(mesh)),
        }
        e = np.zeros_like(y)
        e[k] = 1.0
        y, ok, _, _ = correct(orbit_problem(system.field, M, n), y, e, y[k], args, tol=1e-11)
        if not ok:
            return None
        V = y[: M * n].reshape(M, n)
        if spectral_tail(V) <= 1e-9:
            return float(y[M * n]), float(y[-1])
        new = policy.new_mesh(V, mesh, M)
        y = np.concatenate([convert_values(V, mesh, new).ravel(), y[M * n :]])
        mesh = new
    return None


# ------------------------------------------------------------------------ comparison
def unit(value: float) -> float:
    """One unit of the last digit of ``value`` printed with 6 significant digits."""
    return 10.0 ** (math.floor(math.log10(abs(value))) - 5) if value else 1e-6


def match(reference: list[float], found: list[float]) -> tuple[list, list[float]]:
    """Pair each reference value with the nearest unused found value (within 1e-3
    relative); returns ``[(ref, found or None)]`` and the unmatched found values."""
    left = list(found)
    pairs = []
    for r in reference:
        if left:
            k = int(np.argmin([abs(f - r) for f in left]))
            if abs(left[k] - r) <= 1e-3 * max(1.0, abs(r)):
                pairs.append((r, left.pop(k)))
                continue
        pairs.append((r, None))
    return pairs, left


def point_rows(demo: str, label: str, kind: str, pairs, exact=None) -> list[dict]:
    """One row per AUTO point; agreement to AUTO's printed digits, or — where AUTO's last
    digit is off — to 1e-9 of an independent value that AUTO misses by more."""
    rows = []
    for ref, got in pairs:
        d = None if got is None else (got - ref) / unit(ref)
        ind = None if exact is None else exact(ref)
        ok = d is not None and abs(d) <= AGREE_UNITS
        if not ok and d is not None and ind is not None:
            ok = abs(got - ind) <= 1e-9 * max(1.0, abs(ind)) and abs(ref - ind) > abs(got - ind)
        rows.append(
            {
                "demo": demo,
                "run": label,
                "kind": kind,
                "auto": ref,
                "bifid": got,
                "delta": d,
                "exact": ind,
                "ok": ok,
            }
        )
    return rows


def branch_orbits(data: dict, branch: int) -> list[dict]:
    return [o for o in data.get("orbits", []) if o.get("branch") == branch]


def coverage(orbits: list[dict], stop: dict) -> int:
    """Number of leading orbits of a branch inside the part AUTO computed."""
    params = [o["param"] for o in orbits]
    periods = [o.get("period") or 0.0 for o in orbits]
    for i in range(1, len(orbits)):
        for v in stop.get("param", ()):
            if (params[i - 1] - v) * (params[i] - v) < 0 or (i > 1 and params[i] == v):
                return i + 1
        if periods[i] >= stop.get("period", math.inf):
            return i + 1
        if periods[i] > stop.get("max_period", math.inf):
            return i
    return len(orbits)


def along(orbits: list[dict], param: float, period: float) -> int:
    """Index of the orbit of a branch nearest ``(param, period)`` (relative distances)."""
    d = [
        abs(o["param"] - param) / max(1e-12, abs(param))
        + abs((o.get("period") or 0) - period) / max(1e-12, period)
        for o in orbits
    ]
    return int(np.argmin(d))


def _quadratic(xs: list[float], ys: list[float], x: float) -> float:
    """Lagrange interpolation through three points (two when they are all there is)."""
    if len(xs) == 2:
        return ys[0] + (x - xs[0]) * (ys[1] - ys[0]) / (xs[1] - xs[0])
    (x0, x1, x2), (y0, y1, y2) = xs, ys
    return (
        y0 * (x - x1) * (x - x2) / ((x0 - x1) * (x0 - x2))
        + y1 * (x - x0) * (x - x2) / ((x1 - x0) * (x1 - x2))
        + y2 * (x - x0) * (x - x1) / ((x2 - x0) * (x2 - x1))
    )


def _along(xs: list[float], ys: list[float], x: float) -> list[float]:
    """``y(x)`` on every segment of the polyline that brackets ``x``, by quadratic
    interpolation through the segment and its nearer neighbour where ``x`` is monotone."""
    out = []
    for k in range(len(xs) - 1):
        if xs[k] == xs[k + 1] or not min(xs[k], xs[k + 1]) <= x <= max(xs[k], xs[k + 1]):
            continue
        idx = [k, k + 1]
        for j in (k - 1, k + 2):
            if 0 <= j < len(xs):
                tri = sorted([*idx, j])
                dx = np.diff([xs[i] for i in tri])
                if np.all(dx > 0) or np.all(dx < 0):
                    idx = tri
                    break
        out.append(_quadratic([xs[i] for i in idx], [ys[i] for i in idx], x))
    return out


def curve_delta(orbits: list[dict], param: float, period: float) -> float | None:
    """Distance of AUTO's orbit ``(param, period)`` from bifid's branch, in units of the
    last printed digit: the smaller of the period mismatch at ``param`` and the parameter
    mismatch at ``period`` (quadratic interpolation along the branch); None where the
    branch does not reach AUTO's period."""
    ps = [o["param"] for o in orbits if o.get("period") is not None]
    ts = [o["period"] for o in orbits if o.get("period") is not None]
    if len(ps) < 2 or not min(ts) <= period <= max(ts):
        return None
    cands = [abs(t - period) / unit(period) for t in _along(ps, ts, param)]
    cands += [abs(p - param) / unit(param) for p in _along(ts, ps, period)]
    return min(cands) if cands else None


def orbit_delta(system, run: dict, inside: list[dict], param: float, period: float) -> tuple:
    """Distance of AUTO's orbit ``(param, period)`` from bifid's branch in units of the
    last printed digit, and bifid's period there: from the orbits Newton-corrected
    through AUTO's point (:func:`corrected`), the smaller of the period mismatch at
    ``param`` and the parameter mismatch at ``period``; where neither converges, the
    branch interpolated (:func:`curve_delta`, marked). None: the branch does not reach it."""
    # AUTO prints its period rounded: a point at the end of the branch may lie up to one
    # unit of its last digit outside the branch's periods
    slack = unit(period)
    if (
        len(inside) < 2
        or not min(o["period"] for o in inside) - slack
        <= period
        <= max(o["period"] for o in inside) + slack
    ):
        return None, None, ""
    ps = [o["param"] for o in inside]
    if not min(ps) - 1e-9 * max(1.0, abs(param)) <= param <= max(ps) + 1e-9 * max(1.0, abs(param)):
        return None, None, ""  # the branch does not reach AUTO's parameter
    got = corrected(system, run, inside[along(inside, param, period)], param, period)
    cands = []
    if "period" in got:
        cands.append((abs(got["period"] - period) / unit(period), got["period"]))
    if "param" in got:
        cands.append((abs(got["param"] - param) / unit(param), None))
    if cands:
        d, value = min(cands, key=lambda c: c[0])
        return d, value if value is not None else got.get("period"), ""
    return curve_delta(inside, param, period), None, " (interpolated)"


def missed_folds(label: str, orb: dict, pairs: list, every: list[dict]) -> list[str]:
    """Notes on AUTO's cycle LPs that bifid's branch does not have up to AUTO's last
    period: bifid's cycle fold nearest in the parameter anywhere on the branch, with both
    periods (AUTO's period at a fold near a homoclinic orbit can be off by its mesh)."""
    out = []
    periods = dict(orb["cycle_folds"])
    for ref, got in pairs:
        if got is not None or not every:
            continue
        c = min(every, key=lambda c: abs(c["param"] - ref))
        out.append(
            f"{label}: AUTO's cycle LP at {ref:g} (period {periods.get(ref)!s}) is not on "
            f"bifid's branch up to AUTO's last period; bifid's nearest cycle fold is at "
            f"{c['param']:.9g} (Δ {(c['param'] - ref) / unit(ref):+.1f}), period "
            f"{c.get('period', float('nan')):.6g}"
        )
    return out


def compare_orbits(
    demo: str, run: dict, data: dict, hopf_branch: dict[float, int], system=None
) -> tuple:
    """Rows for the orbit runs of one equilibrium run, and the extra points found."""
    rows, extra, notes = [], [], []
    for orb in run["orbits"]:
        label = f"{run['label']}, orbits from HB {orb['hopf']:g}"
        hb = min(hopf_branch, key=lambda h: abs(h - orb["hopf"])) if hopf_branch else None
        if hb is None or abs(hb - orb["hopf"]) > 1e-3 * max(1.0, abs(orb["hopf"])):
            rows += point_rows(demo, label, "cycle LP", [(p, None) for p, _ in orb["cycle_folds"]])
            notes.append(f"{label}: no orbit branch")
            continue
        b = hopf_branch[hb]
        orbits = branch_orbits(data, b)
        n = coverage(orbits, orb["stop"])
        inside = orbits[:n]
        every = [c for c in data.get("cycle_folds", []) if c.get("branch") == b]
        cfs = [c for c in every if along(orbits, c["param"], c.get("period") or 0) < n]
        pairs, left = match([p for p, _ in orb["cycle_folds"]], [c["param"] for c in cfs])
        rows += point_rows(demo, label, "cycle LP", pairs)
        notes += missed_folds(label, orb, pairs, every)
        notes += [
            f"{label}: AUTO's {kind} at {v:g} (period {t:g}) is on another branch: {why}"
            for kind, v, t, why in orb.get("other_branch", ())
        ]
        extra += [(label, "cycle LP", v) for v in left if "cycle_fold" in orb["detect"]]
        for s in data.get("secondary", []):
            if s.get("branch") != b or along(orbits, s["param"], 0.0) >= n:
                continue
            if s["kind"] == "branch_point" and any(
                abs(s["param"] - v) < 1e-3 for v in orb["branch_points"]
            ):
                continue
            if s["kind"] in orb["detect"]:
                extra.append((label, s["kind"], s["param"]))
        end = next((e for e in data["ends"] if e["branch"] == b), {})
        top = max((o.get("period") or 0.0) for o in orbits)
        for p, t in orb["points"]:
            d, value, how = orbit_delta(system, run, inside, p, t)
            beyond = d is None and end.get("reason") == "homoclinic" and t > top
            rows.append(
                {
                    "demo": demo,
                    "run": label,
                    "kind": "orbit period",
                    "auto": t,
                    "bifid": value,
                    "delta": d,
                    "exact": None,
                    "at": p,
                    "how": how,
                    "ok": None if beyond else d is not None and d <= AGREE_UNITS,
                }
            )
        if orb["homoclinic"] is not None:
            notes.append(
                f"{label}: AUTO stops at period {orb['homoclinic'][1]:g} at "
                f"{orb['homoclinic'][0]:g}; bifid ends '{end.get('reason')}' at "
                f"{end.get('param')!s} (largest period "
                f"{max((o.get('period') or 0) for o in orbits):.4g})"
            )
        bps = [
            c
            for c in data.get("candidates", [])
            if c.get("branch") == b and c["kind"] == "branch_point"
        ]
        for v in orb["branch_points"]:
            hit = any(min(c["bracket"]) - 1e-3 <= v <= max(c["bracket"]) + 1e-3 for c in bps)
            hit = hit or any(
                s.get("branch") == b and s["kind"] == "branch_point" and abs(s["param"] - v) < 1e-3
                for s in data.get("secondary", [])
            )
            rows.append(
                {
                    "demo": demo,
                    "run": label,
                    "kind": "cycle BP",
                    "auto": v,
                    "bifid": v if hit else None,
                    "delta": None,
                    "exact": None,
                    "ok": hit,
                }
            )
    return rows, extra, notes


def compare_equilibria(demo: str, run: dict, data: dict, exact) -> tuple[list, list]:
    rows, extra = [], []
    hopf = [h["param"] for h in data["hopf"] if h.get("branch") == 0]
    folds = [f["param"] for f in data["folds"] if f.get("branch") == 0]
    for kind, key, ref, found in (
        ("HB", "hopf", run["hopf"], hopf),
        ("LP", "fold", run["folds"], folds),
    ):
        pairs, left = match(list(ref), found)
        rows += point_rows(demo, run["label"], kind, pairs, exact.get(kind))
        if key in run["detect"]:
            extra += [(run["label"], kind, v) for v in left]
    cands = [
        c
        for c in data.get("candidates", [])
        if c.get("branch") == 0 and c["kind"] == "branch_point"
    ]
    for v in run["branch_points"]:
        hit = any(min(c["bracket"]) - 1e-6 <= v <= max(c["bracket"]) + 1e-6 for c in cands)
        rows.append(
            {
                "demo": demo,
                "run": run["label"],
                "kind": "BP (candidate)",
                "auto": v,
                "bifid": v if hit else None,
                "delta": None,
                "exact": None,
                "ok": hit,
            }
        )
    return rows, extra


def _nearest(values, rel: float = 1e-4):
    def pick(ref):
        near = [v for v in values if abs(v - ref) <= rel * max(1.0, abs(ref))]
        return min(near, key=lambda v: abs(v - ref)) if near else None

    return pick


def independent(demo: str, run: dict) -> dict:
    """Independent values of the special points, to show whose last digit is off: closed
    forms (``ab``, ``lrz``), else the Hopf points of the dense eigenvalue scan of the test
    suite (``tests/_properties.py``) along the part of the branch without folds."""
    if demo == "lrz":
        s, b = 10.0, 8.0 / 3.0
        return {"HB": lambda ref: s * (s + b + 3) / (s - b - 1)}
    if demo != "ab":
        from bifid.systems import get_system

        system = get_system(demo)
        x0 = None if run["x0"] is None else np.array(run["x0"], dtype=float)
        scan = equilibrium_scan(
            system, run["param"], *run["range"], system.param_vector(run["set"]), x0, n_grid=4001
        )
        return {"HB": _nearest([h for h, _ in scan.hopf])}
    B, beta = run["set"]["B"], 3.0

    def da(u1):
        return u1 * math.exp(-B * u1 / (1 + beta)) / (1 - u1)

    # Hopf: trace 0 -> B u1 - (1 + beta) - 1/(1 - u1) = 0; fold: d Da / d u1 = 0
    hb = np.roots([-B, B + 1 + beta, -(2 + beta)]).real
    lp = np.roots([B / (1 + beta), -B / (1 + beta), 1.0])
    lp = lp[np.isreal(lp)].real

    return {
        "HB": _nearest([da(u) for u in hb if 0 < u < 1]),
        "LP": _nearest([da(u) for u in lp if 0 < u < 1]),
    }


def run_demo(name: str, orbits: bool = True) -> dict:
    from bifid.systems import get_system

    module = load_demo(name)
    system = get_system(name)
    rows, extra, notes, timing = [], [], [], []
    for run in module.AUTO_RUNS:
        if not orbits:
            run = {**run, "orbits": []}
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "orbits.nc"
            code, data, err, dt = run_cli(
                continue_args(run, name, orbits, path if run["orbits"] else None)
            )
            if data is not None and run["orbits"]:
                attach_orbits(data, path)
        timing.append(dt)
        log(f"{name} {run['label']}: exit {code} in {dt:.1f} s")
        if data is None or "hopf" not in data:  # no diagram (an error, or interrupted)
            notes.append(
                f"{run['label']}: no diagram (exit {code}): "
                f"{(data or {}).get('message') or err.strip()[-300:]}"
            )
            continue
        if not data.get("complete", False):
            notes.append(
                f"{run['label']}: incomplete ({data.get('status')}): "
                f"{data.get('message', '')[:200]}"
            )
        r, e = compare_equilibria(name, run, data, independent(name, run))
        rows += r
        extra += e
        hopf_branch = {}
        for o in data.get("orbits", []):
            hopf_branch.setdefault(o["branch"], o["param"])
        r, e, n = compare_orbits(name, run, data, {v: k for k, v in hopf_branch.items()}, system)
        rows, extra, notes = rows + r, extra + e, notes + n
        n_cand = sum(1 for c in data.get("candidates", []) if c["kind"] != "branch_point")
        if n_cand:
            notes.append(
                f"{run['label']}: {n_cand} non-branch-point candidate(s): "
                + "; ".join(
                    f"{c['kind']} {c['bracket']}: {c['reason'][:90]}"
                    for c in data["candidates"]
                    if c["kind"] != "branch_point"
                )
            )
    return {
        "name": name,
        "rows": rows,
        "extra": extra,
        "notes": notes,
        "time": sum(timing),
        "runs": len(module.AUTO_RUNS),
    }


# ----------------------------------------------------------------------------- report
def fmt(v, digits: int = 9) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.{digits}g}"
    return str(v)


def render(results: list[dict], orbits: bool = True, demos: list[str] | None = None) -> str:
    lines = [
        "## AUTO-07p demo suite (`bench_auto.py`)",
        "",
        "Every equilibrium run of the AUTO-07p demos below, through `bifid continue … --json`,",
        "against the special points AUTO-07p prints in its regression log (`test/hyper.all`,",
        f"AUTO-07p commit `{AUTO_COMMIT[:12]}`; systems and numbers transcribed in",
        "`benchmarks/auto_demos/`). Δ: bifid − AUTO in units of AUTO's last printed digit",
        f"(agreement: |Δ| ≤ {AGREE_UNITS:g}, or bifid within 1e-9 of the independent value",
        "where AUTO's last digit is off); independent: a closed form (`ab`, `lrz`) or the",
        "dense eigenvalue scan of the property test; extra: located points of a kind AUTO",
        "looked for that AUTO does not list, within the part of the branch AUTO computed.",
        "Orbit periods: bifid's orbit Newton-corrected through AUTO's point from the nearest",
        "orbit of the branch, at AUTO's parameter (bifid's period shown) and at AUTO's period",
        "(parameter free); Δ the smaller mismatch, in units of AUTO's last digit.",
        "" if orbits else "\nEquilibria only (`--no-orbits`): the orbit runs were not made.\n",
        "| demo | runs | AUTO points | agree | disagree / missing | beyond a homoclinic end "
        "| extra | wall [s] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        n = len(r["rows"])
        ok = sum(1 for x in r["rows"] if x["ok"])
        beyond = sum(1 for x in r["rows"] if x["ok"] is None)
        lines.append(
            f"| {r['name']} | {r['runs']} | {n} | {ok} | {n - ok - beyond} | {beyond} "
            f"| {len(r['extra'])} | {r['time']:.0f} |"
        )
    lines += [
        "",
        "| demo | run | kind | AUTO | bifid | Δ | independent |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        for x in r["rows"]:
            at = f" at {x['at']:g}" if "at" in x else ""
            delta = "—" if x["delta"] is None else f"{x['delta']:+.2f}"
            mark = x.get("how", "") + (
                "" if x["ok"] else " (beyond bifid's homoclinic end)" if x["ok"] is None else " ✗"
            )
            lines.append(
                f"| {x['demo']} | {x['run']} | {x['kind']}{at} | {fmt(x['auto'])} | "
                f"{fmt(x['bifid'])} | {delta}{mark} | {fmt(x['exact'])} |"
            )
    extra = [(r["name"], *e) for r in results for e in r["extra"]]
    lines += ["", f"Extra located points (not in AUTO's output): {len(extra)}"]
    lines += [f"- {d} {lab}: {k} at {v:.9g}" for d, lab, k, v in extra]
    notes = [(r["name"], n) for r in results for n in r["notes"]]
    if notes:
        lines += ["", "Notes:"] + [f"- {d}: {n}" for d, n in notes]
    total = sum(r["time"] for r in results)
    demos = list(demos or [r["name"] for r in results])
    subset = "" if tuple(demos) == DEMOS else " --demos " + " ".join(demos)
    flag = "" if orbits else " --no-orbits"
    lines += [
        "",
        f"Command: `python benchmarks/bench_auto.py{subset}{flag}` (one run; wall time of "
        f"the `bifid continue` runs {total:.0f} s, on 2 cores shared with other jobs).",
    ]
    if len(results) < len(demos):
        lines.append(
            f"The run was interrupted after {len(results)} of its {len(demos)} demos "
            f"({', '.join(r['name'] for r in results)})."
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--demos", nargs="*", default=list(DEMOS), choices=DEMOS)
    ap.add_argument("--no-orbits", action="store_true", help="equilibria only")
    ap.add_argument("--no-write", action="store_true", help="print, do not write BENCHMARKS.md")
    a = ap.parse_args(argv)
    import bifid  # noqa: F401  (float64)

    results = []
    for name in a.demos:
        results.append(run_demo(name, not a.no_orbits))
        md = render(results, not a.no_orbits, a.demos)
        if not a.no_write:  # after every demo: an interrupted run leaves what it did
            write_section("auto", md)
            log(f"wrote the 'auto' section of BENCHMARKS.md ({len(results)} demos)")
    print(md)
    bad = sum(1 for r in results for x in r["rows"] if x["ok"] is False) + sum(
        len(r["extra"]) for r in results
    )
    return 0 if bad == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
