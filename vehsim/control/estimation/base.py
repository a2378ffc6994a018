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

from ...tire.lugre import AbstractLongitudinalTire
from ...vehicle.quarter_car import QuarterCar
from ..plant.hardware import BrakeHardware


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
