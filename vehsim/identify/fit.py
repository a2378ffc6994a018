r"""Identify lumped LuGre parameters from braking data, through the simulator.

**Open loop** (as the report did, section 2.2): the lumped friction state of eqs. 22-25 is
driven by the measured $v(t)$, $\omega(t)$, and the predicted force
$F = (\sigma_0\bar z + \sigma_1\dot{\bar z} + \sigma_2 v_r)F_n$ (eq. 23, measured $F_n$) is
compared with the measured $F_x$. **Closed loop**: the quarter car of
`vehsim.vehicle.quarter_car` is driven by the measured brake torque and predicts $v$,
$\omega$ and $F_x$ together (adaptive diffrax solve; residuals scaled by the peaks of
$|F_x|$, $|v|$, $|\omega|$). Noise-free closed-loop data from the lumped quarter car are
recovered to < 1e-4 relative from a start 20 % off (`tests/test_identify_fit.py`).

The least-squares problem $\min_\theta \tfrac12\sum_k r_k(\theta)^2$ is solved by
Levenberg-Marquardt (optimistix) with forward-mode Jacobians through the solve. Every
parameter is positive by construction: the solver works on $u = \log\theta$, with
$\mu_s = \mu_c + e^{u}$ so that $\mu_c\le\mu_s$ always. A batch of initial guesses is
solved in one `vmap`ped call and the best kept.

**Integrating the stiff friction state on the data grid.** Given $v$, $\omega$ linear
between samples, eq. 22 is linear in $\bar z$: $\dot{\bar z} = v_r - a\bar z$ with
$a = \theta\sigma_0|v_r|/g(v_r) + \kappa|\omega r|$ (up to $\sim10^4$ 1/s when locked). The
open-loop fit solves it with `diffrax.diffeqsolve` and `ExponentialIntegrator`, the
exponential midpoint rule: $v_r$, $a$ frozen at the midpoint of each (sub)step $h$ and
integrated exactly, $\bar z^+ = e^{-ah}\bar z + h\,\varphi(ah)\,v_r$ with
$\varphi(x) = (1-e^{-x})/x$: second order, unconditionally stable, and exact in the
quasi-static limit. `tests/test_identify_fit.py` checks it against a tight `Kvaerno5` solve.
The Levenberg-Marquardt Jacobian is forward mode through that solve: the tangent of the
step map is the same linear recurrence with its own forcing, solved by the same diffrax
solver for all parameters at once (`_open_loop_sensitivities`; exact derivatives of the
discrete scheme). Closed loop: one `diffrax.ForwardMode` JVP per free parameter.

**Convergence** is declared when optimistix's LM terminates, or when the optimum is
certified by MINPACK-style tests that survive noisy data (relative gradient cosine
$\le 10^{-6}$ or a Gauss-Newton-predicted relative loss reduction $\le 10^{-6}$), after
setting aside parameters driven to their bound 0 (reported in `at_bound`). A Jacobian of
condition number $> 10^9$ (in relative parameters) means the data cannot determine the
parameters (e.g. no slip excitation): the fit then fails with the residual in the message.

**Standard errors** come from the Gauss-Newton covariance
$\operatorname{cov}\theta = s^2(J^\top J)^{-1}$, $s^2 = \sum r_k^2/(N-p)$, with $J$ the
Jacobian in the physical parameters at the optimum. They assume white residuals; sensor
lag and sample-and-hold correlate real residuals, so read them as lower bounds.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from typing import Any

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from .._math import one_minus_exp_over, safe_abs, safe_div
from ..solvers.exponential import ExponentialIntegrator, StepMapSolver, StepMapTerm
from ..tire.lugre import LuGreParams, LumpedLuGre, decay_rate
from ..vehicle.quarter_car import PrescribedLoad, QuarterCar, simulate_quarter_car
from .braking import BrakingData


PARAMETER_NAMES = ("sigma0", "sigma1", "sigma2", "mu_c", "mu_s", "v_s", "kappa0", "alpha", "theta")
LUMPED_PARAMETERS = ("sigma0", "sigma1", "sigma2", "mu_c", "mu_s", "v_s", "kappa0")
# sigma2 (viscous, ~1e-3 s/m) is nearly collinear with (mu_c, mu_s, v_s) over the speeds of a
# braking (Stribeck curve plus a linear term): on real data freeing it sends mu_c to its
# bound. It is fixed at the initial guess by default; free it with `free=LUMPED_PARAMETERS`.
DEFAULT_FREE = ("sigma0", "sigma1", "mu_c", "mu_s", "v_s", "kappa0")
UNITS = {"sigma0": "1/m", "sigma1": "s/m", "sigma2": "s/m", "mu_c": "-", "mu_s": "-",
         "v_s": "m/s", "kappa0": "-", "alpha": "-", "theta": "-"}


class FitError(RuntimeError):
    """A fit did not converge (raised with `throw=True`); the message gives the residual and
    `.result` holds the `FitResult` (status, parameters reached, residuals)."""

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


def default_initial_guess() -> LumpedLuGre:
    """A generic dry-asphalt starting point (L = 0.2 m, alpha = 1/2, theta = 1)."""
    return LumpedLuGre(
        LuGreParams(sigma0=150.0, sigma1=1.0, sigma2=0.004, mu_c=0.7, mu_s=1.2, v_s=5.0,
                    alpha=0.5, theta=1.0, L=0.2),
        kappa0=1.5,
    )


def parameter_values(model: LumpedLuGre) -> dict[str, Any]:
    """The fitted quantities of `model` by name (eqs. 10, 22-25)."""
    p = model.params
    return {n: (model.kappa0 if n == "kappa0" else getattr(p, n)) for n in PARAMETER_NAMES}


def with_values(model: LumpedLuGre, values: dict[str, Any]) -> LumpedLuGre:
    """`model` with the named quantities replaced (no validation: works under tracing)."""
    names = [n for n in values if n != "kappa0"]
    if names:
        model = eqx.tree_at(lambda m: [getattr(m.params, n) for n in names], model,
                            [jnp.asarray(values[n], dtype=float) for n in names])
    if "kappa0" in values:
        model = eqx.tree_at(lambda m: m.kappa0, model, jnp.asarray(values["kappa0"], dtype=float))
    return model


def to_unconstrained(model: LumpedLuGre, names: Sequence[str], keep_mu_s=False):
    r"""$u$: logs of the named quantities, with $\log(\mu_s-\mu_c)$ in place of $\mu_s$; with
    `keep_mu_s` (a bool, may be traced: $\mu_s$ held fixed while $\mu_c$ is fitted)
    $\operatorname{logit}(\mu_c/\mu_s)$ in place of $\log\mu_c$, so that $0<\mu_c<\mu_s$."""
    vals = parameter_values(model)
    out = []
    for n in names:
        x = vals[n] - vals["mu_c"] if n == "mu_s" else vals[n]
        u = jnp.log(jnp.asarray(x, dtype=float))
        if n == "mu_c" and keep_mu_s is not False:
            ratio = jnp.where(keep_mu_s, vals["mu_c"] / vals["mu_s"], 0.5)
            u = jnp.where(keep_mu_s, jnp.log(ratio) - jnp.log1p(-ratio), u)
        out.append(u)
    return jnp.stack(out)


def from_unconstrained(u, model: LumpedLuGre, names: Sequence[str],
                       keep_mu_s=False) -> LumpedLuGre:
    r"""Inverse of `to_unconstrained`: every result is a valid parameter set. With
    `keep_mu_s`, $\mu_s$ stays at the value in `model` and $\mu_c = \mu_s\,
    \mathrm{sigmoid}(u)$."""
    vals = {n: jnp.exp(u[i]) for i, n in enumerate(names) if n != "mu_s"}
    if "mu_c" in vals and keep_mu_s is not False:
        ratio = jax.nn.sigmoid(u[list(names).index("mu_c")])
        vals["mu_c"] = jnp.where(keep_mu_s, model.params.mu_s * ratio, vals["mu_c"])
    if "mu_s" in names:
        mu_c = vals.get("mu_c", model.params.mu_c)
        vals["mu_s"] = jnp.where(keep_mu_s, model.params.mu_s,
                                 mu_c + jnp.exp(u[list(names).index("mu_s")]))
    return with_values(model, vals)


def _keeps_mu_s(mask):
    """True where `mu_s` is held fixed while `mu_c` is fitted (`mask` over PARAMETER_NAMES)."""
    return (~mask[PARAMETER_NAMES.index("mu_s")]) & mask[PARAMETER_NAMES.index("mu_c")]


# --------------------------------------------------------------------------------------
# Forward models
# --------------------------------------------------------------------------------------


def _z_steady(model: LumpedLuGre, v, omega, r):
    r"""Steady friction state $\bar z_{ss} = v_r / (\theta\sigma_0|v_r|/g + \kappa|\omega r|)$."""
    v_r = r * omega - v
    a = decay_rate(model.params, v_r) + model.kappa0 / model.params.L * safe_abs(omega * r)
    return safe_div(v_r, a)


def _substep_midpoints(d: BrakingData, substeps: int):
    r"""$v$, $\omega$ (linear between samples) at the midpoint of every substep, and the
    substep lengths $h$ [s]."""
    frac = (jnp.arange(substeps) + 0.5) / substeps
    mid = lambda x: (x[:-1, None] + frac[None, :] * jnp.diff(x)[:, None]).reshape(-1)  # noqa: E731
    return mid(d.v), mid(d.omega), jnp.repeat(jnp.diff(d.t) / substeps, substeps)


def _coefficients(model: LumpedLuGre, d: BrakingData, substeps: int):
    r"""Per substep $m$ (unit steps in substep time): $a_m = h(\theta\sigma_0|v_r|/g +
    \kappa|\omega r|)$ and $b_m = h v_r$ at the substep midpoint, $h$ the substep [s];
    and the steady state $\bar z(t_0)$."""
    p = model.params
    kappa = model.kappa0 / p.L
    v, om, h = _substep_midpoints(d, substeps)
    v_r = d.r * om - v
    a = h * (decay_rate(p, v_r) + kappa * safe_abs(om * d.r))
    return a, h * v_r, _z_steady(model, d.v[0], d.omega[0], d.r)


def _linear_solve(a, b, y0, adjoint):
    r"""$dy/ds = b_m - a_m y$ for $s\in[m, m+1)$, unit steps of `ExponentialIntegrator`
    (exact: $y_{m+1} = e^{-a_m}y_m + \varphi(a_m)b_m$); `b` may carry trailing dimensions
    (one column per right-hand side). Returns $y$ after every step."""
    num = a.shape[0]

    def vector_field(s, y, args):
        m = jnp.clip(jnp.floor(s).astype(int), 0, num - 1)
        return b[m] - a[m] * y

    sol = dfx.diffeqsolve(
        dfx.ODETerm(vector_field), ExponentialIntegrator(), 0.0, float(num), 1.0, y0,
        saveat=dfx.SaveAt(steps=True), adjoint=adjoint, max_steps=num,
    )
    return sol.ys


def _friction_state(model: LumpedLuGre, d: BrakingData, substeps: int, adjoint):
    r"""$\bar z(t_k)$: eq. 22 driven by $v$, $\omega$ linear between samples, through diffrax.

    The solve runs in substep time $s\in[0, S(T-1)]$ ($S$ = `substeps`, $dt/ds = h_k/S$ in
    sample interval $k$) with unit steps, the coefficients of eq. 22 frozen at each
    substep's midpoint, $d\bar z/ds = (h_k/S)(v_r - a\bar z)$, which `ExponentialIntegrator`
    solves exactly: the exponential midpoint rule on the data grid. The coefficients are
    evaluated for all substeps at once (vectorised) before the solve.
    """
    a, b, z0 = _coefficients(model, d, substeps)
    zs = _linear_solve(a, b, z0, adjoint)
    return jnp.concatenate([z0[None], zs[substeps - 1::substeps]])


def _lumped_parameters(model: LumpedLuGre):
    r"""$q = (\theta, \sigma_0, \kappa, \mu_c, \mu_s, v_s, \alpha, \sigma_1, \sigma_2)$."""
    p = model.params
    return jnp.stack([jnp.asarray(x, dtype=float) for x in (
        p.theta, p.sigma0, model.kappa0 / p.L, p.mu_c, p.mu_s, p.v_s, p.alpha, p.sigma1,
        p.sigma2)])


def _decay_rate_partials(q, v_r, omega_r):
    r"""$\partial a/\partial(\theta, \sigma_0, \kappa, \mu_c, \mu_s, v_s, \alpha)$, shape
    `(n, 7)`, of $a = \theta\sigma_0|v_r|/g + \kappa|\omega r|$ (eqs. 10, 22, 25), by hand:
    with $s = |v_r/v_s|^\alpha$, $E = e^{-s}$, $g = \mu_c + (\mu_s-\mu_c)E$,
    $A = \theta\sigma_0|v_r|/g$ and $w = A(\mu_s-\mu_c)Es/g$:
    $(\sigma_0|v_r|/g,\ \theta|v_r|/g,\ |\omega r|,\ -A(1-E)/g,\ -AE/g,\ -w\alpha/v_s,
    \ w\ln|v_r/v_s|)$, all finite (zero where needed) at $v_r = 0$. A vectorised JVP of eq. 10
    through `jnp.where` costs ~3x more."""
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


def _solve_columns(a, b, y0, adjoint):
    """`_linear_solve` of the columns of `b` (steps, k) sharing the decay `a` (steps,), in
    vector-valued solves of at most 8 columns: XLA on CPU saves a trajectory of more than 8
    columns (or with a decay per column) ~10x slower per column."""
    chunks = -(-b.shape[1] // 8)
    return jnp.concatenate([_linear_solve(a, bi, yi, adjoint) for bi, yi in zip(
        jnp.array_split(b, chunks, axis=1), jnp.array_split(y0, chunks))], axis=1)


def _phi_and_log_slope(a):
    r"""$\varphi(a)$ and $\varphi'(a)/\varphi(a)$, $\varphi(x) = (1 - e^{-x})/x$."""
    phi, dphi = jax.jvp(one_minus_exp_over, (a,), (jnp.ones_like(a),))
    return phi, dphi / phi


def _tangent_weight(log_slope, a, b, z):
    r"""$w = (\varphi'(a)(b - az) - \varphi(a)z)/\varphi(a)$, $z$ at the step start: the
    tangent of a step of the exponential midpoint rule along $\dot a$ is
    $e^{-a}\dot z + \varphi(a)\,\dot a\,w$ (`_open_loop_sensitivities`)."""
    return log_slope * (b - a * z) - z


def _state_and_tangent_solve(a, b, da, z0, dz0, adjoint):
    r"""$\bar z$ and its tangents $\dot z_j$ ($j \le 5$) in one diffrax solve of the
    augmented state $y = (\bar z, \dot z_1, \dots)$: per unit step the maps of
    `_linear_solve` and of the tangent recurrence of `_open_loop_sensitivities`,
    $\bar z^+ = e^{-a}\bar z + \varphi(a)b$,
    $\dot z_j^+ = e^{-a}\dot z_j + \varphi(a)\,\dot a_j w(\bar z)$,
    $w = (\varphi'(a)(b - a\bar z) - \varphi(a)\bar z)/\varphi(a)$ at the step start:
    the same numbers as the state solve followed by the tangent solve, in one pass.

    At most 5 tangents: XLA CPU compiles a while loop whose body is small (its bytes
    accessed per iteration) into one kernel and runs larger bodies op by op, ~20x slower
    per step; this body crosses that line at 7 columns (measured, 4000 steps: 40-80 ns per
    step with 6 columns, 1.6-2 us with 7 or 8; the state and tangent solves apart: 100-200
    ns)."""
    num = a.shape[0]
    phi, ratio = _phi_and_log_slope(a)
    decay, phi_b, phi_da = jnp.exp(-a), phi * b, phi[:, None] * da

    def step_map(s, y, args):
        m = jnp.clip(jnp.floor(s).astype(int), 0, num - 1)
        w = _tangent_weight(ratio[m], a[m], b[m], y[0])
        return decay[m] * y + jnp.concatenate([phi_b[m][None], w * phi_da[m]])

    sol = dfx.diffeqsolve(
        StepMapTerm(step_map), StepMapSolver(), 0.0, float(num), 1.0,
        jnp.concatenate([z0[None], dz0]), saveat=dfx.SaveAt(steps=True), adjoint=adjoint,
        max_steps=num,
    )
    return sol.ys


# u-directions that move only the force of eq. 23, not the friction state (sigma1, sigma2)
_FORCE_ONLY = np.array([n in ("sigma1", "sigma2") for n in PARAMETER_NAMES])


def _open_loop_sensitivities(u, directions, model_of, data: Sequence[BrakingData],
                             substeps: int, z_rows: int | None = None):
    r"""Forces $F(t_k)$ of every braking and their derivatives along each row of
    `directions` (in $u$): a list of `(F (samples,), dF (directions, samples))`.

    Forward sensitivities through the same diffrax solve: the step map
    $z^+ = z + \varphi(a)(b - az)$ has the tangent
    $\dot z^+ = (1 - a\varphi(a))\dot z + c$,
    $c = \dot a\,(\varphi'(a)(b - az) - \varphi(a)z)$ ($b = hv_r$ does not depend on the
    parameters): the same linear recurrence with forcing $c/\varphi(a)$, solved for all
    directions at once by vector-valued diffrax solves (exact derivatives of the discrete
    scheme). `z_rows`: only the first `z_rows` directions may move the friction state (the
    others move only $\sigma_1$, $\sigma_2$; their $\dot z = 0$); with at most 5 such
    directions, state and tangents share one solve (`_state_and_tangent_solve`). $\dot a$
    comes from `_decay_rate_partials` and the chain rule through the parameter map; the
    force of eq. 23 is differentiated by hand the same way.
    """
    fm = dfx.ForwardMode()
    n_dir = directions.shape[0]
    n_z = n_dir if z_rows is None else z_rows
    model = model_of(u)
    q = _lumped_parameters(model)
    # parameter tangents (directions x 9)
    dq = jax.vmap(lambda e: jax.jvp(lambda x: _lumped_parameters(model_of(x)), (u,), (e,))[1])(
        directions)
    out = []
    for d in data:
        v_mid, om_mid, h = _substep_midpoints(d, substeps)
        v_r_mid = d.r * om_mid - v_mid
        P = _decay_rate_partials(q, v_r_mid, om_mid * d.r)
        # the coefficients of `_coefficients` from the same partials (a is 1-homogeneous in
        # theta and kappa): a = h (theta da/dtheta + kappa da/dkappa), b = h v_r
        a, b = h * (q[0] * P[:, 0] + q[2] * P[:, 2]), h * v_r_mid
        z0 = _z_steady(model, d.v[0], d.omega[0], d.r)
        da = h[:, None] * (P @ dq[:n_z, :7].T)  # (steps, z directions)
        dz0 = jax.vmap(lambda e, d=d: jax.jvp(
            lambda x: _z_steady(model_of(x), d.v[0], d.omega[0], d.r), (u,), (e,))[1])(
                directions[:n_z])
        if n_z <= 5:  # state and tangents in one solve
            ys = _state_and_tangent_solve(a, b, da, z0, dz0, fm)
            zs, xs = ys[:, 0], ys[:, 1:]
        else:
            zs = _linear_solve(a, b, z0, fm)
            z_start = jnp.concatenate([z0[None], zs[:-1]])
            _, ratio = _phi_and_log_slope(a)
            xs = _solve_columns(a, da * _tangent_weight(ratio, a, b, z_start)[:, None], dz0, fm)
        z = jnp.concatenate([z0[None], zs[substeps - 1::substeps]])
        dz = jnp.concatenate([dz0[:, None], xs[substeps - 1::substeps].T], axis=1)
        dz = jnp.concatenate([dz, jnp.zeros((n_dir - n_z, dz.shape[1]), dz.dtype)])
        # eq. 23: F/F_n = sigma0 z + sigma1 (v_r - a z) + sigma2 v_r, a at the samples
        v_r, om_r = d.r * d.omega - d.v, d.r * d.omega
        P = _decay_rate_partials(q, v_r, om_r)
        a_k = q[0] * P[:, 0] + q[2] * P[:, 2]
        da_k = dq[:, :7] @ P.T
        sigma0, sigma1, sigma2 = q[1], q[7], q[8]
        zdot = v_r - a_k * z
        F = (sigma0 * z + sigma1 * zdot + sigma2 * v_r) * d.F_n
        dF = (dq[:, 1:2] * z[None, :] + sigma0 * dz + dq[:, 7:8] * zdot[None, :]
              - sigma1 * (da_k * z[None, :] + a_k[None, :] * dz)
              + dq[:, 8:9] * v_r[None, :]) * d.F_n[None, :]
        out.append((F, dF))
    return out


def predict_open_loop(model: LumpedLuGre, data: BrakingData, substeps: int = 2, *,
                      adjoint=None):
    r"""Predicted $F_x(t_k)$ [N]: eqs. 22-23 driven by measured $v$, $\omega$, $F_n$.

    The friction state is integrated by diffrax on the data grid (`substeps` exponential
    midpoint steps per sample interval, see the module docstring) from the steady state at
    $t_0$. `adjoint`: diffrax adjoint (default `RecursiveCheckpointAdjoint`: any AD mode;
    `diffrax.ForwardMode()` for forward-mode Jacobians).
    """
    return _open_loop_many(model, [data], substeps, adjoint)[0]


def _open_loop_many(model: LumpedLuGre, data: Sequence[BrakingData], substeps: int,
                    adjoint=None):
    """`predict_open_loop` for several brakings (one diffrax solve each)."""
    adjoint = dfx.RecursiveCheckpointAdjoint() if adjoint is None else adjoint
    out = []
    for d in data:
        z = _friction_state(model, d, substeps, adjoint)
        r = jnp.broadcast_to(d.r, d.t.shape)
        out.append(jax.vmap(model.mu)(z, d.v, d.omega, r) * d.F_n)
    return out


def closed_loop_car(model: LumpedLuGre, data: BrakingData) -> QuarterCar:
    """The quarter car of a braking: lumped tire, measured load as input, `m`, `J`, `r`."""
    if data.T_b is None or data.m is None or data.J is None:
        raise ValueError(f"closed-loop fit of {data.name!r} needs column 'T_b' and side-file "
                         "entries 'm' [kg] and 'J' [kg m^2]")
    return QuarterCar(model, mass=data.m, inertia=data.J, radius=data.r,
                      load=PrescribedLoad(data.t, data.F_n))


def predict_closed_loop(model: LumpedLuGre, data: BrakingData, *, rtol=1e-6, atol=1e-8,
                        solver=None, adjoint=None, throw=True):
    r"""Predicted $(v, \omega, F_x)$ at the samples: the quarter car driven by $T_b(t)$.

    Adaptive steps (`rtol`, `atol`) of `solver` (default `Kvaerno5`, implicit; an explicit
    `Tsit5` compiles faster and copes with short brakings, its steps limited by stability).
    """
    car = closed_loop_car(model, data)
    state0 = car.init_state(data.v[0], data.t[0], omega0=data.omega[0])
    # start from the steady friction state of the first sample
    state0 = eqx.tree_at(lambda s: s.tire, state0,
                         _z_steady(model, data.v[0], data.omega[0], data.r))
    sol = simulate_quarter_car(car, data.t, data.T_b, data.v[0], state0, rtol=rtol, atol=atol,
                               solver=solver, adjoint=adjoint, throw=throw, max_steps=50_000)
    return sol.v, sol.omega, sol.Fx


# --------------------------------------------------------------------------------------
# Residuals
# --------------------------------------------------------------------------------------


def _scales(data: Sequence[BrakingData]):
    """Peak |F_x|, |v|, |omega| over the brakings (arrays: traceable, no recompiles)."""
    peak = lambda f: jnp.max(jnp.stack([jnp.max(jnp.abs(f(d))) for d in data]))  # noqa: E731
    return peak(lambda d: d.F_x), peak(lambda d: d.v), peak(lambda d: d.omega)


def _solver_of(scheme):
    """Internally `substeps` carries the open-loop substeps or the closed-loop solver."""
    return scheme if isinstance(scheme, dfx.AbstractSolver) else None


def _residuals(model, data, mode, scales, substeps, rtol, adjoint=None):
    F_s, v_s, om_s = scales
    if mode == "open_loop":
        F = _open_loop_many(model, data, substeps, adjoint)
        return jnp.concatenate([(Fi - d.F_x) / F_s for Fi, d in zip(F, data)])
    out = []
    for d in data:
        v, om, F = predict_closed_loop(model, d, rtol=rtol, atol=rtol * 1e-2,
                                       solver=_solver_of(substeps), adjoint=dfx.ForwardMode(),
                                       throw=False)
        out += [(F - d.F_x) / F_s, (v - d.v) / v_s, (om - d.omega) / om_s]
    return jnp.concatenate(out)


def fit_loss(model: LumpedLuGre, data: Sequence[BrakingData], mode: str = "open_loop",
             substeps: int = 2, rtol: float = 1e-6):
    r"""$\tfrac12\sum_k r_k^2$ with $r_k$ the force (and, closed loop, speed) errors scaled by
    the peak measured $|F_x|$ ($|v|$, $|\omega|$). Differentiable in `model`."""
    r = _residuals(model, list(data), mode, _scales(data), substeps, rtol)
    return 0.5 * jnp.sum(r**2)


# --------------------------------------------------------------------------------------
# Errors and results
# --------------------------------------------------------------------------------------


def force_errors(F_pred, F_meas) -> dict[str, float]:
    """RMS and peak force errors [N], also relative to the peak measured |F_x|."""
    F_pred, F_meas = np.asarray(F_pred), np.asarray(F_meas)
    e = F_pred - F_meas
    peak = float(np.max(np.abs(F_meas)))
    rms = float(np.sqrt(np.mean(e**2)))
    return {
        "rms_error_N": rms,
        "rms_error_rel_peak": rms / peak,
        "max_abs_error_N": float(np.max(np.abs(e))),
        "peak_force_measured_N": peak,
        "peak_force_predicted_N": float(np.max(np.abs(F_pred))),
        "peak_force_error_N": float(np.max(np.abs(F_pred)) - peak),
    }


@dataclasses.dataclass(frozen=True)
class FitResult:
    """Outcome of `fit_open_loop` / `fit_closed_loop`.

    `model` holds the best parameters; `values` every quantity by name; `std_errors` those
    of the free ones (Gauss-Newton); `status` is ``"converged"`` or says why not
    (``"max_steps"``, ``"not_identifiable"``, ``"nonfinite"``) and `message` gives the
    residual; `at_bound` names parameters the data drive to 0 (within 2 standard errors);
    `errors` the force errors per training braking; `starts` every start's loss.
    """

    model: LumpedLuGre
    mode: str
    free: tuple[str, ...]
    values: dict[str, float]
    std_errors: dict[str, float]
    loss: float
    rms_force_residual_N: float
    converged: bool
    status: str
    message: str
    num_steps: int
    condition_number: float
    errors: dict[str, dict[str, float]]
    starts: dict[str, Any]
    wall_time_s: float
    at_bound: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary with the equations' parameter names."""
        return {
            "mode": self.mode,
            "status": self.status,
            "converged": self.converged,
            "message": self.message,
            "parameters": self.values,
            "free": list(self.free),
            "std_errors": self.std_errors,
            "at_lower_bound": list(self.at_bound),
            "units": {n: UNITS[n] for n in PARAMETER_NAMES},
            "L": float(self.model.params.L),
            "loss": self.loss,
            "rms_force_residual_N": self.rms_force_residual_N,
            "num_steps": self.num_steps,
            "condition_number": self.condition_number,
            "train_errors": self.errors,
            "multistart": self.starts,
            "wall_time_s": self.wall_time_s,
        }


def evaluate(model: LumpedLuGre, data: BrakingData, mode: str = "open_loop",
             substeps: int = 2) -> tuple[np.ndarray, dict[str, float]]:
    """Predicted force on `data` and its `force_errors` (e.g. on a held-out braking)."""
    anon = _unnamed(data)
    if mode == "open_loop":
        F = _predict_open_loop_jit(model, anon, substeps, adjoint=dfx.ForwardMode())
    else:
        F = _predict_closed_loop_jit(model, anon, solver=_solver_of(substeps),
                                     adjoint=dfx.ForwardMode(), throw=False)[2]
    return np.asarray(F), force_errors(F, data.F_x)


def _log(verbose, msg):
    if verbose:
        print(f"  fit: {msg}", file=sys.stderr, flush=True)


def _merge(u, u_fixed, mask):
    return jnp.where(mask, u, u_fixed)


def _jvp_columns(fn, x, mask):
    """`fn(x)` and its Jacobian transposed, (len(x), len(fn(x))): one forward-mode JVP per
    column where `mask` is true (zeros elsewhere), in a `lax.map` (not a `vmap`)."""
    r0 = fn(x)
    eye = jnp.eye(x.shape[0], dtype=x.dtype)

    def column(i):
        return jax.lax.cond(mask[i], lambda: jax.jvp(fn, (x,), (eye[i],))[1],
                            lambda: jnp.zeros_like(r0))

    return r0, jax.lax.map(column, jnp.arange(x.shape[0]))


def _data_residual_with_jacobian(mask, model, data, mode, scales, substeps, rtol, slots=7):
    r"""$u \mapsto r(u)$ (data residuals) carrying its forward-mode Jacobian.

    Levenberg-Marquardt needs the whole Jacobian $J$ at every step. Through a forward-mode
    `while_loop`, `jax.linearize` cannot split off a cheap linear part (it re-runs the solve
    for every column), and `jax.jacfwd` (a `vmap` of JVPs) batches the solve's saved
    trajectory, which is slow. So $J$ is built from forward sensitivities: open loop,
    vector-valued tangent solves for the free directions that move the friction state,
    gathered into `slots` (static: 5, or 7 when more are free) rows, plus $\sigma_1$,
    $\sigma_2$, which move only the force (`_open_loop_sensitivities`); closed loop, one
    forward-mode JVP through the solve per *free* parameter (`lax.map` + `lax.cond`: fixed
    columns cost nothing). The JVP rule is the product with $J$:
    optimistix's `linearize` then keeps $J$ and its linear operator is a matrix product.
    """
    keep = _keeps_mu_s(mask)

    def residual(u):
        m = from_unconstrained(u, model, PARAMETER_NAMES, keep)
        return _residuals(m, data, mode, scales, substeps, rtol, dfx.ForwardMode())

    def with_jacobian(u):
        if mode != "open_loop":
            return _jvp_columns(residual, u, mask)
        # the free directions that move the friction state gathered into `slots` rows
        # (padding rows are zero), then sigma1 and sigma2 (zero rows unless free): with at
        # most 5 state directions the state and its tangents share one solve per braking
        z_mask = mask & ~_FORCE_ONLY
        rows = jnp.concatenate([jnp.nonzero(z_mask, size=slots, fill_value=0)[0],
                                jnp.asarray(np.flatnonzero(_FORCE_ONLY))])
        used = jnp.concatenate([jnp.arange(slots) < jnp.sum(z_mask),
                                mask[_FORCE_ONLY]])[:, None]
        directions = jnp.eye(u.shape[0], dtype=u.dtype)[rows] * used
        model_of = lambda x: from_unconstrained(x, model, PARAMETER_NAMES, keep)  # noqa: E731
        out = _open_loop_sensitivities(u, directions, model_of, data, substeps, slots)
        r0 = jnp.concatenate([(F - d.F_x) / scales[0] for (F, _), d in zip(out, data)])
        dF = jnp.concatenate([dF / scales[0] for _, dF in out], axis=1) * used
        return r0, jnp.zeros((u.shape[0], dF.shape[1]), dF.dtype).at[rows].add(dF)

    @jax.custom_jvp
    def r(u):
        return residual(u)

    @r.defjvp
    def r_jvp(primals, tangents):
        (u,), (du,) = primals, tangents
        r0, Jt = with_jacobian(u)
        return r0, du @ Jt

    return r


class _ScaledTrustRegion(optx.ClassicalTrustRegion):
    r"""`optx.ClassicalTrustRegion` whose first step size (the inverse Levenberg-Marquardt
    damping $1/\lambda_0$) is given instead of 1."""

    initial_step_size: Any = 1.0

    def init(self, y, f_info_struct):
        state = super().init(y, f_info_struct)
        return eqx.tree_at(lambda s: s.step_size, state,
                           jnp.asarray(self.initial_step_size, dtype=float))


class _LevenbergMarquardt(optx.AbstractGaussNewton):
    r"""`optx.LevenbergMarquardt` with Marquardt's scale-aware initial damping
    $\lambda_0 = \tau\max_j(J^\top J)_{jj}$ at the start (Nielsen 1999; $\tau = 10^{-4}$
    measured best on the shipped brakings: 26/20/20 steps for the three train pairs vs
    31/27/26 with optimistix's $\lambda_0 = 1$), damped steps from the normal equations by
    Cholesky ($p\le9$ unknowns; XLA's QR of the tall Jacobian costs more than the rest of
    a step)."""

    rtol: float
    atol: float
    norm: Any
    descent: Any
    search: Any
    verbose: Any

    def __init__(self, rtol, atol, initial_step_size):
        self.rtol, self.atol, self.norm = rtol, atol, optx.max_norm
        self.descent = optx.DampedNewtonDescent(linear_solver=lx.Normal(lx.Cholesky()))
        self.search = _ScaledTrustRegion(initial_step_size=initial_step_size)
        self.verbose = lambda **kwargs: None


INITIAL_DAMPING = 1e-4


@eqx.filter_jit
@eqx.debug.assert_max_traces(max_traces=None)  # counts traces: the tests check for retraces
def _solve_batch(u0s, u_fixed, mask, prior_weight, model, data, mode, scales, substeps, rtol,
                 tol, max_steps, slots=7):
    # All of PARAMETER_NAMES are always in `u`; fixed ones are masked (zero Jacobian columns,
    # so LM never moves them). One compilation serves every choice of free parameters.
    data_residual = _data_residual_with_jacobian(mask, model, data, mode, scales, substeps,
                                                 rtol, slots)

    def residual(u, args):
        u = _merge(u, u_fixed, mask)
        prior = prior_weight * jnp.where(mask, u - u_fixed, 0.0)
        return jnp.concatenate([data_residual(u), prior])

    def one(u0):
        J = jax.jacfwd(lambda u: residual(u, None))(u0)
        lambda_0 = INITIAL_DAMPING * jnp.max(jnp.sum(J**2, axis=0))
        solver = _LevenbergMarquardt(tol, tol, 1.0 / lambda_0)
        sol = optx.least_squares(residual, solver, u0, max_steps=max_steps, throw=False)
        # the residuals and the Jacobian (in u) at the last accepted point, `sol.value`, are
        # in the solver's state (no further solve)
        r = sol.state.f_info.residual
        return _merge(sol.value, u_fixed, mask), 0.5 * jnp.sum(r**2), \
            sol.result == optx.RESULTS.successful, sol.stats["num_steps"], r, \
            sol.state.f_info.jac.as_matrix()

    if u0s.shape[0] == 1:  # no batch: a smaller program to compile (closed loop)
        return jax.tree.map(lambda x: x[None], one(u0s[0]))
    return jax.vmap(one)(u0s)


_predict_open_loop_jit = eqx.filter_jit(predict_open_loop)
_predict_closed_loop_jit = eqx.filter_jit(predict_closed_loop)


def _unnamed(d: BrakingData) -> BrakingData:
    """`d` without its (static) name, so that compiled fits are shared between brakings."""
    f = _strong_float  # no weak types, no eager dispatches
    return BrakingData(t=f(d.t), v=f(d.v), omega=f(d.omega), F_x=f(d.F_x), F_n=f(d.F_n),
                       r=f(d.r), T_b=f(d.T_b), m=f(d.m), J=f(d.J))


def _dtheta_du(theta_all, names):
    """d(free physical values)/d(free u) for the transform of `from_unconstrained` (9 x p)."""
    idx = {n: i for i, n in enumerate(PARAMETER_NAMES)}
    T = np.zeros((len(PARAMETER_NAMES), len(names)))
    for j, n in enumerate(names):
        if n == "mu_s":
            T[idx["mu_s"], j] = theta_all[idx["mu_s"]] - theta_all[idx["mu_c"]]
        else:
            T[idx[n], j] = theta_all[idx[n]]
            if n == "mu_c" and "mu_s" not in names:  # mu_c = mu_s sigmoid(u), mu_s held
                T[idx[n], j] *= 1.0 - theta_all[idx["mu_c"]] / theta_all[idx["mu_s"]]
            if n == "mu_c":  # mu_s = mu_c + exp(u_mu_s) moves with mu_c when mu_s is free
                T[idx["mu_s"], j] = theta_all[idx["mu_c"]] if "mu_s" in names else 0.0
    return T


def _strong_float(x):
    """`x` as a strong (not weak-typed) float64 array, without a JAX dispatch: weak-typed and
    strong leaves would compile separately, and eager conversions cost ~20 us each."""
    if x is None:
        return None
    if isinstance(x, jax.Array) and x.dtype == jnp.float64 and not x.weak_type:
        return x
    return np.asarray(x, dtype=float)


def _values_batch(model, us, keep_mu_s=False):
    """The values of `PARAMETER_NAMES` for each row of `us` (batch, 9)."""
    return jax.vmap(lambda u: jnp.stack([jnp.asarray(x, dtype=float) for x in parameter_values(
        from_unconstrained(u, model, PARAMETER_NAMES, keep_mu_s)).values()]))(us)


@eqx.filter_jit
def _fit_core(model, data, mask, prior_weight, key, spread, n_starts, mode, scales, substeps,
              rtol, tol, max_steps, slots):
    """Everything of a fit that runs in JAX, in one compiled call (eager dispatches of the
    small pre- and post-fit steps cost more than a Levenberg-Marquardt step): the starts,
    the batched solve, the best start, and its residuals and Jacobian (the solver's last,
    in the unconstrained coordinates u)."""
    keep = _keeps_mu_s(mask)
    u_fixed = to_unconstrained(model, PARAMETER_NAMES, keep)
    noise = jax.random.normal(jax.random.PRNGKey(key), (n_starts - 1, len(PARAMETER_NAMES)))
    u0s = jnp.concatenate([u_fixed[None], u_fixed[None] + spread * noise * mask[None, :]])
    us, losses, ok, steps, rs, Js = _solve_batch(u0s, u_fixed, mask, prior_weight, model, data,
                                                 mode, scales, substeps, rtol, tol, max_steps,
                                                 slots)
    # the best start: the least finite loss among the converged ones, else among all
    rank = jnp.where(jnp.isfinite(losses), losses, jnp.inf) + jnp.where(ok, 0.0, 1e300)
    best = jnp.argmin(rank)
    best_model = from_unconstrained(us[best], model, PARAMETER_NAMES, keep)
    values = _values_batch(model, us, keep)
    # the data rows (the prior's rows last) of the best start's residuals and Jacobian in u
    n_data = rs.shape[1] - len(PARAMETER_NAMES)
    return dict(u_fixed=u_fixed, us=us, losses=losses, ok=ok, steps=steps, best=best,
                model=best_model, theta=values[best], r=rs[best, :n_data],
                J_u=Js[best, :n_data], values=values, initial=_values_batch(model, u0s, keep))


def _singular_values(A):
    """Singular values of a tall `A`, descending: from the eigenvalues of the small
    $A^\top A$ when they resolve the smallest one (condition number below ~1e6), else from
    a QR of `A` (a tall LAPACK call, which can cost ~10 ms beside XLA's threads)."""
    ev = np.linalg.eigvalsh(A.T @ A)[::-1]
    if ev[-1] > 1e-12 * ev[0]:
        return np.sqrt(ev)
    return np.linalg.svd(np.linalg.qr(A, mode="r"), compute_uv=False)


def _fit(data, init, free, fixed, mode, n_starts, spread, key, tol, max_steps, substeps, rtol,
         throw, verbose, prior_weight, gtol=1e-6, ftol=1e-6) -> FitResult:
    t_start = time.perf_counter()
    data = [data] if isinstance(data, BrakingData) else list(data)
    if not data:
        raise ValueError("fit needs at least one braking")
    model = default_initial_guess() if init is None else init
    fixed = dict(fixed or {})
    for n in list(fixed) + list(free):
        if n not in PARAMETER_NAMES:
            raise ValueError(f"unknown parameter {n!r}; known: {list(PARAMETER_NAMES)}")
    if fixed:
        model = with_values(model, fixed)
    if "mu_s" in fixed and "mu_c" in free and "mu_c" not in fixed:
        mu_c, mu_s = float(model.params.mu_c), float(model.params.mu_s)
        if not mu_c < mu_s:
            raise ValueError(
                f"fixed mu_s = {mu_s:g} must exceed the initial mu_c = {mu_c:g}: with mu_s held, "
                "mu_c is fitted in (0, mu_s); give an initial guess with a smaller mu_c")
    model = jax.tree.map(_strong_float, model)
    names = tuple(n for n in PARAMETER_NAMES if n in free and n not in fixed)
    if not names:
        raise ValueError("no free parameters")
    if n_starts < 1:
        raise ValueError(f"n_starts must be >= 1, got {n_starts}")
    anon = [_unnamed(d) for d in data]
    # the scales from the concrete data in NumPy (no eager JAX dispatches)
    scales = tuple(np.asarray(max(float(np.max(np.abs(np.asarray(f(d))))) for d in data))
                   for f in (lambda d: d.F_x, lambda d: d.v, lambda d: d.omega))
    mask = np.asarray([n in names for n in PARAMETER_NAMES])
    _log(verbose, f"{mode}: {len(names)} parameters {list(names)}, {n_starts} start(s), "
         f"{sum(len(d) for d in data)} samples in {len(data)} braking(s); solving "
         "(the first call compiles)...")
    core = _fit_core(model, anon, mask, np.asarray(float(prior_weight)), np.asarray(key),
                     np.asarray(float(spread)), n_starts, mode, scales, substeps, rtol, tol,
                     max_steps, 5 if sum(n not in ("sigma1", "sigma2") for n in names) <= 5
                     else 7)
    core = {k: v if k == "model" else np.asarray(v) for k, v in core.items()}
    us, losses, ok, steps, best = (core[k] for k in ("us", "losses", "ok", "steps", "best"))
    best = int(best)
    finite = np.isfinite(losses)
    _log(verbose, f"solved {n_starts} start(s) in {time.perf_counter() - t_start:.1f}s: "
         f"{int(ok.sum())} converged, best loss {np.nanmin(np.where(finite, losses, np.nan)):.4g}"
         if finite.any() else "no start gave a finite loss")
    best_model, theta_all, r = core["model"], core["theta"], core["r"]
    cols = [PARAMETER_NAMES.index(n) for n in names]
    # the solver's last Jacobian, in u: to the physical values by the chain rule,
    # J_u = J_theta dtheta/du (the fixed values do not depend on the free u)
    du = _dtheta_du(theta_all, names)
    J_u = core["J_u"][:, cols]
    J = J_u @ np.linalg.inv(du[cols, :])
    theta = theta_all[cols]
    N, p = J.shape
    loss = float(0.5 * np.sum(r**2))  # data term only (without the prior)
    if mode == "open_loop":  # the force residuals are r: no second solve
        ends = np.cumsum([len(d) for d in data])
        preds = [(F_pred, force_errors(F_pred, d.F_x)) for F_pred, d in zip(
            (np.asarray(d.F_x) + float(scales[0]) * ri for ri, d in zip(
                np.split(r, ends[:-1]), data)), data)]
    else:
        preds = [evaluate(best_model, d, mode, substeps) for d in data]
    rms_F = float(np.sqrt(np.mean(np.concatenate(
        [(F - np.asarray(d.F_x)) ** 2 for (F, _), d in zip(preds, data)]))))
    # identifiability: singular values of the Jacobian in relative (log) parameters
    Jrel = J * theta[None, :]
    sv = _singular_values(Jrel) if np.all(np.isfinite(Jrel)) else np.array([0.0])
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    std = {n: math.nan for n in names}
    if np.isfinite(cond) and N > p:
        s2 = float(np.sum(r**2) / (N - p))
        cov = s2 * np.linalg.inv(J.T @ J)
        std = {n: float(math.sqrt(max(cov[i, i], 0.0))) for i, n in enumerate(names)}
    # first-order optimality in the solver's coordinates u (MINPACK's gtol test): the cosine
    # between the residual vector (data and prior) and each Jacobian column. optimistix's LM
    # stops on small steps and small loss changes; with noisy data at the optimum every trial
    # step is rejected, so a fit can run out of steps although it sits at the minimum.
    Ju = np.concatenate([J_u, float(prior_weight) * np.eye(p)])
    ru = np.concatenate([r, float(prior_weight) * (us[best] - core["u_fixed"])[cols]])
    # A parameter the data push towards zero (dL/du > 0) whose value is within two standard
    # errors of zero sits at its bound: the log transform reaches 0 only at u = -inf, so LM
    # crawls. Such parameters are reported (`at_bound`) and left out of the tests below
    # (a one-sided, KKT-like condition).
    grad_u = Ju.T @ ru
    values_all = dict(zip(PARAMETER_NAMES, theta_all.tolist()))
    size = np.array([theta[i] - (values_all["mu_c"] if n == "mu_s" else 0.0)
                     for i, n in enumerate(names)])
    se = np.array([std[n] for n in names])
    at_bound = (grad_u > 0) & np.isfinite(se) & (size < 2.0 * se)
    inner = ~at_bound
    Ji, ri = Ju[:, inner], ru
    with np.errstate(invalid="ignore", divide="ignore"):
        cosine = np.abs(Ji.T @ ri) / (np.linalg.norm(Ji, axis=0) * np.linalg.norm(ri))
    cosine = np.append(np.nan_to_num(cosine, nan=0.0), 0.0)
    # ... and MINPACK's ftol test: the loss reduction the Gauss-Newton model still predicts
    # (full step, no damping) is negligible relative to the loss.
    if np.all(np.isfinite(Ji)) and np.all(np.isfinite(ri)) and Ji.shape[1]:
        # normal equations (p x p): a tall LAPACK call here can cost ~10 ms when it wakes
        # BLAS threads that compete with XLA's; the ftol test needs few digits
        step = np.linalg.lstsq(Ji.T @ Ji, -(Ji.T @ ri), rcond=None)[0]
        predicted = float(np.sum(ri**2) - np.sum((ri + Ji @ step) ** 2)) / max(
            float(np.sum(ri**2)), 1e-300)
    else:
        predicted = 0.0 if Ji.shape[1] == 0 else math.inf
    stationary = bool(np.all(cosine <= gtol)) or predicted <= ftol
    bound_names = [n for n, b in zip(names, at_bound) if b]
    if not (np.isfinite(loss) and np.all(np.isfinite(theta))):
        status = "nonfinite"
    elif not np.isfinite(cond) or cond > 1e9 or sv[0] == 0.0:
        status = "not_identifiable"
    elif not (ok[best] or stationary):
        status = "max_steps"
    else:
        status = "converged"
    converged = status == "converged"
    reason = {
        "converged": ("converged" if ok[best] else
                      f"converged (predicted relative loss reduction {predicted:.2g})"),
        "nonfinite": "the fit produced non-finite values",
        "not_identifiable": (f"parameters not identifiable from these data (Jacobian condition "
                             f"number {cond:.3g}; is there slip excitation?)"),
        "max_steps": (f"Levenberg-Marquardt did not converge in {max_steps} steps (gradient "
                      f"cosine {float(np.nanmax(cosine)):.2g} > {gtol:g}, predicted relative "
                      f"loss reduction {predicted:.2g} > {ftol:g})"),
    }[status]
    if bound_names and status == "converged":
        reason += "; at the lower bound 0 (within 2 standard errors): " + ", ".join(
            f"{n} = {values_all[n]:.3g} +/- {std[n]:.2g}" for n in bound_names)
    message = f"{reason}; loss {loss:.6g}, RMS force residual {rms_F:.4g} N"
    values = dict(values_all)
    # spread over the starts that reached (within 1e-6 relative) the best loss
    all_vals = [dict(zip(PARAMETER_NAMES, row)) for row in core["values"].tolist()]
    near = [i for i in range(n_starts) if finite[i]
            and losses[i] <= losses[best] * (1 + 1e-6) + 1e-300]
    spread_info = {
        n: {"min": float(min(all_vals[i][n] for i in near)),
            "max": float(max(all_vals[i][n] for i in near))} if near else None
        for n in names
    }
    starts = {
        "n_starts": n_starts,
        "losses": [float(x) if np.isfinite(x) else None for x in losses],
        "converged": [bool(x) for x in ok],
        "num_steps": [int(x) for x in np.asarray(steps)],
        "best": best,
        "n_at_best": len(near),
        "spread_at_best": spread_info,
        "initial": [{n: v for n, v in vals.items() if n in names}
                    for vals in (dict(zip(PARAMETER_NAMES, row))
                                 for row in core["initial"].tolist())],
    }
    errors = {d.name: e for (_, e), d in zip(preds, data)}
    wall = time.perf_counter() - t_start
    _log(verbose, f"{status}: {message} ({wall:.1f}s)")
    result = FitResult(
        model=best_model, mode=mode, free=names, values=values, std_errors=std, loss=loss,
        rms_force_residual_N=rms_F, converged=converged, status=status, message=message,
        num_steps=int(np.asarray(steps)[best]), condition_number=cond, errors=errors,
        starts=starts, wall_time_s=wall, at_bound=tuple(bound_names),
    )
    if throw and not converged:
        raise FitError(f"fit did not converge: {message}", result)
    return result


def fit_open_loop(data, init: LumpedLuGre | None = None, *, free=DEFAULT_FREE, fixed=None,
                  n_starts: int = 8, spread: float = 0.3, key: int = 0, tol: float = 1e-6,
                  max_steps: int = 100, substeps: int = 2, prior_weight: float = 1e-4,
                  throw: bool = True, verbose: bool = False) -> FitResult:
    r"""Fit the lumped LuGre model (eqs. 22-25) to brakings, driven by measured $v$, $\omega$.

    **Arguments:**

    - `data`: a `BrakingData` or a sequence of them (fitted together).
    - `init`: starting `LumpedLuGre` (default `default_initial_guess()`); also supplies the
      fixed quantities (`L`, and `alpha`, `theta` unless freed).
    - `free`: names to fit (default sigma0, sigma1, mu_c, mu_s, v_s, kappa0; sigma2 stays
      at the initial guess unless freed, see `DEFAULT_FREE`; alpha, theta may be freed).
    - `fixed`: ``{name: value}`` held fixed (e.g. ``{"kappa0": 1.0}``, report Fig. 10).
    - `n_starts`, `spread`, `key`: multi-start: the initial guess plus `n_starts - 1` starts
      at $\log\theta_0 + $ `spread` $\cdot N(0, 1)$, all solved in one vmapped call.
    - `tol`: Levenberg-Marquardt `rtol` = `atol`; `max_steps` its step limit.
    - `substeps`: integrator substeps per sample interval.
    - `prior_weight` $w$: a weak prior (ridge) $w(\log\theta - \log\theta_0)$ on the free
      parameters, appended to the residuals (scaled by the peak force): it keeps nearly flat
      directions from wandering. $w = 10^{-4}$ changes well-determined parameters by far
      less than their standard errors (and exact data are recovered to ~1e-5); 0 turns it off.
    - `throw`: raise `FitError` (with the residual) if the best start did not converge or
      the parameters are not identifiable; with `False` check `result.status`.
    - `verbose`: progress on stderr.

    **Returns:** a `FitResult`.
    """
    return _fit(data, init, free, fixed, "open_loop", n_starts, spread, key, tol, max_steps,
                substeps, 1e-6, throw, verbose, prior_weight)


def fit_closed_loop(data, init: LumpedLuGre | None = None, *, free=DEFAULT_FREE, fixed=None,
                    n_starts: int = 1, spread: float = 0.3, key: int = 0, tol: float = 1e-8,
                    max_steps: int = 100, rtol: float = 1e-6, solver=None,
                    prior_weight: float = 1e-4, throw: bool = True,
                    verbose: bool = False) -> FitResult:
    r"""Fit the quarter car (lumped tire) driven by the measured brake torque $T_b(t)$,
    predicting $v$, $\omega$, $F_x$ together (residuals scaled by their peaks).

    Needs `T_b` and the side-file `m`, `J` in every braking. The solve is adaptive, with
    relative tolerance `rtol`, by `solver` (default `Kvaerno5`; see `predict_closed_loop`),
    with forward-mode sensitivities. Other arguments as in `fit_open_loop`.
    """
    return _fit(data, init, free, fixed, "closed_loop", n_starts, spread, key, tol, max_steps,
                solver, rtol, throw, verbose, prior_weight)
