r"""Average lumped 2D LuGre: forces (eqs. 35-36) and aligning torque (eqs. 37-38).

With $\xi = \zeta/L$, $f_n = F_nq(\xi)/L$, $c = |\omega r|$ and the mean states
$\bar z_i = \int_0^1 z_iq\,d\xi$ (eq. 20 per axis) and $\hat z_y = \int_0^1 z_yq\,\xi\,d\xi$,
$G/(F_nL) = \int_0^1 q\,\xi\,d\xi$:
$$\dot{\bar z}_i = v_{ri} - C_{0i}(v_r)\bar z_i - \kappa_i c\,\bar z_i,\qquad
  F_i = F_n(\sigma_{0i}\bar z_i + \sigma_{1i}\dot{\bar z}_i + \sigma_{2i}v_{ri}),$$
$$\dot{\hat z}_y = \frac{G}{F_nL}v_{ry} - C_{0y}\hat z_y - \nu c\,\hat z_y + \frac cL\bar z_y,\qquad
  \frac{M_z}{F_nL} = \sigma_{0y}(\tfrac12\bar z_y - \hat z_y) + \sigma_{1y}(\tfrac12\dot{\bar z}_y
  - \dot{\hat z}_y) + \sigma_{2y}v_{ry}(\tfrac12 - \tfrac{G}{F_nL}),$$
our sign (forces on the tire, $F_i = -F_i^\text{report}$; $M_z$ as eq. 33). Integrating eq. 31a
against $q$ and $q\xi$ gives these equations exactly with
$\kappa_i = \bigl(z_i(1)q(1) - \int z_iq'\bigr)/(L\bar z_i)$ and
$\nu = \bigl(z_y(1)q(1) - \int z_yq'\xi\bigr)/(L\hat z_y)$; the lumped model replaces them by
constants $\kappa_0/L$, $\nu_0/L$ (eq. 25 analogue; for a uniform load $\kappa_0 = 1$,
$\nu_0 = 2$ when the deflection is uniform, $2$ and $3$ when it is linear), or, with
`steady_state_gains=True`, by the values that make the steady state equal to the
distributed model's (the approach of the report's refs. [37-39]), computed from the closed
form at the current inputs.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_range
from .._math import floor_transport, one_minus_exp_over
from .distributed2d import graded_nodes
from .load import AbstractLoadDistribution, UniformLoad
from .lugre2d import AbstractPatchLuGre2D, LuGre2DParams, decay_rates


_GL_X, _GL_W = np.polynomial.legendre.leggauss(20)


def _first_moment(load):
    xs, ws = load.gauss_points(16)
    return jnp.sum(jnp.asarray(ws * xs) * load.q(jnp.asarray(xs)))


class LumpedLuGre2D(AbstractPatchLuGre2D):
    r"""Lumped 2D LuGre with aligning torque (eqs. 35-38); state $(\bar z_x, \bar z_y, \hat z_y)$.

    **Arguments:**

    - `params`: `LuGre2DParams`.
    - `load`: load shape (enters through $G$ and, with `steady_state_gains`, the gains).
    - `kappa0`: $(\kappa_{0x}, \kappa_{0y})$ or a scalar, $\ge 0$ (default 1).
    - `nu0`: $\nu_0 \ge 0$ (default 2).
    - `steady_state_gains`: use the gains that reproduce the distributed steady state.
    """

    params: LuGre2DParams
    load: AbstractLoadDistribution
    kappa0: Float[Array, ...]
    nu0: Float[Array, ""]
    G: Float[Array, ""]
    steady_state_gains: bool = eqx.field(static=True)

    def __init__(self, params, load=None, kappa0=1.0, nu0=2.0, steady_state_gains=False):
        self.params = params
        self.load = UniformLoad() if load is None else load
        self.kappa0 = jnp.broadcast_to(jnp.asarray(kappa0, dtype=float), (2,))
        self.nu0 = jnp.asarray(nu0, dtype=float)
        check_range("LumpedLuGre2D", "kappa0", self.kappa0, lower=0.0)
        check_range("LumpedLuGre2D", "nu0", self.nu0, lower=0.0)
        self.G = _first_moment(self.load)
        self.steady_state_gains = bool(steady_state_gains)
    def init_state(self):
        return jnp.zeros(3)

    def gains(self, v_r, c):
        r"""$(\kappa_x, \kappa_y, \nu)$ [1/m]: constants, or the steady-state-exact values."""
        L = self.params.L
        const = jnp.concatenate([self.kappa0, self.nu0[None]]) / L
        if not self.steady_state_gains:
            return const
        C0 = decay_rates(self.params, v_r)
        rolling = c > 0
        k = C0 * L / floor_transport(jnp.where(rolling, c, 1.0))
        # Steady profile z_i = v_ri (L/c) Z_i, Z_i = xi phi(k_i xi) = (1 - exp(-k_i xi))/k_i:
        # the gains depend only on its shape, so they are smooth through v_r = 0 while
        # rolling. With E_i = exp(-k_i xi), 1 - k_i Zbar_i = Ebar_i and G - k_y Zhat = Ehat:
        # no cancellation towards lock, where Zbar_i ~ 1/k_i (nodes graded to the layer).
        x, w = graded_nodes(self.load, k, _GL_X, _GL_W)
        wq = w * self.load.q(x)
        Z = x[:, None] * one_minus_exp_over(k[None, :] * x[:, None])  # (N, 2)
        E = jnp.exp(-k[None, :] * x[:, None])
        Zbar, Ebar = wq @ Z, wq @ E
        Zhat, Ehat = (wq * x) @ Z[:, 1], (wq * x) @ E[:, 1]
        kap = Ebar / (L * Zbar)
        nu = (Ehat + Zbar[1]) / (L * Zhat)
        kap = jnp.where(rolling, kap, const[:2])
        nu = jnp.where(rolling, nu, const[2])
        return jnp.concatenate([kap, nu[None]])

    def derivative(self, state, v_r, c):
        C0 = decay_rates(self.params, v_r)
        k = self.gains(v_r, c)
        zb = state[:2]
        zb_dot = v_r - C0 * zb - k[:2] * c * zb
        zh_dot = (self.G * v_r[1] - C0[1] * state[2] - k[2] * c * state[2]
                  + c / self.params.L * zb[1])
        return jnp.concatenate([zb_dot, zh_dot[None]])

    def mu(self, state, v_r, c):
        r"""$(F_x/F_n, F_y/F_n, M_z/(F_nL))$ (eqs. 36, 38)."""
        p = self.params
        d = self.derivative(state, v_r, c)
        f = p.sigma0 * state[:2] + p.sigma1 * d[:2] + p.sigma2 * v_r
        mz = (p.sigma0[1] * (0.5 * state[1] - state[2]) + p.sigma1[1] * (0.5 * d[1] - d[2])
              + p.sigma2[1] * v_r[1] * (0.5 - self.G))
        return jnp.stack([f[0], f[1], mz])

