"""The structured interior-point solver on problems with known answers."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim import RESULTS
from vehsim.optimal.ip import AbstractStagewiseNLP, IPOptions, interior_point
from vehsim.optimal.ip.block_tridiagonal import block_factor, block_matvec, block_solve


class RestToRest(AbstractStagewiseNLP):
    """Point mass, friction circle |a| <= amax, from rest at 0 to rest at (L, 0), free t_f.

    Bang-bang optimum t_f = 2 sqrt(L / amax); with an even number of piecewise-constant
    segments the switch falls on a knot and the discrete optimum is exact."""

    num_stages: int = eqx.field(static=True)
    state_size: int = eqx.field(static=True, default=5)
    control_size: int = eqx.field(static=True, default=2)
    L: jax.Array = eqx.field(converter=jnp.asarray, default=10.0)
    amax: jax.Array = eqx.field(converter=jnp.asarray, default=5.0)

    def transition(self, x, u, k):
        h = x[4] / self.num_stages
        p = x[:2] + h * x[2:4] + 0.5 * h**2 * u
        v = x[2:4] + h * u
        return jnp.concatenate([p, v, x[4:]])

    def terminal_cost(self, x):
        return x[4]

    def path_inequality(self, x, u, k):
        return jnp.stack([self.amax**2 - u @ u, x[4] - 0.1])

    def initial_equality(self, x):
        return x[:4]

    def terminal_equality(self, x):
        return jnp.stack([x[0] - self.L, x[1], x[2], x[3]])


def _guess(M, L=10.0):
    xs0 = jnp.zeros((M + 1, 5)).at[:, 0].set(jnp.linspace(0, L, M + 1))
    xs0 = xs0.at[:, 4].set(5.0).at[:, 2].set(2.0)
    return xs0, jnp.zeros((M, 2))


@pytest.fixture(scope="module")
def bang_bang():
    M = 12
    prob = RestToRest(num_stages=M)
    return prob, interior_point(prob, *_guess(M))


def test_bang_bang_min_time_matches_analytic(bang_bang):
    prob, sol = bang_bang
    assert sol.result == RESULTS.successful
    t_exact = 2 * np.sqrt(10.0 / 5.0)
    assert abs(float(sol.xs[-1, 4]) - t_exact) < 1e-6
    # bang-bang: full acceleration, then full braking, along x
    a = np.asarray(sol.us[:, 0])
    np.testing.assert_allclose(a[:6], 5.0, atol=1e-3)
    np.testing.assert_allclose(a[6:], -5.0, atol=1e-3)
    assert float(sol.inf_pr) < 1e-9


def test_batch_by_vmap_and_result(bang_bang):
    prob, _ = bang_bang
    amax = jnp.array([5.0, 2.5])
    xs0, us0 = _guess(prob.num_stages)

    def solve(a):
        p = eqx.tree_at(lambda q: q.amax, prob, a)
        return interior_point(p, xs0, us0, IPOptions(max_iter=60), throw=False)

    sols = jax.vmap(solve)(amax)
    assert np.all(np.asarray(sols.converged))
    np.testing.assert_allclose(sols.xs[:, -1, 4], 2 * np.sqrt(10.0 / amax), atol=1e-6)


def test_iteration_limit_reports_result_and_residuals(bang_bang):
    prob, _ = bang_bang
    xs0, us0 = _guess(prob.num_stages)
    sol = interior_point(prob, xs0, us0, IPOptions(max_iter=3), throw=False)
    assert sol.result == RESULTS.ip_max_iterations and not sol.converged
    assert int(sol.iterations) == 3
    assert float(sol.inf_pr) > 1e-6 and np.isfinite(float(sol.inf_du))
    with pytest.raises(RuntimeError, match="inf_pr="):
        interior_point(prob, xs0, us0, IPOptions(max_iter=3))


def test_block_tridiagonal_solve_matches_dense():
    nx, nu, ne, M = 3, 2, 2, 4
    nb = 2 * nx + nu + ne
    rng = np.random.default_rng(0)
    Kd = rng.normal(size=(M + 1, nb, nb))
    Kd = Kd + Kd.transpose(0, 2, 1)
    Kd[:, :nx, :nx] += np.diag(np.logspace(-6, 8, nx))  # graded pivots
    N = (M + 1) * nb
    K = np.zeros((N, N))
    for k in range(M + 1):
        K[k * nb:(k + 1) * nb, k * nb:(k + 1) * nb] = Kd[k]
        if k < M:
            for i in range(nx):
                r, c = (k + 1) * nb + i, k * nb + nx + nu + i
                K[r, c] = K[c, r] = 1.0
    rhs = rng.normal(size=(M + 1, nb))
    W, V, neg, _ = block_factor(jnp.asarray(Kd), nx, nu)
    sol = np.asarray(block_solve(W, V, jnp.asarray(rhs), nx, nu))
    ref = np.linalg.solve(K, rhs.reshape(-1))
    np.testing.assert_allclose(sol.reshape(-1), ref, rtol=1e-7, atol=1e-9)
    assert int(neg) == int(np.sum(np.linalg.eigvalsh(K) < 0))  # Sylvester inertia
    np.testing.assert_allclose(
        np.asarray(block_matvec(jnp.asarray(Kd), jnp.asarray(sol), nx, nu)).reshape(-1),
        K @ sol.reshape(-1), rtol=1e-9, atol=1e-9,
    )
