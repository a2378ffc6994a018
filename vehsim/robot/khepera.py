r"""A realistic Khepera plant and the closed-loop simulation at the 50 Hz control rate.

Each control sample $k$ (period $T = 1/50$ s, zero-order hold):

1. *measure*: the host reads the pose over the serial link: by default the odometry the
   robot integrated from its encoder counts (`vehsim.robot.odometry`: 12 pulses/mm, the
   nominal wheel diameter and wheel base), as it was `read_delay_samples` samples ago; with
   `encoders` off, the true pose instead (an external tracker), and with `noise` on, white
   Gaussian noise added to whichever is read;
2. *control*: the controller maps $(t, \hat p)$ to $(v, \omega)$, turned into wheel
   speeds $v_{L,R} = v \mp \omega b/2$ with the nominal wheel base $b$;
3. *command*: quantised to the Khepera speed unit (one pulse per 10 ms, 8.33 mm/s) and
   saturated at 127 units (1.06 m/s), then sent through a transport delay of
   `delay_samples` samples;
4. *plant*: over `substeps` sub-steps each wheel's pulse rate follows its command through
   its own first-order motor lag $\tau_{L,R}$ (the on-board PID loop). The ground moves under
   each wheel at that rate times the wheel's true travel per pulse (`wheel_scale`, the
   diameter mismatch) and, with `slip` on, times $1 - s_{i,k}$ with a random slip
   $s_{i,k} \sim N(0, \sigma_s^2)$ per wheel and sample; the pose moves along the exact
   unicycle arc of those ground speeds with the true wheel base $b\,$`wheel_base_scale`.

Every effect has a switch (boolean array field), and `ideal_plant()` turns all off (the
ZOH remains: it is the control rate). Values not in the report are marked **unverified**
(docs/parameters.md): wheel base 53 mm, speed unit, saturation; the motor time
constants, link delays, wheel mismatch, slip and noise levels are modelling choices.

`simulate_robot` runs one closed loop; `simulate_robot_grid` runs controllers x systems x
initial poses x seeds in one jitted call: one `lax.scan` over time whose body evaluates each
(controller, system) group's law vmapped over its runs (all gains in one PyTree) and
advances the shared plant vmapped over all runs, keeping only the scoring statistics. The
random disturbances (sensor noise, wheel slip) depend only on the run's key and the sample
index, so they are drawn once per initial pose (not per group) for blocks of 50 samples at
a time; the result is identical to `simulate_robot` run by run.
"""

from __future__ import annotations

import functools as ft
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._checks import (
    check_nonnegative,
    check_positive,
    check_range,
    is_concrete,
    sample_count,
)
from .._controller_grid import grid_sample, split_groups, tile_groups
from .._fields import array_field, bool_field, int_field
from .._results import RESULTS
from ..progress import advance, progress_bar, resolve
from ..sharding import pad_members, shard_members
from .controllers import AbstractController
from .missions import check_poses
from .odometry import dead_reckon, delay_line_read, delay_line_write, encoder_counts
from .scoring import RunStats
from .unicycle import AbstractSystem, body_velocity, unicycle_step, wheel_speeds


MAX_DELAY = 8
"""Length of the link's delay lines (largest allowed `delay_samples`, `read_delay_samples`)."""


class KheperaPlant(eqx.Module):
    r"""Khepera robot seen through its serial link (report 2.1).

    **Fields** (SI units):

    - `sample_time` [s]: control period, 0.02 (50 Hz, report).
    - `wheel_base` [m]: nominal wheel base $b$, 0.053 (**unverified**, docs/parameters.md):
      what the host uses for commands and odometry.
    - `pulses_per_meter` [1/m]: encoder resolution $p$, 12 000 (12 pulses/mm, report).
    - `speed_unit` [m/s]: speed-command quantum, one pulse per 10 ms = 1/120 m/s
      (**unverified**, docs/parameters.md).
    - `speed_limit` [m/s]: wheel-speed saturation, 127 units = 1.058 m/s (**unverified**).
    - `motor_time_constant` [s]: first-order lag of the (left, right) wheel, (0.06, 0.09):
      different on purpose, as the report says the two motors differ.
    - `delay_samples` [-]: samples from issuing a command to the motors applying it
      (integer, 0..8), 1.
    - `read_delay_samples` [-]: age in samples of the pose the host reads (integer, 0..8), 1;
      the loop's latency is the sum of the two (40 ms).
    - `wheel_scale` [-]: true ground travel per pulse over the nominal $1/p$, (left, right),
      (0.9985, 1.0015): wheel diameters 0.3 % apart (Borenstein's $E_d$ = 1.003).
    - `wheel_base_scale` [-]: true wheel base over the nominal one, 1.02 (1 mm on 53 mm).
    - `slip_std` [-]: standard deviation $\sigma_s$ of the random slip of each wheel in
      each sample, 0.02 (used when `slip` is on).
    - `noise_position` [m], `noise_heading` [rad]: standard deviations of the white noise
      added to the measured pose, 0.2 mm and 0.2 deg (used when `noise` is on).
    - switches: `motor_dynamics`, `delay` (both link delays), `quantization` (speed
      commands), `saturation`, `encoders` (the pose from odometry of quantised encoder
      counts; off = the true pose is read, as from an external tracker), `mismatch`
      (`wheel_scale`, `wheel_base_scale`; off = the nominal geometry is the true one),
      `slip` (off by default), `noise` (off by default: the Khepera has no pose sensor but
      its encoders).
    """

    sample_time: Float[Array, ""] = array_field(default=0.02)
    wheel_base: Float[Array, ""] = array_field(default=0.053)
    pulses_per_meter: Float[Array, ""] = array_field(default=12_000.0)
    speed_unit: Float[Array, ""] = array_field(default=1.0 / 120.0)
    speed_limit: Float[Array, ""] = array_field(default=127.0 / 120.0)
    motor_time_constant: Float[Array, 2] = array_field(default=(0.06, 0.09))
    delay_samples: Array = int_field(default=1)
    read_delay_samples: Array = int_field(default=1)
    wheel_scale: Float[Array, 2] = array_field(default=(0.9985, 1.0015))
    wheel_base_scale: Float[Array, ""] = array_field(default=1.02)
    slip_std: Float[Array, ""] = array_field(default=0.02)
    noise_position: Float[Array, ""] = array_field(default=0.0002)
    noise_heading: Float[Array, ""] = array_field(default=0.2 * 3.141592653589793 / 180)
    motor_dynamics: Array = bool_field(default=True)
    delay: Array = bool_field(default=True)
    quantization: Array = bool_field(default=True)
    saturation: Array = bool_field(default=True)
    encoders: Array = bool_field(default=True)
    mismatch: Array = bool_field(default=True)
    slip: Array = bool_field(default=False)
    noise: Array = bool_field(default=False)

    def __check_init__(self):
        owner = "KheperaPlant"
        for name in ("sample_time", "wheel_base", "pulses_per_meter", "speed_unit",
                     "speed_limit", "motor_time_constant", "wheel_scale", "wheel_base_scale"):
            check_positive(owner, name, getattr(self, name))
        for name in ("motor_time_constant", "wheel_scale"):  # (left, right), or one for both
            shape = jnp.shape(getattr(self, name))
            if shape and shape[-1] != 2:
                raise ValueError(f"KheperaPlant.{name} must be one value or a (left, right) "
                                 f"pair, got shape {shape}")
        for name in ("delay_samples", "read_delay_samples"):
            value = getattr(self, name)
            check_range(owner, name, value, lower=0, upper=MAX_DELAY)
            if is_concrete(value) and not jnp.issubdtype(jnp.asarray(value).dtype,
                                                         jnp.integer):
                raise ValueError(f"KheperaPlant.{name} must be an integer in [0, "
                                 f"{MAX_DELAY}], got {value}")
        for name in ("slip_std", "noise_position", "noise_heading"):
            check_nonnegative(owner, name, getattr(self, name))


def realistic_plant(**changes) -> KheperaPlant:
    """The Khepera as the report's host sees it: every effect on but `slip` and `noise`
    (fields can be overridden, e.g. `noise=True` for white noise on the odometry, or
    `encoders=False, noise=True` for an external tracker of the true pose)."""
    return KheperaPlant(**changes)


def ideal_plant(**changes) -> KheperaPlant:
    """The plant with every effect off: ZOH at 50 Hz on the exact unicycle."""
    off = dict(motor_dynamics=False, delay=False, quantization=False, saturation=False,
               encoders=False, mismatch=False, slip=False, noise=False)
    off.update(changes)
    return KheperaPlant(**off)


class RobotRun(eqx.Module):
    """One closed-loop run: samples at the control rate (`ts`, true `pose`, `measured` pose,
    `command` (v, omega)), the true `final_pose`, and the scoring statistics of the true
    pose (`stats`, what an observer of the robot sees) and of the robot's odometry
    (`odometry_stats`, what the host logs: the pose of the report's Figs. 4-5), and the
    `result` (`RESULTS.successful`, or `RESULTS.nonfinite` where the run left the numbers)."""

    ts: Float[Array, " n"] | None
    pose: Float[Array, "n 3"] | None
    measured: Float[Array, "n 3"] | None
    command: Float[Array, "n 2"] | None
    final_pose: Float[Array, 3]
    stats: RunStats
    odometry_stats: RunStats
    result: RESULTS


class _Pose(eqx.Module):
    """A pose (x, y, gamma) kept by component: batched, three arrays of runs, each computed
    once per sample (a stacked pose is computed component by component, each recomputing
    the sub-steps' shared terms; docs/performance.md)."""

    x: Float[Array, ""]
    y: Float[Array, ""]
    gamma: Float[Array, ""]

    @classmethod
    def of(cls, pose: Float[Array, "*batch 3"]) -> _Pose:
        return cls(pose[..., 0], pose[..., 1], pose[..., 2])

    def stacked(self) -> Float[Array, "*batch 3"]:
        return jnp.stack([self.x, self.y, self.gamma], axis=-1)


class _PlantState(eqx.Module):
    pose: _Pose                      # true pose
    wheels: Float[Array, 2]          # pulse rates of the wheels, in nominal m/s
    commands: Float[Array, "n 2"]    # delay line of wheel-speed commands
    travel: Float[Array, 2]          # nominal wheel travel (pulses / p, unquantised)
    odometry: Float[Array, 3]        # the robot's dead-reckoned pose
    readings: Float[Array, "n 3"]    # delay line of the pose the link reports
    stats: RunStats                  # of the true pose
    odometry_stats: RunStats         # of the odometry's pose (its commands': in `stats`)


def _initial_state(pose0, t_final) -> _PlantState:
    dtype = pose0.dtype
    return _PlantState(_Pose.of(pose0), jnp.zeros(2, dtype),
                       jnp.zeros((MAX_DELAY + 1, 2), dtype), jnp.zeros(2, dtype),
                       pose0, jnp.tile(pose0, (MAX_DELAY + 1, 1)),
                       RunStats.init(t_final), RunStats.init(t_final))


def _disturbances(plant: KheperaPlant, key, k, dtype):
    """Random inputs of sample k of the run with key `key`: standard normal numbers drawn
    from `fold_in(key, k)`, scaled to the pose noise (3) and the wheel slips (2), zero
    where switched off. One draw of five numbers, the pose noise first; with the slip off
    only the first three are drawn (the same numbers: JAX's partitionable threefry draws
    each element from its own counter), with both off none."""
    sigma = jnp.stack([plant.noise_position, plant.noise_position, plant.noise_heading,
                       plant.slip_std, plant.slip_std])
    on = jnp.stack([plant.noise, plant.noise, plant.noise, plant.slip, plant.slip])

    def draw(n):
        normal = jax.random.normal(jax.random.fold_in(key, k), (n,), dtype)
        scaled = jnp.where(on[:n], normal * sigma[:n], 0.0)
        return jnp.concatenate([scaled, jnp.zeros(5 - n, dtype)])

    n_noise = 3 if jax.config.jax_threefry_partitionable else 5
    which = jnp.where(plant.slip, 2, jnp.where(plant.noise, 1, 0))
    return jax.lax.switch(which, [lambda: jnp.zeros(5, dtype), lambda: draw(n_noise),
                                  lambda: draw(5)])


def _measure(plant: KheperaPlant, state: _PlantState, k, disturbance):
    """The pose the controller sees at sample k: the link's reading plus the noise, and the
    state with the pose sensed at sample k entered into the link's delay line."""
    sensed = jnp.where(plant.encoders, state.odometry, state.pose.stacked())
    readings = delay_line_write(state.readings, k, sensed)
    delay = jnp.where(plant.delay, plant.read_delay_samples, 0)
    measured = delay_line_read(readings, k, delay) + disturbance[:3]
    return eqx.tree_at(lambda s: s.readings, state, readings), measured


def _wheel_command(plant: KheperaPlant, command):
    """Wheel speeds of (v, omega), quantised to the speed unit and saturated."""
    wheel_cmd = wheel_speeds(command[0], command[1], plant.wheel_base)
    quantum = plant.speed_unit
    wheel_cmd = jnp.where(plant.quantization, jnp.round(wheel_cmd / quantum) * quantum,
                          wheel_cmd)
    return jnp.where(plant.saturation,
                     jnp.clip(wheel_cmd, -plant.speed_limit, plant.speed_limit), wheel_cmd)


def _move(plant: KheperaPlant, substeps: int, pose, wheels, travel, applied, slip):
    """`substeps` sub-steps of the motor lags and of the true motion (module docstring)."""
    h = plant.sample_time / substeps
    lag = jnp.where(plant.motor_dynamics, -jnp.expm1(-h / plant.motor_time_constant), 1.0)
    ground = jnp.where(plant.mismatch, plant.wheel_scale, 1.0) * (1.0 - slip)
    base = plant.wheel_base * jnp.where(plant.mismatch, plant.wheel_base_scale, 1.0)
    for _ in range(substeps):  # unrolled: a few sub-steps, no loop
        wheels = wheels + lag * (applied - wheels)
        vv, ww = body_velocity(wheels * ground, base)
        pose = unicycle_step(pose, vv, ww, h)
        travel = travel + wheels * h
    return pose, wheels, travel


def _advance(plant: KheperaPlant, substeps: int, save: bool, state: _PlantState, k,
             measured, command, disturbance):
    """Apply the command (v, omega) issued at sample k and move the plant one sample."""
    delay = jnp.where(plant.delay, plant.delay_samples, 0)
    # the command of sample k enters the delay line; the motors get that of sample k - delay
    # (zero before the first command arrives)
    commands = delay_line_write(state.commands, k, _wheel_command(plant, command))
    applied = delay_line_read(commands, k, delay)
    pose, wheels, travel = _move(plant, substeps, state.pose.stacked(), state.wheels,
                                 state.travel, applied, disturbance[3:])
    ppm = plant.pulses_per_meter
    d = (encoder_counts(travel, ppm, plant.encoders)
         - encoder_counts(state.travel, ppm, plant.encoders)) / ppm
    odometry = dead_reckon(state.odometry, d[0], d[1], plant.wheel_base)
    t = k * plant.sample_time
    stats = state.stats.update(t, state.pose.stacked(), command)
    # the odometry is scored under the same commands, whose statistics are those of `stats`:
    # its own are left as they were (not computed) and `_as_run` puts those of `stats` in
    odometry_stats = (state.odometry_stats.update(t, state.odometry, command)
                      .with_command_statistics(state.odometry_stats))
    out = (t, state.pose.stacked(), measured, command) if save else None
    return _PlantState(_Pose.of(pose), wheels, commands, travel, odometry,
                       state.readings, stats, odometry_stats), out


def _step(velocity_fn, plant: KheperaPlant, substeps: int, save: bool, key, state, k):
    """One control sample of the closed loop (see the module docstring)."""
    disturbance = _disturbances(plant, key, k, state.pose.x.dtype)
    state, measured = _measure(plant, state, k, disturbance)
    v, omega = velocity_fn(k * plant.sample_time, measured)
    return _advance(plant, substeps, save, state, k, measured, jnp.stack([v, omega]),
                    disturbance)


def _result(finite) -> RESULTS:
    """`RESULTS.successful` where `finite`, else `RESULTS.nonfinite` (any batch shape)."""
    def where(ok):
        return RESULTS.where(ok, RESULTS.successful, RESULTS.nonfinite)

    for _ in range(jnp.ndim(finite)):
        where = jax.vmap(where)
    return where(finite)


def _as_run(state: _PlantState, out, save) -> RobotRun:
    odometry_stats = state.odometry_stats.with_command_statistics(state.stats)
    final = state.pose.stacked()
    # the statistics saw every sample's poses and commands but the final pose
    result = _result(state.stats.finite & odometry_stats.finite
                     & jnp.all(jnp.isfinite(final), axis=-1))
    if save:
        ts, pose, measured, command = out
        return RobotRun(ts, pose, measured, command, final, state.stats, odometry_stats,
                        result)
    return RobotRun(None, None, None, None, final, state.stats, odometry_stats, result)


def _closed_loop(velocity_fn, pose0, key, plant: KheperaPlant, n_steps: int, substeps: int,
                 save: bool) -> RobotRun:
    pose0 = jnp.asarray(pose0, dtype=float)
    state0 = _initial_state(pose0, n_steps * plant.sample_time)
    step = ft.partial(_step, velocity_fn, plant, substeps, save, key)
    state, out = jax.lax.scan(step, state0, jnp.arange(n_steps))
    return _as_run(state, out, save)


@eqx.filter_jit
def _simulate(controller, system, pose0, key, plant, n_steps, substeps, save):
    fn = ft.partial(_velocity, controller, system)
    return _closed_loop(fn, pose0, key, plant, n_steps, substeps, save)


def _velocity(controller, system, t, pose):
    return controller.velocity(t, pose, system)


def simulate_robot(controller: AbstractController, system: AbstractSystem, pose0,
             key: PRNGKeyArray | None = None, plant: KheperaPlant | None = None,
             duration: float = 40.0, substeps: int = 4, save: bool = True) -> RobotRun:
    """Closed loop of one controller on the Khepera plant from `pose0` = (x, y, gamma).

    **Arguments:** `controller`, `system` (System I or II; ignored by controller 4), `pose0`
    [m, m, rad], `key` (sensor noise and wheel slip; default PRNGKey(0)), `plant` (default: realistic),
    `duration` [s] (rounded to whole samples), `substeps` per sample for the motor lag,
    `save` (keep the sampled trajectory).
    **Returns:** a `RobotRun`.
    """
    plant = realistic_plant() if plant is None else plant
    key = jax.random.PRNGKey(0) if key is None else key
    n_steps = sample_count("simulate_robot", duration, plant.sample_time, substeps)
    check_poses("simulate_robot", "pose0", pose0, (3,))
    return _simulate(controller, system, jnp.asarray(pose0, dtype=float), key, plant,
                     n_steps, int(substeps), bool(save))


def _block_size(n_steps: int, largest: int = 50) -> int:
    """The largest divisor of `n_steps` not above `largest`."""
    return max(b for b in range(1, min(largest, n_steps) + 1) if n_steps % b == 0)


@eqx.filter_jit
def _grid(controllers, systems, poses, keys, plant, n_steps, substeps, save, progress=False):
    # One scan over time, in blocks of B samples. Per block: the random disturbances (noise,
    # slip) of the P initial poses for all B samples, drawn at once (each (controller,
    # system) group reuses the same P sequences, so they are drawn once, not G times). Per
    # sample (`grid_sample`): measure all G x P runs, evaluate each group's law on its own
    # P runs, then advance the shared plant on all runs.
    G = len(controllers) * len(systems)
    t_final = n_steps * plant.sample_time
    carry0 = jax.vmap(lambda p: _initial_state(p, t_final))(tile_groups(poses, G))
    B = _block_size(n_steps)

    def step(carry, xs):
        k, disturbance = xs
        disturbance = tile_groups(disturbance, G)
        t = k * plant.sample_time  # the same for every run: each law takes it unbatched
        laws = [ft.partial(_law, c, s, t) for c in controllers for s in systems]

        def sense(carry):
            carry, measured = jax.vmap(lambda c, d: _measure(plant, c, k, d))(carry,
                                                                            disturbance)
            return carry, measured, measured

        def act(carry, measured, command):
            return jax.vmap(lambda c, m, u, d: _advance(plant, substeps, save, c, k, m, u, d))(
                carry, measured, command, disturbance)

        (carry, _), out = grid_sample(sense, laws, act, carry, (None,) * G)
        return carry, out

    def block(carry, ks):
        disturbance = jax.vmap(lambda k: jax.vmap(
            lambda key: _disturbances(plant, key, k, poses.dtype))(keys))(ks)
        carry, out = jax.lax.scan(step, carry, (ks, disturbance))
        return (advance(B, carry) if progress else carry), out

    carry, out = jax.lax.scan(block, carry0, jnp.arange(n_steps).reshape(-1, B))
    if save:  # scan stacks time first: (n / B, B, G P, ...) -> (G P, n, ...)
        out = jax.tree_util.tree_map(
            lambda a: jnp.swapaxes(a.reshape((n_steps,) + a.shape[2:]), 0, 1), out)
    return split_groups(_as_run(carry, out, save), G)


def _law(controller, system, t, state, pose):
    """A robot controller as a law of the controller grid: no state, (v, omega) of the
    measured pose at time t."""
    return state, jnp.stack(controller.velocity(t, pose, system))


def simulate_robot_grid(controllers: Sequence[AbstractController],
                        systems: Sequence[AbstractSystem], poses0, keys,
                        plant: KheperaPlant | None = None, duration: float = 40.0,
                        substeps: int = 4, save: bool = False, devices=None,
                        progress: bool | None = None) -> RobotRun:
    r"""Every controller x system x initial pose (with its noise key), in one jitted call.

    **Arguments:** `controllers` (C of them), `systems` (S), `poses0` of shape (P, 3) and
    `keys` of shape (P, 2) (one key per initial pose for its noise and slip, e.g. missions x
    seeds flattened), `plant`, `duration`, `substeps`, `save` (keep trajectories: memory grows as
    C x S x P x samples, so only for small grids).
    **Returns:** a `RobotRun` whose fields have leading axes (C, S, P); score its `stats`
    with `vehsim.robot.scoring.score_run` under `jax.vmap`.

    `devices`: shard the initial poses across these JAX devices (a one-dimensional mesh,
    `jax.shard_map`; poses padded to a multiple of the device count, padding dropped), as
    `vehsim.sweep` does. Default: no sharding (the default device). On a CPU host, forcing
    host devices (`XLA_FLAGS=--xla_force_host_platform_device_count=2`) and passing
    `jax.devices()` runs one shard per core, usually faster than one device's threads
    (results equal to rounding; docs/performance.md).

    `progress`: show the control samples simulated on stderr, per block of samples
    (`vehsim.progress`; default off, on in the command line).
    """
    plant = realistic_plant() if plant is None else plant
    poses0 = jnp.asarray(poses0, dtype=float)
    keys = jnp.asarray(keys)
    C, S = len(controllers), len(systems)
    n_steps = sample_count("simulate_robot_grid", duration, plant.sample_time, substeps)
    check_poses("simulate_robot_grid", "poses0", poses0, (-1, 3))
    if not controllers or not systems:
        raise ValueError("simulate_robot_grid needs at least one controller and one system, "
                         f"got {len(controllers)} and {len(systems)}")
    static = (tuple(controllers), tuple(systems))
    progress = resolve(progress)
    shards = 1 if devices is None else max(1, len(devices))
    with progress_bar("robot grid", n_steps * shards, "samples", enabled=progress):
        if shards == 1:
            run = _grid(*static, poses0, keys, plant, n_steps, int(substeps), bool(save),
                        progress)
        else:
            n = poses0.shape[0]
            poses0, keys = pad_members((poses0, keys), len(devices))
            run = _sharded_grid(*static, poses0, keys, plant, n_steps, int(substeps),
                                bool(save), tuple(devices), progress)
            run = jax.tree_util.tree_map(lambda a: a[:, :n], run)
        run = jax.block_until_ready(run)
    return jax.tree_util.tree_map(lambda a: a.reshape((C, S) + a.shape[1:]), run)


@eqx.filter_jit
def _sharded_grid(controllers, systems, poses, keys, plant, n_steps, substeps, save, devices,
                  progress=False):
    def shard(p, k, plant):
        return _grid(controllers, systems, p, k, plant, n_steps, substeps, save, progress)

    # `_grid` returns (groups, runs, ...): the runs, which are split, are the second axis
    return shard_members(shard, devices, in_axes=(0, 0, None), out_axis=1)(poses, keys, plant)
