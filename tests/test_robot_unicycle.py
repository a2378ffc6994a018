"""Unicycle kinematics and the System I / System II transformations (report eq. 3)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim.robot.unicycle import (
    SystemI,
    SystemII,
    body_velocity,
    chained_rhs,
    s_function,
    unicycle_rhs,
    unicycle_step,
    wheel_speeds,
)


def _poses(n, max_heading, seed=0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.8, 0.8, (n, 2))
    g = rng.uniform(-max_heading, max_heading, (n, 1))
    return jnp.asarray(np.hstack([xy, g]))


@pytest.mark.parametrize("system,max_heading", [(SystemI(), 3.1), (SystemII(), 1.5)])
def test_round_trip(system, max_heading):
    poses = _poses(200, max_heading)
    back = jax.vmap(lambda p: system.to_pose(system.to_chained(p)))(poses)
    np.testing.assert_allclose(back, poses, rtol=0, atol=1e-12)
    x = jax.vmap(system.to_chained)(poses)
    again = jax.vmap(lambda z: system.to_chained(system.to_pose(z)))(x)
    np.testing.assert_allclose(again, x, rtol=1e-12, atol=1e-12)


def test_system_i_matches_eq3():
    x, y, g = 0.3, -0.2, 0.7
    chained = SystemI(length=1.0).to_chained(jnp.array([x, y, g]))
    expected = [x * np.cos(g) + y * np.sin(g), g, x * np.sin(g) - y * np.cos(g)]
    np.testing.assert_allclose(chained, expected, atol=1e-15)


@pytest.mark.parametrize("system,max_heading", [(SystemI(), 3.1), (SystemII(), 1.4)])
def test_input_map_gives_chained_form(system, max_heading):
    """d/dt to_chained(pose) under (v, w) = system.velocity(pose, u) equals (u1, u2, x1 u2)."""
    poses = _poses(50, max_heading, seed=1)
    us = jnp.asarray(np.random.default_rng(2).normal(size=(50, 2)))

    def check(pose, u):
        v, w = system.velocity(pose, u)
        _, xdot = jax.jvp(system.to_chained, (pose,), (unicycle_rhs(pose, v, w),))
        return xdot - chained_rhs(system.to_chained(pose), u)

    np.testing.assert_allclose(jax.vmap(check)(poses, us), 0.0, atol=1e-10)


def test_eq2_identity_of_s():
    """2 ds/dt = x1 u2 - u1 x2 for the chained form (eq. 2)."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        x, u = jnp.asarray(rng.normal(size=3)), jnp.asarray(rng.normal(size=2))
        _, sdot = jax.jvp(s_function, (x,), (chained_rhs(x, u),))
        np.testing.assert_allclose(2 * sdot, x[0] * u[1] - u[0] * x[1], atol=1e-13)


def test_unicycle_step_is_exact_arc():
    pose = jnp.array([0.1, -0.2, 0.4])
    v, w, h = 0.3, 1.7, 0.5
    out = unicycle_step(pose, v, w, h)
    exact = [0.1 + v / w * (np.sin(0.4 + w * h) - np.sin(0.4)),
             -0.2 - v / w * (np.cos(0.4 + w * h) - np.cos(0.4)), 0.4 + w * h]
    np.testing.assert_allclose(out, exact, atol=1e-14)
    straight = unicycle_step(pose, v, 0.0, h)
    np.testing.assert_allclose(straight, [0.1 + v * h * np.cos(0.4),
                                          -0.2 + v * h * np.sin(0.4), 0.4], atol=1e-15)
    g = jax.grad(lambda w: unicycle_step(pose, v, w, h)[1])(0.0)
    assert np.isfinite(g)
    fd = (unicycle_step(pose, v, 1e-6, h)[1] - unicycle_step(pose, v, -1e-6, h)[1]) / 2e-6
    np.testing.assert_allclose(g, fd, rtol=1e-6)


def test_wheel_speeds_round_trip():
    wheels = wheel_speeds(0.2, -1.5, 0.053)
    np.testing.assert_allclose(wheels, [0.2 + 1.5 * 0.0265, 0.2 - 1.5 * 0.0265])
    v, w = body_velocity(wheels, 0.053)
    np.testing.assert_allclose([v, w], [0.2, -1.5], atol=1e-14)


def test_bad_length_raises():
    with pytest.raises(ValueError, match="length"):
        SystemI(length=-1.0)
