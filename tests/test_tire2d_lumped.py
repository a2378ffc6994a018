"""Lumped 2D LuGre (eqs. 35-38): exact aggregation of the PDE and the steady-state gains."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from helpers import assert_grad_matches_fd

from vehsim.params import lugre2d_bakker1987
from vehsim.tire.base import AbstractTire
from vehsim.tire.distributed2d import DistributedLuGre2D, steady_state_mu_2d
from vehsim.tire.load import QuarticLoad, TrapezoidalLoad
from vehsim.tire.lumped2d import LumpedLuGre2D


P = lugre2d_bakker1987()


def test_lumped_equations_are_the_exact_aggregate_of_the_pde():
    """With kappa_i and nu evaluated from a PDE state (their exact eq. 24-type values), the
    lumped right-hand sides and eqs. 36, 38 equal the load-weighted PDE quantities."""
    load = QuarticLoad()  # q(0) = q(1) = 0
    pde = DistributedLuGre2D(P, load, n=32)
    xi = pde.nodes / P.L
    z = jnp.stack([2e-3 * xi * (1.2 - xi), -3e-3 * jnp.sin(1.5 * xi)])
    v_r, c = jnp.array([0.7, -1.1]), jnp.asarray(19.0)
    zdot = pde.derivative(z, v_r, c)
    zbar, zhat = z @ pde.w_q, z[1] @ (pde.w_q * xi)
    # exact gains: kappa_i L = (z(1) q(1) - int z q') / zbar, nu L = (z(1) q(1) - int z q' xi)/zhat
    from vehsim.tire.distributed import _load_weights

    _, w_dq = _load_weights(load, pde.n)
    w_dq = jnp.asarray(w_dq)
    kappa0 = -(z @ w_dq) / zbar
    nu0 = -(z[1] @ (w_dq * xi)) / zhat
    lumped = LumpedLuGre2D(P, load, kappa0=kappa0, nu0=nu0)
    state = jnp.concatenate([zbar, zhat[None]])
    d = lumped.derivative(state, v_r, c)
    np.testing.assert_allclose(d[:2], zdot @ pde.w_q, rtol=1e-10)
    np.testing.assert_allclose(d[2], zdot[1] @ (pde.w_q * xi), rtol=1e-10)
    np.testing.assert_allclose(lumped.mu(state, v_r, c), pde.mu(z, v_r, c), rtol=1e-10)


@eqx.filter_jit
def _lumped_and_closed(lumped, v_r, c):
    def one(v_r, c):
        # steady state of the (linear in the state) lumped ODE: one 3x3 solve
        f = lambda s: lumped.derivative(s, v_r, c)  # noqa: E731
        J = jax.jacfwd(f)(jnp.zeros(3))
        s = jnp.linalg.solve(J, -f(jnp.zeros(3)))
        return lumped.mu(s, v_r, c), steady_state_mu_2d(lumped.params, lumped.load, v_r, c)

    return jax.vmap(one)(v_r, c)


def test_steady_state_gains_reproduce_distributed_steady_state():
    for load in (TrapezoidalLoad(0.25), QuarticLoad()):
        lumped = LumpedLuGre2D(P, load, steady_state_gains=True)
        assert isinstance(lumped, AbstractTire)
        v_r = jnp.array([[1.0, 1.4], [-4.0, 3.0]])
        c = jnp.array([20.0, 16.0])
        got, want = _lumped_and_closed(lumped, v_r, c)
        np.testing.assert_allclose(got, want, rtol=1e-8)


def test_steady_state_gains_towards_lock_in_both_modes():
    """Towards lock the gains' (1 - k Zbar) / (L Zbar) cancelled and a fixed quadrature could
    not resolve the boundary layer: the slope in c was 18 % off at c = 1e-4 m/s, of the
    wrong sign at 1e-6 and NaN at 1e-200. The lumped steady state's Jacobian in (v_r, c),
    reverse and forward, now equals the closed form's (graded quadrature of eq. 31) there,
    and below the transport floor stays finite and equal to the one at 1e-6."""
    for load in (TrapezoidalLoad(0.25), QuarticLoad()):
        lumped = LumpedLuGre2D(P, load, steady_state_gains=True)

        def steady(x):
            v_r, c = x[:2], x[2]
            f = lambda s: lumped.derivative(s, v_r, c)  # noqa: E731
            s = jnp.linalg.solve(jax.jacfwd(f)(jnp.zeros(3)), -f(jnp.zeros(3)))
            return lumped.mu(s, v_r, c)

        def closed(x):
            return steady_state_mu_2d(P, load, x[:2], x[2])

        for c in (1e-2, 1e-4, 1e-6):
            x = jnp.array([-6.0, 1.5, c])
            peer = jax.jacfwd(closed)(x)
            scale = jnp.max(jnp.abs(peer), axis=0, keepdims=True)
            for jac in (jax.jacrev(steady)(x), jax.jacfwd(steady)(x)):
                # (the closed form's own slope in c rounds to ~1e-6 at c = 1e-6)
                np.testing.assert_allclose(jac / scale, peer / scale, rtol=1e-4, atol=1e-6)
        at_floor = jax.jacrev(steady)(jnp.array([-6.0, 1.5, 1e-200]))
        np.testing.assert_allclose(at_floor[:, :2], jax.jacfwd(closed)(x)[:, :2], rtol=1e-6,
                                   atol=1e-12)


def test_lumped_gradients_at_zero_speed():
    lumped = LumpedLuGre2D(P, TrapezoidalLoad(0.25), steady_state_gains=True)
    s = jnp.array([1e-3, -2e-3, -1e-3])

    def f(x):
        return (jnp.sum(lumped.dynamics(s, x[0], x[1], x[2], 0.25, 4000.0))
                + jnp.sum(lumped.forces(s, x[0], x[1], x[2], 0.25, 4000.0)))

    f = jax.jit(f)
    for x in ([0.0, 0.0, 0.0], [6.0, 0.0, 24.0], [6.0, -1.0, 24.0]):
        assert_grad_matches_fd(f, jnp.array(x), rtol=1e-5, atol=1e-5, eps=1e-7)
