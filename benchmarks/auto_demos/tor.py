"""AUTO-07p demo ``tor``: an electronic circuit with a torus bifurcation (Freire et al.).

``x' = (-(beta + nu) x + beta y - a3 x^3 + b3 (y - x)^3) / r``,
``y' = beta x - (beta + gamma) y - z - b3 (y - x)^3``, ``z' = y``;
``nu = PAR(1)``, ``beta = PAR(2)``, ``gamma = PAR(3)``, ``r = PAR(4)``, ``a3 = PAR(5)``,
``b3 = PAR(6)``. Transcribed from AUTO-07p ``demos/tor/tor.f90`` at commit
44cc1c42a888179bdbd608a40613caee9cbc4675 (see the package docstring for the attribution);
reference values from ``test/hyper.all`` (``Demo tor``), run constants from ``c.tor`` (ISP=2,
ILP=1; nu from -0.9 to -0.4) and ``tor.auto`` (the orbits of the first Hopf point, 125
steps: the branch is compared up to AUTO's last period). The torus and period-doubling
points of the demo lie on a branch that bifurcates from this one (branch switching), which
bifid does not do.

The orbits born at the Hopf point are symmetric, ``u(t + T/2) = -u(t)`` (the field is odd).
Just past the cycle fold at ``nu = -0.799899`` a branch of non-symmetric orbits leaves them at
a symmetry-breaking cycle branch point (``nu = -0.7998991433``, ``T = 39.381419``), and the
demo's run (NTST = 25) moves onto it without reporting the branch point: its last cycle LP,
``(-0.796906, 42.2879)``, is a fold of the non-symmetric orbits (``other_branch`` below).
bifid stays on the symmetric branch, so the comparison stops at that branch point. Checked
independently by multiple shooting (SciPy DOP853, rtol 1e-11, 40 and 80 segments): the
symmetric branch's next fold is at ``(-0.7969090553, 49.356691)`` (bifid's), the
non-symmetric branch's at ``(-0.7969060628, 42.287508)`` (AUTO's), and the demo rerun with
NTST = 30 to 100 reports the branch point and then bifid's fold.
"""

import jax.numpy as jnp

from bifid.systems import Parameter, System, register


def field(u, p):
    """FUNC of tor.f90."""
    nu, beta, gamma, r, a3, b3 = p[0], p[1], p[2], p[3], p[4], p[5]
    x, y, z = u[0], u[1], u[2]
    c = b3 * (y - x) ** 3
    return jnp.stack(
        [
            (-(beta + nu) * x + beta * y - a3 * x**3 + c) / r,
            beta * x - (beta + gamma) * y - z - c,
            y,
        ]
    )


register(
    "tor",
    System(
        name="tor",
        states=("x", "y", "z"),
        parameters=(
            Parameter("nu", -0.9, "1", "PAR(1)"),
            Parameter("beta", 0.5, "1", "PAR(2)"),
            Parameter("gamma", -0.6, "1", "PAR(3)"),
            Parameter("r", 0.6, "1", "PAR(4)"),
            Parameter("a3", 0.328578, "1", "PAR(5)"),
            Parameter("b3", 0.933578, "1", "PAR(6)"),
        ),
        field=field,
        default_param="nu",
        description="AUTO-07p demo tor",
    ),
    overwrite=True,
)

AUTO_RUNS = [
    {
        "label": "origin",
        "param": "nu",
        "range": (-0.9, -0.4),
        "set": {},
        "x0": None,
        "detect": ("hopf", "fold", "branch_point"),
        "hopf": (-0.589337,),
        "folds": (),
        "branch_points": (-0.5,),
        "orbits": [
            {
                "hopf": -0.589337,
                "detect": ("cycle_fold", "period_doubling", "torus", "branch_point"),
                # AUTO leaves the symmetric orbits at their branch point (docstring)
                "stop": {"period": 39.3814},
                "cycle_folds": (
                    (-0.584335, 8.42647),
                    (-0.832514, 19.4158),
                    (-0.787590, 29.3732),
                    (-0.799899, 39.3706),
                ),
                "other_branch": (
                    (
                        "cycle LP",
                        -0.796906,
                        42.2879,
                        "a fold of the non-symmetric orbits AUTO switches to at the "
                        "unreported branch point (-0.799899, period 39.381); shooting: "
                        "(-0.7969060628, 42.287508)",
                    ),
                ),
                "branch_points": (-0.587029, -0.832438),
                "points": (),
                "homoclinic": None,
            }
        ],
    },
    {
        "label": "x > 0 branch",
        "param": "nu",
        "range": (-0.9, -0.55),
        "set": {},
        "x0": (0.562955, 0.0, 0.448037),
        "detect": ("hopf", "fold", "branch_point"),
        "hopf": (),
        "folds": (),
        "branch_points": (),
        "orbits": [],
    },
]
