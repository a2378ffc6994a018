r"""The lumped LuGre tire whose steady state is eq. 19: the plant and the estimators' model.

The lumped model of eqs. 22-23 with $\kappa(t)$ of eq. 24 evaluated on the steady-state
deflection profile of a uniform load (eq. 15):
$$\dot{\bar z} = v_r - \frac{|\omega r|}{L\,\psi(k)}\bar z,\qquad
  F = (\sigma_0\bar z + \sigma_1\dot{\bar z} + \sigma_2v_r)F_n,\qquad
  k = \frac{\theta\sigma_0|v_r|L}{g(v_r)|\omega r|},\quad \psi(k) = \frac{k-1+e^{-k}}{k^2},$$
i.e. $\kappa_0 = 1/\psi(k) - k$ in eq. 25: 2 at small slip, 1 for a locked wheel (the range
the report gives). The mean of eq. 15 over a uniform patch is $\bar z_{ss} = v_rL\psi(k)/|\omega
r|$, so the steady state of this model is eq. 19 in braking and eq. 18 in driving exactly, and
the peak of its force-slip curve is the peak of eq. 19: the controllers' target and the
physical limit of `vehsim.control.road.bound` use the same curve the plant delivers. For a locked
wheel ($\omega = 0$) the decay is the point model's, $\theta\sigma_0|v_r|/g$ (report remark
after eq. 16).
"""

from __future__ import annotations

import jax.numpy as jnp

from .._math import floor_transport, safe_abs, safe_div
from .lugre import AbstractLongitudinalTire, LuGreParams, relative_velocity, stribeck
from .steady_state import braking_mu_uniform, driving_mu_uniform


def psi(x):
    r"""$\psi(x) = (x - 1 + e^{-x})/x^2$ for $x\ge0$ (1/2 at 0; a series below $10^{-3}$)."""
    small = x < 1e-3
    xs = jnp.where(small, jnp.ones_like(x), x)
    exact = (xs + jnp.expm1(-xs)) / (xs * xs)
    return jnp.where(small, 0.5 - x / 6.0 + x * x / 24.0 - x * x * x / 120.0, exact)


def _excess(k):
    r"""$1/\psi(k) - k = k(1 - e^{-k})/(k - 1 + e^{-k})$, between 2 (at 0) and 1 (as $k \to
    \infty$), in a form without cancellation at large $k$ (a series below $10^{-3}$)."""
    small = k < 1e-3
    ks = jnp.where(small, jnp.ones_like(k), k)
    em = jnp.expm1(-ks)
    return jnp.where(small, 1.0 / psi(k) - k, -em / (1.0 + em / ks))


def decay(params: LuGreParams, v, omega, r):
    r"""Total decay rate $|\omega r|/(L\psi(k))$ of $\bar z$ [1/s] (module docstring); the
    point model's $\theta\sigma_0|v_r|/g$ for a locked wheel. Evaluated as
    $\theta\sigma_0|v_r|/g + (|\omega r|/L)(1/\psi(k) - k)$, the same number, whose
    derivatives stay exact as the wheel nears lock ($k \sim 1/|\omega r|$ grows without
    bound; the quotient's lost all their digits below $|\omega r| \approx 10^{-12}$ m/s)."""
    p = params
    v_r = relative_velocity(v, omega, r)
    c = safe_abs(omega * r)
    rolling = c > 0
    c_safe = floor_transport(jnp.where(rolling, c, 1.0))
    sliding = p.theta * p.sigma0 * safe_abs(v_r) / stribeck(p, v_r)
    k = sliding * p.L / c_safe
    return sliding + jnp.where(rolling, c_safe / p.L * _excess(k), 0.0)


class UniformLumpedLuGre(AbstractLongitudinalTire):
    r"""Lumped LuGre (eqs. 22-23) with the steady-state $\kappa$ of a uniform load, so that
    its steady state is eq. 19 (braking) and eq. 18 (driving) exactly (module docstring).

    **Arguments:** `params`, a `LuGreParams` (the road condition is `params.theta`).
    """

    params: LuGreParams

    def init_state(self):
        return jnp.zeros(())

    def dynamics(self, state, v, omega, r):
        return relative_velocity(v, omega, r) - decay(self.params, v, omega, r) * state

    def mu(self, state, v, omega, r):
        p = self.params
        zdot = self.dynamics(state, v, omega, r)
        return p.sigma0 * state + p.sigma1 * zdot + p.sigma2 * relative_velocity(v, omega, r)

    def steady_state(self, v, omega, r):
        r"""$\bar z_{ss} = v_r L\psi(k)/|\omega r|$, i.e. $v_r$ over the decay rate (0 at
        rest)."""
        return safe_div(relative_velocity(v, omega, r), decay(self.params, v, omega, r))

    def braking_mu(self, s, v, r=None):
        r"""Steady-state $F/F_n$ at braking slip $s = r\omega/v - 1\in[-1, 0]$ (eq. 19; the
        radius does not enter)."""
        return braking_mu_uniform(self.params, s, v)

    def driving_mu(self, s, omega, r):
        r"""Steady-state $F/F_n$ at driving slip $s = 1 - v/(r\omega)\in[0, 1]$ (eq. 18)."""
        return driving_mu_uniform(self.params, s, omega, r)
