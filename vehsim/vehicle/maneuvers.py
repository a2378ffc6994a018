r"""Open-loop test maneuvers for the torque-input `HalfCar`: control laws $u(t, y)$.

Each returns a callable ``u(t, state) -> (T_F, T_R, delta)`` for `vehsim.simulate`; all
arguments may be JAX arrays (so a sweep can vmap over them). Steering and torque steps are
smoothed over `rise` seconds with $3s^2 - 2s^3$ (finite input rates; adaptive solvers stay
efficient and the inputs stay differentiable).
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp

from .._checks import check_finite, check_nonnegative, check_positive, check_range


def smooth_step(t, t0, rise):
    r"""0 before $t_0$, 1 after $t_0 + $ `rise`, $3s^2 - 2s^3$ in between."""
    s = jnp.clip((t - t0) / rise, 0.0, 1.0)
    return s * s * (3.0 - 2.0 * s)


def _check_steering(owner, delta, start: tuple[str, float], rise):
    """A steering angle within a quarter turn, its start time (name, value) not negative and
    a positive rise."""
    check_range(owner, "delta", delta, lower=-0.5 * math.pi, upper=0.5 * math.pi)
    check_nonnegative(owner, *start)
    check_positive(owner, "rise", rise)


def step_steer(delta, t_step=0.5, rise=0.2, drive_torque=0.0):
    r"""Step steer: $\delta(t) = \delta\,H(t - t_{step})$ (smoothed), constant torques.

    **Arguments:** `delta` [rad] final steering angle; `t_step` [s]; `rise` [s];
    `drive_torque` [N m] on each axle (0: coasting). Refuses a steering angle beyond a
    quarter turn, a negative step time and a rise that is not positive.
    """
    _check_steering("step_steer", delta, ("t_step", t_step), rise)
    check_finite("step_steer", "drive_torque", drive_torque)

    def u(t, y):
        d = delta * smooth_step(t, t_step, rise)
        T = drive_torque * jnp.ones_like(d)
        return jnp.stack([T, T, d])

    return u


def brake_in_turn(
    delta, brake_torque, t_brake=2.0, rise=0.2, front_share=0.6, t_steer=0.2, omega_lock=1.0
):
    r"""Braking in a turn: steer to $\delta$ (at `t_steer`), then brake from `t_brake`.

    The total braking torque `brake_torque` [N m] ($> 0$) is split `front_share` :
    1 - `front_share` between the axles. Brakes oppose the wheel's rotation,
    $T_i = -T_{b,i}\tanh(\omega_i/\omega_{lock})$ ($\omega_{lock}$ = `omega_lock` rad/s),
    so a locked wheel stays (nearly) locked instead of being spun backwards. Needs the
    `HalfCar` state (wheel speeds at indices 6, 7). Refuses a steering angle beyond a
    quarter turn, a negative torque or time, a share outside [0, 1].
    """
    _check_steering("brake_in_turn", delta, ("t_steer", t_steer), rise)
    for name, value in (("brake_torque", brake_torque), ("t_brake", t_brake)):
        check_nonnegative("brake_in_turn", name, value)
    check_range("brake_in_turn", "front_share", front_share, lower=0.0, upper=1.0)
    check_positive("brake_in_turn", "omega_lock", omega_lock)

    def u(t, y):
        d = delta * smooth_step(t, t_steer, rise)
        b = brake_torque * smooth_step(t, t_brake, rise)
        TF = -front_share * b * jnp.tanh(y[6] / omega_lock)
        TR = -(1.0 - front_share) * b * jnp.tanh(y[7] / omega_lock)
        return jnp.stack([TF, TR, d])

    return u


MANEUVERS = {"step_steer": step_steer, "brake_in_turn": brake_in_turn}


def half_car_scenario(params, tire, maneuver: str, speed: float, axes: Sequence[str]):
    r"""``member -> (HalfCar, inputs, state0)`` for a sweep (`vehsim.sweep`) of the
    `HalfCar` over named axes.

    **Arguments:** `params` (`HalfCarParams`) and `tire` (any static or dynamic
    `AbstractTire`) of the base vehicle; `maneuver`: a key of `MANEUVERS`; `speed` [m/s]:
    the initial speed unless ``"speed"`` is an axis; `axes`: the member's names, each a
    `HalfCarParams` field, an array field of the tire, ``"speed"`` or an argument of the
    maneuver (``delta``, ``brake_torque``, ...). Unknown names raise `ValueError`.
    """
    from .half_car import HalfCar

    if maneuver not in MANEUVERS:
        raise ValueError(f"unknown maneuver {maneuver!r}; known: {sorted(MANEUVERS)}")
    build = MANEUVERS[maneuver]
    build_args = set(inspect.signature(build).parameters)
    maneuver_args = build_args | {"speed"}
    vehicle_fields = set(type(params).__dataclass_fields__)
    tire_fields = {k for k, v in vars(tire).items() if eqx.is_array(v)}
    for name in axes:
        if name not in vehicle_fields | tire_fields | maneuver_args:
            raise ValueError(
                f"unknown sweep axis {name!r}; vehicle fields {sorted(vehicle_fields)}, "
                f"tire fields {sorted(tire_fields)}, maneuver arguments {sorted(maneuver_args)}"
            )
    defaults = {k: v for k, v in {"delta": 0.1, "brake_torque": 1500.0}.items()
                if k in build_args}

    def scenario(member):
        p = _replace(params, {k: member[k] for k in axes if k in vehicle_fields})
        t = _replace(tire, {k: member[k] for k in axes if k in tire_fields})
        kw = dict(defaults) | {k: member[k] for k in axes if k in build_args}
        car = HalfCar(p, t)
        v0 = member["speed"] if "speed" in member else speed
        check_positive("half_car_scenario", "speed", v0)
        return car, build(**kw), car.init_state(vx=v0)

    return scenario


def _replace(module, changes: dict):
    """`module` with some fields changed, rebuilt through its constructor where it has the
    default one (so that its field checks run on concrete values); else by `eqx.tree_at`."""
    if not changes:
        return module
    try:
        return dataclasses.replace(module, **changes)
    except TypeError:  # a custom __init__ that does not take every field
        return eqx.tree_at(lambda m: [getattr(m, k) for k in changes], module,
                           list(changes.values()))
