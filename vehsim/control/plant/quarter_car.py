r"""The braked quarter car between two control samples, and a surface change along the road.

The plant is `vehsim.QuarterCar` (constant load by default) with the brake torque of the
actuator (`vehsim.control.plant.hardware`), plus the distance travelled $x$ and the wheel angle
$\varphi$ (for the tone wheel), one flat state
$$y = (x,\ v,\ \omega,\ F_n,\ \bar z,\ \varphi),\qquad \dot x = v,\quad \dot\varphi = \omega.$$
Between samples it is integrated by `vehsim.ROS34PW2`, linearly implicit in the stiff block
$(v, \omega, \bar z)$ (the bristle decay reaches $10^5$ 1/s on a sliding wheel on ice; the
tire damping through the wheel inertia, $r^2\sigma_1F_n/J$, $10^3$ 1/s), with step-size
control (`vehsim.control.plant.integrate`). A `SurfaceChange` is crossed over
the contact patch: the tire's parameters are blended by the fraction $w$ of the patch on
the new surface, $w = (x - x_c)/L_c$ clipped to [0, 1] for a change at distance $x_c$
($(t - t_c)v/L_c$ for one at time $t_c$), $L_c$ the transition length (the patch length,
0.25 m, by default). An instant change would hit the friction state with a new decay rate
$10^2$-$10^3$ times the old (dry to ice), and the damping term $\sigma_1\dot z$ with a force
spike of a hundred times the normal load. Once stopped
(below `STANDSTILL` m/s) the plant is held: a standing car has nothing more to show, and the
friction state's decay has no scale there.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float

from ..._checks import check_positive, check_range
from ..._fields import array_field
from ...tire.lugre import AbstractLongitudinalTire
from ...vehicle.quarter_car import QuarterCar
from .hardware import BrakeHardware, brake_torque
from .integrate import integrate_sample
from .sensors import EncoderState, count_edges


STANDSTILL = 0.05
"""Speed [m/s] below which the plant is held."""


class SurfaceChange(eqx.Module):
    r"""The road changes to `tire` (a tire of the same kind on the new surface) once the
    distance travelled reaches `distance` [m] or the time reaches `time` [s] (either may be
    `inf`: never), over the transition `length` [m] (module docstring)."""

    tire: AbstractLongitudinalTire
    distance: Float[Array, ""] = array_field(default=float("inf"))
    time: Float[Array, ""] = array_field(default=float("inf"))
    length: Float[Array, ""] = array_field(default=0.25)

    def __check_init__(self):
        check_positive("SurfaceChange", "length", self.length)
        for name in ("distance", "time"):
            value = getattr(self, name)
            check_range("SurfaceChange", name, value, lower=0.0, allow_inf=True)


class BrakingScenario(eqx.Module):
    """A braking: the quarter car `car` (its tire on the first surface), the initial speed
    `speed` [m/s] (> 0, free rolling), and the `change` of surface (default: none)."""

    car: QuarterCar
    speed: Float[Array, ""] = array_field()
    change: SurfaceChange | None = None

    def __post_init__(self):
        if self.change is None:
            self.change = SurfaceChange(self.car.tire)

    def __check_init__(self):
        check_positive("BrakingScenario", "speed", self.speed)
        a = jax.tree_util.tree_structure(self.car.tire)
        b = jax.tree_util.tree_structure(self.change.tire)
        if a != b:
            raise ValueError("BrakingScenario.change.tire must be the same kind of tire as "
                             "car.tire")

    def tire_at(self, t, x, v=None) -> AbstractLongitudinalTire:
        """The tire in effect at time `t` after travelling `x` at speed `v` (blended over
        the change's transition; the speed matters only for a change in time)."""
        w = change_fraction(self.change, t, x, self.speed if v is None else v)
        return jax.tree_util.tree_map(lambda a, b: a + w * (b - a), self.car.tire,
                                      self.change.tire)


def change_fraction(change: SurfaceChange, t, x, v):
    """The fraction of the contact patch on the new surface (module docstring).

    A change at `inf` (never) is replaced by 0 inside the unused branch as well (double
    `where`): the unused branch's derivative, `t - inf`, times its zero cotangent would be a
    NaN in reverse mode."""
    never_x, never_t = jnp.isinf(change.distance), jnp.isinf(change.time)
    d = jnp.where(never_x, -1.0, x - jnp.where(never_x, 0.0, change.distance))
    s = jnp.where(never_t, -1.0,
                  (t - jnp.where(never_t, 0.0, change.time)) * jnp.maximum(v, 0.0))
    return jnp.clip(jnp.maximum(d, s) / change.length, 0.0, 1.0)


def braking_quarter_car(tire: AbstractLongitudinalTire, mass=350.0, inertia=1.0,
                        radius=0.3, omega_eps=1.0) -> QuarterCar:
    r"""The quarter car of the braking scenarios: a quarter of a 1400 kg car on a wheel of
    1 kg m^2 and 0.3 m radius (values of the order used by Savaresi and Tanelli 2010).

    The brake's smoothing $\omega_\epsilon$ = 1 rad/s (`QuarterCar`'s default is 0.05): a
    locked wheel then creeps at $\omega_\epsilon\operatorname{artanh}(rF/T_b)$, at most a
    few per mille of the speed, and its stiffness, $T_b/(J\omega_\epsilon)$, stays where the
    fixed sub-steps resolve it. With 0.05 rad/s a wheel locked on ice at a few m/s settles
    into a spurious backward spin of the linearly implicit steps."""
    return QuarterCar(tire, mass=mass, inertia=inertia, radius=radius, omega_eps=omega_eps)


def initial_plant_state(scenario: BrakingScenario) -> Float[Array, " n"]:
    """Free rolling at the scenario's speed, undeflected tire, at the origin."""
    qs = scenario.car.init_state(scenario.speed)
    return ravel_pytree((jnp.zeros(()), qs, jnp.zeros(())))[0]


def unpack(scenario: BrakingScenario, y):
    """``(x, QuarterCarState, phi)`` of the flat state `y`."""
    return ravel_pytree((jnp.zeros(()), scenario.car.init_state(1.0), jnp.zeros(())))[1](y)


def _stiff_block(scenario: BrakingScenario) -> tuple[int, ...]:
    n_tire = ravel_pytree(scenario.car.tire.init_state())[0].shape[0]
    return (1, 2) + tuple(range(4, 4 + n_tire))


def _vector_field(t, y, args):
    scenario, hardware, torque0, target, t_sample = args
    x, qs, phi = unpack(scenario, y)
    car = eqx.tree_at(lambda c: c.tire, scenario.car, scenario.tire_at(t, x, qs.v))
    rates = car.dynamics(t, qs, brake_torque(hardware, torque0, target, t - t_sample))
    return ravel_pytree((qs.v, rates, qs.omega))[0]


def advance(scenario: BrakingScenario, hardware: BrakeHardware, y, enc: EncoderState, t_sample,
            torque0, target, substeps: int):
    """Integrate the plant over one sample from `t_sample` under the brake torque that
    starts at `torque0` and lags towards `target`, counting tone-wheel edges; derivatives
    hold the steps' Jacobians constant (`ROS34PW2.frozen_jacobian`, docs/differentiating.md).

    **Returns:** the state and the encoder state at the next sample, and the solve's
    result.
    """
    args = (scenario, hardware, torque0, target, t_sample)
    y1, result = integrate_sample(_vector_field, y, args, t_sample, hardware.sample_time,
                                  (_stiff_block(scenario),), substeps, frozen_jacobian=True)
    w0, w1 = unpack(scenario, y)[1].omega, unpack(scenario, y1)[1].omega
    enc1 = count_edges(hardware, enc, t_sample, hardware.sample_time, y[-1], y1[-1], w0, w1)
    moving = unpack(scenario, y)[1].v > STANDSTILL
    return jnp.where(moving, y1, y), jax.tree_util.tree_map(
        lambda a, b: jnp.where(moving, a, b), enc1, enc), result
