"""Equilibria in one parameter: continuation, stability, Hopf points, folds, branch points.

The branch ``f(x, lambda) = 0`` is followed by pseudo-arclength continuation
(``_palc``). Special points are found by test functions between consecutive points and
reported only once located and verified (``_verify``):

* **Hopf** — the eigenvalues of ``J = f_x`` at the two points are matched (assignment on
  their distances, so each eigenvalue is followed continuously) and an eigenvalue whose
  real part changes sign while it is *complex at both ends* marks a Hopf crossing. A
  complex pair that collides on the real axis (complex-to-real) and a neutral saddle
  (``±mu`` real) change no real part's sign, so they are never candidates. Where the
  matching is ambiguous (a crossing next to a collision, or a count of unstable
  eigenvalues that the matching does not explain) the interval is bisected on the branch
  (up to ``MAX_BISECTIONS`` times). The crossing is then located by Newton on the Hopf
  defining system and verified (``_hopf``).
* **Fold** — the parameter component of the tangent changes sign (driver), located by a
  secant search and verified (``_folds``).
* **Branch point** — ``det [G_y; t^T]`` changes sign (driver); flagged as a candidate
  (branch points are not located).
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import linear_sum_assignment

from bifid.continuation._branch import Branch, SpecialPoint
from bifid.continuation._folds import report_folds
from bifid.continuation._hopf import add_lyapunov, with_param
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._palc import ZeroProblem, correct, palc
from bifid.continuation._verify import Findings
from bifid.errors import BifidInputError, ConvergenceError
from bifid.systems import System

Array = jnp.ndarray

#: bisections of a branch interval whose eigenvalue crossings are ambiguous
MAX_BISECTIONS = 8
#: an eigenvalue is complex when |Im| exceeds this fraction of the spectral scale
COMPLEX_TOL = 1e-10


@functools.lru_cache(maxsize=32)
def equilibrium_problem(field: Callable) -> ZeroProblem:
    """Zero problem ``f(x, p[idx] = lambda) = 0`` with ``y = [x, lambda]``."""

    def residual(y, args):
        return field(y[:-1], with_param(args["p"], args["idx"], y[-1]))

    return ZeroProblem(residual=residual, param_index=-1)


@functools.lru_cache(maxsize=32)
def _batched_jacobian(field: Callable) -> Callable:
    return jax.jit(jax.vmap(jax.jacfwd(field), in_axes=(0, 0)))


@functools.lru_cache(maxsize=32)
def _batched_residual(problem: ZeroProblem) -> Callable:
    return jax.jit(jax.vmap(problem.residual, in_axes=(0, None)))


def check_x0(system: System, x0: np.ndarray | None) -> np.ndarray:
    """A starting state: ``n_states`` finite numbers; when None, the system's own guess
    (:attr:`System.x0 <bifid.systems.System>`, e.g. ``x0 = [...]`` in a ``.toml`` file),
    else zeros.

    Raises
    ------
    BifidInputError
        On a wrong length or a value that is not finite.
    """
    if x0 is None:
        return np.zeros(system.n_states) if system.x0 is None else np.array(system.x0)
    try:
        x = np.asarray(x0, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise BifidInputError(f"x0 must be numbers, got {x0!r}.") from None
    if x.shape[0] != system.n_states:
        raise BifidInputError(
            f"x0 must have {system.n_states} values (one per state: "
            f"{', '.join(system.states)}); got {x.shape[0]}."
        )
    if not np.all(np.isfinite(x)):
        raise BifidInputError(f"x0 must be finite numbers, got {x.tolist()}.")
    return x


def _check_field(system: System, x: np.ndarray, p: Array) -> None:
    """The field evaluates at the start to ``n_states`` numbers (a user's field that
    raises or returns the wrong shape is an input error, not a traceback)."""
    try:
        f = np.asarray(system.field(jnp.asarray(x), p))
    except Exception as exc:  # any error of a user's function
        raise BifidInputError(
            f"the field of {system.name!r} fails at x0={x.tolist()}: "
            f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        ) from None
    if f.shape != (system.n_states,):
        raise BifidInputError(
            f"the field of {system.name!r} must return {system.n_states} values (one per "
            f"state), got shape {f.shape}."
        )
    if not (np.all(np.isfinite(np.asarray(p))) and np.all(np.isfinite(f))):
        raise BifidInputError(
            f"the field of {system.name!r} is not finite at the start (x0={x.tolist()}, "
            f"parameters {np.asarray(p).tolist()}): give finite parameters and a starting "
            "guess where the field is defined."
        )


def _eigenvalues(field: Callable, ys: np.ndarray, p: Array, idx: int) -> np.ndarray:
    ps = np.repeat(np.asarray(p)[None, :], ys.shape[0], axis=0)
    ps[:, idx] = ys[:, -1]
    J = np.asarray(_batched_jacobian(field)(jnp.asarray(ys[:, :-1]), jnp.asarray(ps)))
    if not np.all(np.isfinite(J)):
        k = int(np.argmax(~np.all(np.isfinite(J), axis=(1, 2))))
        raise ConvergenceError(f"the Jacobian is not finite at parameter {ys[k, -1]:.6g}")
    return np.linalg.eigvals(J)


def _classify(ea: np.ndarray, eb: np.ndarray) -> list[tuple[str, complex, complex]] | None:
    """Eigenvalues that cross the imaginary axis between two points.

    Returns ``("hopf", a, b)`` once per complex pair (its member with ``Im > 0``),
    ``("real", a, b)`` for a real eigenvalue, ``("mixed", a, b)`` for one complex at one
    end and real at the other; None when the matching does not explain the change in the
    number of eigenvalues with positive real part.
    """
    scale = max(1.0, float(np.max(np.abs(ea))), float(np.max(np.abs(eb))))
    rows, cols = linear_sum_assignment(np.abs(ea[:, None] - eb[None, :]))
    out: list[tuple[str, complex, complex]] = []
    signed = 0
    for i, j in zip(rows, cols, strict=True):
        a, b = complex(ea[i]), complex(eb[j])
        if (a.real > 0) == (b.real > 0):
            continue
        signed += 1 if b.real > 0 else -1
        ca, cb = abs(a.imag) > COMPLEX_TOL * scale, abs(b.imag) > COMPLEX_TOL * scale
        if ca and cb:
            if a.imag > 0:
                out.append(("hopf", a, b))
        else:
            out.append(("real" if not (ca or cb) else "mixed", a, b))
    if signed != int(np.sum(eb.real > 0)) - int(np.sum(ea.real > 0)):
        return None
    return out


def _hopf_crossings(ya, yb, ea, eb, between, depth=0) -> list[tuple]:
    """``(ya, yb, a, b, clear)`` for every Hopf crossing (``clear``) or ambiguous crossing
    between two branch points, bisecting the interval where the matching is ambiguous."""
    found = _classify(ea, eb)
    if found is not None and all(kind != "mixed" for kind, _, _ in found):
        return [(ya, yb, a, b, True) for kind, a, b in found if kind == "hopf"]
    ym = between(ya, yb) if depth < MAX_BISECTIONS else None
    if ym is None:
        mixed = [(a, b) for kind, a, b in (found or []) if kind != "real"]
        if found is None:  # take the complex eigenvalue nearest the axis at either end
            k = int(np.argmin(np.where(np.abs(ea.imag) > 0, np.abs(ea.real), np.inf)))
            mixed = [(complex(ea[k]), complex(eb[int(np.argmin(np.abs(eb - ea[k])))]))]
        return [(ya, yb, a, b, False) for a, b in mixed if max(abs(a.imag), abs(b.imag)) > 0]
    em = between.eigenvalues(ym)
    return _hopf_crossings(ya, ym, ea, em, between, depth + 1) + _hopf_crossings(
        ym, yb, em, eb, between, depth + 1
    )


class _Between:
    """Corrected branch points between two points: ``y(s)`` on the hyperplane through
    ``ya + s (yb - ya)`` normal to ``yb - ya``."""

    def __init__(
        self, system: System, problem: ZeroProblem, args: dict, idx: int, tol: float
    ) -> None:
        self.system, self.problem, self.args, self.idx, self.tol = system, problem, args, idx, tol

    def at(self, ya: np.ndarray, yb: np.ndarray, s: float) -> np.ndarray | None:
        row = yb - ya
        y_pred = ya + s * row
        y, ok, _, _ = correct(
            self.problem, y_pred, row, float(row @ y_pred), self.args, tol=self.tol
        )
        return y if ok else None

    def __call__(self, ya: np.ndarray, yb: np.ndarray) -> np.ndarray | None:
        return self.at(ya, yb, 0.5)

    def eigenvalues(self, y: np.ndarray) -> np.ndarray:
        return _eigenvalues(self.system.field, y[None, :], self.args["p"], self.idx)[0]


def _locate_crossing(between: _Between, param: str, ya, yb, a: complex, b: complex) -> SpecialPoint:
    """The zero of the crossing eigenvalue's real part on the branch between ``ya`` and
    ``yb``: an Illinois (secant) search on ``s`` in ``y(s)``, following the eigenvalue to
    its nearest neighbour at each new point. Only first derivatives of the field are
    needed, and the point cannot leave the branch."""
    sa, fa, sb, fb, lam = 0.0, a.real, 1.0, b.real, a
    y_best, best = ya, a
    scale = max(1.0, abs(a), abs(b))
    for _ in range(80):
        s = (sa * fb - sb * fa) / (fb - fa) if fb != fa else 0.5 * (sa + sb)
        y = between.at(ya, yb, s)
        if y is None:
            raise ConvergenceError(
                f"the branch could not be corrected near {param}="
                f"{float((ya + s * (yb - ya))[-1]):.8g}"
            )
        e = between.eigenvalues(y)
        lam = complex(e[int(np.argmin(np.abs(e - lam)))])
        y_best, best = y, lam
        if (lam.real > 0) == (fb > 0):
            sb, fb = s, lam.real
            fa = fa / 2.0  # Illinois: keep the bracket shrinking from both sides
        else:
            sa, fa = s, lam.real
            fb = fb / 2.0
        if abs(lam.real) <= 1e-15 * scale or abs(sb - sa) <= 1e-15:
            break
    J = np.asarray(
        _batched_jacobian(between.system.field)(
            jnp.asarray(y_best[None, :-1]),
            jnp.asarray(between.args["p"]).at[between.idx].set(y_best[-1])[None, :],
        )
    )[0]
    w, V = np.linalg.eig(J)
    k = int(np.argmin(np.abs(w - best)))
    q, om = V[:, k], float(w[k].imag)
    if om < 0:
        q, om = np.conj(q), -om
    p_h = np.asarray(between.args["p"], dtype=float).copy()
    p_h[between.idx] = y_best[-1]
    lo, hi = between.at(ya, yb, sa), between.at(ya, yb, sb)
    prec = abs(float(hi[-1] - lo[-1])) if lo is not None and hi is not None else abs(sb - sa)
    # a search that hit the zero exactly leaves a wide bracket: the error is then the
    # residual real part over its rate of change along the branch
    slope = abs((b.real - a.real) / (float(yb[-1]) - float(ya[-1]))) if yb[-1] != ya[-1] else 0.0
    if slope > 0:
        prec = min(prec, 2.0 * abs(best.real) / slope)
    return SpecialPoint(
        kind="hopf",
        param=float(y_best[-1]),
        index=-1,
        bracket=(float(ya[-1]), float(yb[-1])),
        solution=np.asarray(y_best[:-1]),
        precision=prec + 1e-15 * max(1.0, abs(y_best[-1])),
        data={
            "omega": om,
            "frequency_hz": om / (2 * np.pi),
            "eigenvector": q,
            "p": p_h,
            "param_name": param,
        },
    )


def _find_hopf(findings, system, param, ys, eigs, between) -> None:
    context = {"field": system.field}
    for i in range(len(ys) - 1):
        for ya, yb, a, b, clear in _hopf_crossings(ys[i], ys[i + 1], eigs[i], eigs[i + 1], between):
            result = findings.confirm(
                "hopf",
                (float(ys[i][-1]), float(ys[i + 1][-1])),
                lambda ya=ya, yb=yb, a=a, b=b: _locate_crossing(between, param, ya, yb, a, b),
                context=context,
                index=i,
                slack=float(np.max(np.abs(ys[i + 1] - ys[i]))),
            )
            if isinstance(result, SpecialPoint):
                add_lyapunov(system.field, result)
            elif not clear:
                result.reason = (
                    "an eigenvalue crossed the imaginary axis next to a collision "
                    f"of eigenvalues; {result.reason}"
                )


def equilibria(
    system: System,
    param: str,
    *,
    p: Array | None = None,
    x0: np.ndarray | None = None,
    start: float | None = None,
    options: ContinuationOptions | None = None,
    progress: Callable[[int, float], None] | None = None,
) -> Branch:
    """Continue equilibria of an autonomous system in ``param``.

    Parameters
    ----------
    system : System
    param : str
        Continuation parameter.
    p : array, optional
        Parameter vector (defaults); ``param`` starts at ``start`` or ``p[param]``.
    x0 : array of shape (n,), optional
        Guess of the starting equilibrium (default: the system's ``x0`` when it has one,
        else zeros).
    start : float, optional
        Starting parameter value.
    options : ContinuationOptions
        Bounds ``p_min``/``p_max`` and ``direction`` set the range. The arclength steps
        ``ds`` are measured with the states relative to the size of the starting
        equilibrium (``max(1, max|x|)``), so they are in the parameter's units wherever the
        states change little.

    Returns
    -------
    Branch
        ``kind="equilibrium"``; ``data["eigenvalues"]`` (n_points, n); verified special
        points "hopf" (with ``omega``, ``lyapunov``, ``criticality``) and "fold";
        ``candidates`` for what was detected but not verified (branch points among them).

    Raises
    ------
    BifidInputError
        For a forced system, an unknown parameter or a bad ``x0``.
    ConvergenceError
        If no equilibrium can be found at the start.
    """
    if system.kind != "autonomous":
        raise BifidInputError(
            f"{system.name!r} is a forced system: it has periodic responses, not equilibria; "
            "use frc/scurve."
        )
    options = options or ContinuationOptions()
    idx = system.index(param)
    p = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    lam0 = float(p[idx]) if start is None else float(start)
    x0 = check_x0(system, x0)
    _check_field(system, x0, p.at[idx].set(lam0))
    problem = equilibrium_problem(system.field)
    args = {"p": p, "idx": jnp.asarray(idx)}
    y0 = np.concatenate([x0, [lam0]])
    e = np.zeros_like(y0)
    e[-1] = 1.0
    y_c, ok, _, res = correct(problem, y0, e, lam0, args, tol=options.newton_tol, max_iter=30)
    if not ok:
        raise ConvergenceError(
            f"No equilibrium of {system.name!r} found near the start {param}={lam0:.6g} from "
            f"x0={x0.tolist()} (Newton residual {res:.1e}); pass a better starting guess x0."
        )
    t0 = np.zeros_like(y0)
    t0[-1] = float(options.direction)
    # arclength: the states relative to the size of the starting equilibrium (at least 1)
    scale = max(1.0, float(np.max(np.abs(y_c[:-1]))))
    weights = np.concatenate([np.full(system.n_states, scale**-2), [1.0]])
    result = palc(
        problem,
        y_c,
        t0,
        args,
        options,
        progress=progress,
        correct_start=False,
        param_name=param,
        weights=weights,
    )
    ys = result.ys
    eigs = _eigenvalues(system.field, ys, p, idx)
    params = ys[:, -1]
    findings = _special_points(system, param, problem, args, idx, options, result, eigs)
    residual = np.max(np.abs(np.asarray(_batched_residual(problem)(jnp.asarray(ys), args))), axis=1)
    return Branch(
        kind="equilibrium",
        system=system.name,
        param=param,
        params=params,
        solutions=ys[:, :-1],
        stable=np.all(eigs.real < 0, axis=1),
        special_points=findings.sorted_points(),
        data={"eigenvalues": eigs, "state": ys[:, :-1]},
        p=np.asarray(p),
        status=result.status,
        message=result.message,
        options=options,
        signals=tuple(system.states),
        meta={"states": list(system.states)},
        verification={"residual": residual},
        candidates=findings.candidates,
    )


def _special_points(system, param, problem, args, idx, options, result, eigs) -> Findings:
    """The verified Hopf points and folds of an equilibrium branch, and its candidates
    (branch points are flagged, not located)."""
    ys = result.ys
    params = ys[:, -1]
    findings = Findings()
    if options.detect_bifurcations:
        _find_hopf(
            findings,
            system,
            param,
            ys,
            eigs,
            _Between(system, problem, args, idx, options.newton_tol),
        )
    if options.detect_folds:
        report_folds(
            findings,
            result,
            params,
            lambda i, y_f, prec: SpecialPoint(
                kind="fold",
                param=float(y_f[-1]),
                index=i,
                bracket=(params[i], params[i + 1]),
                solution=y_f[:-1],
                precision=prec,
            ),
            {"problem": problem, "args": args},
        )
    for i in result.branch_points:
        findings.flag(
            "branch_point",
            (params[i], params[i + 1]),
            "det [G_y; t^T] changed sign: a branch point (branch points are flagged, not located)",
        )
    return findings
