r"""Aggregate dynamics of the distributed 2D LuGre model by the method of moments (eqs. 39-48).

In $\xi = \zeta/L$ the moments of eq. 39 over a piece $[a, b]\subset[0, 1]$ are
$m^{ab}_{p,i}(t) = \int_a^b z_i(t,\xi)\,\xi^p\,d\xi$ and, since $v_r$, $C_{0i}$ and the
transport speed $c = |\omega r|$ are uniform over the patch, eq. 31a integrated by parts gives
the recursion of eqs. 41-42 ($p\ge0$, the last term absent for $p=0$):
$$\dot m^{ab}_{p,i} = \frac{b^{p+1}-a^{p+1}}{p+1}v_{ri} - C_{0i}m^{ab}_{p,i}
  - \frac cL\bigl(z_i(t,b)\,b^p - z_i(t,a)\,a^p\bigr) + \frac cL\,p\,m^{ab}_{p-1,i}.$$
A load that is polynomial on pieces, $q(\xi) = \sum_k c^{(j)}_k\xi^k$ on $[e_j, e_{j+1}]$
(eq. 43; one piece for uniform, quartic or any `PolynomialLoad`, three for the trapezoid),
gives the forces and moment exactly in terms of the moments (eqs. 46, 48, our sign):
$$\frac{F_i}{F_n} = \sum_j\sum_k c^{(j)}_k\bigl(\sigma_{0i}m^{(j)}_{k,i}
  + \sigma_{1i}\dot m^{(j)}_{k,i}\bigr) + \sigma_{2i}v_{ri},$$
$$\frac{M_z}{F_nL} = \sum_j\sum_k c^{(j)}_k\Bigl(\sigma_{0y}
  \bigl(\tfrac12m^{(j)}_{k,y} - m^{(j)}_{k+1,y}\bigr)
  + \sigma_{1y}\bigl(\tfrac12\dot m^{(j)}_{k,y} - \dot m^{(j)}_{k+1,y}\bigr)\Bigr)
  + \sigma_{2y}v_{ry}\int_0^1q\,(\tfrac12-\xi)\,d\xi .$$
So moments up to degree $m+1$ per piece are needed, and the recursion is closed *except*
for the boundary values $z_i(t, e_j)$ at the piece edges.

**The boundary terms (eqs. 41-42).** At the leading edge $z(t,0) = 0$. At an edge $e>0$ (an
interface or the trailing edge $e=1$) the value is found by the characteristic argument. The
PDE is transport at speed $c/L$ of a point-model ODE whose coefficients do not depend on
$\xi$; let $s(t) = \int_0^t c/L$ be the distance travelled by the tread since $t=0$.

1. While $s(t) < e$ the tread at $e$ was already in the patch at $t=0$. If the initial
   deflection is uniform (e.g. zero, or a locked wheel's state) it has since obeyed
   exactly the point model $\dot w = v_r - C_0(v_r)w$, so $z(t,e) = w(t)$. We carry $w$
   (2 states) and $s$ (1 state): **exact**.
2. Once $s(t)\ge e$ the tread at $e$ entered at the leading edge at time $t_e$ with
   $s(t)-s(t_e) = e$, and $z(t,e) = \int_{t_e}^t e^{-\int_\tau^tC_0}v_r(\tau)\,d\tau$ - a
   *delayed* functional of the inputs. No finite set of moments determines it for
   arbitrary input histories (with $C_0 = 0$ the trailing edge obeys
   $\dot z(t,1) = v_r(t) - v_r(t_e)$, a delay equation), so a finite moment system cannot be
   exact for every input. We use the value along the characteristic with the inputs frozen
   at their current values,
   $z(t,e) = \frac{v_rL}{c}\,e\,\varphi\bigl(\tfrac{C_0L}{c}e\bigr)$, $\varphi(x) = (1-e^{-x})/x$,
   which is **exact whenever the inputs have been constant for the last transit time**
   $eL/c$ (so exact for step inputs - the transients of Fig. 17 - and at every steady
   state), with an error of order (transit time) x (input rate) otherwise. For step inputs
   cases 1 and 2 agree at the switch $s = e$, so the right-hand side is continuous.

Loads that vanish at the trailing edge (quartic, trapezoid) do not escape this: the force
combination $\sum_kc_km_k$ has no trailing-edge term, but the chain $q\to q'\to\dots\to$ const
of lower moments it needs ends in $m_0$, whose equation (42) carries $z(t,1)$.

**Accuracy, measured** (`tests/test_moments.py`, `experiments/benchmarks/moments_vs_pde.py`):
for a slip step from an undeflected patch the moments agree with a fine-grid PDE to its own
accuracy (< 2e-4 relative for the uniform load, ~1e-5 for trapezoid and quartic, shrinking
with the ODE tolerance) and reach the closed-form steady state to 1e-6. For inputs that
change while a tread element crosses the patch (a slip-angle ramp over one transit time)
the frozen closure is wrong by O(1) at the trailing edge for about one transit time, and
the monomial moments amplify that error (the load coefficients $c_k$ alternate in sign and
are large: $\sum|c_k| \approx 100$ for the quartic), so the forces can be wrong by more
than 100 % for a while; they return to the exact steady state once the inputs settle.
**True exactness for arbitrary input histories is impossible with finitely many states**;
use `DistributedLuGre2D` for fast, non-step transients.

State: `(m, w, s)` with moments `m` of shape `(2, pieces, m+2)`, the point-model deflection
`w` (2,) and the travelled distance `s` (in patch lengths).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._math import one_minus_exp_over, safe_abs
from .base import AbstractTire
from .load import AbstractLoadDistribution, PolynomialLoad, TrapezoidalLoad, UniformLoad
from .lugre2d import LuGre2DParams, decay_rates, relative_velocity_2d


def piecewise_coefficients(load: AbstractLoadDistribution, degree: int | None = None):
    r"""Edges $0 = e_0 < \dots < e_P = 1$ and monomial coefficients $c^{(j)}_k$ (in global
    $\xi$) with $q(\xi) = \sum_kc^{(j)}_k\xi^k$ on $[e_j, e_{j+1}]$.

    Exact for `PolynomialLoad` (uniform, quartic, user polynomials) and `TrapezoidalLoad`
    (differentiable in the ramp). Any other load needs `degree`: each piece between its
    kinks is interpolated at `degree + 1` Chebyshev points (the Taylor-type approximation of
    eq. 43), and the moment model is then exact for that interpolant.

    **Returns:** `(edges (P+1,), coeffs (P, K))`.
    """
    if isinstance(load, PolynomialLoad):
        c = load.coefficients
        if degree is not None and degree + 1 > c.shape[0]:
            c = jnp.concatenate([c, jnp.zeros(degree + 1 - c.shape[0])])
        return jnp.array([0.0, 1.0]), c[None, :]
    if isinstance(load, TrapezoidalLoad):
        eps = load.ramp
        h = 1.0 / (1.0 - eps)
        zero = jnp.zeros(())
        coeffs = jnp.stack([
            jnp.stack([zero, h / eps]),
            jnp.stack([h, zero]),
            jnp.stack([h / eps, -h / eps]),
        ])
        edges = jnp.stack([zero, eps, 1.0 - eps, jnp.ones(())])
        return edges, coeffs
    if degree is None:
        raise ValueError(
            f"MomentLuGre2D.degree is required for a {type(load).__name__} (a load that is not "
            "piecewise polynomial): give the polynomial degree per piece, >= 0"
        )
    if int(degree) < 0:
        raise ValueError(f"MomentLuGre2D.degree must be >= 0, got {degree}")
    edges = np.unique(np.concatenate([[0.0, 1.0], np.asarray(load.kinks(), dtype=float)]))
    coeffs = []
    for a, b in zip(edges[:-1], edges[1:]):
        t = np.cos(np.pi * (np.arange(degree + 1) + 0.5) / (degree + 1))
        x = 0.5 * (a + b) + 0.5 * (b - a) * t
        V = np.vander(x, degree + 1, increasing=True)
        coeffs.append(np.linalg.solve(V, np.asarray(load.q(jnp.asarray(x)))))
    return jnp.asarray(edges), jnp.asarray(np.stack(coeffs))


def _powers(x, K):
    """x**k for k = 0..K-1 along a new last axis (integer powers: finite gradients at 0)."""
    return jnp.stack([jnp.ones_like(x)] + [x**k for k in range(1, K)], axis=-1)


class MomentLuGre2D(AbstractTire):
    r"""Method-of-moments model of the distributed 2D LuGre tire (eqs. 39-48).

    See the module docstring for the equations and for when the moment system is exact.

    **Arguments:**

    - `params`: `LuGre2DParams`.
    - `load`: normalised load shape (default uniform); polynomial and trapezoidal loads are
      represented exactly.
    - `degree`: polynomial degree per piece for other loads (see `piecewise_coefficients`).
    """

    params: LuGre2DParams
    load: AbstractLoadDistribution
    edges: Float[Array, " P1"]
    coeffs: Float[Array, "P K"]
    lever: Float[Array, ""]
    n_moments: int = eqx.field(static=True)

    def __init__(self, params: LuGre2DParams, load: AbstractLoadDistribution | None = None,
                 degree: int | None = None):
        self.params = params
        self.load = UniformLoad() if load is None else load
        self.edges, self.coeffs = piecewise_coefficients(self.load, degree)
        self.n_moments = int(self.coeffs.shape[1]) + 1
        # int_0^1 q (1/2 - xi) dxi from the piece coefficients (exact, differentiable).
        K = self.coeffs.shape[1]
        a, b = self.edges[:-1], self.edges[1:]
        ints = (_powers(b, K + 2)[:, 1:] - _powers(a, K + 2)[:, 1:]) / jnp.arange(1, K + 2)[None, :]
        self.lever = jnp.sum(self.coeffs * (0.5 * ints[:, :K] - ints[:, 1:]))

    @property
    def pieces(self) -> int:
        return int(self.coeffs.shape[0])

    def init_state(self, z0=None):
        r"""Moments of the uniform deflection `z0` (default 0), shape (2,) [m]."""
        z0 = jnp.zeros(2) if z0 is None else jnp.asarray(z0, dtype=float)
        K = self.n_moments
        a, b = self.edges[:-1], self.edges[1:]
        k = jnp.arange(1, K + 1)
        ints = (_powers(b, K + 1)[:, 1:] - _powers(a, K + 1)[:, 1:]) / k[None, :]
        return (z0[:, None, None] * ints[None, :, :], z0, jnp.zeros(()))

    def edge_values(self, state, v_r, c):
        r"""$z_i(t, e_j)$ at every piece edge, shape `(2, P+1)` (module docstring, cases 1-2)."""
        _, w, s = state
        C0 = decay_rates(self.params, v_r)
        rolling = c > 0
        c_safe = jnp.where(rolling, c, 1.0)
        e = self.edges[None, :]
        frozen = (v_r * self.params.L / c_safe)[:, None] * e * one_minus_exp_over(
            (C0 * self.params.L / c_safe)[:, None] * e
        )
        inside = (s < self.edges)[None, :]
        z = jnp.where(inside, w[:, None], frozen)
        return z.at[:, 0].set(0.0)

    def derivative(self, state, v_r, c):
        r"""Time derivative of `(m, w, s)` (eqs. 41-42 plus the boundary states)."""
        m, w, _ = state
        K = self.n_moments
        C0 = decay_rates(self.params, v_r)
        b_rate = c / self.params.L
        a, b = self.edges[:-1], self.edges[1:]
        pa, pb = _powers(a, K + 1), _powers(b, K + 1)
        k = jnp.arange(1, K + 1)
        ints = (pb[:, 1:] - pa[:, 1:]) / k[None, :]
        zedge = self.edge_values(state, v_r, c)
        boundary = zedge[:, 1:, None] * pb[None, :, :K] - zedge[:, :-1, None] * pa[None, :, :K]
        p = jnp.arange(K)
        lower = jnp.concatenate([jnp.zeros_like(m[..., :1]), m[..., :-1]], axis=-1)
        m_dot = (
            v_r[:, None, None] * ints[None, :, :]
            - C0[:, None, None] * m
            - b_rate * boundary
            + b_rate * p[None, None, :] * lower
        )
        w_dot = v_r - C0 * w
        return (m_dot, w_dot, b_rate)

    def mu(self, state, v_r, c):
        r"""$(F_x/F_n, F_y/F_n, M_z/(F_nL))$ (eqs. 46 and 48, our sign)."""
        p = self.params
        m = state[0]
        m_dot = self.derivative(state, v_r, c)[0]
        K = self.n_moments
        agg = p.sigma0[:, None, None] * m + p.sigma1[:, None, None] * m_dot  # (2, P, K)
        f = jnp.sum(self.coeffs[None, :, :] * agg[:, :, : K - 1], axis=(1, 2)) + p.sigma2 * v_r
        lever_terms = 0.5 * agg[1, :, : K - 1] - agg[1, :, 1:]
        mz = jnp.sum(self.coeffs * lever_terms) + p.sigma2[1] * v_r[1] * self.lever
        return jnp.stack([f[0], f[1], mz])

    def mean_deflection(self, state):
        r"""$\bar z_i = \int_0^1 z_i q\,d\xi$ (eq. 20 per axis) [m]."""
        K = self.n_moments
        return jnp.sum(self.coeffs[None, :, :] * state[0][:, :, : K - 1], axis=(1, 2))

    def dynamics(self, state, vx, vy, omega, r, Fz):
        return self.derivative(state, relative_velocity_2d(vx, vy, omega, r),
                               safe_abs(omega * r))

    def forces(self, state, vx, vy, omega, r, Fz):
        mu = self.mu(state, relative_velocity_2d(vx, vy, omega, r), safe_abs(omega * r))
        return Fz * mu * jnp.stack([jnp.ones(()), jnp.ones(()), self.params.L])
