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

The only term that is not a function of the current state and inputs is the *delayed*
arrival term (with $C_0 = 0$ the trailing edge obeys $\dot z(t,1) = v_r(t) - v_r(t_e)$, a
delay equation), so no finite state closes it for arbitrary inputs. But the edge values
are functionals of the *input history alone* (the coefficients $v_r$, $C_0$, $c$ do not
depend on $z$), which gives two ways to close eqs. 41-42:

- **Exact, for inputs known in advance** (`simulate_moments`, the transients of Fig. 17,
  a recorded manoeuvre): a first solve integrates five history states (tread travelled,
  $\int C_0$, and the point model from rest) with dense output, and `TransitHistory`
  returns the exact $z_i(t, e)$ at every edge from them and the entry time $t_e$. The
  moment system then reproduces the PDE for *any* input history and any piecewise
  polynomial load, up to solver tolerance.
- **Online** (this class as an `AbstractTire` inside a vehicle, where the inputs depend on
  the state): we carry $z_e$ for every edge and $s$ as states, with the arrival term
  evaluated with the inputs frozen over the transit ($\dot t_e = 1$,
  $e^{-\int C_0} = e^{-C_0eL/c}$, $v_r(t_e) = v_r(t)$; zero for a locked wheel, $c = 0$).
  This is exact whenever the inputs are constant since the last passage began: for a slip
  step from a uniform deflection the whole moment system is exact at all times, and at
  every steady state $z_e = \frac{v_rL}{c}e\,\varphi(\frac{C_0L}{c}e)$,
  $\varphi(x) = (1-e^{-x})/x$, the closed form. Otherwise it errs through the arrival
  term, damped by $e^{-C_0eL/c}$.

Loads that vanish at the trailing edge (quartic, trapezoid) do not escape this: the force
combination $\sum_kc_km_k$ has no trailing-edge term, but the chain $q\to q'\to\dots\to$ const
of lower moments it needs ends in $m_0$, whose equation (42) carries $z(t,1)$. The moment
system is also badly conditioned in the edge values: the interior of the PDE never depends
on the outflow value $z(t,1)$, but the moments do, and an error $\delta$ in it reaches $m_p$
with steady gain $\sum_{j\le p}\frac{p!}{j!}\bigl(\frac{c}{LC_0}\bigr)^{p-j+1}$ (~100 for
$p = 5$ at $c/(LC_0)\approx0.8$), which the alternating load coefficients
($\sum|c_k|\approx100$ for the quartic) amplify again; hence the exact closure, and tight
tolerances (rtol 1e-8) for the quartic.

**Accuracy, measured** (`tests/test_moments.py`, `experiments/benchmarks/moments_vs_pde.py`,
worst of F_x, F_y, M_z relative to its peak, against the PDE at n = 96-128): slip steps from
an undeflected patch, either closure, < 1e-4 at rtol 1e-8 and the closed-form steady state
to 1e-6; slip-angle ramps over 10 ms (one transit) and 100 ms at 20 m/s, alpha = 4 and
15 deg: exact closure < 2.2e-4 at rtol 1e-8 for uniform, trapezoidal and quartic loads
(the frozen online closure errs by 0.20/1.8/20 (10 ms) and 0.46/1.9/3e2 (100 ms) there).

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
        ints = self._ints(self.n_moments)[2]
        z_edge = jnp.broadcast_to(z0[:, None], (2, self.pieces))
        return (z0[:, None, None] * ints[None, :, :], z_edge, jnp.zeros(()))

    def edge_values(self, state):
        r"""$z_i(t, e_j)$ at every piece edge, shape `(2, P+1)` ($z = 0$ at the leading edge)."""
        z_edge = state[1]
        return jnp.concatenate([jnp.zeros_like(z_edge[:, :1]), z_edge], axis=1)

    def _ints(self, K):
        a, b = self.edges[:-1], self.edges[1:]
        pa, pb = _powers(a, K + 1), _powers(b, K + 1)
        return pa, pb, (pb[:, 1:] - pa[:, 1:]) / jnp.arange(1, K + 1)[None, :]

    def moment_rates(self, m, zedge, v_r, c):
        r"""Eqs. 41-42 for moments `m` (2, P, K) given the deflections at every piece edge,
        `zedge` (2, P+1) (leading edge first)."""
        K = self.n_moments
        C0 = decay_rates(self.params, v_r)
        pa, pb, ints = self._ints(K)
        boundary = zedge[:, 1:, None] * pb[None, :, :K] - zedge[:, :-1, None] * pa[None, :, :K]
        p = jnp.arange(K)
        lower = jnp.concatenate([jnp.zeros_like(m[..., :1]), m[..., :-1]], axis=-1)
        return (
            v_r[:, None, None] * ints[None, :, :]
            - C0[:, None, None] * m
            - (c / self.params.L) * boundary
            + (c / self.params.L) * p[None, None, :] * lower
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
        K = self.n_moments
        agg = p.sigma0[:, None, None] * m + p.sigma1[:, None, None] * m_dot  # (2, P, K)
        f = jnp.sum(self.coeffs[None, :, :] * agg[:, :, : K - 1], axis=(1, 2)) + p.sigma2 * v_r
        lever_terms = 0.5 * agg[1, :, : K - 1] - agg[1, :, 1:]
        mz = jnp.sum(self.coeffs * lever_terms) + p.sigma2[1] * v_r[1] * self.lever
        return jnp.stack([f[0], f[1], mz])

    def mu(self, state, v_r, c):
        r"""$(F_x/F_n, F_y/F_n, M_z/(F_nL))$ (eqs. 46 and 48, our sign)."""
        return self.mu_from_moments(state[0], self.derivative(state, v_r, c)[0], v_r)

    def mean_deflection(self, state):
        r"""$\bar z_i = \int_0^1 z_i q\,d\xi$ (eq. 20 per axis) [m]."""
        K = self.n_moments
        return jnp.sum(self.coeffs[None, :, :] * state[0][:, :, : K - 1], axis=(1, 2))



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
    solver=None,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 100_000,
    history_max_steps: int = 4096,
    throw: bool = True,
):
    r"""Exact method of moments for inputs known in advance (eqs. 39-48, no closure).

    `MomentLuGre2D` as an `AbstractTire` closes the edge values with inputs frozen over a
    transit, exact only for piecewise-constant inputs. When the inputs are given as functions
    of time (as in Fig. 17, or a recorded manoeuvre) the edge values are instead functionals
    of the input history (`TransitHistory`): a first solve integrates the five history states
    $(s, E, w)$ with dense output, and the moment ODE of eqs. 41-42 then uses the exact
    $z_i(t, e_j)$ at every piece edge. The result equals the distributed PDE (eqs. 31-34) up
    to solver tolerance for *any* input history and any piecewise-polynomial load.

    **Arguments:** as `simulate_tire_2d` (`vx`, `vy`, `omega`, `Fz` constants, samples on
    `ts` or callables of `t`; `r` [m]), plus `z0` (2,), the uniform initial deflection [m]
    (default 0). `solver` defaults to `Tsit5` for both solves. `history_max_steps` bounds the
    history solve, whose dense output is stored: every edge lookup searches it, so a buffer
    far larger than needed costs time (100 000 slots made a 30 ms transient 5x slower than
    4096). A history needing more steps fails loudly (`throw=True`); raise it for long runs.

    **Returns:** a `Tire2DSolution` whose `state` is the moments `(T, 2, P, K)`.
    """
    import diffrax as dfx
    import jax

    from .lugre2d import Tire2DSolution, relative_velocity_2d
    from .transient import as_signal

    if not isinstance(model, MomentLuGre2D):
        raise TypeError(f"simulate_moments needs a MomentLuGre2D, got {type(model).__name__}")
    ts = jnp.asarray(ts, dtype=float)
    vx_s, vy_s, om_s, fz_s = (as_signal(ts, x) for x in (vx, vy, omega, Fz))
    z0 = jnp.zeros(2) if z0 is None else jnp.asarray(z0, dtype=float)
    L = model.params.L
    solver = dfx.Tsit5() if solver is None else solver
    controller = dfx.PIDController(rtol=rtol, atol=atol)

    def slip(t):
        return (relative_velocity_2d(vx_s(t), vy_s(t), om_s(t), r),
                jnp.abs(om_s(t) * r))

    def history_field(t, h, args):
        v_r, c = slip(t)
        C0 = decay_rates(model.params, v_r)
        return jnp.concatenate([(c / L)[None], C0, v_r - C0 * h[3:5]])

    hist = dfx.diffeqsolve(
        dfx.ODETerm(history_field), solver, t0=ts[0], t1=ts[-1], dt0=None, y0=jnp.zeros(5),
        saveat=dfx.SaveAt(dense=True), stepsize_controller=controller,
        max_steps=history_max_steps, throw=throw,
    )
    history = TransitHistory(hist, z0)
    edges = model.edges[1:]

    def rates(t, m):
        v_r, c = slip(t)
        z_e = history.edge_deflections(t, edges)
        zedge = jnp.concatenate([jnp.zeros((2, 1)), z_e], axis=1)
        return model.moment_rates(m, zedge, v_r, c), v_r

    m0 = model.init_state(z0)[0]
    sol = dfx.diffeqsolve(
        dfx.ODETerm(lambda t, m, args: rates(t, m)[0]), solver, t0=ts[0], t1=ts[-1], dt0=None,
        y0=m0, saveat=dfx.SaveAt(ts=ts), stepsize_controller=controller, max_steps=max_steps,
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
