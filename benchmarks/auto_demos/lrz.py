"""AUTO-07p demo ``lrz``: the Lorenz equations.

``x' = sigma (y - x)``, ``y' = rho x - y - x z``, ``z' = x y - beta z``;
``rho = PAR(1)``, ``beta = PAR(2)``, ``sigma = PAR(3)``. Transcribed from AUTO-07p
``demos/lrz/lrz.f90`` at commit 44cc1c42a888179bdbd608a40613caee9cbc4675 (see the package
docstring for the attribution); reference values from ``test/hyper.all`` (``Demo lrz``), run
constants from ``c.lrz`` (ISP=2, ILP=0: no folds detected; rho up to 30) and ``lrz.auto``
(orbits in rho and PERIOD, 35 steps). AUTO switches branches at the pitchfork rho = 1; bifid
does not (a branch point is a candidate), so the two non-trivial branches are started
from AUTO's points at rho = 30 with ``--x0``.
"""

import jax.numpy as jnp

from bifid.systems import Parameter, System, register


def field(u, p):
    """FUNC of lrz.f90."""
    rho, beta, sigma = p[0], p[1], p[2]
    x, y, z = u[0], u[1], u[2]
    return jnp.stack([sigma * (y - x), rho * x - y - x * z, x * y - beta * z])


register(
    "lrz",
    System(
        name="lrz",
        states=("x", "y", "z"),
        parameters=(
            Parameter("rho", 0.0, "1", "PAR(1)"),
            Parameter("beta", 8.0 / 3.0, "1", "PAR(2)"),
            Parameter("sigma", 10.0, "1", "PAR(3)"),
        ),
        field=field,
        default_param="rho",
        description="AUTO-07p demo lrz (Lorenz equations)",
    ),
    overwrite=True,
)

# the first periodic run's printed orbits (rho, PERIOD), every second step
_POINTS = (
    (24.7263, 0.653196),
    (24.6221, 0.656815),
    (24.3598, 0.666114),
    (23.8815, 0.683815),
    (23.1354, 0.713505),
    (22.0780, 0.760644),
    (20.6702, 0.835069),
    (18.8821, 0.957569),
    (16.7353, 1.18330),
    (14.8138, 1.62929),
    (13.9678, 2.78130),
    (13.9266, 6.70329),
    (13.9266, 12.6885),
    (13.9266, 34.1837),
)
_ORBIT = {
    "hopf": 24.7368,
    "detect": ("period_doubling", "torus", "branch_point"),
    "stop": {"max_period": 585.401},
    "cycle_folds": (),
    "branch_points": (),
    "points": _POINTS,
    "homoclinic": (13.9266, 585.401),
}

AUTO_RUNS = [
    {
        "label": "trivial branch",
        "param": "rho",
        "range": (0.0, 30.0),
        "set": {},
        "x0": None,
        "detect": ("hopf", "branch_point"),
        "hopf": (),
        "folds": (),
        "branch_points": (1.0,),
        "orbits": [],
    },
    {
        "label": "x > 0 branch",
        "param": "rho",
        "range": (30.0, 2.0),
        "set": {},
        "x0": (8.79394, 8.79394, 29.0),
        "detect": ("hopf", "branch_point"),
        "hopf": (24.7368,),
        "folds": (),
        "branch_points": (),
        "orbits": [_ORBIT],
    },
    {
        "label": "x < 0 branch",
        "param": "rho",
        "range": (30.0, 2.0),
        "set": {},
        "x0": (-8.79394, -8.79394, 29.0),
        "detect": ("hopf", "branch_point"),
        "hopf": (24.7368,),
        "folds": (),
        "branch_points": (),
        "orbits": [_ORBIT],
    },
]
