"""Point 2D LuGre (eqs. 26-30): reduction to the longitudinal model, friction ellipse, gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import assert_grad_matches_fd, module_grad_matches_fd

from vehsim.params import lugre2d_bakker1987, table3
from vehsim.tire.base import AbstractTire
from vehsim.tire.lugre import PointLuGre, decay_rate, stribeck
from vehsim.tire.lugre2d import (
    LuGre2DParams,
    PointLuGre2D,
    decay_rates,
    relative_velocity_2d,
    slip_angle,
    stribeck_2d,
)


def _isotropic(p1):
    two = jnp.ones(2)
    return LuGre2DParams(sigma0=p1.sigma0 * two, sigma1=p1.sigma1 * two, sigma2=p1.sigma2 * two,
                         mu_k=p1.mu_c * two, mu_s=p1.mu_s * two, v_s=p1.v_s, gamma=p1.alpha,
                         L=p1.L)


def test_isotropic_model_is_the_longitudinal_one():
    """M_k = mu_c I, M_s = mu_s I: g is eq. 10 of |v_r| and C_0 = sigma0 |v_r| / g (eq. 8)."""
    p1 = table3()
    p2 = _isotropic(p1)
    for v_r in ([3.0, 0.0], [-1.0, 2.0], [0.2, -0.1]):
        v_r = jnp.array(v_r)
        speed = jnp.linalg.norm(v_r)
        np.testing.assert_allclose(stribeck_2d(p2, v_r), stribeck(p1, speed), rtol=1e-13)
        np.testing.assert_allclose(decay_rates(p2, v_r), decay_rate(p1, speed) * jnp.ones(2),
                                   rtol=1e-13)
    # pure longitudinal: same state derivative and force as the 1D point model
    m1, m2 = PointLuGre(p1), PointLuGre2D(p2)
    for v, omega in ((20.0, 60.0), (20.0, 70.0), (5.0, 0.0)):
        d2 = m2.dynamics(jnp.array([1e-3, 0.0]), v, 0.0, omega, 0.3, 1.0)
        np.testing.assert_allclose(d2[0], m1.dynamics(1e-3, v, omega, 0.3), rtol=1e-13)
        np.testing.assert_allclose(m2.forces(jnp.array([1e-3, 0.0]), v, 0.0, omega, 0.3, 1.0)[0],
                                   m1.mu(1e-3, v, omega, 0.3), rtol=1e-13)


def test_steady_state_lies_on_the_kinetic_friction_ellipse():
    """Steady sliding z_i = v_ri/C_0i gives sigma0_i z_i = mu_ki^2 g v_ri /
    ||M_k^2 v_r|| with g = ||M_k^2 v_r||/||M_k v_r||, so sum_i (F_i/(F_n mu_ki))^2 = 1."""
    p = lugre2d_bakker1987()
    p = LuGre2DParams(sigma0=p.sigma0, sigma1=p.sigma1, sigma2=jnp.zeros(2), mu_k=p.mu_k,
                      mu_s=p.mu_s, v_s=p.v_s, gamma=p.gamma, L=p.L)
    m = PointLuGre2D(p)
    for phi in np.linspace(0.1, 2 * np.pi, 9):
        v_r = 400.0 * jnp.array([np.cos(phi), np.sin(phi)])
        z = v_r / decay_rates(p, v_r)
        mu = m.mu(z, v_r)
        np.testing.assert_allclose(m.derivative(z, v_r), 0.0, atol=1e-12)
        # exactly: sum_i (F_i/(F_n mu_ki))^2 = (g ||M_k v|| / ||M_k^2 v||)^2, -> 1 when fast
        ratio = stribeck_2d(p, v_r) * jnp.linalg.norm(p.mu_k * v_r) / jnp.linalg.norm(
            p.mu_k**2 * v_r)
        np.testing.assert_allclose(jnp.sum((mu / p.mu_k) ** 2), ratio**2, rtol=1e-12)
        np.testing.assert_allclose(ratio, 1.0, rtol=1e-4)
        assert np.all(np.sign(mu) == np.sign(v_r))  # friction opposes the tread's sliding


def test_interface_signs():
    m = PointLuGre2D(lugre2d_bakker1987())
    assert isinstance(m, AbstractTire)
    np.testing.assert_allclose(relative_velocity_2d(20.0, -1.0, 70.0, 0.3), [1.0, 1.0])
    # a locked wheel sliding forward and to the right: braking force, force to the left
    v_r = relative_velocity_2d(20.0, -3.0, 0.0, 0.3)
    z = v_r / decay_rates(m.params, v_r)  # steady sliding
    F = m.forces(z, 20.0, -3.0, 0.0, 0.3, 4000.0)
    assert F[0] < 0 and F[1] > 0 and F[2] == 0
    assert float(slip_angle(20.0, -3.0)) > 0


def test_gradients_at_zero_relative_velocity_and_zero_speed():
    p = lugre2d_bakker1987()
    m = PointLuGre2D(p)

    def f(x):
        d = m.dynamics(jnp.array([1e-3, -2e-3]), x[0], x[1], x[2], 0.25, 4000.0)
        F = m.forces(jnp.array([1e-3, -2e-3]), x[0], x[1], x[2], 0.25, 4000.0)
        return jnp.sum(d) + jnp.sum(F)

    # zero speed, and zero relative velocity while rolling
    f = jax.jit(f)
    for x in ([0.0, 0.0, 0.0], [6.0, 0.0, 24.0]):
        assert_grad_matches_fd(f, jnp.array(x), rtol=1e-5, atol=1e-6, eps=1e-7)
    # slip angle: atan2 has no derivative at the origin; ours is finite (0) there, exact elsewhere
    g0 = jax.grad(lambda x: slip_angle(x[0], x[1]))(jnp.zeros(2))
    np.testing.assert_array_equal(g0, 0.0)
    assert_grad_matches_fd(lambda x: slip_angle(x[0], x[1]), jnp.array([3.0, -1.0]), rtol=1e-6)
    v_r = jnp.array([0.3, -0.4])
    module_grad_matches_fd(jax.jit(lambda q: jnp.sum(PointLuGre2D(q).mu(jnp.array([1e-3, 2e-3]),
                                                                          v_r))),
                           p, ["sigma0", "mu_k", "mu_s", "v_s", "gamma"], rtol=1e-5)
    g = jax.grad(lambda q: jnp.sum(decay_rates(q, jnp.zeros(2))))(p)
    assert all(np.all(np.isfinite(leaf)) for leaf in jax.tree_util.tree_leaves(g))


@pytest.mark.parametrize(
    "field, value, match",
    [("mu_s", [0.5, 3.0], "mu_k <= mu_s"), ("sigma0", [-1.0, 1.0], "sigma0"),
     ("gamma", 0.0, "gamma"), ("mu_k", [1.0], "last axis of length 2")],
)
def test_bad_parameters_raise(field, value, match):
    kw = dict(sigma0=[1.0, 1.0], sigma1=[0.0, 0.0], sigma2=[0.0, 0.0], mu_k=[0.8, 0.8],
              mu_s=[1.0, 1.0], v_s=1.0, gamma=0.5, L=0.2)
    kw[field] = value
    with pytest.raises(ValueError, match=match):
        LuGre2DParams(**kw)
