"""AUTO-07p demo ``pp2``: a predator-prey model with harvesting of the prey.

``u1' = r u1 (1 - u1) - u1 u2 - quota (1 - e^{-k u1})``, ``u2' = -u2 + c u1 u2``;
``quota = PAR(1)``, ``r = PAR(2)``, ``k = PAR(3)``, ``c = PAR(4)`` (AUTO's names: ``fish``
and ``sharks`` for ``u1`` and ``u2``). Transcribed from AUTO-07p ``demos/pp2/pp2.f90`` at
commit 44cc1c42a888179bdbd608a40613caee9cbc4675 (see the package docstring for the
attribution); reference values from ``test/hyper.all`` (``Demo pp2``), run constants from
``c.pp2`` (ISP=2, ILP=1 by default; quota from 0 to 1, fish >= -0.25) and ``pp2.auto``
(orbits in quota and PERIOD up to period 36). AUTO switches branches at the branch points
0.6 and 0.821904; bifid does not, so each branch is started from one of AUTO's points
with ``--x0``.
"""

import jax.numpy as jnp

from bifid.systems import Parameter, System, register


def field(u, p):
    """FUNC of pp2.f90."""
    quota, r, k, c = p[0], p[1], p[2], p[3]
    e = jnp.exp(-k * u[0])
    return jnp.stack(
        [r * u[0] * (1 - u[0]) - u[0] * u[1] - quota * (1 - e), -u[1] + c * u[0] * u[1]]
    )


register(
    "pp2",
    System(
        name="pp2",
        states=("fish", "sharks"),
        parameters=(
            Parameter("quota", 0.0, "1", "harvesting quota, PAR(1)"),
            Parameter("r", 3.0, "1", "PAR(2)"),
            Parameter("k", 5.0, "1", "PAR(3)"),
            Parameter("c", 3.0, "1", "PAR(4)"),
        ),
        field=field,
        default_param="quota",
        description="AUTO-07p demo pp2 (predator-prey)",
    ),
    overwrite=True,
)

_POINTS = (
    (0.671709, 10.4024),
    (0.672635, 10.5098),
    (0.674476, 10.7334),
    (0.677204, 11.0918),
    (0.680756, 11.6162),
    (0.685012, 12.3547),
    (0.689760, 13.3795),
    (0.694676, 14.7957),
    (0.699324, 16.7572),
    (0.703216, 19.4886),
    (0.705948, 23.3184),
    (0.707420, 28.7287),
    (0.707941, 35.9999),
)
_DETECT = ("hopf", "fold", "branch_point")

AUTO_RUNS = [
    {
        "label": "no fish",
        "param": "quota",
        "range": (0.0, 1.0),
        "set": {},
        "x0": None,
        "detect": _DETECT,
        "hopf": (),
        "folds": (),
        "branch_points": (0.6,),
        "orbits": [],
    },
    {
        "label": "no sharks",
        "param": "quota",
        "range": (0.0, 1.0),
        "set": {},
        "x0": (1.0, 0.0),
        "detect": _DETECT,
        "hopf": (),
        "folds": (0.832929,),
        "branch_points": (0.821904, 0.6),
        "orbits": [],
    },
    {
        "label": "fish = 1/3",
        "param": "quota",
        "range": (0.0, 1.0),
        "set": {},
        "x0": (1.0 / 3.0, 2.0),
        "detect": _DETECT,
        "hopf": (0.671594,),
        "folds": (),
        "branch_points": (0.821904,),
        "orbits": [
            {
                "hopf": 0.671594,
                "detect": ("cycle_fold", "period_doubling", "torus", "branch_point"),
                "stop": {"param": (0.0, 1.0), "period": 36.0},
                "cycle_folds": (),
                "branch_points": (),
                "points": _POINTS,
                "homoclinic": None,
            }
        ],
    },
]
