r"""Closed loop: the quarter car of `vehsim.vehicle.quarter_car` (lumped tire, measured load)
driven by the measured brake torque $T_b(t)$ predicts $v$, $\omega$ and $F_x$ together.
"""

from __future__ import annotations

from typing import Any, ClassVar

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._checks import check_range
from ..tire.lugre import LumpedLuGre
from ..vehicle.normal_load import PrescribedLoad
from ..vehicle.quarter_car import QuarterCar, simulate_quarter_car
from .base import AbstractBrakingModel
from .braking import BrakingData
from .friction_state import steady_friction_state


def closed_loop_car(model: LumpedLuGre, data: BrakingData) -> QuarterCar:
    """The quarter car of a braking: lumped tire, measured load as input, `m`, `J`, `r`."""
    if data.T_b is None or data.m is None or data.J is None:
        raise ValueError(f"closed-loop fit of {data.name!r} needs column 'T_b' and side-file "
                         "entries 'm' [kg] and 'J' [kg m^2]")
    return QuarterCar(model, mass=data.m, inertia=data.J, radius=data.r,
                      load=PrescribedLoad(data.t, data.F_n))


def predict_closed_loop(model: LumpedLuGre, data: BrakingData, *, rtol=1e-6, atol=1e-8,
                        solver=None, adjoint=None, throw=True):
    r"""Predicted $(v, \omega, F_x)$ at the samples: the quarter car driven by $T_b(t)$, from
    the measured $v$, $\omega$ and the steady friction state at $t_0$.

    Adaptive steps (`rtol`, `atol`) of `solver` (default `Kvaerno5`, implicit; an explicit
    `Tsit5` compiles faster and copes with short brakings, its steps limited by stability).
    """
    car = closed_loop_car(model, data)
    state0 = car.init_state(data.v[0], data.t[0], omega0=data.omega[0])
    state0 = eqx.tree_at(lambda s: s.tire, state0,
                         steady_friction_state(model, data.v[0], data.omega[0], data.r))
    sol = simulate_quarter_car(car, data.t, data.T_b, data.v[0], state0, rtol=rtol, atol=atol,
                               solver=solver, adjoint=adjoint, throw=throw, max_steps=50_000)
    return sol.v, sol.omega, sol.Fx


_predict_closed_loop_jit = eqx.filter_jit(predict_closed_loop)


def jvp_columns(fn, x, mask):
    """`fn(x)` and its Jacobian transposed, (len(x), len(fn(x))): one forward-mode JVP per
    column where `mask` is true (zeros elsewhere), in a `lax.map` (not a `vmap`, which would
    batch the solve's saved trajectory)."""
    r0 = fn(x)
    eye = jnp.eye(x.shape[0], dtype=x.dtype)

    def column(i):
        return jax.lax.cond(mask[i], lambda: jax.jvp(fn, (x,), (eye[i],))[1],
                            lambda: jnp.zeros_like(r0))

    return r0, jax.lax.map(column, jnp.arange(x.shape[0]))


class ClosedLoopBraking(AbstractBrakingModel):
    r"""$v$, $\omega$ and $F_x$ predicted by the quarter car driven by the measured torque;
    residuals $(F - F_x)/\max|F_x|$, $(v - v_m)/\max|v_m|$, $(\omega - \omega_m)/\max|\omega_m|$.

    `solver`: the diffrax solver (default `Kvaerno5`), adaptive with relative tolerance
    `rtol` and absolute `rtol`/100, in `diffrax.ForwardMode` (whatever the `adjoint` given to
    `residuals`). The Jacobian: one forward-mode JVP per free parameter (`jvp_columns`).
    """

    solver: Any = None
    rtol: float = 1e-6
    name: ClassVar[str] = "closed_loop"

    def __check_init__(self):
        check_range("ClosedLoopBraking", "rtol", self.rtol, lower=0.0, upper=1.0,
                    lower_open=True, upper_open=True)

    def predict_force(self, model, data):
        return _predict_closed_loop_jit(model, data, rtol=self.rtol, atol=self.rtol * 1e-2,
                                        solver=self.solver, adjoint=dfx.ForwardMode(),
                                        throw=False)[2]

    def residuals(self, model, data, scales, adjoint=None):
        F_s, v_s, om_s = scales
        out = []
        for d in data:
            v, om, F = predict_closed_loop(model, d, rtol=self.rtol, atol=self.rtol * 1e-2,
                                           solver=self.solver, adjoint=dfx.ForwardMode(),
                                           throw=False)
            out += [(F - d.F_x) / F_s, (v - d.v) / v_s, (om - d.omega) / om_s]
        return jnp.concatenate(out)

    def residuals_and_jacobian(self, u, mask, model_of, data, scales, slots):
        return jvp_columns(lambda x: self.residuals(model_of(x), data, scales), u, mask)

    def fitted_forces(self, model, data, r, scales):
        # at the default tolerance (rtol 1e-6) whatever the fit's `rtol`, as fits report them
        at_default = ClosedLoopBraking(solver=self.solver)
        return [np.asarray(at_default.predict_force(model, d)) for d in data]
