r"""Isotropic Magic Formula with friction ellipse (combined slip), as in `docs/maneuvers.md`.

$$\mu(s) = D\sin(C\arctan(Bs)),$$
with, for a wheel of practical longitudinal slip $\kappa = (\omega r - V_x)/V_x$ and
wheel-frame velocity $(V_x, V_y)$,
$$s_x = -\frac{\kappa}{1+\kappa},\quad s_y = \frac{V_y/V_x}{1+\kappa},\quad
  s = \sqrt{s_x^2+s_y^2},\quad \mu_x = -\frac{s_x}{s}\mu(s),\quad \mu_y = -\frac{s_y}{s}\mu(s).$$
Forces are $f_x = \mu_x F_z$, $f_y = \mu_y F_z$ (wheel frame; $F_z$ the normal load).

In velocities, $s_x = (V_x - \omega r)/(\omega r)$ and $s_y = V_y/(\omega r)$: the force
opposes the slip velocity $(V_x - \omega r, V_y)$ with magnitude $\mu(s)F_z$ and
$s = |\text{slip velocity}|/(\omega r)$. The tire is static (state shape ``(0,)``).
"""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_positive
from .._fields import array_field, float_array
from .base import AbstractTire


ROLLING_FLOOR = 1e-3
r"""Floor on the rolling speed $\omega r$ [m/s] in `FrictionEllipseTire.forces`."""


def _mu_over_s(B, C, D, s2):
    r"""$\mu(s)/s$ as a smooth function of $s^2$ (finite value and gradient at $s = 0$).

    Near 0, $\sin(C\arctan(Bs))/s = CB - B^3(C/3 + C^3/6)s^2 + O(s^4)$.
    """
    small = s2 < 1e-12
    s2_safe = jnp.where(small, jnp.ones_like(s2), s2)
    s = jnp.sqrt(s2_safe)
    exact = D * jnp.sin(C * jnp.arctan(B * s)) / s
    series = D * (C * B - B**3 * (C / 3 + C**3 / 6) * s2)
    return jnp.where(small, series, exact)


LOCKED_FLOOR = 1e-4
r"""Floor of $|1 + \kappa| = |\omega r|/V_x$ in `FrictionEllipseTire.mu` (1 mm/s of
$|\omega r|$ at 10 m/s, `ROLLING_FLOOR`'s)."""


class FrictionEllipseTire(AbstractTire):
    r"""Isotropic Magic Formula $\mu(s) = D\sin(C\arctan(Bs))$ with friction ellipse.

    **Fields:** `B`, `C`, `D` (dimensionless; `D` is the peak friction coefficient),
    `lateral_ratio` $\rho_y$ (1: the friction circle): the ellipse's lateral semi-axis over
    its longitudinal one, $\mu_y$ times $\rho_y$, so that the peak in pure side slip is
    $\rho_y D$ (a tire whose side force peaks below its braking force, as the drive
    plant's LuGre tire, `docs/driver.md`), and `lateral_stiffness` $k_y$ (None:
    isotropic, $k_y = 1$ without the product) the side slip's scale in the combined slip,
    $s = \sqrt{s_x^2 + (k_y s_y)^2}$ and $(\mu_x, \mu_y) = -(s_x, \rho_y k_y s_y)\,\mu(s)/s$,
    so that pure side slip follows $\rho_y\mu(k_y s_y)$: its slope at zero slip is
    $\rho_y k_y$ times the braking one and its peak lies at $s^*/k_y$ (the plant's LuGre
    tire, whose bristles are about half as stiff sideways, `fit_planner_tire`).

    Used two ways:

    - as an `AbstractTire` (`forces(state, vx, vy, omega, r, Fz)`), for the torque-input
      half-car: theoretical slips $(V_x - \omega r, V_y)/|\omega r|$, so a wheel rolling
      backwards gets the mirror image of the forward forces, with $|\omega r|$ floored at
      `ROLLING_FLOOR` = 1 mm/s so a locked wheel slides with $\mu \to D\sin(C\pi/2)$
      (not a division by zero);
    - as a slip-input law `mu(kappa, tan_alpha)` for the reduced half-car (eqs. 61-63),
      with $\kappa \in (-1, \infty)$ the control input and `tan_alpha` $= V_y/V_x$.
    """

    load_proportional: ClassVar[bool] = True

    B: Float[Array, "..."] = array_field()
    C: Float[Array, "..."] = array_field()
    D: Float[Array, "..."] = array_field()
    lateral_ratio: Float[Array, "..."] = array_field(default=1.0)
    lateral_stiffness: Float[Array, "..."] | None = eqx.field(
        default=None, converter=lambda x: None if x is None else float_array(x))

    def __check_init__(self):
        check_positive("FrictionEllipseTire", "B", self.B)
        check_positive("FrictionEllipseTire", "C", self.C)
        check_positive("FrictionEllipseTire", "D", self.D)
        check_positive("FrictionEllipseTire", "lateral_ratio", self.lateral_ratio)
        if self.lateral_stiffness is not None:
            check_positive("FrictionEllipseTire", "lateral_stiffness", self.lateral_stiffness)

    def mu_of_s(self, s):
        r"""$\mu(s) = D\sin(C\arctan(Bs))$."""
        return self.D * jnp.sin(self.C * jnp.arctan(self.B * s))

    @property
    def peak_slip(self):
        r"""The combined slip of the peak, $s^* = \tan(\pi/(2C))/B$ (where
        $C\arctan(Bs) = \pi/2$); $\infty$ for $C \le 1$, whose $\mu(s)$ rises to $D$ only
        as $s \to \infty$."""
        C = jnp.asarray(self.C, float)
        safe = jnp.where(C > 1.0, C, 2.0)  # double-where: no infinite derivative at C <= 1
        return jnp.where(C > 1.0, jnp.tan(jnp.pi / (2.0 * safe)) / self.B, jnp.inf)

    def mu_theoretical(self, sx, sy):
        r"""$(\mu_x, \mu_y) = -(s_x, \rho_y k_y s_y)\,\mu(s)/s$ from the theoretical
        slips, $s = \sqrt{s_x^2 + (k_y s_y)^2}$."""
        if self.lateral_stiffness is not None:
            sy = self.lateral_stiffness * sy
        g = _mu_over_s(self.B, self.C, self.D, sx * sx + sy * sy)
        return -sx * g, -sy * (self.lateral_ratio * g)

    def mu(self, kappa, tan_alpha):
        r"""$(\mu_x, \mu_y)$ from practical slip $\kappa$ and $V_y/V_x$ (module docstring):
        the theoretical slips $(-\kappa, \tan\alpha)/|1 + \kappa|$, with $|1 + \kappa|
        = |\omega r|/V_x$ floored at `LOCKED_FLOOR` as `forces` floors $|\omega r|$, so that
        a locked wheel ($\kappa = -1$) slides at $\mu \to D\sin(C\pi/2)$ with finite
        derivatives, and one turning backwards ($\kappa < -1$) gets the mirror image, as in
        `forces`. The maneuvers of `docs/maneuvers.md` bound $\kappa \ge -0.99$.
        """
        one_plus = jnp.maximum(jnp.abs(1.0 + kappa), LOCKED_FLOOR)
        return self.mu_theoretical(-kappa / one_plus, tan_alpha / one_plus)

    def init_state(self):
        return jnp.zeros((0,))

    def dynamics(self, state, vx, vy, omega, r, Fz):
        return jnp.zeros((0,))

    def forces(self, state, vx, vy, omega, r, Fz):
        rolling = jnp.maximum(jnp.abs(omega * r), ROLLING_FLOOR)  # |omega r|: backwards too
        mu_x, mu_y = self.mu_theoretical((vx - omega * r) / rolling, vy / rolling)
        return jnp.stack([mu_x * Fz, mu_y * Fz, jnp.zeros_like(mu_x * Fz)])


def rally_gravel_tire() -> FrictionEllipseTire:
    """The maneuver benchmark's gravel tire (`docs/maneuvers.md`): B=7, C=1.6, D=0.52."""
    return FrictionEllipseTire(B=7.0, C=1.6, D=0.52)
