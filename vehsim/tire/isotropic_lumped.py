r"""A small dynamic combined-slip tire: isotropic lumped LuGre (eqs. 22-23 in two dimensions).

The longitudinal lumped model of eqs. 22-23 with the relative velocity made a vector,
$v_r = (\omega r - V_x,\ -V_y)$ (contact-patch velocity relative to the road, wheel frame):
$$\dot z = v_r - \frac{\theta\sigma_0|v_r|}{g(|v_r|)}z - \kappa|\omega r|z,\qquad
  (f_x, f_y) = (\sigma_0 z + \sigma_1\dot z + \sigma_2 v_r)F_z,\qquad M_z = 0,$$
with one set of `LuGreParams` for both directions and $\kappa = \kappa_0/L$ (eq. 25). In pure
longitudinal slip it is exactly `LumpedLuGre`. It is the dynamic tire the half-car tests and
the `simulate_batch` benchmark use; the anisotropic 2D models of report section 2.4
(eqs. 31-48) plug into the vehicles the same way, through `AbstractTire`.
"""

import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_range
from .._fields import array_field
from .._math import safe_abs, safe_norm
from .base import AbstractTire
from .lugre import LuGreParams, stribeck


class IsotropicLumpedLuGre(AbstractTire):
    r"""Isotropic lumped LuGre tire; friction state $z = (z_x, z_y)$ [m].

    **Arguments:** `params` (`LuGreParams`), `kappa0` (dimensionless, $\kappa = \kappa_0/L$).
    """

    params: LuGreParams
    kappa0: Float[Array, "..."] = array_field(default=1.0)

    def __check_init__(self):
        check_range("IsotropicLumpedLuGre", "kappa0", self.kappa0, lower=0.0)

    def init_state(self):
        return jnp.zeros(2)

    def _rates(self, state, vx, vy, omega, r):
        p = self.params
        v_r = jnp.stack([omega * r - vx, -vy])
        speed = safe_norm(v_r)
        decay = p.theta * p.sigma0 * speed / stribeck(p, speed)
        decay = decay + self.kappa0 / p.L * safe_abs(omega * r)
        return v_r, v_r - decay * state

    def dynamics(self, state, vx, vy, omega, r, Fz):
        return self._rates(state, vx, vy, omega, r)[1]

    def forces(self, state, vx, vy, omega, r, Fz):
        p = self.params
        v_r, z_dot = self._rates(state, vx, vy, omega, r)
        mu = p.sigma0 * state + p.sigma1 * z_dot + p.sigma2 * v_r
        return jnp.stack([mu[0] * Fz, mu[1] * Fz, jnp.zeros_like(mu[0] * Fz)])
