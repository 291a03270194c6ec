"""The bifurcation diagram of an autonomous system in one parameter.

Equilibria from the start of the range towards its end, with their verified Hopf points,
folds and branch-point candidates, and the branch of periodic orbits born at every
verified Hopf point, gathered into one :class:`~bifid.continuation.Diagram` — what
``bifid continue`` prints.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax.numpy as jnp
import numpy as np

from bifid.continuation._branch import Branch, SpecialPoint
from bifid.continuation._collocation import hopf_orbits
from bifid.continuation._diagram import Diagram, diagram_of
from bifid.continuation._equilibria import equilibria
from bifid.continuation._options import ContinuationOptions
from bifid.continuation._verify import LOCATION_ERRORS
from bifid.errors import BifidInputError, ConvergenceError
from bifid.systems import System


def _failed_orbit_branch(
    system: System, param: str, p: Any, hopf: SpecialPoint, exc: BaseException
) -> Branch:
    text = str(exc).strip().splitlines()
    return Branch(
        kind="periodic",
        system=system.name,
        param=param,
        params=np.empty(0),
        solutions=np.empty((0, system.n_states)),
        stable=np.empty(0, bool),
        special_points=[],
        data={},
        p=np.asarray(p),
        status="failed",
        message=f"the orbit branch of the Hopf point at {param}={hopf.param:.8g} "
        f"failed: {text[0] if text else type(exc).__name__}",
        signals=tuple(system.states),
        meta={"start_param": hopf.param},
    )


def bifurcation_diagram(
    system: System,
    param: str,
    start: float,
    end: float,
    *,
    p: Any = None,
    x0: np.ndarray | None = None,
    n_mesh: int = 64,
    max_mesh: int | None = None,
    adapt: bool = True,
    max_steps: int = 1000,
    orbits: bool = True,
    eq_options: ContinuationOptions | None = None,
    orbit_options: ContinuationOptions | None = None,
    progress: Callable[[int, float], None] | None = None,
    stability: str = "integrated",
    **diagram_kw: Any,
) -> Diagram:
    """Equilibria over ``[start, end]`` and the orbit branches of their Hopf points.

    Parameters
    ----------
    system : System
        An autonomous system.
    param : str
        Continuation parameter.
    start, end : float
        The equilibrium branch starts at ``start`` (from ``x0``) and runs towards ``end``;
        every branch stays within ``[min(start, end), max(start, end)]``.
    p : array, optional
        Parameter vector (defaults of the system).
    x0 : array of shape (n,), optional
        Guess of the equilibrium at ``start`` (default: the system's ``x0`` when it has
        one, else zeros).
    n_mesh, max_mesh, adapt
        Starting mesh of the orbits, its limit and whether it adapts (see
        :func:`~bifid.continuation.hopf_orbits`).
    max_steps : int
        Step budget of each branch (of the default options).
    orbits : bool
        Continue the orbits of every Hopf point (False: equilibria only).
    eq_options, orbit_options : ContinuationOptions, optional
        Options of the equilibrium branch and of the orbit branches (defaults: steps
        scaled to the range, bounds of the range, ``max_steps``).
    progress : callable ``(n_points, param) -> None``, optional
    stability : {"integrated", "collocation"}
        Source of the orbits' Floquet multipliers (see
        :func:`~bifid.continuation.hopf_orbits`; "collocation" compiles nothing).
    **diagram_kw
        Passed to :class:`~bifid.continuation.Diagram` (``settings``, ``warnings``, ...).

    Returns
    -------
    Diagram
        ``kind="bifurcation"``: the equilibrium branch first, then one orbit branch per
        verified Hopf point (a branch that could not be continued is a failed branch
        with its reason, which makes the diagram incomplete).

    Raises
    ------
    BifidInputError
        For a forced system, an unknown parameter, ``start == end`` or a bad ``x0``.
    ConvergenceError
        If no equilibrium is found at ``start``.
    """
    start, end = float(start), float(end)
    if not (np.isfinite(start) and np.isfinite(end)) or start == end:
        raise BifidInputError(
            f"the range must be two different finite numbers, got {start!r}, {end!r}."
        )
    p = system.param_vector() if p is None else jnp.asarray(p, dtype=jnp.float64)
    lo, hi = min(start, end), max(start, end)
    span = hi - lo
    eq_options = eq_options or ContinuationOptions(
        ds=span / 50,
        ds_max=span / 20,
        ds_min=span * 1e-9,
        p_min=lo,
        p_max=hi,
        max_steps=max_steps,
        direction=1 if end > start else -1,
    )
    eq = equilibria(system, param, p=p, x0=x0, start=start, options=eq_options, progress=progress)
    branches = [eq]
    if orbits:
        # at least ten steps across the range in the parameter; longer ones in the orbits
        # where the branch is nearly vertical (the orbits change, the parameter hardly)
        orbit_options = orbit_options or ContinuationOptions(
            ds=1e-3,
            ds_max=0.25,
            dp_max=max(1e-3, min(0.25, span / 10)),
            ds_min=1e-9,
            p_min=lo,
            p_max=hi,
            max_steps=max_steps,
        )
        for h in eq.special("hopf"):
            try:
                branches.append(
                    hopf_orbits(
                        system,
                        h,
                        p=p,
                        n_mesh=n_mesh,
                        max_mesh=max_mesh,
                        adapt=adapt,
                        options=orbit_options,
                        progress=progress,
                        stability=stability,
                    )
                )
            except LOCATION_ERRORS as exc:
                branches.append(_failed_orbit_branch(system, param, p, h, exc))
    return diagram_of("bifurcation", branches, **diagram_kw)


def continue_from_hopf(
    system: System,
    param: str,
    lo: float,
    hi: float,
    *,
    p: Any = None,
    x0: np.ndarray | None = None,
    n_mesh: int = 64,
    max_mesh: int | None = None,
    eq_options: ContinuationOptions | None = None,
    orbit_options: ContinuationOptions | None = None,
    progress: Callable[[int, float], None] | None = None,
    stability: str = "integrated",
) -> tuple[Branch, list[Branch]]:
    """Equilibria over ``[lo, hi]`` and the periodic-orbit branch of every Hopf point:
    :func:`bifurcation_diagram` as a pair ``(equilibria, orbit branches)``, for callers
    that need a Hopf point.

    Raises
    ------
    BifidInputError
        If the range contains no verified Hopf point.
    ConvergenceError
        If the orbits of a Hopf point could not be started (the reason in the message).
    """
    diagram = bifurcation_diagram(
        system,
        param,
        lo,
        hi,
        p=p,
        x0=x0,
        n_mesh=n_mesh,
        max_mesh=max_mesh,
        eq_options=eq_options,
        orbit_options=orbit_options,
        progress=progress,
        stability=stability,
    )
    eq, *branches = diagram.branches
    if not eq.special("hopf"):
        a, b = min(lo, hi), max(lo, hi)
        raise BifidInputError(
            f"No Hopf point of {system.name!r} in {param} ∈ [{a:g}, {b:g}]; "
            "widen the range or change parameters."
        )
    for br in branches:
        if br.status == "failed" and len(br) == 0:
            raise ConvergenceError(br.message)
    return eq, branches
