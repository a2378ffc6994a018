"""The horizon problem with several RK4 steps per stage (`horizon_problem`'s
``steps_per_stage``): each stage is that many RK4 steps with the road's curvature at their
points and the corridor at their starts and midpoints, and on a stiff planning tire it
follows the car where one step of the stage does not. The reference is diffrax's adaptive
Tsit5 at a tight tolerance on the same right-hand side (eqs. 61-63 in arc length)."""

import diffrax
import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs
from vehsim.drive.horizon import RELAX_STAGES
from vehsim.optimal.curvilinear import spatial_rhs
from vehsim.optimal.primitives import rally_gravel_car


pytestmark = pytest.mark.xdist_group("horizon_steps")

ROAD = vs.CentrelineRoad.from_segments([("straight", 6.0), ("arc", 9.0, 90.0),
                                        ("straight", 30.0)], 2.0)
M, HORIZON, S0 = 10, 20.0, 3.0  # stages of 2 m from 3 m before the arc


@pytest.fixture(scope="module")
def table():
    return vs.RoadTable.from_road(ROAD)


def _state(vx):
    """$X$ (9): 0.2 m left of the centre, heading 0.05 rad off it, drifting (v_y = 0.3 m/s,
    r = 0.4 rad/s), the axles braking and driving a little, steered into the arc."""
    return jnp.array([0.2, 0.05, vx, 0.3, 0.4, -0.02, 0.03, 0.08, 0.0])


def _problem(table, car, S, X=None):
    """The horizon problem of M stages of 2 m from ``X`` (default `_state` at 8 m/s), each
    of ``S`` steps, margin 0.1 m."""
    X = _state(8.0) if X is None else X
    return vs.horizon_problem(table, car, S0, X[:8],
                              jnp.full((M,), float(car.tire.D)), horizon=HORIZON, margin=0.1,
                              steps_per_stage=S)


def _exact(table, car, X, u, k):
    """The stage ``k`` of 2 m integrated by diffrax (Tsit5, rtol 1e-11) with the table's
    curvature at every point."""
    h = HORIZON / M
    term = diffrax.ODETerm(lambda s, x, _: spatial_rhs(car, x, u, table.curvature_at(s)))
    sol = diffrax.diffeqsolve(term, diffrax.Tsit5(), S0 + k * h, S0 + (k + 1) * h, 0.01, X,
                              stepsize_controller=diffrax.PIDController(rtol=1e-11,
                                                                        atol=1e-12),
                              max_steps=100000)
    return sol.ys[-1]


def _rk4(table, car, X, u, s, h, S):
    """``S`` classical RK4 steps of ``h/S`` from arc length ``s``, written out."""
    f = lambda s, x: spatial_rhs(car, x, u, table.curvature_at(s))  # noqa: E731
    d = h / S
    for j in range(S):
        a = s + j * d
        k1 = f(a, X)
        k2 = f(a + d / 2, X + d / 2 * k1)
        k3 = f(a + d / 2, X + d / 2 * k2)
        k4 = f(a + d, X + d * k3)
        X = X + d / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return X


@pytest.mark.parametrize("S", [1, 3])
def test_a_stage_is_its_rk4_steps_with_the_curvature_at_their_points(table, S):
    """Stage 2 (over the straight's end and the arc's start, where the curvature jumps) of
    the problem with ``S`` steps per stage is ``S`` RK4 steps of the stage's length / S,
    each with the curvature at its own start, middle and end, to rounding; and the corridor
    is the road's, less the margin, at the steps' inner starts and at their midpoints, and
    there too widened to hold a start outside it."""
    car = rally_gravel_car()
    # the left edge widening along the road (by 2 cm per m), so that where each bound is
    # read matters
    table = eqx.tree_at(lambda t: t.width_left, table,
                        table.width_left + 0.02 * (table.s - table.s[0]))
    prob = _problem(table, car, S)
    X, u, k = _state(8.0), jnp.array([0.01, -0.02, 0.05]), 2
    h = HORIZON / M
    got = prob.transition(X, u, k)
    want = _rk4(table, car, X, u, S0 + k * h, h, S)
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    starts = S0 + k * h + (h / S) * np.arange(S)
    lo_hi = lambda s: np.stack([  # noqa: E731
        -np.asarray(ROAD.width_right(s)) + 0.1,
        np.asarray(ROAD.width_left(s)) + 0.02 * (s - float(table.s[0])) - 0.1], -1)
    assert prob.corridor_steps.shape == (M, S - 1, 2)
    np.testing.assert_allclose(prob.corridor_steps[k], lo_hi(starts[1:]), atol=1e-12)
    np.testing.assert_allclose(prob.corridor_mid[k], lo_hi(starts + h / (2 * S)), atol=1e-12)
    # from 0.3 m beyond the left edge of the corridor, the first `RELAX_STAGES` stages are
    # widened by that and 5 cm at the start, linearly to nothing at their end: stage 1's
    # steps see it at their own arc lengths
    n0 = float(lo_hi(np.array(S0))[1]) + 0.3
    wide = _problem(table, car, S, _state(8.0).at[0].set(n0))
    starts = S0 + h + (h / S) * np.arange(S)
    widened = lambda s: lo_hi(s) + np.outer(  # noqa: E731
        0.35 * (1.0 - (s - S0) / (RELAX_STAGES * h)), [-1.0, 1.0])
    np.testing.assert_allclose(wide.corridor_steps[1], widened(starts[1:]), atol=1e-12)
    np.testing.assert_allclose(wide.corridor_mid[1], widened(starts + h / (2 * S)),
                               atol=1e-12)


def test_a_stiff_tire_needs_several_steps_per_stage(table):
    """On the tire of the plant's shape (`planner_car`: B about 33, $BCD$ about 26) at 6 m/s
    the lateral modes decay at about 7 per metre, and one RK4 step of a 2 m stage is far
    outside RK4's stability interval: entering the arc with a little counter-drift, the
    stage's end misstates the lateral velocity by more than its exact value. Eight steps of
    0.25 m follow it to 1 mm/s. On the benchmark's gravel tire one step is off by 0.05-0.1
    m/s, four steps by less than 1 mm/s."""
    X = _state(6.0).at[3:5].set(jnp.array([-0.1, 0.2]))
    u, k = jnp.array([0.0, 0.0, 0.02]), 2

    def errors(car, steps):
        exact = _exact(table, car, X, u, k)
        return exact, {S: np.abs(np.asarray(_problem(table, car, S, X).transition(X, u, k)
                                            - exact))[3:5] for S in steps}

    exact, err = errors(vs.planner_car(0.52), (1, 8))
    _, err_gravel = errors(rally_gravel_car(), (1, 4))
    print("v_y, r exact", exact[3:5], "errors: stiff", err, "gravel", err_gravel)
    assert err[1][0] > abs(float(exact[3])) > 0.2  # m/s
    assert np.all(err[8] < 1e-3)
    assert 0.02 < err_gravel[1][0] < 0.1 and np.all(err_gravel[4] < 1e-3)


def test_the_driver_plans_with_its_steps_per_stage(table):
    """`RecedingHorizonDriver.steps_per_stage` reaches its horizon problems, and a count
    below one is refused by name."""
    driver = vs.RecedingHorizonDriver(table=table, steps_per_stage=3)
    prob = driver.problem(0.0, _state(8.0)[:8], jnp.full((driver.num_stages,), 0.52))
    assert prob.steps_per_stage == 3 and prob.curvature.shape == (driver.num_stages, 3, 3)
    with pytest.raises(ValueError, match="steps_per_stage must be an integer >= 1"):
        vs.RecedingHorizonDriver(table=table, steps_per_stage=0)
