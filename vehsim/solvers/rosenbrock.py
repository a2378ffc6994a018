r"""A linearly implicit solver for vehicles with stiff wheel-tire blocks: Rosenbrock-W ROS34PW2.

With dynamic tires the stiff part of a vehicle's vector field is local: each wheel's spin
$\omega_i$ and its tire's friction states $z_i$ form a small block (the tire damping
$\sigma_1$ acting through the wheel inertia, $r^2\sigma_1F_z/I_w$, and the bristle decay
$\theta\sigma_0|v_r|/g + \kappa|\omega r|$, both of order $10^3$ 1/s), while the chassis is
not stiff. An explicit solver is held to steps of a millisecond by those blocks. A
Rosenbrock-W method solves, per stage, a linear system with $W = I - \gamma h J$ instead of
a nonlinear one, and keeps its order for *any* $J$ (that is what "W" means); only its
stability depends on how well $J$ captures the stiff directions. Here $J$ is the Jacobian of
the vector field restricted to the stiff blocks (block diagonal, computed per step by as many
forward-mode products as a block has states), zero elsewhere: the chassis is effectively
integrated explicitly, the blocks implicitly, and each stage costs one vector-field
evaluation and one small dense solve per block.

Scheme (Hairer-Wanner form, autonomous W-method; time enters only through the stage times,
which is the W-method of the autonomised system with $\partial f/\partial t$ left out of W):
$$W k_i = h f\Big(t_0 + c_i h,\ y_0 + \sum_{j<i} a_{ij}k_j\Big) + hJ\sum_{j<i}\gamma_{ij}k_j,
  \qquad y_1 = y_0 + \sum_i b_i k_i,$$
with the coefficients of ROS34PW2 (Rang and Angermann, BIT 45 (2005) 761-787): 4 stages,
order 3, L-stable, stiffly accurate, embedded order-2 solution for the error estimate.

When it pays: at loose and moderate accuracy on vehicles with dynamic tires, where it takes
several times fewer steps than an explicit solver held by the stiff blocks. Being of order
3 it needs tight tolerances for high accuracy, where an explicit higher-order solver wins.
Its error estimate understates the global error of the wheel speeds, so choose the
tolerance by the accuracy reached, not by the tolerance's value (measurements and the
variants tried: docs/performance.md).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


_GAMMA = 4.3586652150845900e-01
_A = np.array([
    [0.0, 0.0, 0.0, 0.0],
    [8.7173304301691801e-01, 0.0, 0.0, 0.0],
    [8.4457060015369423e-01, -1.1299064236484185e-01, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
])
_G = np.array([
    [0.0, 0.0, 0.0, 0.0],
    [-8.7173304301691801e-01, 0.0, 0.0, 0.0],
    [-9.0338057013044082e-01, 5.4180672388095326e-02, 0.0, 0.0],
    [2.4212380706095346e-01, -1.2232505839045147e00, 5.4526025533510214e-01, 0.0],
])
_B = np.array([2.4212380706095346e-01, -1.2232505839045147e00, 1.5452602553351020e00,
               4.3586652150845900e-01])
_B_HAT = np.array([3.7810903145819369e-01, -9.6042292212423178e-02, 5.0e-01,
                   2.1793326075422950e-01])
_C = _A.sum(axis=1)


def solve_small(M, b):
    r"""Solve $M x = b$ for a stack of small dense systems by unrolled Gaussian elimination.

    `M`: ``(..., m, m)``, `b`: ``(..., m)``. No pivoting: meant for $W = I - \gamma hJ$ of a
    dissipative block (leading minors positive). Written with elementwise operations so a
    batch of them (`jax.vmap`) vectorises instead of calling LAPACK once per system.
    """
    m = M.shape[-1]
    rows = [M[..., i, :] for i in range(m)]
    rhs = [b[..., i] for i in range(m)]
    for k in range(m):
        for i in range(k + 1, m):
            factor = rows[i][..., k] / rows[k][..., k]
            rows[i] = rows[i] - factor[..., None] * rows[k]
            rhs[i] = rhs[i] - factor * rhs[k]
    x = [None] * m
    for i in reversed(range(m)):
        acc = rhs[i]
        for j in range(i + 1, m):
            acc = acc - rows[i][..., j] * x[j]
        x[i] = acc / rows[i][..., i]
    return jnp.stack(x, axis=-1)


class ROS34PW2(dfx.AbstractAdaptiveSolver):
    r"""Rosenbrock-W method ROS34PW2 with a block-diagonal Jacobian of the stiff states.

    **Arguments:**

    - `blocks`: tuple of index tuples into the (flat, 1D) state, one per stiff block, all of
      the same length (e.g. `HalfCar.stiff_blocks`: each wheel speed with its tire's
      friction states). States in no block are integrated explicitly.
    - `frozen_jacobian`: differentiate the step with $J$ held constant (default `False`:
      the exact derivative of the step). The step's values are the same either way; its
      derivative then leaves out $\partial J/\partial(t_0, y_0, \text{args})$, the
      second derivatives of the vector field that differentiating the Jacobian costs (the
      derivative of the W-method with that $J$ as its approximation, which a W-method
      allows: it differs from the exact step's derivative by the step's sensitivity to its
      Jacobian approximation, of the order of the local error).
    - `unroll_stages`: stages 2-4 written out in sequence rather than as one loop (default
      `False`). The values are the same; as a loop, the vector field and its linearisation
      appear once in the compiled program instead of three times, so programs compile
      faster (the forward-mode derivative of a short closed-loop drive by 17-28 %), while
      batches of adaptive solves run 5-12 % faster unrolled (docs/performance.md).

    Order 3 with an embedded order-2 error estimate (use it with `diffrax.PIDController`);
    per step: one Jacobian-vector product per block column (all blocks at once), four
    vector-field evaluations (one shared with the Jacobian products) and four small solves
    per block. Dense output: cubic Hermite (one more evaluation, at the end of the step).
    """

    blocks: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    frozen_jacobian: bool = eqx.field(static=True, default=False)
    unroll_stages: bool = eqx.field(static=True, default=False)

    term_structure: ClassVar = dfx.AbstractTerm
    interpolation_cls: ClassVar[Callable[..., dfx.ThirdOrderHermitePolynomialInterpolation]] = (
        dfx.ThirdOrderHermitePolynomialInterpolation
    )

    def __check_init__(self):
        sizes = {len(b) for b in self.blocks}
        if len(self.blocks) == 0 or len(sizes) != 1 or 0 in sizes:
            raise ValueError(
                f"ROS34PW2.blocks must be a non-empty tuple of equally long, non-empty index "
                f"tuples, got {self.blocks}"
            )

    def order(self, terms):
        del terms
        return 3

    def error_order(self, terms):
        del terms
        return 3

    def init(self, terms, t0, t1, y0, args):
        del terms, t0, t1, y0, args
        return None

    def func(self, terms, t0, y0, args):
        return terms.vf(t0, y0, args)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        idx = np.asarray(self.blocks)  # (n_blocks, m)
        n_blocks, m = idx.shape
        h = t1 - t0

        def f(t, y):
            return terms.vf(t, y, args)

        # f at the start and its linearisation; the Jacobian used is J = P df/dy (the rows
        # of the stiff states, all columns); its stiff-by-stiff blocks (column j of every
        # block from one product) make W = I - gamma h J block-triangular
        del solver_state, made_jump
        f0, lin = jax.linearize(lambda y: f(t0, y), y0)
        if self.frozen_jacobian:
            # the same linear map (the same operations on the same values), its residuals
            # (the linearisation point's intermediates) constants of the derivatives
            lin_fn, residuals = jax.closure_convert(lin, y0)
            residuals = [jax.lax.stop_gradient(r) for r in residuals]
            lin = lambda v: lin_fn(v, *residuals)  # noqa: E731
        tangents = jnp.zeros((m, y0.shape[0]), y0.dtype)
        for j in range(m):
            tangents = tangents.at[j, idx[:, j]].set(1.0)
        cols = jax.vmap(lin)(tangents)
        J = jnp.moveaxis(cols[:, idx], 0, -1)  # (n_blocks, m, m): d f[idx[b,i]] / d y[idx[b,j]]
        W = jnp.eye(m, dtype=y0.dtype)[None] - _GAMMA * h * J
        stiff = np.zeros(y0.shape[0], bool)
        stiff[idx.ravel()] = True

        # stages 2-4 as one loop (its body, and so the vector field, traced once rather than
        # three times: a smaller program, the same operations on each stage's values;
        # `unroll_stages` writes it out); the first stage's f is f0, from the linearisation
        a, gam, c = jnp.asarray(_A), jnp.asarray(_G), jnp.asarray(_C)

        def stage_k(ks, i, fi):
            rhs = h * fi
            # W k = rhs + h J g, g = sum_j gamma_ij k_j; off the blocks k = h f; on them
            # (I - gamma h J_ss) k_s = h f_s + h J_s (g + gamma k_n)
            k_n = jnp.where(stiff, 0.0, rhs)
            g = sum((gam[i, j] * ks[j] for j in range(4)), start=jnp.zeros_like(y0))
            corr = lin(jnp.where(stiff, 0.0, g) + _GAMMA * k_n)[idx]
            corr = corr + jnp.einsum("bij,bj->bi", J, g[idx])
            k_s = solve_small(W, rhs[idx] + h * corr)
            return ks.at[i].set(k_n.at[idx].set(k_s))

        def stage(ks, i):
            yi = y0 + sum(a[i, j] * ks[j] for j in range(4))
            return stage_k(ks, i, f(t0 + c[i] * h, yi)), None

        ks = stage_k(jnp.zeros((4,) + y0.shape, y0.dtype), 0, f0)
        ks, _ = jax.lax.scan(stage, ks, jnp.arange(1, 4), unroll=self.unroll_stages)
        y1 = y0 + sum(_B[i] * ks[i] for i in range(4))
        y_error = sum((_B[i] - _B_HAT[i]) * ks[i] for i in range(4))
        f1 = f(t1, y1)
        dense_info = dict(y0=y0, y1=y1, k0=h * f0, k1=h * f1)
        return y1, y_error, dense_info, None, dfx.RESULTS.successful
