r"""The lumped friction state of eq. 22 driven by measured $v(t)$, $\omega(t)$, on the data
grid.

With $v$, $\omega$ linear between samples, eq. 22 is linear in $\bar z$:
$\dot{\bar z} = v_r - a\bar z$, $a = \theta\sigma_0|v_r|/g(v_r) + \kappa|\omega r|$,
$\kappa = \kappa_0/L$ (up to $\sim10^4$ 1/s when the wheel locks: stiff). It is solved by
`vehsim`'s one solve helper (`diffrax.diffeqsolve`) with `ExponentialIntegrator`, the exponential midpoint rule: $v_r$
and $a$ frozen at the midpoint of each substep $h$ and integrated exactly,
$\bar z^+ = e^{-ah}\bar z + h\,\varphi(ah)\,v_r$, $\varphi(x) = (1-e^{-x})/x$: second
order, unconditionally stable, and exact in the quasi-static limit.
"""

from __future__ import annotations

import diffrax as dfx
import jax.numpy as jnp

from .._integrate import integrate
from .._math import safe_abs, safe_div
from ..solvers.exponential import ExponentialIntegrator
from ..tire.lugre import LumpedLuGre, decay_rate
from .braking import BrakingData


def steady_friction_state(model: LumpedLuGre, v, omega, r):
    r"""$\bar z_{ss} = v_r / (\theta\sigma_0|v_r|/g + \kappa|\omega r|)$ (eq. 22 at rest),
    the initial state of every prediction."""
    v_r = r * omega - v
    a = decay_rate(model.params, v_r) + model.kappa0 / model.params.L * safe_abs(omega * r)
    return safe_div(v_r, a)


def substep_midpoints(d: BrakingData, substeps: int):
    r"""$v$, $\omega$ (linear between samples) at the midpoint of every substep, and the
    substep lengths $h$ [s]."""
    frac = (jnp.arange(substeps) + 0.5) / substeps
    mid = lambda x: (x[:-1, None] + frac[None, :] * jnp.diff(x)[:, None]).reshape(-1)  # noqa: E731
    return mid(d.v), mid(d.omega), jnp.repeat(jnp.diff(d.t) / substeps, substeps)


def coefficients(model: LumpedLuGre, d: BrakingData, substeps: int):
    r"""Per substep $m$: $a_m = h(\theta\sigma_0|v_r|/g + \kappa|\omega r|)$ and
    $b_m = h v_r$ at the substep midpoint ($h$ the substep [s]: unit steps in substep time),
    and the steady state $\bar z(t_0)$."""
    p = model.params
    kappa = model.kappa0 / p.L
    v, om, h = substep_midpoints(d, substeps)
    v_r = d.r * om - v
    a = h * (decay_rate(p, v_r) + kappa * safe_abs(om * d.r))
    return a, h * v_r, steady_friction_state(model, d.v[0], d.omega[0], d.r)


def linear_solve(a, b, y0, adjoint):
    r"""$dy/ds = b_m - a_m y$ for $s\in[m, m+1)$, unit steps of `ExponentialIntegrator`
    (exact: $y_{m+1} = e^{-a_m}y_m + \varphi(a_m)b_m$); `b` may carry trailing dimensions
    (one column per right-hand side). Returns $y$ after every step."""
    num = a.shape[0]

    def vector_field(s, y, args):
        m = jnp.clip(jnp.floor(s).astype(int), 0, num - 1)
        return b[m] - a[m] * y

    # stiff and linear in y: unit steps of the exponential integrator (exact per step), every
    # step saved, the buffer exactly as long as the steps
    sol = integrate(
        vector_field, None, y0, solver=ExponentialIntegrator(), t0=0.0, t1=float(num),
        dt0=1.0, stepsize_controller=dfx.ConstantStepSize(), saveat=dfx.SaveAt(steps=True),
        max_steps=num, adjoint=adjoint,
    )
    return sol.ys


def friction_state(model: LumpedLuGre, d: BrakingData, substeps: int, adjoint):
    r"""$\bar z(t_k)$ from the steady state at $t_0$, `substeps` steps per sample interval.

    The solve runs in substep time $s$ with unit steps ($dt/ds = h$), so that the
    coefficients of every substep are evaluated at once (vectorised) before the solve.
    """
    a, b, z0 = coefficients(model, d, substeps)
    zs = linear_solve(a, b, z0, adjoint)
    return jnp.concatenate([z0[None], zs[substeps - 1::substeps]])
