"""AUTO-07p demo ``pp3``: a predator-prey-superpredator model with harvesting.

``u1' = u1 (1 - u1) - p4 u1 u2``,
``u2' = -p2 u2 + p4 u1 u2 - p5 u2 u3 - p1 (1 - e^{-p6 u2})``,
``u3' = -p3 u3 + p5 u2 u3``; ``pi = PAR(i)``. Transcribed from AUTO-07p
``demos/pp3/pp3.f90`` at commit 44cc1c42a888179bdbd608a40613caee9cbc4675 (see the package
docstring for the attribution); reference values from ``test/hyper.all`` (``Demo pp3``), run
constants from ``c.pp3`` (ISP=2, ILP=1; p1 from 0 to 1, stops where the norm of the state is
1.2) and ``pp3.auto`` (orbits from every Hopf point, stopping at p1 = 0, 0.3 or 1). AUTO
switches branches at the branch points 0.75 and 0.31934; bifid does not, so each branch is
started from one of AUTO's points with ``--x0``.
"""

import jax.numpy as jnp

from bifid.systems import Parameter, System, register


def field(u, p):
    """FUNC of pp3.f90."""
    p1, p2, p3, p4, p5, p6 = p[0], p[1], p[2], p[3], p[4], p[5]
    return jnp.stack(
        [
            u[0] * (1 - u[0]) - p4 * u[0] * u[1],
            -p2 * u[1] + p4 * u[0] * u[1] - p5 * u[1] * u[2] - p1 * (1 - jnp.exp(-p6 * u[1])),
            -p3 * u[2] + p5 * u[1] * u[2],
        ]
    )


register(
    "pp3",
    System(
        name="pp3",
        states=("u1", "u2", "u3"),
        parameters=(
            Parameter("p1", 0.0, "1", "harvesting, PAR(1)"),
            Parameter("p2", 0.25, "1", "PAR(2)"),
            Parameter("p3", 0.5, "1", "PAR(3)"),
            Parameter("p4", 4.0, "1", "PAR(4)"),
            Parameter("p5", 3.0, "1", "PAR(5)"),
            Parameter("p6", 5.0, "1", "PAR(6)"),
        ),
        field=field,
        default_param="p1",
        description="AUTO-07p demo pp3 (three species)",
    ),
    overwrite=True,
)

_DETECT = ("hopf", "fold", "branch_point")
_ODETECT = ("cycle_fold", "period_doubling", "torus", "branch_point")
_STOP = {"param": (0.0, 0.3, 1.0)}

AUTO_RUNS = [
    {
        "label": "u2 = u3 = 0",
        "param": "p1",
        "range": (0.0, 1.0),
        "set": {},
        "x0": (1.0, 0.0, 0.0),
        "detect": _DETECT,
        "hopf": (),
        "folds": (),
        "branch_points": (0.75,),
        "orbits": [],
    },
    {
        "label": "u3 = 0",
        "param": "p1",
        "range": (0.800796, 0.0),
        "set": {},
        "x0": (1.19897, -0.0497420, 0.0),
        "detect": _DETECT,
        "hopf": (0.459600, 0.106415),
        "folds": (),
        "branch_points": (0.75, 0.319340),
        "orbits": [
            {
                "hopf": 0.459600,
                "detect": _ODETECT,
                "stop": _STOP,
                "cycle_folds": (),
                "branch_points": (0.301234,),
                "homoclinic": None,
                "points": ((0.4, 7.59431), (0.35, 7.93328), (0.3, 8.28510)),
            },
            {
                "hopf": 0.106415,
                "detect": _ODETECT,
                "stop": _STOP,
                "cycle_folds": (),
                "branch_points": (),
                "homoclinic": None,
                "points": ((0.15, 9.25346), (0.2, 9.00365), (0.25, 8.64975), (0.3, 8.28510)),
            },
        ],
    },
    {
        "label": "u1 = 1/3",
        "param": "p1",
        "range": (0.0, 1.0),
        "set": {},
        "x0": (1.0 / 3.0, 1.0 / 6.0, 0.361111),
        "detect": _DETECT,
        "hopf": (0.229357, 0.503835),
        "folds": (),
        "branch_points": (0.319340,),
        "orbits": [
            {
                "hopf": 0.229357,
                "detect": _ODETECT,
                "stop": _STOP,
                "cycle_folds": (),
                "branch_points": (),
                "homoclinic": None,
                "points": ((0.25, 7.00718), (0.3, 8.24881)),
            },
            {
                "hopf": 0.503835,
                "detect": _ODETECT,
                "stop": _STOP,
                "cycle_folds": (),
                "branch_points": (0.301235,),
                "homoclinic": None,
                "points": ((0.4, 9.78590), (0.35, 9.18831), (0.3, 8.24882)),
            },
        ],
    },
]
