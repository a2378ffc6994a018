r"""The closed braking loop at the controller's rate, one `lax.scan` over samples.

Per sample $k$ at $t_k = kT$: measure (`vehsim.control.plant.sensors`), update the observer with
the mean brake torque of the last sample, let the controller command a torque from the
measurement and the estimator's belief (its `belief`: the tire it believes in;
the full torque below `handback_speed`), pass it through the actuator (`vehsim.control.plant.hardware`) and
integrate the plant to $t_{k+1}$ (`vehsim.control.plant.quarter_car`). The stopping distance and time
are recorded when the speed first falls below `stop_speed` (linear interpolation within
the sample), so a batch need not keep trajectories.
"""

from __future__ import annotations

import functools as ft

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray, PyTree

from .._checks import check_count, check_range, sample_count
from .._controller_grid import grid_sample, split_groups, tile_groups
from .._results import RESULTS, as_result
from .._solution import AbstractSolution
from .controllers.braking import AbstractBrakeController, measurement
from .estimation.base import AbstractFrictionEstimator
from .plant.hardware import (
    ActuatorState,
    BrakeHardware,
    actuator_target,
    brake_torque,
    mean_brake_torque,
    realistic_hardware,
)
from .plant.integrate import SUBSTEPS
from .plant.quarter_car import BrakingScenario, advance, initial_plant_state, unpack
from .plant.sensors import EncoderState, vehicle_speed, wheel_speed


STOP_SPEED = 1.0
"""Speed [m/s] at which a braking counts as stopped (the stopping distance's end)."""
HANDBACK_SPEED = 3.0
"""Measured speed [m/s] below which the controllers hand back to plain braking."""


class BrakingRun(AbstractSolution):
    """One closed-loop braking: `stopping_distance` [m] and `stopping_time` [s] (inf if the
    speed stayed above `STOP_SPEED`), the `final_speed` and `final_distance` at the end of
    the run, `result` (a `vehsim.RESULTS` item:
    the first sample whose solve failed, e.g. `max_steps_reached`), `stats` (``num_steps``:
    the plant's integration steps, samples times substeps), and, if saved (else `None`), the
    sample times `ts` and `signals` at the control rate: ``ts``, the
    distance `x`, speeds `v`, `omega`, the true `slip` $r\\omega/v - 1$ and friction `mu`
    $= F_x/F_n$, the brake `torque` at the sample and the `target` it lags towards over the
    sample, the controller's `command` and `phase`, the measured `v_meas`, `omega_meas`
    (standing for time `omega_stamp`; a measurement if `fresh`), and the estimator's
    `signals` (for a `FrictionObserver`: `theta_hat`, `v_hat`, wheel-speed `innovation`
    and the covariance of its log, `theta_covariance`).

    ``run["v"]`` is a saved signal; a batch of runs (`simulate_braking_grid`: leading axes
    (C, M); `stack`) is indexed like an array, ``runs[c, m]`` or ``runs[c]``, giving the run
    (or sub-batch) with every field indexed alike."""

    stopping_distance: Float[Array, ""]
    stopping_time: Float[Array, ""]
    final_speed: Float[Array, ""]
    final_distance: Float[Array, ""]
    result: RESULTS
    signals: dict | None
    ts: Float[Array, " T"] | None
    stats: dict

    def __getitem__(self, index):
        if isinstance(index, str):
            return super().__getitem__(index)
        return jax.tree_util.tree_map(lambda a: a[index], self)


class PreviousSample(eqx.Module):
    """What the observer and the controller need of the last sample: the measured wheel
    speed `omega` [rad/s], and the brake `torque` [N m] the actuator applied at its start
    and the `target` it lagged towards over it."""

    omega: Float[Array, ""]
    torque: Float[Array, ""]
    target: Float[Array, ""]


class StopRecord(eqx.Module):
    """The `distance` [m] and `time` [s] at which the speed first fell below `STOP_SPEED`
    (inf until then)."""

    distance: Float[Array, ""]
    time: Float[Array, ""]


class LoopState(eqx.Module):
    """Everything a run carries from sample to sample except the controller's own state:
    the plant state `y`, the encoder, the actuator, the observer, the `previous` sample, the
    `stop` record and the first unsuccessful result of a sample's solve."""

    y: Array
    encoder: EncoderState
    actuator: ActuatorState
    observer: PyTree
    previous: PreviousSample
    stop: StopRecord
    result: RESULTS


def _init(scenario: BrakingScenario, observer: AbstractFrictionEstimator,
          hardware: BrakeHardware):
    y0 = initial_plant_state(scenario)
    qs = unpack(scenario, y0)[1]
    inf = jnp.asarray(jnp.inf, dtype=y0.dtype)
    z = jnp.zeros((), y0.dtype)
    return LoopState(y0, EncoderState.init(hardware, qs.omega), ActuatorState.init(),
                     observer.init(qs.omega, qs.v), PreviousSample(qs.omega, z, z),
                     StopRecord(inf, inf), RESULTS.successful)


def _sense(scenario, observer, hardware, substeps, key, st: LoopState, k):
    """Measure, update the observer: ``(state, Measurement, signals to save)``."""
    T = hardware.sample_time
    t = k * T
    qs = unpack(scenario, st.y)[1]
    omega_m, stamp, fresh, enc = wheel_speed(hardware, st.encoder, t, qs.omega)
    v_m = vehicle_speed(hardware, key, k, qs.v)
    previous = st.previous
    # the update of the first sample (no last sample yet) is computed and dropped, not
    # branched around: a vmapped cond computes both branches anyway, and reverse mode
    # through a cond keeps residuals for both (a larger program to compile)
    updated = observer.update(st.observer, scenario.car, hardware, substeps, v_m, omega_m, stamp,
                              fresh, previous.torque, previous.target, t - T)
    obs = jax.tree_util.tree_map(lambda a, b: jnp.where(k > 0, a, b), updated, st.observer)
    m = measurement(omega_m, obs.v, previous.omega, scenario.car.radius, T,
                    mean_brake_torque(hardware, previous.torque, previous.target))
    seen = dict(v_meas=v_m, omega_meas=omega_m, omega_stamp=stamp, fresh=fresh) | \
        observer.signals(obs)
    previous = eqx.tree_at(lambda p: p.omega, previous, omega_m)
    st = LoopState(st.y, enc, st.actuator, obs, previous, st.stop, st.result)
    return st, m, seen


def _move(scenario, hardware, substeps, handback, save, st: LoopState, k, cmd, phase):
    """Actuate and integrate the plant to the next sample: ``(state, signals to save)``."""
    T = hardware.sample_time
    t = k * T
    cmd = jnp.where(st.observer.v < handback, hardware.max_torque, cmd)
    act, target = actuator_target(hardware, st.actuator, k, cmd)
    y1, enc, result = advance(scenario, hardware, st.y, st.encoder, t, act.torque, target, substeps)
    out = _signals(scenario, st.y, t, act.torque, cmd, phase) | {"target": target} if save \
        else None
    previous = PreviousSample(st.previous.omega, act.torque, target)
    act = eqx.tree_at(lambda a: a.torque, act, brake_torque(hardware, act.torque, target, T))
    stop = _stop(st.stop, scenario, st.y, y1, t, T)
    result = RESULTS.where(st.result == RESULTS.successful, as_result(result), st.result)
    return LoopState(y1, enc, act, st.observer, previous, stop, result), out


def _signals(scenario, y, t, torque, cmd, phase):
    x, qs, _ = unpack(scenario, y)
    r = scenario.car.radius
    mu = scenario.tire_at(t, x, qs.v).mu(qs.tire, qs.v, qs.omega, r)
    slip = qs.omega * r / jnp.maximum(qs.v, 1e-9) - 1.0
    return dict(ts=t, x=x, v=qs.v, omega=qs.omega, slip=slip, mu=mu, torque=torque,
                command=cmd, phase=phase)


def _sample(scenario, controller, observer, hardware, key, substeps, save, handback, carry, k):
    st, ctrl = carry
    st, m, seen = _sense(scenario, observer, hardware, substeps, key, st, k)
    ctrl, cmd, phase = controller.command(ctrl, m, observer.belief(st.observer), scenario.car,
                                          hardware.sample_time, hardware.max_torque)
    st, out = _move(scenario, hardware, substeps, handback, save, st, k, cmd, phase)
    return (st, ctrl), (out | seen if save else None)


def _stop(stop: StopRecord, scenario, y0, y1, t, T) -> StopRecord:
    """The stop record after the sample from `y0` to `y1`: its first crossing of
    `STOP_SPEED`, interpolated linearly in the sample."""
    x0, q0, _ = unpack(scenario, y0)
    x1, q1, _ = unpack(scenario, y1)
    crossing = (q0.v >= STOP_SPEED) & (q1.v < STOP_SPEED) & jnp.isinf(stop.distance)
    w = jnp.clip((q0.v - STOP_SPEED) / jnp.where(crossing, q0.v - q1.v, 1.0), 0.0, 1.0)
    return StopRecord(jnp.where(crossing, x0 + w * (x1 - x0), stop.distance),
                      jnp.where(crossing, t + w * T, stop.time))


def closed_loop(scenario: BrakingScenario, controller: AbstractBrakeController,
                observer: AbstractFrictionEstimator, hardware: BrakeHardware, key: PRNGKeyArray,
                n_steps: int, substeps: int = SUBSTEPS, save: bool = True,
                handback_speed=HANDBACK_SPEED) -> BrakingRun:
    """The braking of `scenario` under `controller` for `n_steps` samples (pure function:
    jit, vmap over scenarios, keys and array fields, grad with respect to any of them, in
    forward or reverse mode; the sample is checkpointed, so reverse mode stores one carry per
    sample). `n_steps` and `substeps` are integers >= 1, `handback_speed` [m/s] >= 0."""
    check_count("closed_loop", "n_steps", n_steps, sep=": ")
    check_count("closed_loop", "substeps", substeps, sep=": ")
    check_range("closed_loop", "handback_speed", handback_speed, lower=0.0)
    carry0 = (_init(scenario, observer, hardware), controller.init(hardware.max_torque))
    step = ft.partial(_sample, scenario, controller, observer, hardware, key, substeps, save,
                      jnp.asarray(handback_speed, dtype=float))
    # reverse mode keeps only the carry per sample and recomputes the sample on the way back
    # (docs/differentiating.md); no effect on values, forward mode or plain runs
    step = jax.checkpoint(step, prevent_cse=False)
    (st, _), out = jax.lax.scan(step, carry0, jnp.arange(n_steps))
    return _run(scenario, st, out, n_steps * substeps)


def _run(scenario, st: LoopState, out, num_steps: int) -> BrakingRun:
    x, qs, _ = unpack(scenario, st.y)
    return BrakingRun(st.stop.distance, st.stop.time, qs.v, x, st.result, out,
                      None if out is None else out["ts"], {"num_steps": jnp.asarray(num_steps)})


@eqx.filter_jit
def _simulate(scenario, controller, observer, hardware, key, n_steps, substeps, save, handback):
    return closed_loop(scenario, controller, observer, hardware, key, n_steps, substeps, save,
                       handback)


def simulate_braking(scenario: BrakingScenario, controller: AbstractBrakeController,
                     observer: AbstractFrictionEstimator, hardware: BrakeHardware | None = None,
                     key: PRNGKeyArray | None = None, duration: float = 5.0,
                     substeps: int = SUBSTEPS, save: bool = True,
                     handback_speed: float = HANDBACK_SPEED) -> BrakingRun:
    """Simulate one closed-loop braking (jitted; new array values do not recompile).

    **Arguments:** `scenario` (`BrakingScenario`), `controller`, `observer`
    (an `AbstractFrictionEstimator`, e.g. a `FrictionObserver`, run for every controller),
    `hardware` (default: realistic),
    `key` (sensor noise; default PRNGKey(0)), `duration` [s] (rounded to whole samples),
    `substeps` (integration sub-steps per sample), `save` (keep the signals),
    `handback_speed` [m/s].

    **Returns:** a `BrakingRun`.
    """
    hardware = realistic_hardware() if hardware is None else hardware
    key = jax.random.PRNGKey(0) if key is None else key
    n_steps = sample_count("simulate_braking", duration, hardware.sample_time, substeps)
    check_range("simulate_braking", "handback_speed", handback_speed, lower=0.0)
    return _simulate(scenario, controller, observer, hardware, key, n_steps, int(substeps),
                     bool(save), jnp.asarray(handback_speed, dtype=float))


def _grid_step(scenarios, controllers, observers, hardware, keys, substeps, save, handback, carry,
               k):
    """One sample of every run (`grid_sample`): sense and move vmapped over all runs, each
    controller's law vmapped over its own group only."""
    def sense(st):
        st, m, seen = jax.vmap(lambda sc, ob, key, s: _sense(sc, ob, hardware, substeps, key, s, k))(
            scenarios, observers, keys, st)
        beliefs = jax.vmap(lambda ob, s: ob.belief(s.observer))(observers, st)
        return st, (m, beliefs, scenarios), seen

    def act(st, seen, commands):
        cmd, phase = commands
        st, out = jax.vmap(
            lambda sc, s, c, p: _move(sc, hardware, substeps, handback, save, s, k, c, p))(
            scenarios, st, cmd, phase)
        return st, (out | seen if save else None)

    laws = [ft.partial(_law, controller, hardware) for controller in controllers]
    st, ctrls = carry
    return grid_sample(sense, laws, act, st, ctrls)


def _law(controller, hardware, ctrl, inputs):
    """A braking controller as a law of the controller grid: its state, and the (torque
    command, phase) of the sample's measurement and the observer's belief."""
    m, belief, scenario = inputs
    ctrl, cmd, phase = controller.command(ctrl, m, belief, scenario.car, hardware.sample_time,
                                          hardware.max_torque)
    return ctrl, (cmd, phase)


def closed_loop_grid(scenarios: BrakingScenario, controllers,
                     observers: AbstractFrictionEstimator,
                     hardware: BrakeHardware, keys, n_steps: int, substeps: int = SUBSTEPS,
                     save: bool = False, handback_speed=HANDBACK_SPEED) -> BrakingRun:
    """`simulate_braking_grid` as a pure function of its inputs (jit, vmap, jvp apply)."""
    G = len(controllers)
    scenarios, observers, keys = tile_groups((scenarios, observers, keys), G)
    st0 = jax.vmap(lambda sc, ob: _init(sc, ob, hardware))(scenarios, observers)
    M = keys.shape[0] // G
    ctrl0 = tuple(jax.vmap(lambda _: c.init(hardware.max_torque))(jnp.arange(M)) for c in controllers)
    step = ft.partial(_grid_step, scenarios, tuple(controllers), observers, hardware, keys, substeps,
                      save, jnp.asarray(handback_speed, dtype=float))
    (st, _), out = jax.lax.scan(step, (st0, ctrl0), jnp.arange(n_steps))
    if save:  # scan stacks time first
        out = jax.tree_util.tree_map(lambda a: jnp.swapaxes(a, 0, 1), out)
    run = jax.vmap(ft.partial(_run, num_steps=n_steps * substeps))(scenarios, st, out)
    return split_groups(run, G)


_grid = eqx.filter_jit(closed_loop_grid)


def simulate_braking_grid(scenarios: BrakingScenario, controllers,
                          observers: AbstractFrictionEstimator,
                          keys, hardware: BrakeHardware | None = None, duration: float = 5.0,
                          substeps: int = SUBSTEPS, save: bool = False,
                          handback_speed: float = HANDBACK_SPEED) -> BrakingRun:
    """Every controller on every run, in one jitted call.

    **Arguments:** `scenarios`, `observers` and `keys` with a leading axis of M runs (stack
    them with `stack`), `controllers` (C of them, each with its own code), `hardware`,
    `duration`, `substeps`, `save` (keep the signals: memory grows as C x M x samples),
    `handback_speed`.

    **Returns:** a `BrakingRun` whose fields have leading axes (C, M).
    """
    hardware = realistic_hardware() if hardware is None else hardware
    n_steps = sample_count("simulate_braking_grid", duration, hardware.sample_time, substeps)
    check_range("simulate_braking_grid", "handback_speed", handback_speed, lower=0.0)
    return _grid(scenarios, tuple(controllers), observers, hardware, keys, n_steps, int(substeps),
                 bool(save), jnp.asarray(handback_speed, dtype=float))


def stack(items):
    """A batch (one new leading axis) of modules of the same structure: the scenarios and
    observers of `simulate_braking_grid`, or runs (index a batch of runs with
    ``runs[i]``)."""
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *items)
