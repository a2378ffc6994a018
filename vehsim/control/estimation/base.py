r"""The interface of a friction estimator in the braking loop (`vehsim.control.loop`).

Per sample the loop hands the estimator the measured speeds (the wheel speed standing for
its time stamp, a measurement only if `fresh`), and the brake torque of the last sample; the
estimator's state carries a filtered vehicle speed `v` (the controllers' speed), and its
`belief` is the tire it currently believes in, whose steady-state curve the controllers read
their targets off. `signals` names what a saved run keeps of its state.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp

from ...tire.lugre import AbstractLongitudinalTire
from ...vehicle.quarter_car import QuarterCar
from ..plant.hardware import BrakeHardware
from ..plant.integrate import SUBSTEPS


class AbstractFrictionEstimator(eqx.Module):
    """An estimator of the road run beside the plant, sample by sample (module docstring).
    Its state has a field `v`: the filtered vehicle speed [m/s]."""

    @abc.abstractmethod
    def init(self, omega0, v0):
        """The state before the first sample, from the first measured speeds."""

    @abc.abstractmethod
    def update(self, state, car: QuarterCar, hardware: BrakeHardware, substeps: int, v, omega,
               stamp, fresh, torque0, target, t0):
        """One sample: the state after the sample from `t0` (brake torque from `torque0`
        lagging towards `target`), given the measured wheel speed `omega` standing for time
        `stamp` (a measurement only if `fresh`) and the measured vehicle speed `v`."""

    @abc.abstractmethod
    def belief(self, state) -> AbstractLongitudinalTire:
        """The tire the estimator believes in at `state`."""

    @abc.abstractmethod
    def signals(self, state) -> dict:
        """What a saved run keeps of the state, by name (scalars)."""


def run_estimator(estimator: AbstractFrictionEstimator, car: QuarterCar, hardware: BrakeHardware,
                  record, substeps: int = SUBSTEPS):
    """The estimator run over a recorded braking (a `BrakingRecord`) as the loop runs it:
    at sample $k > 0$ it sees the measurements of sample $k$ and the brake torque of sample
    $k - 1$. Under a controller that does not read the belief (`LockedWheel`,
    `RuleBasedABS`) this is the estimator of the loop itself. **Returns:** its state after
    every sample (leading axis: samples)."""
    def step(state, k):
        j = jnp.maximum(k - 1, 0)
        new = estimator.update(state, car, hardware, substeps, record.v_meas[k],
                               record.omega_meas[k], record.omega_stamp[k], record.fresh[k],
                               record.torque[j], record.target[j], record.ts[j])
        new = jax.tree_util.tree_map(lambda a, b: jnp.where(k > 0, a, b), new, state)
        return new, new

    state0 = estimator.init(record.omega_meas[0], record.v_meas[0])
    return jax.lax.scan(step, state0, jnp.arange(record.ts.shape[0]))[1]
