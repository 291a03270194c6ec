"""AUTO-07p demo ``ab``: the A -> B reaction in a continuous stirred tank.

``u1' = -u1 + Da (1 - u1) e^{u2}``,
``u2' = -u2 + Da B (1 - u1) e^{u2} - beta u2``;
``Da = PAR(1)``, ``B = PAR(2)``, ``beta = PAR(3)``. Transcribed from AUTO-07p
``demos/ab/ab.f90`` at commit 44cc1c42a888179bdbd608a40613caee9cbc4675 (see the package
docstring for the attribution); reference values from ``test/hyper.all`` (``Demo ab``) with
the run constants of ``demos/ab/c.ab.2`` (equilibria in ``Da`` up to 0.25, ILP=1, ISP=1)
and ``c.ab.3`` (orbits, ILP=0, ISP=1: AUTO detects no orbit bifurcations there; stops at
``Da = 0.25`` or period 1000). The six runs start from AUTO's labels at B = 8, 14, 15, 16, 17
and 18 of its first run (``c.ab.1``).
"""

import jax.numpy as jnp

from bifid.systems import Parameter, System, register


def field(u, p):
    """FUNC of ab.f90."""
    da, b, beta = p[0], p[1], p[2]
    e = jnp.exp(u[1])
    return jnp.stack([-u[0] + da * (1 - u[0]) * e, -u[1] + da * b * (1 - u[0]) * e - beta * u[1]])


register(
    "ab",
    System(
        name="ab",
        states=("u1", "u2"),
        parameters=(
            Parameter("Da", 0.0, "1", "Damkohler number, PAR(1)"),
            Parameter("B", 8.0, "1", "heat of reaction, PAR(2)"),
            Parameter("beta", 3.0, "1", "heat transfer coefficient, PAR(3)"),
        ),
        field=field,
        default_param="Da",
        description="AUTO-07p demo ab (A -> B reaction)",
    ),
    overwrite=True,
)

_EQ = {"param": "Da", "range": (0.0, 0.25), "x0": None, "detect": ("hopf", "fold", "branch_point")}
_ORBIT = {
    "detect": (),
    "stop": {"param": (0.25,), "period": 1000.0},
    "cycle_folds": (),
    "branch_points": (),
    "homoclinic": None,
}

AUTO_RUNS = [
    {
        **_EQ,
        "label": "B=8",
        "set": {"B": 8.0},
        "hopf": (),
        "folds": (),
        "branch_points": (),
        "orbits": [],
    },
    {
        **_EQ,
        "label": "B=14",
        "set": {"B": 14.0},
        "hopf": (0.165042,),
        "folds": (),
        "branch_points": (),
        "orbits": [{**_ORBIT, "hopf": 0.165042, "points": ((0.25, 2.22034),)}],
    },
    {
        **_EQ,
        "label": "B=15",
        "set": {"B": 15.0},
        "hopf": (0.146882,),
        "folds": (),
        "branch_points": (),
        "orbits": [{**_ORBIT, "hopf": 0.146882, "points": ((0.25, 1.72637),)}],
    },
    {
        **_EQ,
        "label": "B=16",
        "set": {"B": 16.0},
        "hopf": (0.132538,),
        "folds": (),
        "branch_points": (),
        "orbits": [{**_ORBIT, "hopf": 0.132538, "points": ((0.25, 1.23162),)}],
    },
    {
        **_EQ,
        "label": "B=17",
        "set": {"B": 17.0},
        "hopf": (0.120866, 0.217079),
        "folds": (0.121901, 0.117015),
        "branch_points": (),
        "orbits": [
            {**_ORBIT, "hopf": 0.120866, "points": (), "homoclinic": (0.120102, 999.882)},
            {**_ORBIT, "hopf": 0.217079, "points": (), "homoclinic": (0.119455, 999.991)},
        ],
    },
    {
        **_EQ,
        "label": "B=18",
        "set": {"B": 18.0},
        "hopf": (0.111153, 0.183833),
        "folds": (0.111565, 0.0995741),
        "branch_points": (),
        "orbits": [
            {**_ORBIT, "hopf": 0.111153, "points": (), "homoclinic": (0.110829, 999.998)},
            {**_ORBIT, "hopf": 0.183833, "points": (), "homoclinic": (0.110114, 999.991)},
        ],
    },
]
