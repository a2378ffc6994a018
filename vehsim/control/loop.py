r"""The closed braking loop at the controller's rate, one `lax.scan` over samples.

Per sample $k$ at $t_k = kT$: measure (`vehsim.control.sensors`), update the observer with
the mean brake torque of the last sample, let the controller command a torque (the full
torque below `handback_speed`), pass it through the actuator (`vehsim.control.hardware`) and
integrate the plant to $t_{k+1}$ (`vehsim.control.plant`). The stopping distance and time
are recorded when the speed first falls below `stop_speed` (linear interpolation within
the sample), so a batch need not keep trajectories.
"""

from __future__ import annotations

import functools as ft

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .controllers import AbstractBrakeController, measurement
from .hardware import ActuatorState, BrakeHardware, actuator_target, brake_torque
from .observer import FrictionObserver
from .plant import BrakingScenario, advance, initial_plant_state, unpack
from .sensors import EncoderState, vehicle_speed, wheel_speed


STOP_SPEED = 1.0
"""Speed [m/s] at which a braking counts as stopped (the stopping distance's end)."""
HANDBACK_SPEED = 3.0
"""Measured speed [m/s] below which the controllers hand back to plain braking."""


class BrakingRun(eqx.Module):
    """One closed-loop braking: `stopping_distance` [m] and `stopping_time` [s] (inf if the
    speed stayed above `STOP_SPEED`), and, if saved, samples at the control rate: `ts`, the
    distance `x`, speeds `v`, `omega`, the true `slip` $r\\omega/v - 1$ and friction `mu`
    $= F_x/F_n$, the applied brake `torque`, the controller's `command` and `phase`, the
    measured `v_meas`, `omega_meas`, and the observer's `theta_hat`."""

    stopping_distance: Float[Array, ""]
    stopping_time: Float[Array, ""]
    final_speed: Float[Array, ""]
    signals: dict | None

    def __getitem__(self, name):
        return self.signals[name]


def _sample(scenario, controller, observer, hw, key, substeps, save, handback, carry, k):
    y, enc, act, obs, ctrl, prev, stop = carry
    car, T = scenario.car, hw.sample_time
    t = k * T
    x, qs, _ = unpack(scenario, y)
    omega_m, stamp, fresh, enc = wheel_speed(hw, enc, t, qs.omega)
    v_m = vehicle_speed(hw, key, k, qs.v)
    omega_prev, torque_prev, target_prev = prev
    obs = jax.lax.cond(
        k > 0, lambda o: observer.update(o, car, hw, substeps, v_m, omega_m, stamp, fresh,
                                         torque_prev, target_prev, t - T),
        lambda o: o, obs)
    m = measurement(omega_m, obs.v, omega_prev, car.radius, T)
    ctrl, cmd, phase = controller.command(ctrl, m, obs.theta, observer.model, car, T,
                                          hw.max_torque)
    cmd = jnp.where(obs.v < handback, hw.max_torque, cmd)
    act, target = actuator_target(hw, act, k, cmd)
    prev = (omega_m, act.torque, target)
    y1, enc = advance(scenario, hw, y, enc, t, act.torque, target, substeps)
    torque = act.torque
    act = eqx.tree_at(lambda a: a.torque, act, brake_torque(hw, act.torque, target, T))
    stop = _stop(stop, scenario, y, y1, t, T)
    out = None
    if save:
        tire = scenario.tire_at(t, x)
        mu = tire.mu(qs.tire, qs.v, qs.omega, car.radius)
        slip = qs.omega * car.radius / jnp.maximum(qs.v, 1e-9) - 1.0
        out = dict(ts=t, x=x, v=qs.v, omega=qs.omega, slip=slip, mu=mu, torque=torque,
                   command=cmd, phase=phase, v_meas=v_m, omega_meas=omega_m, v_hat=obs.v,
                   theta_hat=obs.theta, innovation=obs.innovation)
    return (y1, enc, act, obs, ctrl, prev, stop), out


def _stop(stop, scenario, y0, y1, t, T):
    """(distance, time) of the first crossing of `STOP_SPEED`, interpolated in the sample."""
    x0, q0, _ = unpack(scenario, y0)
    x1, q1, _ = unpack(scenario, y1)
    crossing = (q0.v >= STOP_SPEED) & (q1.v < STOP_SPEED) & jnp.isinf(stop[0])
    w = jnp.clip((q0.v - STOP_SPEED) / jnp.where(crossing, q0.v - q1.v, 1.0), 0.0, 1.0)
    return (jnp.where(crossing, x0 + w * (x1 - x0), stop[0]),
            jnp.where(crossing, t + w * T, stop[1]))


def closed_loop(scenario: BrakingScenario, controller: AbstractBrakeController,
                observer: FrictionObserver, hw: BrakeHardware, key: PRNGKeyArray,
                n_steps: int, substeps: int = 4, save: bool = True,
                handback_speed=HANDBACK_SPEED) -> BrakingRun:
    """The braking of `scenario` under `controller` for `n_steps` samples (pure function:
    jit, vmap over scenarios, keys and array fields, grad with respect to any of them)."""
    y0 = initial_plant_state(scenario)
    qs = unpack(scenario, y0)[1]
    inf = jnp.asarray(jnp.inf, dtype=y0.dtype)
    carry0 = (y0, EncoderState.init(hw, qs.omega), ActuatorState.init(),
              observer.init(qs.omega, qs.v), controller.init(hw.max_torque),
              (qs.omega, jnp.zeros(()), jnp.zeros(())), (inf, inf))
    step = ft.partial(_sample, scenario, controller, observer, hw, key, substeps, save,
                      jnp.asarray(handback_speed, dtype=y0.dtype))
    step = jax.checkpoint(step, static_argnums=())
    carry, out = jax.lax.scan(step, carry0, jnp.arange(n_steps))
    stop = carry[6]
    return BrakingRun(stop[0], stop[1], unpack(scenario, carry[0])[1].v, out)


@eqx.filter_jit
def _simulate(scenario, controller, observer, hw, key, n_steps, substeps, save, handback):
    return closed_loop(scenario, controller, observer, hw, key, n_steps, substeps, save,
                       handback)


def simulate_braking(scenario: BrakingScenario, controller: AbstractBrakeController,
                     observer: FrictionObserver, hardware: BrakeHardware | None = None,
                     key: PRNGKeyArray | None = None, duration: float = 5.0,
                     substeps: int = 4, save: bool = True,
                     handback_speed: float = HANDBACK_SPEED) -> BrakingRun:
    """Simulate one closed-loop braking (jitted; new array values do not recompile).

    **Arguments:** `scenario` (`BrakingScenario`), `controller`, `observer`
    (`FrictionObserver`, run for every controller), `hardware` (default: realistic),
    `key` (sensor noise; default PRNGKey(0)), `duration` [s] (rounded to whole samples),
    `substeps` (integration sub-steps per sample), `save` (keep the signals),
    `handback_speed` [m/s].

    **Returns:** a `BrakingRun`.
    """
    from .hardware import realistic_hardware

    hw = realistic_hardware() if hardware is None else hardware
    key = jax.random.PRNGKey(0) if key is None else key
    n_steps = int(round(duration / float(hw.sample_time)))
    return _simulate(scenario, controller, observer, hw, key, n_steps, int(substeps),
                     bool(save), jnp.asarray(handback_speed, dtype=float))
