r"""Exact closures of the moment system for inputs known in advance.

The edge values $z_i(t, e_j)$ are functionals of the input history alone
(`vehsim.tire.moments`, "The boundary terms"). Two exact ways to evaluate them:

- **delay** (`simulate_moments_delay`): the entry time $t_e$ of the tread now at each edge,
  the decay $D_e = \int_{t_e}^tC_0$ and $z_e$ are ODE states beside the moments, switched
  on at the first passages $t_p$ (`passage_times`), where the solve is split into segments;
- **history** (`simulate_moments_history`): a first solve of $(s, E_x, E_y, w_x, w_y)$ with
  dense output (`TransitHistory`), searched for $t_e$ at every right-hand side.
"""

from __future__ import annotations

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jaxtyping import Array, Float

from ..._checks import check_nonnegative
from ..._integrate import DEFLECTION_ATOL, MAX_STEPS, RTOL, integrate, solve_stats
from ..._results import RESULTS
from ..lugre2d import decay_rates, relative_velocity_2d
from ..transient import TireSolution, input_signals, inputs_at
from .model import MomentLuGre2D


HISTORY_MAX_STEPS = 4096
"""Default step budget of the history solve of `simulate_moments_history`: its dense output
is stored and searched at every edge lookup, so the buffer costs time in proportion."""


# --------------------------------------------------------------------------------------
# The input history and the entry times
# --------------------------------------------------------------------------------------


def _travelled(solution, x):
    return solution.evaluate(x)[0]


def _travel_rate(solution, x):
    return solution.derivative(x)[0]


def _bracketed_newton(solution, t, distance):
    r"""$x\in[0, t]$ with $s(x) = $ `distance` for the increasing $s$ of `solution`: Newton
    steps with $\dot s = c/L$ inside a shrinking bracket, bisection where a step leaves it
    (locked phases, $\dot s = 0$)."""
    tol = 1e-14 * (1.0 + jnp.abs(distance))

    def body(carry):
        x, lo, hi, _, it = carry
        f = _travelled(solution, x) - distance
        lo = jnp.where(f <= 0, x, lo)
        hi = jnp.where(f > 0, x, hi)
        r = _travel_rate(solution, x)
        newton = x - f / jnp.where(r > 0, r, 1.0)
        ok = (r > 0) & (newton >= lo) & (newton <= hi)
        x_next = jnp.where(ok, newton, 0.5 * (lo + hi))
        # keep a converged iterate: the loop stops on the residual of `x`
        return jnp.where(jnp.abs(f) <= tol, x, x_next), lo, hi, f, it + 1

    def cond(carry):
        _, lo, hi, f, it = carry
        return (jnp.abs(f) > tol) & (hi - lo > 1e-15 * t) & (it < 200)

    r0 = _travel_rate(solution, t)
    ahead = (_travelled(solution, t) - distance) / jnp.where(r0 > 0, r0, 1.0)
    guess = jnp.clip(t - jnp.where(r0 > 0, ahead, 0.5 * t), 0.0, t)
    init = (guess, jnp.zeros_like(t), t, jnp.asarray(jnp.inf), jnp.asarray(0))
    return lax.while_loop(cond, body, init)[0]


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
        r"""$t_e\in[0,t]$ with $s(t_e) = $ `distance` ($\le s(t)$): safeguarded Newton
        (`_bracketed_newton`, which sees no tangents), then one Newton step outside it so
        that gradients follow the implicit function theorem."""
        frozen = jax.tree_util.tree_map(
            lambda x: lax.stop_gradient(x) if eqx.is_array(x) else x, self.solution)
        x = lax.stop_gradient(
            _bracketed_newton(frozen, lax.stop_gradient(t), lax.stop_gradient(distance)))
        r = _travel_rate(self.solution, x)
        f = _travelled(self.solution, x) - distance
        return x - jnp.where(r > 0, f / jnp.where(r > 0, r, 1.0), 0.0)

    def edge_deflections(self, t, edges):
        r"""$z_i(t, e)$ for `edges` (P,) in $(0, 1]$, shape `(2, P)` (class docstring)."""
        s, E, w = self._at(t)

        def one(e):
            entered = s >= e
            t_e = self.entry_time(t, jnp.where(entered, s - e, 0.0))
            _, E_e, w_e = self._at(jnp.where(entered, t_e, 0.0))
            new_tread = w - jnp.exp(-(E - E_e)) * w_e
            old_tread = w + jnp.exp(-E) * self.z0
            return jnp.where(entered, new_tread, old_tread)

        return jax.vmap(one, out_axes=1)(edges)


def passage_times(c_of_t, t0, t1, distances, L, nodes: int = 32):
    r"""First times $t_p\in[t_0, t_1]$ with $\int_{t_0}^{t_p}c/L = $ `distances` (P,), by Newton
    on a `nodes`-point Gauss-Legendre quadrature of the transport speed; $t_1$ where the
    tread has not travelled that far by $t_1$. The iterations see no tangents; one last
    Newton step outside them gives the implicit-function gradient."""
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


# --------------------------------------------------------------------------------------
# Shared by the two closures
# --------------------------------------------------------------------------------------


def _slip(signals, r, t):
    """$(v_r, c = |\\omega r|)$ at time `t` from the input signals `(vx, vy, omega, Fz)`."""
    vx_s, vy_s, om_s, _ = signals
    return relative_velocity_2d(vx_s(t), vy_s(t), om_s(t), r), jnp.abs(om_s(t) * r)


def _forces(model, fz_s, t, m, m_dot, v_r):
    """$(F_x, F_y, M_z)$ [N, N, N m] from the moments and their rates (eqs. 46, 48)."""
    scale = jnp.stack([jnp.ones(()), jnp.ones(()), model.params.L])
    return fz_s(t) * model.mu_from_moments(m, m_dot, v_r) * scale


def _prepare(name, model, ts, vx, vy, omega, Fz, z0):
    if not isinstance(model, MomentLuGre2D):
        raise TypeError(f"{name} needs a MomentLuGre2D, got {type(model).__name__}")
    if not callable(Fz):
        check_nonnegative(name, "Fz", Fz)
    ts = jnp.asarray(ts, dtype=float)
    z0 = jnp.zeros(2) if z0 is None else jnp.asarray(z0, dtype=float)
    return ts, input_signals(ts, vx, vy, omega, Fz), z0


# --------------------------------------------------------------------------------------
# The delay closure
# --------------------------------------------------------------------------------------


class _SegmentClock(eqx.Module):
    r"""One solve in a segment clock $\tau\in[0, P+1]$: segment $k = [t_k, t_{k+1}]$ (between
    passages, `bounds` $= (t_0, t_{p,1}, \dots, t_{p,P}, t_1)$) is $\tau\in[k, k+1]$,
    $t = t_k + (\tau - k)(t_{k+1} - t_k)$. The switches sit at the integers (fixed jumps of the
    solver) and the passage times enter only through this map, so they are differentiated
    like any other parameter."""

    bounds: Float[Array, " P2"]
    width: Float[Array, " P1"]

    def __init__(self, bounds):
        self.bounds = bounds
        self.width = bounds[1:] - bounds[:-1]

    @property
    def pieces(self) -> int:
        return self.width.shape[0] - 1

    def __call__(self, tau):
        """(segment, t, dt/dtau) at clock time `tau`."""
        k = jnp.clip(jnp.floor(tau), 0, self.pieces).astype(int)
        return k, self.bounds[k] + (tau - k) * self.width[k], self.width[k]

    def to_tau(self, t):
        """Clock time of the times `t`."""
        k = jnp.clip(jnp.searchsorted(self.bounds, t, side="right") - 1, 0, self.pieces)
        w = self.width[k]
        frac = jnp.where(w > 0, (t - self.bounds[k]) / jnp.where(w > 0, w, 1.0), 0.0)
        return k + jnp.clip(frac, 0.0, 1.0)


def _delay_rates(model, slip, z0, t, y, entered):
    r"""Rates of the delay-closure state `y` = (moments, $y_e$, $D_e$, $t_e$) at time `t`, with
    `entered` (P,) the edges whose first passage is past; $z_e = y_e$ once entered, else
    $y_e + e^{-D_e}z_0$ (the old tread). **Returns:** `(dy, m, m_dot, v_r)`."""
    P, K = model.pieces, model.n_moments
    m, ye, D, te = jnp.split(y, np.cumsum([2 * P * K, 2 * P, 2 * P]))
    m, ye, D = m.reshape(2, P, K), ye.reshape(2, P), D.reshape(2, P)
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


def _landing_taus(clock, speed, t1, edges, L, kinks):
    """Clock times to land steps on: the segment switches and, given `kinks` (times where the
    inputs kink), those times and their arrival at every edge."""
    jumps = jnp.arange(1.0, clock.pieces + 1.0)
    if kinks is None:
        return jumps
    T = jnp.atleast_1d(jnp.asarray(kinks, dtype=float))
    arrive = jax.vmap(lambda tk: passage_times(speed, tk, t1, edges, L))(T)
    kink_taus = lax.stop_gradient(clock.to_tau(jnp.concatenate([T, arrive.ravel()])))
    return jnp.sort(jnp.concatenate([jumps, kink_taus]))


def simulate_moments_delay(
    model: MomentLuGre2D,
    ts,
    vx,
    vy,
    omega,
    r,
    Fz,
    z0=None,
    *,
    kinks=None,
    solver: dfx.AbstractSolver | None = None,
    rtol: float = RTOL,
    atol: float = DEFLECTION_ATOL,
    max_steps: int = MAX_STEPS,
    throw: bool = True,
) -> TireSolution:
    r"""Exact method of moments for inputs known in advance (eqs. 39-48, no closure error):
    the edge values from delay states.

    `MomentLuGre2D` as an `AbstractTire` closes the edge values with inputs frozen over a
    transit, exact only for piecewise-constant inputs. When the inputs are given as functions
    of time (as in Fig. 17, or a recorded manoeuvre) the edge values are functionals of the
    input history, and the moment ODE of eqs. 41-42 uses the exact $z_i(t, e_j)$ at every
    piece edge, here from the entry times $t_e$ carried as ODE states beside the moments: one
    solve, its steps landed on the first passage of tread over each edge. It needs
    $c(t_e) > 0$: for tread that entered while the wheel was locked use
    `simulate_moments_history`. The result equals the distributed PDE (eqs. 31-34) up to
    solver tolerance for any such input history and any piecewise-polynomial load.

    The edge equations switch on at the passage times $t_p$ (sorted, as the edges are): the
    solve runs on a `_SegmentClock` with a fixed set of edges reached in each segment, so
    the switch falls between steps and its gradient (through $t_p$, e.g. in the wheel speed)
    comes from the segment bounds.

    **Arguments:** as `simulate_tire` for a combined-slip tire (`vx`, `vy`, `omega`, `Fz`
    constants, samples on `ts` or callables of `t`; `r` [m]), plus `z0` (2,), the uniform
    initial deflection [m] (default 0); `kinks`: times where the inputs have a kink or a
    jump (the end of a ramp), where steps are landed, and on their arrival at every edge,
    where they kink the edge values. `solver` defaults to `Tsit5`; `rtol`, `atol`,
    `max_steps` as in `simulate_tire`.

    **Returns:** a `TireSolution` whose `state` is the moments `(T, 2, P, K)`.
    """
    ts, signals, z0 = _prepare("simulate_moments_delay", model, ts, vx, vy, omega, Fz, z0)
    P, L, edges = model.pieces, model.params.L, model.edges[1:]
    t0, t1 = ts[0], ts[-1]

    def slip(t):
        return _slip(signals, r, t)

    def speed(t):
        return slip(t)[1]

    clock = _SegmentClock(jnp.concatenate([t0[None], passage_times(speed, t0, t1, edges, L),
                                           t1[None]]))

    def rates(tau, y):
        k, t, w = clock(tau)
        return t, w, _delay_rates(model, slip, z0, t, y, jnp.arange(P) < k)

    def field(tau, y, args):
        _, w, (dy, *_) = rates(tau, y)
        return w * dy

    def save(tau, y, args):
        # forces and moments only, not the edge states: under vmap every save writes the
        # whole batch's buffer, so a narrow buffer is cheaper than a vectorised pass after
        t, _, (_, m, m_dot, v_r) = rates(tau, y)
        return _forces(model, signals[3], t, m, m_dot, v_r), m

    y0 = jnp.concatenate([model.init_state(z0)[0].ravel(), jnp.zeros(4 * P), jnp.full(P, t0)])
    # the solve runs in the segment clock tau in [0, P + 1], saving at the clock times of ts
    sol = integrate(
        field, None, y0, solver=solver, t0=0.0, t1=float(P + 1), rtol=rtol, atol=atol,
        jump_ts=_landing_taus(clock, speed, t1, edges, L, kinks), max_steps=max_steps,
        saveat=dfx.SaveAt(ts=clock.to_tau(ts), fn=save), throw=throw,
    )
    forces, moments = sol.ys
    return TireSolution(ts=ts, state=moments, forces=forces, inputs=inputs_at(ts, signals),
                        result=sol.result, stats=solve_stats(sol))


# --------------------------------------------------------------------------------------
# The history closure
# --------------------------------------------------------------------------------------


def _solve_history(model, ts, slip, **options):
    r"""Dense solution of $(s, E_x, E_y, w_x, w_y)$ from rest (`TransitHistory`)."""
    L = model.params.L

    def history_field(t, h, args):
        v_r, c = slip(t)
        C0 = decay_rates(model.params, v_r)
        return jnp.concatenate([(c / L)[None], C0, v_r - C0 * h[3:5]])

    return integrate(history_field, ts, jnp.zeros(5), saveat=dfx.SaveAt(dense=True), **options)


def _first_passages(history, ts, edges):
    r"""First passage of tread over each edge ($s = e$, a kink of $z(t, e)$; `ts[-1]` if
    never), as step times for the moment solve."""
    s_end = history.solution.evaluate(ts[-1])[0]
    passage = jax.vmap(lambda e: history.entry_time(ts[-1], e))(jnp.minimum(edges, s_end))
    return lax.stop_gradient(jnp.where(edges <= s_end, passage, ts[-1]))


def simulate_moments_history(
    model: MomentLuGre2D,
    ts,
    vx,
    vy,
    omega,
    r,
    Fz,
    z0=None,
    *,
    solver: dfx.AbstractSolver | None = None,
    rtol: float = RTOL,
    atol: float = DEFLECTION_ATOL,
    max_steps: int = MAX_STEPS,
    history_solver: dfx.AbstractSolver | None = None,
    history_rtol: float | None = None,
    history_atol: float | None = None,
    history_max_steps: int = HISTORY_MAX_STEPS,
    throw: bool = True,
) -> TireSolution:
    r"""Exact method of moments for inputs known in advance (eqs. 39-48, no closure error):
    the edge values from the input history.

    As `simulate_moments_delay`, with the exact $z_i(t, e_j)$ from a first solve of five
    history states with dense output (`TransitHistory`), searched by safeguarded Newton for
    the entry times at every right-hand side: it also handles tread that entered while the
    wheel was locked ($c(t_e) = 0$, where the delay states fail), and is the slower of the
    two.

    **Arguments:** as `simulate_moments_delay` (without `kinks`: the first passages are found
    in the history), plus the history solve's `history_solver`, `history_rtol`,
    `history_atol` (default: those of the moment solve) and `history_max_steps` (default
    `HISTORY_MAX_STEPS`), which bounds it. Its dense output is stored and every edge lookup
    searches it, so a buffer far larger than needed costs time; a history needing more
    steps fails loudly (`throw=True`): raise it for long runs.

    **Returns:** a `TireSolution` whose `state` is the moments `(T, 2, P, K)`; its `result`
    is the history solve's where that failed, and its `stats` count the steps of both.
    """
    ts, signals, z0 = _prepare("simulate_moments_history", model, ts, vx, vy, omega, Fz, z0)
    edges = model.edges[1:]

    def slip(t):
        return _slip(signals, r, t)

    hist = _solve_history(
        model, ts, slip, solver=solver if history_solver is None else history_solver,
        rtol=rtol if history_rtol is None else history_rtol,
        atol=atol if history_atol is None else history_atol, max_steps=history_max_steps,
        throw=throw)
    history = TransitHistory(hist, z0)

    def rates(t, m):
        v_r, c = slip(t)
        z_e = history.edge_deflections(t, edges)
        zedge = jnp.concatenate([jnp.zeros((2, 1)), z_e], axis=1)
        return model.moment_rates(m, zedge, v_r, c), v_r

    sol = integrate(
        lambda t, m, args: rates(t, m)[0], ts, model.init_state(z0)[0], solver=solver,
        rtol=rtol, atol=atol, step_ts=_first_passages(history, ts, edges),
        max_steps=max_steps, throw=throw,
    )

    def force_at(t, m):
        m_dot, v_r = rates(t, m)
        return _forces(model, signals[3], t, m, m_dot, v_r)

    forces = jax.vmap(force_at)(ts, sol.ys)
    result = RESULTS.where(hist.result == RESULTS.successful, sol.result, hist.result)
    stats = jax.tree.map(lambda a, b: a + b, solve_stats(hist), solve_stats(sol))
    return TireSolution(ts=ts, state=sol.ys, forces=forces, inputs=inputs_at(ts, signals),
                        result=result, stats=stats)
