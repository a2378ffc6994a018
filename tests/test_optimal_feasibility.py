"""The path between the shooting nodes stays on the road (corner clearance, interior points of
`vehsim.optimal.shooting`), checked by an integration written here: SciPy's DOP853 at tight
tolerances of the half-car from every knot, under the solution's piecewise-linear inputs."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from optimal_cache import M, corner90_min_time, corner90_min_time_nodes_only
from scipy.integrate import solve_ivp

from vehsim.optimal import roads
from vehsim.optimal.shooting import _RK4_B, _dense_weights, _rk4_segment


pytestmark = pytest.mark.xdist_group("corner90_min_time")

POINTS = 20  # evaluation points per segment: those of `violations()` (20 substeps)


def _between_nodes(prim):
    """Largest distance off the road [m] of the car's path, integrated from each knot over its
    segment (tau in [k/M, (k+1)/M], t = tau t_f) with the inputs linear in tau between the
    knots (the knot's inputs plus the segment's rates), sampled at `POINTS` + 1 points."""
    prob, xs, us = prim.problem, np.asarray(prim.solution.xs), np.asarray(prim.solution.us)
    vehicle = prob.vehicle
    f = jax.jit(lambda y, inputs: vehicle.f(y, inputs))
    tf = xs[0, 9]
    worst = 0.0
    for k in range(M):
        tau0 = k / M

        def rhs(tau, y, k=k, tau0=tau0):
            inputs = xs[k, 6:9] + us[k] * (tau - tau0)
            return tf * np.asarray(f(jnp.asarray(y), jnp.asarray(inputs)))

        taus = np.linspace(tau0, (k + 1) / M, POINTS + 1)
        sol = solve_ivp(rhs, (tau0, taus[-1]), xs[k, :6], method="DOP853", t_eval=taus,
                        rtol=1e-10, atol=1e-10)
        assert sol.success
        worst = max(worst, float(prob.road.distance_off_road(sol.y[0], sol.y[1]).max()))
    return worst


@pytest.fixture(scope="module")
def both():
    return corner90_min_time(), corner90_min_time_nodes_only()


def test_path_between_the_nodes_stays_on_the_road(both):
    """With the default corner clearance the path between the nodes leaves the road by less
    than 1 cm (a few mm here, on 30 segments); with the corridor at the nodes only it cuts the
    inner corner by more than 5 cm (about 20 cm here). Both are feasible at the nodes, and the
    clearance costs time. The record reports the same between-node violation as the
    independent integration at the same points (to 0.1 mm: 20 RK4 substeps against DOP853)."""
    cleared, nodes_only = both
    assert cleared.problem.corner_clearance and not nodes_only.problem.corner_clearance
    off_cleared, off_nodes = _between_nodes(cleared), _between_nodes(nodes_only)
    assert off_cleared < 0.01, off_cleared
    assert off_nodes > 0.05, off_nodes
    for prim, off in ((cleared, off_cleared), (nodes_only, off_nodes)):
        assert prim.solution.converged
        v = prim.violations()
        assert v["corridor"] <= 1e-9
        assert v["corridor_between_nodes"] == pytest.approx(off, abs=1e-4)
    assert float(cleared.t_f) > float(nodes_only.t_f)


def test_continuous_extension_of_rk4():
    """`_dense_weights`: RK4's weights at theta = 1, exact (third order) for x' = t^2 at every
    interior fraction, and `_rk4_segment` returns those states with the same end and nodes as
    without them."""
    np.testing.assert_allclose(_dense_weights(1.0), _RK4_B, rtol=0, atol=1e-15)
    assert sum(_dense_weights(0.3)) == pytest.approx(0.3, abs=1e-15)
    rhs = lambda y, u: jnp.stack([y[1] ** 2 * u, jnp.ones(())])  # y = (x, t), x' = u t^2
    y0, h, S, thetas = jnp.array([0.5, 0.2]), 0.25, 3, (1 / 3, 0.5, 0.8)
    end, starts, dense = _rk4_segment(rhs, y0, 2.0, h, S, thetas)
    end0, starts0 = _rk4_segment(rhs, y0, 2.0, h, S)
    np.testing.assert_array_equal(end, end0)
    np.testing.assert_array_equal(starts, starts0)
    assert dense.shape == (S, len(thetas), 2)
    for i in range(S):
        for j, th in enumerate(thetas):
            t = 0.2 + (i + th) * h
            exact = 0.5 + 2.0 * (t**3 - 0.2**3) / 3.0
            assert float(dense[i, j, 0]) == pytest.approx(exact, rel=1e-13)
            assert float(dense[i, j, 1]) == pytest.approx(t, rel=1e-13)


def test_corner_clearance_refuses_a_chord_across_the_corner():
    """Two nodes on the road on either side of corner90's inner corner (8, 8) whose chord
    cuts it: feasible at the nodes, refused by the clearance (here 4 cm); a chord as long
    but clear of the corner passes."""
    from vehsim.optimal.primitives import car_problem, rally_gravel_car

    rd = roads.road("corner90")
    kw = dict(road=rd, objective="min-time", car=rally_gravel_car(), num_stages=2,
              steps_per_stage=1, tf_max=4.0)
    prob = car_problem(**kw)
    a, b = np.array([7.95, 8.03]), np.array([8.03, 7.95])  # the chord passes (7.99, 7.99)
    assert rd.distance_off_road(*((a + b) / 2)) > 0 and rd.on_road(*a) and rd.on_road(*b)

    def between(p, q):
        nodes = jnp.zeros((1, 10)).at[0, :2].set(p)
        return prob._corridor_between(nodes, jnp.zeros(10).at[:2].set(q), None)

    assert float(between(a, b).min()) < 0
    shift = np.array([0.3, 0.3])
    assert float(between(a + shift, b + shift).min()) > 0
    assert car_problem(**kw, corner_clearance=False)._corridor_between(
        jnp.zeros((1, 10)), jnp.zeros(10), None).shape == (0,)


@pytest.mark.parametrize("field, value", [("interior_points", -1), ("interior_points", 9),
                                          ("corner_clearance", 1)])
def test_bad_between_settings_are_refused(field, value):
    from vehsim.optimal.primitives import car_problem, rally_gravel_car

    with pytest.raises((ValueError, TypeError), match=field):
        car_problem("corner90", "min-time", rally_gravel_car(), 10, 1, 4.0,
                    **{field: value})


def test_interior_points_shape_the_stage_constraints():
    """P interior points add the whole corridor at P points of each step; the clearance adds
    the corner constraints at both ends of each of the (P + 1) S chords."""
    from vehsim.optimal.primitives import car_problem, rally_gravel_car

    rd = roads.road("sturn")
    nc, ncorner = rd.num_corridor_constraints, len(rd.corners)
    x = jnp.asarray([0.0, 9.0, 0.0, 8.0, 0.0, 0.0, 0.0, 0.0, 0.0, 5.0])
    u = jnp.zeros(3)
    sizes = {}
    for clear in (False, True):
        for P in (0, 2):
            prob = car_problem(rd, "min-time", rally_gravel_car(), 10, 2, 4.0,
                               corner_clearance=clear, interior_points=P)
            sizes[clear, P] = prob.path_inequality(x, u, 0).shape[0]
    assert sizes[False, 2] - sizes[False, 0] == 2 * 2 * nc
    assert sizes[True, 0] - sizes[False, 0] == 2 * 2 * ncorner
    assert sizes[True, 2] - sizes[False, 2] == 2 * 3 * 2 * ncorner
    assert math.isfinite(float(jnp.sum(prob.path_inequality(x, u, 0))))
