r"""Initial guesses for the maneuver problems: a constant-speed run along the road's
centreline, the point-mass optimum, and that optimum mapped to the reduced half-car.

The car problems have several local optima and start badly from the centreline; the
point-mass problem ($|a| \le D g$) solves easily from it, and its path and speed carry over
to the car: heading along the velocity, kinematic steering $\delta = \arctan(L r / V)$, and
slips that realise the tangential acceleration on the tire's curve (inverted Magic Formula).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ..vehicle.reduced import ReducedHalfCar
from .ip import IPOptions, interior_point
from .roads import Road
from .shooting import DELTA_MAX, PointMassOCP


def centreline_guess(road: Road, num_stages: int, speed: float = 5.0):
    """Point-mass knots (x, y, vx, vy, t_f) at constant ``speed`` along the centreline, and
    the accelerations (M, 2) that turn the velocity from knot to knot."""
    pts = np.asarray(road.centreline, float)
    seg = np.hypot(*np.diff(pts, axis=0).T)
    s_knots = np.concatenate([[0.0], np.cumsum(seg)])
    length = s_knots[-1]
    s = np.linspace(0.0, length, num_stages + 1)
    x = np.interp(s, s_knots, pts[:, 0])
    y = np.interp(s, s_knots, pts[:, 1])
    i = np.clip(np.searchsorted(s_knots, s, side="right") - 1, 0, len(seg) - 1)
    d = np.diff(pts, axis=0) / seg[:, None]
    vx, vy = speed * d[i, 0], speed * d[i, 1]
    tf = np.full_like(s, length / speed)
    xs = np.stack([x, y, vx, vy, tf], 1)
    h = tf[0] / num_stages
    us = np.diff(xs[:, 2:4], axis=0) / h
    us = np.concatenate([us[1:], us[-1:]], 0) * 0.5 + us * 0.5
    return jax.device_put(xs), jax.device_put(us)  # jnp.asarray would run a copy program


def point_mass_guess_from_car(car: ReducedHalfCar, car_xs, friction: float):
    """Point-mass knots (x, y, vx, vy, t_f) and accelerations (M, 2) of a car's knots
    (x, y, psi, v_x, v_y, r, kappa_F, kappa_R, delta, t_f): the same positions and final
    time, the body velocity turned into the ground frame, and the car's own accelerations
    at the knots (from `car.f`, eqs. 61-63), averaged over each stage and kept within
    99 % of ``friction`` g. The car's path is feasible for the point mass (its friction ellipse
    lies inside the friction circle); a start on it lets the bound's solve find an optimum
    below the car's where the centreline starts do not."""
    xs = np.asarray(car_xs, float)
    body = np.asarray(jax.vmap(car.f)(jnp.asarray(xs[:, :6]), jnp.asarray(xs[:, 6:9])))
    psi, vx, vy, r = xs[:, 2], xs[:, 3], xs[:, 4], xs[:, 5]
    ax, ay = body[:, 3] - r * vy, body[:, 4] + r * vx
    c, s = np.cos(psi), np.sin(psi)
    acc = np.stack([c * ax - s * ay, s * ax + c * ay], 1)
    pm = np.stack([xs[:, 0], xs[:, 1], c * vx - s * vy, s * vx + c * vy, xs[:, -1]], 1)
    a = 0.5 * (acc[:-1] + acc[1:])
    limit = 0.99 * friction * float(car.params.g)
    a *= np.minimum(1.0, limit / np.maximum(np.hypot(*a.T), 1e-300))[:, None]
    return jax.device_put(pm), jax.device_put(a)


def car_guess_from_point_mass(car: ReducedHalfCar, road: Road, pm_xs, pm_us):
    """Map a point-mass trajectory to car knots (10 states) and input rates (3): speed at
    least 2 m/s, heading along the velocity from the start set's heading, steering from the
    yaw rate (within 90 % of its bound), and equal front and rear slips giving the tangential
    acceleration (within 80 % of the peak friction)."""
    pm_xs, pm_us = np.asarray(pm_xs), np.asarray(pm_us)
    M = pm_us.shape[0]
    tf = float(pm_xs[0, 4])
    vxi, vyi = pm_xs[:, 2], pm_xs[:, 3]
    V = np.maximum(np.hypot(vxi, vyi), 2.0)
    theta = np.unwrap(np.arctan2(vyi, vxi))
    psi0 = dict(road.start.fixed)["psi"]
    psi = psi0 + theta - theta[0]
    tau = np.linspace(0, 1, M + 1)
    r = np.gradient(psi, tau) / tf
    p = car.params
    wheelbase = float(p.lF + p.lR)
    delta = np.clip(np.arctan(wheelbase * r / V), -0.9 * DELTA_MAX, 0.9 * DELTA_MAX)
    a = np.concatenate([pm_us, pm_us[-1:]], 0)
    a_t = (a[:, 0] * vxi + a[:, 1] * vyi) / V
    Dmu = float(car.tire.D)
    mux = np.clip(a_t / float(p.g), -0.8 * Dmu, 0.8 * Dmu)
    s = np.tan(np.arcsin(np.abs(mux) / Dmu) / float(car.tire.C)) / float(car.tire.B)
    sx = -np.sign(mux) * s
    kappa = -sx / (1.0 + sx)
    xs = np.stack([pm_xs[:, 0], pm_xs[:, 1], psi, V, 0 * V, r, kappa, kappa, delta,
                   np.full_like(V, tf)], 1)
    us = np.diff(xs[:, 6:9], axis=0) * M
    return jax.device_put(xs), jax.device_put(us)  # jnp.asarray would run a copy program


def car_guess(car: ReducedHalfCar, road: Road, num_stages: int, steps_per_stage: int = 1,
              margin: float = 0.5, friction_fraction: float = 0.6,
              solver: Callable = interior_point, corner_clearance: bool = True,
              interior_points: int = 0):
    """A comfortable starting guess for the car: the min-time point mass in a corridor shrunk
    by ``margin`` [m] with ``friction_fraction`` of the tire's peak friction (so that the
    car's corridor, friction and speed-floor constraints all have slack), solved by
    ``solver`` (`interior_point`) and mapped to car states and inputs by
    `car_guess_from_point_mass`; ``corner_clearance``, ``interior_points``: the point mass's
    corridor between the nodes (`PointMassOCP`)."""
    prob = PointMassOCP(road=road, friction=friction_fraction * float(car.tire.D),
                        num_stages=num_stages, steps_per_stage=steps_per_stage, margin=margin,
                        corner_clearance=corner_clearance, interior_points=interior_points)
    xs0, us0 = centreline_guess(road, num_stages, 4.0)
    pm = solver(prob, xs0, us0, IPOptions(), throw=False)
    return car_guess_from_point_mass(car, road, pm.xs, pm.us)
