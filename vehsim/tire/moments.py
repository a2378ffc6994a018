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
interface or the trailing edge $e=1$) the value is tracked by a characteristic argument. The
PDE is transport at speed $c/L$ of a point-model ODE whose coefficients do not depend on
$\xi$; let $s(t) = \int_0^t c/L$ be the distance travelled by the tread since $t=0$
(in patch lengths) and $t_e(t)$ the time at which the tread now at $e$ entered the patch
($s(t) - s(t_e) = e$). Differentiating
$z(t,e) = \int_{t_e}^t e^{-\int_\tau^tC_0}v_r(\tau)\,d\tau$ (for $s \ge e$) gives the exact
edge equation
$$\dot z_e = v_r - C_0\,z_e - H(s - e)\,\dot t_e\,e^{-\int_{t_e}^tC_0}\,v_r(t_e),$$
whose last term is the deflection-free tread arriving from the leading edge. Before the
first passage ($s < e$) the tread at $e$ was in the patch at $t = 0$; for a uniform initial
deflection (zero, or a locked wheel's state) it obeys the point model, which is the same
equation without the last term. We carry $z_e$ for every edge $e > 0$ and $s$ as states.

- The only term that is not a function of the current state and inputs is the *delayed*
  arrival term. No finite state determines it for arbitrary input histories (with
  $C_0 = 0$ the trailing edge obeys $\dot z(t,1) = v_r(t) - v_r(t_e)$, a delay equation),
  so **a finite moment system cannot be exact for every input**. We evaluate it with the
  inputs frozen over the transit: $\dot t_e = 1$,
  $e^{-\int C_0} = e^{-C_0eL/c}$, $v_r(t_e) = v_r(t)$ (zero for a locked wheel, $c = 0$).
- This is **exact whenever the inputs are constant since the last passage began**: so for a
  slip step from a uniform deflection (the transients of Fig. 17) the whole moment system
  is exact at all times, and at every steady state $z_e = \frac{v_rL}{c}e\,
  \varphi(\frac{C_0L}{c}e)$, $\varphi(x) = (1-e^{-x})/x$, the closed form.
- Otherwise the error enters only through the arrival term, damped by
  $e^{-C_0eL/c}$: of order $e^{-C_0eL/c}\,|\Delta v_r|$ for an input change $\Delta v_r$
  within one transit time.

Loads that vanish at the trailing edge (quartic, trapezoid) do not escape this: the force
combination $\sum_kc_km_k$ has no trailing-edge term, but the chain $q\to q'\to\dots\to$ const
of lower moments it needs ends in $m_0$, whose equation (42) carries $z(t,1)$.

**Accuracy, measured** (`tests/test_moments.py`, `experiments/benchmarks/moments_vs_pde.py`):
for a slip step from an undeflected patch the moments agree with a fine-grid PDE to the
PDE's own accuracy (< 2e-4 relative for the uniform load, ~1e-5 for trapezoid and quartic;
the moment error itself shrinks with the ODE tolerance) and reach the closed-form steady
state to 1e-6. **For inputs that vary during a transit the moment system is not exact and
is badly conditioned**: the interior of the PDE never depends on the outflow value
$z(t,1)$, but the moments do, and an error $\delta$ in it reaches $m_p$ with steady gain
$\sum_{j\le p}\frac{p!}{j!}\bigl(\frac{c}{LC_0}\bigr)^{p-j+1}$ (~100 for $p = 5$ at
$c/(LC_0)\approx0.8$), which the alternating load coefficients ($\sum|c_k|\approx100$ for
the quartic) amplify again. Measured (benchmark, 4 deg slip-angle ramp at 20 m/s, worst
of F_x, F_y, M_z relative to its peak): ramp over 10 ms (one transit) - uniform 0.20,
trapezoid 1.8, quartic 20; over 100 ms - uniform 0.46, trapezoid 1.9, quartic 3e2 (all
return to the exact steady state once the inputs settle). Use `DistributedLuGre2D`
(cheap at n = 16-48) for such inputs.

State: `(m, z_edge, s)`: moments `m` of shape `(2, P, K)` (P pieces, K = load degree + 2),
edge deflections `z_edge` of shape `(2, P)` (the right edge of every piece) and the
travelled distance `s` (in patch lengths).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .load import AbstractLoadDistribution, PolynomialLoad, TrapezoidalLoad, UniformLoad
from .lugre2d import AbstractPatchLuGre2D, LuGre2DParams, decay_rates


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


class MomentLuGre2D(AbstractPatchLuGre2D):
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
        r"""State of the uniform deflection `z0` (default 0), shape (2,) [m]."""
        z0 = jnp.zeros(2) if z0 is None else jnp.asarray(z0, dtype=float)
        K = self.n_moments
        a, b = self.edges[:-1], self.edges[1:]
        k = jnp.arange(1, K + 1)
        ints = (_powers(b, K + 1)[:, 1:] - _powers(a, K + 1)[:, 1:]) / k[None, :]
        z_edge = jnp.broadcast_to(z0[:, None], (2, self.pieces))
        return (z0[:, None, None] * ints[None, :, :], z_edge, jnp.zeros(()))

    def edge_values(self, state):
        r"""$z_i(t, e_j)$ at every piece edge, shape `(2, P+1)` ($z = 0$ at the leading edge)."""
        z_edge = state[1]
        return jnp.concatenate([jnp.zeros_like(z_edge[:, :1]), z_edge], axis=1)

    def derivative(self, state, v_r, c):
        r"""Time derivative of `(m, z_edge, s)` (eqs. 41-42 and the edge equations)."""
        m, z_edge, s = state
        K = self.n_moments
        C0 = decay_rates(self.params, v_r)
        b_rate = c / self.params.L
        a, b = self.edges[:-1], self.edges[1:]
        pa, pb = _powers(a, K + 1), _powers(b, K + 1)
        k = jnp.arange(1, K + 1)
        ints = (pb[:, 1:] - pa[:, 1:]) / k[None, :]
        zedge = self.edge_values(state)
        boundary = zedge[:, 1:, None] * pb[None, :, :K] - zedge[:, :-1, None] * pa[None, :, :K]
        p = jnp.arange(K)
        lower = jnp.concatenate([jnp.zeros_like(m[..., :1]), m[..., :-1]], axis=-1)
        m_dot = (
            v_r[:, None, None] * ints[None, :, :]
            - C0[:, None, None] * m
            - b_rate * boundary
            + b_rate * p[None, None, :] * lower
        )
        # Edge equations: point model minus the (frozen) arrival of undeflected tread.
        rolling = c > 0
        c_safe = jnp.where(rolling, c, 1.0)
        decay = jnp.exp(-(C0 * self.params.L / c_safe)[:, None] * b[None, :])
        arrived = (s >= b)[None, :] & rolling
        arrival = jnp.where(arrived, decay * v_r[:, None], 0.0)
        z_edge_dot = v_r[:, None] - C0[:, None] * z_edge - arrival
        return (m_dot, z_edge_dot, b_rate)

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

