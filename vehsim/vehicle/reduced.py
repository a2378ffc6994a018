r"""Reduced half-car with slip inputs (report eqs. 61-63) and torque recovery.

The longitudinal slips $\kappa_F$, $\kappa_R$ of the two axles are the inputs (with the
steering angle $\delta$): the wheel spin dynamics (eqs. 52-53) and the suspension
(eqs. 54-60) drop out, and the normal loads follow the quasi-static load transfer of
the benchmark maneuvers (docs/maneuvers.md), solved exactly (`vehsim.vehicle.planar.quasi_static_loads`).

The torques that realise a slip history are recovered afterwards (report text after
eq. 63): $\omega_i = (1+\kappa_i)V_{ix}/r$, and by eqs. 52-53
$$T_i = I_i\dot\omega_i + f_{ix}r,\qquad
  \dot\omega_i = \big(\dot\kappa_i V_{ix} + (1+\kappa_i)\dot V_{ix}\big)/r.$$
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_type
from .._math import safe_arctan2
from ..tire.base import AbstractTire
from .base import AbstractVehicle
from .params import HalfCarParams
from .planar import (
    axle_velocities,
    front_body_x,
    load_transfer,
    planar_rates,
    quasi_static_loads,
)


class ReducedHalfCar(AbstractVehicle):
    r"""Eqs. 61-63: state $(x, y, \psi, v_x, v_y, r)$, input $(\kappa_F, \kappa_R, \delta)$.

    $x, y$ [m] position of the centre of gravity (inertial), $\psi$ [rad] yaw angle,
    $v_x, v_y$ [m/s] body-frame velocity, $r$ [rad/s] yaw rate. The practical slip
    $\kappa_i = (\omega_i r - V_{ix})/V_{ix}$ ($\kappa = -1$: locked wheel) is defined with
    the wheel-frame longitudinal speed $V_{ix}$ of the axle; the model is singular at
    $V_{ix} = 0$ (the maneuvers' path constraint keeps $V_{ix} \ge 1$ m/s).

    **Arguments:**

    - `params`: `HalfCarParams` (the suspension fields are not used).
    - `tire`: a *static* `AbstractTire` (empty friction state), for the front axle and,
      unless `tire_R` is given, the rear; e.g. `FrictionEllipseTire` (the maneuvers' tire) or
      `LinearTire`. A load-proportional tire on both axles (no `tire_R`) is evaluated
      once, over the pair of axles (`jax.vmap`), so that compiled derivatives run each of
      its operations once.
    - `tire_R`: the rear tire if it differs (static too; then each axle's tire is
      evaluated on its own).
    - `load_iterations`: fixed-point iterations of the load transfer (`quasi_static_loads`)
      for tires whose forces are not proportional to the load; with load-proportional tires
      (`AbstractTire.load_proportional`) each tire is evaluated once, at unit load, and the
      loads are exact (`load_transfer`).
    """

    params: HalfCarParams
    tire: AbstractTire
    tire_R: AbstractTire | None = None
    load_iterations: int = eqx.field(static=True, default=1)

    state_names: ClassVar[tuple[str, ...]] = ("x", "y", "psi", "vx", "vy", "yaw_rate")
    control_names: ClassVar[tuple[str, ...]] = ("kappa_F", "kappa_R", "delta")

    def __check_init__(self):
        check_type("ReducedHalfCar", "params", self.params, HalfCarParams)
        check_type("ReducedHalfCar", "tire", self.tire, AbstractTire)
        check_type("ReducedHalfCar", "tire_R", self.tire_R, AbstractTire, optional=True)
        for name, tire in (("tire", self.tire), ("tire_R", self.tire_R)):
            if tire is not None and jnp.shape(tire.init_state()) != (0,):
                raise ValueError(
                    f"ReducedHalfCar.{name} must be static (friction state of shape (0,)); "
                    "use HalfCar for dynamic tires"
                )

    @property
    def tires(self) -> tuple[AbstractTire, AbstractTire]:
        """(front tire, rear tire)."""
        return self.tire, self.tire if self.tire_R is None else self.tire_R

    def axle_velocities(self, state, delta):
        r"""$(V_{Fx}, V_{Fy}, V_{Rx}, V_{Ry})$: wheel-frame velocities of the axle centres [m/s].

        $V_{Fx}$ and $V_{Rx}$ are the speeds of the maneuvers' path constraint ($\ge 1$ m/s).
        """
        return axle_velocities(self.params, state[3], state[4], state[5], delta)

    def wheel_speeds(self, state, controls):
        r"""$\omega_i = (1+\kappa_i)V_{ix}/r$ [rad/s] for the front and rear axle."""
        VFx, _, VRx, _ = self.axle_velocities(state, controls[2])
        r = self.params.r
        return (1.0 + controls[0]) * VFx / r, (1.0 + controls[1]) * VRx / r

    def _axle_forces(self, state, controls):
        kF, kR, delta = controls[0], controls[1], controls[2]
        VFx, VFy, VRx, VRy = self.axle_velocities(state, delta)
        r = self.params.r
        omF, omR = (1.0 + kF) * VFx / r, (1.0 + kR) * VRx / r
        tire_F, tire_R = self.tires
        s0 = jnp.zeros((0,))
        if tire_F.load_proportional and tire_R.load_proportional:
            # each tire once, at unit load: the loads are then exact (`load_transfer`), and
            # the second derivatives of the optimal-control solver cost half as much
            if self.tire_R is None:
                # one tire on both axles: one evaluation over the pair, so that the
                # compiled derivatives run each of its operations once, on both axles
                unit_F, unit_R = jax.vmap(
                    lambda vx, vy, om: tire_F.forces(s0, vx, vy, om, r, 1.0))(
                    jnp.stack([VFx, VRx]), jnp.stack([VFy, VRy]), jnp.stack([omF, omR]))
            else:
                unit_F = tire_F.forces(s0, VFx, VFy, omF, r, 1.0)
                unit_R = tire_R.forces(s0, VRx, VRy, omR, r, 1.0)
            FzF, FzR = load_transfer(self.params, front_body_x(unit_F[0], unit_F[1], delta),
                                     unit_R[0])
            return unit_F * FzF, unit_R * FzR, FzF, FzR

        def front(Fz):
            return tire_F.forces(s0, VFx, VFy, omF, r, Fz)

        def rear(Fz):
            return tire_R.forces(s0, VRx, VRy, omR, r, Fz)

        def front_bx(Fz):
            f = front(Fz)
            return front_body_x(f[0], f[1], delta)

        FzF, FzR = quasi_static_loads(
            self.params, front_bx, lambda Fz: rear(Fz)[0], self.load_iterations
        )
        return front(FzF), rear(FzR), FzF, FzR

    def normal_loads(self, state, controls):
        r"""$(F_{zF}, F_{zR})$ [N], quasi-static load transfer (eq. 55 with $\theta=0$)."""
        _, _, FzF, FzR = self._axle_forces(state, controls)
        return FzF, FzR

    def tire_forces(self, state, controls):
        r"""Wheel-frame tire forces $(f_x, f_y, M_z)$ of the front and rear axle [N, N, N m]."""
        fF, fR, _, _ = self._axle_forces(state, controls)
        return fF, fR

    def f(self, state: Float[Array, " 6"], controls: Float[Array, " 3"]) -> Float[Array, " 6"]:
        r"""Eqs. 61-63 in body-frame velocities (see `vehsim.vehicle.planar`)."""
        self.check_shapes(state, controls)
        fF, fR, _, _ = self._axle_forces(state, controls)
        return planar_rates(
            self.params, state[2], state[3], state[4], state[5], fF, fR, controls[2]
        )

    def recover_torques(self, state, controls, controls_dot):
        r"""Wheel speeds and torques that realise the slips (eqs. 52-53 differentiated).

        **Arguments:** `state`, `controls` $(\kappa_F, \kappa_R, \delta)$ and their time
        derivative `controls_dot` at one instant.

        **Returns:** $(\omega_F, \omega_R, T_F, T_R)$ [rad/s, rad/s, N m, N m].
        """
        p = self.params
        delta, delta_dot = controls[2], controls_dot[2]
        state_dot = self.f(state, controls)

        def vx_axles(y, d):
            VFx, _, VRx, _ = self.axle_velocities(y, d)
            return jnp.stack([VFx, VRx])

        V, V_dot = jax.jvp(vx_axles, (state, delta), (state_dot, delta_dot))
        kappa, kappa_dot = controls[:2], controls_dot[:2]
        omega = (1.0 + kappa) * V / p.r
        omega_dot = (kappa_dot * V + (1.0 + kappa) * V_dot) / p.r
        fF, fR = self.tire_forces(state, controls)
        T_F = p.Iw_F * omega_dot[0] + fF[0] * p.r
        T_R = p.Iw_R * omega_dot[1] + fR[0] * p.r
        return omega[0], omega[1], T_F, T_R

    def signals(self, state, controls) -> dict:
        """Named signals: pose, velocities, sideslip, slips, wheel speeds, forces, loads."""
        kF, kR, delta = controls[0], controls[1], controls[2]
        VFx, VFy, VRx, VRy = self.axle_velocities(state, delta)
        fF, fR, FzF, FzR = self._axle_forces(state, controls)
        omF, omR = self.wheel_speeds(state, controls)
        rates = self.f(state, controls)
        vx, vy = state[3], state[4]
        return {
            "x": state[0], "y": state[1], "psi": state[2],
            "vx": vx, "vy": vy, "yaw_rate": state[5],
            "speed": jnp.hypot(vx, vy),
            "sideslip": safe_arctan2(vy, vx),
            "ax": rates[3] - state[5] * vy,
            "ay": rates[4] + state[5] * vx,
            "delta": delta, "kappa_F": kF, "kappa_R": kR,
            "alpha_F": safe_arctan2(VFy, VFx), "alpha_R": safe_arctan2(VRy, VRx),
            "Vx_F": VFx, "Vx_R": VRx,
            "omega_F": omF, "omega_R": omR,
            "Fx_F": fF[0], "Fy_F": fF[1], "Fx_R": fR[0], "Fy_R": fR[1],
            "Fz_F": FzF, "Fz_R": FzR,
        }
