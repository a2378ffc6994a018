r"""Steady-state closed forms of the distributed longitudinal LuGre model (eqs. 15-19).

With $\xi = \zeta/L$, $c = |\omega r|$ and $k = \theta\sigma_0|v_r|L/(g(v_r)\,c)$, eq. 15 reads
$$z_{ss}(\xi) = \operatorname{sgn}(v_r)\frac{g}{\theta\sigma_0}\bigl(1-e^{-k\xi}\bigr)
             = \frac{v_r L}{c}\,\xi\,\varphi(k\xi),\qquad \varphi(x) = \frac{1-e^{-x}}{x}.$$
The second form is smooth through $v_r = 0$ and is what we evaluate while the wheel rolls;
for a locked wheel ($c = 0$) the profile is the point-model value $\operatorname{sgn}(v_r)g/(\theta\sigma_0)$
(report remark after eq. 16).

The closed forms are pure elementwise functions for use under ``jit``, ``vmap`` and ``grad``:
they check nothing, and a NaN slip, speed or radius gives a NaN force (the modules that
hold the parameters check them when they are built).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._math import floor_transport, one_minus_exp_over, safe_abs
from .load import AbstractLoadDistribution
from .lugre import LuGreParams, relative_velocity, stribeck


_GL_X, _GL_W = np.polynomial.legendre.leggauss(48)


def _psi(x):
    """(x - 1 + exp(-x)) / x**2 for x >= 0 (= 1/2 at 0), so that 1 - phi(x) = x psi(x)."""
    small = x < 1e-3
    xs = jnp.where(small, jnp.ones_like(x), x)
    exact = (xs + jnp.expm1(-xs)) / (xs * xs)
    series = 0.5 - x / 6.0 + x * x / 24.0 - x * x * x / 120.0
    return jnp.where(small, series, exact)


def _rolling_terms(params: LuGreParams, v, omega, r):
    v_r = relative_velocity(v, omega, r)
    g = stribeck(params, v_r)
    c = safe_abs(omega * r)
    rolling = c > 0
    c_safe = floor_transport(jnp.where(rolling, c, 1.0))
    k = params.theta * params.sigma0 * safe_abs(v_r) * params.L / (g * c_safe)
    return v_r, g, c_safe, rolling, k


def _near_lock(v_r, g, c, k, params):
    r"""$v_rL/c$ and, for $k > 1$ (towards lock, where $v_rL/c \to \infty$ while the
    profile's $\xi\phi(k\xi) \sim 1/k$), the same product regrouped as
    $g\,\mathrm{sgn}(v_r)/(\theta\sigma_0)$ times $k\xi\phi(k\xi) = 1 - e^{-k\xi}$: the
    values agree, and the derivatives stay exact as $|\omega r| \to 0$."""
    large = k > 1.0
    scale_small = v_r * params.L / c
    scale_large = jnp.sign(v_r) * g / (params.theta * params.sigma0)
    return large, scale_small, scale_large


def z_ss(params: LuGreParams, zeta, v, omega, r):
    r"""Steady-state deflection profile $z_{ss}(\zeta)$ (eqs. 15-16) [m]."""
    v_r, g, c, rolling, k = _rolling_terms(params, v, omega, r)
    xi = zeta / params.L
    large, small_scale, large_scale = _near_lock(v_r, g, c, k, params)
    z_roll = jnp.where(large, large_scale * -jnp.expm1(-k * xi),
                       small_scale * xi * one_minus_exp_over(k * xi))
    z_lock = jnp.sign(v_r) * g / (params.theta * params.sigma0)
    return jnp.where(rolling, z_roll, z_lock)


def graded_edges(load: AbstractLoadDistribution, *ks):
    """Sorted panel edges on [0, 1]: the load's kinks and, for each boundary-layer rate
    `k`, the edges 40/k, 4/k and 0.4/k of its layer (thickness 1/k, at the leading edge)."""
    edges = [jnp.zeros(()), jnp.ones(())]
    edges += list(load.kinks())
    for k in ks:
        layer = jnp.minimum(1.0, 40.0 / jnp.maximum(k, 1e-30))
        edges += [layer, 0.1 * layer, 0.01 * layer]
    return jnp.sort(jnp.stack([jnp.asarray(e, dtype=float) for e in edges]))


def steady_state_mu(params: LuGreParams, load: AbstractLoadDistribution, v, omega, r):
    r"""Steady-state normalised force $F_{ss}/F_n$ for any load density (eq. 17).

    $$\frac{F_{ss}}{F_n} = \sigma_0\int_0^1 z_{ss}(\xi)\,q(\xi)\,d\xi + \sigma_2 v_r,$$
    by Gauss-Legendre quadrature on panels graded to the boundary layer of thickness $1/k$
    at the leading edge and split at the load's kinks, so that the layer is resolved at any
    slip.
    """
    v_r, g, c, rolling, k = _rolling_terms(params, v, omega, r)
    edges = graded_edges(load, k)
    a, b = edges[:-1, None], edges[1:, None]
    xi = 0.5 * (b - a) * jnp.asarray(_GL_X)[None, :] + 0.5 * (a + b)
    w = 0.5 * (b - a) * jnp.asarray(_GL_W)[None, :]
    # K = int_0^1 xi phi(k xi) q(xi) dxi ; z_ss = v_r L / c * xi phi(k xi); towards lock
    # (k > 1) the same as g sgn(v_r) / (theta sigma0) * int (1 - exp(-k xi)) q (`_near_lock`)
    large, small_scale, large_scale = _near_lock(v_r, g, c, k, params)
    q = load.q(xi)
    K = jnp.sum(w * xi * one_minus_exp_over(k * xi) * q)
    kK = jnp.sum(w * -jnp.expm1(-k * xi) * q)
    mu_roll = params.sigma0 * jnp.where(large, large_scale * kK, small_scale * K)
    mu_lock = jnp.sign(v_r) * g / params.theta
    return jnp.where(rolling, mu_roll, mu_lock) + params.sigma2 * v_r


def driving_mu_uniform(params: LuGreParams, s, omega, r):
    r"""Driving steady state, uniform load (eq. 18), $s = 1 - v/(r\omega)$, $\omega > 0$ fixed.

    $$\frac{F_d}{F_n} = \operatorname{sgn}(v_r)\frac{g}{\theta}\Bigl(1+\frac{g}{\theta\sigma_0L|s|}
    \bigl(e^{-\theta\sigma_0L|s|/g}-1\bigr)\Bigr) + \sigma_2 r\omega s,$$
    evaluated as $\sigma_0 L s\,\psi(x)$, $x=\theta\sigma_0L|s|/g$, $\psi(x)=(x-1+e^{-x})/x^2$,
    which is the same number and smooth at $s = 0$.
    """
    p = params
    v_r = r * omega * s
    g = stribeck(p, v_r)
    x = p.theta * p.sigma0 * p.L * safe_abs(s) / g
    return p.sigma0 * p.L * s * _psi(x) + p.sigma2 * v_r


def braking_mu_uniform(params: LuGreParams, s, v):
    r"""Braking steady state, uniform load (eq. 19), $s = r\omega/v - 1\in[-1, 0]$, $v > 0$ fixed.

    $$\frac{F_b}{F_n} = \operatorname{sgn}(v_r)\frac{g}{\theta}\Bigl(1+\frac{g|1+s|}{\theta\sigma_0L|s|}
    \bigl(e^{-\theta\sigma_0L|s|/(g|1+s|)}-1\bigr)\Bigr) + \sigma_2 v s,$$
    with $g = g(vs)$. At $s=-1$ (locked wheel) it equals the point model, $-g/\theta - \sigma_2 v$.
    Evaluated as $\sigma_0 L s\,\psi(x)/|1+s|$, $x = \theta\sigma_0L|s|/(g|1+s|)$, and for
    $x > 1$ (towards lock) as the same number regrouped, $\operatorname{sgn}(s)(g/\theta)
    (1 + (e^{-x} - 1)/x)$, whose derivatives stay exact as $1 + s \to 0$ (the first form
    divides by $|1+s|$ what $\psi$ makes small: a cancellation). At exactly $s = -1$, the
    kink of $|1+s|$, the derivative is the mean of the two one-sided ones, as $|x|$'s is 0 at 0.
    """
    p = params
    v_r = v * s
    g = stribeck(p, v_r)
    one_s = safe_abs(1.0 + s)
    locked = one_s == 0
    one_s_safe = jnp.where(locked, 1.0, one_s)
    x = p.theta * p.sigma0 * p.L * safe_abs(s) / (g * one_s_safe)
    large = x > 1.0
    x_large = jnp.where(large, x, 2.0)
    rolling = jnp.where(large,
                        jnp.sign(s) * g / p.theta * (1.0 + jnp.expm1(-x_large) / x_large),
                        p.sigma0 * p.L * s / one_s_safe * _psi(jnp.where(large, 0.5, x)))
    return jnp.where(locked, jnp.sign(s) * g / p.theta, rolling) + p.sigma2 * v_r
