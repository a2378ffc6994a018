r"""The physical limit of a braking (and of a traction run): the stopping distance if the tire
delivered the peak of its steady-state curve at every instant.

A point mass $m$ on the normal load $F_n$ decelerating at $\mu^*(v)F_n/m$, with
$\mu^*(v)$ the peak of the true surface's curve at the current speed (`peak_braking`, the
code the estimate-based controller aims with). Taking the speed as the variable,
$$x(v) = \int_v^{v_0}\frac{mu}{\mu^*(u)F_n}du,\qquad t(v) = \int_v^{v_0}\frac{m}{\mu^*(u)F_n}du,$$
by composite Gauss-Legendre quadrature down to `STOP_SPEED` (jitted). With a surface change the first
surface acts down to the speed $v_c$ at which $x(v_c)$ reaches the change's distance (or
$t(v_c)$ its time), found by bisection, and the second from there.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._constants import GRAVITY
from .loop import STOP_SPEED
from .peak import peak_braking, peak_driving
from .plant import BrakingScenario


_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(12)
_PANELS = 16
_BISECTIONS = 48


def _integrals(tire, car, v_lo, v_hi):
    """$(x, t)$ of the point mass braking from `v_hi` to `v_lo` on `tire`."""
    edges = jnp.linspace(0.0, 1.0, _PANELS + 1)
    a, b = edges[:-1, None], edges[1:, None]
    u = (0.5 * (b - a) * jnp.asarray(_NODES)[None] + 0.5 * (a + b)).ravel()
    w = (0.5 * (b - a) * jnp.asarray(_WEIGHTS)[None]).ravel()
    speeds = v_lo + (v_hi - v_lo) * u
    mu = jax.vmap(lambda v: peak_braking(tire, v, car.radius)[1])(speeds)
    dtdv = car.mass / (mu * car.Fn_static)
    scale = v_hi - v_lo
    return scale * jnp.sum(w * dtdv * speeds), scale * jnp.sum(w * dtdv)


@eqx.filter_jit
def physical_limit(scenario: BrakingScenario, stop_speed: float = STOP_SPEED):
    r"""``(bound_distance, bound_time)`` [m, s] of `scenario` (module docstring)."""
    car, change = scenario.car, scenario.change
    v0 = scenario.speed
    v_stop = jnp.asarray(stop_speed, dtype=v0.dtype)
    x1, t1 = _integrals(car.tire, car, v_stop, v0)
    reached = (x1 > change.distance) | (t1 > change.time)

    def exceeds(v):  # the first surface alone reaches the change before speed v
        x, t = _integrals(car.tire, car, v, v0)
        return (x > change.distance) | (t > change.time)

    def bisect(i, bracket):
        lo, hi = bracket  # exceeds(lo) is True, exceeds(hi) is False
        mid = 0.5 * (lo + hi)
        e = exceeds(mid)
        return jnp.where(e, mid, lo), jnp.where(e, hi, mid)

    lo, hi = jax.lax.fori_loop(0, _BISECTIONS, bisect, (v_stop, v0))
    v_c = jnp.where(reached, 0.5 * (lo + hi), v_stop)
    xa, ta = _integrals(car.tire, car, v_c, v0)
    xb, tb = _integrals(change.tire, car, v_stop, v_c)
    xb, tb = jnp.where(reached, xb, 0.0), jnp.where(reached, tb, 0.0)
    return xa + xb, ta + tb


def _driving_time(tire, car, v_lo, v_hi):
    """Time for the point mass to accelerate from `v_lo` to `v_hi` at the driving peak."""
    edges = jnp.linspace(0.0, 1.0, _PANELS + 1)
    a, b = edges[:-1, None], edges[1:, None]
    u = (0.5 * (b - a) * jnp.asarray(_NODES)[None] + 0.5 * (a + b)).ravel()
    w = (0.5 * (b - a) * jnp.asarray(_WEIGHTS)[None]).ravel()
    speeds = v_lo + (v_hi - v_lo) * u
    mu = jax.vmap(lambda v: peak_driving(tire, v)[1])(speeds)
    return (v_hi - v_lo) * jnp.sum(w * car.mass / (mu * car.Fn_static))


@eqx.filter_jit
def traction_limit(scenario: BrakingScenario, duration):
    r"""The speed [m/s] a point mass reaches from the scenario's speed after `duration` [s]
    if the tire delivered the peak of its driving curve (eq. 18, `peak_driving`) at every
    instant: the speed $v$ at which $\int_{v_0}^v m\,du/(\mu^*(u)F_n)$ = `duration`, by
    bisection (no surface change)."""
    car, v0 = scenario.car, scenario.speed
    v_max = v0 + 1.5 * GRAVITY * duration  # mu* < 1.5 on every named surface

    def bisect(i, bracket):
        lo, hi = bracket
        mid = 0.5 * (lo + hi)
        late = _driving_time(car.tire, car, v0, mid) > duration
        return jnp.where(late, lo, mid), jnp.where(late, mid, hi)

    lo, hi = jax.lax.fori_loop(0, _BISECTIONS, bisect, (v0, v_max))
    return 0.5 * (lo + hi)
