"""Roads, corridor smoothing, validation, and the shooting functions' derivatives."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tests.helpers import assert_grad_matches_fd
from vehsim.optimal.primitives import rally_gravel_car
from vehsim.optimal.roads import (
    SMOOTHING,
    Rect,
    boundary_set,
    corner90,
    make_road,
    road,
    smooth_max,
    sturn,
    uturn,
)
from vehsim.optimal.shooting import ManeuverOCP


def test_smooth_max_is_conservative_and_exact_off_the_diagonal():
    a = jnp.linspace(-1, 1, 401)
    b = 0.3 * jnp.ones_like(a)
    sm = smooth_max(a, b)
    mx = jnp.maximum(a, b)
    assert np.all(np.asarray(sm) <= np.asarray(mx) + 1e-15)
    assert np.max(np.asarray(mx - sm)) <= 0.071 * SMOOTHING
    far = np.abs(np.asarray(a - b)) >= SMOOTHING
    np.testing.assert_allclose(np.asarray(sm)[far], np.asarray(mx)[far], atol=1e-14)
    # C^1 across the band edge
    g = jax.vmap(jax.grad(smooth_max))(jnp.array([0.4 - 1e-9, 0.4 + 1e-9]), jnp.array([0.3, 0.3]))
    np.testing.assert_allclose(g[0], g[1], atol=1e-6)


@pytest.mark.parametrize(
    "make, vertices",
    [(corner90, [(8, 8)]), (uturn, [(-8, 8), (8, 8)]), (sturn, [(-1, -8), (1, 8)])],
)
def test_smooth_corridor_is_inside_the_road(make, vertices):
    rd = make()
    rng = np.random.default_rng(1)
    xmin = min(leg.xmin for leg in rd.legs)
    xmax = max(leg.xmax for leg in rd.legs)
    ymin = min(leg.ymin for leg in rd.legs)
    ymax = max(leg.ymax for leg in rd.legs)
    pts = rng.uniform([xmin, ymin], [xmax, ymax], size=(4000, 2))
    c = np.asarray(jax.vmap(rd.corridor)(jnp.asarray(pts[:, 0]), jnp.asarray(pts[:, 1])))
    feasible = np.all(c >= 0, axis=1)
    on = np.array([rd.on_road(x, y) for x, y in pts])
    assert np.all(on[feasible])  # conservative: smooth-feasible implies on the road
    # and it loses little: road points it excludes are within the smoothing of a corner
    lost = pts[on & ~feasible]
    v = np.asarray(vertices, float)
    d = np.min(np.hypot(lost[:, None, 0] - v[None, :, 0], lost[:, None, 1] - v[None, :, 1]), 1)
    assert np.all(d < SMOOTHING)


def test_road_by_name_and_unknown():
    assert road("corner90").name == "corner90"
    with pytest.raises(ValueError, match="unknown road"):
        road("chicane")


def test_infeasible_roads_are_refused():
    rd = corner90()
    # end box outside the corridor
    with pytest.raises(ValueError, match="off its leg"):
        make_road("bad", rd.legs, rd.outer, rd.corners, rd.start,
                  boundary_set({"y": -5.0, "psi": -math.pi / 2, "yaw_rate": 0.0},
                               {"x": (11.0, 13.0)}, "x"), rd.centreline)
    # start and end on legs that do not connect
    with pytest.raises(ValueError, match="do not touch"):
        make_road("bad", (Rect(-5.0, 5.0, 8.0, 10.0), Rect(8.0, 10.0, -5.0, 10.0)), rd.outer,
                  rd.corners, rd.start, rd.end, rd.centreline)


def test_shooting_functions_gradients_match_finite_differences():
    prob = ManeuverOCP(vehicle=rally_gravel_car(), road=corner90(), num_stages=4,
                       steps_per_stage=2)
    x = jnp.array([2.0, 8.7, -0.2, 9.0, 0.6, -0.8, 0.05, -0.3, -0.2, 3.5])
    u = jnp.array([0.3, -0.5, 0.4])
    rng = np.random.default_rng(0)
    w_F = jnp.asarray(rng.normal(size=10))
    w_h = jnp.asarray(rng.normal(size=prob.path_inequality(x, u, 0).shape[0]))

    def scalar(y):
        F, h = prob.transition_and_path(y[:10], y[10:], 1)
        return w_F @ F + w_h @ h + prob.stage_cost(y[:10], y[10:], 1)

    assert_grad_matches_fd(scalar, jnp.concatenate([x, u]), rtol=1e-5, atol=1e-7)
    assert_grad_matches_fd(lambda y: prob.terminal_inequality(y) @ jnp.arange(
        prob.terminal_inequality(x).shape[0], dtype=float), x, rtol=1e-5, atol=1e-7)
