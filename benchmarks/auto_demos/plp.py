"""AUTO-07p demo ``plp``: a model of a periodic reaction with large state values.

``s' = (s0 - s) - rho r``, ``a' = alpha (a0 - a) - rho r``, ``r = s a / (1 + s + kappa s^2)``;
``s0 = PAR(1)``, ``a0 = PAR(2)``, ``alpha = PAR(3)``, ``rho = PAR(4)``, ``kappa = PAR(5)``.
Transcribed from AUTO-07p ``demos/plp/plp.f90`` at commit
44cc1c42a888179bdbd608a40613caee9cbc4675 (see the package docstring for the attribution);
reference values from ``test/hyper.all`` (``Demo plp``), run constants from ``c.plp.ss``
(equilibria in rho from its starting point to 6; ILP=1, ISP=1) and ``c.plp.ps`` (orbits from
each Hopf point, stopping at rho = 4; ILP=1, ISP=1: cycle folds detected). The states are of
order 100: tolerances must be relative to the size of the state.
"""

import jax.numpy as jnp

from bifid.systems import Parameter, System, register


def field(u, p):
    """FUNC of plp.f90."""
    s0, a0, alpha, rho, kappa = p[0], p[1], p[2], p[3], p[4]
    s, a = u[0], u[1]
    r = s * a / (1 + s + kappa * s**2)
    return jnp.stack([(s0 - s) - rho * r, alpha * (a0 - a) - rho * r])


register(
    "plp",
    System(
        name="plp",
        states=("s", "a"),
        parameters=(
            Parameter("s0", 110.0, "1", "PAR(1)"),
            Parameter("a0", 500.0, "1", "PAR(2)"),
            Parameter("alpha", 0.2, "1", "PAR(3)"),
            Parameter("rho", 2.021628, "1", "PAR(4)"),
            Parameter("kappa", 0.1, "1", "PAR(5)"),
        ),
        field=field,
        default_param="rho",
        description="AUTO-07p demo plp",
    ),
    overwrite=True,
)

_ORBIT = {
    "detect": ("cycle_fold",),
    "stop": {"param": (4.0,)},
    "branch_points": (),
    "homoclinic": None,
}

AUTO_RUNS = [
    {
        "label": "rho from 2.021628 to 6",
        "param": "rho",
        "range": (2.021628, 6.0),
        "set": {},
        "x0": (45.55974, 177.7987),
        "detect": ("hopf", "fold", "branch_point"),
        "hopf": (3.49995, 4.65046),
        "folds": (),
        "branch_points": (),
        "orbits": [
            {
                **_ORBIT,
                "hopf": 3.49995,
                "cycle_folds": ((2.75969, 10.0064),),
                "points": ((4.0, 6.73966),),
            },
            {
                **_ORBIT,
                "hopf": 4.65046,
                "cycle_folds": ((5.00784, 5.67658),),
                "points": ((4.0, 6.73966),),
            },
        ],
    },
]
