r"""Linear tire: forces proportional to slip and load (the textbook bicycle-model tire).

$$f_x = c_\kappa F_z\,\kappa,\qquad f_y = -c_\alpha F_z\,\frac{V_y}{V_x},\qquad
  \kappa = \frac{\omega r - V_x}{V_x}.$$
$c_\kappa$, $c_\alpha$ are stiffnesses per unit load (1/rad); an axle carrying $F_z$ has
cornering stiffness $C_\alpha = c_\alpha F_z$. Useful for closed forms (understeer gradient).
At $V_x = 0$ the forces are zero (the slips are defined as 0 there, with finite gradients).
"""

from typing import ClassVar

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_positive
from .._fields import array_field
from .._math import safe_div
from .base import AbstractTire


class LinearTire(AbstractTire):
    r"""$f_x = c_\kappa F_z\kappa$, $f_y = -c_\alpha F_z V_y/V_x$, $M_z = 0$ (static tire).

    **Fields:** `c_kappa` [-] longitudinal and `c_alpha` [1/rad] cornering stiffness per
    unit normal load.
    """

    load_proportional: ClassVar[bool] = True

    c_kappa: Float[Array, "..."] = array_field()
    c_alpha: Float[Array, "..."] = array_field()

    def __check_init__(self):
        check_positive("LinearTire", "c_kappa", self.c_kappa)
        check_positive("LinearTire", "c_alpha", self.c_alpha)

    def init_state(self):
        return jnp.zeros((0,))

    def dynamics(self, state, vx, vy, omega, r, Fz):
        return jnp.zeros((0,))

    def forces(self, state, vx, vy, omega, r, Fz):
        kappa = safe_div(omega * r - vx, vx)
        tan_alpha = safe_div(vy, vx)
        fx = self.c_kappa * Fz * kappa
        fy = -self.c_alpha * Fz * tan_alpha
        return jnp.stack([fx, fy, jnp.zeros_like(fx)])
