"""Distributed 2D LuGre (eqs. 31-34): closed-form steady state, point-model collapse, symmetry."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from helpers import assert_grad_matches_fd

from vehsim.params import lugre2d_bakker1987, table3
from vehsim.tire.distributed2d import (
    DistributedLuGre2D,
    slip_velocities,
    steady_state_forces,
    steady_state_forces as _steady_state_forces,
    steady_state_mu_2d,
    steady_state_mu_2d as _steady_state_mu_2d,
)
from vehsim.tire.load import QuarticLoad, TrapezoidalLoad, UniformLoad
from vehsim.tire.lugre2d import PointLuGre2D
from vehsim.tire.steady_state import steady_state_mu as steady_state_mu_1d


P = lugre2d_bakker1987()
LOADS = (UniformLoad(), TrapezoidalLoad(0.25), QuarticLoad())
SLIPS = ((0.05, 0.05), (-0.2, 0.2), (0.0, 0.01), (0.5, -0.3), (0.01, 0.0))


@eqx.filter_jit
def _discrete_and_closed(model, kappa, alpha):
    def one(k, a):
        v_r, c = slip_velocities(20.0, k, a)
        z = model.steady_state(v_r, c)
        return (model.derivative(z, v_r, c), model.mu(z, v_r, c),
                steady_state_mu_2d(model.params, model.load, v_r, c))

    return jax.vmap(one)(kappa, alpha)


def test_discrete_steady_state_matches_closed_form():
    kappa, alpha = (jnp.array(x) for x in zip(*SLIPS))
    for load in LOADS:
        d, mu, closed = _discrete_and_closed(DistributedLuGre2D(P, load, n=48), kappa, alpha)
        np.testing.assert_allclose(d, 0.0, atol=1e-9)
        np.testing.assert_allclose(mu, closed, rtol=1e-4, atol=1e-8)


def test_closed_form_reduces_to_longitudinal_eq_17():
    """alpha = 0 with the Table 3 parameters on both axes: the x force is eq. 17's."""
    p1 = table3()
    two = jnp.ones(2)
    p2 = type(P)(sigma0=p1.sigma0 * two, sigma1=p1.sigma1 * two, sigma2=p1.sigma2 * two,
                 mu_k=p1.mu_c * two, mu_s=p1.mu_s * two, v_s=p1.v_s, gamma=p1.alpha, L=p1.L)
    for load in LOADS:
        for v, omega in ((20.0, 60.0), (20.0, 72.0), (20.0, 0.0)):
            v_r = jnp.array([omega * 0.3 - v, 0.0])
            mu = jax.jit(steady_state_mu_2d)(p2, load, v_r, jnp.asarray(omega * 0.3))
            np.testing.assert_allclose(mu[0], jax.jit(steady_state_mu_1d)(p1, load, v, omega, 0.3),
                                       rtol=1e-10)
            np.testing.assert_allclose(mu[1:], 0.0, atol=1e-14)


def test_slope_towards_lock_is_eq_17s_in_both_modes():
    """d/d omega of the x force as omega r -> 0 (1e-6 to 1e-14 m/s), reverse and forward,
    equals the longitudinal eq. 17's (its profile regrouped towards lock): the 2D profile
    v_r L / c xi phi(k xi) cancelled, its slope 100 % off by 1e-13. Below `TRANSPORT_FLOOR`
    (1e-200 m/s) the slope is the same, in both modes (a subnormal omega r gave NaN)."""
    p1 = table3()
    two = jnp.ones(2)
    p2 = type(P)(sigma0=p1.sigma0 * two, sigma1=p1.sigma1 * two, sigma2=p1.sigma2 * two,
                 mu_k=p1.mu_c * two, mu_s=p1.mu_s * two, v_s=p1.v_s, gamma=p1.alpha, L=p1.L)
    v, r, load = 20.0, 0.3, UniformLoad()

    def two_d(omega):
        return steady_state_mu_2d(p2, load, jnp.stack([omega * r - v, 0.0 * omega]),
                                  omega * r)[0]

    def one_d(omega):
        return steady_state_mu_1d(p1, load, v, omega, r)

    for wr in (1e-6, 1e-9, 1e-12, 1e-14):
        omega = wr / r
        peer = jax.grad(one_d)(omega)
        np.testing.assert_allclose([jax.grad(two_d)(omega),
                                    jax.jvp(two_d, (omega,), (1.0,))[1]], [peer, peer],
                                   rtol=1e-8)
    peer = jax.grad(one_d)(1e-14 / r)
    np.testing.assert_allclose([jax.grad(two_d)(1e-200 / r),
                                jax.jvp(two_d, (1e-200 / r,), (1.0,))[1]], [peer, peer],
                               rtol=1e-8)
    assert np.isfinite(jax.grad(two_d)(1e-300)) and np.isfinite(two_d(1e-310))


def test_locked_wheel_collapses_to_point_model():
    """omega = 0: no transport, no SAT penalty: every node obeys the point model exactly."""
    point = PointLuGre2D(P)
    for load in LOADS:
        model = DistributedLuGre2D(P, load, n=16)
        z = jnp.stack([jnp.linspace(-1e-3, 2e-3, 17), jnp.linspace(3e-3, 0.0, 17)])
        d = model.dynamics(z, 20.0, -4.0, 0.0, 0.3, 4000.0)
        expect = jax.vmap(lambda zz: point.dynamics(zz, 20.0, -4.0, 0.0, 0.3, 4000.0),
                          in_axes=1, out_axes=1)(z)
        np.testing.assert_allclose(d, expect, rtol=1e-14, atol=1e-14)
        zu = jnp.outer(jnp.array([-1e-3, 2e-3]), jnp.ones(17))
        F = model.forces(zu, 20.0, -4.0, 0.0, 0.3, 4000.0)
        Fp = point.forces(zu[:, 0], 20.0, -4.0, 0.0, 0.3, 4000.0)
        np.testing.assert_allclose(F[:2], Fp[:2], rtol=1e-12)
        # symmetric loads: a uniform deflection has no lever arm
        np.testing.assert_allclose(F[2], 0.0, atol=1e-9)


def test_symmetry_of_steady_state():
    """F_y, M_z odd in alpha; F_x odd in the driving slip s = v_rx/(omega r) at fixed omega."""
    steady_state_forces = jax.jit(_steady_state_forces)
    steady_state_mu_2d = jax.jit(_steady_state_mu_2d)
    for load in LOADS:
        for kappa, alpha in SLIPS:
            f = steady_state_forces(P, load, 20.0, kappa, alpha, 4000.0)
            g = steady_state_forces(P, load, 20.0, kappa, -alpha, 4000.0)
            np.testing.assert_allclose(g[1:], -f[1:], rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(g[0], f[0], rtol=1e-12, atol=1e-9)
        for s, vy in ((0.05, 1.0), (0.3, -2.0)):
            c = jnp.asarray(20.0)
            a = steady_state_mu_2d(P, load, jnp.array([s * c, vy]), c)
            b = steady_state_mu_2d(P, load, jnp.array([-s * c, vy]), c)
            np.testing.assert_allclose(b[0], -a[0], rtol=1e-12)
            np.testing.assert_allclose(b[1:], a[1:], rtol=1e-12)
        # aligning: M_z opposes F_y (force builds up behind the patch centre)
        f = steady_state_forces(P, load, 20.0, 0.0, 0.05, 4000.0)
        assert f[1] > 0 and f[2] < 0


def test_gradients_at_zero_slip_and_zero_speed():
    load = TrapezoidalLoad(0.25)

    def f(x):
        F = steady_state_forces(P, load, 20.0, x[0], x[1], 4000.0)
        return jnp.sum(F * jnp.array([1.0, 1.0, 10.0]))

    assert_grad_matches_fd(jax.jit(f), jnp.zeros(2), rtol=1e-5, atol=1e-6, eps=1e-7)
    model = DistributedLuGre2D(P, load, n=12)
    z = jnp.stack([jnp.linspace(0.0, 1e-3, 13), jnp.linspace(0.0, -2e-3, 13)])

    def g(x):
        d = model.dynamics(z, x[0], x[1], x[2], 0.25, 4000.0)
        return jnp.sum(d) + jnp.sum(model.forces(z, x[0], x[1], x[2], 0.25, 4000.0))

    g = jax.jit(g)
    # zero speed, and exactly zero relative velocity while rolling (omega r = 0.25 * 24 = 6)
    for x in ([0.0, 0.0, 0.0], [6.0, 0.0, 24.0]):
        assert_grad_matches_fd(g, jnp.array(x), rtol=1e-5, atol=1e-5, eps=1e-7)
