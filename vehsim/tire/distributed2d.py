r"""Distributed combined-slip LuGre over a rectangular patch (eqs. 31-34), and its steady state.

$$\frac{\partial z_i}{\partial t} + |\omega r|\frac{\partial z_i}{\partial\zeta}
   = v_{ri} - C_{0i}(v_r)\,z_i,\qquad z_i(t, 0) = 0,\qquad i = x, y\quad\text{(eq. 31a)},$$
$$F_i = \int_0^L\Bigl(\sigma_{0i}z_i + \sigma_{1i}\frac{\partial z_i}{\partial t}
   + \sigma_{2i}v_{ri}\Bigr)f_n\,d\zeta\quad\text{(eqs. 31b-32)},\qquad
  M_z = \int_0^L\Bigl(\sigma_{0y}z_y + \sigma_{1y}\frac{\partial z_y}{\partial t}
   + \sigma_{2y}v_{ry}\Bigr)f_n\Bigl(\frac L2-\zeta\Bigr)d\zeta\quad\text{(eq. 33)},$$
with $C_{0i}$ of eq. 27 and the signs of `vehsim.tire.lugre2d` (forces on the tire,
$F_i = -F_i^\text{report}$). The two components share the transport speed $|\omega r|$ and
are coupled only through $C_{0i}(v_r)$, which is uniform over the patch.

**Discretisation:** exactly that of the longitudinal `DistributedLuGre`, applied to each
component: Chebyshev-Gauss-Lobatto collocation in $\xi = \zeta/L$, the inflow condition
imposed weakly by the SAT penalty $-\tau(|\omega r|/L)z_0$, which vanishes with the transport,
so a locked wheel ($\omega = 0$) collapses *exactly* to `PointLuGre2D` at every node.

**Steady state** (derived as eq. 15): for constant inputs, with $c = |\omega r|$ and
$k_i = C_{0i}L/c$,
$$z_{i,ss}(\xi) = \frac{v_{ri}}{C_{0i}}\bigl(1 - e^{-k_i\xi}\bigr)
  = \frac{v_{ri}L}{c}\,\xi\,\varphi(k_i\xi),\qquad \varphi(x) = \frac{1-e^{-x}}{x},$$
and $z_{i,ss} = v_{ri}/C_{0i}$ for a locked wheel; `steady_state_forces` integrates it
against the load (eqs. 32-33 with $\partial_t z = 0$).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_nonnegative
from .._math import floor_transport, one_minus_exp_over, safe_abs, safe_div
from .distributed import (
    chebyshev_nodes,
    interpolation_matrix,
    patch_collocation,
)
from .load import AbstractLoadDistribution, UniformLoad
from .lugre2d import AbstractPatchLuGre2D, LuGre2DParams, decay_rates
from .steady_state import graded_edges


def lever_moment(load: AbstractLoadDistribution):
    r"""$\int_0^1 q(\xi)(1/2 - \xi)\,d\xi$: the load's centre of pressure ahead of the patch centre
    (in units of $L$); zero for loads symmetric about the centre."""
    xs, ws = load.gauss_points(16)
    return jnp.sum(jnp.asarray(ws * (0.5 - xs)) * load.q(jnp.asarray(xs)))


class DistributedLuGre2D(AbstractPatchLuGre2D):
    r"""Distributed 2D LuGre PDE (eqs. 31-34), Chebyshev collocation with $n+1$ nodes per axis.

    State: deflections $z_i(\zeta_j)$, shape `(2, n+1)` (rows $x$, $y$; $\zeta_j = L\xi_j$).

    **Arguments:**

    - `params`: `LuGre2DParams`.
    - `load`: normalised load shape $q$ with $f_n = F_nq(\zeta/L)/L$ (default uniform).
    - `n`: polynomial degree (default 48).
    """

    params: LuGre2DParams
    load: AbstractLoadDistribution
    n: int = eqx.field(static=True)
    D: Float[Array, "n1 n1"]
    w_q: Float[Array, " n1"]
    w_m: Float[Array, " n1"]
    lever: Float[Array, ""]
    tau: Float[Array, ""]

    def __init__(self, params: LuGre2DParams, load: AbstractLoadDistribution | None = None,
                 n: int = 48):
        self.params = params
        self.load = UniformLoad() if load is None else load
        self.n, self.D, self.tau = patch_collocation("DistributedLuGre2D", n)
        xs, ws = self.load.gauss_points(self.n + 8)
        P = interpolation_matrix(self.n, xs)
        q = np.asarray(self.load.q(jnp.asarray(xs)))
        self.w_q = jnp.asarray((ws * q) @ P)
        self.w_m = jnp.asarray((ws * q * (0.5 - xs)) @ P)
        self.lever = lever_moment(self.load)

    @property
    def nodes(self) -> Float[Array, " n1"]:
        r"""Node positions $\zeta_j$ [m]."""
        return jnp.asarray(chebyshev_nodes(self.n)) * self.params.L

    def init_state(self):
        return jnp.zeros((2, self.n + 1))

    def derivative(self, state, v_r, c):
        r"""$\partial_t z$ for relative velocity `v_r` and transport speed $c = |\omega r|$."""
        C0 = decay_rates(self.params, v_r)
        b = c / self.params.L
        transport = state @ self.D.T
        transport = transport.at[:, 0].add(self.tau * state[:, 0])
        return v_r[:, None] - C0[:, None] * state - b * transport

    def mu(self, state, v_r, c):
        r"""$(F_x/F_n, F_y/F_n, M_z/(F_nL))$ for the given state and inputs."""
        p = self.params
        zdot = self.derivative(state, v_r, c)
        integrand = p.sigma0[:, None] * state + p.sigma1[:, None] * zdot
        f = integrand @ self.w_q + p.sigma2 * v_r
        m = integrand[1] @ self.w_m + p.sigma2[1] * v_r[1] * self.lever
        return jnp.stack([f[0], f[1], m])

    def steady_state(self, v_r, c):
        """Discrete steady state for constant inputs (one linear solve per axis)."""
        C0 = decay_rates(self.params, v_r)
        b = c / self.params.L
        T = self.D.at[0, 0].add(self.tau)
        eye = jnp.eye(self.n + 1)

        def solve(a, vri):
            degenerate = (a == 0) & (b == 0)
            A = jnp.where(degenerate, eye, a * eye + b * T)
            z = jnp.linalg.solve(A, jnp.full(self.n + 1, vri))
            return jnp.where(degenerate, 0.0, z)

        return jnp.stack([solve(C0[0], v_r[0]), solve(C0[1], v_r[1])])


_GL_X, _GL_W = np.polynomial.legendre.leggauss(40)


def steady_state_profile(params: LuGre2DParams, xi, v_r, c):
    r"""$z_{i,ss}(\xi)$ (eq. 15 analogue, module docstring) at 1-D `xi`, shape `(N, 2)`."""
    C0 = decay_rates(params, v_r)
    rolling = c > 0
    c_safe = jnp.where(rolling, c, 1.0)
    k = _layer_rates(C0, params.L, c_safe)
    large = (k > 1.0)[None, :]
    xi = jnp.asarray(xi).reshape(-1, 1)
    z_lock = jnp.broadcast_to(safe_div(v_r, C0)[None, :], (xi.shape[0], 2))
    # towards lock (k > 1) v_r L / c xi phi(k xi) regrouped as v_r / C0 (1 - exp(-k xi)):
    # the same values, and derivatives free of the 1/c cancelling a small phi
    c_small = jnp.where(large, 1.0, c_safe)
    k_small = C0[None, :] * params.L / c_small
    z_small = v_r[None, :] * params.L / c_small * xi * one_minus_exp_over(k_small * xi)
    z_roll = jnp.where(large, z_lock * -jnp.expm1(-k[None, :] * xi), z_small)
    return jnp.where(rolling, z_roll, z_lock)


def _layer_rates(C0, L, c):
    """$k_i = C_{0,i}L/c$ with $c$ floored by `floor_transport`."""
    return C0 * L / floor_transport(c)


def graded_nodes(load: AbstractLoadDistribution, k, gx, gw):
    r"""Nodes and weights on $[0, 1]$ of the Gauss rule `gx`, `gw` (on $[-1, 1]$) on panels
    split at the load's kinks and graded to the leading-edge boundary layers of the rates
    `k` (`graded_edges`), so that an integrand such as $e^{-k_i\xi}q(\xi)$ is resolved at
    any slip."""
    edges = graded_edges(load, *jnp.atleast_1d(k))
    a, b = edges[:-1, None], edges[1:, None]
    gx, gw = jnp.asarray(gx)[None, :], jnp.asarray(gw)[None, :]
    return (0.5 * (b - a) * gx + 0.5 * (a + b)).reshape(-1), (0.5 * (b - a) * gw).reshape(-1)


def steady_state_mu_2d(params: LuGre2DParams, load: AbstractLoadDistribution, v_r, c):
    r"""Closed-form steady state $(F_x/F_n, F_y/F_n, M_z/(F_nL))$ of eqs. 31-33.

    Gauss-Legendre quadrature of $z_{ss}q$ on panels split at the load's kinks and graded to
    the leading-edge boundary layers of thickness $1/k_i$, so that they are resolved at any
    slip. The 2D counterpart of `vehsim.tire.steady_state.steady_state_mu`. `v_r` is the
    pair $(v_{r,x}, v_{r,y})$ (batches: `jax.vmap`); a NaN transport speed `c` gives NaN.
    """
    if jnp.shape(v_r) != (2,):
        raise ValueError("steady_state_mu_2d: v_r must have shape (2,), the longitudinal and "
                         f"lateral relative velocity, got shape {jnp.shape(v_r)}")
    C0 = decay_rates(params, v_r)
    c_safe = jnp.where(c > 0, c, 1.0)
    k = _layer_rates(C0, params.L, c_safe)
    xi, w = graded_nodes(load, k, _GL_X, _GL_W)
    z = steady_state_profile(params, xi, v_r, c)
    wq = w * load.q(xi)
    f = params.sigma0 * (wq @ z) + params.sigma2 * v_r
    m = params.sigma0[1] * ((wq * (0.5 - xi)) @ z[:, 1]) + params.sigma2[1] * v_r[1] * (
        wq @ (0.5 - xi)
    )
    # c > 0 is False for a NaN c, which would otherwise read as the locked wheel's c = 0
    return jnp.where(jnp.isnan(c), jnp.nan, jnp.stack([f[0], f[1], m]))


def slip_velocities(v, kappa, alpha):
    r"""Relative velocity and transport speed for speed $v$, longitudinal slip $\kappa$ and
    slip angle $\alpha$: $v_x = v\cos\alpha$, $\omega r = v_x(1+\kappa)$, so
    $v_r = (\kappa v\cos\alpha,\; v\sin\alpha)$ and $c = |\omega r|$."""
    vx = v * jnp.cos(alpha)
    wr = vx * (1.0 + kappa)
    return jnp.stack([wr - vx, v * jnp.sin(alpha)]), safe_abs(wr)


def steady_state_forces(params: LuGre2DParams, load: AbstractLoadDistribution, v, kappa, alpha,
                        Fz):
    r"""Steady $(F_x, F_y, M_z)$ [N, N, N m] at speed $v$ [m/s], slip ratio $\kappa$ and slip
    angle $\alpha$ [rad] (the curves of Figs. 13-15); the load `Fz` [N] >= 0."""
    check_nonnegative("steady_state_forces", "Fz", Fz)
    v_r, c = slip_velocities(v, kappa, alpha)
    mu = steady_state_mu_2d(params, load, v_r, c)
    return Fz * mu * jnp.stack([jnp.ones(()), jnp.ones(()), params.L])
