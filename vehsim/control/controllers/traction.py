r"""Traction control: a driven wheel accelerating from low speed (report section 2.2).

The same quarter car, hardware and observer as the brakings, with a negative brake torque
driving the wheel (`QuarterCar`: $J\dot\omega = -rF_x - T_b\tanh(\omega/\omega_\epsilon)$, so
$T_b < 0$ is a drive torque for a forward-turning wheel; the actuator's lag, rate limit and
delay stand for the engine's torque response). Slips are driving slips,
$s = 1 - v/(r\omega)\in[0, 1)$.

- `FullThrottle`: the drive torque `drive_torque` from the start (the wheel spins up).
- `TractionControl`: the wheel speed held at $v/(1 - s^*)$, $s^*$ the peak of the belief's
  driving curve (`driving_curve`: eq. 18 at $\hat\theta$ for a `UniformLumpedLuGre`
  belief, the computed steady state for any other) at the measured speed (`peak_driving`),
  by the feedforward
  $T_{ff} = \hat\mu^*F_n(r + J/(mr(1 - s^*)))$ (the drive torque that balances the friction
  torque and accelerates the wheel with the car) plus PI feedback on the peripheral speed
  error, as `PeakSlipTracking` brakes.

The physical limit is `traction_limit`: the speed a point mass reaches at the driving peak.
`traction_scenario` builds the driven wheel on a named surface, on any plant tire, with the
observer over any assumed model (`FrictionObserver`); the shape-free `PeakEstimator` reads
braking slips only, and on a driven wheel holds its prior.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from ..._checks import check_nonnegative, check_positive
from ..._fields import array_field
from ...tire.lugre import AbstractLongitudinalTire
from ..estimation.observer import FrictionObserver
from ..experiments.scenarios import observer_for
from ..plant.quarter_car import BrakingScenario, braking_quarter_car
from ..road.peak import peak_driving
from ..road.surfaces import surface
from .braking import AbstractBrakeController


class FullThrottle(AbstractBrakeController):
    """The drive torque `drive_torque` [N m] (1500) from the start."""

    drive_torque: Float[Array, ""] = array_field(default=1500.0)

    def __check_init__(self):
        check_positive("FullThrottle", "drive_torque", self.drive_torque)

    def init(self, max_torque):
        return jnp.zeros(())

    def command(self, state, m, belief, car, dt, max_torque):
        return state, -self.drive_torque, jnp.zeros((), int)


class TractionControl(AbstractBrakeController):
    r"""Driving-slip tracking at the estimated peak (module docstring): gains `kp` [N m s/m]
    (60), `ki` [N m/m] (600), at most `drive_torque` (1500 N m), target `slip_scale` times
    the peak slip."""

    kp: Float[Array, ""] = array_field(default=60.0)
    ki: Float[Array, ""] = array_field(default=600.0)
    drive_torque: Float[Array, ""] = array_field(default=1500.0)
    slip_scale: Float[Array, ""] = array_field(default=1.0)

    def __check_init__(self):
        for name in ("kp", "ki"):
            check_nonnegative("TractionControl", name, getattr(self, name))
        check_positive("TractionControl", "drive_torque", self.drive_torque)
        check_positive("TractionControl", "slip_scale", self.slip_scale)

    def init(self, max_torque):
        return jnp.zeros(())

    def command(self, state, m, belief, car, dt, max_torque):
        v = jnp.maximum(m.v, 0.5)
        s_peak, mu_peak = peak_driving(belief, v, r=car.radius)
        s = jnp.clip(self.slip_scale * s_peak, 1e-3, 0.95)
        r = car.radius
        feedforward = mu_peak * car.Fn_static * (r + car.inertia / (car.mass * r * (1.0 - s)))
        e = v / (1.0 - s) - r * m.omega
        limit = self.drive_torque
        integral = jnp.clip(state + self.ki * e * dt, -feedforward, limit - feedforward)
        torque = jnp.clip(feedforward + integral + self.kp * e, 0.0, limit)
        return integral, -torque, jnp.zeros((), int)


def traction_scenario(name: str, speed: float = 2.0,
                      tire: AbstractLongitudinalTire | None = None, model=None, **changes):
    """``(BrakingScenario, FrictionObserver)`` of a driven wheel from `speed` [m/s] on the
    surface `name` (rolling freely at the start).

    `tire`: a plant tire other than the surface's (e.g. `other_tire(name)`); `model`: what
    the observer assumes (any `FrictionObserver.model`: an `AbstractRoadParametrisation`, a
    LuGre tire with its road condition, any other tire with its friction scale; default: the
    surface's tire at its family's prior road condition, as `braking_scenario`); `changes`:
    further `FrictionObserver` fields (with a `model`, its projection range `theta_min`,
    `theta_max` default to the observer's own)."""
    srf = surface(name)
    plant_tire = srf.tire() if tire is None else tire
    scenario = BrakingScenario(braking_quarter_car(plant_tire), speed)
    if model is None:
        return scenario, observer_for(srf, **changes)
    return scenario, FrictionObserver(model, **changes)
