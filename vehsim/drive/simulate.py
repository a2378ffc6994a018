r"""The sampled-data drive: any controller, an optional grip estimator, the plant.

Per sample $k$: the controller reads the measurement of sample $k$ (and the estimator's
belief, if there is an estimator) and issues a command; `drive_step` applies it over the
sample and returns the measurement of sample $k + 1$, which the estimator then takes in.
The loop is one `jax.lax.scan`; a Monte Carlo of drives is a `vmap` of `simulate_drive`
over keys (and, if wanted, plants or initial states).
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PyTree

from .._checks import check_positive
from .._fields import array_field
from .plant import DrivePlant, DriveState, drive_step, measure_drive
from .sensors import DriveMeasurement


class AbstractDriveController(eqx.Module):
    """A controller of the drive: `init` from the first measurement, then `command` per
    sample. `estimate` is the grip estimator's `GripEstimate` (None without one)."""

    @abc.abstractmethod
    def init(self, measurement: DriveMeasurement) -> PyTree:
        """The controller's state before the first sample."""

    @abc.abstractmethod
    def command(self, state: PyTree, measurement: DriveMeasurement, estimate
                ) -> tuple[PyTree, Float[Array, " 3"]]:
        r"""``(state, command)``: the command $(T_F, T_R, \delta)$ [N m, N m, rad]."""


def _arc_point(curvature, s):
    r"""The point at arc length `s` on the path from the origin heading along $x$ with
    constant `curvature` (a circle to the left for > 0, the $x$ axis for 0)."""
    small = jnp.abs(curvature * s) < 1e-6
    ks = jnp.where(small, 1.0, curvature * s)
    sinc = jnp.where(small, 1.0 - (curvature * s) ** 2 / 6.0, jnp.sin(ks) / ks)
    cosc = jnp.where(small, curvature * s / 2.0, (1.0 - jnp.cos(ks)) / ks)
    return s * sinc, s * cosc


class PathFollower(AbstractDriveController):
    r"""A test driver: pure pursuit on a path of constant curvature, and a torque schedule.

    The path starts at the origin heading along $x$, with curvature $\kappa$ (`curvature`
    [1/m]; 0: the $x$ axis). The steering is pure pursuit (Coulter 1992): with the
    look-ahead point $p$ at arc length $s_0 + L_d$ past the measured position's nearest
    path point, $\alpha$ its bearing from the heading, $\delta = \arctan(2\ell\sin\alpha
    /L_d)$ ($\ell$ the wheelbase), plus a slalom term $A\sin(2\pi ft)$. The axle torques
    are `torque` plus `pulse_torque` during the first `pulse_width` seconds of every
    `pulse_period` (braking or driving pulses, to excite the tires).

    **Fields:** `wheelbase` [m] (2.7), `curvature` [1/m] (0), `lookahead` $L_d$ [m] (10),
    `torque` [N m] (2,) (0, 0), `pulse_torque` [N m] (2,) (0, 0), `pulse_period` [s] (1),
    `pulse_width` [s] (0), `slalom_amplitude` $A$ [rad] (0), `slalom_frequency` $f$ [Hz]
    (0.5).
    """

    wheelbase: Float[Array, ""] = array_field(default=2.7)
    curvature: Float[Array, ""] = array_field(default=0.0)
    lookahead: Float[Array, ""] = array_field(default=10.0)
    torque: Float[Array, " 2"] = array_field(default=(0.0, 0.0))
    pulse_torque: Float[Array, " 2"] = array_field(default=(0.0, 0.0))
    pulse_period: Float[Array, ""] = array_field(default=1.0)
    pulse_width: Float[Array, ""] = array_field(default=0.0)
    slalom_amplitude: Float[Array, ""] = array_field(default=0.0)
    slalom_frequency: Float[Array, ""] = array_field(default=0.5)

    def __check_init__(self):
        for name in ("wheelbase", "lookahead", "pulse_period"):
            check_positive("PathFollower", name, getattr(self, name))

    def init(self, measurement):
        return jnp.zeros(())

    def nearest_arc_length(self, x, y):
        """Arc length of the path point nearest to $(x, y)$ (on a circle: by its angle)."""
        k = self.curvature
        line = k == 0
        k_safe = jnp.where(line, 1.0, k)
        angle = jnp.arctan2(k_safe * x, 1.0 - k_safe * y)
        angle = jnp.where(angle < 0, angle + 2 * jnp.pi, angle)
        return jnp.where(line, x, angle / k_safe)

    def command(self, state, m: DriveMeasurement, estimate):
        s = self.nearest_arc_length(m.x, m.y) + self.lookahead
        px, py = _arc_point(self.curvature, s)
        alpha = jnp.arctan2(py - m.y, px - m.x) - m.psi
        delta = jnp.arctan(2.0 * self.wheelbase * jnp.sin(alpha) / self.lookahead)
        delta = delta + self.slalom_amplitude * jnp.sin(2 * jnp.pi * self.slalom_frequency * m.t)
        pulse = jnp.remainder(m.t, self.pulse_period) < self.pulse_width
        torque = self.torque + jnp.where(pulse, self.pulse_torque, 0.0)
        return state, jnp.concatenate([torque, delta[None]])


class CommandSchedule(AbstractDriveController):
    r"""Open loop: the command `commands[k]` $(T_F, T_R, \delta)$ at sample $k$ (the last
    row held after the table ends); the measurements are ignored. **Fields:** `commands`
    shape (N, 3)."""

    commands: Float[Array, "N 3"] = array_field()

    def __check_init__(self):
        if jnp.ndim(self.commands) != 2 or jnp.shape(self.commands)[-1] != 3:
            raise ValueError(f"CommandSchedule.commands must have shape (N, 3) (T_F, T_R, "
                             f"delta per sample), got {jnp.shape(self.commands)}")

    def init(self, measurement):
        return jnp.zeros((), int)

    def command(self, state, measurement, estimate):
        k = jnp.minimum(state, self.commands.shape[0] - 1)
        return state + 1, self.commands[k]


class DriveRun(eqx.Module):
    """A drive, sample by sample (leading axis: samples $1..N$): the plant `states`
    (`DriveState`), the `measurements`, the `commands` issued before each sample, the
    estimator's `estimates` (`GripEstimate`, None without an estimator); `final`: the plant
    state at the end; `controller_info`: the controller's `info(state)` after each command
    (None for a controller without `info`); `poses`: the centre of gravity's $(x, y)$ at
    every integration step (N, substeps, 2; None unless asked for,
    `simulate_drive(..., substep_poses=True)`)."""

    states: DriveState
    measurements: DriveMeasurement
    commands: Float[Array, "N 3"]
    estimates: PyTree
    final: DriveState
    controller_info: PyTree = None
    poses: PyTree = None


def simulate_drive(plant: DrivePlant, controller: AbstractDriveController, state0: DriveState,
                   key, num_samples: int, estimator=None, *,
                   substep_poses: bool = False) -> DriveRun:
    r"""`num_samples` control samples of `controller` driving `plant` from `state0`, the
    sensor noise of sample $k$ drawn from ``fold_in(key, k)`` (module docstring), $k$ the
    plant's own sample count (`DriveState.k`): a drive continued from `DriveRun.final`
    with the same key draws the noise the longer drive would have drawn.

    `estimator`: an `AbstractGripEstimator` run on the measurements; the controller gets
    its `estimate` before each command. A controller with an `info(state)` method has it
    recorded after each command (`DriveRun.controller_info`). `substep_poses`: also record
    the centre of gravity's pose at every integration step (`DriveRun.poses`,
    `drive_step`)."""
    m0 = measure_drive(plant, state0, jax.random.fold_in(key, state0.k))
    c0 = controller.init(m0)
    e0 = None if estimator is None else estimator.init(m0)
    info = getattr(controller, "info", None)

    def sample(carry, _):
        state, m, cs, es = carry
        estimate = None if estimator is None else estimator.estimate(es)
        cs, command = controller.command(cs, m, estimate)
        record = None if info is None else info(cs)
        state, m, *poses = drive_step(plant, state, command, jax.random.fold_in(key, state.k + 1),
                                      substep_poses=substep_poses)
        if estimator is not None:
            es = estimator.update(es, m)
            estimate = estimator.estimate(es)
        return (state, m, cs, es), (state, m, command, estimate, record,
                                    poses[0] if poses else None)

    (final, _, _, _), (states, ms, commands, estimates, infos, poses) = jax.lax.scan(
        sample, (state0, m0, c0, e0), jnp.arange(num_samples))
    return DriveRun(states, ms, commands, estimates, final, infos, poses)
