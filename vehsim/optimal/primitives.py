r"""Optimal driving primitives (report section 2.5, Fig. 20): minimum-time and maximum-exit-
speed maneuvers of the reduced half-car (eqs. 61-63) on the benchmark roads.

Pipeline: a constant-speed guess along the road's centreline -> the point-mass problem
($|a| \le Dg$, the spec's lower bound) -> its path and speed mapped to the car (heading along
the velocity, kinematic steering, slips from the tangential acceleration) -> the car problem,
all solved by the structured interior-point method of `vehsim.optimal.nlp`.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..tire.friction_ellipse import FrictionEllipseTire, rally_gravel_tire
from ..vehicle.params import rally_gravel
from ..vehicle.reduced import ReducedHalfCar
from .nlp import IPOptions, IPSolution, interior_point
from .roads import Road, road as road_by_name
from .shooting import DELTA_MAX, IDX_TF, ManeuverOCP, PointMassOCP


def rally_gravel_car(D=0.52) -> ReducedHalfCar:
    """The spec's vehicle: rally-gravel half-car with the friction-ellipse tire (peak ``D``)."""
    tire = rally_gravel_tire()
    if D is not None:
        tire = FrictionEllipseTire(B=tire.B, C=tire.C, D=D)
    return ReducedHalfCar(params=rally_gravel(), tire=tire)


def _road(road: str | Road) -> Road:
    return road_by_name(road) if isinstance(road, str) else road


def centreline_guess(road: Road, num_stages: int, speed: float = 5.0):
    """Point-mass knots (x, y, vx, vy, t_f) at constant ``speed`` along the centreline."""
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
    # accelerations that turn the velocity from knot to knot (a consistent start)
    h = tf[0] / num_stages
    us = np.diff(xs[:, 2:4], axis=0) / h
    us = np.concatenate([us[1:], us[-1:]], 0) * 0.5 + us * 0.5
    return jnp.asarray(xs), jnp.asarray(us)


def car_guess_from_point_mass(car: ReducedHalfCar, road: Road, pm_xs, pm_us):
    """Map a point-mass trajectory to car knots (10 states) and input rates (3)."""
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
    return jnp.asarray(xs), jnp.asarray(us)


class Primitive(eqx.Module):
    """A solved maneuver: ``problem``, the interior-point ``solution``, and convenience
    fields ``t_f`` [s], ``exit_speed`` [m/s] and ``status``."""

    problem: Any
    solution: IPSolution

    @property
    def t_f(self):
        return self.solution.xs[-1, IDX_TF]

    @property
    def exit_speed(self):
        x = self.solution.xs[-1]
        return jnp.hypot(x[3], x[4])

    @property
    def status(self):
        return self.solution.status

    def nodes(self):
        return self.problem.nodes(self.solution.xs, self.solution.us)


def point_mass_bound(road: str | Road, objective: str = "min-time", *, D: float = 0.52,
                     num_stages: int = 50, steps_per_stage: int = 3, tf_max: float = 4.0,
                     options: IPOptions = IPOptions(), throw: bool = True):
    """The spec's lower bound on t_f (upper bound on the exit speed): point mass, |a| <= D g."""
    rd = _road(road)
    prob = PointMassOCP(road=rd, friction=D, objective=objective, tf_max=tf_max,
                        num_stages=num_stages, steps_per_stage=steps_per_stage)
    best = None
    for speed in (4.0, 7.0):
        xs0, us0 = centreline_guess(rd, num_stages, speed)
        sol = interior_point(prob, xs0, us0, options, throw=False)
        if best is None or (int(sol.status) == 0 and (
                int(best.status) != 0 or float(sol.objective) < float(best.objective))):
            best = sol
    if throw and int(best.status) != 0:
        interior_point(prob, xs0, us0, options, throw=True)
    return Primitive(problem=prob, solution=best)


def _solve_car(road, objective, car, num_stages, steps_per_stage, tf_max, options, throw,
               guess=None, rate_weight=1e-5):
    rd = _road(road)
    prob = ManeuverOCP(vehicle=car, road=rd, objective=objective, tf_max=tf_max,
                       num_stages=num_stages, steps_per_stage=steps_per_stage,
                       rate_weight=rate_weight)
    if guess is None:
        pm = point_mass_bound(rd, "min-time", D=float(car.tire.D), num_stages=num_stages,
                              steps_per_stage=steps_per_stage, options=IPOptions(), throw=False)
        xs0, us0 = car_guess_from_point_mass(car, rd, pm.solution.xs, pm.solution.us)
        if objective == "max-exit":
            xs0 = xs0.at[:, IDX_TF].set(jnp.minimum(xs0[:, IDX_TF], 0.98 * tf_max))
    else:
        xs0, us0 = guess
    sol = interior_point(prob, xs0, us0, options, throw=throw)
    return Primitive(problem=prob, solution=sol)


def min_time_primitive(road: str | Road = "corner90", *, car: ReducedHalfCar | None = None,
                       num_stages: int = 50, steps_per_stage: int = 3,
                       options: IPOptions = IPOptions(max_iter=500), guess=None,
                       throw: bool = True) -> Primitive:
    """Minimum-time maneuver through ``road`` (Table 4 boundary conditions, free t_f).

    **Arguments:** ``road`` (name or `Road`), ``car`` (default `rally_gravel_car()`),
    discretisation ``num_stages`` x ``steps_per_stage`` (nodes; the spec asks >= 150),
    ``options``, an optional ``guess`` (xs, us), ``throw``.

    **Returns:** a `Primitive`.
    """
    car = rally_gravel_car() if car is None else car
    return _solve_car(road, "min-time", car, num_stages, steps_per_stage, 4.0, options, throw,
                      guess)


def max_exit_primitive(road: str | Road = "corner90", *, tf_max: float = 4.0,
                       car: ReducedHalfCar | None = None, num_stages: int = 50,
                       steps_per_stage: int = 3, options: IPOptions = IPOptions(max_iter=500),
                       guess=None, throw: bool = True) -> Primitive:
    """Maximum exit speed through ``road`` with t_f <= ``tf_max`` (spec: 4.0 s on corner90)."""
    car = rally_gravel_car() if car is None else car
    return _solve_car(road, "max-exit", car, num_stages, steps_per_stage, tf_max, options,
                      throw, guess)


def log(msg: str) -> None:
    print(f"  {msg}", file=sys.stderr, flush=True)


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    jax.block_until_ready(out)
    return out, time.perf_counter() - t0
