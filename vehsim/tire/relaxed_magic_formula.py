r"""A longitudinal Magic Formula with a relaxation length: a tire family other than LuGre.

$$\dot u = v_r - |v|\,\frac{u}{\sigma_\kappa},\qquad \mu = D\sin\bigl(C\arctan(Bs' - E(Bs'
  - \arctan Bs'))\bigr),\qquad s' = \frac{u}{\sigma_\kappa},$$
with $u$ [m] the carcass deflection and $s'$ the transient slip, which tends to $v_r/|v|$
(the braking/driving slip) with time constant $\sigma_\kappa/|v|$. Bakker, Nyborg and Pacejka
(1987) for the formula; Pacejka, *Tire and Vehicle Dynamics* (2012), ch. 7 for the
relaxation length. Signs as in `vehsim.tire.lugre` ($v_r = r\omega - v$, $\mu > 0$ driving).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_positive, check_range
from .._fields import array_field
from .._math import safe_abs, safe_div
from .lugre import AbstractLongitudinalTire, relative_velocity, relaxed_deflection_rate
from .magic_formula import magic_formula


class MagicFormulaParams(eqx.Module):
    r"""Longitudinal Magic Formula $\mu(s) = D\sin(C\arctan(Bs - E(Bs - \arctan Bs)))$.

    **Fields:** `B` stiffness factor [-] (> 0), `C` shape factor [-] (> 0), `D` peak
    friction [-] (> 0), `E` curvature factor [-] ($\le 1$), `relaxation_length`
    $\sigma_\kappa$ [m] (> 0).
    """

    B: Float[Array, "*batch"] = array_field(default=12.0)
    C: Float[Array, "*batch"] = array_field(default=1.65)
    D: Float[Array, "*batch"] = array_field(default=1.0)
    E: Float[Array, "*batch"] = array_field(default=0.3)
    relaxation_length: Float[Array, "*batch"] = array_field(default=0.25)

    def __check_init__(self):
        owner = "MagicFormulaParams"
        check_positive(owner, "B", self.B)
        check_positive(owner, "C", self.C)
        check_positive(owner, "D", self.D)
        check_range(owner, "E", self.E, upper=1.0)
        check_positive(owner, "relaxation_length", self.relaxation_length)


class RelaxedMagicFormula(AbstractLongitudinalTire):
    r"""Magic Formula driven by a transient slip with relaxation length $\sigma_\kappa$.

    State: the carcass deflection $u$ [m], $\dot u = v_r - |v|\,u/\sigma_\kappa$;
    $\mu = $ `magic_formula`$(u/\sigma_\kappa, B, C, D, E)$ (module docstring). Finite at
    $v = 0$ (the state is then held).
    """

    params: MagicFormulaParams

    def init_state(self):
        return jnp.zeros(())

    def dynamics(self, state, v, omega, r):
        return relaxed_deflection_rate(state, v, omega, r, self.params.relaxation_length)

    def mu(self, state, v, omega, r):
        p = self.params
        return magic_formula(state / p.relaxation_length, p.B, p.C, p.D, p.E)

    def steady_state(self, v, omega, r):
        r"""$u = \sigma_\kappa v_r/|v|$ (0 at $v = 0$)."""
        return safe_div(self.params.relaxation_length * relative_velocity(v, omega, r),
                        safe_abs(v))

    def braking_mu(self, s, v, r=None):
        r"""The formula at braking slip $s$ (the transient slip's rest value; $v$ and $r$ do
        not enter)."""
        p = self.params
        return magic_formula(s, p.B, p.C, p.D, p.E)
