r"""The car's sensors: white Gaussian noise on each channel, keyed per sample.

At each sample the plant reports (`DriveMeasurement`) the axle wheel speeds, the yaw rate,
the longitudinal and lateral accelerations of the body (an IMU at the centre of gravity,
$a_x = \dot v_x - rv_y$, $a_y = \dot v_y + rv_x$, eqs. 49-50 in the body frame), the
velocity over ground in the body frame $(v_x, v_y)$ (an optical ground-speed sensor, or
GNSS Doppler velocity rotated by the heading), the pose $(x, y, \psi)$ (GNSS and heading),
the steering angle and the mean axle torques applied over the last sample (the actuators'
own model, as an engine or brake controller reports them). Each channel gets
$\mathcal N(0, \sigma^2)$ noise with its `DriveSensors` standard deviation, drawn from the
sample's key: a batch of seeds is a `vmap` over keys. The steering angle and the torques
are reported without noise.

**Values** (modelling choices, **not from a source**): wheel speed 0.05 rad/s, yaw rate
0.005 rad/s, accelerations 0.1 m/s^2, ground velocity 0.05 m/s, position 0.3 m (a
differential GNSS), heading 0.005 rad.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_nonnegative
from .._fields import array_field, bool_field


class DriveSensors(eqx.Module):
    """Noise standard deviations (SI units; module docstring) and the switch `noise_on`."""

    wheel_speed_std: Float[Array, ""] = array_field(default=0.05)
    yaw_rate_std: Float[Array, ""] = array_field(default=0.005)
    acceleration_std: Float[Array, ""] = array_field(default=0.1)
    velocity_std: Float[Array, ""] = array_field(default=0.05)
    position_std: Float[Array, ""] = array_field(default=0.3)
    heading_std: Float[Array, ""] = array_field(default=0.005)
    noise_on: Array = bool_field(default=True)

    def __check_init__(self):
        for name in ("wheel_speed_std", "yaw_rate_std", "acceleration_std", "velocity_std",
                     "position_std", "heading_std"):
            check_nonnegative("DriveSensors", name, getattr(self, name))


class DriveMeasurement(eqx.Module):
    r"""What the controller sees at a sample: time `t` [s], `omega` (front, rear) [rad/s],
    `yaw_rate` [rad/s], `ax`, `ay` [m/s^2], ground velocity `vx`, `vy` [m/s] (body frame),
    pose `x`, `y` [m], `psi` [rad], `delta` [rad] and the mean axle torques `torque`
    (front, rear) [N m] of the last sample."""

    t: Float[Array, ""]
    omega: Float[Array, " 2"]
    yaw_rate: Float[Array, ""]
    ax: Float[Array, ""]
    ay: Float[Array, ""]
    vx: Float[Array, ""]
    vy: Float[Array, ""]
    x: Float[Array, ""]
    y: Float[Array, ""]
    psi: Float[Array, ""]
    delta: Float[Array, ""]
    torque: Float[Array, " 2"]

    @property
    def speed(self):
        """Ground speed $\\sqrt{v_x^2 + v_y^2}$ [m/s]."""
        return jnp.hypot(self.vx, self.vy)


def measure(sensors: DriveSensors, key, t, truth: dict, delta, torque) -> DriveMeasurement:
    """The measurement of the true signals `truth` (`HalfCar.signals` names) with the noise
    of `key`."""
    keys = jax.random.split(key, 9)
    on = jnp.where(sensors.noise_on, 1.0, 0.0)
    dtype = jnp.result_type(float)

    def noisy(i, value, std, shape=()):
        return value + on * std * jax.random.normal(keys[i], shape, dtype)

    omega = jnp.stack([truth["omega_F"], truth["omega_R"]])
    return DriveMeasurement(
        t=jnp.asarray(t, dtype=dtype),
        omega=noisy(0, omega, sensors.wheel_speed_std, (2,)),
        yaw_rate=noisy(1, truth["yaw_rate"], sensors.yaw_rate_std),
        ax=noisy(2, truth["ax"], sensors.acceleration_std),
        ay=noisy(3, truth["ay"], sensors.acceleration_std),
        vx=noisy(4, truth["vx"], sensors.velocity_std),
        vy=noisy(5, truth["vy"], sensors.velocity_std),
        x=noisy(6, truth["x"], sensors.position_std),
        y=noisy(7, truth["y"], sensors.position_std),
        psi=noisy(8, truth["psi"], sensors.heading_std),
        delta=jnp.asarray(delta, dtype=dtype),
        torque=jnp.asarray(torque, dtype=dtype),
    )
