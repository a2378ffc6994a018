r"""Braking hardware as it is: a sampled controller, a hydraulic actuator, wheel and speed
sensors, each effect switchable (as the Khepera plant's are).

Per control sample (period $T$, zero-order hold):

1. the controller's torque command $T_c$ is saturated to $[-T_{max}, T_{max}]$ (the
   braking controllers command $T_c \ge 0$; a negative command drives the wheel);
2. *delay*: it reaches the modulator $d$ = round(`actuator_delay` / $T$) samples later;
3. *rate limit*: the delayed command moves by at most `torque_rate` $\cdot T$ per sample
   (the valves' flow limit), giving the target $T_d$;
4. *lag*: the brake torque follows $\tau\dot T_b = T_d - T_b$ exactly over the sample,
   $T_b(t_k + t) = T_d + (T_b(t_k) - T_d)e^{-t/\tau}$.

The sensors: the wheel speed from a tone wheel of `encoder_pulses` teeth by edge timing
(`vehsim.control.plant.sensors`), the vehicle speed with white noise of `speed_noise_std`.

**Values.** A 200 Hz loop, as production ABS units run (5-10 ms cycles); the hydraulic
actuator of Savaresi and Tanelli (*Active Braking Control Systems Design for Vehicles*,
Springer 2010): first-order with 70 rad/s bandwidth ($\tau$ = 14.3 ms) and a 10 ms pure
delay; a torque rate of 60 kN m/s (about 1500 bar/s at 40 N m/bar) and 2500 N m at most,
**unverified** modelling choices; a 48-tooth tone wheel (common on passenger cars); speed noise
0.05 m/s (a modelling choice).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._checks import check_integer, check_nonnegative, check_positive, is_concrete
from ..._fields import array_field, bool_field


MAX_DELAY = 8
"""Length of the command delay buffer: the largest delay is `MAX_DELAY` samples."""


class BrakeHardware(eqx.Module):
    r"""The sampled controller, the actuator and the sensors (module docstring).

    **Fields** (SI units): `sample_time` [s] (0.005); `actuator_delay` [s] (0.010, rounded
    to whole samples, at most `MAX_DELAY`); `time_constant` $\tau$ [s] (1/70); `torque_rate`
    [N m/s] (60 000); `max_torque` [N m] (2500); `encoder_pulses` [1/rev] (48);
    `speed_noise_std` [m/s] (0.05); switches `delay`, `rate_limit`, `lag`, `encoder`
    (off: the true wheel speed is measured), `noise`.
    """

    sample_time: Float[Array, ""] = array_field(default=0.005)
    actuator_delay: Float[Array, ""] = array_field(default=0.010)
    time_constant: Float[Array, ""] = array_field(default=1.0 / 70.0)
    torque_rate: Float[Array, ""] = array_field(default=60_000.0)
    max_torque: Float[Array, ""] = array_field(default=2500.0)
    encoder_pulses: Float[Array, ""] = array_field(default=48.0)
    speed_noise_std: Float[Array, ""] = array_field(default=0.05)
    delay: Array = bool_field(default=True)
    rate_limit: Array = bool_field(default=True)
    lag: Array = bool_field(default=True)
    encoder: Array = bool_field(default=True)
    noise: Array = bool_field(default=True)

    def __check_init__(self):
        # a component's values are checked only where it is switched on: with the delay off,
        # `ideal_hardware(sample_time=0.001)` holds a 10 ms delay it never applies
        owner = "BrakeHardware"
        check_positive(owner, "sample_time", self.sample_time)
        check_positive(owner, "max_torque", self.max_torque)
        for switch, name in (("lag", "time_constant"), ("rate_limit", "torque_rate"),
                             ("encoder", "encoder_pulses")):
            value = _where_on(getattr(self, switch), getattr(self, name))
            if value is not None:
                check_positive(owner, name, value)
                if name == "encoder_pulses":  # teeth of the tone wheel
                    check_integer(owner, name, value, lower=1)
        noise = _where_on(self.noise, self.speed_noise_std)
        if noise is not None:
            check_nonnegative(owner, "speed_noise_std", noise)
        if all(is_concrete(x) for x in (self.delay, self.actuator_delay, self.sample_time)):
            on, d, T = np.broadcast_arrays(np.asarray(self.delay, dtype=bool),
                                           np.asarray(self.actuator_delay, dtype=float),
                                           np.asarray(self.sample_time, dtype=float))
            bad = on & ~((d >= 0.0) & (d <= MAX_DELAY * T))
            if np.any(bad):
                raise ValueError(
                    f"BrakeHardware.actuator_delay must lie in [0, {MAX_DELAY * T[bad].flat[0]:g}]"
                    f", got {d[bad].flat[0]:g} (at most {MAX_DELAY} samples of sample_time, "
                    "the delay buffer's length, while the delay is on; delay=False turns it off)")

    def delay_samples(self):
        """The command delay in samples (0 when the delay is switched off)."""
        d = jnp.round(self.actuator_delay / self.sample_time).astype(int)
        return jnp.where(self.delay, d, 0)


def _where_on(switch, value):
    """The concrete values of `value` where `switch` is on (None when either is traced)."""
    if not (is_concrete(switch) and is_concrete(value)):
        return None
    on = np.broadcast_to(np.asarray(switch, dtype=bool), np.shape(value))
    return np.asarray(value, dtype=float)[on]


def realistic_hardware(**changes) -> BrakeHardware:
    """The hardware with every effect on (fields can be overridden)."""
    return BrakeHardware(**changes)


def ideal_hardware(**changes) -> BrakeHardware:
    """Every effect off: the command acts at once, the true speeds are measured (the
    sampling remains: it is the control rate)."""
    off = dict(delay=False, rate_limit=False, lag=False, encoder=False, noise=False)
    off.update(changes)
    return BrakeHardware(**off)


class ActuatorState(eqx.Module):
    """The commands on their way (`buffer`, one slot per sample), the last rate-limited
    target `target` and the brake torque `torque` at the sample time."""

    buffer: Float[Array, " n"]
    target: Float[Array, ""]
    torque: Float[Array, ""]

    @staticmethod
    def init(torque0=0.0) -> ActuatorState:
        t = jnp.asarray(torque0, dtype=float)
        return ActuatorState(jnp.full(MAX_DELAY + 1, t), t, t)


def actuator_target(hardware: BrakeHardware, state: ActuatorState, k, command):
    """Steps 1-3 of the module docstring for the command issued at sample `k`: the new
    state (torque not yet advanced) and the target $T_d$ held over the sample."""
    command = jnp.clip(command, -hardware.max_torque, hardware.max_torque)
    n = MAX_DELAY + 1
    buffer = jax.lax.dynamic_update_index_in_dim(state.buffer, command, k % n, 0)
    delayed = jax.lax.dynamic_index_in_dim(buffer, (k - hardware.delay_samples()) % n, 0,
                                           keepdims=False)
    step = hardware.torque_rate * hardware.sample_time
    limited = jnp.clip(delayed, state.target - step, state.target + step)
    target = jnp.where(hardware.rate_limit, limited, delayed)
    return ActuatorState(buffer, target, state.torque), target


def brake_torque(hardware: BrakeHardware, torque0, target, t):
    r"""$T_b$ a time `t` after the sample: the exact lag response (step 4), or the target
    itself when the lag is off."""
    tau = jnp.where(hardware.lag, hardware.time_constant, 1.0)  # unchecked when off
    decay = jnp.exp(-t / tau)
    return jnp.where(hardware.lag, target + (torque0 - target) * decay, target)


def mean_brake_torque(hardware: BrakeHardware, torque0, target):
    r"""$\frac1T\int_0^T T_b\,dt$ over one sample (the exact mean of the lag response)."""
    a = hardware.sample_time / jnp.where(hardware.lag, hardware.time_constant, 1.0)
    frac = -jnp.expm1(-a) / a
    return jnp.where(hardware.lag, target + (torque0 - target) * frac, target)
