r"""Distributed longitudinal LuGre model: the PDE of eqs. 11-14 over the contact patch.

$$\frac{\partial z}{\partial t} + |r\omega|\frac{\partial z}{\partial\zeta}
   = v_r - \frac{\theta\sigma_0|v_r|}{g(v_r)}z,\qquad z(0, t) = 0,$$
$$F(t) = \int_0^L\Bigl(\sigma_0 z + \sigma_1\frac{\partial z}{\partial t} + \sigma_2 v_r\Bigr)f_n(\zeta)\,d\zeta
\quad\text{(eq. 13)}.$$

**Discretisation (method of lines).** Chebyshev-Gauss-Lobatto collocation in
$\xi=\zeta/L\in[0,1]$ with $n+1$ nodes clustered at both edges (where the inflow boundary
layer of width $g|r\omega|/(\theta\sigma_0|v_r|)$ sits), spectral accuracy for smooth
profiles, and a stiff implicit integrator in time (the transport eigenvalues scale as
$n^2|r\omega|/L$). The inflow condition $z(0,t)=0$ is imposed weakly, by a
simultaneous-approximation-term penalty $-\tau\,(|r\omega|/L)\,z_0$ on the leading-edge
node: when $\omega = 0$ the penalty vanishes with the transport, so a locked wheel collapses
*exactly* to the point model (report remark after eq. 16). Integrals over the patch use
weights exact for the Chebyshev interpolant times the load shape, split at the load's kinks.

**Reversal of $\omega$ (footnote 2).** The $\zeta$ origin is always the current leading
edge, so the transport speed is $|r\omega|\ge0$ and the inflow is always at $\zeta=0$; as in
the report (and in the lumped and moment models that aggregate it), the profile is not
mirrored at a reversal.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._math import safe_abs
from .load import AbstractLoadDistribution, UniformLoad
from .lugre import AbstractLongitudinalTire, LuGreParams, decay_rate, relative_velocity


def chebyshev_nodes(n: int) -> np.ndarray:
    r"""Chebyshev-Gauss-Lobatto nodes on [0, 1]: $\xi_j = (1-\cos(\pi j/n))/2$."""
    return 0.5 * (1.0 - np.cos(np.pi * np.arange(n + 1) / n))


def chebyshev_differentiation(n: int) -> np.ndarray:
    r"""Matrix $D$ with $(Dz)_i \approx z'(\xi_i)$ on the nodes of `chebyshev_nodes`."""
    x = np.cos(np.pi * np.arange(n + 1) / n)
    c = np.ones(n + 1)
    c[0] = c[-1] = 2.0
    c *= (-1.0) ** np.arange(n + 1)
    dx = x[:, None] - x[None, :]
    D = np.outer(c, 1.0 / c) / (dx + np.eye(n + 1))
    D -= np.diag(D.sum(axis=1))
    return -2.0 * D  # d/dxi = -2 d/dx


def clenshaw_curtis_weights(n: int) -> np.ndarray:
    """Clenshaw-Curtis quadrature weights on [0, 1] for the nodes of `chebyshev_nodes`."""
    theta = np.pi * np.arange(n + 1) / n
    w = np.zeros(n + 1)
    v = np.ones(n - 1)
    if n % 2 == 0:
        w[0] = w[n] = 1.0 / (n**2 - 1)
        for k in range(1, n // 2):
            v -= 2.0 * np.cos(2 * k * theta[1:-1]) / (4 * k**2 - 1)
        v -= np.cos(n * theta[1:-1]) / (n**2 - 1)
    else:
        w[0] = w[n] = 1.0 / n**2
        for k in range(1, (n - 1) // 2 + 1):
            v -= 2.0 * np.cos(2 * k * theta[1:-1]) / (4 * k**2 - 1)
    w[1:-1] = 2.0 * v / n
    return 0.5 * w


def interpolation_matrix(n: int, xi_out: np.ndarray) -> np.ndarray:
    """Barycentric interpolation from the Chebyshev nodes to points ``xi_out``."""
    nodes = chebyshev_nodes(n)
    bw = (-1.0) ** np.arange(n + 1)
    bw[0] *= 0.5
    bw[-1] *= 0.5
    diff = xi_out[:, None] - nodes[None, :]
    exact = np.isclose(diff, 0.0, atol=1e-15)
    diff = np.where(exact, 1.0, diff)
    P = bw / diff
    P /= P.sum(axis=1, keepdims=True)
    rows = exact.any(axis=1)
    P[rows] = exact[rows].astype(float)
    return P


def patch_collocation(owner: str, n) -> tuple[int, Array, Array]:
    """Validated degree ``n``, Chebyshev differentiation matrix $D$ on [0, 1] and the inflow
    penalty $\tau = 1/w_0$ ($w_0$ the Clenshaw-Curtis edge weight) for $n+1$ nodes."""
    if int(n) < 4:
        raise ValueError(f"{owner}.n must be >= 4, got {n}")
    n = int(n)
    D = jnp.asarray(chebyshev_differentiation(n))
    return n, D, jnp.asarray(1.0 / clenshaw_curtis_weights(n)[0])


def _load_weights(load: AbstractLoadDistribution, n: int):
    """Weights w, w' with sum_j w_j z_j = int_0^1 z q dxi and sum_j w'_j z_j = int z q' dxi."""
    xs, ws = load.gauss_points(n + 8)
    P = interpolation_matrix(n, xs)
    q = np.asarray(load.q(jnp.asarray(xs)))
    dq = np.asarray(load.dq(jnp.asarray(xs)))
    return (ws * q) @ P, (ws * dq) @ P


class DistributedLuGre(AbstractLongitudinalTire):
    r"""Distributed LuGre PDE (eqs. 11-14), Chebyshev collocation with $n+1$ nodes.

    The state is the deflection $z$ at the nodes $\zeta_j = L\xi_j$ (shape `(n+1,)`).

    **Arguments:**

    - `params`: `LuGreParams` (uses `L`).
    - `load`: normalised load shape (default `UniformLoad()`).
    - `n`: polynomial degree (default 48; steady states converge spectrally, see
      `vehsim reproduce` for a convergence study).
    """

    params: LuGreParams
    load: AbstractLoadDistribution
    n: int = eqx.field(static=True)
    D: Float[Array, "n1 n1"]
    w_q: Float[Array, " n1"]
    w_dq: Float[Array, " n1"]
    q_end: Float[Array, ""]
    tau: Float[Array, ""]

    def __init__(self, params: LuGreParams, load: AbstractLoadDistribution | None = None, n=48):
        self.params = params
        self.load = UniformLoad() if load is None else load
        self.n, self.D, self.tau = patch_collocation("DistributedLuGre", n)
        w_q, w_dq = _load_weights(self.load, self.n)
        self.w_q = jnp.asarray(w_q)
        self.w_dq = jnp.asarray(w_dq)
        self.q_end = jnp.asarray(self.load.q(jnp.ones(())))

    @property
    def nodes(self) -> Float[Array, " n1"]:
        r"""Node positions $\zeta_j$ [m]."""
        return jnp.asarray(chebyshev_nodes(self.n)) * self.params.L

    def init_state(self):
        return jnp.zeros(self.n + 1)

    def _operator(self, v, omega, r):
        """(a, b): dz/dt = v_r - a z - b (D z + tau e0 z0)."""
        v_r = relative_velocity(v, omega, r)
        return v_r, decay_rate(self.params, v_r), safe_abs(omega * r) / self.params.L

    def dynamics(self, state, v, omega, r):
        v_r, a, b = self._operator(v, omega, r)
        transport = self.D @ state
        transport = transport.at[0].add(self.tau * state[0])
        return v_r - a * state - b * transport

    def mu(self, state, v, omega, r):
        p = self.params
        zdot = self.dynamics(state, v, omega, r)
        return self.w_q @ (p.sigma0 * state + p.sigma1 * zdot) + p.sigma2 * relative_velocity(
            v, omega, r
        )

    def mean_deflection(self, state):
        r"""$\bar z = \frac{1}{F_n}\int_0^L z f_n\,d\zeta$ (eq. 20) [m]."""
        return self.w_q @ state

    def kappa_times_mean_deflection(self, state):
        r"""$\kappa\bar z = \bigl([z q]_0^1 - \int_0^1 z\,q'\,d\xi\bigr)/L$ (eq. 24 times $\bar z$):
        the transport term of eq. 22, finite even where $\bar z$ crosses zero."""
        num = state[-1] * self.q_end - state[0] * self.load.q(jnp.zeros(())) - self.w_dq @ state
        return num / self.params.L

    def kappa(self, state):
        r"""Exact $\kappa(t)$ of eq. 24 [1/m]:
        $\kappa = \bigl([z q]_0^1 - \int_0^1 z\,q'\,d\xi\bigr)/(L\bar z)$ (0 where $\bar z = 0$)."""
        zbar = self.mean_deflection(state)
        num = self.kappa_times_mean_deflection(state)
        is_zero = zbar == 0
        return jnp.where(is_zero, 0.0, num / jnp.where(is_zero, 1.0, zbar))

    def steady_state(self, v, omega, r):
        """Discrete steady state for constant inputs (one linear solve; `steady_state_mu`
        and `braking_mu` use it)."""
        v_r, a, b = self._operator(v, omega, r)
        A = a * jnp.eye(self.n + 1) + b * (self.D.at[0, 0].add(self.tau))
        degenerate = (a == 0) & (b == 0)
        A = jnp.where(degenerate, jnp.eye(self.n + 1), A)
        z = jnp.linalg.solve(A, jnp.full(self.n + 1, v_r))
        return jnp.where(degenerate, 0.0, z)
