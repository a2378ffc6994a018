r"""Forward sensitivities of the open-loop force: exact derivatives of the discrete scheme of
`friction_state`, for the Levenberg-Marquardt Jacobian.

A step of the exponential midpoint rule, $z^+ = z + \varphi(a)(b - az)$ ($b = hv_r$ does not
depend on the parameters), has the tangent along $\dot a$
$$\dot z^+ = e^{-a}\dot z + \varphi(a)\,\dot a\,w,\qquad
w = \frac{\varphi'(a)(b - az) - \varphi(a)z}{\varphi(a)},$$
the same linear recurrence with its own forcing: the tangents of all directions are solved
together, by the same diffrax solver, as the columns of vector-valued solves. The partials
of $a$ (eqs. 10, 22, 25) and of the force (eq. 23) are written by hand.
"""

from __future__ import annotations

from collections.abc import Sequence

import diffrax as dfx
import jax
import jax.numpy as jnp
import numpy as np

from .._fields import float_array
from .._integrate import integrate
from .._math import one_minus_exp_over, safe_abs
from ..solvers.exponential import StepMapSolver, StepMapTerm
from ..tire.lugre import LumpedLuGre
from .braking import BrakingData
from .friction_state import linear_solve, steady_friction_state, substep_midpoints
from .parameters import PARAMETER_NAMES


# the u-directions that move only the force of eq. 23, not the friction state
FORCE_ONLY = np.array([n in ("sigma1", "sigma2") for n in PARAMETER_NAMES])


def lumped_parameters(model: LumpedLuGre):
    r"""$q = (\theta, \sigma_0, \kappa, \mu_c, \mu_s, v_s, \alpha, \sigma_1, \sigma_2)$."""
    p = model.params
    return jnp.stack([float_array(x) for x in (
        p.theta, p.sigma0, model.kappa0 / p.L, p.mu_c, p.mu_s, p.v_s, p.alpha, p.sigma1,
        p.sigma2)])


def decay_rate_partials(q, v_r, omega_r):
    r"""$\partial a/\partial(\theta, \sigma_0, \kappa, \mu_c, \mu_s, v_s, \alpha)$, shape
    `(n, 7)`, of $a = \theta\sigma_0|v_r|/g + \kappa|\omega r|$ (eqs. 10, 22, 25).

    With $s = |v_r/v_s|^\alpha$, $E = e^{-s}$, $g = \mu_c + (\mu_s-\mu_c)E$,
    $A = \theta\sigma_0|v_r|/g$ and $w = A(\mu_s-\mu_c)Es/g$:
    $(\sigma_0|v_r|/g,\ \theta|v_r|/g,\ |\omega r|,\ -A(1-E)/g,\ -AE/g,\ -w\alpha/v_s,
    \ w\ln|v_r/v_s|)$, all finite (zero where needed) at $v_r = 0$. By hand: cheaper than a
    JVP through the `jnp.where`s of eq. 10.
    """
    theta, sigma0, _, mu_c, mu_s, v_s, alpha = (q[i] for i in range(7))
    abs_vr = safe_abs(v_r)
    x = abs_vr / v_s
    pos = x > 0
    log_x = jnp.where(pos, jnp.log(jnp.where(pos, x, 1.0)), 0.0)
    s = jnp.where(pos, jnp.exp(alpha * log_x), 0.0)
    E = jnp.exp(-s)
    g = mu_c + (mu_s - mu_c) * E
    c = abs_vr / g
    A_g = theta * sigma0 * c / g
    w = A_g * (mu_s - mu_c) * E * s
    return jnp.stack([sigma0 * c, theta * c, safe_abs(omega_r), -A_g * (1.0 - E), -A_g * E,
                      -w * alpha / v_s, w * log_x], axis=-1)


def _decay_rate_from_partials(q, P):
    r"""$a = \theta\,\partial a/\partial\theta + \kappa\,\partial a/\partial\kappa$ from the
    partials `P` of `decay_rate_partials` ($a$ is 1-homogeneous in $\theta$ and $\kappa$)."""
    return q[0] * P[:, 0] + q[2] * P[:, 2]


def phi_and_log_slope(a):
    r"""$\varphi(a)$ and $\varphi'(a)/\varphi(a)$, $\varphi(x) = (1 - e^{-x})/x$."""
    phi, dphi = jax.jvp(one_minus_exp_over, (a,), (jnp.ones_like(a),))
    return phi, dphi / phi


def tangent_weight(log_slope, a, b, z):
    r"""$w = (\varphi'(a)(b - az) - \varphi(a)z)/\varphi(a)$, $z$ at the step start."""
    return log_slope * (b - a * z) - z


def solve_columns(a, b, y0, adjoint):
    """`linear_solve` of the columns of `b` (steps, k) sharing the decay `a` (steps,), at most
    8 columns per solve (wider solves save their trajectories much more slowly)."""
    chunks = -(-b.shape[1] // 8)
    return jnp.concatenate([linear_solve(a, bi, yi, adjoint) for bi, yi in zip(
        jnp.array_split(b, chunks, axis=1), jnp.array_split(y0, chunks))], axis=1)


def state_and_tangent_solve(a, b, da, z0, dz0, adjoint):
    r"""$\bar z$ and its tangents $\dot z_j$ ($j \le 5$) in one diffrax solve of the
    augmented state $y = (\bar z, \dot z_1, \dots)$, per unit step
    $\bar z^+ = e^{-a}\bar z + \varphi(a)b$, $\dot z_j^+ = e^{-a}\dot z_j +
    \varphi(a)\,\dot a_j w(\bar z)$: the numbers of `linear_solve` followed by
    `solve_columns`, in one pass.

    At most 5 tangents: beyond that, a step of the augmented solve costs more than the
    steps of two separate solves (docs/performance.md).
    """
    num = a.shape[0]
    phi, ratio = phi_and_log_slope(a)
    decay, phi_b, phi_da = jnp.exp(-a), phi * b, phi[:, None] * da

    def step_map(s, y, args):
        m = jnp.clip(jnp.floor(s).astype(int), 0, num - 1)
        w = tangent_weight(ratio[m], a[m], b[m], y[0])
        return decay[m] * y + jnp.concatenate([phi_b[m][None], w * phi_da[m]])

    # the exact step map in unit steps (forward-mode sensitivities share the solve), every
    # step saved, the buffer exactly as long as the steps
    sol = integrate(
        StepMapTerm(step_map), None, jnp.concatenate([z0[None], dz0]), solver=StepMapSolver(),
        t0=0.0, t1=float(num), dt0=1.0, stepsize_controller=dfx.ConstantStepSize(),
        saveat=dfx.SaveAt(steps=True), max_steps=num, adjoint=adjoint,
    )
    return sol.ys


def _state_tangents(q, dq, model: LumpedLuGre, d: BrakingData, substeps: int, dz0):
    r"""$\bar z(t_k)$ and its tangents (rows) along the parameter tangents `dq` (rows),
    from the initial tangents `dz0`."""
    fm = dfx.ForwardMode()
    v_mid, om_mid, h = substep_midpoints(d, substeps)
    v_r_mid = d.r * om_mid - v_mid
    P = decay_rate_partials(q, v_r_mid, om_mid * d.r)
    # the coefficients of `coefficients`, a from the same partials
    a, b = h * _decay_rate_from_partials(q, P), h * v_r_mid
    z0 = steady_friction_state(model, d.v[0], d.omega[0], d.r)
    da = h[:, None] * (P @ dq[:, :7].T)  # (steps, directions)
    if dq.shape[0] <= 5:  # state and tangents in one solve
        ys = state_and_tangent_solve(a, b, da, z0, dz0, fm)
        zs, xs = ys[:, 0], ys[:, 1:]
    else:
        zs = linear_solve(a, b, z0, fm)
        z_start = jnp.concatenate([z0[None], zs[:-1]])
        _, ratio = phi_and_log_slope(a)
        xs = solve_columns(a, da * tangent_weight(ratio, a, b, z_start)[:, None], dz0, fm)
    z = jnp.concatenate([z0[None], zs[substeps - 1::substeps]])
    dz = jnp.concatenate([dz0[:, None], xs[substeps - 1::substeps].T], axis=1)
    return z, dz


def _force_tangents(q, dq, z, dz, d: BrakingData):
    r"""Eq. 23, $F = (\sigma_0\bar z + \sigma_1(v_r - a\bar z) + \sigma_2 v_r)F_n$ ($a$ at the
    samples), and its tangents (rows) along `dq` and `dz`."""
    v_r, om_r = d.r * d.omega - d.v, d.r * d.omega
    P = decay_rate_partials(q, v_r, om_r)
    a_k = _decay_rate_from_partials(q, P)
    da_k = dq[:, :7] @ P.T
    sigma0, sigma1, sigma2 = q[1], q[7], q[8]
    zdot = v_r - a_k * z
    F = (sigma0 * z + sigma1 * zdot + sigma2 * v_r) * d.F_n
    dF = (dq[:, 1:2] * z[None, :] + sigma0 * dz + dq[:, 7:8] * zdot[None, :]
          - sigma1 * (da_k * z[None, :] + a_k[None, :] * dz)
          + dq[:, 8:9] * v_r[None, :]) * d.F_n[None, :]
    return F, dF


def open_loop_sensitivities(u, directions, model_of, data: Sequence[BrakingData],
                            substeps: int, z_rows: int | None = None):
    r"""Forces $F(t_k)$ of every braking and their derivatives along each row of
    `directions` (in $u$; `model_of(u)` the tire): a list of
    `(F (samples,), dF (directions, samples))`.

    `z_rows`: only the first `z_rows` directions may move the friction state (the others
    move only $\sigma_1$, $\sigma_2$: $\dot z = 0$); with at most 5 of them, state and
    tangents share one solve (`state_and_tangent_solve`).
    """
    n_dir = directions.shape[0]
    n_z = n_dir if z_rows is None else z_rows
    model = model_of(u)
    q = lumped_parameters(model)
    tangent = lambda f, e: jax.jvp(lambda x: f(model_of(x)), (u,), (e,))[1]  # noqa: E731
    dq = jax.vmap(lambda e: tangent(lumped_parameters, e))(directions)  # (directions, 9)
    out = []
    for d in data:
        dz0 = jax.vmap(lambda e, d=d: tangent(
            lambda m: steady_friction_state(m, d.v[0], d.omega[0], d.r), e))(directions[:n_z])
        z, dz = _state_tangents(q, dq[:n_z], model, d, substeps, dz0)
        dz = jnp.concatenate([dz, jnp.zeros((n_dir - n_z, dz.shape[1]), dz.dtype)])
        out.append(_force_tangents(q, dq, z, dz, d))
    return out
