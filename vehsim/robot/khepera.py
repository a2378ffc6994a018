r"""A realistic Khepera plant and the closed-loop simulation at the 50 Hz control rate.

Each control sample (period $T = 1/50$ s, zero-order hold):

1. *measure*: the pose is read from encoder odometry (wheel travel quantised to
   12 pulses/mm, dead reckoning with the midpoint heading) plus Gaussian sensor noise;
2. *control*: the controller maps $(t, \hat p)$ to $(v, \omega)$, turned into wheel
   speeds $v_{L,R} = v \mp \omega b/2$;
3. *command*: quantised to the Khepera speed unit (one pulse per 10 ms, 8.33 mm/s) and
   saturated at 127 units (1.06 m/s), then sent through a transport delay of $d$ samples;
4. *plant*: over `substeps` sub-steps each wheel follows its command through its own
   first-order motor lag $\tau_{L,R}$ (the on-board PID loop), and the pose moves along
   the exact unicycle arc of the wheel speeds.

Every effect has a switch (boolean array field), and `ideal_plant()` turns all off (the
ZOH remains: it is the control rate). Values not in the report are marked **unverified**
(docs/parameters.md): wheel base 53 mm, speed unit, saturation; the motor time
constants, delay and noise levels are modelling choices.

`simulate_robot` runs one closed loop; `simulate_robot_grid` runs controllers x systems x
initial poses x seeds in one jitted call: one `lax.scan` over time whose body evaluates each
(controller, system) group's law vmapped over its runs (all gains in one PyTree) and
advances the shared plant vmapped over all runs, keeping only the scoring statistics. The
sensor noise depends only on the run's key and the sample index, so it is drawn once per
initial pose (not per group) for blocks of 50 samples at a time; the result is identical to
`simulate_robot` run by run.
"""

from __future__ import annotations

import functools as ft
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from .._checks import check_nonnegative, check_positive, check_range, is_concrete
from .._fields import array_field, bool_field, int_field
from ..progress import advance, progress_bar, resolve
from ..sharding import pad_members, shard_members
from .controllers import AbstractController
from .scoring import RunStats
from .unicycle import AbstractSystem, body_velocity, unicycle_step, wheel_speeds


MAX_DELAY = 8
"""Length of the command delay buffer (largest allowed `delay_samples`)."""


class KheperaPlant(eqx.Module):
    r"""Khepera robot seen through its serial link (report 2.1).

    **Fields** (SI units):

    - `sample_time` [s]: control period, 0.02 (50 Hz, report).
    - `wheel_base` [m]: 0.053 (**unverified**, docs/parameters.md).
    - `pulses_per_meter` [1/m]: encoder resolution, 12 000 (12 pulses/mm, report).
    - `speed_unit` [m/s]: speed-command quantum, one pulse per 10 ms = 1/120 m/s
      (**unverified**, docs/parameters.md).
    - `speed_limit` [m/s]: wheel-speed saturation, 127 units = 1.058 m/s (**unverified**).
    - `motor_time_constant` [s]: first-order lag of the (left, right) wheel, (0.06, 0.09):
      different on purpose, as the report says the two motors differ.
    - `delay_samples` [-]: transport delay of the commands in samples (integer, 0..8), 2.
    - `noise_position` [m], `noise_heading` [rad]: standard deviations of the sensor noise
      added to the measured pose, 0.2 mm and 0.2 deg.
    - switches `motor_dynamics`, `delay`, `quantization` (speed commands), `saturation`,
      `encoders` (odometry from quantised encoder counts; off = the true pose is measured),
      `noise`: booleans.
    """

    sample_time: Float[Array, ""] = array_field(default=0.02)
    wheel_base: Float[Array, ""] = array_field(default=0.053)
    pulses_per_meter: Float[Array, ""] = array_field(default=12_000.0)
    speed_unit: Float[Array, ""] = array_field(default=1.0 / 120.0)
    speed_limit: Float[Array, ""] = array_field(default=127.0 / 120.0)
    motor_time_constant: Float[Array, 2] = array_field(default=(0.06, 0.09))
    delay_samples: Array = int_field(default=2)
    noise_position: Float[Array, ""] = array_field(default=0.0002)
    noise_heading: Float[Array, ""] = array_field(default=0.2 * 3.141592653589793 / 180)
    motor_dynamics: Array = bool_field(default=True)
    delay: Array = bool_field(default=True)
    quantization: Array = bool_field(default=True)
    saturation: Array = bool_field(default=True)
    encoders: Array = bool_field(default=True)
    noise: Array = bool_field(default=True)

    def __check_init__(self):
        owner = "KheperaPlant"
        for name in ("sample_time", "wheel_base", "pulses_per_meter", "speed_unit",
                     "speed_limit", "motor_time_constant"):
            check_positive(owner, name, getattr(self, name))
        check_range(owner, "delay_samples", self.delay_samples, lower=0, upper=MAX_DELAY)
        if is_concrete(self.delay_samples) and not jnp.issubdtype(
                jnp.asarray(self.delay_samples).dtype, jnp.integer):
            raise ValueError(f"KheperaPlant.delay_samples must be an integer in [0, "
                             f"{MAX_DELAY}], got {self.delay_samples}")
        check_nonnegative(owner, "noise_position", self.noise_position)
        check_nonnegative(owner, "noise_heading", self.noise_heading)


def realistic_plant(**changes) -> KheperaPlant:
    """The Khepera plant with every effect on (fields can be overridden)."""
    return KheperaPlant(**changes)


def ideal_plant(**changes) -> KheperaPlant:
    """The plant with every effect off: ZOH at 50 Hz on the exact unicycle."""
    off = dict(motor_dynamics=False, delay=False, quantization=False, saturation=False,
               encoders=False, noise=False)
    off.update(changes)
    return KheperaPlant(**off)


class RobotRun(eqx.Module):
    """One closed-loop run: samples at the control rate (`ts`, true `pose`, `measured` pose,
    `command` (v, omega)), the true `final_pose`, and the scoring statistics `stats`."""

    ts: Float[Array, " n"] | None
    pose: Float[Array, "n 3"] | None
    measured: Float[Array, "n 3"] | None
    command: Float[Array, "n 2"] | None
    final_pose: Float[Array, 3]
    stats: RunStats


def _initial_carry(pose0, t_final):
    dtype = pose0.dtype
    return (pose0, jnp.zeros(2, dtype), jnp.zeros((MAX_DELAY + 1, 2), dtype),
            jnp.zeros(2, dtype), pose0, RunStats.init(t_final))


def _noise(plant: KheperaPlant, key, k, dtype):
    """Sensor noise of sample k of the run with noise key `key` (zero when switched off)."""
    sigma = jnp.stack([plant.noise_position, plant.noise_position, plant.noise_heading])
    noise = jax.random.normal(jax.random.fold_in(key, k), (3,), dtype) * sigma
    return jnp.where(plant.noise, noise, jnp.zeros_like(noise))


def _measure(plant: KheperaPlant, carry, noise):
    """The pose the controller sees: odometry (or truth) plus the sensor `noise`."""
    pose, odometry = carry[0], carry[4]
    return jnp.where(plant.encoders, odometry, pose) + noise


def _advance(plant: KheperaPlant, substeps: int, save: bool, carry, k, measured, command):
    """Apply the command (v, omega) issued at sample k and move the plant one sample."""
    pose, wheels, buffer, travel, odometry, stats = carry
    T = plant.sample_time
    h = T / substeps
    b = plant.wheel_base
    lag = jnp.where(plant.motor_dynamics, -jnp.expm1(-h / plant.motor_time_constant), 1.0)
    delay = jnp.where(plant.delay, plant.delay_samples, 0)

    def count(travel):
        c = travel * plant.pulses_per_meter
        return jnp.where(plant.encoders, jnp.floor(c), c)

    t = k * T
    wheel_cmd = wheel_speeds(command[0], command[1], b)
    quantum = plant.speed_unit
    wheel_cmd = jnp.where(plant.quantization, jnp.round(wheel_cmd / quantum) * quantum,
                          wheel_cmd)
    wheel_cmd = jnp.where(plant.saturation,
                          jnp.clip(wheel_cmd, -plant.speed_limit, plant.speed_limit),
                          wheel_cmd)
    # Ring buffer: sample k writes slot k mod (MAX_DELAY + 1) and applies the command of
    # sample k - delay (zero before the first command arrives).
    n_slots = MAX_DELAY + 1
    buffer = jax.lax.dynamic_update_index_in_dim(buffer, wheel_cmd, k % n_slots, 0)
    applied = jax.lax.dynamic_index_in_dim(buffer, (k - delay) % n_slots, 0, keepdims=False)
    counts_before = count(travel)

    def sub(_, state):
        pose, wheels, travel = state
        wheels = wheels + lag * (applied - wheels)
        vv, ww = body_velocity(wheels, b)
        return unicycle_step(pose, vv, ww, h), wheels, travel + wheels * h

    state = (pose, wheels, travel)
    for i in range(substeps):  # unrolled: a few sub-steps, fused into one kernel
        state = sub(i, state)
    new_pose, wheels, travel = state
    d = (count(travel) - counts_before) / plant.pulses_per_meter
    ds, dg = 0.5 * (d[0] + d[1]), (d[1] - d[0]) / b
    mid = odometry[2] + 0.5 * dg
    odometry = odometry + jnp.stack([ds * jnp.cos(mid), ds * jnp.sin(mid), dg])
    stats = stats.update(t, pose, command)
    out = (t, pose, measured, command) if save else None
    return (new_pose, wheels, buffer, travel, odometry, stats), out


def _step(velocity_fn, plant: KheperaPlant, substeps: int, save: bool, key, carry, k):
    """One control sample of the closed loop (see the module docstring)."""
    measured = _measure(plant, carry, _noise(plant, key, k, carry[0].dtype))
    v, omega = velocity_fn(k * plant.sample_time, measured)
    return _advance(plant, substeps, save, carry, k, measured, jnp.stack([v, omega]))


def _as_run(carry, out, save) -> RobotRun:
    final_pose, stats = carry[0], carry[5]
    if save:
        ts, pose, measured, command = out
        return RobotRun(ts, pose, measured, command, final_pose, stats)
    return RobotRun(None, None, None, None, final_pose, stats)


def _closed_loop(velocity_fn, pose0, key, plant: KheperaPlant, n_steps: int, substeps: int,
                 save: bool) -> RobotRun:
    pose0 = jnp.asarray(pose0, dtype=float)
    carry0 = _initial_carry(pose0, n_steps * plant.sample_time)
    step = ft.partial(_step, velocity_fn, plant, substeps, save, key)
    carry, out = jax.lax.scan(step, carry0, jnp.arange(n_steps))
    return _as_run(carry, out, save)


@eqx.filter_jit
def _simulate(controller, system, pose0, key, plant, n_steps, substeps, save):
    fn = ft.partial(_velocity, controller, system)
    return _closed_loop(fn, pose0, key, plant, n_steps, substeps, save)


def _velocity(controller, system, t, pose):
    return controller.velocity(t, pose, system)


def simulate_robot(controller: AbstractController, system: AbstractSystem, pose0,
             key: PRNGKeyArray | None = None, plant: KheperaPlant | None = None,
             t_final: float = 40.0, substeps: int = 4, save: bool = True) -> RobotRun:
    """Closed loop of one controller on the Khepera plant from `pose0` = (x, y, gamma).

    **Arguments:** `controller`, `system` (System I or II; ignored by controller 4), `pose0`
    [m, m, rad], `key` (sensor noise; default PRNGKey(0)), `plant` (default: realistic),
    `t_final` [s] (rounded to whole samples), `substeps` per sample for the motor lag,
    `save` (keep the sampled trajectory).
    **Returns:** a `RobotRun`.
    """
    plant = realistic_plant() if plant is None else plant
    key = jax.random.PRNGKey(0) if key is None else key
    n_steps = int(round(t_final / float(plant.sample_time)))
    return _simulate(controller, system, jnp.asarray(pose0, dtype=float), key, plant,
                     n_steps, int(substeps), bool(save))


def _block_size(n_steps: int, largest: int = 50) -> int:
    """The largest divisor of `n_steps` not above `largest`."""
    return max(b for b in range(1, min(largest, n_steps) + 1) if n_steps % b == 0)


@eqx.filter_jit
def _grid(controllers, systems, poses, keys, plant, n_steps, substeps, save, progress=False):
    # One scan over time, in blocks of B samples. Per block: the sensor noise of the P
    # initial poses for all B samples, drawn at once (each (controller, system) group
    # reuses the same P noise sequences, so they are drawn once, not G times). Per sample:
    # measure all G x P runs, evaluate each group's law on its own P runs, then advance the
    # shared plant on all runs (vmapped). A lax.switch on a batched controller index would
    # make XLA evaluate every law for every run; grouping computes each law only where used.
    fns = [ft.partial(_velocity, c, s) for c in controllers for s in systems]
    G, P = len(fns), poses.shape[0]
    t_final = n_steps * plant.sample_time
    all_poses = jnp.tile(poses, (G, 1))
    carry0 = jax.vmap(lambda p: _initial_carry(p, t_final))(all_poses)
    B = _block_size(n_steps)

    def step(carry, xs):
        k, noise = xs
        measured = jax.vmap(ft.partial(_measure, plant))(carry, jnp.tile(noise, (G, 1)))
        t = k * plant.sample_time
        commands = [jax.vmap(lambda m: jnp.stack(fn(t, m)))(measured[g * P:(g + 1) * P])
                    for g, fn in enumerate(fns)]
        command = jnp.concatenate(commands)
        return jax.vmap(lambda c, m, u: _advance(plant, substeps, save, c, k, m, u))(
            carry, measured, command)

    def block(carry, ks):
        noise = jax.vmap(lambda k: jax.vmap(lambda key: _noise(plant, key, k, poses.dtype))(
            keys))(ks)
        carry, out = jax.lax.scan(step, carry, (ks, noise))
        return (advance(B, carry) if progress else carry), out

    carry, out = jax.lax.scan(block, carry0, jnp.arange(n_steps).reshape(-1, B))
    if save:  # scan stacks time first: (n / B, B, G P, ...) -> (G P, n, ...)
        out = jax.tree_util.tree_map(
            lambda a: jnp.swapaxes(a.reshape((n_steps,) + a.shape[2:]), 0, 1), out)
    run = _as_run(carry, out, save)
    return jax.tree_util.tree_map(lambda a: a.reshape((G, P) + a.shape[1:]), run)


def simulate_robot_grid(controllers: Sequence[AbstractController],
                  systems: Sequence[AbstractSystem], poses0, keys,
                  plant: KheperaPlant | None = None, t_final: float = 40.0,
                  substeps: int = 4, save: bool = False, devices=None,
                  progress: bool | None = None) -> RobotRun:
    r"""Every controller x system x initial pose (with its noise key), in one jitted call.

    **Arguments:** `controllers` (C of them), `systems` (S), `poses0` of shape (P, 3) and
    `keys` of shape (P, 2) (one noise key per initial pose, e.g. missions x seeds
    flattened), `plant`, `t_final`, `substeps`, `save` (keep trajectories: memory grows as
    C x S x P x samples, so only for small grids).
    **Returns:** a `RobotRun` whose fields have leading axes (C, S, P); score its `stats`
    with `vehsim.robot.scoring.score_run` under `jax.vmap`.

    `devices`: shard the initial poses across these JAX devices (a one-dimensional mesh,
    `jax.shard_map`; poses padded to a multiple of the device count, padding dropped), as
    `vehsim.sweep` does. Default: no sharding (the default device). On a CPU host, forcing
    host devices (`XLA_FLAGS=--xla_force_host_platform_device_count=2`) and passing
    `jax.devices()` runs one shard per core, usually faster than XLA's intra-op threading
    (results equal to rounding: operations fuse differently; docs/performance.md).

    `progress`: show the control samples simulated on stderr, per block of samples
    (`vehsim.progress`; default off, on in the command line).
    """
    plant = realistic_plant() if plant is None else plant
    poses0 = jnp.asarray(poses0, dtype=float)
    keys = jnp.asarray(keys)
    C, S = len(controllers), len(systems)
    n_steps = int(round(t_final / float(plant.sample_time)))
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
