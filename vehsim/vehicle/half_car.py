r"""Half-car with wheel spin and suspension dynamics (report eqs. 49-60), torque inputs.

State (flat vector; `HalfCar.state_names`, then the friction states of the front and the
rear tire, if the tire is dynamic):
$$(x, y, \psi, v_x, v_y, r,\ \omega_F, \omega_R,\ z, \dot z, \theta, \dot\theta,\
  \zeta_F, \zeta_R)$$
with body-frame velocities $v_x, v_y$, yaw rate $r$, wheel speeds $\omega_i$, heave $z$
(up) and pitch $\theta$ (nose down) of the suspended body. Controls: $(T_F, T_R, \delta)$,
the front and rear axle torques [N m] and the steering angle [rad].

- Planar motion: eqs. 49-51 (body frame, see `vehsim.vehicle.planar`).
- Wheels: $I_F\dot\omega_F = T_F - f_{Fx}r$, $I_R\dot\omega_R = T_R - f_{Rx}r$ (eqs. 52-53).
- Suspension: $m\ddot z = f_{Fz} + f_{Rz} - mg$ (eq. 54),
  $I_y\ddot\theta = (f_{Rz}\ell_R - f_{Fz}\ell_F)\cos\theta
  - (\Sigma f_{Rx} + \Sigma f_{Fx})(h+z)$ (eqs. 55-56), with the loads of eqs. 59-60:
  $f_{Fz} = f^o_{Fz} - K_F\Delta z_F - C_F\Delta\dot z_F$,
  $f_{Rz} = f^o_{Rz} - K_R\Delta z_R - C_R\Delta\dot z_R$,
  $\Delta z_F = z - \ell_F\sin\theta$, $\Delta z_R = z + \ell_R\sin\theta$ (and their rates).

With ``suspension=False`` the loads instead follow the quasi-static load transfer of the
reduced model (docs/maneuvers.md) and $z, \dot z, \theta, \dot\theta$ stay 0;
this is the model the reduced one (eqs. 61-63) is exactly equivalent to.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float

from .._checks import check_count, check_type
from .._math import safe_arctan2, safe_div
from ..tire.base import AbstractTire
from .base import AbstractVehicle
from .params import HalfCarParams
from .planar import axle_velocities, front_body_x, planar_rates, quasi_static_loads


class HalfCar(AbstractVehicle):
    r"""The half-car of eqs. 49-60 with any `AbstractTire` on both axles.

    **Arguments:**

    - `params`: `HalfCarParams`.
    - `tire`: the front tire, and the rear one unless `tire_R` is given (static or dynamic:
      a dynamic tire's friction states become vehicle states, one set per axle).
    - `tire_R`: the rear tire if it differs (same type of friction state as `tire`).
    - `suspension`: True (default) for the suspension dynamics of eqs. 54-60; False for
      the quasi-static load transfer of the reduced model.
    - `load_iterations`: used only with ``suspension=False`` (see `quasi_static_loads`).

    Axle loads are clipped at 0: a lifted axle carries no friction, and its spring, whose
    wheel has left the ground, no longer acts on the body (eqs. 54-55 with the clipped
    loads; the wheels have no mass of their own).
    """

    params: HalfCarParams
    tire: AbstractTire
    tire_R: AbstractTire | None = None
    suspension: bool = eqx.field(static=True, default=True)
    load_iterations: int = eqx.field(static=True, default=1)

    state_names: ClassVar[tuple[str, ...]] = (
        "x", "y", "psi", "vx", "vy", "yaw_rate", "omega_F", "omega_R",
        "z", "z_dot", "theta", "theta_dot",
    )
    control_names: ClassVar[tuple[str, ...]] = ("T_F", "T_R", "delta")

    def __check_init__(self):
        check_type("HalfCar", "params", self.params, HalfCarParams)
        check_type("HalfCar", "tire", self.tire, AbstractTire)
        check_type("HalfCar", "tire_R", self.tire_R, AbstractTire, optional=True)
        check_count("HalfCar", "load_iterations", self.load_iterations)
        if self.tire_R is not None:
            zF, zR = ravel_pytree(self.tire.init_state())[0], ravel_pytree(
                self.tire_R.init_state())[0]
            if zF.shape != zR.shape:
                raise ValueError(
                    f"HalfCar.tire_R must have a friction state of the same size as tire "
                    f"({zF.shape[0]}), got {zR.shape[0]}"
                )

    @property
    def tires(self) -> tuple[AbstractTire, AbstractTire]:
        """(front tire, rear tire)."""
        return self.tire, self.tire if self.tire_R is None else self.tire_R

    @property
    def tire_state_size(self) -> int:
        """Length of one tire's flattened friction state."""
        return ravel_pytree(self.tire.init_state())[0].shape[0]

    @property
    def state_size(self) -> int:
        return len(self.state_names) + 2 * self.tire_state_size

    @property
    def stiff_blocks(self) -> tuple[tuple[int, ...], tuple[int, ...]]:
        r"""State indices of the two stiff wheel-tire blocks, $(\omega_F, z_F)$ and
        $(\omega_R, z_R)$, for `vehsim.ROS34PW2` (the tire damping acting through the wheel
        inertia, $r^2\sigma_1F_z/I_w$, and the friction-state decay are the fast modes)."""
        n, k = len(self.state_names), self.tire_state_size
        front = (6,) + tuple(range(n, n + k))
        rear = (7,) + tuple(range(n + k, n + 2 * k))
        return front, rear

    def init_state(self, vx=0.0, vy=0.0, yaw_rate=0.0, x=0.0, y=0.0, psi=0.0, delta=0.0):
        r"""A state with free-rolling wheels ($\omega_i = V_{ix}/r$), the suspension at rest
        ($z = \theta = 0$, the equilibrium of eqs. 57-58) and undeflected tires."""
        VFx, _, VRx, _ = axle_velocities(self.params, vx, vy, yaw_rate, delta)
        head = jnp.stack([jnp.asarray(v, dtype=float) for v in (
            x, y, psi, vx, vy, yaw_rate, VFx / self.params.r, VRx / self.params.r,
            0.0, 0.0, 0.0, 0.0)])
        z0 = ravel_pytree(self.tire.init_state())[0]
        return jnp.concatenate([head, z0, z0])

    def _split(self, state):
        n, k = len(self.state_names), self.tire_state_size
        unravel = ravel_pytree(self.tire.init_state())[1]
        return state[:n], unravel(state[n:n + k]), unravel(state[n + k:n + 2 * k])

    def _suspension_loads(self, q):
        p = self.params
        z, z_dot, theta, theta_dot = q[8], q[9], q[10], q[11]
        FzF0, FzR0 = p.static_loads()
        s, c = jnp.sin(theta), jnp.cos(theta)
        FzF = FzF0 - p.K_F * (z - p.lF * s) - p.C_F * (z_dot - p.lF * c * theta_dot)
        FzR = FzR0 - p.K_R * (z + p.lR * s) - p.C_R * (z_dot + p.lR * c * theta_dot)
        return FzF, FzR

    def _evaluate(self, state, controls):
        """Everything the vector field and the signals need, computed once."""
        p = self.params
        q, zF, zR = self._split(state)
        delta = controls[2]
        VFx, VFy, VRx, VRy = axle_velocities(p, q[3], q[4], q[5], delta)
        omF, omR = q[6], q[7]

        tire_F, tire_R = self.tires

        def front(Fz):
            return tire_F.forces(zF, VFx, VFy, omF, p.r, jnp.maximum(Fz, 0.0))

        def rear(Fz):
            return tire_R.forces(zR, VRx, VRy, omR, p.r, jnp.maximum(Fz, 0.0))

        if self.suspension:
            FzF, FzR = self._suspension_loads(q)
        else:
            FzF, FzR = quasi_static_loads(
                p, lambda Fz: front_body_x(*front(Fz)[:2], delta), lambda Fz: rear(Fz)[0],
                self.load_iterations,
            )
        return dict(q=q, zF=zF, zR=zR, V=(VFx, VFy, VRx, VRy), fF=front(FzF), fR=rear(FzR),
                    Fz=(FzF, FzR))

    def f(self, state: Float[Array, " n"], controls: Float[Array, " 3"]) -> Float[Array, " n"]:
        """Eqs. 49-60 (see the module docstring)."""
        self.check_shapes(state, controls)
        p = self.params
        e = self._evaluate(state, controls)
        q, fF, fR = e["q"], e["fF"], e["fR"]
        T_F, T_R, delta = controls[0], controls[1], controls[2]
        VFx, VFy, VRx, VRy = e["V"]
        FzF, FzR = e["Fz"]
        planar = planar_rates(p, q[2], q[3], q[4], q[5], fF, fR, delta)
        wheels = jnp.stack([(T_F - fF[0] * p.r) / p.Iw_F, (T_R - fR[0] * p.r) / p.Iw_R])
        # the ground pushes, never pulls: an axle whose spring would pull the body down
        # has lifted its wheel, and carries nothing (the tire's load and the body's alike)
        FzF_t, FzR_t = jnp.maximum(FzF, 0.0), jnp.maximum(FzR, 0.0)
        if self.suspension:
            z, z_dot, theta, theta_dot = q[8], q[9], q[10], q[11]
            sum_fx = front_body_x(fF[0], fF[1], delta) + fR[0]
            z_dd = (FzF_t + FzR_t) / p.m - p.g
            theta_dd = ((FzR_t * p.lR - FzF_t * p.lF) * jnp.cos(theta)
                        - sum_fx * (p.h + z)) / p.Iy
            susp = jnp.stack([z_dot, z_dd, theta_dot, theta_dd])
        else:
            susp = jnp.zeros(4)
        tire_F, tire_R = self.tires
        dzF = ravel_pytree(tire_F.dynamics(e["zF"], VFx, VFy, q[6], p.r, FzF_t))[0]
        dzR = ravel_pytree(tire_R.dynamics(e["zR"], VRx, VRy, q[7], p.r, FzR_t))[0]
        return jnp.concatenate([planar, wheels, susp, dzF, dzR])

    def signals(self, state, controls) -> dict:
        """Named signals: pose, velocities, sideslip, slips, wheel speeds, forces, loads."""
        p = self.params
        e = self._evaluate(state, controls)
        q, fF, fR = e["q"], e["fF"], e["fR"]
        VFx, VFy, VRx, VRy = e["V"]
        rates = self.f(state, controls)
        vx, vy, r = q[3], q[4], q[5]
        return {
            "x": q[0], "y": q[1], "psi": q[2], "vx": vx, "vy": vy, "yaw_rate": r,
            "speed": jnp.hypot(vx, vy),
            "sideslip": safe_arctan2(vy, vx),
            "ax": rates[3] - r * vy, "ay": rates[4] + r * vx,
            "T_F": controls[0], "T_R": controls[1], "delta": controls[2],
            "omega_F": q[6], "omega_R": q[7],
            "kappa_F": safe_div(q[6] * p.r - VFx, VFx),
            "kappa_R": safe_div(q[7] * p.r - VRx, VRx),
            "alpha_F": safe_arctan2(VFy, VFx), "alpha_R": safe_arctan2(VRy, VRx),
            "Vx_F": VFx, "Vx_R": VRx,
            "Fx_F": fF[0], "Fy_F": fF[1], "Mz_F": fF[2],
            "Fx_R": fR[0], "Fy_R": fR[1], "Mz_R": fR[2],
            "Fz_F": e["Fz"][0], "Fz_R": e["Fz"][1],
            "z": q[8], "theta": q[10],
        }
