r"""Quarter-car braking: one wheel, its share of the vehicle mass, a brake torque, a tire.

$$m\dot v = F_x,\qquad J\dot\omega = -rF_x - T_b(t)\tanh(\omega/\omega_\epsilon),\qquad
  F_x = \mu(\text{tire state}, v, \omega)\,F_n,$$

with the tire any `AbstractLongitudinalTire` (point, lumped or distributed LuGre, or the
relaxed Magic Formula of `vehsim.tire.relaxed_magic_formula`) and the normal load $F_n$
constant, relaxing to a load-transfer target, or prescribed (`vehsim.vehicle.normal_load`).
This is the plant of report section 2.2: the brakings of Figs. 10-11 are the response of
such a wheel to the brake torque. Sign conventions as in `vehsim.tire.lugre`: $F_x<0$ decelerates the car.

The brake is a friction torque opposing rotation; $\tanh(\omega/\omega_\epsilon)$ makes it
smooth, so a locked wheel creeps at $r\omega\approx r\omega_\epsilon\,
\operatorname{artanh}(r|F_x|/T_b)$ instead of switching (keep $\omega_\epsilon$ small).
"""

from __future__ import annotations

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Float, PyTree

from .._checks import (
    check_finite_signals,
    check_positive,
    check_shaped_like,
    check_times,
    check_type,
)
from .._constants import GRAVITY
from .._fields import array_field
from .._integrate import (
    DEFLECTION_ATOL,
    EQUILIBRIUM_DTMAX,
    MAX_STEPS,
    RTOL,
    check_solver_settings,
    integrate,
    solve_stats,
)
from .._results import RESULTS, as_result
from .._signals import as_signal
from .._solution import AbstractSolution
from ..tire.lugre import AbstractLongitudinalTire
from .normal_load import AbstractNormalLoad, ConstantLoad


class QuarterCarState(eqx.Module):
    """State of the quarter car: speeds, normal load and the tire's friction state."""

    v: Float[Array, ""]
    omega: Float[Array, ""]
    Fn: Float[Array, ""]
    tire: PyTree


class QuarterCar(eqx.Module):
    r"""One braked wheel carrying its share of the vehicle mass (see the module docstring).

    **Arguments:**

    - `tire`: any `AbstractLongitudinalTire`.
    - `mass` $m$ [kg]: the vehicle mass carried by this wheel (> 0).
    - `inertia` $J$ [kg m^2]: wheel (plus brake disc and half-shaft) inertia (> 0).
    - `radius` $r$ [m]: rolling radius (> 0).
    - `load`: an `AbstractNormalLoad` (default `ConstantLoad()`).
    - `Fn_static` [N]: static load (default $mg$).
    - `omega_eps` $\omega_\epsilon$ [rad/s]: brake-torque smoothing (> 0, default 0.05).
    """

    tire: AbstractLongitudinalTire
    mass: Float[Array, ""] = array_field()
    inertia: Float[Array, ""] = array_field()
    radius: Float[Array, ""] = array_field()
    load: AbstractNormalLoad = eqx.field(default_factory=ConstantLoad)
    Fn_static: Float[Array, ""] | None = eqx.field(default=None)
    omega_eps: Float[Array, ""] = array_field(default=0.05)

    def __post_init__(self):
        if self.Fn_static is None:
            self.Fn_static = jnp.asarray(self.mass) * GRAVITY
        else:
            self.Fn_static = jnp.asarray(self.Fn_static)

    def __check_init__(self):
        check_type("QuarterCar", "tire", self.tire, AbstractLongitudinalTire)
        check_positive("QuarterCar", "mass", self.mass)
        check_positive("QuarterCar", "inertia", self.inertia)
        check_positive("QuarterCar", "radius", self.radius)
        check_positive("QuarterCar", "Fn_static", self.Fn_static)
        check_positive("QuarterCar", "omega_eps", self.omega_eps)

    def init_state(self, v0, t0=0.0, omega0=None) -> QuarterCarState:
        """Free rolling at speed `v0` ($\\omega_0 = v_0/r$ unless given), undeflected tire."""
        v0 = jnp.asarray(v0, dtype=float)
        omega0 = v0 / self.radius if omega0 is None else jnp.asarray(omega0, dtype=float)
        return QuarterCarState(
            v=v0, omega=omega0, Fn=jnp.asarray(self.load.initial(t0, self.Fn_static), dtype=float),
            tire=self.tire.init_state(),
        )

    def normal_load(self, t, state: QuarterCarState):
        """$F_n$ [N] acting at time `t`."""
        return self.load.value(t, state.Fn)

    def force(self, t, state: QuarterCarState):
        r"""$F_x = \mu F_n$ [N]."""
        mu = self.tire.mu(state.tire, state.v, state.omega, self.radius)
        return mu * self.normal_load(t, state)

    def dynamics(self, t, state: QuarterCarState, brake_torque) -> QuarterCarState:
        """Time derivative of the state for brake torque `brake_torque` [N m] (>= 0)."""
        Fx = self.force(t, state)
        Tb = brake_torque * jnp.tanh(state.omega / self.omega_eps)
        return QuarterCarState(
            v=Fx / self.mass,
            omega=(-self.radius * Fx - Tb) / self.inertia,
            Fn=self.load.rate(t, state.Fn, Fx, self.Fn_static),
            tire=self.tire.dynamics(state.tire, state.v, state.omega, self.radius),
        )


class QuarterCarSolution(AbstractSolution):
    """Result of `simulate_quarter_car` at the save times: speed `v`, wheel speed `omega`,
    the acting load `Fn`, the force `Fx`, the `brake_torque` (also ``sol["v"]``, ...) and
    the tire's friction state `tire`."""

    ts: Float[Array, " T"]
    v: Float[Array, " T"]
    omega: Float[Array, " T"]
    Fn: Float[Array, " T"]
    Fx: Float[Array, " T"]
    brake_torque: Float[Array, " T"]
    tire: PyTree
    result: RESULTS = eqx.field(converter=as_result)
    stats: dict

    @property
    def signals(self) -> dict:
        return dict(v=self.v, omega=self.omega, Fn=self.Fn, Fx=self.Fx,
                    brake_torque=self.brake_torque)


def simulate_quarter_car(
    car: QuarterCar,
    ts: Float[Array, " T"],
    brake_torque,
    v0,
    state0: QuarterCarState | None = None,
    *,
    solver: dfx.AbstractSolver | None = None,
    rtol: float = RTOL,
    atol: float = DEFLECTION_ATOL,
    dt0: float | None = None,
    max_steps: int = MAX_STEPS,
    dtmax: float | None = EQUILIBRIUM_DTMAX,
    adjoint: dfx.AbstractAdjoint | None = None,
    throw: bool = True,
) -> QuarterCarSolution:
    r"""Integrate the quarter car from free rolling at `v0` under a brake torque $T_b(t)$.

    **Arguments:**

    - `car`: a `QuarterCar`.
    - `ts`: increasing save times [s].
    - `brake_torque`: $T_b$ [N m]: constant, samples on `ts` (linear between), or callable.
    - `v0`: initial speed [m/s] (ignored if `state0` is given).
    - `solver`: default `Kvaerno5` (implicit: the friction state is stiff at large slip).
    - `dt0`: `None` for adaptive steps (`rtol`, `atol`; default `DEFLECTION_ATOL`: the
      state holds the tire's deflections), or a fixed step [s].
    - `max_steps`: the step budget (as every vehsim solve, `vehsim._integrate`).
    - `dtmax`: the largest adaptive step [s] (default `EQUILIBRIUM_DTMAX`, 10 ms: from a
      standstill or free rolling the motion's error alone would lengthen the steps past
      what a derivative needs; None: unbounded).
    - `adjoint`: e.g. `diffrax.ForwardMode()` for Jacobians in least squares.
    - `throw`: raise if the solve fails; otherwise check `result`.

    **Returns:** a `QuarterCarSolution` with $v$, $\omega$, $F_n$, $F_x$ at `ts`.
    """
    check_times("simulate_quarter_car", ts)
    check_solver_settings("simulate_quarter_car", rtol=rtol, atol=atol, max_steps=max_steps,
                          dt0=dt0, dtmax=dtmax, solver=solver, adjoint=adjoint)
    check_finite_signals("simulate_quarter_car", brake_torque=brake_torque,
                         v0=None if state0 is not None else v0)
    ts = jnp.asarray(ts, dtype=float)
    Tb_fn = as_signal(ts, brake_torque)
    if state0 is None:
        y0 = car.init_state(v0, ts[0])
    else:  # v0 is ignored, and may be None
        check_shaped_like("simulate_quarter_car", "state0", state0, car.init_state(0.0, ts[0]),
                          "QuarterCar.init_state(v0)")
        y0 = state0

    def vector_field(t, y, args):
        return car.dynamics(t, y, Tb_fn(t))

    if solver is None:
        # fixed steps (dt0 given): the implicit solver's Newton iterations need tolerances
        solver = dfx.Kvaerno5() if dt0 is None else dfx.Kvaerno5(
            root_finder=dfx.VeryChord(rtol=rtol, atol=atol, norm=optx.max_norm))
    sol = integrate(
        vector_field, ts, y0, solver=solver, dt0=dt0, rtol=rtol, atol=atol,
        stepsize_controller=None if dt0 is None else dfx.ConstantStepSize(),
        max_steps=max_steps, dtmax=dtmax, adjoint=adjoint, throw=throw,
    )
    ys = sol.ys
    Fx = jax.vmap(car.force)(ts, ys)
    Fn = jax.vmap(car.normal_load)(ts, ys)
    return QuarterCarSolution(
        ts=ts, v=ys.v, omega=ys.omega, Fn=Fn, Fx=Fx, brake_torque=jax.vmap(Tb_fn)(ts),
        tire=ys.tire, result=sol.result, stats=solve_stats(sol),
    )
