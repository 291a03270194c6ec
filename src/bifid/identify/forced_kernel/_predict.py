r"""Forced responses of a fitted kernel model (thesis eqs. 6.10–6.21), as branches.

* :func:`frc` — pseudo-arclength continuation in Ω of the fixed points of eq. 6.10
  (equivalent to eq. 6.11, better conditioned), folds located, the peak refined;
* :func:`scurve` — at fixed Ω, ``Γ(ρ) = sqrt(a² + (b − Ω)²ρ²)`` is explicit in ρ (eq. 6.11),
  so the S-curve is exact on a ρ grid; folds where ``dΓ/dρ = 0``;
* :func:`backbone` — eq. 6.21, ``b(ρ, Ω) = Ω`` solved for Ω along ρ;
* stability of every point from the eigenvalues of the Jacobian of eq. 6.10 in ``(ρ, ψ)``.
"""

from __future__ import annotations

import math
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.continuation import Branch, ContinuationOptions, SpecialPoint, correct, palc
from bifid.errors import BifidInputError, ConvergenceError
from bifid.identify.forced_kernel._reduced import (
    FRC_PROBLEM,
    ab_grid,
    backbone_mean,
    dgamma_drho,
    fold_radii,
    response_radii,
    sgamma,
    wrap_lag,
)
from bifid.identify.forced_kernel._state import ReducedFit

__all__ = ["backbone", "fixed_points", "frc", "omega_window", "scurve"]

SOURCE = "forced_kernel"


def fixed_points(
    rf: ReducedFit,
    omega: float,
    forcing: float,
    *,
    rho_max: float | None = None,
    n_grid: int = 2000,
) -> list[dict[str, float]]:
    """All fixed points of eq. 6.10 at ``(Ω, F)`` below ``rho_max``: roots in ρ of eq. 6.11
    bracketed on a grid, each refined by bisection.

    Returns a list of ``{rho, psi, phase, stable}`` sorted by amplitude.
    """
    gamma = float(rf.gamma(forcing, omega))
    rmax = 3.0 * rf.rho_range[1] if rho_max is None else float(rho_max)
    rr = np.linspace(rmax / n_grid, rmax, n_grid)
    a, b = (np.asarray(v) for v in ab_grid(rf.model, rr, np.full(n_grid, float(omega))))
    res = a**2 + (b - omega) ** 2 * rr**2 - gamma**2
    i = np.nonzero(np.sign(res[:-1]) * np.sign(res[1:]) < 0)[0]
    if not i.size:
        return []
    r = np.asarray(response_radii(rf.model, omega, gamma, rr[i], rr[i + 1]))
    a, b = (np.asarray(v) for v in ab_grid(rf.model, r, np.full(r.shape, float(omega))))
    psi = np.arctan2(-a / gamma, -(b - omega) * r / gamma)
    _, stable = rf.stable(r, psi, np.full(r.shape, float(omega)), np.full(r.shape, gamma))
    return [
        {
            "rho": float(r[k]),
            "psi": float(psi[k]),
            "phase": float(wrap_lag(psi[k])),
            "stable": bool(stable[k]),
        }
        for k in range(r.size)
    ]


def omega_window(rf: ReducedFit, omega_range: Any) -> tuple[float, float]:
    """The frequency window of an FRC (default: the trained range widened by 25 %)."""
    if omega_range is None:
        lo, hi = rf.omega_range
        w = max(hi - lo, 0.02 * hi)
        return lo - 0.25 * w, hi + 0.25 * w
    lo, hi = (float(v) for v in omega_range)
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise BifidInputError(f"omega_range must be 0 < low < high, got {omega_range!r}.")
    return lo, hi


def forced_branch(
    rf: ReducedFit,
    rho: np.ndarray,
    psi: np.ndarray,
    omega: np.ndarray,
    forcing: np.ndarray,
    param: str,
    specials: list[SpecialPoint],
    status: str,
    message: str,
    options: ContinuationOptions,
) -> Branch:
    """A :class:`Branch` of forced responses ``(ρ, ψ)`` at ``(Ω, F)`` with their stability;
    ``params`` are Ω (``param="Omega"``) or F (``"F"``)."""
    gamma = rf.gamma(forcing, omega)
    eig, stable = rf.stable(rho, psi, omega, gamma)
    return Branch(
        kind="forced",
        system=SOURCE,
        param=param,
        params=np.asarray(omega if param == "Omega" else forcing, dtype=float),
        solutions=np.stack([rho, psi], axis=1),
        stable=stable,
        special_points=specials,
        data={
            "amplitude": rho[:, None],
            "observed_amplitude": rho,
            "phase": wrap_lag(psi),
            "omega": np.asarray(omega, dtype=float),
            "forcing": np.asarray(forcing, dtype=float),
            "eigenvalues": eig,
        },
        p=np.array([rf.forcing_scale]),
        status=status,
        message=message,
        options=options,
        signals=("y",),
        meta={
            "observed": "y",
            "forcing_scale": rf.forcing_scale,
            "forcing_frequency": rf.forcing_frequency,
        },
    )


def _point(
    kind: str,
    param: float,
    index: int,
    bracket: tuple[float, float],
    rho: float,
    psi: float,
    omega: float,
    forcing: float,
    precision: float,
) -> SpecialPoint:
    return SpecialPoint(
        kind=kind,
        param=param,
        index=index,
        bracket=bracket,
        solution=np.array([rho, psi]),
        precision=precision,
        status="converged",
        data={"amplitude": rho, "phase": float(wrap_lag(psi)), "omega": omega, "forcing": forcing},
    )


def _peak(
    ys: np.ndarray, tangents: np.ndarray, args: dict, weights: np.ndarray
) -> tuple[np.ndarray, int]:
    """The FRC point of largest amplitude: a parabola in arclength through the largest
    sampled point and its neighbours, corrected onto the curve; ``(y, index)``."""
    i = int(np.argmax(ys[:, 0]))
    if 0 < i < len(ys) - 1:
        seg = np.sqrt(np.sum(np.diff(ys[i - 1 : i + 2], axis=0) ** 2 * weights, axis=1))
        s = np.array([-seg[0], 0.0, seg[1]])
        r = ys[i - 1 : i + 2, 0]
        den = (s[0] - s[1]) * (s[0] - s[2]) * (s[1] - s[2])
        if den != 0:
            a2 = (s[2] * (r[1] - r[0]) + s[1] * (r[0] - r[2]) + s[0] * (r[2] - r[1])) / den
            a1 = (
                s[2] ** 2 * (r[0] - r[1]) + s[1] ** 2 * (r[2] - r[0]) + s[0] ** 2 * (r[1] - r[2])
            ) / den
            if a2 < 0:
                t = np.asarray(tangents[i])
                guess = ys[i] + float(np.clip(-a1 / (2 * a2), s[0], s[2])) * t
                row = weights * t
                y, ok, _, _ = correct(
                    FRC_PROBLEM,
                    jnp.asarray(guess),
                    jnp.asarray(row),
                    float(row @ guess),
                    args,
                    tol=1e-12,
                )
                if ok and y[0] >= ys[i, 0]:
                    return np.asarray(y), i
    return ys[i], i


def frc(
    rf: ReducedFit,
    forcing: float,
    omega_range: Any = None,
    *,
    options: ContinuationOptions | None = None,
    rho_cap: float | None = None,
) -> Branch:
    """Forced response curve at forcing ``F``: continuation of eq. 6.11 in Ω.

    Parameters
    ----------
    forcing : float
        ``F`` (the model uses Γ = κF, or κF Ω̄/Ω along the curve with
        ``forcing_frequency="inverse"``).
    omega_range : (float, float), optional
        Frequency window (default: :func:`omega_window`).
    options : ContinuationOptions, optional
        Steps are in the arclength of ``(ρ/s_ρ, ψ, Ω/s_Ω)``.
    rho_cap : float, optional
        Stop when the amplitude exceeds it (default 4 × the largest trained amplitude).

    Returns
    -------
    Branch
        ``kind="forced"``, ``param="Omega"``, ``solutions`` = (ρ, ψ); folds and the peak as
        special points (``fold``, ``peak``); ``meta["scales"]``: the arclength scales.
    """
    f = float(forcing)
    if not (math.isfinite(f) and f > 0):
        raise BifidInputError(f"forcing must be a positive number, got {forcing!r}.")
    lo, hi = omega_window(rf, omega_range)
    cap = 4.0 * rf.rho_range[1] if rho_cap is None else float(rho_cap)
    starts = fixed_points(rf, lo, f, rho_max=cap)
    if not starts:
        raise ConvergenceError(
            f"no response of the model at Ω = {lo:.6g}, F = {f:.6g} below amplitude {cap:.4g}; "
            "widen omega_range or raise rho_cap."
        )
    s_rho, s_om = max(rf.rho_range[1], 1e-12), max(hi - lo, 1e-12)
    weights = np.array([1.0 / s_rho**2, 1.0, 1.0 / s_om**2])
    opts = (
        options
        or ContinuationOptions(ds=0.01, ds_min=1e-8, ds_max=0.04, max_steps=4000, newton_tol=1e-9)
    ).with_(p_min=lo - 1e-12, p_max=hi)
    args = {"model": rf.model, "gamma": jnp.asarray(f * rf.forcing_scale)}  # κF
    res = palc(
        FRC_PROBLEM,
        jnp.asarray([starts[0]["rho"], starts[0]["psi"], lo]),
        jnp.asarray([0.0, 0.0, 1.0]),
        args,
        opts,
        weights=jnp.asarray(weights),
        stop=lambda y: bool(y[0] <= 0 or y[0] > cap),
    )
    if res.ys.shape[0] < 2:
        raise ConvergenceError(f"FRC continuation failed at the start: {res.message}")
    ys = np.asarray(res.ys)
    status, message = res.status, res.message
    if status == "completed":
        status, message = "range", f"amplitude left (0, {cap:.4g}]"
    specials = [
        _point(
            "fold",
            float(yf[2]),
            int(i),
            (float(ys[i, 2]), float(ys[i + 1, 2])),
            float(yf[0]),
            float(yf[1]),
            float(yf[2]),
            f,
            float(prec),
        )
        for i, yf, prec in res.folds
    ]
    yp, ip = _peak(ys, np.asarray(res.tangents), args, weights)
    specials.append(
        _point(
            "peak",
            float(yp[2]),
            ip,
            (float(yp[2]), float(yp[2])),
            float(yp[0]),
            float(yp[1]),
            float(yp[2]),
            f,
            0.0,
        )
    )
    branch = forced_branch(
        rf,
        ys[:, 0],
        ys[:, 1],
        ys[:, 2],
        np.full(len(ys), f),
        "Omega",
        specials,
        status,
        message,
        opts,
    )
    branch.meta["scales"] = {"omega": s_om, "amplitude": s_rho}
    return branch


def scurve(
    rf: ReducedFit,
    omega: float,
    forcing_range: Any = None,
    *,
    n_points: int = 400,
    rho_cap: float | None = None,
) -> Branch:
    """S-curve at frequency Ω: ``Γ(ρ) = sqrt(a² + (b−Ω)²ρ²)`` on a ρ grid (eq. 6.11), and
    ``F = Γ / (Γ per unit F at Ω)``.

    The branch runs from small amplitude until ``F`` leaves ``forcing_range`` (default
    ``[0, 1.5 × largest trained F]``) or ρ reaches ``rho_cap``. Folds are where
    ``dΓ/dρ = 0``.
    """
    om = float(omega)
    if not (math.isfinite(om) and om > 0):
        raise BifidInputError(f"omega must be a positive number, got {omega!r}.")
    f_lo, f_hi = (
        (0.0, 1.5 * rf.forcing_range[1])
        if forcing_range is None
        else (float(forcing_range[0]), float(forcing_range[1]))
    )
    if not (math.isfinite(f_lo) and math.isfinite(f_hi) and 0 <= f_lo < f_hi):
        raise BifidInputError(f"forcing_range must be 0 <= low < high, got {forcing_range!r}.")
    cap = 4.0 * rf.rho_range[1] if rho_cap is None else float(rho_cap)
    k = float(rf.gamma(1.0, om))  # Γ per unit F at this Ω
    rr = np.linspace(cap / (50 * n_points), cap, 20 * n_points)
    a, b = (np.asarray(v) for v in ab_grid(rf.model, rr, np.full(rr.shape, om)))
    fgrid = np.asarray(sgamma(a, b, rr, om)[0]) / k
    inside = fgrid >= f_lo
    if not np.any(inside):
        raise ConvergenceError(f"the model's S-curve at Ω = {om:.6g} never reaches F = {f_lo}.")
    i0 = int(np.argmax(inside))
    above = np.nonzero(fgrid[i0:] > f_hi)[0]
    i1 = i0 + int(above[0]) if above.size else len(rr) - 1
    rho = np.linspace(max(rr[max(i0 - 1, 0)], rr[0]), rr[i1], n_points)
    a, b = (np.asarray(v) for v in ab_grid(rf.model, rho, np.full(rho.shape, om)))
    g, psi = (np.asarray(v) for v in sgamma(a, b, rho, om))
    forcing = g / k
    dg = np.asarray(dgamma_drho(rf.model, rho, om))
    i = np.nonzero(np.sign(dg[:-1]) * np.sign(dg[1:]) < 0)[0]
    specials = []
    if i.size:
        r = np.asarray(fold_radii(rf.model, om, rho[i], rho[i + 1]))
        af, bf = (np.asarray(v) for v in ab_grid(rf.model, r, np.full(r.shape, om)))
        gf, pf = (np.asarray(v) for v in sgamma(af, bf, r, om))
        specials = [
            _point(
                "fold",
                float(gf[j] / k),
                int(i[j]),
                (float(forcing[i[j]]), float(forcing[i[j] + 1])),
                float(r[j]),
                float(pf[j]),
                om,
                float(gf[j] / k),
                1e-12 * max(1.0, float(r[j])),
            )
            for j in range(r.size)
        ]
    status, message = (
        ("range", "reached the forcing bound")
        if above.size
        else ("steps", f"reached the amplitude cap {cap:.4g} before the forcing bound")
    )
    return forced_branch(
        rf,
        rho,
        psi,
        np.full(rho.shape, om),
        forcing,
        "F",
        specials,
        status,
        message,
        ContinuationOptions(p_min=f_lo, p_max=max(f_hi, f_lo + 1e-300)),
    )


def backbone(rf: ReducedFit, amplitude_range: Any = None, *, n_points: int = 200) -> Branch:
    """Backbone curve, eq. 6.21: ``b(ρ, Ω) = Ω`` solved for Ω at each ρ.

    ``kind="backbone"``, ``param="amplitude"``, ``params`` = ρ, ``data["omega"]``; the
    branch ends (``status="failed"``) where the solution stops continuing.
    """
    if amplitude_range is None:
        r_lo, r_hi = 0.01 * rf.rho_range[1], rf.rho_range[1]
    else:
        r_lo, r_hi = (float(v) for v in amplitude_range)
    if not (math.isfinite(r_lo) and math.isfinite(r_hi) and 0 <= r_lo < r_hi):
        raise BifidInputError(f"amplitude_range must be 0 <= low < high, got {amplitude_range!r}.")
    rho = np.linspace(r_lo, r_hi, n_points)
    # start Ω: fixed-point iteration Ω ← b(ρ0, Ω) from the trained centre
    o0 = rf.omega_c
    for _ in range(50):
        o0 = float(np.asarray(ab_grid(rf.model, rho[:1], np.array([o0]))[1])[0])
    om, res = (np.asarray(v) for v in backbone_mean(rf.model, rho, jnp.asarray(o0)))
    ok = np.isfinite(om) & (res < 1e-9 * max(abs(o0), 1.0))
    status, message = "completed", ""
    if not np.all(ok):
        first_bad = int(np.argmin(ok))
        rho, om = rho[:first_bad], om[:first_bad]
        status = "failed"
        message = (
            f"b(ρ, Ω) = Ω has no solution near the previous one beyond "
            f"ρ = {rho[-1] if rho.size else r_lo:.4g}"
        )
        if rho.size < 2:
            raise ConvergenceError(f"backbone: {message}")
    return Branch(
        kind="backbone",
        system=SOURCE,
        param="amplitude",
        params=rho,
        solutions=np.stack([rho, np.full(rho.shape, np.pi / 2)], axis=1),
        stable=np.ones(rho.shape, dtype=bool),
        special_points=[],
        data={"omega": om, "amplitude": rho[:, None], "observed_amplitude": rho},
        p=np.array([rf.forcing_scale]),
        status=status,
        message=message,
        options=ContinuationOptions(),
        signals=("y",),
        meta={"observed": "y", "backbone_start": o0},
    )
