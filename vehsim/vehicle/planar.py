r"""Planar (bicycle) kinematics and dynamics shared by the half-car models (eqs. 49-51, 61-63).

Velocities are kept in the body frame: $v_x$ forward, $v_y$ to the left, yaw rate
$r = \dot\psi$ counter-clockwise. With $f_i = (f_{ix}, f_{iy})$ the tire forces of axle
$i$ in its wheel frame (front rotated by the steering angle $\delta$), eqs. 49-51 read
$$m(\dot v_x - r v_y) = f_{Fx}\cos\delta - f_{Fy}\sin\delta + f_{Rx},\qquad
  m(\dot v_y + r v_x) = f_{Fx}\sin\delta + f_{Fy}\cos\delta + f_{Ry},$$
$$J\dot r = (f_{Fy}\cos\delta + f_{Fx}\sin\delta)\ell_F - f_{Ry}\ell_R,\qquad
  \dot x = v_x\cos\psi - v_y\sin\psi,\quad \dot y = v_x\sin\psi + v_y\cos\psi,$$
which is eqs. 49-50 ($m\ddot x$, $m\ddot y$ in the inertial frame) rotated into the body.
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp

from .params import HalfCarParams


def axle_velocities(params: HalfCarParams, vx, vy, yaw_rate, delta):
    r"""Wheel-frame velocities of the axle centres, $(V_{Fx}, V_{Fy}, V_{Rx}, V_{Ry})$.

    Rear: $(v_x, v_y - \ell_R r)$. Front: $(v_x, v_y + \ell_F r)$ rotated by $-\delta$.
    """
    vyF = vy + params.lF * yaw_rate
    c, s = jnp.cos(delta), jnp.sin(delta)
    return vx * c + vyF * s, -vx * s + vyF * c, vx, vy - params.lR * yaw_rate


def front_body_x(fFx, fFy, delta):
    r"""$\Sigma f_{Fx} = f_{Fx}\cos\delta - f_{Fy}\sin\delta$ (eq. 56)."""
    return fFx * jnp.cos(delta) - fFy * jnp.sin(delta)


def planar_rates(params: HalfCarParams, psi, vx, vy, yaw_rate, fF, fR, delta):
    r"""$(\dot x, \dot y, \dot\psi, \dot v_x, \dot v_y, \dot r)$ of eqs. 49-51 / 61-63.

    `fF`, `fR`: wheel-frame forces $(f_x, f_y)$ of the front and rear axle [N].
    """
    c, s = jnp.cos(delta), jnp.sin(delta)
    fFx, fFy = fF[0], fF[1]
    fRx, fRy = fR[0], fR[1]
    Fbx = fFx * c - fFy * s + fRx
    Fby = fFx * s + fFy * c + fRy
    Mz = (fFy * c + fFx * s) * params.lF - fRy * params.lR
    cp, sp = jnp.cos(psi), jnp.sin(psi)
    return jnp.stack([
        vx * cp - vy * sp,
        vx * sp + vy * cp,
        yaw_rate,
        Fbx / params.m + yaw_rate * vy,
        Fby / params.m - yaw_rate * vx,
        Mz / params.Iz,
    ])


def quasi_static_loads(
    params: HalfCarParams,
    body_fx_F: Callable,
    body_fx_R: Callable,
    iterations: int = 1,
):
    r"""Normal loads with quasi-static longitudinal load transfer (docs/maneuvers.md).

    Solves $F_{zF} + F_{zR} = mg$ and
    $F_{zR}\ell_R - F_{zF}\ell_F - h(F_{zF}\mu_{F,bx} + F_{zR}\mu_{R,bx}) = 0$
    (eq. 55 with no pitch motion), where $\mu_{i,bx} = \Sigma f_{ix}/F_{zi}$ is the body-x
    force per unit load of axle $i$:
    $$F_{zF} = \frac{mg(\ell_R - h\mu_{R,bx})}{\ell_F + \ell_R + h(\mu_{F,bx} - \mu_{R,bx})},
      \qquad F_{zR} = mg - F_{zF}.$$
    For tires whose forces are proportional to the load (the maneuvers' friction-ellipse tire,
    `LinearTire`) $\mu_{i,bx}$ does not depend on the load and one iteration is the exact
    solution of the 2x2 system. For other tires, $\mu_{i,bx}$ is re-evaluated at the latest
    loads `iterations` times (a fixed-point iteration starting from eqs. 57-58).

    **Arguments:** `body_fx_F(Fz)`, `body_fx_R(Fz)`: body-x force of each axle [N] as a
    function of its normal load.

    **Returns:** $(F_{zF}, F_{zR})$ [N].
    """
    FzF, FzR = params.static_loads()
    floor = 1e-3 * params.m * params.g
    for _ in range(iterations):
        FzF_eval = jnp.maximum(FzF, floor)
        FzR_eval = jnp.maximum(FzR, floor)
        FzF, FzR = load_transfer(params, body_fx_F(FzF_eval) / FzF_eval,
                                 body_fx_R(FzR_eval) / FzR_eval)
    return FzF, FzR


def load_transfer(params: HalfCarParams, muF_bx, muR_bx):
    r"""$(F_{zF}, F_{zR})$ [N] of `quasi_static_loads` for given body-x forces per unit load
    $\mu_{F,bx}$, $\mu_{R,bx}$ (the exact loads where the tires' forces are proportional
    to the load)."""
    mg = params.m * params.g
    FzF = mg * (params.lR - params.h * muR_bx) / (
        params.wheelbase + params.h * (muF_bx - muR_bx)
    )
    return FzF, mg - FzF
