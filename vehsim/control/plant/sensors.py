r"""Wheel speed by edge timing on a tone wheel, and a noisy vehicle speed.

The tone wheel has $N$ teeth ($\Delta = 2\pi/N$). Between samples the simulator records the
count of edges passed, $n = \lfloor\varphi/\Delta\rfloor$ of the wheel angle $\varphi$, and the
times of the last two edges (within the sample, on the cubic through the angles and wheel
speeds at its ends, by Newton's method).
At a sample at which an edge has arrived since the last one, the speed is one tooth over the
last edge interval, $\hat\omega = \Delta/(t^e_1 - t^e_2)$, as ABS units time the edges of
their wheel-speed sensors: the mean speed over that interval, stamped at its midpoint
(`stamp`), where it equals the true speed to second order. When no edge arrived the
estimate falls to the bound the missing edge gives, $\min(\hat\omega_{k-1}, \Delta/(t_k -
t^e_1))$, and it is not a measurement (`fresh` is false): a locked wheel sends no edges.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..._math import safe_div
from .hardware import BrakeHardware
from .integrate import hermite


class EncoderState(eqx.Module):
    """Edges counted (`count`, and as of the last sample `count_sample`), the times of the
    last two edges (`edge_time`, `edge_time_before`), and the last speed estimate `omega`."""

    count: Float[Array, ""]
    count_sample: Float[Array, ""]
    edge_time: Float[Array, ""]
    edge_time_before: Float[Array, ""]
    omega: Float[Array, ""]

    @staticmethod
    def init(hardware: BrakeHardware, omega0) -> EncoderState:
        """At an edge at t = 0, the wheel having turned steadily at `omega0` before."""
        z = jnp.zeros(())
        omega0 = jnp.asarray(omega0, dtype=float)
        before = -safe_div(2.0 * jnp.pi / hardware.encoder_pulses, omega0, fill=1.0)
        return EncoderState(z, z, z, before, omega0)


def count_edges(hardware: BrakeHardware, enc: EncoderState, t0, T, phi0, phi1, omega0, omega1
                ) -> EncoderState:
    """Edges passed during the sample from `t0` of length `T` in which the wheel angle went
    from `phi0` to `phi1` and its speed from `omega0` to `omega1`."""
    delta = 2.0 * jnp.pi / hardware.encoder_pulses
    n1 = jnp.floor(phi1 / delta)

    def time_of(n):
        target = n * delta
        tau = jnp.clip(safe_div(target - phi0, phi1 - phi0), 0.0, 1.0)
        for _ in range(3):
            rate = T * hermite_rate(tau, T, phi0, phi1, omega0, omega1)
            tau = jnp.clip(tau - safe_div(hermite(tau, T, phi0, phi1, omega0, omega1) - target,
                                          rate), 0.0, 1.0)
        return t0 + tau * T

    new = n1 > enc.count
    before = jnp.where(n1 - enc.count >= 2, time_of(n1 - 1.0), enc.edge_time)
    return EncoderState(jnp.where(new, n1, enc.count), enc.count_sample,
                        jnp.where(new, time_of(n1), enc.edge_time),
                        jnp.where(new, before, enc.edge_time_before), enc.omega)


def hermite_rate(tau, T, p0, p1, d0, d1):
    """The time derivative of `hermite` at the fraction `tau` of the sample."""
    t2 = tau * tau
    return ((6 * t2 - 6 * tau) * p0 + (3 * t2 - 4 * tau + 1) * T * d0
            + (6 * tau - 6 * t2) * p1 + (3 * t2 - 2 * tau) * T * d1) / T


def wheel_speed(hardware: BrakeHardware, enc: EncoderState, t, omega_true):
    """``(omega, stamp, fresh, state)``: the measured wheel speed at sample time `t`, the time
    it stands for, whether it is a measurement (an edge arrived since the last sample, or
    the encoder is switched off and the true speed at `t` is measured) rather than a bound,
    and the encoder state for the next sample."""
    delta = 2.0 * jnp.pi / hardware.encoder_pulses
    fresh = enc.count > enc.count_sample
    timed = safe_div(delta, enc.edge_time - enc.edge_time_before)
    bound = safe_div(delta, t - enc.edge_time, fill=enc.omega)
    omega = jnp.where(fresh, timed, jnp.minimum(enc.omega, bound))
    stamp = jnp.where(fresh, 0.5 * (enc.edge_time + enc.edge_time_before), t)
    omega = jnp.where(hardware.encoder, omega, omega_true)
    stamp = jnp.where(hardware.encoder, stamp, t)
    new = EncoderState(enc.count, enc.count, enc.edge_time, enc.edge_time_before, omega)
    return omega, stamp, fresh | ~hardware.encoder, new


def vehicle_speed(hardware: BrakeHardware, key, k, v_true):
    """The measured vehicle speed at sample `k`: truth plus the noise of run key `key`."""
    noise = hardware.speed_noise_std * jax.random.normal(jax.random.fold_in(key, k), (),
                                                   jnp.result_type(float))
    return v_true + jnp.where(hardware.noise, noise, 0.0)
