"""Verify before report: candidates, verified Hopf points and folds of equilibria, and the
driver's scaled tolerances, on systems with closed forms or published reference values."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

from bifid.continuation import (
    Candidate,
    Check,
    ContinuationOptions,
    Findings,
    SpecialPoint,
    Verdict,
    confirm,
    equilibria,
    first_lyapunov_coefficient,
    locate_hopf,
    register_verifier,
)
from bifid.errors import BifidInputError, ConvergenceError
from bifid.systems import Parameter, System, get_system


# ----------------------------------------------------------------- the mechanism
@register_verifier("test_zero")
def _verify_test_zero(point, context):
    return Verdict((Check.at_most("value", context["value"](point.param), 1e-9),))


def _point(param: float) -> SpecialPoint:
    return SpecialPoint(
        kind="test_zero",
        param=param,
        index=-1,
        bracket=(param, param),
        solution=np.zeros(1),
        precision=1e-12,
    )


def test_confirm_returns_a_verified_point_or_a_candidate_with_the_reason():
    """Check the three outcomes: verified, not verified (with the failed check), not located."""
    ctx = {"value": lambda x: x - 0.3}
    ok = confirm("test_zero", (0.2, 0.4), lambda: _point(0.3), context=ctx, index=7)
    assert isinstance(ok, SpecialPoint) and ok.status == "converged" and ok.index == 7
    assert ok.verification["value"] == pytest.approx(0.0) and ok.bracket == (0.2, 0.4)
    assert ok.verification["tolerance"]["value"] == 1e-9
    bad = confirm("test_zero", (0.2, 0.4), lambda: _point(0.31), context=ctx)
    assert isinstance(bad, Candidate) and "not verified" in bad.reason and "value" in bad.reason
    far = confirm("test_zero", (0.2, 0.4), lambda: _point(0.9), context={"value": lambda x: 0.0})
    assert isinstance(far, Candidate) and "outside_bracket" in far.reason

    def fails():
        raise ConvergenceError("Newton diverged")

    lost = confirm("test_zero", (0.2, 0.4), fails, context=ctx)
    assert isinstance(lost, Candidate) and "could not be located: Newton diverged" in lost.reason
    inf = _point(0.3)
    inf.data["lyapunov"] = math.inf
    assert isinstance(confirm("test_zero", (0.2, 0.4), lambda: inf, context=ctx), Candidate)


def test_only_verified_points_enter_the_located_list():
    """Check that Findings refuses a point that did not go through confirm()."""
    f = Findings()
    with pytest.raises(BifidInputError, match="verified"):
        f.add(_point(0.3))
    with pytest.raises(BifidInputError, match="no verifier"):
        confirm("no_such_kind", (0, 1), lambda: _point(0.5))
    f.flag("branch_point", (0.1, 0.2), "flagged")
    assert f.points == [] and f.candidates[0].kind == "branch_point"
    ctx = {"value": lambda x: x - 0.3}
    first = f.confirm("test_zero", (0.25, 0.35), lambda: _point(0.3), context=ctx)
    again = f.confirm("test_zero", (0.28, 0.45), lambda: _point(0.3), context=ctx)
    assert f.points == [first] and isinstance(again, Candidate)
    assert "already located at 0.3" in again.reason


# ------------------------------------------------------------- the A -> B reaction
def _ab_field(u, p):
    # AUTO-07p demo "ab" (demos/ab/ab.f90): Da = p[0], B = p[1], beta = p[2]
    e = jnp.exp(u[1])
    return jnp.stack(
        [-u[0] + p[0] * (1 - u[0]) * e, -u[1] + p[0] * p[1] * (1 - u[0]) * e - p[2] * u[1]]
    )


AB = System(
    name="ab_test",
    states=("u1", "u2"),
    parameters=(Parameter("Da", 0.0), Parameter("B", 8.0), Parameter("beta", 3.0)),
    field=_ab_field,
    default_param="Da",
)


def _ab_exact(B: float, beta: float = 3.0):
    """Hopf points (trace J = 0) and folds (dDa/du1 = 0) along u2 = B u1 / (1 + beta)."""
    k = B / (1 + beta)

    def da(u):
        return u * math.exp(-k * u) / (1 - u)

    hopf = sorted(da(u) for u in np.roots([-B, B + 1 + beta, -(2 + beta)]).real if 0 < u < 1)
    disc = k * k - 4 * k
    folds = [] if disc < 0 else sorted(da((k + s * math.sqrt(disc)) / (2 * k)) for s in (-1, 1))
    return hopf, folds


@pytest.mark.parametrize("B", [14.0, 17.0, 18.0])
def test_ab_reports_exactly_the_hopf_points_and_folds_of_the_closed_form(B):
    """Check ab (AUTO demo) in Da over [0, 0.25]: every Hopf point and fold to 1e-9, no
    other located point and no candidate (the spurious omega ~ 0 Hopf points at folds and
    real-eigenvalue collisions are gone)."""
    opts = ContinuationOptions(
        ds=0.005, ds_max=0.0125, ds_min=1e-10, p_min=0.0, p_max=0.25, max_steps=2000
    )
    eq = equilibria(AB, "Da", p=AB.param_vector(B=B), start=0.0, options=opts)
    hopf, folds = _ab_exact(B)
    got_h = sorted(sp.param for sp in eq.special("hopf"))
    got_f = sorted(sp.param for sp in eq.special("fold"))
    assert len(got_h) == len([h for h in hopf if h <= 0.25]) and len(got_f) == len(folds)
    assert np.allclose(got_h, [h for h in hopf if h <= 0.25], rtol=0, atol=1e-9)
    assert np.allclose(got_f, folds, rtol=0, atol=1e-9)
    assert eq.candidates == [] and eq.status == "range"
    for sp in eq.special_points:
        assert sp.status == "converged" and sp.verification
        assert all(v is True for v in [math.isfinite(sp.param), sp.precision < 1e-6])
    for h in eq.special("hopf"):
        assert abs(h.verification["real_part"]) <= h.verification["tolerance"]["real_part"]
        assert h.data["omega"] > 1e-3 and math.isfinite(h.data["lyapunov"])


def test_locate_hopf_at_a_fold_is_refused_not_reported():
    """Check that Newton on the Hopf system started at a fold (where it has the omega = 0
    solution J v = 0) gives an error saying why, not a Hopf point."""
    B = 18.0
    _, folds = _ab_exact(B)  # the first fold has u1 = 2/3, u2 = B u1 / (1 + beta) = 3
    with pytest.raises(ConvergenceError, match="not verified: omega = 0"):
        locate_hopf(
            AB, "Da", np.array([2.0 / 3.0, 3.0]), folds[0], AB.param_vector(B=B), omega_guess=1e-9
        )


def test_first_lyapunov_coefficient_undefined_at_a_zero_eigenvalue():
    """Check a fold-Hopf point (eigenvalues ±i and 0): a ConvergenceError, not inf or a
    LinAlgError."""

    def field(x, p):
        return jnp.stack([-x[1] + x[0] * x[2], x[0] + x[1] * x[2], x[0] ** 2 + x[1] ** 2])

    with pytest.raises(ConvergenceError, match="singular"):
        first_lyapunov_coefficient(field, jnp.zeros(3), jnp.zeros(1), 1.0)


def test_van_der_pol_has_one_hopf_point_not_one_per_eigenvalue_collision():
    """Check the origin of Van der Pol over mu in [-3, 5]: one Hopf point (mu = 0, omega 1);
    the collisions at mu = ±1 (complex pair -> two real eigenvalues) are not Hopf points."""
    s = get_system("vanderpol")
    opts = ContinuationOptions(ds=0.16, ds_max=0.4, ds_min=1e-9, p_min=-3, p_max=5)
    eq = equilibria(s, "mu", start=-3.0, options=opts)
    (h,) = eq.special_points
    assert h.kind == "hopf" and abs(h.param) < 1e-12 and h.data["omega"] == pytest.approx(1.0)
    assert eq.candidates == []
    assert eq.stable[eq.params < -1e-9].all() and not eq.stable[eq.params > 1e-9].any()


# ------------------------------------------------------------------- the driver
def _plp_field(u, p):
    # AUTO-07p demo "plp" (demos/plp/plp.f90): states of order 100
    r = u[0] * u[1] / (1 + u[0] + p[4] * u[0] ** 2)
    return jnp.stack([(p[0] - u[0]) - p[3] * r, p[2] * (p[1] - u[1]) - p[3] * r])


PLP = System(
    name="plp_test",
    states=("s", "a"),
    parameters=(
        Parameter("s0", 110.0),
        Parameter("a0", 500.0),
        Parameter("alpha", 0.2),
        Parameter("rho", 2.021628),
        Parameter("kappa", 0.1),
    ),
    field=_plp_field,
    default_param="rho",
)


def test_tolerances_scale_with_the_state_plp():
    """Check plp (states ~100): the branch converges from AUTO's start to rho = 6 and has
    AUTO's two Hopf points (3.49995, 4.65046, printed to 6 digits)."""
    opts = ContinuationOptions(ds=0.08, ds_max=0.2, ds_min=1e-9, p_min=2.021628, p_max=6.0)
    eq = equilibria(PLP, "rho", x0=np.array([45.55974, 177.7987]), options=opts)
    assert eq.status == "range" and eq.params[-1] == pytest.approx(6.0)
    got = [sp.param for sp in eq.special("hopf")]
    assert np.allclose(got, [3.49995, 4.65046], rtol=0, atol=2e-5)
    assert eq.special("fold") == [] and eq.candidates == []


def _pp2_field(u, p):
    # AUTO-07p demo "pp2" (demos/pp2/pp2.f90): quota = p[0]
    return jnp.stack(
        [
            p[1] * u[0] * (1 - u[0]) - u[0] * u[1] - p[0] * (1 - jnp.exp(-p[2] * u[0])),
            -u[1] + p[3] * u[0] * u[1],
        ]
    )


PP2 = System(
    name="pp2_test",
    states=("fish", "sharks"),
    parameters=(
        Parameter("quota", 0.0),
        Parameter("r", 3.0),
        Parameter("k", 5.0),
        Parameter("c", 3.0),
    ),
    field=_pp2_field,
    default_param="quota",
)


def test_branch_approaching_a_bound_asymptotically_ends_there():
    """Check pp2 without sharks from fish = 1: the fold (AUTO 0.832929), the branch points
    (AUTO 0.821904, 0.6) as candidates only, and the branch ends at the bound 0 that it
    approaches only as fish -> -inf (status "range", never a parameter of 1e-209)."""
    opts = ContinuationOptions(
        ds=0.02, ds_max=0.05, ds_min=1e-9, p_min=0.0, p_max=1.0, max_steps=3000
    )
    eq = equilibria(PP2, "quota", x0=np.array([1.0, 0.0]), options=opts)
    assert eq.status == "range" and 0.0 <= eq.params[-1] <= 1e-8
    (fold,) = eq.special("fold")
    assert fold.param == pytest.approx(0.832929, abs=2e-6) and eq.special("hopf") == []
    bps = sorted(c.bracket for c in eq.candidates)
    assert [c.kind for c in eq.candidates] == ["branch_point"] * 2
    for (a, b), v in zip(bps, (0.6, 0.821904), strict=True):
        assert min(a, b) - 1e-6 <= v <= max(a, b) + 1e-6


@pytest.mark.parametrize("x0", [[1.0], [1.0, np.nan], "a,b"])
def test_bad_starting_guess_is_an_input_error(x0):
    """Check x0 of the wrong length or not finite: BifidInputError naming the states."""
    with pytest.raises(BifidInputError, match="x0"):
        equilibria(PP2, "quota", x0=x0, options=ContinuationOptions(p_min=0.0, p_max=1.0))


def test_a_field_that_fails_or_has_the_wrong_shape_is_an_input_error():
    """Check a user's field that raises, or returns one value per state too many: a
    BifidInputError naming the system, not a traceback from inside the solver."""

    def raising(x, p):
        raise ZeroDivisionError("boom")

    def too_long(x, p):
        return jnp.stack([x[0], x[1], p[0]])

    for field, needle in ((raising, "fails at x0"), (too_long, "must return 2 values")):
        s = System(
            name="bad",
            states=("a", "b"),
            parameters=(Parameter("k", 1.0),),
            field=field,
            default_param="k",
        )
        with pytest.raises(BifidInputError, match=needle):
            equilibria(s, "k", options=ContinuationOptions(p_min=0.0, p_max=2.0))
