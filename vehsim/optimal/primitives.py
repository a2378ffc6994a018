r"""Optimal driving primitives (report section 2.5, Fig. 20): minimum-time and maximum-exit-
speed maneuvers of the reduced half-car (eqs. 61-63) on the benchmark roads.

Pipeline: a constant-speed guess along the road's centreline -> the point-mass problem
($|a| \le Dg$, the spec's lower bound) -> its path and speed mapped to the car (heading along
the velocity, kinematic steering, slips from the tangential acceleration) -> the car problem,
all solved by the structured interior-point method of `vehsim.optimal.ip`.
"""

from __future__ import annotations

import sys
import time
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._results import result_name, result_record
from ..tire.friction_ellipse import FrictionEllipseTire, rally_gravel_tire
from ..vehicle.params import rally_gravel
from ..vehicle.reduced import ReducedHalfCar
from .ip import IPOptions, IPSolution, interior_point
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


def car_guess(car: ReducedHalfCar, road: Road, num_stages: int, steps_per_stage: int = 1,
              margin: float = 0.5, friction_fraction: float = 0.6):
    """A comfortable starting guess for the car: the min-time point mass in a corridor shrunk
    by ``margin`` with ``friction_fraction`` of the tire's peak friction (so the car's corridor,
    friction and speed-floor constraints all have slack), mapped to car states and inputs."""
    prob = PointMassOCP(road=road, friction=friction_fraction * float(car.tire.D),
                        num_stages=num_stages, steps_per_stage=steps_per_stage, margin=margin)
    xs0, us0 = centreline_guess(road, num_stages, 4.0)
    pm = interior_point(prob, xs0, us0, IPOptions(), throw=False)
    return car_guess_from_point_mass(car, road, pm.xs, pm.us)


class Primitive(eqx.Module):
    """A solved maneuver: ``problem``, the interior-point ``solution``, and convenience
    fields ``t_f`` [s], ``exit_speed`` [m/s] and ``result`` (`vehsim.RESULTS`)."""

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
    def result(self):
        return self.solution.result

    def nodes(self):
        """States at every integration node (M S + 1, nx), uniform in tau."""
        return self.problem.nodes(self.solution.xs, self.solution.us)

    def time(self):
        n = self.nodes()
        return jnp.linspace(0.0, 1.0, n.shape[0]) * self.t_f

    def signals(self) -> dict:
        """Named signals at every node (car problems): pose, speeds, sideslip, slips, forces."""
        n = self.nodes()
        sig = jax.vmap(self.problem.vehicle.signals)(n[:, :6], n[:, 6:9])
        return {k: np.asarray(v) for k, v in sig.items()}

    def violations(self) -> dict:
        """Constraint violations of the solution, measured exactly at every node: distance off
        the road (union of legs, not the smooth corridor) [m], boundary conditions (max abs,
        m/rad/(m/s)), input bounds, axle-speed floor [m/s], shooting defects."""
        prob, sol = self.problem, self.solution
        n = np.asarray(self.nodes())
        rd = prob.road
        off = rd.distance_off_road(n[:, 0], n[:, 1])
        bc = max(float(jnp.max(jnp.abs(prob.initial_equality(sol.xs[0])))),
                 float(jnp.max(jnp.abs(prob.terminal_equality(sol.xs[-1])))))
        box = [prob.road.boundary_inequality(rd.start, sol.xs[0]),
               prob.road.boundary_inequality(rd.end, sol.xs[-1])]
        bc = max(bc, float(max(jnp.max(jnp.maximum(-b, 0.0), initial=0.0) for b in box)))
        defects = np.asarray(sol.xs[1:]) - np.asarray(
            jax.vmap(prob.transition)(sol.xs[:-1], sol.us, jnp.arange(prob.num_stages)))
        out = dict(corridor=float(np.max(off)), boundary=bc,
                   defects=float(np.max(np.abs(defects))))
        if isinstance(prob, ManeuverOCP):
            kF, kR, d = n[:, 6], n[:, 7], n[:, 8]
            inp = np.concatenate([-0.99 - kF, kF - 1.0, -0.99 - kR, kR - 1.0,
                                  np.abs(d) - float(DELTA_MAX)])
            out["inputs"] = float(max(np.max(inp), 0.0))
            sig = self.signals()
            out["axle_speed_floor"] = float(max(0.0, 1.0 - min(sig["Vx_F"].min(),
                                                               sig["Vx_R"].min())))
            if prob.objective == "max-exit":
                out["time_budget"] = float(max(0.0, float(self.t_f - prob.tf_max)))
        return out


def _better(sol: IPSolution, best: IPSolution | None) -> bool:
    """A converged solution beats a failed one, then the lower objective wins."""
    return best is None or (
        bool(sol.converged)
        and (not bool(best.converged) or float(sol.objective) < float(best.objective))
    )


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
        if _better(sol, best):
            best = sol
    if throw and not bool(best.converged):
        interior_point(prob, xs0, us0, options, throw=True)
    return Primitive(problem=prob, solution=best)


DEFAULT_STARTS = ((0.5, 0.6),)
"""(corridor margin [m], friction fraction) of the point-mass problems that seed the car."""


def _solve_car(road, objective, car, num_stages, steps_per_stage, tf_max, options, throw,
               guess=None, rate_weight=1e-5, starts=DEFAULT_STARTS):
    rd = _road(road)
    prob = ManeuverOCP(vehicle=car, road=rd, objective=objective, tf_max=tf_max,
                       num_stages=num_stages, steps_per_stage=steps_per_stage,
                       rate_weight=rate_weight)
    guesses = []
    if guess is None:
        for margin, frac in starts:
            xs0, us0 = car_guess(car, rd, num_stages, steps_per_stage, margin=margin,
                                 friction_fraction=frac)
            if objective == "max-exit":
                xs0 = xs0.at[:, IDX_TF].set(jnp.minimum(xs0[:, IDX_TF], 0.98 * tf_max))
            guesses.append((xs0, us0))
    else:
        guesses.append(guess)
    best = None
    for xs0, us0 in guesses:
        sol = interior_point(prob, xs0, us0, options, throw=False)
        if _better(sol, best):
            best = sol
    if throw and not bool(best.converged):
        interior_point(prob, *guesses[-1], options, throw=True)  # raises with residuals
    return Primitive(problem=prob, solution=best)


def min_time_primitive(road: str | Road = "corner90", *, car: ReducedHalfCar | None = None,
                       num_stages: int = 50, steps_per_stage: int = 3,
                       options: IPOptions = IPOptions(max_iter=500), guess=None,
                       starts=DEFAULT_STARTS, throw: bool = True) -> Primitive:
    """Minimum-time maneuver through ``road`` (Table 4 boundary conditions, free t_f).

    **Arguments:** ``road`` (name or `Road`), ``car`` (default `rally_gravel_car()`),
    discretisation ``num_stages`` x ``steps_per_stage`` (nodes; the spec asks >= 150),
    ``options``, an optional ``guess`` (xs, us), ``starts``: several (margin, friction
    fraction) point-mass seeds, the best converged optimum is kept (the problems have
    several local optima), ``throw``.

    **Returns:** a `Primitive`.
    """
    car = rally_gravel_car() if car is None else car
    return _solve_car(road, "min-time", car, num_stages, steps_per_stage, 4.0, options, throw,
                      guess, starts=starts)


def max_exit_primitive(road: str | Road = "corner90", *, tf_max: float = 4.0,
                       car: ReducedHalfCar | None = None, num_stages: int = 50,
                       steps_per_stage: int = 3, options: IPOptions = IPOptions(max_iter=500),
                       guess=None, starts=DEFAULT_STARTS, throw: bool = True) -> Primitive:
    """Maximum exit speed through ``road`` with t_f <= ``tf_max`` (spec: 4.0 s on corner90)."""
    car = rally_gravel_car() if car is None else car
    return _solve_car(road, "max-exit", car, num_stages, steps_per_stage, tf_max, options,
                      throw, guess, starts=starts)


def solution_record(prim: Primitive, bound: Primitive | None = None) -> dict:
    """JSON-ready record of a solved primitive: t_f, exit_speed, ``status`` (the result's
    name) and ``message``, residuals,
    violations, the point-mass bound and its ratio, states and inputs at every node."""
    sol = prim.solution
    sig = prim.signals()
    rec = dict(
        road=prim.problem.road.name, objective=prim.problem.objective,
        t_f=float(prim.t_f), exit_speed=float(prim.exit_speed), **result_record(sol.result),
        iterations=int(sol.iterations),
        residuals=dict(inf_pr=float(sol.inf_pr), inf_du=float(sol.inf_du),
                       compl=float(sol.compl)),
        segments=prim.problem.num_stages, nodes=int(prim.nodes().shape[0]),
    )
    v = prim.violations()
    rec["violations"] = v
    rec["max_corridor_violation"] = v["corridor"]
    if bound is not None:
        rec["point_mass_t_f"] = float(bound.t_f)
        rec["point_mass_exit_speed"] = float(bound.exit_speed)
        rec["point_mass_status"] = result_name(bound.result)
        rec["t_f_over_bound"] = float(prim.t_f / bound.t_f)
    rec["t"] = np.asarray(prim.time())
    rec["states"] = {k: sig[k] for k in ("x", "y", "psi", "vx", "vy", "yaw_rate")}
    rec["inputs"] = {k: sig[k] for k in ("kappa_F", "kappa_R", "delta")}
    rec["signals"] = {k: sig[k] for k in ("speed", "sideslip", "Fz_F", "Fz_R", "Fx_F", "Fx_R",
                                          "Fy_F", "Fy_R", "Vx_F", "Vx_R")}
    return rec


def log(msg: str) -> None:
    print(f"  {msg}", file=sys.stderr, flush=True)


def timed(fn, *args, **kwargs):
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    jax.block_until_ready(out)
    return out, time.perf_counter() - t0


def batch_primitives(road: str | Road, frictions, objective: str = "min-time", *,
                     mode: str = "continuation", num_stages: int = 50,
                     steps_per_stage: int = 1, tf_max: float = 4.0,
                     options: IPOptions = IPOptions(max_iter=500)):
    """The same maneuver over a batch of road frictions D (the tire's peak coefficient).

    ``mode='vmap'``: one vmapped solve (every member iterates until the slowest converges;
    suited to accelerators). ``mode='continuation'``: sequential solves, each warm-started
    from its neighbour's solution (sort the frictions; usually fastest on CPU).
    Never raises on a member's failure: check ``result`` (per member).

    **Returns:** a `Primitive` whose problem and solution are batched along axis 0 (vmap), or
    a list of `Primitive` (continuation).
    """
    rd = _road(road)
    frictions = jnp.asarray(frictions, float)
    if mode not in ("vmap", "continuation"):
        raise ValueError(f"batch_primitives mode must be 'vmap' or 'continuation', got {mode!r}")
    car0 = rally_gravel_car(float(frictions[0]))
    prob0 = ManeuverOCP(vehicle=car0, road=rd, objective=objective, tf_max=tf_max,
                        num_stages=num_stages, steps_per_stage=steps_per_stage)
    xs0, us0 = car_guess(car0, rd, num_stages, steps_per_stage)
    if objective == "max-exit":
        xs0 = xs0.at[:, IDX_TF].set(jnp.minimum(xs0[:, IDX_TF], 0.98 * tf_max))
    if mode == "vmap":
        def one(D):
            prob = eqx.tree_at(lambda p: p.vehicle.tire.D, prob0, D)
            return interior_point(prob, xs0, us0, options, throw=False)

        sols = jax.vmap(one)(frictions)
        probs = eqx.tree_at(lambda p: p.vehicle.tire.D, prob0, frictions)
        return Primitive(problem=probs, solution=sols)
    out = []
    guess = (xs0, us0)
    warm = eqx.tree_at(lambda o: o.mu0, options, 1e-4)
    for i, D in enumerate(frictions):
        prob = eqx.tree_at(lambda p: p.vehicle.tire.D, prob0, D)
        sol = interior_point(prob, *guess, options if i == 0 else warm, throw=False)
        if bool(sol.converged):
            guess = (sol.xs, sol.us)
        out.append(Primitive(problem=prob, solution=sol))
    return out
