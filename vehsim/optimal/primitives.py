r"""Optimal driving primitives (report section 2.5, Fig. 20): minimum-time and maximum-exit-
speed maneuvers of the reduced half-car (eqs. 61-63) on the benchmark roads
(docs/maneuvers.md).

Pipeline: a constant-speed guess along the road's centreline -> the point-mass problem
($|a| \le Dg$, the benchmark's lower bound) -> its path and speed mapped to the car
(`vehsim.optimal.guesses`) -> the car problem, all solved by the structured interior-point
method (`vehsim.optimal.ip`). The problems have several local optima: several point-mass
seeds can be tried, and the best converged optimum is kept.

Every interior-point solve goes through ``solver`` (default `interior_point`; any function
with its signature): the functions here are plain compositions of jitted programs, and how a
program is compiled, cached or overlapped with other work is the caller's choice.
"""

from __future__ import annotations

import operator
import sys
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._checks import check_count, is_count, require_float64
from .._results import result_name
from ..sharding import pad_members, sharded_vmap
from ..tire.friction_ellipse import FrictionEllipseTire, rally_gravel_tire
from ..vehicle.params import rally_gravel
from ..vehicle.reduced import ReducedHalfCar
from .guesses import (
    car_guess,
    car_guess_from_point_mass,
    centreline_guess,
    point_mass_guess_from_car,
)
from .ip import IPOptions, IPSolution, interior_point
from .ip.solver import canonical_options, print_iteration_log
from .primitive import Primitive
from .roads import Road, road as road_by_name
from .shooting import IDX_TF, ManeuverOCP, PointMassOCP


DEFAULT_STARTS = ((0.5, 0.6),)
"""(corridor margin [m], friction fraction) of the point-mass problems that seed the car."""
MULTISTART_SEEDS = ((0.5, 0.6), (0.3, 0.8), (0.8, 0.5), (0.5, 0.4), (0.2, 0.6), (0.6, 0.7))
"""Point-mass seeds of ``starts=N``, in order (the default first); after as many of them as
N allows, every other start is the centreline at a constant speed (`CENTRELINE_SPEEDS`)."""
CENTRELINE_SPEEDS = (5.0, 8.0, 3.5, 6.5, 10.0)
"""Speeds [m/s] of the centreline starts of ``starts=N``, in order."""
MAX_EXIT_MU0 = 0.01
"""Initial barrier $\\mu_0$ of max-exit solves from point-mass seeds (min-time keeps
`IPOptions`' 0.1): from a seed near the optimum the smaller start converges in fewer
iterations and more reliably; from the centreline runs of a multi-start it takes longer,
so ``starts=N`` keeps 0.1 (both measured in docs/performance.md)."""


def _check_objective(objective: str) -> None:
    if objective not in ("min-time", "max-exit"):
        raise ValueError(f"objective must be 'min-time' or 'max-exit', got {objective!r}")


def primitive_options(objective: str = "min-time", starts=None, **changes) -> IPOptions:
    """The interior-point settings of the primitives: ``max_iter=500``, and for max-exit
    from point-mass seeds (``starts`` a sequence of seeds, None or 1) the initial barrier
    `MAX_EXIT_MU0`; an int ``starts`` > 1 (a multi-start with centreline runs) keeps
    ``mu0 = 0.1``. Keyword ``changes`` override any field."""
    _check_objective(objective)
    multistart = is_count(starts) and operator.index(starts) > 1
    settings = dict(max_iter=500)
    if objective == "max-exit" and not multistart:
        settings["mu0"] = MAX_EXIT_MU0
    return IPOptions(**{**settings, **changes})


def rally_gravel_car(D=0.52) -> ReducedHalfCar:
    """The benchmark vehicle (docs/maneuvers.md): rally-gravel reduced half-car with the
    friction-ellipse tire of peak ``D``."""
    tire = rally_gravel_tire()
    if D is not None:
        tire = FrictionEllipseTire(B=tire.B, C=tire.C, D=D)
    return ReducedHalfCar(params=rally_gravel(), tire=tire)


def _road(road: str | Road) -> Road:
    return road_by_name(road) if isinstance(road, str) else road


def _within_budget(xs0, tf_max):
    """Guess knots with t_f at most 98 % of the max-exit time budget (knots on the last
    axis; any leading batch axes)."""
    return xs0.at[..., IDX_TF].set(jnp.minimum(xs0[..., IDX_TF], 0.98 * tf_max))


_FLOAT32 = ("In float32 the solves run to their iteration limit far from the optimum "
            "(corner90 at 40 stages: 500 iterations, t_f 7.01 s against 3.62 s)")


def _better(sol: IPSolution, best: IPSolution | None) -> bool:
    """A converged solution beats a failed one, then the lower objective wins."""
    return best is None or (
        bool(sol.converged)
        and (not bool(best.converged) or float(sol.objective) < float(best.objective))
    )


def point_mass_bound(road: str | Road, objective: str = "min-time", *, D: float = 0.52,
                     num_stages: int = 50, steps_per_stage: int = 3, tf_max: float = 4.0,
                     options: IPOptions | None = None, throw: bool = True,
                     solver: Callable = interior_point, corner_clearance: bool = True,
                     interior_points: int = 0, car: ReducedHalfCar | None = None,
                     car_xs=None) -> Primitive:
    """The physical bound of the benchmark (docs/maneuvers.md): a point mass with
    $|a| \\le D g$, a lower bound on t_f (an upper bound on the exit speed). Two
    centreline starts (4 and 7 m/s), the best converged optimum kept; ``options`` default
    ``IPOptions()``; ``solver``: the interior-point solve (`interior_point`);
    ``corner_clearance``, ``interior_points``: the corridor between the nodes
    (`PointMassOCP`); ``car_xs``: the knots of ``car`` (default `rally_gravel_car`) on
    the same stages, a third start (`point_mass_guess_from_car`). The problem has local
    optima: on sturn the centreline starts alone end 0.6 % slower than the car's own
    optimum, which the car's start undercuts (`primitive_and_bound` gives it)."""
    require_float64("the point-mass bound", _FLOAT32)
    options = IPOptions() if options is None else options
    rd = _road(road)
    prob = PointMassOCP(road=rd, friction=D, objective=objective, tf_max=tf_max,
                        num_stages=num_stages, steps_per_stage=steps_per_stage,
                        corner_clearance=corner_clearance, interior_points=interior_points)
    best = None
    starts = [centreline_guess(rd, num_stages, speed) for speed in (4.0, 7.0)]
    if car_xs is not None:
        car = rally_gravel_car(D) if car is None else car
        starts.append(point_mass_guess_from_car(car, car_xs, D))
    for xs0, us0 in starts:
        sol = solver(prob, xs0, us0, options, throw=False)
        if _better(sol, best):
            best = sol
    if throw and not bool(best.converged):
        solver(prob, xs0, us0, options, throw=True)  # raises with residuals
    return Primitive(problem=prob, solution=best)


def multistart_guesses(car: ReducedHalfCar, road: Road, n: int, num_stages: int,
                       steps_per_stage: int = 1, corner_clearance: bool = True,
                       interior_points: int = 0):
    """``n`` starting guesses (knots (n, M+1, 10), controls (n, M, 3)) of different kinds:
    point-mass optima (`MULTISTART_SEEDS`, solved in one batched call) and constant-speed
    runs along the centreline (`CENTRELINE_SPEEDS`), alternating from the default seed."""
    check_count("multistart_guesses", "starts", n, sep=": ")
    n_seeds = min((n + 1) // 2, len(MULTISTART_SEEDS))
    n_lines = n - n_seeds
    if n_lines > len(CENTRELINE_SPEEDS):
        raise ValueError(f"starts must be at most "
                         f"{len(MULTISTART_SEEDS) + len(CENTRELINE_SPEEDS)}, got {n}")
    margins, fractions = (jnp.asarray(c, float) for c in zip(*MULTISTART_SEEDS[:n_seeds]))
    prob = PointMassOCP(road=road, friction=float(car.tire.D), num_stages=num_stages,
                        steps_per_stage=steps_per_stage, corner_clearance=corner_clearance,
                        interior_points=interior_points)
    xs0, us0 = centreline_guess(road, num_stages, 4.0)

    def seed(margin, fraction):
        p = eqx.tree_at(lambda q: (q.margin, q.friction), prob, (margin, fraction * prob.friction))
        return interior_point(p, xs0, us0, IPOptions(), throw=False)

    pm = jax.vmap(seed)(margins, fractions)
    seeds = [car_guess_from_point_mass(car, road, pm.xs[i], pm.us[i]) for i in range(n_seeds)]
    lines = [car_guess_from_point_mass(car, road, *centreline_guess(road, num_stages, v))
             for v in CENTRELINE_SPEEDS[:n_lines]]
    order = [g for pair in zip(seeds, lines) for g in pair]
    order += seeds[len(lines):] + lines[len(seeds):]
    return jnp.stack([g[0] for g in order]), jnp.stack([g[1] for g in order])


def car_problem(road: str | Road, objective: str, car: ReducedHalfCar, num_stages: int,
                steps_per_stage: int, tf_max: float, rate_weight: float = 1e-5,
                corner_clearance: bool = True, interior_points: int = 0) -> ManeuverOCP:
    """The car's maneuver problem that `min_time_primitive` and `max_exit_primitive` solve."""
    return ManeuverOCP(vehicle=car, road=_road(road), objective=objective, tf_max=tf_max,
                       num_stages=num_stages, steps_per_stage=steps_per_stage,
                       rate_weight=rate_weight, corner_clearance=corner_clearance,
                       interior_points=interior_points)


def car_guesses(prob: ManeuverOCP, starts=DEFAULT_STARTS, guess=None,
                solver: Callable = interior_point) -> list:
    """The starting guesses ``[(xs0, us0), ...]`` of `prob` from the point-mass seeds
    ``starts`` (`car_guess`, each seed solved by ``solver``; within 98 % of the time budget
    for max-exit), or ``[guess]``."""
    if guess is not None:
        M, nx, nu = prob.num_stages, prob.state_size, prob.control_size
        shapes = ((M + 1, nx), (M, nu))
        if not (isinstance(guess, tuple | list) and len(guess) == 2
                and all(np.shape(a) == s for a, s in zip(guess, shapes))):
            got = (tuple(np.shape(a) for a in guess) if isinstance(guess, tuple | list)
                   else type(guess).__name__)
            raise ValueError(f"guess must be a pair (xs, us) of knots {shapes[0]} and "
                             f"controls {shapes[1]} for {M} stages, got {got}")
        return [guess]
    guesses = []
    for margin, frac in starts:
        xs0, us0 = car_guess(prob.vehicle, prob.road, prob.num_stages, prob.steps_per_stage,
                             margin=margin, friction_fraction=frac, solver=solver,
                             corner_clearance=prob.corner_clearance,
                             interior_points=prob.interior_points)
        if prob.objective == "max-exit":
            xs0 = _within_budget(xs0, prob.tf_max)
        guesses.append((xs0, us0))
    return guesses


def best_of_guesses(prob: ManeuverOCP, guesses, options: IPOptions, solver: Callable,
                    throw: bool) -> Primitive:
    """`prob` solved by ``solver`` from each guess in turn, the best solution kept
    (`_better`); ``throw``: raise with the last guess's residuals if none converged."""
    best = None
    for xs0, us0 in guesses:
        sol = solver(prob, xs0, us0, options, throw=False)
        if _better(sol, best):
            best = sol
    if throw and not bool(best.converged):
        solver(prob, *guesses[-1], options, throw=True)  # raises with residuals
    return Primitive(problem=prob, solution=best)


def _solve_car(road, objective, car, num_stages, steps_per_stage, tf_max, options, throw,
               guess=None, rate_weight=1e-5, starts=DEFAULT_STARTS,
               solver: Callable = interior_point, corner_clearance: bool = True,
               interior_points: int = 0) -> Primitive:
    """The car's primitive: from point-mass seeds solved one after the other, or (an int
    ``starts``) from every start of `multistart_guesses` in one batched call."""
    require_float64("the car's primitive", _FLOAT32)
    if not is_count(starts) and guess is None and len(starts) == 0:
        raise ValueError("starts must be a whole number >= 1 or a non-empty sequence of "
                         "(margin, friction fraction) seeds, got an empty one")
    prob = car_problem(road, objective, car, num_stages, steps_per_stage, tf_max, rate_weight,
                       corner_clearance, interior_points)
    if is_count(starts) and guess is None:
        starts = operator.index(starts)
        xs0, us0 = batched_starts(prob, starts)
        sols = solve_starts(prob, xs0, us0, canonical_options(options), starts_batch_size())
        return best_start(prob, sols, starts, options.verbose, throw)
    return best_of_guesses(prob, car_guesses(prob, starts, guess, solver), options, solver,
                           throw)


@eqx.filter_jit
def solve_starts(prob, xs0, us0, options: IPOptions, batch_size: int | None) -> IPSolution:
    """The starts (leading axis) split over every device; each device solves its slice in
    vmapped chunks of ``batch_size`` (None: all at once). ``options`` as `canonical_options`
    gives them (one program for the quiet and the verbose solve)."""
    solve = sharded_vmap(lambda p, x, u, o: interior_point(p, x, u, o, throw=False),
                         in_axes=(None, 0, 0, None), batch_size=batch_size)
    return solve(prob, xs0, us0, options)


def starts_batch_size() -> int | None:
    """Starts solved together on one device: 1 on a CPU (each start stops at its own
    convergence; a vmapped batch steps every start until the slowest one has converged,
    several times the work when one start is slow), all of them on an accelerator."""
    return 1 if jax.default_backend() == "cpu" else None


def batched_starts(prob: ManeuverOCP, n: int):
    """The ``n`` guesses of `multistart_guesses` for `prob` (within 98 % of the time budget
    for max-exit), padded to a multiple of the device count (`vehsim.sharding.pad_members`;
    on a CPU force one host device per core with
    ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` before JAX starts)."""
    xs0, us0 = multistart_guesses(prob.vehicle, prob.road, n, prob.num_stages,
                                  prob.steps_per_stage, prob.corner_clearance,
                                  prob.interior_points)
    if prob.objective == "max-exit":
        xs0 = _within_budget(xs0, prob.tf_max)
    return pad_members((xs0, us0), len(jax.devices()))


def best_start(prob: ManeuverOCP, sols: IPSolution, n: int, verbose: bool,
               throw: bool) -> Primitive:
    """The best converged of the first ``n`` solutions ``sols`` (batched along axis 0, as
    `solve_starts` returns them), every start kept in the primitive's ``starts``;
    ``verbose``: print each start's iteration log."""
    # on one device, as the arrays the caller combines them with (the bound, the record)
    sols = jax.device_put(jax.tree.map(lambda a: a[:n], sols), jax.devices()[0])
    if verbose:
        names = result_name(sols.result)
        for k in range(n):
            sol = jax.tree.map(lambda a: a[k], sols)
            print(f"start {k}: {names[k]}, objective {float(sol.objective):.8g} after "
                  f"{int(sol.iterations)} iterations (inf_pr {float(sol.inf_pr):.1e}, inf_du "
                  f"{float(sol.inf_du):.1e})", file=sys.stderr)
            print_iteration_log(sol)
    converged = np.asarray(sols.converged)
    if throw and not converged.any():
        raise RuntimeError(f"interior point did not converge from any of the {n} starts: "
                           f"{sols.message}")
    value = np.where(converged, np.asarray(sols.objective), np.inf)
    best = int(np.argmin(value)) if converged.any() else 0
    pick = jax.tree_util.tree_map(lambda a: a[best], sols)
    return Primitive(problem=prob, solution=pick, starts=sols)


def min_time_primitive(road: str | Road = "corner90", *, car: ReducedHalfCar | None = None,
                       num_stages: int = 50, steps_per_stage: int = 3,
                       options: IPOptions | None = None, guess=None,
                       starts=DEFAULT_STARTS, throw: bool = True,
                       solver: Callable = interior_point, corner_clearance: bool = True,
                       interior_points: int = 0) -> Primitive:
    """Minimum-time maneuver through ``road`` (Table 4 boundary conditions, free t_f).

    **Arguments:** ``road`` (name or `Road`), ``car`` (default `rally_gravel_car()`),
    discretisation ``num_stages`` x ``steps_per_stage`` (nodes; the benchmark uses >= 150,
    docs/maneuvers.md), ``options`` (default `primitive_options` of the objective and
    ``starts``), an optional ``guess`` (xs, us), ``starts``: several
    (margin, friction fraction) point-mass seeds solved one after the other, or an int N:
    N starts of different kinds (`multistart_guesses`) solved in one compiled call split
    over the devices (one after another on each CPU device, vmapped on an accelerator),
    every start's solution kept in the primitive's ``starts``; the best converged optimum is
    returned either way. ``throw``. ``solver``: the interior-point solve of the seeds and
    the car (`interior_point`, or a function with its signature); an int ``starts`` solves
    the car's starts in one batched program of its own. ``corner_clearance``,
    ``interior_points``: the corridor between the nodes (`ManeuverOCP`; the point-mass
    seeds get the same).

    **Returns:** a `Primitive`.
    """
    car = rally_gravel_car() if car is None else car
    options = primitive_options("min-time", starts) if options is None else options
    return _solve_car(road, "min-time", car, num_stages, steps_per_stage, 4.0, options, throw,
                      guess, starts=starts, solver=solver, corner_clearance=corner_clearance,
                      interior_points=interior_points)


def max_exit_primitive(road: str | Road = "corner90", *, tf_max: float = 4.0,
                       car: ReducedHalfCar | None = None, num_stages: int = 50,
                       steps_per_stage: int = 3, options: IPOptions | None = None,
                       guess=None, starts=DEFAULT_STARTS, throw: bool = True,
                       solver: Callable = interior_point, corner_clearance: bool = True,
                       interior_points: int = 0) -> Primitive:
    """Maximum exit speed through ``road`` with t_f <= ``tf_max`` (4.0 s on corner90 in the
    benchmark, docs/maneuvers.md); arguments as `min_time_primitive` (the default
    ``options``, `primitive_options`, start from point-mass seeds at the smaller barrier
    `MAX_EXIT_MU0`)."""
    car = rally_gravel_car() if car is None else car
    options = primitive_options("max-exit", starts) if options is None else options
    return _solve_car(road, "max-exit", car, num_stages, steps_per_stage, tf_max, options,
                      throw, guess, starts=starts, solver=solver,
                      corner_clearance=corner_clearance, interior_points=interior_points)


def primitive_and_bound(road: str | Road = "corner90", objective: str = "min-time", *,
                        car: ReducedHalfCar | None = None, tf_max: float = 4.0,
                        num_stages: int = 50, steps_per_stage: int = 3,
                        options: IPOptions | None = None, starts=DEFAULT_STARTS,
                        throw: bool = True, solver: Callable = interior_point,
                        corner_clearance: bool = True,
                        interior_points: int = 0) -> tuple[Primitive, Primitive]:
    """A primitive and its physical bound, what `solution_record` compares: the car's
    `min_time_primitive` or `max_exit_primitive` (arguments as there) and the
    `point_mass_bound` of the same road, objective, friction, discretisation and budget.
    ``throw`` applies to the car's primitive; the bound never raises (check its result).

    **Returns:** ``(primitive, bound)``.
    """
    _check_objective(objective)
    car = rally_gravel_car() if car is None else car
    options = primitive_options(objective, starts) if options is None else options
    prim = _solve_car(road, objective, car, num_stages, steps_per_stage, tf_max, options,
                      throw, starts=starts, solver=solver, corner_clearance=corner_clearance,
                      interior_points=interior_points)
    bound = point_mass_bound(road, objective, D=float(car.tire.D), num_stages=num_stages,
                             steps_per_stage=steps_per_stage, tf_max=tf_max, throw=False,
                             solver=solver, corner_clearance=corner_clearance,
                             interior_points=interior_points, car=car,
                             car_xs=prim.solution.xs)
    return prim, bound


def _friction_batch(road, frictions, objective, num_stages, steps_per_stage, tf_max,
                    options):
    """The problem at the first friction, its guess, the options and the frictions."""
    rd = _road(road)
    options = primitive_options(objective) if options is None else options
    frictions = jnp.asarray(frictions, float)
    car0 = rally_gravel_car(float(frictions[0]))
    prob0 = ManeuverOCP(vehicle=car0, road=rd, objective=objective, tf_max=tf_max,
                        num_stages=num_stages, steps_per_stage=steps_per_stage)
    xs0, us0 = car_guess(car0, rd, num_stages, steps_per_stage)
    if objective == "max-exit":
        xs0 = _within_budget(xs0, tf_max)
    return prob0, xs0, us0, options, frictions


def vmap_primitives(road: str | Road, frictions, objective: str = "min-time", *,
                    num_stages: int = 50, steps_per_stage: int = 1, tf_max: float = 4.0,
                    options: IPOptions | None = None) -> Primitive:
    """The same maneuver over a batch of road frictions D (the tire's peak coefficient), in
    one vmapped solve: every member iterates until the slowest converges (suited to
    accelerators). ``options``: default `primitive_options` of the objective. Never raises
    on a member's failure: check ``result`` (per member).

    **Returns:** a `Primitive` whose problem and solution are batched along axis 0.
    """
    prob0, xs0, us0, options, frictions = _friction_batch(
        road, frictions, objective, num_stages, steps_per_stage, tf_max, options)

    def one(D):
        prob = eqx.tree_at(lambda p: p.vehicle.tire.D, prob0, D)
        return interior_point(prob, xs0, us0, options, throw=False)

    sols = jax.vmap(one)(frictions)
    probs = eqx.tree_at(lambda p: p.vehicle.tire.D, prob0, frictions)
    return Primitive(problem=probs, solution=sols)


def continuation_primitives(road: str | Road, frictions, objective: str = "min-time", *,
                            num_stages: int = 50, steps_per_stage: int = 1,
                            tf_max: float = 4.0, options: IPOptions | None = None,
                            warm_mu0: float = 1e-4) -> list[Primitive]:
    """The same maneuver over a batch of road frictions D (the tire's peak coefficient), by
    continuation: sequential solves, each warm-started from its neighbour's converged
    solution with the barrier parameter `warm_mu0` (sort the frictions). ``options``:
    default `primitive_options` of the objective (the first solve's). Never raises on a
    member's failure: check ``result`` (per member).

    **Returns:** a list of `Primitive`, one per friction.
    """
    prob0, xs0, us0, options, frictions = _friction_batch(
        road, frictions, objective, num_stages, steps_per_stage, tf_max, options)
    out = []
    guess = (xs0, us0)
    warm = eqx.tree_at(lambda o: o.mu0, options, warm_mu0)
    for i, D in enumerate(frictions):
        prob = eqx.tree_at(lambda p: p.vehicle.tire.D, prob0, D)
        sol = interior_point(prob, *guess, options if i == 0 else warm, throw=False)
        if bool(sol.converged):
            guess = (sol.xs, sol.us)
        out.append(Primitive(problem=prob, solution=sol))
    return out
