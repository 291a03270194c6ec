"""AUTO-07p demo ``abc``: the A -> B -> C reaction in a continuous stirred tank.

``x1' = -x1 + D (1 - x1) e^{x3}``,
``x2' = -x2 + D e^{x3} (1 - x1 - s x2)``,
``x3' = -x3 - beta x3 + D B e^{x3} (1 - x1 + alpha s x2)``;
``D = PAR(1)``, ``alpha = PAR(2)``, ``beta = PAR(3)``, ``B = PAR(4)``, ``s = PAR(5)``.
Transcribed from AUTO-07p ``demos/abc/abc.f90`` at commit
44cc1c42a888179bdbd608a40613caee9cbc4675 (see the package docstring for the attribution);
reference values from ``test/hyper.all`` (``Demo abc``): equilibria with ``c.abc.1`` (ILP=1,
ISP=1, D from 0 to 0.4), orbits from each Hopf point with ``c.abc.2``-``c.abc.5`` (ILP=1,
ISP=1: cycle folds detected; stops at D = 0.25).
"""

import jax.numpy as jnp

from bifid.systems import Parameter, System, register


def field(x, p):
    """FUNC of abc.f90."""
    d, alpha, beta, b, s = p[0], p[1], p[2], p[3], p[4]
    e = jnp.exp(x[2])
    x1c = 1 - x[0]
    return jnp.stack(
        [
            -x[0] + d * x1c * e,
            -x[1] + d * e * (x1c - s * x[1]),
            -x[2] - beta * x[2] + d * b * e * (x1c + alpha * s * x[1]),
        ]
    )


register(
    "abc",
    System(
        name="abc",
        states=("x1", "x2", "x3"),
        parameters=(
            Parameter("D", 0.0, "1", "Damkohler number, PAR(1)"),
            Parameter("alpha", 1.0, "1", "PAR(2)"),
            Parameter("beta", 1.55, "1", "PAR(3)"),
            Parameter("B", 8.0, "1", "PAR(4)"),
            Parameter("s", 0.04, "1", "PAR(5)"),
        ),
        field=field,
        default_param="D",
        description="AUTO-07p demo abc (A -> B -> C reaction)",
    ),
    overwrite=True,
)

_ORBIT = {"detect": ("cycle_fold",), "branch_points": (), "homoclinic": None}

AUTO_RUNS = [
    {
        "label": "D from 0 to 0.4",
        "param": "D",
        "range": (0.0, 0.4),
        "set": {},
        "x0": None,
        "detect": ("hopf", "fold", "branch_point"),
        "hopf": (0.204185, 0.229836, 0.259957, 0.346208),
        "folds": (),
        "branch_points": (),
        "orbits": [
            {
                **_ORBIT,
                "hopf": 0.204185,
                "stop": {"param": (0.25,)},
                "cycle_folds": ((0.213697, 7.61104), (0.211903, 8.28914)),
                "points": ((0.250003, 6.53496),),
            },
            {
                **_ORBIT,
                "hopf": 0.229836,
                "stop": {"param": (0.25,)},
                "cycle_folds": ((0.224962, 6.52551),),
                "points": ((0.250001, 7.92732),),
            },
            {
                **_ORBIT,
                "hopf": 0.259957,
                "stop": {"param": (0.25,)},
                "cycle_folds": (),
                "points": ((0.25, 7.92716),),
            },
            {
                **_ORBIT,
                "hopf": 0.346208,
                "stop": {"param": (0.25,)},
                "cycle_folds": (),
                "points": ((0.249999, 6.53497),),
            },
        ],
    },
]
