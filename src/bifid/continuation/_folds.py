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
    _, s_full, vt = np.linalg.svd(Gy, full_matrices=True)
    t = vt[-1]
    t = t / np.sqrt(t @ (w * t))
    s_u = np.linalg.svd(np.delete(Gy, pi, axis=1), compute_uv=False)
    return Verdict(
        (
            Check.at_most(
                "residual",
                float(np.max(np.abs(G))),
                FOLD_RESIDUAL_TOL * (1.0 + float(np.max(np.abs(y)))),
            ),
            Check.at_most("tangent_param", float(t[pi]), FOLD_TANGENT_TOL),
            Check.at_most("null_vector", float(s_u[-1]) / max(1.0, float(s_u[0])), FOLD_NULL_TOL),
            Check.at_least("rank_margin", float(s_full[-1]) / float(s_full[0]), FOLD_RANK_MIN),
        )
    )


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
