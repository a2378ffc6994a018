r"""The physical limit of a braking (and of a traction run): the stopping distance if the tire
delivered the peak of its steady-state curve at every instant.

A point mass $m$ on the normal load $F_n$ decelerating at $\mu^*(v)F_n/m$, with
$\mu^*(v)$ the peak of the true surface's curve at the current speed (`peak_braking`, the
code the estimate-based controller aims with). Taking the speed as the variable,
$$x(v) = \int_v^{v_0}\frac{mu}{\mu^*(u)F_n}du,\qquad t(v) = \int_v^{v_0}\frac{m}{\mu^*(u)F_n}du,$$
by composite Gauss-Legendre quadrature down to `STOP_SPEED` (jitted). With a surface change the first
surface acts down to the speed $v_c$ at which $x(v_c)$ reaches the change's distance (or
$t(v_c)$ its time), found by bisection, and the second from there.

`actuated_limit` is the same limit for a given `BrakeHardware`: the tire force is also
capped by the brake torque the actuator has built up since the onset under a full command,
$F \le T_b(t)/r$ (the wheel decelerates, so $rF = T_b + J\dot\omega < T_b$). Over the
first `ONSET` seconds the point mass is integrated in time (RK4, the actuator's delay, rate
limit and lag exactly as in the loop), from there by the quadrature with
$\mu^*(v)$ capped at $T_{max}/(rF_n)$. It is what no controller on that hardware can beat:
the realistic actuator takes about 50 ms to build the torque of dry asphalt's peak, and a
car reaching a change to ice 0.5 m/s faster than the instantaneous limit brakes tens of
metres longer on the ice.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._checks import check_nonnegative, check_order
from ..._constants import GRAVITY
from ..loop import STOP_SPEED
from ..plant.hardware import ActuatorState, BrakeHardware, actuator_target, brake_torque
from ..plant.quarter_car import BrakingScenario
from .peak import peak_braking, peak_driving


_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(12)
_PANELS = 16
_BISECTIONS = 48
ONSET = 0.25
"""Time [s] over which `actuated_limit` integrates the actuator's torque rise."""
_ONSET_SUBSTEPS = 4


def _speed_quadrature(v_lo, v_hi):
    """Nodes (speeds) and weights of the composite Gauss-Legendre rule on [`v_lo`, `v_hi`]
    (`_PANELS` panels)."""
    edges = jnp.linspace(0.0, 1.0, _PANELS + 1)
    a, b = edges[:-1, None], edges[1:, None]
    u = (0.5 * (b - a) * jnp.asarray(_NODES)[None] + 0.5 * (a + b)).ravel()
    w = (0.5 * (b - a) * jnp.asarray(_WEIGHTS)[None]).ravel()
    return v_lo + (v_hi - v_lo) * u, (v_hi - v_lo) * w


def _integrals(tire, car, v_lo, v_hi, cap=jnp.inf):
    """$(x, t)$ of the point mass braking from `v_hi` to `v_lo` on `tire` (friction
    coefficient at most `cap`)."""
    speeds, w = _speed_quadrature(v_lo, v_hi)
    mu = jax.vmap(lambda v: peak_braking(tire, v, car.radius)[1])(speeds)
    dtdv = car.mass / (jnp.minimum(mu, cap) * car.Fn_static)
    return jnp.sum(w * dtdv * speeds), jnp.sum(w * dtdv)


def _two_surfaces(scenario: BrakingScenario, v0, v_stop, distance, time, cap=jnp.inf):
    """$(x, t)$ from `v0` to `v_stop` on the first surface until the change's `distance`
    or `time` (counted from `v0`), on the second from there."""
    car, change = scenario.car, scenario.change
    x1, t1 = _integrals(car.tire, car, v_stop, v0, cap)
    reached = (x1 > distance) | (t1 > time)

    def exceeds(v):  # the first surface alone reaches the change before speed v
        x, t = _integrals(car.tire, car, v, v0, cap)
        return (x > distance) | (t > time)

    def bisect(i, bracket):
        lo, hi = bracket  # exceeds(lo) is True, exceeds(hi) is False
        mid = 0.5 * (lo + hi)
        e = exceeds(mid)
        return jnp.where(e, mid, lo), jnp.where(e, hi, mid)

    lo, hi = jax.lax.fori_loop(0, _BISECTIONS, bisect, (v_stop, v0))
    v_c = jnp.where(reached, 0.5 * (lo + hi), v_stop)
    xa, ta = _integrals(car.tire, car, v_c, v0, cap)
    xb, tb = _integrals(change.tire, car, v_stop, v_c, cap)
    xb, tb = jnp.where(reached, xb, 0.0), jnp.where(reached, tb, 0.0)
    return xa + xb, ta + tb


def _check_stop_speed(owner: str, scenario: BrakingScenario, stop_speed) -> None:
    check_nonnegative(owner, "stop_speed", stop_speed)
    check_order(owner, "stop_speed", stop_speed, "speed", scenario.speed)


def physical_limit(scenario: BrakingScenario, stop_speed: float = STOP_SPEED):
    r"""``(bound_distance, bound_time)`` [m, s] of `scenario` (module docstring; jitted);
    `stop_speed` [m/s] in [0, the scenario's speed]."""
    _check_stop_speed("physical_limit", scenario, stop_speed)
    return _physical_limit(scenario, stop_speed)


@eqx.filter_jit
def _physical_limit(scenario: BrakingScenario, stop_speed):
    v0 = scenario.speed
    v_stop = jnp.asarray(stop_speed, dtype=v0.dtype)
    return _two_surfaces(scenario, v0, v_stop, scenario.change.distance, scenario.change.time)


def _onset(scenario: BrakingScenario, hardware: BrakeHardware, n_samples: int, v_stop):
    """``(x, t, v)`` of the point mass after `n_samples` samples of the actuator's rise
    under a full command (time counted while the speed is above `v_stop`)."""
    car = scenario.car
    T = hardware.sample_time
    h = T / _ONSET_SUBSTEPS

    def sample(carry, k):
        act, x, v, t_moving = carry
        act, target = actuator_target(hardware, act, k, hardware.max_torque)

        def rates(tau, x, v):
            tire = scenario.tire_at(k * T + tau, x, v)
            mu = peak_braking(tire, jnp.maximum(v, v_stop), car.radius)[1]
            torque = jnp.maximum(brake_torque(hardware, act.torque, target, tau), 0.0)
            force = jnp.minimum(mu * car.Fn_static, torque / car.radius)
            return v, jnp.where(v > v_stop, -force / car.mass, 0.0)

        for i in range(_ONSET_SUBSTEPS):  # classical RK4 on (x, v)
            tau = i * h
            k1 = rates(tau, x, v)
            k2 = rates(tau + h / 2, x + h / 2 * k1[0], v + h / 2 * k1[1])
            k3 = rates(tau + h / 2, x + h / 2 * k2[0], v + h / 2 * k2[1])
            k4 = rates(tau + h, x + h * k3[0], v + h * k3[1])
            t_moving = t_moving + jnp.where(v > v_stop, h, 0.0)
            x = x + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            v = v + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        act = eqx.tree_at(lambda a: a.torque, act, brake_torque(hardware, act.torque, target, T))
        return (act, x, v, t_moving), None

    zero = jnp.zeros((), scenario.speed.dtype)
    (_, x, v, t), _ = jax.lax.scan(sample, (ActuatorState.init(), zero, scenario.speed, zero),
                                   jnp.arange(n_samples))
    return x, t, v


@eqx.filter_jit
def _actuated(scenario, hardware, n_samples, stop_speed):
    v_stop = jnp.asarray(stop_speed, dtype=scenario.speed.dtype)
    x1, t1, v1 = _onset(scenario, hardware, n_samples, v_stop)
    cap = hardware.max_torque / (scenario.car.radius * scenario.car.Fn_static)
    change = scenario.change
    x2, t2 = _two_surfaces(scenario, jnp.maximum(v1, v_stop), v_stop, change.distance - x1,
                           change.time - t1, cap)
    return x1 + x2, t1 + t2


def actuated_limit(scenario: BrakingScenario, hardware: BrakeHardware,
                   stop_speed: float = STOP_SPEED):
    r"""``(bound_distance, bound_time)`` [m, s] of `scenario` on `hardware`: the physical
    limit with the tire force also capped by the brake torque the actuator builds under a
    full command from the onset (module docstring). Jitted; the onset's length in samples,
    `ONSET` / `hardware.sample_time`, is static. `stop_speed` [m/s] in [0, the scenario's
    speed]."""
    _check_stop_speed("actuated_limit", scenario, stop_speed)
    n_samples = max(1, math.ceil(ONSET / float(hardware.sample_time)))
    return _actuated(scenario, hardware, n_samples, stop_speed)


def _driving_time(tire, car, v_lo, v_hi):
    """Time for the point mass to accelerate from `v_lo` to `v_hi` at the driving peak."""
    speeds, w = _speed_quadrature(v_lo, v_hi)
    mu = jax.vmap(lambda v: peak_driving(tire, v, r=car.radius)[1])(speeds)
    return jnp.sum(w * car.mass / (mu * car.Fn_static))


@eqx.filter_jit
def traction_limit(scenario: BrakingScenario, duration):
    r"""The speed [m/s] a point mass reaches from the scenario's speed after `duration` [s]
    if the tire (any tire) delivered the peak of its driving curve (`peak_driving`; eq. 18
    for `UniformLumpedLuGre`) at every
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
