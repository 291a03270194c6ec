"""Folds (limit points) of a continued branch, verified before they are reported.

The driver detects a fold where the parameter component of the tangent changes sign and
locates it by a secant search on that component (``_palc``). A located point ``y`` of a
zero problem ``G(y) = 0`` (``y = [u, lambda]``) is verified as a fold when

* it is on the curve: ``max|G(y)| <= FOLD_RESIDUAL_TOL * (1 + max|y|)``;
* the parameter component of the unit tangent (null vector of ``G_y``, in the weighted
  norm of the branch) vanishes: ``|t_lambda| <= FOLD_TANGENT_TOL``;
* ``G_u`` has a null vector: ``sigma_min(G_u) <= FOLD_NULL_TOL * max(1, sigma_max(G_u))``;
* it is not a branch point: ``G_y`` keeps full rank,
  ``sigma_min(G_y) >= FOLD_RANK_MIN * sigma_max(G_y)``.

The criteria hold for any zero problem — equilibria, forced responses (FRC and S-curve
folds) and periodic orbits (folds of cycles) — so :func:`verify_fold` serves them all.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import scipy.linalg

from bifid.continuation._branch import SpecialPoint
from bifid.continuation._correctors import NewtonCorrector
from bifid.continuation._palc import PalcResult
from bifid.continuation._verify import Check, Findings, Verdict, register_verifier

FOLD_RESIDUAL_TOL = 1e-8
FOLD_TANGENT_TOL = 1e-6
FOLD_NULL_TOL = 1e-6
FOLD_RANK_MIN = 1e-10


@register_verifier("fold")
def verify_fold(point: SpecialPoint, context: Mapping[str, Any]) -> Verdict:
    """Verify a located fold of ``context["problem"]`` at ``context["y"]`` (the whole
    unknown vector) with ``context["args"]`` and optional ``context["weights"]``."""
    problem, args = context["problem"], context["args"]
    y = np.asarray(context["y"], dtype=float)
    G, Gy = NewtonCorrector(problem).evaluate(y, args)
    if not (np.all(np.isfinite(G)) and np.all(np.isfinite(Gy))):
        return Verdict((Check.finite("jacobian", np.inf),))
    n1 = y.shape[0]
    pi = problem.param_index % n1
    w = np.asarray(context.get("weights", np.ones(n1)), dtype=float)
    if n1 < SVD_MAX_UNKNOWNS:
        _, s_full, vt = np.linalg.svd(Gy, full_matrices=True)
        t = vt[-1]
        s_u = np.linalg.svd(np.delete(Gy, pi, axis=1), compute_uv=False)
        null, rank = float(s_u[-1]) / max(1.0, float(s_u[0])), float(s_full[-1] / s_full[0])
    else:
        t, null, rank = _large_fold_measures(Gy, pi)
    t = t / np.sqrt(t @ (w * t))
    return Verdict(
        (
            Check.at_most(
                "residual",
                float(np.max(np.abs(G))),
                FOLD_RESIDUAL_TOL * (1.0 + float(np.max(np.abs(y)))),
            ),
            Check.at_most("tangent_param", abs(float(t[pi])), FOLD_TANGENT_TOL),
            Check.at_most("null_vector", null, FOLD_NULL_TOL),
            Check.at_least("rank_margin", rank, FOLD_RANK_MIN),
        )
    )


#: from this many unknowns on the fold criteria come from two LU factorisations and
#: inverse / power iterations instead of two dense SVDs (0.7 s each at 500 unknowns,
#: minutes on a fine mesh; the LU route takes tens of milliseconds)
SVD_MAX_UNKNOWNS = 200


def _large_fold_measures(Gy: np.ndarray, pi: int) -> tuple[np.ndarray, float, float]:
    """The null vector of ``G_y``, ``sigma_min(G_u) / max(1, sigma_max(G_u))`` and
    ``sigma_min(G_y) / sigma_max(G_y)`` without an SVD.

    ``G_u`` is factorised once: its smallest singular value by inverse iteration on
    ``(G_u^T G_u)^{-1}``, the null vector of ``G_y`` as ``[-G_u^{-1} G_lambda; 1]``
    (bordering with the parameter direction). With ``t`` the unit null vector, the
    bordered matrix ``[G_y; t^T]`` has the singular values of ``G_y`` and 1, so its
    smallest (inverse iteration on its factorisation) bounds ``sigma_min(G_y)`` from
    below: the rank check is never passed by an estimate. Largest singular values by
    power iteration. Estimates to a few per cent, against criteria set decades apart.
    """
    Gu = np.delete(Gy, pi, axis=1)
    g_lam = Gy[:, pi]
    with np.errstate(all="ignore"):
        lu_u = scipy.linalg.lu_factor(Gu, check_finite=False)
        x = scipy.linalg.lu_solve(lu_u, g_lam, check_finite=False)
    t = np.insert(-x, pi, 1.0)
    if not np.all(np.isfinite(t)):
        return t, 0.0, 0.0
    t = t / np.linalg.norm(t)
    s_u_min = _smallest_singular(lu_u, Gu.shape[0])
    A = np.vstack([Gy, t[None, :]])
    with np.errstate(all="ignore"):
        lu_a = scipy.linalg.lu_factor(A, check_finite=False)
    s_min = min(_smallest_singular(lu_a, A.shape[0]), 1.0)
    null = s_u_min / max(1.0, _largest_singular(Gu))
    return t, null, s_min / _largest_singular(Gy)


def _smallest_singular(lu, n: int, iters: int = 50) -> float:
    """``sigma_min`` of a factorised square matrix: inverse iteration on ``(A^T A)^{-1}``
    from a fixed start (deterministic)."""
    v = np.random.default_rng(0).standard_normal(n)
    v /= np.linalg.norm(v)
    est = np.inf
    with np.errstate(all="ignore"):
        for _ in range(iters):
            z = scipy.linalg.lu_solve(lu, scipy.linalg.lu_solve(lu, v, trans=1), trans=0)
            nz = float(np.linalg.norm(z))
            if not (np.isfinite(nz) and nz > 0):
                return 0.0
            new = 1.0 / np.sqrt(nz)
            v = z / nz
            if abs(new - est) <= 1e-3 * new:
                return new
            est = new
    return float(est)


def _largest_singular(A: np.ndarray, iters: int = 50) -> float:
    """``sigma_max`` by power iteration on ``A^T A`` from a fixed start."""
    v = np.random.default_rng(1).standard_normal(A.shape[1])
    v /= np.linalg.norm(v)
    est = 0.0
    for _ in range(iters):
        z = A.T @ (A @ v)
        nz = float(np.linalg.norm(z))
        if nz == 0.0:
            return 0.0
        new = np.sqrt(nz)
        v = z / nz
        if abs(new - est) <= 1e-3 * new:
            return float(new)
        est = new
    return float(est)


def report_folds(
    findings: Findings,
    result: PalcResult,
    params: Sequence[float],
    point_of: Callable[[int, np.ndarray, float], SpecialPoint],
    context: Mapping[str, Any],
    *,
    kind: str = "fold",
    offset: int = 0,
) -> None:
    """Verify the folds a driver run located and add them (or candidates) to ``findings``.

    Parameters
    ----------
    findings : Findings
    result : PalcResult
    params : sequence of float
        Parameter of each point of the branch (``result.ys`` shifted by ``offset``).
    point_of : callable ``(i, y, precision) -> SpecialPoint``
        Builds the (unverified) point from the located unknowns ``y``.
    context : mapping
        ``problem``, ``args`` and optionally ``weights`` for :func:`verify_fold`.
    kind : str
        ``fold`` or ``cycle_fold`` (the latter needs its own registered verifier).
    offset : int
        Points prepended to ``result.ys`` in ``params``.

    The located parameter may lie beyond both bracketing points (the parameter is extremal
    at a fold), by at most the distance between the two points.
    """
    for i, y_f, prec in result.folds:
        k = i + offset
        step = float(np.max(np.abs(result.ys[i + 1] - result.ys[i])))
        findings.confirm(
            kind,
            (params[k], params[k + 1]),
            lambda i=i, y_f=y_f, prec=prec: point_of(i, y_f, prec),
            context={**context, "y": y_f},
            index=k,
            slack=step,
        )
    for i in result.fold_failures:
        k = i + offset
        findings.flag(
            kind,
            (params[k], params[k + 1]),
            "the parameter turned between these points but the fold could not be located",
        )
