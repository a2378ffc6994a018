r"""ABS on both axles of the half car braking in a turn (report eqs. 49-60).

The `HalfCar` (suspension dynamics, so that the load moves to the front as it brakes) on
dynamic isotropic lumped LuGre tires (`IsotropicLumpedLuGre`, the surface's parameters,
$\kappa_0$ = 1.5), steered to a constant angle `delta` from the start and braked from
`brake_time` on. Each axle has its own actuator (`BrakeHardware`, per-axle torque) and
controller, sampled at the hardware's rate; the controllers see the axle's wheel speed and
its longitudinal speed over the ground (measured with the hardware's speed noise; the tone
wheels are not modelled here) and the axle's mean brake torque over the last sample, and are
told the road's lumped LuGre curve and the axle as a quarter car (`axle_cars`). Axle torques
are $T_i = -T_{b,i}\tanh(\omega_i/ \omega_\epsilon)$, $\omega_\epsilon$ = 1 rad/s.
Integration as the quarter car's (`integrate_sample`, implicit in each wheel with its tire).

With locked wheels a tire has no lateral grip left to give: locked front wheels plough the
car straight on (the yaw rate falls to nothing while steered), a locked rear axle lets the
car spin (yaw rate and sideslip grow); ABS keeps the wheels rolling near their peak, the car
follows the steering and its yaw rate stays bounded.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ..._checks import check_nonnegative, check_positive, check_range, sample_count
from ..._fields import array_field
from ..._results import RESULTS
from ..._solution import AbstractSolution
from ...tire.isotropic_lumped import IsotropicLumpedLuGre
from ...tire.uniform_lumped import UniformLumpedLuGre
from ...vehicle.half_car import HalfCar
from ...vehicle.maneuvers import smooth_step
from ...vehicle.params import rally_gravel
from ...vehicle.planar import axle_velocities
from ...vehicle.quarter_car import QuarterCar
from ..controllers.braking import AbstractBrakeController, RuleBasedABS, measurement
from ..plant.hardware import (
    ActuatorState,
    BrakeHardware,
    actuator_target,
    brake_torque,
    mean_brake_torque,
)
from ..plant.integrate import SUBSTEPS, integrate_sample
from ..road.surfaces import surface


OMEGA_EPS = 1.0
"""Brake-torque smoothing [rad/s] (as `braking_quarter_car`)."""


class TurnScenario(eqx.Module):
    """The car, its initial speed [m/s], the steering angle [rad] (reached over 0.2 s), the
    time braking starts [s] and the rear brakes' share `rear_share` of the front brakes'
    torque capacity (the front-biased proportioning of a passenger car)."""

    car: HalfCar
    speed: Float[Array, ""] = array_field()
    delta: Float[Array, ""] = array_field()
    brake_time: Float[Array, ""] = array_field()
    rear_share: Float[Array, ""] = array_field(default=0.4)

    def __check_init__(self):
        check_positive("TurnScenario", "speed", self.speed)
        check_range("TurnScenario", "delta", self.delta, lower=-math.pi / 2, upper=math.pi / 2,
                    lower_open=True, upper_open=True)
        check_nonnegative("TurnScenario", "brake_time", self.brake_time)
        check_range("TurnScenario", "rear_share", self.rear_share, lower=0.0, upper=1.0)


def turn_scenario(name: str = "dry_asphalt", speed=25.0, delta=0.02, brake_time=0.5,
                  rear_share=0.4):
    """The rally-gravel half car (`vehsim.rally_gravel`) on the surface `name`."""
    tire = IsotropicLumpedLuGre(surface(name).params, kappa0=1.5)
    return TurnScenario(HalfCar(rally_gravel(), tire), speed, delta, brake_time, rear_share)


def rear_abs() -> RuleBasedABS:
    """The rear axle's ABS: the rule-based cycle held to small slips (dump above 4 %, at once
    above 10 %), as production systems keep the rear axle stable at the cost of some of
    its braking force."""
    return RuleBasedABS(slip_threshold=0.04, lock_slip=0.1)


class TurnState(eqx.Module):
    """What the turn carries from sample to sample: the car's state `y`, the axles'
    actuators (batched over the two axles), the axle controllers' states, the wheel speeds
    at the last sample `omega_prev`, the axles' mean brake torques over it `brake_prev` and
    the first unsuccessful `result` of a sample's
    integration."""

    y: Array
    actuator: ActuatorState
    controllers: tuple
    omega_prev: Array
    brake_prev: Array
    result: RESULTS


class TurnRun(AbstractSolution):
    """Result of `simulate_turn`: at the control rate `ts` [s], `signals` holds the car's
    named signals (``x``, ``y``, ``psi``, ``vx``, ``vy``, ``yaw_rate``, ``speed``,
    ``sideslip``, ...), the axle brake ``torque`` (T, 2), the true ``slip`` (T, 2) and the
    controllers' ``phase`` (T, 2); `result` is the first sample whose integration failed
    (`RESULTS.nonfinite`), `stats` the integration steps."""

    ts: Float[Array, " T"]
    signals: dict
    result: RESULTS
    stats: dict


def _controls(sc: TurnScenario, hardware, y, t, t0, torque0, target):
    brake = brake_torque(hardware, torque0, target, t - t0)
    omega = y[6:8]
    axle = -brake * jnp.tanh(omega / OMEGA_EPS)
    delta = sc.delta * smooth_step(t, 0.0, 0.2)
    return jnp.stack([axle[0], axle[1], delta])


def _rates(t, y, args):
    sc, hardware, t0, torque0, target = args
    return sc.car.f(y, _controls(sc, hardware, y, t, t0, torque0, target))


def axle_cars(sc: TurnScenario):
    """What an axle's controller is told: the belief (the road's lumped LuGre,
    `UniformLumpedLuGre` of the tire's parameters: the turn has no estimator) and the axle as
    a quarter car (its static load, wheel inertia and radius)."""
    p = sc.car.params
    belief = UniformLumpedLuGre(sc.car.tire.params)
    length = p.lF + p.lR
    return belief, tuple(QuarterCar(belief, mass=p.m * share / length, inertia=inertia,
                                    radius=p.r, omega_eps=OMEGA_EPS)
                         for share, inertia in ((p.lR, p.Iw_F), (p.lF, p.Iw_R)))


def _axle_capacity(sc, hardware, i):
    """The brake torque capacity [N m] of axle ``i`` (0 front, 1 rear: `rear_share` of it)."""
    return hardware.max_torque * (1.0 if i == 0 else sc.rear_share)


def _sample(sc, controllers, hardware, key, st: TurnState, k):
    T = hardware.sample_time
    t = k * T
    p = sc.car.params
    delta = sc.delta * smooth_step(t, 0.0, 0.2)
    VFx, _, VRx, _ = axle_velocities(p, st.y[3], st.y[4], st.y[5], delta)
    noise = hardware.speed_noise_std * jax.random.normal(jax.random.fold_in(key, k), (2,))
    v_m = jnp.stack([VFx, VRx]) + jnp.where(hardware.noise, noise, 0.0)
    omega = st.y[6:8]
    belief, cars = axle_cars(sc)
    cmds, phases, new_ctrl = [], [], []
    for i, controller in enumerate(controllers):
        m = measurement(omega[i], v_m[i], st.omega_prev[i], p.r, T, st.brake_prev[i])
        # each axle's controller is told its own brakes' capacity (its anti-windup limit)
        cap = _axle_capacity(sc, hardware, i)
        c, cmd, phase = controller.command(st.controllers[i], m, belief, cars[i], T, cap)
        new_ctrl.append(c)
        cmds.append(jnp.where(t >= sc.brake_time, jnp.minimum(cmd, cap), 0.0))
        phases.append(phase)
    act, target = jax.vmap(lambda a, c: actuator_target(hardware, a, k, c))(st.actuator,
                                                                      jnp.stack(cmds))
    args = (sc, hardware, t, act.torque, target)
    y1, result = integrate_sample(_rates, st.y, args, t, T, sc.car.stiff_blocks)
    out = dict(ts=t, state=st.y, torque=act.torque, phase=jnp.stack(phases),
               slip=p.r * omega / jnp.stack([VFx, VRx]) - 1.0)
    brake_mean = mean_brake_torque(hardware, act.torque, target)
    act = eqx.tree_at(lambda a: a.torque, act, brake_torque(hardware, act.torque, target, T))
    result = RESULTS.where(st.result == RESULTS.successful, result, st.result)
    return TurnState(y1, act, tuple(new_ctrl), omega, brake_mean, result), out


@eqx.filter_jit
def _simulate(sc, controllers, hardware, key, n_steps):
    y0 = sc.car.init_state(vx=sc.speed)
    act0 = jax.vmap(lambda _: ActuatorState.init())(jnp.arange(2))
    ctrl0 = tuple(c.init(_axle_capacity(sc, hardware, i)) for i, c in enumerate(controllers))
    step = lambda st, k: _sample(sc, controllers, hardware, key, st, k)  # noqa: E731
    st0 = TurnState(y0, act0, ctrl0, y0[6:8], jnp.zeros(2, y0.dtype), RESULTS.successful)
    st, out = jax.lax.scan(step, st0, jnp.arange(n_steps))
    return st.result, out


def simulate_turn(sc: TurnScenario, front: AbstractBrakeController,
                  rear: AbstractBrakeController, hardware: BrakeHardware | None = None,
                  key: PRNGKeyArray | None = None, duration: float = 4.0) -> TurnRun:
    """Brake in a turn with the `front` and `rear` axle controllers.

    **Returns:** a `TurnRun`: the signals at the control rate, the car's named signals
    (``x``, ``y``, ``psi``, ``vx``, ``vy``, ``yaw_rate``, ``speed``, ``sideslip``, ...),
    the axle brake ``torque`` (T, 2), ``slip`` (T, 2) and controller ``phase`` (T, 2), and
    the integration's `result`.
    """
    hardware = BrakeHardware(max_torque=4000.0) if hardware is None else hardware
    key = jax.random.PRNGKey(0) if key is None else key
    n_steps = sample_count("simulate_turn", duration, hardware.sample_time)
    result, out = _simulate(sc, (front, rear), hardware, key, n_steps)
    ts = out.pop("ts")
    delta = sc.delta * smooth_step(ts, 0.0, 0.2)
    controls = jnp.stack([jnp.zeros_like(delta), jnp.zeros_like(delta), delta], axis=1)
    named = jax.vmap(sc.car.signals)(out.pop("state"), controls)
    for name in ("T_F", "T_R"):
        named.pop(name)
    return TurnRun(ts=ts, signals=out | named, result=result,
                   stats={"num_steps": jnp.asarray(n_steps * SUBSTEPS)})
