"""SINDy baseline for the hopf_hybrid benchmark: what a user would fit to the stable cycles.

Parametric SINDy (pysindy): the measured states ``x`` (scaled by their RMS) with the wind speed
as a constant input ``u = U - U_c``, a cubic polynomial library in ``(x, u)`` and sequentially
thresholded least squares. SINDy learns from time series of trajectories, so it can only use
the stable cycles (unstable ones are measured under control). The identified polynomial ODE is
wrapped as a bifid :class:`~bifid.systems.System` and analysed by continuation like the true
system: Hopf point of its equilibria, fold of its cycle branch.
"""

from __future__ import annotations

import time
from typing import Any

import jax.numpy as jnp
import numpy as np


def fit_sindy(records, threshold: float = 0.05, degree: int = 3, smooth: int = 0) -> dict[str, Any]:
    """Fit SINDy to the stable records ``(param, signals, fs, stable)``; return the model.

    ``smooth``: if > 0, derivatives by pysindy's ``SmoothedFiniteDifference`` with a
    Savitzky–Golay window of that many samples (what a user would pick for noisy
    measurements); 0: plain finite differences (pysindy's default)."""
    import pysindy as ps

    stable = [r for r in records if r[3]]
    X = [np.asarray(r[1]) for r in stable]
    scale = np.sqrt(np.mean(np.concatenate(X) ** 2, axis=0))
    uc = float(np.mean([r[0] for r in stable]))
    t0 = time.perf_counter()
    model = ps.SINDy(
        feature_library=ps.PolynomialLibrary(degree=degree),
        optimizer=ps.STLSQ(threshold=threshold, alpha=1e-6),
        **(
            {
                "differentiation_method": ps.SmoothedFiniteDifference(
                    smoother_kws={"window_length": int(smooth), "polyorder": 3}
                )
            }
            if smooth
            else {}
        ),
    )
    model.fit(
        [x / scale for x in X],
        u=[np.full((len(x), 1), r[0] - uc) for x, r in zip(X, stable, strict=True)],
        t=[1.0 / r[2] for r in stable],
    )
    return {
        "model": model,
        "coef": np.asarray(model.coefficients()),
        "powers": np.asarray(model.feature_library.powers_),
        "scale": scale,
        "uc": uc,
        "n_terms": int(np.count_nonzero(model.coefficients())),
        "fit_time": time.perf_counter() - t0,
        "equations": model.equations(),
    }


def sindy_system(fit: dict[str, Any], param: str = "U"):
    """The identified ODE as a bifid System (states scaled, parameter in raw units)."""
    from bifid.systems import Parameter, System

    coef = jnp.asarray(fit["coef"])
    powers = jnp.asarray(fit["powers"])
    uc = fit["uc"]
    n = coef.shape[0]

    degree = int(np.max(fit["powers"]))
    cols = jnp.arange(powers.shape[1])

    def field(x, p):
        xu = jnp.concatenate([x, jnp.atleast_1d(p[0] - uc)])
        # monomials by gathering x^0..x^degree (x ** p with p = 0 has a NaN derivative at 0)
        table = jnp.stack([xu**0 * 1.0] + [xu**k for k in range(1, degree + 1)])
        feats = jnp.prod(table[powers, cols[None, :]], axis=1)
        return coef @ feats

    return System(
        name="sindy",
        states=tuple(f"s{k}" for k in range(n)),
        parameters=(Parameter(param, uc, "m/s", "bifurcation parameter"),),
        field=field,
        default_param=param,
        description="SINDy model (benchmark)",
    )


def analyse(fit: dict[str, Any], p_range=(12.0, 22.0)) -> dict[str, Any]:
    """Hopf point and fold of cycles of the SINDy model by continuation.

    The Hopf point detected on the equilibrium branch is refined with
    :func:`bifid.continuation.locate_hopf`; if that fails, the detected bracket value is
    reported with ``hopf_status = "guess"``. The cycle branch from a located Hopf point
    gives the fold. Failures are reported, not raised.
    """
    from bifid.continuation import ContinuationOptions, equilibria, hopf_orbits, locate_hopf

    system = sindy_system(fit)
    lo, hi = p_range
    out: dict[str, Any] = {
        "n_terms": fit["n_terms"],
        "fit_time": fit["fit_time"],
        "hopf": None,
        "fold": None,
    }
    try:
        eq = equilibria(
            system,
            "U",
            start=lo,
            options=ContinuationOptions(p_min=lo, p_max=hi, ds=0.05, ds_max=0.5, max_steps=500),
        )
    except Exception as exc:
        out["error"] = f"equilibria: {type(exc).__name__}: {exc}"[:300]
        return out
    hopfs = [sp for sp in eq.special_points if sp.kind == "hopf"]
    if not hopfs:
        out["error"] = "no Hopf point of the SINDy model in the range"
        return out
    hp = hopfs[0]
    out.update(hopf=float(hp.param), hopf_status=hp.status, criticality=hp.data.get("criticality"))
    if "eigenvector" not in hp.data:
        try:
            hp = locate_hopf(
                system,
                "U",
                np.asarray(hp.solution),
                float(hp.param),
                system.param_vector({"U": float(hp.param)}),
                omega_guess=hp.data.get("omega"),
            )
            out.update(
                hopf=float(hp.param), hopf_status="located", criticality=hp.data.get("criticality")
            )
        except Exception as exc:
            out["error"] = f"locate_hopf: {type(exc).__name__}: {exc}"[:300]
            return out
    try:
        br = hopf_orbits(
            system,
            hp,
            n_mesh=32,
            options=ContinuationOptions(p_min=lo, p_max=hi, ds=0.02, ds_max=0.2, max_steps=300),
        )
        folds = [sp.param for sp in br.special_points if sp.kind == "cycle_fold"]
        out["fold"] = float(folds[0]) if folds else None
        if not folds:
            out["error"] = f"no fold of cycles (branch ended: {br.status}, {len(br.params)} orbits)"
    except Exception as exc:
        out["error"] = f"hopf_orbits: {type(exc).__name__}: {exc}"[:300]
    return out
