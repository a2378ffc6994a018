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

**Basis.** The same system can be written against any basis of the polynomials of degree
$< K$ on each piece (`basis_tables`); only the linear maps change, and exactness does not.
The default is the shifted Legendre polynomials of each piece,
$\mu^{(j)}_{k,i} = \int_0^1 z_i(t, e_j + h_jx)\tilde P_k(x)\,dx$, $h_j = e_{j+1}-e_j$:
eq. 41 becomes
$\dot\mu_k = v_r\delta_{k0} - C_0\mu_k - \frac{c}{Lh}\bigl(z(t,e_{j+1}) - (-1)^kz(t,e_j)
- \sum_{l<k,\ k-l\ \text{odd}}2(2l+1)\mu_l\bigr)$ (from $\tilde P_k(1) = 1$,
$\tilde P_k(0) = (-1)^k$ and $\tilde P_k'$ in the basis), and eqs. 46/48 take the Legendre
coefficients of $q$ and of $q(\tfrac12-\xi)$ per piece, $O(1)$ where the monomial
coefficients alternate ($30, -60, 30$ for the quartic). `basis="monomial"` is eq. 41
verbatim. Both agree to solver tolerance; the Legendre form lowers the quartic's error at a
given tolerance several-fold (5.8e-4 to 7e-5 at rtol 1e-8 with the online closure), but the
amplification of edge errors below is a property of the truncated system, the same in every
basis.

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
equation without the last term.

The only term that is not a function of the current state and inputs is the *delayed*
arrival term (with $C_0 = 0$ the trailing edge obeys $\dot z(t,1) = v_r(t) - v_r(t_e)$, a
delay equation), so no finite state closes it for arbitrary inputs. But the edge values
are functionals of the *input history alone* (the coefficients $v_r$, $C_0$, $c$ do not
depend on $z$), which gives these closures of eqs. 41-42:

- **Exact, delay states** (`simulate_moments(closure="delay")`, the default, for inputs
  known in advance: the transients of Fig. 17, a recorded manoeuvre). The entry time obeys
  $\dot t_e = c(t)/c(t_e)$ (from $s(t) - s(t_e) = e$), and the inputs can be evaluated at
  $t_e$, so $t_e$, $D_e = \int_{t_e}^tC_0$ ($\dot D_e = C_0(t) - \dot t_eC_0(t_e)$) and
  $z_e$ with its exact edge equation are ODE states beside the moments, switched on at the
  first passage $t_p$ ($s(t_p) = e$, found beforehand by Newton on a Gauss quadrature of
  $c/L$). The moment system then reproduces the PDE for any rolling input history up to
  solver tolerance. Needs $c(t_e) > 0$: tread that entered while the wheel was locked
  needs the history closure.
- **Exact, history** (`closure="history"`): a first solve integrates five history states
  (tread travelled, $\int C_0$, and the point model from rest) with dense output, and
  `TransitHistory` returns the exact $z_i(t, e)$ at every edge from them and the entry
  time found by safeguarded Newton (locked phases included). Each right-hand side then
  searches the dense output: 3-10x slower than the delay states.
- **Exact, solved in closed form** (`moments_step_response`, for a step in slip: inputs
  constant from $t_0$ on, from a uniform deflection): between passages over the piece
  edges the whole system is linear with constant coefficients and a nilpotent coupling,
  so it is solved exactly by finite sums (no time stepping): the transients of Fig. 17 at
  the cost of a few dozen small array operations, and exactly steady after one transit.
- **Online** (this class as an `AbstractTire` inside a vehicle, where the inputs depend on
  the state): we carry $z_e$ for every edge and $s$ as states, with the arrival term
  evaluated with the inputs frozen over the transit ($\dot t_e = 1$,
  $e^{-\int C_0} = e^{-C_0eL/c}$, $v_r(t_e) = v_r(t)$; zero for a locked wheel, $c = 0$).
  This is exact whenever the inputs are constant since the last passage began: for a slip
  step from a uniform deflection the whole moment system is exact at all times, and at
  every steady state $z_e = \frac{v_rL}{c}e\,\varphi(\frac{C_0L}{c}e)$,
  $\varphi(x) = (1-e^{-x})/x$, the closed form. Otherwise it errs through the arrival
  term, damped by $e^{-C_0eL/c}$.

**Conditioning, and the kink at first passage.** Loads that vanish at the trailing edge
(quartic, trapezoid) do not escape the edge values: the force combination has no
trailing-edge term, but the chain $q\to q'\to\dots\to$ const of lower moments it needs ends
in $m_0$, whose equation (42) carries $z(t,1)$. The interior of the PDE never depends on the
outflow value $z(t,1)$, but the truncated moment system does: an error $\delta$ in it
reaches $m_p$ with steady gain $\sum_{j\le p}\frac{p!}{j!}\bigl(\frac{c}{LC_0}\bigr)^{p-j+1}$,
and for the quartic at 4 deg slip angle a relative error in $z(t,1)$ reaches $M_z$
(relative) amplified about 1000 times (trapezoid 30, uniform 5), in any basis. The edge
values are continuous but kink where fresh tread first reaches the edge ($t = t_p$); a step
across that kink leaves a local error of the order of the step in $z_e$, which this gain
turned into the dominant error (the quartic's $M_z$ needed rtol 1e-8). Landing a step on
$t_p$ (a `jump_ts` of the solver, with the switch written in $t$ so that it falls exactly
between steps) removes it: the quartic then reaches 1.4e-4 at rtol 1e-5 in 16 steps. The
online closure cannot land on its switch (it depends on the state), and still needs tight
tolerances.

**Accuracy, measured** (`tests/test_moments.py`, `experiments/benchmarks/moments_vs_pde.py`,
worst of F_x, F_y, M_z relative to its peak, against the PDE at n = 64-128): slip steps from
an undeflected patch, either closure, < 1e-4 at rtol 1e-8 and the closed-form steady state
to 1e-6 (online closure at rtol 1e-12); the delay closure reaches 1e-3 at rtol 1e-4
(uniform 1.5e-4, trapezoid 3.6e-5) and 1e-5 (quartic 1.3e-4) in 10-16 steps. Slip-angle
ramps over 10 ms (one transit) and 100 ms at 20 m/s, alpha = 4 and 15 deg: exact closures
< 2.2e-4 at rtol 1e-8 for uniform, trapezoidal and quartic loads, and the delay closure told
the ramp's end (`kinks`) < 8e-4 at rtol 1e-5 for every load (the quartic needs rtol 1e-8
without it); the frozen online closure errs by 0.20/1.8/20 (10 ms) and 0.46/1.9/3e2
(100 ms) there.

State (online closure): `(m, z_edge, s)`: moments `m` (in `basis`) of shape `(2, P, K)`
(P pieces, K = load degree + 2), edge deflections `z_edge` of shape `(2, P)` (the right
edge of every piece) and the travelled distance `s` (in patch lengths).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .load import (
    AbstractLoadDistribution,
    AbstractPolynomialLoad,
    TrapezoidalLoad,
    UniformLoad,
)
from .lugre2d import AbstractPatchLuGre2D, LuGre2DParams, decay_rates


def piecewise_coefficients(load: AbstractLoadDistribution, degree: int | None = None):
    r"""Edges $0 = e_0 < \dots < e_P = 1$ and monomial coefficients $c^{(j)}_k$ (in global
    $\xi$) with $q(\xi) = \sum_kc^{(j)}_k\xi^k$ on $[e_j, e_{j+1}]$.

    Exact for `AbstractPolynomialLoad` (uniform, quartic, user polynomials) and `TrapezoidalLoad`
    (differentiable in the ramp). Any other load needs `degree`: each piece between its
    kinks is interpolated at `degree + 1` Chebyshev points (the Taylor-type approximation of
    eq. 43), and the moment model is then exact for that interpolant.

    **Returns:** `(edges (P+1,), coeffs (P, K))`.
    """
    if isinstance(load, AbstractPolynomialLoad):
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


BASES = ("legendre", "monomial")


def _legendre_tables(K):
    r"""Shifted Legendre polynomials $\tilde P_k(x) = P_k(2x-1)$ on $[0, 1]$, $k < K$: Gauss
    nodes and weights on $[0, 1]$ exact to degree $2K+1$, the values $\tilde P_k(x_g)$
    (K, G), and the derivative map $\tilde P_k' = \sum_{l<k,\ k-l\ \text{odd}}
    2(2l+1)\tilde P_l$ as a strictly lower-triangular matrix (K, K)."""
    x, w = np.polynomial.legendre.leggauss(K + 1)
    x, w = 0.5 * (x + 1.0), 0.5 * w
    vals = np.stack([np.polynomial.legendre.legval(2 * x - 1, np.eye(K)[k]) for k in range(K)])
    k, j = np.meshgrid(np.arange(K), np.arange(K), indexing="ij")
    deriv = np.where((j < k) & ((k - j) % 2 == 1), 2.0 * (2 * j + 1), 0.0)
    return x, w, vals, deriv


def basis_tables(edges, coeffs, K: int, basis: str):
    r"""The moment system of eqs. 41-42 and 46/48 in `basis`, as arrays per piece.

    For moments $\mu_k$ of $z$ against basis functions $\phi^{(j)}_k$ on piece $j$, eq. 31a
    integrated by parts gives, in both bases,
    $$\dot\mu = v_r\,s - C_0\mu - \frac cL\bigl(z(t,b)\,\rho - z(t,a)\,\lambda\bigr)
      + \frac cL\,T\mu,\qquad \frac{F}{F_n} = w_F\cdot(\sigma_0\mu + \sigma_1\dot\mu)
      + \sigma_2v_r,$$
    with $s_k = \int\phi_k$, $\rho_k = \phi_k(b)$, $\lambda_k = \phi_k(a)$, $T$ the map of
    $\phi_k'$ onto the basis, $w_F$ the coefficients of $q$ and $w_M$ those of
    $q(\tfrac12-\xi)$ (for $M_z$). **Monomial** (eqs. 41-42 verbatim): $\phi_k = \xi^k$,
    $s_k = (b^{k+1}-a^{k+1})/(k+1)$, $\rho_k = b^k$, $\lambda_k = a^k$, $T_{k,k-1} = k$.
    **Legendre**: $\phi_k = \tilde P_k((\xi-a)/h)/h$, $h = b - a$, so
    $\mu_k = \int_0^1 z(a+hx)\tilde P_k(x)\,dx$, $s_k = \delta_{k0}$, $\rho_k = 1/h$,
    $\lambda_k = (-1)^k/h$, $T = $ (derivative map)$/h$; $w_{F,k} = h(2k+1)\int_0^1
    q(a+hx)\tilde P_k\,dx$ (exact Gauss projection of the polynomial load).

    **Returns:** `(src, right, left, transport, w_force, w_moment)`, shapes
    `(P,K), (P,K), (P,K), (P,K,K), (P,K), (P,K)`.
    """
    a, b = edges[:-1], edges[1:]
    P, m1 = coeffs.shape
    if basis == "monomial":
        pa, pb = _powers(a, K + 1), _powers(b, K + 1)
        src = (pb[:, 1:] - pa[:, 1:]) / jnp.arange(1, K + 1)[None, :]
        shift = np.diag(np.arange(1.0, K), -1)
        transport = jnp.broadcast_to(jnp.asarray(shift), (P, K, K))
        zero = jnp.zeros((P, K - m1))
        w_force = jnp.concatenate([coeffs, zero], axis=1)
        prev = jnp.concatenate([jnp.zeros((P, 1)), coeffs, zero[:, 1:]], axis=1)
        w_moment = 0.5 * w_force - prev
        return src, pb[:, :K], pa[:, :K], transport, w_force, w_moment
    x, w, vals, deriv = _legendre_tables(K)
    h = b - a
    xi = a[:, None] + h[:, None] * jnp.asarray(x)[None, :]  # (P, G)
    q = jnp.sum(coeffs[:, None, :] * _powers(xi, m1), axis=-1)
    proj = jnp.asarray((2 * np.arange(K) + 1)[:, None] * vals * w[None, :])  # (K, G)
    w_force = h[:, None] * (q @ proj.T)
    w_moment = h[:, None] * ((q * (0.5 - xi)) @ proj.T)
    ones = jnp.ones((P, K))
    src = ones * jnp.asarray(np.eye(K)[0])[None, :]
    right = ones / h[:, None]
    left = jnp.asarray((-1.0) ** np.arange(K))[None, :] / h[:, None]
    transport = jnp.asarray(deriv)[None, :, :] / h[:, None, None]
    return src, right, left, transport, w_force, w_moment


class MomentLuGre2D(AbstractPatchLuGre2D):
    r"""Method-of-moments model of the distributed 2D LuGre tire (eqs. 39-48).

    See the module docstring for the equations, the basis, and when the moment system is
    exact.

    **Arguments:**

    - `params`: `LuGre2DParams`.
    - `load`: normalised load shape (default uniform); polynomial and trapezoidal loads are
      represented exactly.
    - `degree`: polynomial degree per piece for other loads (see `piecewise_coefficients`).
    - `basis`: `"legendre"` (default; shifted Legendre moments per piece, well conditioned)
      or `"monomial"` (the report's $\int z\xi^p$ of eq. 39). The same moment system in two
      bases (`basis_tables`): both are exact; they differ in rounding and in how the
      solver's error control sees the state.
    """

    params: LuGre2DParams
    load: AbstractLoadDistribution
    edges: Float[Array, " P1"]
    coeffs: Float[Array, "P K"]
    lever: Float[Array, ""]
    src: Float[Array, "P K"]
    right: Float[Array, "P K"]
    left: Float[Array, "P K"]
    transport: Float[Array, "P K K"]
    w_force: Float[Array, "P K"]
    w_moment: Float[Array, "P K"]
    coupling_powers: Float[Array, "K1 D D"]
    response_source: Float[Array, "3 K1"]
    response_edges: Float[Array, "3 K1 P"]
    n_moments: int = eqx.field(static=True)
    basis: str = eqx.field(static=True)

    def __init__(self, params: LuGre2DParams, load: AbstractLoadDistribution | None = None,
                 degree: int | None = None, basis: str = "legendre"):
        if basis not in BASES:
            raise ValueError(f"MomentLuGre2D.basis must be one of {BASES}, got {basis!r}")
        self.params = params
        self.load = UniformLoad() if load is None else load
        self.basis = basis
        self.edges, self.coeffs = piecewise_coefficients(self.load, degree)
        self.n_moments = int(self.coeffs.shape[1]) + 1
        # int_0^1 q (1/2 - xi) dxi from the piece coefficients (exact, differentiable).
        K = self.coeffs.shape[1]
        a, b = self.edges[:-1], self.edges[1:]
        ints = (_powers(b, K + 2)[:, 1:] - _powers(a, K + 2)[:, 1:]) / jnp.arange(1, K + 2)[None, :]
        self.lever = jnp.sum(self.coeffs * (0.5 * ints[:, :K] - ints[:, 1:]))
        (self.src, self.right, self.left, self.transport, self.w_force,
         self.w_moment) = basis_tables(self.edges, self.coeffs, self.n_moments, basis)
        N = coupling_matrix(self.transport, self.right, self.left)
        powers = [jnp.eye(N.shape[0])]
        for _ in range(self.n_moments):
            powers.append(N @ powers[-1])
        self.coupling_powers = jnp.stack(powers)
        # The load rows w_c N^i of `moments_step_response` (F_x, F_y from w_force, M_z from
        # w_moment; no weight on the edge deflections), applied to the source pattern
        # (the moments' src, 1 at every edge) and to each edge deflection.
        P, PK = self.pieces, self.coeffs.shape[0] * self.n_moments
        w = jnp.concatenate([jnp.stack([self.w_force.ravel()] * 2 + [self.w_moment.ravel()]),
                             jnp.zeros((3, P))], axis=1)  # (3, D)
        rows = jnp.einsum("cd,ide->cie", w, self.coupling_powers)  # (3, K + 1, D)
        self.response_source = rows @ jnp.concatenate([self.src.ravel(), jnp.ones(P)])
        self.response_edges = rows[..., PK:]

    @property
    def pieces(self) -> int:
        return int(self.coeffs.shape[0])

    def init_state(self, z0=None):
        r"""State of the uniform deflection `z0` (default 0), shape (2,) [m]."""
        z0 = jnp.zeros(2) if z0 is None else jnp.asarray(z0, dtype=float)
        z_edge = jnp.broadcast_to(z0[:, None], (2, self.pieces))
        return (z0[:, None, None] * self.src[None, :, :], z_edge, jnp.zeros(()))

    def edge_values(self, state):
        r"""$z_i(t, e_j)$ at every piece edge, shape `(2, P+1)` ($z = 0$ at the leading edge)."""
        z_edge = state[1]
        return jnp.concatenate([jnp.zeros_like(z_edge[:, :1]), z_edge], axis=1)

    def moment_rates(self, m, zedge, v_r, c):
        r"""Eqs. 41-42 (in `self.basis`, `basis_tables`) for moments `m` (2, P, K) given the
        deflections at every piece edge, `zedge` (2, P+1) (leading edge first)."""
        C0 = decay_rates(self.params, v_r)
        boundary = (zedge[:, 1:, None] * self.right[None, :, :]
                    - zedge[:, :-1, None] * self.left[None, :, :])
        lower = jnp.einsum("jkl,ijl->ijk", self.transport, m)
        return (
            v_r[:, None, None] * self.src[None, :, :]
            - C0[:, None, None] * m
            + (c / self.params.L) * (lower - boundary)
        )

    def derivative(self, state, v_r, c):
        r"""Time derivative of `(m, z_edge, s)` (eqs. 41-42 and the edge equations)."""
        m, z_edge, s = state
        C0 = decay_rates(self.params, v_r)
        b = self.edges[1:]
        m_dot = self.moment_rates(m, self.edge_values(state), v_r, c)
        # Edge equations: point model minus the (frozen) arrival of undeflected tread.
        rolling = c > 0
        c_safe = jnp.where(rolling, c, 1.0)
        decay = jnp.exp(-(C0 * self.params.L / c_safe)[:, None] * b[None, :])
        arrived = (s >= b)[None, :] & rolling
        arrival = jnp.where(arrived, decay * v_r[:, None], 0.0)
        z_edge_dot = v_r[:, None] - C0[:, None] * z_edge - arrival
        return (m_dot, z_edge_dot, c / self.params.L)

    def mu_from_moments(self, m, m_dot, v_r):
        r"""$(F_x/F_n, F_y/F_n, M_z/(F_nL))$ from the moments and their rates (eqs. 46, 48)."""
        p = self.params
        agg = p.sigma0[:, None, None] * m + p.sigma1[:, None, None] * m_dot  # (2, P, K)
        f = jnp.sum(self.w_force[None, :, :] * agg, axis=(1, 2)) + p.sigma2 * v_r
        mz = jnp.sum(self.w_moment * agg[1]) + p.sigma2[1] * v_r[1] * self.lever
        return jnp.stack([f[0], f[1], mz])

    def mu(self, state, v_r, c):
        r"""$(F_x/F_n, F_y/F_n, M_z/(F_nL))$ (eqs. 46 and 48, our sign)."""
        return self.mu_from_moments(state[0], self.derivative(state, v_r, c)[0], v_r)

    def mean_deflection(self, state):
        r"""$\bar z_i = \int_0^1 z_i q\,d\xi$ (eq. 20 per axis) [m]."""
        return jnp.sum(self.w_force[None, :, :] * state[0], axis=(1, 2))


class TransitHistory(eqx.Module):
    r"""What the patch edges remember of the inputs: the exact trailing-edge closure.

    Along a characteristic the PDE (eq. 31a) is the point model, so the deflection at an edge
    $e$ (in patch lengths) is a functional of the input history alone,
    $$z_i(t, e) = \begin{cases} w_i(t) - e^{-(E_i(t)-E_i(t_e))}\,w_i(t_e), & s(t)\ge e,\\
      w_i(t) + e^{-E_i(t)}z_{0i}, & s(t) < e,\end{cases}$$
    with $s(t)=\int_0^tc/L$ the tread travelled, $t_e$ the entry time of the tread now at
    $e$ ($s(t)-s(t_e)=e$), $E_i(t)=\int_0^tC_{0i}$ and $w$ the point model started
    undeflected, $\dot w_i = v_{ri}-C_{0i}w_i$, $w_i(0)=0$ (the two cases: tread that entered
    after $t=0$ at $z=0$, and tread that was on the patch at $t=0$ with the uniform deflection
    $z_0$). `solution` is a dense diffrax solution of $(s, E_x, E_y, w_x, w_y)$.
    """

    solution: object
    z0: Float[Array, " 2"]

    def _at(self, t):
        h = self.solution.evaluate(t)
        return h[0], h[1:3], h[3:5]

    def entry_time(self, t, distance):
        r"""$t_e\in[0,t]$ with $s(t_e) = $ `distance` ($\le s(t)$): safeguarded Newton with
        $\dot s = c/L$, then one Newton step outside the loop so that gradients follow the
        implicit function theorem (the loop itself sees no tangents)."""
        import jax
        from jax import lax

        t_ = lax.stop_gradient(t)
        distance_ = lax.stop_gradient(distance)
        frozen = jax.tree_util.tree_map(
            lambda x: lax.stop_gradient(x) if eqx.is_array(x) else x, self.solution)

        def s_of(x, sol=frozen):
            return sol.evaluate(x)[0]

        def rate(x, sol=frozen):
            return sol.derivative(x)[0]

        def tol(d):
            return 1e-14 * (1.0 + jnp.abs(d))

        def body(carry):
            x, lo, hi, _, it = carry
            f = s_of(x) - distance_
            lo = jnp.where(f <= 0, x, lo)
            hi = jnp.where(f > 0, x, hi)
            r = rate(x)
            newton = x - f / jnp.where(r > 0, r, 1.0)
            ok = (r > 0) & (newton >= lo) & (newton <= hi)
            x_next = jnp.where(ok, newton, 0.5 * (lo + hi))
            # keep a converged iterate: the loop stops on the residual of `x`
            return jnp.where(jnp.abs(f) <= tol(distance_), x, x_next), lo, hi, f, it + 1

        def cond(carry):
            _, lo, hi, f, it = carry
            return (jnp.abs(f) > tol(distance_)) & (hi - lo > 1e-15 * t_) & (it < 200)

        r0 = rate(t_)
        guess = jnp.clip(t_ - jnp.where(r0 > 0, (s_of(t_) - distance_) / jnp.where(r0 > 0, r0, 1.0),
                                        0.5 * t_), 0.0, t_)
        init = (guess, jnp.zeros_like(t_), t_, jnp.asarray(jnp.inf), jnp.asarray(0))
        x = lax.stop_gradient(lax.while_loop(cond, body, init)[0])
        r = rate(x, self.solution)
        f = s_of(x, self.solution) - distance
        return x - jnp.where(r > 0, f / jnp.where(r > 0, r, 1.0), 0.0)

    def edge_deflections(self, t, edges):
        r"""$z_i(t, e)$ for `edges` (P,) in $(0, 1]$, shape `(2, P)` (module docstring)."""
        import jax

        s, E, w = self._at(t)

        def one(e):
            entered = s >= e
            t_e = self.entry_time(t, jnp.where(entered, s - e, 0.0))
            _, E_e, w_e = self._at(jnp.where(entered, t_e, 0.0))
            new_tread = w - jnp.exp(-(E - E_e)) * w_e
            old_tread = w + jnp.exp(-E) * self.z0
            return jnp.where(entered, new_tread, old_tread)

        return jax.vmap(one, out_axes=1)(edges)


CLOSURES = ("delay", "history")


def passage_times(c_of_t, t0, t1, distances, L, nodes: int = 32):
    r"""First times $t_p\in[t_0, t_1]$ with $\int_{t_0}^{t_p}c/L = $ `distances` (P,), by Newton
    on a `nodes`-point Gauss-Legendre quadrature of the transport speed; $t_1$ where the
    tread has not travelled that far by $t_1$. The iterations see no tangents; one last
    Newton step outside them gives the implicit-function gradient."""
    import jax
    from jax import lax

    gx, gw = np.polynomial.legendre.leggauss(nodes)
    gx, gw = jnp.asarray(0.5 * (gx + 1.0)), jnp.asarray(0.5 * gw)

    def travelled(t):
        tau = t0 + (t - t0) * gx
        return (t - t0) * jnp.sum(gw * jax.vmap(c_of_t)(tau)) / L

    def rate(t):
        return c_of_t(t) / L

    def one(d):
        r0 = lax.stop_gradient(rate(t0))
        t = jnp.clip(t0 + d / jnp.where(r0 > 0, r0, 1.0), t0, t1)
        for _ in range(8):
            r = lax.stop_gradient(rate(t))
            f = lax.stop_gradient(travelled(t) - d)
            t = lax.stop_gradient(jnp.clip(t - f / jnp.where(r > 0, r, jnp.inf), t0, t1))
        r = rate(t)
        t = t - (travelled(t) - d) / jnp.where(r > 0, r, 1.0)
        return jnp.where(lax.stop_gradient(travelled(t1)) >= d, t, t1)

    return jax.vmap(one)(distances)


def _simulate_delay(model, ts, signals, r, z0, solver, controller, max_steps, throw, kinks=None):
    r"""`simulate_moments` with the delay-state closure (see its docstring).

    The edge equations switch on at the passage times $t_p$ (sorted, as the edges are): the
    solve is split there into $P + 1$ segments with a fixed set of edges reached in each, so
    the switch falls between steps and its gradient (through $t_p$, e.g. in the wheel speed)
    comes from the segment bounds."""
    import diffrax as dfx
    import jax

    from .lugre2d import relative_velocity_2d
    from .transient import Tire2DSolution

    vx_s, vy_s, om_s, fz_s = signals
    L = model.params.L
    P, K = model.pieces, model.n_moments
    edges = model.edges[1:]
    t0, t1 = ts[0], ts[-1]
    sizes = np.cumsum([2 * P * K, 2 * P, 2 * P])

    def slip(t):
        return (relative_velocity_2d(vx_s(t), vy_s(t), om_s(t), r), jnp.abs(om_s(t) * r))

    passage = passage_times(lambda t: slip(t)[1], t0, t1, edges, L)

    def unpack(y):
        m, ye, D, te = jnp.split(y, sizes)
        return m.reshape(2, P, K), ye.reshape(2, P), D.reshape(2, P), te

    def rates(t, y, entered):
        m, ye, D, te = unpack(y)
        # inputs now and when the tread now at each edge entered, in one vectorised pass
        v_all, c_all = jax.vmap(slip)(jnp.concatenate([t[None], te]))
        C_all = jax.vmap(lambda v: decay_rates(model.params, v))(v_all)  # (P + 1, 2)
        v_r, c, C0 = v_all[0], c_all[0], C_all[0]
        v_re, c_e, C0e = v_all[1:], c_all[1:], C_all[1:]
        moving = entered & (c_e > 0)
        te_dot = jnp.where(moving, c / jnp.where(moving, c_e, 1.0), 0.0)
        decay = jnp.exp(-D)
        ye_dot = v_r[:, None] - C0[:, None] * ye - te_dot[None, :] * decay * v_re.T
        D_dot = C0[:, None] - te_dot[None, :] * C0e.T
        z_e = ye + jnp.where(entered[None, :], 0.0, decay * z0[:, None])
        zedge = jnp.concatenate([jnp.zeros((2, 1)), z_e], axis=1)
        m_dot = model.moment_rates(m, zedge, v_r, c)
        dy = jnp.concatenate([m_dot.ravel(), ye_dot.ravel(), D_dot.ravel(), te_dot])
        return dy, m, m_dot, v_r

    y0 = jnp.concatenate([model.init_state(z0)[0].ravel(), jnp.zeros(4 * P), jnp.full(P, t0)])
    # One solve in a segment clock tau in [0, P + 1]: segment k = [t_k, t_{k+1}] (between
    # passages) is tau in [k, k + 1], t = t_k + (tau - k)(t_{k+1} - t_k). The switches sit at
    # the integers (fixed jumps of the solver) and the passage times enter only through this
    # map, so they are differentiated like any other parameter.
    bounds = jnp.concatenate([t0[None], passage, t1[None]])
    width = bounds[1:] - bounds[:-1]

    def segment(tau):
        return jnp.clip(jnp.floor(tau), 0, P).astype(int)

    def clock(tau):
        # (segment, t, dt/dtau) on the segment clock
        k = segment(tau)
        return k, bounds[k] + (tau - k) * width[k], width[k]

    def field(tau, y, args):
        k, t, w = clock(tau)
        return w * rates(t, y, jnp.arange(P) < k)[0]

    def to_tau(t):
        k = jnp.clip(jnp.searchsorted(bounds, t, side="right") - 1, 0, P)
        w = width[k]
        frac = jnp.where(w > 0, (t - bounds[k]) / jnp.where(w > 0, w, 1.0), 0.0)
        return k + jnp.clip(frac, 0.0, 1.0)

    scale = jnp.stack([jnp.ones(()), jnp.ones(()), L])

    def save(tau, y, args):
        # forces and moments only (not the edge states): under vmap every save writes the
        # whole batch's buffer, so a narrow buffer is cheaper than a vectorised pass after
        k, t, _ = clock(tau)
        _, m, m_dot, v_r = rates(t, y, jnp.arange(P) < k)
        return fz_s(t) * model.mu_from_moments(m, m_dot, v_r) * scale, m

    taus = to_tau(ts)
    jumps = jnp.arange(1.0, P + 1.0)
    if kinks is not None:
        # input kinks at T, and their arrival at every edge (s(t) - s(T) = e): land steps there
        T = jnp.atleast_1d(jnp.asarray(kinks, dtype=float))
        arrive = jax.vmap(lambda tk: passage_times(lambda t: slip(t)[1], tk, t1, edges, L))(T)
        kink_taus = jax.lax.stop_gradient(to_tau(jnp.concatenate([T, arrive.ravel()])))
        jumps = jnp.sort(jnp.concatenate([jumps, kink_taus]))
    sol = dfx.diffeqsolve(
        dfx.ODETerm(field), solver, t0=0.0, t1=float(P + 1), dt0=None, y0=y0,
        saveat=dfx.SaveAt(ts=taus, fn=save),
        stepsize_controller=dfx.ClipStepSizeController(controller, jump_ts=jumps),
        max_steps=max_steps, throw=throw,
    )
    (forces, moments), result, num_steps = sol.ys, sol.result, sol.stats["num_steps"]
    return Tire2DSolution(ts=ts, state=moments, forces=forces, result=result,
                          num_steps=num_steps)


def simulate_moments(
    model: MomentLuGre2D,
    ts,
    vx,
    vy,
    omega,
    r,
    Fz,
    z0=None,
    *,
    closure: str = "delay",
    kinks=None,
    solver=None,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 100_000,
    history_max_steps: int = 4096,
    history_solver=None,
    history_rtol: float | None = None,
    history_atol: float | None = None,
    throw: bool = True,
):
    r"""Exact method of moments for inputs known in advance (eqs. 39-48, no closure).

    `MomentLuGre2D` as an `AbstractTire` closes the edge values with inputs frozen over a
    transit, exact only for piecewise-constant inputs. When the inputs are given as functions
    of time (as in Fig. 17, or a recorded manoeuvre) the edge values are functionals of the
    input history, and the moment ODE of eqs. 41-42 uses the exact $z_i(t, e_j)$ at every
    piece edge (module docstring): with `closure="delay"` (default) from the entry times
    $t_e$ carried as ODE states beside the moments, one solve, its steps landed on the first
    passage of tread over each edge; with `closure="history"` from a first solve of five
    history states with dense output (`TransitHistory`), which also handles tread that
    entered while the wheel was locked ($c(t_e) = 0$, where the delay states fail). The
    result equals the distributed PDE (eqs. 31-34) up to solver tolerance for any such
    input history and any piecewise-polynomial load.

    **Arguments:** as `simulate_tire_2d` (`vx`, `vy`, `omega`, `Fz` constants, samples on
    `ts` or callables of `t`; `r` [m]), plus `z0` (2,), the uniform initial deflection [m]
    (default 0). `kinks` (delay closure): times where the inputs have a kink or a jump (the
    end of a ramp); steps are landed on them and on their arrival at every edge, where they
    kink the edge values. `solver` defaults to `Tsit5`. History closure only: `history_solver`,
    `history_rtol`, `history_atol` (default: those of the moment solve) and
    `history_max_steps`, which bounds the history solve, whose dense output is stored: every
    edge lookup searches it, so a buffer far larger than needed costs time (100 000 slots
    made a 30 ms transient 5x slower than 4096). A history needing more steps fails loudly
    (`throw=True`); raise it for long runs.

    **Returns:** a `Tire2DSolution` whose `state` is the moments `(T, 2, P, K)`.
    """
    import diffrax as dfx
    import jax

    from .._signals import as_signal
    from .lugre2d import relative_velocity_2d
    from .transient import Tire2DSolution

    if not isinstance(model, MomentLuGre2D):
        raise TypeError(f"simulate_moments needs a MomentLuGre2D, got {type(model).__name__}")
    if closure not in CLOSURES:
        raise ValueError(f"simulate_moments closure must be one of {CLOSURES}, got {closure!r}")
    ts = jnp.asarray(ts, dtype=float)
    vx_s, vy_s, om_s, fz_s = (as_signal(ts, x) for x in (vx, vy, omega, Fz))
    z0 = jnp.zeros(2) if z0 is None else jnp.asarray(z0, dtype=float)
    L = model.params.L
    solver = dfx.Tsit5() if solver is None else solver
    controller = dfx.PIDController(rtol=rtol, atol=atol)
    if closure == "delay":
        return _simulate_delay(model, ts, (vx_s, vy_s, om_s, fz_s), r, z0, solver, controller,
                               max_steps, throw, kinks)
    history_solver = solver if history_solver is None else history_solver
    history_controller = dfx.PIDController(
        rtol=rtol if history_rtol is None else history_rtol,
        atol=atol if history_atol is None else history_atol)

    def slip(t):
        return (relative_velocity_2d(vx_s(t), vy_s(t), om_s(t), r),
                jnp.abs(om_s(t) * r))

    def history_field(t, h, args):
        v_r, c = slip(t)
        C0 = decay_rates(model.params, v_r)
        return jnp.concatenate([(c / L)[None], C0, v_r - C0 * h[3:5]])

    hist = dfx.diffeqsolve(
        dfx.ODETerm(history_field), history_solver, t0=ts[0], t1=ts[-1], dt0=None,
        y0=jnp.zeros(5), saveat=dfx.SaveAt(dense=True), stepsize_controller=history_controller,
        max_steps=history_max_steps, throw=throw,
    )
    history = TransitHistory(hist, z0)
    edges = model.edges[1:]
    # The first passage of tread over an edge (s = e) is a kink of z(t, e): land a step on it.
    s_end = history.solution.evaluate(ts[-1])[0]
    passage = jax.vmap(lambda e: history.entry_time(ts[-1], e))(jnp.minimum(edges, s_end))
    passage = jax.lax.stop_gradient(jnp.where(edges <= s_end, passage, ts[-1]))
    moment_controller = dfx.ClipStepSizeController(controller, step_ts=passage)

    def rates(t, m):
        v_r, c = slip(t)
        z_e = history.edge_deflections(t, edges)
        zedge = jnp.concatenate([jnp.zeros((2, 1)), z_e], axis=1)
        return model.moment_rates(m, zedge, v_r, c), v_r

    m0 = model.init_state(z0)[0]
    sol = dfx.diffeqsolve(
        dfx.ODETerm(lambda t, m, args: rates(t, m)[0]), solver, t0=ts[0], t1=ts[-1], dt0=None,
        y0=m0, saveat=dfx.SaveAt(ts=ts), stepsize_controller=moment_controller, max_steps=max_steps,
        throw=throw,
    )

    def force_at(t, m):
        m_dot, v_r = rates(t, m)
        scale = jnp.stack([jnp.ones(()), jnp.ones(()), L])
        return fz_s(t) * model.mu_from_moments(m, m_dot, v_r) * scale

    forces = jax.vmap(force_at)(ts, sol.ys)
    result = dfx.RESULTS.where(hist.result == dfx.RESULTS.successful, sol.result, hist.result)
    return Tire2DSolution(ts=ts, state=sol.ys, forces=forces, result=result,
                          num_steps=hist.stats["num_steps"] + sol.stats["num_steps"])


def decay_integrals(x, n: int, exp_neg_x=None):
    r"""$I_j(x) = \int_0^1 e^{-xu}\,u^j/j!\,du$ for $j < n$, $x \ge 0$, shape `(..., n)`
    (`exp_neg_x`: $e^{-x}$ if the caller has it).

    Integration by parts gives $I_j = e^{-x}/(j+1)! + x\,I_{j+1}$, a recursion with positive
    terms only: below $x = 2$ it runs downwards from $I_{n-1}$ by its series
    $\sum_i (-x)^i/(i!\,(n-1)!\,(i+n))$ (24 terms; finite gradient at $x = 0$, where
    $I_j = 1/(j+1)!$). From $x = 2$ on, $I_j = P(j+1, x)/x^{j+1}$ with the regularised
    incomplete gamma function $P(j+1, x) = 1 - e^{-x}\sum_{i\le j}x^i/i!$, which loses at most
    ~2 digits to cancellation for $j \le 6$ (5 for $j = 10$). Each branch sees only arguments in
    its own range (double `where`); elementwise only, so that XLA fuses it (`gammainc` costs
    30x more)."""
    x = jnp.asarray(x, dtype=float)
    small = x < 2.0
    xs = jnp.where(small, x, 0.0)[..., None]
    xl = jnp.where(small, 2.0, x)[..., None]
    fact = np.cumprod([1.0] + list(range(1, max(n, 24) + 1)))
    top = jnp.zeros_like(xs)
    for i in range(23, -1, -1):
        top = top * xs + (-1.0) ** i / (fact[i] * fact[n - 1] * (i + n))
    ex = jnp.exp(-x) if exp_neg_x is None else exp_neg_x
    e_s = jnp.where(small, ex, 1.0)[..., None]
    e_l = jnp.where(small, np.exp(-2.0), ex)[..., None]
    series = [top]
    for j in range(n - 2, -1, -1):
        series.append(e_s / fact[j + 1] + xs * series[-1])
    series = jnp.concatenate(series[::-1], -1)
    term, partial, power = jnp.ones_like(xl), [], []
    for k in range(n):
        partial.append(term if k == 0 else partial[-1] + term)
        power.append(xl if k == 0 else power[-1] * xl)
        term = term * xl / (k + 1)
    partial, power = jnp.concatenate(partial, -1), jnp.concatenate(power, -1)
    large = (1.0 - e_l * partial) / power
    return jnp.where(small[..., None], series, large)


def coupling_matrix(transport, right, left):
    r"""$N$ of `moments_step_response`: eqs. 41-42 less the decay and the sources, per axis, on
    $Y = (\mu^{(0)}, \dots, \mu^{(P-1)}, z_{e_1}, \dots, z_{e_P})$ (moments of each piece, then the
    deflection at each piece's right edge): $\dot\mu^{(j)} \ni \lambda\bigl(T_j\mu^{(j)}
    - \rho_j z_{e_{j+1}} + \lambda_j z_{e_j}\bigr)$, $z_{e_0} = 0$ (`basis_tables`).
    Strictly block lower triangular, so $N^{K+1} = 0$. **Returns:** `(D, D)`, $D = PK + P$."""
    P, K = right.shape
    eye = jnp.eye(P)
    Nmm = jnp.einsum("jkl,jJ->jkJl", transport, eye).reshape(P * K, P * K)
    Nme = (-right[:, :, None] * eye[:, None, :]
           + left[:, :, None] * jnp.eye(P, k=-1)[:, None, :]).reshape(P * K, P)
    top = jnp.concatenate([Nmm, Nme], axis=1)
    return jnp.concatenate([top, jnp.zeros((P, P * K + P))], axis=0)


def _segment_starts(T0, TW, a_seg, b_seg, jumps):
    r"""$N^iY(t_k)$ at every segment start $k = 0..P$ of `moments_step_response`, from
    $N^iY(t_0)$ (`T0`, axis 1 the power $i$, any trailing axes), the sources $N^i\beta_k$
    (`TW`, axis 1 the segment), the coefficients $a_j, b_j$ over each whole segment
    (`a_seg`, `b_seg`, `(B, P, n)`) and the edge jumps at each passage (`jumps[k]`, like
    `T0`): since $N^iY(t_{k+1}) = \sum_ja_jN^{i+j}Y(t_k) + b_jN^{i+j}\beta_k$ (zero past
    $i + j = K$), no matrix product is needed beyond the first tables. Also applies to the
    tables contracted with a row vector (the load rows of eqs. 46/48).
    **Returns:** `(B, P + 1, n, ...)`."""
    n = T0.shape[1]
    lift = (None,) * (T0.ndim - 2)
    # upper triangular Toeplitz form of the shift: (A T)[i] = sum_j a_j T[i + j]
    gap = np.arange(n)[None, :] - np.arange(n)[:, None]  # m - i
    ahead = jnp.asarray(gap >= 0)

    def toeplitz(c):  # (B, n) -> (B, n, n, 1, ...)
        return jnp.where(ahead, c[:, np.maximum(gap, 0)], 0.0)[(Ellipsis,) + lift]

    out = [T0]
    for k, jump in enumerate(jumps):
        out.append(jump + jnp.sum(toeplitz(a_seg[:, k]) * out[-1][:, None]
                                  + toeplitz(b_seg[:, k]) * TW[:, k][:, None], axis=2))
    return jnp.stack(out, axis=1)


def moments_step_response(model: MomentLuGre2D, ts, vx, vy, omega, r, Fz, z0=None):
    r"""The moment system (eqs. 41-42) after a slip step, solved exactly (no time stepping).

    For inputs constant from `ts[0]` on (`vx`, `vy`, `omega` scalars: a step in slip, as in
    Fig. 17) from a uniform deflection `z0`, $v_r$, $C_{0i}$ and $\lambda = |\omega r|/L$ are
    constant, and tread reaches the piece edge $e_j$ at $t_j = e_jL/|\omega r|$. Per axis,
    with $Y = (\mu, z_e)$ the moments of every piece and the edge deflections, eqs. 41-42 and
    the edge equations (module docstring; exact here, since $t_e = t - e_jL/|\omega r|$) are
    between passages the linear system
    $$\dot Y = (-C_0I + \lambda N)Y + \beta_k,\qquad t\in[t_k, t_{k+1}),$$
    with $N$ the transport and boundary couplings (`coupling_matrix`) and $\beta_k$ the source
    $v_r$ less the arrival $e^{-C_0e_j/\lambda}v_r$ of undeflected tread at the edges reached;
    at $t_k$ the edge value $z_{e_k}$ jumps by $-e^{-C_0t_k}z_0$ (the old tread, deflected by
    the point model from $z_0$, leaves; no jump from rest). $N$ is nilpotent and commutes with
    $C_0I$, hence exactly, for $\tau = t - t_k$,
    $$Y(t) = \sum_{j=0}^{K}\Bigl(e^{-C_0\tau}\frac{(\lambda\tau)^j}{j!}N^jY(t_k)
      + \lambda^j\tau^{j+1}I_j(C_0\tau)\,N^j\beta_k\Bigr)$$
    (`decay_integrals`), and the forces and aligning moment follow from eqs. 46 and 48 with
    $\dot Y = (-C_0I + \lambda N)Y + \beta_k$. Those are linear in $Y$, so they need only
    $w_cN^jY(t_k)$ and $w_cN^j\beta_k$ for the three load rows $w_c$ ($F_x$, $F_y$, $M_z$):
    the model keeps $w_cN^j$ applied to the source pattern and to each edge deflection
    (`response_source`, `response_edges`), and a call works on tables of shape
    $(3, P+1, K+1)$, with no $(D, D)$ product (the moments themselves, `state`, take the full
    tables, and XLA drops them when only the forces are used). Written so that XLA CPU
    compiles it into few kernels with few independent branches (19 for one piece, 26 for
    the trapezoid): its runtime dispatches independent kernels to other threads, which
    costs more than the kernels at this size. This is the step response of the
    distributed PDE (eqs. 31-34) to rounding: from the last passage on
    ($t \ge L/|\omega r|$) it is the closed-form steady state exactly. Differentiable in
    everything (zero slip and a locked wheel, $\omega = 0$, included). For input histories use
    `simulate_moments`.

    **Arguments:** as `simulate_moments`, except that `vx`, `vy`, `omega` [m/s, rad/s] are
    constants (`Fz` may still be a signal: it scales the forces); `z0` (2,) [m], default 0.

    **Returns:** a `Tire2DSolution` whose `state` is the moments `(T, 2, P, K)` and whose
    `num_steps` is 0 (no steps are taken).
    """
    import diffrax as dfx
    import jax

    from .._signals import as_signal
    from .lugre2d import relative_velocity_2d
    from .transient import Tire2DSolution

    if not isinstance(model, MomentLuGre2D):
        raise TypeError(f"moments_step_response needs a MomentLuGre2D, got {type(model).__name__}")
    for name, x in (("vx", vx), ("vy", vy), ("omega", omega)):
        if callable(x) or jnp.ndim(x) != 0:
            raise TypeError(
                f"moments_step_response: {name} must be a scalar (inputs constant after the "
                f"step), got {'a callable' if callable(x) else f'shape {jnp.shape(x)}'}; for "
                "input histories use simulate_moments")
    ts = jnp.asarray(ts, dtype=float)
    fz_s = as_signal(ts, Fz)
    z0 = jnp.zeros(2) if z0 is None else jnp.asarray(z0, dtype=float)
    p = model.params
    P, K = model.pieces, model.n_moments
    n, PK = K + 1, P * K
    v_r = relative_velocity_2d(vx, vy, omega, r)
    c = jnp.abs(jnp.asarray(omega, dtype=float) * r)
    C0 = decay_rates(p, v_r)
    lam = c / p.L
    rolling = lam > 0
    lam_safe = jnp.where(rolling, lam, 1.0)
    edges = model.edges[1:]
    t_rel = ts - ts[0]
    passage = jnp.where(rolling, edges / lam_safe, jnp.inf)
    bounds = jnp.concatenate([jnp.zeros(1), jnp.minimum(passage, t_rel[-1])])
    arrival = jnp.exp(-C0[:, None] * edges[None, :] / lam_safe) * v_r[:, None]  # (2, P)
    fact = jnp.asarray(np.cumprod([1.0] + list(range(1, n))))

    def coefficients(tau):
        # a_j, b_j of Y(t_k + tau) = sum_j a_j N^j Y(t_k) + b_j N^j beta_k, shape (2, ..., n)
        x = C0[:, None] * tau[None, :]  # (2, S)
        ex = jnp.exp(-x)
        a = ex[..., None] * (_powers(lam * tau, n) / fact[None, :])[None]
        b = ((_powers(lam, n)[None, :] * tau[:, None] * _powers(tau, n))[None]
             * decay_integrals(x, n, ex))
        return a, b

    # the segment of each save time, and the coefficients over every whole segment and from
    # each save time's segment start, in one pass (2, P + T, n)
    seg = sum((t_rel >= passage[e]).astype(int) for e in range(P))  # (T,)
    a_all, b_all = coefficients(jnp.concatenate([bounds[1:] - bounds[:-1], t_rel - bounds[seg]]))
    a_seg, b_seg, a, b = a_all[:, :P], b_all[:, :P], a_all[:, P:], b_all[:, P:]
    # Where tread that entered after t_0 first reaches edge k, the edge value jumps from the
    # old tread's deflection to the new one's: by -exp(-C0 t_k) z0 (zero from rest).
    jump = -jnp.exp(-C0[None, :] * bounds[1:, None]) * z0[None, :]  # (P, 2)

    # Eqs. 46/48 are linear in (mu, mu_dot), so the forces need only the load rows
    # w_c N^i of the model (`response_source`, `response_edges`: w_c N^i applied to the
    # source pattern and to the edge deflections), contracted with the scalars: tables
    # G[c, k, i] = w_c . N^i Y(t_k) of shape (3, P + 1, n), no (D, D) product at call time.
    def per_output(x):  # F_x from the x moments, F_y and M_z from the y ones: x[[0, 1, 1]]
        # as slices, which XLA fuses into every consumer (a gather it runs on its own)
        return jnp.concatenate([x[:1], x[1:2], x[1:2]], axis=0)

    sig0, sig1, C = per_output(p.sigma0), per_output(p.sigma1), per_output(C0)
    src_rows, edge_rows = model.response_source, model.response_edges  # (3, n), (3, n, P)
    GW = jnp.stack([per_output(v_r)[:, None] * src_rows
                    - sum(edge_rows[..., e] * per_output(arrival)[:, e, None] for e in range(k))
                    for k in range(P + 1)], axis=1)  # w_c . N^i beta_k
    GU = _segment_starts(per_output(z0)[:, None] * src_rows, GW, per_output(a_seg),
                         per_output(b_seg),
                         [per_output(jump[k])[:, None] * edge_rows[..., k] for k in range(P)])

    def rates(G):  # sigma0 w.N^i Y + sigma1 w.N^i (-C0 Y + lambda N Y), i.e. eq. 46 less beta
        nxt = jnp.concatenate([G[..., 1:], jnp.zeros_like(G[..., :1])], axis=-1)
        return ((sig0 - sig1 * C)[:, None, None] * G + (sig1 * lam)[:, None, None] * nxt)

    FU, FW = rates(GU), rates(GW)
    Fb = sig1[:, None] * GW[..., 0]  # sigma1 w.beta_k (the source in mu_dot)
    const = (per_output(p.sigma2) * per_output(v_r)
             * jnp.stack([jnp.ones(()), jnp.ones(()), model.lever]))
    mu = (jnp.sum(per_output(a) * FU[:, seg] + per_output(b) * FW[:, seg], axis=-1) + Fb[:, seg]
          + const[:, None])  # (3, T)
    scale = jnp.stack([jnp.ones(()), jnp.ones(()), p.L])
    forces = jax.vmap(fz_s)(ts)[:, None] * mu.T * scale[None, :]

    # The moments themselves (dropped by XLA when only the forces are used): the same
    # recursion on the full tables N^i Y(t_k), N^i beta_k per axis, shape (2, P + 1, n, D).
    Npow = model.coupling_powers  # (n, D, D)
    # beta_k per axis and segment (2, P + 1, D); the initial state (2, D)
    reached = jnp.arange(P + 1)[:, None] > jnp.arange(P)[None, :]  # (P + 1, P): segment, edge
    beta = jnp.concatenate([
        jnp.broadcast_to((v_r[:, None] * model.src.ravel()[None, :])[:, None, :], (2, P + 1, PK)),
        v_r[:, None, None] - jnp.where(reached[None], arrival[:, None, :], 0.0)], axis=-1)
    y = jnp.concatenate([z0[:, None] * model.src.ravel()[None, :],
                         jnp.broadcast_to(z0[:, None], (2, P))], axis=-1)
    W = jnp.einsum("ide,ake->akid", Npow, beta)
    U = _segment_starts(jnp.einsum("ide,ae->aid", Npow, y), W, a_seg, b_seg,
                        [jump[k][:, None, None] * Npow[None, :, :, PK + k] for k in range(P)])
    Y = jnp.einsum("itn,itnd->tid", a, U[:, seg]) + jnp.einsum("itn,itnd->tid", b, W[:, seg])
    state = Y[..., :PK].reshape(-1, 2, P, K)
    return Tire2DSolution(ts=ts, state=state, forces=forces, result=dfx.RESULTS.successful,
                          num_steps=jnp.zeros((), dtype=int))
