r"""The moment system after a slip step, solved exactly by finite sums (`moments_step_response`).

For inputs constant from $t_0$ on and a uniform initial deflection, the system of eqs. 41-42
with the edge equations is linear with constant coefficients between passages of tread over
the piece edges, and its coupling $N$ (`coupling_matrix`) is nilpotent: each segment is a
finite sum of powers of $N$ (`decay_integrals` for the source terms), and the segment starts
follow by a Toeplitz recursion (`_segment_starts`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..._results import RESULTS
from ..lugre2d import decay_rates, relative_velocity_2d
from ..transient import TireSolution, input_signals, inputs_at
from .basis import powers
from .model import MomentLuGre2D


def decay_integrals(x, n: int, exp_neg_x=None):
    r"""$I_j(x) = \int_0^1 e^{-xu}\,u^j/j!\,du$ for $j < n$, $x \ge 0$, shape `(..., n)`
    (`exp_neg_x`: $e^{-x}$ if the caller has it).

    Integration by parts gives $I_j = e^{-x}/(j+1)! + x\,I_{j+1}$, a recursion with positive
    terms only: below $x = 2$ it runs downwards from $I_{n-1}$ by its series
    $\sum_i (-x)^i/(i!\,(n-1)!\,(i+n))$ (24 terms; finite gradient at $x = 0$, where
    $I_j = 1/(j+1)!$). From $x = 2$ on, $I_j = P(j+1, x)/x^{j+1}$ with the regularised
    incomplete gamma function $P(j+1, x) = 1 - e^{-x}\sum_{i\le j}x^i/i!$, which loses at most
    ~2 digits to cancellation for $j \le 6$ (5 for $j = 10$). Each branch sees only arguments in
    its own range (double `where`); elementwise only, much cheaper than
    `jax.scipy.special.gammainc`."""
    x = jnp.asarray(x, dtype=float)
    small = x < 2.0
    xs = jnp.where(small, x, 0.0)[..., None]
    xl = jnp.where(small, 2.0, x)[..., None]
    fact = np.cumprod([1.0] + list(range(1, max(n, 24) + 1)))
    ex = jnp.exp(-x) if exp_neg_x is None else exp_neg_x
    e_s = jnp.where(small, ex, 1.0)[..., None]
    e_l = jnp.where(small, np.exp(-2.0), ex)[..., None]
    series = _decay_integrals_series(xs, e_s, n, fact)
    large = _decay_integrals_gamma(xl, e_l, n)
    return jnp.where(small[..., None], series, large)


def _decay_integrals_series(xs, e_s, n, fact):
    """$I_{n-1}$ by its series, then the recursion downwards (small arguments)."""
    top = jnp.zeros_like(xs)
    for i in range(23, -1, -1):
        top = top * xs + (-1.0) ** i / (fact[i] * fact[n - 1] * (i + n))
    series = [top]
    for j in range(n - 2, -1, -1):
        series.append(e_s / fact[j + 1] + xs * series[-1])
    return jnp.concatenate(series[::-1], -1)


def _decay_integrals_gamma(xl, e_l, n):
    r"""$(1 - e^{-x}\sum_{i\le j}x^i/i!)/x^{j+1}$ (large arguments)."""
    term, partial, power = jnp.ones_like(xl), [], []
    for k in range(n):
        partial.append(term if k == 0 else partial[-1] + term)
        power.append(xl if k == 0 else power[-1] * xl)
        term = term * xl / (k + 1)
    partial, power = jnp.concatenate(partial, -1), jnp.concatenate(power, -1)
    return (1.0 - e_l * partial) / power


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


class _Step(NamedTuple):
    r"""The constants of a slip step and the coefficients $a_j$, $b_j$ of every segment."""

    v_r: Float[Array, " 2"]
    C0: Float[Array, " 2"]
    lam: Float[Array, ""]
    arrival: Float[Array, "2 P"]  # e^{-C0 e_j / lambda} v_r: undeflected tread reaching e_j
    z0: Float[Array, " 2"]
    jump: Float[Array, "P 2"]  # the edge jump at each passage
    a_seg: Float[Array, "2 P n"]  # over each whole segment
    b_seg: Float[Array, "2 P n"]
    a: Float[Array, "2 T n"]  # from each save time's segment start
    b: Float[Array, "2 T n"]
    seg: Int[Array, " T"]  # the segment of each save time


def _step_coefficients(C0, lam, tau, n):
    r"""$a_j, b_j$ of $Y(t_k + \tau) = \sum_j a_jN^jY(t_k) + b_jN^j\beta_k$, shape `(2, S, n)`:
    $a_j = e^{-C_0\tau}(\lambda\tau)^j/j!$, $b_j = \lambda^j\tau^{j+1}I_j(C_0\tau)$."""
    fact = jnp.asarray(np.cumprod([1.0] + list(range(1, n))))
    x = C0[:, None] * tau[None, :]  # (2, S)
    ex = jnp.exp(-x)
    a = ex[..., None] * (powers(lam * tau, n) / fact[None, :])[None]
    b = ((powers(lam, n)[None, :] * tau[:, None] * powers(tau, n))[None]
         * decay_integrals(x, n, ex))
    return a, b


def _step(model: MomentLuGre2D, ts, vx, vy, omega, r, z0) -> _Step:
    """Passages, arrivals, jumps and the segment coefficients of a slip step at `ts[0]`."""
    p, P, n = model.params, model.pieces, model.n_moments + 1
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
    # the coefficients over every whole segment and from each save time's segment start,
    # in one pass (2, P + T, n)
    seg = sum((t_rel >= passage[e]).astype(int) for e in range(P))  # (T,)
    a_all, b_all = _step_coefficients(
        C0, lam, jnp.concatenate([bounds[1:] - bounds[:-1], t_rel - bounds[seg]]), n)
    # Where tread that entered after t_0 first reaches edge k, the edge value jumps from the
    # old tread's deflection to the new one's: by -exp(-C0 t_k) z0 (zero from rest).
    jump = -jnp.exp(-C0[None, :] * bounds[1:, None]) * z0[None, :]  # (P, 2)
    return _Step(v_r, C0, lam, arrival, z0, jump, a_all[:, :P], b_all[:, :P], a_all[:, P:],
                 b_all[:, P:], seg)


def _per_output(x):
    """`x[[0, 1, 1]]`: F_x from the x moments, F_y and M_z from the y ones (as slices)."""
    return jnp.concatenate([x[:1], x[1:2], x[1:2]], axis=0)


def _step_mu(model: MomentLuGre2D, s: _Step):
    r"""$(F_x/F_n, F_y/F_n, M_z/(F_nL))$ at the save times, shape `(3, T)`.

    Eqs. 46/48 are linear in $(\mu, \dot\mu)$, so they need only the load rows $w_cN^i$ of
    the model (`response_source`, `response_edges`) contracted with the step's scalars:
    tables $G[c, k, i] = w_c\cdot N^iY(t_k)$ of shape `(3, P + 1, n)`, no `(D, D)` product."""
    p, P = model.params, model.pieces
    sig0, sig1, C = _per_output(p.sigma0), _per_output(p.sigma1), _per_output(s.C0)
    src_rows, edge_rows = model.response_source, model.response_edges  # (3, n), (3, n, P)
    GW = jnp.stack([_per_output(s.v_r)[:, None] * src_rows
                    - sum(edge_rows[..., e] * _per_output(s.arrival)[:, e, None]
                          for e in range(k))
                    for k in range(P + 1)], axis=1)  # w_c . N^i beta_k
    GU = _segment_starts(_per_output(s.z0)[:, None] * src_rows, GW, _per_output(s.a_seg),
                         _per_output(s.b_seg),
                         [_per_output(s.jump[k])[:, None] * edge_rows[..., k] for k in range(P)])

    def rates(G):  # sigma0 w.N^i Y + sigma1 w.N^i (-C0 Y + lambda N Y), i.e. eq. 46 less beta
        nxt = jnp.concatenate([G[..., 1:], jnp.zeros_like(G[..., :1])], axis=-1)
        return ((sig0 - sig1 * C)[:, None, None] * G + (sig1 * s.lam)[:, None, None] * nxt)

    FU, FW = rates(GU), rates(GW)
    Fb = sig1[:, None] * GW[..., 0]  # sigma1 w.beta_k (the source in mu_dot)
    const = (_per_output(p.sigma2) * _per_output(s.v_r)
             * jnp.stack([jnp.ones(()), jnp.ones(()), model.lever]))
    return (jnp.sum(_per_output(s.a) * FU[:, s.seg] + _per_output(s.b) * FW[:, s.seg], axis=-1)
            + Fb[:, s.seg] + const[:, None])


def _step_moments(model: MomentLuGre2D, s: _Step):
    r"""The moments at the save times, `(T, 2, P, K)`: the recursion of `_step_mu` on the
    full tables $N^iY(t_k)$, $N^i\beta_k$ per axis, shape `(2, P + 1, n, D)`."""
    P, K = model.pieces, model.n_moments
    PK = P * K
    Npow = model.coupling_powers  # (n, D, D)
    # beta_k per axis and segment (2, P + 1, D); the initial state (2, D)
    reached = jnp.arange(P + 1)[:, None] > jnp.arange(P)[None, :]  # (P + 1, P): segment, edge
    beta = jnp.concatenate([
        jnp.broadcast_to((s.v_r[:, None] * model.src.ravel()[None, :])[:, None, :],
                         (2, P + 1, PK)),
        s.v_r[:, None, None] - jnp.where(reached[None], s.arrival[:, None, :], 0.0)], axis=-1)
    y = jnp.concatenate([s.z0[:, None] * model.src.ravel()[None, :],
                         jnp.broadcast_to(s.z0[:, None], (2, P))], axis=-1)
    W = jnp.einsum("ide,ake->akid", Npow, beta)
    U = _segment_starts(jnp.einsum("ide,ae->aid", Npow, y), W, s.a_seg, s.b_seg,
                        [s.jump[k][:, None, None] * Npow[None, :, :, PK + k] for k in range(P)])
    Y = (jnp.einsum("itn,itnd->tid", s.a, U[:, s.seg])
         + jnp.einsum("itn,itnd->tid", s.b, W[:, s.seg]))
    return Y[..., :PK].reshape(-1, 2, P, K)


def _check_step_inputs(model, vx, vy, omega):
    if not isinstance(model, MomentLuGre2D):
        raise TypeError(f"moments_step_response needs a MomentLuGre2D, got {type(model).__name__}")
    for name, x in (("vx", vx), ("vy", vy), ("omega", omega)):
        if callable(x) or jnp.ndim(x) != 0:
            raise TypeError(
                f"moments_step_response: {name} must be a scalar (inputs constant after the "
                f"step), got {'a callable' if callable(x) else f'shape {jnp.shape(x)}'}; for "
                "input histories use simulate_moments_delay")


def moments_step_response(model: MomentLuGre2D, ts, vx, vy, omega, r, Fz, z0=None):
    r"""The moment system (eqs. 41-42) after a slip step, solved exactly (no time stepping).

    For inputs constant from `ts[0]` on (`vx`, `vy`, `omega` scalars: a step in slip, as in
    Fig. 17) from a uniform deflection `z0`, $v_r$, $C_{0i}$ and $\lambda = |\omega r|/L$ are
    constant, and tread reaches the piece edge $e_j$ at $t_j = e_jL/|\omega r|$. Per axis,
    with $Y = (\mu, z_e)$ the moments of every piece and the edge deflections, eqs. 41-42 and
    the edge equations (exact here, since $t_e = t - e_jL/|\omega r|$) are between passages
    the linear system
    $$\dot Y = (-C_0I + \lambda N)Y + \beta_k,\qquad t\in[t_k, t_{k+1}),$$
    with $N$ the transport and boundary couplings (`coupling_matrix`) and $\beta_k$ the source
    $v_r$ less the arrival $e^{-C_0e_j/\lambda}v_r$ of undeflected tread at the edges reached;
    at $t_k$ the edge value $z_{e_k}$ jumps by $-e^{-C_0t_k}z_0$ (the old tread, deflected by
    the point model from $z_0$, leaves; no jump from rest). $N$ is nilpotent and commutes with
    $C_0I$, hence exactly, for $\tau = t - t_k$,
    $$Y(t) = \sum_{j=0}^{K}\Bigl(e^{-C_0\tau}\frac{(\lambda\tau)^j}{j!}N^jY(t_k)
      + \lambda^j\tau^{j+1}I_j(C_0\tau)\,N^j\beta_k\Bigr)$$
    (`decay_integrals`), and the forces and aligning moment follow from eqs. 46 and 48 with
    $\dot Y = (-C_0I + \lambda N)Y + \beta_k$. Those are linear in $Y$, so the forces need
    only the load rows $w_cN^j$ that the model keeps (`_step_mu`); the moments themselves
    (`state`) take the full tables, and XLA drops them when only the forces are used. This is
    the step response of the distributed PDE (eqs. 31-34) to rounding: from the last passage
    on ($t \ge L/|\omega r|$) it is the closed-form steady state exactly. Differentiable in
    everything (zero slip and a locked wheel, $\omega = 0$, included). For input histories
    use `simulate_moments_delay`.

    **Arguments:** as `simulate_moments_delay`, except that `vx`, `vy`, `omega` [m/s, rad/s] are
    constants (`Fz` may still be a signal: it scales the forces); `z0` (2,) [m], default 0.

    **Returns:** a `TireSolution` whose `state` is the moments `(T, 2, P, K)` and whose
    `stats["num_steps"]` is 0 (no steps are taken).
    """
    _check_step_inputs(model, vx, vy, omega)
    ts = jnp.asarray(ts, dtype=float)
    signals = input_signals(ts, vx, vy, omega, Fz)
    fz_s = signals[3]
    z0 = jnp.zeros(2) if z0 is None else jnp.asarray(z0, dtype=float)
    step = _step(model, ts, vx, vy, omega, r, z0)
    scale = jnp.stack([jnp.ones(()), jnp.ones(()), model.params.L])
    forces = jax.vmap(fz_s)(ts)[:, None] * _step_mu(model, step).T * scale[None, :]
    return TireSolution(ts=ts, state=_step_moments(model, step), forces=forces,
                        inputs=inputs_at(ts, signals), result=RESULTS.successful,
                        stats={"num_steps": jnp.zeros((), dtype=int)})
