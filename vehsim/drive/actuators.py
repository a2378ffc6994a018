r"""The car's actuators, sampled: steering angle and the two axle torques.

Per control sample (period $T$, the plant's control period) each channel $j$ of the
command $u = (T_F, T_R, \delta)$ goes through the steps of the braking hardware
(`vehsim.BrakeHardware`), with its own values:

1. saturation to $[-u_{max,j}, u_{max,j}]$;
2. *delay*: the command reaches the actuator $d_j$ = round(`delay`$_j/T$) samples later
   (at most `MAX_DELAY`);
3. *rate limit*: the delayed command moves by at most `rate`$_j\,T$ per sample, giving the
   target $u_{d,j}$ held over the sample;
4. *lag*: the applied value follows $\tau_j\dot u_j = u_{d,j} - u_j$ exactly over the
   sample, $u_j(t_k + t) = u_{d,j} + (u_j(t_k) - u_{d,j})e^{-t/\tau_j}$, which the
   plant's integrator sees as a function of time within the sample.

**Values** (modelling choices, **not from a source**): a 20 Hz control period; torque
channels (drive-train or brake) with one sample of delay, 0.05 s lag, 30 kN m/s and 4 kN m
per axle; an electric steering actuator with one sample of delay, 0.05 s lag, 1 rad/s (road
wheel) and 0.6 rad.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_positive, is_concrete
from .._fields import array_field, bool_field
from ..control.plant.hardware import MAX_DELAY


class DriveActuators(eqx.Module):
    r"""Control period and the three actuator channels $(T_F, T_R, \delta)$ (module
    docstring). Per-channel fields have shape (3,).

    **Fields** (SI units): `sample_time` $T$ [s] (0.05); `delay` [s] (0.05 each, rounded to
    whole samples, at most `MAX_DELAY`); `time_constant` $\tau$ [s] (0.05 each);
    `rate` [N m/s, N m/s, rad/s] (30 000, 30 000, 1); `limit` [N m, N m, rad] (4000, 4000,
    0.6); switches `delay_on`, `rate_limit_on`, `lag_on` (per channel or one for all).
    """

    sample_time: Float[Array, ""] = array_field(default=0.05)
    delay: Float[Array, " 3"] = array_field(default=(0.05, 0.05, 0.05))
    time_constant: Float[Array, " 3"] = array_field(default=(0.05, 0.05, 0.05))
    rate: Float[Array, " 3"] = array_field(default=(30_000.0, 30_000.0, 1.0))
    limit: Float[Array, " 3"] = array_field(default=(4000.0, 4000.0, 0.6))
    delay_on: Array = bool_field(default=True)
    rate_limit_on: Array = bool_field(default=True)
    lag_on: Array = bool_field(default=True)

    def __check_init__(self):
        owner = "DriveActuators"
        check_positive(owner, "sample_time", self.sample_time)
        for name in ("time_constant", "rate", "limit"):
            check_positive(owner, name, getattr(self, name))
            if jnp.shape(getattr(self, name))[-1:] != (3,):
                raise ValueError(f"{owner}.{name} must have shape (3,) (T_F, T_R, delta), "
                                 f"got {jnp.shape(getattr(self, name))}")
        if is_concrete(self.delay) and is_concrete(self.sample_time):
            d = np.asarray(self.delay, dtype=float)
            T = float(np.max(np.asarray(self.sample_time)))
            if np.any(d < 0) or np.any(d > MAX_DELAY * T):
                raise ValueError(f"DriveActuators.delay must lie in [0, {MAX_DELAY * T:g}] s "
                                 f"(at most {MAX_DELAY} samples of sample_time), got {d}")

    def delay_samples(self):
        """The delay of each channel in samples (0 where it is switched off)."""
        d = jnp.round(self.delay / self.sample_time).astype(int)
        return jnp.where(self.delay_on, d, 0)


def ideal_actuators(**changes) -> DriveActuators:
    """Delay, rate limit and lag off: the command is applied at once over the sample."""
    off = dict(delay_on=False, rate_limit_on=False, lag_on=False)
    off.update(changes)
    return DriveActuators(**off)


class DriveActuatorState(eqx.Module):
    """The commands on their way (`buffer`, one row per sample), the last rate-limited
    target `target` and the applied values `applied` at the sample time (each (3,))."""

    buffer: Float[Array, "n 3"]
    target: Float[Array, " 3"]
    applied: Float[Array, " 3"]

    @staticmethod
    def init(u0=(0.0, 0.0, 0.0)) -> DriveActuatorState:
        u = jnp.broadcast_to(jnp.asarray(u0, dtype=float), (3,))
        return DriveActuatorState(jnp.tile(u, (MAX_DELAY + 1, 1)), u, u)


def actuator_target(act: DriveActuators, state: DriveActuatorState, k, command):
    """Steps 1-3 for the command issued at sample `k`: the new state (applied values not yet
    advanced) and the target held over the sample."""
    command = jnp.clip(jnp.asarray(command, dtype=float), -act.limit, act.limit)
    n = MAX_DELAY + 1
    buffer = state.buffer.at[k % n].set(command)
    delayed = buffer[(k - act.delay_samples()) % n, jnp.arange(3)]
    step = act.rate * act.sample_time
    limited = jnp.clip(delayed, state.target - step, state.target + step)
    target = jnp.where(act.rate_limit_on, limited, delayed)
    return DriveActuatorState(buffer, target, state.applied), target


def applied(act: DriveActuators, u0, target, t):
    """The applied values a time `t` into the sample (step 4; the target with the lag off)."""
    return jnp.where(act.lag_on, target + (u0 - target) * jnp.exp(-t / act.time_constant),
                     target)


def mean_applied(act: DriveActuators, u0, target):
    r"""$\frac1T\int_0^T u\,dt$ over the sample (exact for the lag response)."""
    a = act.sample_time / act.time_constant
    return jnp.where(act.lag_on, target + (u0 - target) * (-jnp.expm1(-a) / a), target)
