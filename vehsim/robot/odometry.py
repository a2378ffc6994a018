r"""What the Khepera's host sees: encoder counts, dead reckoning, the serial link's delay.

Report 2.1: "two incremental encoders are placed on the motor axes ... 600 pulses per
revolution of the wheels or 12 pulses per millimeter of wheel displacement"; the host reads
"position signals" (the counts) over RS-232 at 50 Hz. The host integrates the counts
$n_{L,R}$ into a pose with the *nominal* geometry (travel per pulse $1/p$, wheel base $b$):
$$\Delta s_i = \frac{\Delta n_i}{p},\qquad \Delta s = \tfrac12(\Delta s_L + \Delta s_R),\qquad
  \Delta\gamma = \frac{\Delta s_R - \Delta s_L}{b},$$
$$\hat p_{k+1} = \hat p_k + \bigl(\Delta s\cos(\hat\gamma_k + \Delta\gamma/2),\;
  \Delta s\sin(\hat\gamma_k + \Delta\gamma/2),\;\Delta\gamma\bigr),$$
so the pose it sees carries the errors odometry really has (Borenstein and Feng 1996):
count quantisation ($1/p$ = 1/12 mm), the *systematic* errors of a wheel diameter or a
wheel base that differ from the nominal ones (the encoders sit on the motor axes and count
wheel turns, not ground travel), and the *non-systematic* error of wheel slip.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float


def encoder_counts(travel: Float[Array, 2], pulses_per_meter, quantised) -> Float[Array, 2]:
    r"""Pulses counted for wheel turns worth `travel` [m] of nominal wheel travel:
    $\lfloor p\,s\rfloor$ (incremental encoders), or $p\,s$ unquantised if not `quantised`."""
    c = travel * pulses_per_meter
    return jnp.where(quantised, jnp.floor(c), c)


def dead_reckon(pose: Float[Array, 3], travel_left, travel_right,
                wheel_base) -> Float[Array, 3]:
    r"""One dead-reckoning step of the module docstring (midpoint heading) from wheel
    travels $\Delta s_{L,R}$ [m] and the nominal wheel base $b$ [m]."""
    ds = 0.5 * (travel_left + travel_right)
    dg = (travel_right - travel_left) / wheel_base
    mid = pose[2] + 0.5 * dg
    return pose + jnp.stack([ds * jnp.cos(mid), ds * jnp.sin(mid), dg])


def delay_line_write(buffer: Float[Array, "n m"], k, value) -> Float[Array, "n m"]:
    r"""Write `value` into slot $k \bmod n$ of a ring buffer of $n$ slots."""
    return jax.lax.dynamic_update_index_in_dim(buffer, value, k % buffer.shape[0], 0)


def delay_line_read(buffer: Float[Array, "n m"], k, delay) -> Float[Array, " m"]:
    r"""The value written at index $k - d$ ($d$ = `delay` $< n$; slots never written hold
    the buffer's initial fill)."""
    return jax.lax.dynamic_index_in_dim(buffer, (k - delay) % buffer.shape[0], 0,
                                        keepdims=False)
