r"""The drive plant: the half-car of eqs. 49-60 on a road of varying grip, driven through
sampled actuators and seen through noisy sensors.

Between two control samples (period $T$) the plant integrates the half-car
(`vehsim.HalfCar`, wheel spin eqs. 52-53, suspension loads eqs. 54-60) with a dynamic tire
on each axle whose friction coefficients are scaled by the grip field at that axle's
contact point, $\lambda_F = \lambda(x + \ell_F\cos\psi, y + \ell_F\sin\psi)$ and
$\lambda_R = \lambda(x - \ell_R\cos\psi, y - \ell_R\sin\psi)$ (`vehsim.scale_friction`;
for a LuGre tire $\theta = 1/\lambda$), re-read at every evaluation of the vector field.
The controls $(T_F, T_R, \delta)$ within the sample are the actuators' lag responses
(`vehsim.DriveActuators`). A negative axle torque is a brake torque: it acts as
$T_i^-\tanh(\omega_i/\omega_\epsilon)$ (as in `QuarterCar`), opposing the wheel's
rotation, so a braked wheel locks instead of spinning backwards; a positive one drives the
wheel ($T_i = T_i^+ + T_i^-\tanh(\omega_i/\omega_\epsilon)$, $T^\pm$ the parts of the
applied torque). The integrator is the braking loop's: `substeps` fixed steps
of the linearly implicit `vehsim.ROS34PW2`, implicit in the two stiff wheel-tire blocks
(`HalfCar.stiff_blocks`; the bristle decay of eqs. 27-28 reaches $10^4$ 1/s on a sliding
wheel). At the end of the sample the sensors (`vehsim.DriveSensors`) report a
`DriveMeasurement`.

The default tire is the lumped 2D LuGre of report section 2.3 (eqs. 35-36,
`vehsim.LumpedLuGre2D`) with the `lugre2d_bakker1987` parameters; its aligning moment is
computed (eqs. 37-38) but the half-car does not use it.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .._checks import check_finite, check_positive, check_range
from .._fields import array_field
from ..control.plant.integrate import integrate_sample
from ..tire.base import AbstractTire
from ..tire.lumped2d import LumpedLuGre2D
from ..tire.params import lugre2d_bakker1987
from ..vehicle.half_car import HalfCar
from ..vehicle.params import HalfCarParams, rally_gravel
from .actuators import (
    DriveActuators,
    DriveActuatorState,
    actuator_target,
    applied,
    mean_applied,
)
from .grip import AbstractGripField, SurfaceFactor, UniformGrip, scale_friction
from .sensors import DriveMeasurement, DriveSensors, measure


class DrivePlant(eqx.Module):
    r"""The plant of the module docstring.

    **Fields:** `params` (`HalfCarParams`, default `rally_gravel()`), `tire` (an
    `AbstractTire` that `scale_friction` can scale; default the lumped 2D LuGre of eqs.
    35-36 with `lugre2d_bakker1987()`), `grip` (an `AbstractGripField`, default
    `UniformGrip()`), `actuators` (`DriveActuators`), `sensors` (`DriveSensors`),
    `suspension` (True: eqs. 54-60; False: quasi-static loads), `substeps` (integration
    steps per control sample, 40: 1.25 ms at 20 Hz), `omega_eps` $\omega_\epsilon$ [rad/s]
    (brake-torque smoothing, 0.5), `surface_factor` (None: the tire's friction scaled by the
    grip's $\lambda$ itself, the report's $\theta = 1/\lambda$ for the LuGre family; a
    `SurfaceFactor` $m$: by $m(\lambda)$, for a tire of another family put on the same
    surfaces by their peaks, `peak_surface_factor`).
    """

    params: HalfCarParams = eqx.field(default_factory=rally_gravel)
    tire: AbstractTire = eqx.field(default_factory=lambda: LumpedLuGre2D(lugre2d_bakker1987()))
    grip: AbstractGripField = eqx.field(default_factory=UniformGrip)
    actuators: DriveActuators = eqx.field(default_factory=DriveActuators)
    sensors: DriveSensors = eqx.field(default_factory=DriveSensors)
    suspension: bool = eqx.field(static=True, default=True)
    substeps: int = eqx.field(static=True, default=40)
    omega_eps: Float[Array, ""] = array_field(default=0.5)
    surface_factor: SurfaceFactor | None = None

    def __check_init__(self):
        if not isinstance(self.substeps, int) or self.substeps < 1:
            raise ValueError(f"DrivePlant.substeps must be an integer >= 1, got {self.substeps}")
        scale_friction(self.tire, 1.0)  # refuses a tire it cannot scale, with its name
        check_positive("DrivePlant", "omega_eps", self.omega_eps)

    def axle_points(self, state):
        r"""Contact points of the front and rear axle, $((x_F, y_F), (x_R, y_R))$ [m]."""
        x, y, psi = state[0], state[1], state[2]
        c, s = jnp.cos(psi), jnp.sin(psi)
        p = self.params
        return (x + p.lF * c, y + p.lF * s), (x - p.lR * c, y - p.lR * s)

    def grip_scales(self, state):
        r"""$(\lambda_F, \lambda_R)$ at the axles' contact points."""
        (xF, yF), (xR, yR) = self.axle_points(state)
        return self.grip.scale_at(xF, yF), self.grip.scale_at(xR, yR)

    def car_at(self, state) -> HalfCar:
        """The half-car with each axle's tire on the grip under it at `state`."""
        lamF, lamR = self.grip_scales(state)
        if self.surface_factor is not None:
            lamF, lamR = self.surface_factor(lamF), self.surface_factor(lamR)
        return HalfCar(self.params, scale_friction(self.tire, lamF),
                       scale_friction(self.tire, lamR), suspension=self.suspension)

    @property
    def nominal_car(self) -> HalfCar:
        """The half-car with the tire's own friction on both axles."""
        return HalfCar(self.params, self.tire, suspension=self.suspension)

    def wheel_torques(self, state, controls):
        r"""The controls with each axle torque's negative part acting as a brake,
        $T^+ + T^-\tanh(\omega/\omega_\epsilon)$ (module docstring)."""
        T = controls[:2]
        brake = jnp.tanh(state[6:8] / self.omega_eps)
        return jnp.concatenate([jnp.maximum(T, 0.0) + jnp.minimum(T, 0.0) * brake,
                                controls[2:]])

    def vector_field(self, state, controls):
        """The half-car's rates (eqs. 49-60) with the grip under the axles at `state`."""
        return self.car_at(state).f(state, self.wheel_torques(state, controls))


class DriveState(eqx.Module):
    """The plant between samples: sample index `k`, time `t` [s], the half-car state `car`
    (`HalfCar.state_names` and the tires' friction states) and the actuators' state."""

    k: Int[Array, ""]
    t: Float[Array, ""]
    car: Float[Array, " n"]
    actuators: DriveActuatorState


def init_drive(plant: DrivePlant, vx=0.0, x=0.0, y=0.0, psi=0.0, u0=(0.0, 0.0, 0.0)
               ) -> DriveState:
    """The car driving straight at `vx` [m/s] from the pose `(x, y, psi)`, wheels rolling
    freely, the actuators settled at `u0` = $(T_F, T_R, \\delta)$; `vx` at least 0 (the
    drive's controllers drive forward), every value finite."""
    check_range("init_drive", "vx", vx, lower=0.0)
    for name, value in (("x", x), ("y", y), ("psi", psi), ("u0", u0)):
        check_finite("init_drive", name, value)
    car = plant.nominal_car.init_state(vx=vx, x=x, y=y, psi=psi)
    return DriveState(jnp.zeros((), int), jnp.zeros(()), car, DriveActuatorState.init(u0))


def _rates(t, y, args):
    plant, u0, target, t0 = args
    return plant.vector_field(y, applied(plant.actuators, u0, target, t - t0))


def measure_drive(plant: DrivePlant, state: DriveState, key,
                  torque=None) -> DriveMeasurement:
    """The sensors' reading of `state` with the noise of `key` (`torque`: the mean axle
    torques to report, default the applied ones)."""
    u = state.actuators.applied
    truth = plant.car_at(state.car).signals(state.car, plant.wheel_torques(state.car, u))
    torque = u[:2] if torque is None else torque
    return measure(plant.sensors, key, state.t, truth, u[2], torque)


def drive_step(plant: DrivePlant, state: DriveState, command, key, *,
               substep_poses: bool = False):
    r"""One control sample: the command $(T_F, T_R, \delta)$ issued at sample $k$ goes
    through the actuators, the half-car is integrated over $[t_k, t_k + T]$ and the sensors
    read it at $t_{k+1}$ with the noise of `key`. **Returns** ``(state, measurement)``; with
    `substep_poses`, ``(state, measurement, poses)``, `poses` the centre of gravity's
    $(x, y)$ [m] at the end of every integration step, $t_k + jT/$`substeps`,
    $j = 1..$`substeps` (shape (substeps, 2); the last row is the new state's)."""
    act = plant.actuators
    T = act.sample_time
    act_state, target = actuator_target(act, state.actuators, state.k, command)
    u0 = state.actuators.applied
    car = plant.nominal_car
    out = integrate_sample(_rates, state.car, (plant, u0, target, state.t), state.t, T,
                           car.stiff_blocks, plant.substeps, save_substeps=substep_poses)
    y1 = out[0]
    u1 = applied(act, u0, target, T)
    new = DriveState(state.k + 1, state.t + T, y1,
                     DriveActuatorState(act_state.buffer, target, u1))
    m = measure_drive(plant, new, key, mean_applied(act, u0, target)[:2])
    return (new, m, out[2][:, :2]) if substep_poses else (new, m)
