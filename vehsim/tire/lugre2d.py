r"""Combined longitudinal/lateral LuGre friction: parameters and the point model (eqs. 26-30).

**Sign conventions** (shared with the longitudinal models and `AbstractTire`). In the wheel
frame ($x$ along the heading, $y$ to the left) the relative velocity of the road with respect
to the tread is
$$v_r = (v_{rx}, v_{ry}) = (\omega r - v_x,\; -v_y) = (\omega r - v\cos\alpha,\; v\sin\alpha),$$
with the slip angle $\alpha = \operatorname{atan2}(-v_y, v_x)$ (positive when the wheel slides
to its right, as in the Magic Formula). This is eq. 34 with the report's slip angle measured
the other way ($\alpha_\text{report} = -\alpha$, so eq. 34b reads
$v_{ry} = -v\sin\alpha_\text{report}$).
Forces on the tire are
$$F_i = +F_n(\sigma_{0i}z_i + \sigma_{1i}\dot z_i + \sigma_{2i}v_{ri}),\qquad i = x, y,$$
the same sign as the longitudinal eq. 9: $F_x > 0$ when driving and $F_y$ opposes lateral
sliding. The report's eqs. 26b, 31b, 36 carry a minus sign (their $\mu_i$ is the force the
tire exerts on the road): $F_i = -F_i^\text{report}$. The aligning moment of eq. 33,
$M_z = -\int\mu^\text{report}_y f_n(L/2-\zeta)\,d\zeta = \int \mu_y f_n (L/2-\zeta)\,d\zeta$,
is unchanged: it is the moment about the patch centre of the lateral force acting at
$x = L/2 - \zeta$ ($\zeta = 0$ the leading edge), positive counter-clockwise seen from above,
so $M_z < 0$ (aligning) when $F_y > 0$ builds up behind the centre.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_order, check_positive, check_range
from .._fields import array_field
from .._math import safe_abs, safe_div, safe_norm, safe_pow_abs
from .base import AbstractTire


class LuGre2DParams(eqx.Module):
    r"""Parameters of the combined-slip LuGre models (eqs. 26-38). Per-axis fields have shape
    `(..., 2)` ordered $(x, y)$.

    **Fields** (SI units):

    - `sigma0` [1/m]: bristle stiffnesses $(\sigma_{0x}, \sigma_{0y}) > 0$.
    - `sigma1` [s/m]: bristle damping $(\sigma_{1x}, \sigma_{1y}) \ge 0$.
    - `sigma2` [s/m]: viscous damping $(\sigma_{2x}, \sigma_{2y}) \ge 0$.
    - `mu_k` [-]: kinetic friction, the diagonal of $M_k$ (eq. 30 form), $> 0$.
    - `mu_s` [-]: static friction, the diagonal of $M_s$ (eq. 30), $\mu_{ki} \le \mu_{si}$.
    - `v_s` [m/s]: Stribeck velocity $> 0$.
    - `gamma` [-]: Stribeck exponent of eq. 29 $> 0$.
    - `L` [m]: contact-patch length $> 0$ (distributed, lumped and moment models).
    """

    sigma0: Float[Array, "... 2"] = array_field()
    sigma1: Float[Array, "... 2"] = array_field()
    sigma2: Float[Array, "... 2"] = array_field()
    mu_k: Float[Array, "... 2"] = array_field()
    mu_s: Float[Array, "... 2"] = array_field()
    v_s: Float[Array, ...] = array_field()
    gamma: Float[Array, ...] = array_field(default=0.5)
    L: Float[Array, ...] = array_field(default=0.2)

    def __check_init__(self):
        owner = "LuGre2DParams"
        for name in ("sigma0", "sigma1", "sigma2", "mu_k", "mu_s"):
            shape = jnp.shape(getattr(self, name))
            if len(shape) == 0 or shape[-1] != 2:
                raise ValueError(f"{owner}.{name} must have a last axis of length 2 (x, y), "
                                 f"got shape {shape}")
        check_positive(owner, "sigma0", self.sigma0)
        check_range(owner, "sigma1", self.sigma1, lower=0.0)
        check_range(owner, "sigma2", self.sigma2, lower=0.0)
        check_positive(owner, "mu_k", self.mu_k)
        check_positive(owner, "mu_s", self.mu_s)
        check_order(owner, "mu_k", self.mu_k, "mu_s", self.mu_s)
        check_positive(owner, "v_s", self.v_s)
        check_positive(owner, "gamma", self.gamma)
        check_positive(owner, "L", self.L)


def relative_velocity_2d(vx, vy, omega, r) -> Float[Array, "... 2"]:
    r"""$v_r = (\omega r - v_x, -v_y)$ (eq. 34, see the module docstring for the sign)."""
    vx, vy, omega, r = jnp.broadcast_arrays(*map(jnp.asarray, (vx, vy, omega, r)))
    return jnp.stack([omega * r - vx, -vy], axis=-1)


def slip_angle(vx, vy):
    r"""$\alpha = \operatorname{atan2}(-v_y, v_x)$, with value and gradient 0 at $v_x = v_y = 0$."""
    at_rest = (vx == 0) & (vy == 0)
    return jnp.where(at_rest, 0.0, jnp.arctan2(-vy, jnp.where(at_rest, 1.0, vx)))


def _ratio(m, v_r):
    r"""$\|M^2 v\|/\|M v\|$ for diagonal $M$ = `m`; direction-only, between min and max of `m`.

    At $v = 0$ the ratio has no limit (it depends on the direction); we return the mean of
    `m`, which only matters through $g(0)$ where it multiplies nothing singular."""
    num = safe_norm(m * m * v_r)
    den = safe_norm(m * v_r)
    return safe_div(num, den, fill=0.0) + jnp.where(den == 0, jnp.mean(m, axis=-1), 0.0)


def stribeck_2d(params: LuGre2DParams, v_r):
    r"""$g(v_r) = \frac{\|M_k^2v_r\|}{\|M_kv_r\|} + \Bigl(\frac{\|M_s^2v_r\|}{\|M_sv_r\|}
    - \frac{\|M_k^2v_r\|}{\|M_kv_r\|}\Bigr)e^{-(\|v_r\|/v_s)^\gamma}$ (eq. 29).

    For isotropic $M_k=\mu_kI$, $M_s=\mu_sI$ this is the longitudinal eq. 10."""
    gk = _ratio(params.mu_k, v_r)
    gs = _ratio(params.mu_s, v_r)
    speed = safe_norm(v_r)
    return gk + (gs - gk) * jnp.exp(-safe_pow_abs(speed / params.v_s, params.gamma))


def decay_rates(params: LuGre2DParams, v_r) -> Float[Array, "... 2"]:
    r"""$C_{0i}(v_r) = \lambda(v_r)\sigma_{0i}/\mu_{ki}^2$, $\lambda = \|M_k^2v_r\|/g(v_r)$
    (eqs. 27-28) [1/s]. Zero, with zero gradient, at $v_r = 0$."""
    lam = safe_norm(params.mu_k * params.mu_k * v_r) / stribeck_2d(params, v_r)
    return lam[..., None] * params.sigma0 / params.mu_k**2


def _forces_from(params, z, zdot, v_r):
    return params.sigma0 * z + params.sigma1 * zdot + params.sigma2 * v_r


class PointLuGre2D(AbstractTire):
    r"""Point-contact LuGre for 2D sliding (eqs. 26-30).

    $$\dot z_i = v_{ri} - C_{0i}(v_r)z_i,\qquad
      F_i = F_n(\sigma_{0i}z_i + \sigma_{1i}\dot z_i + \sigma_{2i}v_{ri}),$$
    state $z = (z_x, z_y)$ [m]; $M_z = 0$ (a point has no lever arm). Steady state:
    $z_i = v_{ri}/C_{0i}$, so $F_i/F_n \to \mu_{ki}^2 g\,v_{ri}/\|M_k^2v_r\| + \sigma_{2i}v_{ri}$,
    on the friction ellipse of $M_k$ at high speed.
    """

    params: LuGre2DParams

    def init_state(self):
        return jnp.zeros(2)

    def derivative(self, state, v_r):
        """$\\dot z$ for a given relative velocity (eq. 26a)."""
        return v_r - decay_rates(self.params, v_r) * state

    def mu(self, state, v_r):
        """Normalised forces $F/F_n$ (eq. 26b, our sign)."""
        return _forces_from(self.params, state, self.derivative(state, v_r), v_r)

    def dynamics(self, state, vx, vy, omega, r, Fz):
        return self.derivative(state, relative_velocity_2d(vx, vy, omega, r))

    def forces(self, state, vx, vy, omega, r, Fz):
        mu = self.mu(state, relative_velocity_2d(vx, vy, omega, r))
        return jnp.stack([Fz * mu[0], Fz * mu[1], jnp.zeros_like(Fz * mu[0])])


class AbstractPatchLuGre2D(AbstractTire):
    r"""A 2D LuGre tire over the contact patch, written in the relative velocity $v_r$
    (eq. 34) and the transport speed $c = |\omega r|$.

    Subclasses give `derivative(state, v_r, c)` (the friction states' time derivative) and
    `mu(state, v_r, c)` = $(F_x/F_n, F_y/F_n, M_z/(F_nL))$; the `AbstractTire` methods follow.
    """

    params: eqx.AbstractVar[LuGre2DParams]

    @abc.abstractmethod
    def derivative(self, state, v_r, c):
        """Time derivative of the friction state."""

    @abc.abstractmethod
    def mu(self, state, v_r, c):
        """$(F_x/F_n, F_y/F_n, M_z/(F_nL))$."""

    def dynamics(self, state, vx, vy, omega, r, Fz):
        return self.derivative(state, relative_velocity_2d(vx, vy, omega, r),
                               safe_abs(omega * r))

    def forces(self, state, vx, vy, omega, r, Fz):
        mu = self.mu(state, relative_velocity_2d(vx, vy, omega, r), safe_abs(omega * r))
        return Fz * mu * jnp.stack([jnp.ones(()), jnp.ones(()), self.params.L])
