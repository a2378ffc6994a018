"""Benchmark: vehsim's structured interior point vs CasADi + IPOPT on the maneuver problems.

The same model (reduced half-car, friction-ellipse Magic Formula, quasi-static load transfer),
the same boundary conditions, corridor (the same conservative smooth inner corners) and input
bounds, the same objective (including the tiny input-rate penalty), the same starting guess,
and the same nodes (N intervals uniform in tau, corridor and axle-speed floor at every node).

IPOPT transcriptions (``--method``):
- ``rk4``: one RK4 step per interval (exactly vehsim's discretisation: compares solvers);
- ``trapezoidal``: direct collocation with the trapezoidal rule (the classic baseline).
t_f is carried per interval with t_{f,k+1} = t_{f,k} (no dense column), exact Hessians by
CasADi's AD, MUMPS with its default ordering; IPOPT's time is the solver call (after
building the NLP: building counts as its compile time).

Prints JSON lines; headline ``ratio`` = IPOPT wall time / vehsim wall time (same run, the
best of three solves each), with ``profile``: where one vehsim iteration's time goes
(`iteration_profile`).

    PYTHONPATH=. python experiments/benchmarks/ocp_vs_ipopt.py --segments 150

``--multistart 8``: the best of 8 starts in one call against IPOPT's 8 sequential solves;
the starts are split over the devices JAX sees (on a CPU, one host device per core with
``XLA_FLAGS=--xla_force_host_platform_device_count=2`` before the command; the row records
``devices``).

``--sweep 30,50,100,150,200``: solution quality over many instances (vehsim's primitive and
IPOPT from the same guess), with a summary line; ``--problems corner90:max-exit:3.8`` sets
another time budget, ``--mu0`` another initial barrier.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import jax
import numpy as np


jax.config.update("jax_enable_x64", True)

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # also when loaded by path
import _casadi_maneuver as _casadi  # noqa: E402
from _casadi_maneuver import LIMIT_NAMES, road_data  # noqa: E402

from vehsim import is_successful, result_name  # noqa: E402
from vehsim.optimal.guesses import car_guess  # noqa: E402
from vehsim.optimal.ip import interior_point  # noqa: E402
from vehsim.optimal.primitives import primitive_options, rally_gravel_car  # noqa: E402
from vehsim.optimal.roads import SMOOTHING, road as road_by_name  # noqa: E402
from vehsim.optimal.shooting import (  # noqa: E402
    DELTA_MAX,
    IDX_TF,
    KAPPA_MAX,
    KAPPA_MIN,
    SPEED_FLOOR,
    TF_MIN,
    ManeuverOCP,
)


LIMITS = dict(SMOOTHING=SMOOTHING, SPEED_FLOOR=SPEED_FLOOR, KAPPA_MIN=KAPPA_MIN,
              KAPPA_MAX=KAPPA_MAX, DELTA_MAX=DELTA_MAX, TF_MIN=TF_MIN)
assert set(LIMITS) == set(LIMIT_NAMES)


def ipopt_solve(rd, objective, D, N, xs0, us0, **kwargs):
    """`_casadi_maneuver.ipopt_solve` on vehsim's road ``rd`` with vehsim's bounds."""
    return _casadi.ipopt_solve(road_data(rd), LIMITS, objective, D, N, xs0, us0, **kwargs)


def _best_time(f, repeats=3):
    """Smallest wall time of ``repeats`` calls of ``f`` (blocking), and its last result."""
    best, out = math.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(f())
        best = min(best, time.perf_counter() - t0)
    return best, out


def iteration_profile(prob, sol, per_iteration_s):
    """Where one interior-point iteration's time goes, at the solution's point: stage
    derivatives (Jacobians and Lagrangian Hessians), one KKT factorisation and solve (times
    the mean factorisations per iteration of the inertia correction), one line-search trial
    (a constraint evaluation; times the mean trials per iteration), and the rest (residuals,
    steps, the loop) as the difference from the measured time per iteration [ms]."""
    import equinox as eqx

    from vehsim.optimal.ip.derivatives import stage_derivatives, stage_values
    from vehsim.optimal.ip.kkt import Iterate, _condensed_system, checked_solve, kkt_matrix
    from vehsim.optimal.ip.problem import stage_layout

    lay = stage_layout(prob)
    mg = lay.masks().g
    ys = lay.join(sol.xs, sol.us)
    deriv = eqx.filter_jit(lambda p, y, lam, n, z: stage_derivatives(p, lay, y, lam, n, z))
    values = eqx.filter_jit(lambda p, y: stage_values(p, lay, y))
    t_deriv, d = _best_time(lambda: deriv(prob, ys, sol.lam, sol.nu, sol.z), 20)
    t_values, _ = _best_time(lambda: values(prob, ys), 20)
    it = Iterate(ys=ys, s=jax.numpy.where(mg > 0, jax.numpy.maximum(d.g, 1e-6), 1.0), z=sol.z,
                 lam=sol.lam, nu=sol.nu)
    rhs, W0 = _condensed_system(lay, it, d, 1e-6)
    K = kkt_matrix(lay, W0, d, 1e-8)
    solve = jax.jit(lambda K, r: checked_solve(lay, K, r))
    t_factor, _ = _best_time(lambda: solve(K, rhs), 20)
    n = int(sol.iterations)
    factorisations = float(np.mean(np.asarray(sol.log.factorisations)[:n]))
    trials = float(np.mean(np.asarray(sol.log.trials)[:n]))
    parts = {"derivatives_ms": 1e3 * t_deriv,
             "kkt_ms": 1e3 * t_factor * factorisations,
             "line_search_ms": 1e3 * t_values * trials}
    return dict(parts, per_iteration_ms=1e3 * per_iteration_s,
                other_ms=1e3 * per_iteration_s - sum(parts.values()),
                factorisation_ms=1e3 * t_factor, factorisations_per_iteration=factorisations,
                trial_ms=1e3 * t_values, trials_per_iteration=trials)


def violations(rd, xs):
    off = rd.distance_off_road(xs[:, 0], xs[:, 1])
    return float(np.max(off))


def violation_between_nodes(prob, xs, us):
    """Largest distance off the road [m] of the path re-integrated between the nodes
    (`ManeuverOCP.fine_nodes`, 20 RK4 substeps per step) of knots ``xs`` and rates ``us``
    (either solver's)."""
    fine = np.asarray(prob.fine_nodes(jax.numpy.asarray(xs), jax.numpy.asarray(us), 20))
    return violations(prob.road, fine)


IPOPT_ONCE = """
import json, sys
import numpy as np
sys.path.insert(0, {here!r})
from _casadi_maneuver import ipopt_solve
problem = json.load(open(sys.argv[1]))
data = np.load(sys.argv[2])
ip = ipopt_solve(problem["road"], problem["limits"], "min-time", 0.52, {N}, data["xs"],
                 data["us"])
with open(sys.argv[3], "w") as f:
    json.dump(dict(t_f=float(ip["xs"][-1, 9]), status=ip["status"], xs=ip["xs"].tolist()), f)
assert "jax" not in sys.modules
"""


def end_to_end(N: int, repeats: int = 5) -> None:
    """From process start to files written: ``vehsim optimise corner90`` (the default
    command, progress lines included) with an empty compilation cache (cold) and then
    ``repeats`` times with the cache it filled (warm; the median is the headline), and a
    process that builds the same problem in CasADi, solves it with IPOPT from the same car
    guess and writes its JSON (median of ``repeats`` processes). The warm runs and the IPOPT
    processes alternate, so that a machine whose speed drifts during the run (a shared
    virtual machine) slows both alike. The IPOPT process imports
    CasADi and NumPy only (`_casadi_maneuver`): the road, bounds and guess come from files,
    computing them being vehsim's work."""
    import subprocess
    import tempfile
    from pathlib import Path

    here = str(Path(__file__).resolve().parent)
    root = str(Path(here).parent.parent)
    # Python caches compiled bytecode next to the sources unless told not to; a sandbox that
    # tells it not to would recompile every imported module of both processes on every run
    env = {k: v for k, v in os.environ.items()
           if k not in ("JAX_COMPILATION_CACHE_DIR", "PYTHONDONTWRITEBYTECODE")}
    env["PYTHONPATH"] = root

    def wall(cmd):
        t0 = time.perf_counter()
        subprocess.run(cmd, env=env, check=True, capture_output=True)
        return time.perf_counter() - t0

    with tempfile.TemporaryDirectory() as tmp:
        env["VEHSIM_CACHE_DIR"] = str(Path(tmp) / "cache")
        cmd = [sys.executable, "-m", "vehsim", "optimise", "corner90", "--segments", str(N),
               "--out", str(Path(tmp) / "out")]
        cold = wall(cmd)
        xs0, us0 = car_guess(rally_gravel_car(), road_by_name("corner90"), N, 1)
        np.savez(Path(tmp) / "guess.npz", xs=np.asarray(xs0), us=np.asarray(us0))
        (Path(tmp) / "problem.json").write_text(json.dumps(dict(
            road=road_data(road_by_name("corner90")), limits=LIMITS)))
        script = IPOPT_ONCE.format(here=here, N=N)
        ipopt_cmd = [sys.executable, "-c", script, str(Path(tmp) / "problem.json"),
                     str(Path(tmp) / "guess.npz"), str(Path(tmp) / "ipopt.json")]
        warm, ipopt = [], []
        for _ in range(repeats):
            warm.append(wall(cmd))
            ipopt.append(wall(ipopt_cmd))
        rec = json.loads((Path(tmp) / "out" / "corner90_min-time.json").read_text())
        ip = json.loads((Path(tmp) / "ipopt.json").read_text())
    warm_s, ipopt_s = float(np.median(warm)), float(np.median(ipopt))
    print(json.dumps(dict(
        problem="corner90:min-time end to end", segments=N, end_to_end_cold_s=cold,
        end_to_end_warm_s=warm_s, end_to_end_warm_runs_s=warm, ipopt_end_to_end_s=ipopt_s,
        ipopt_end_to_end_runs_s=ipopt, ratio_warm=ipopt_s / warm_s,
        ratio_warm_pairs=[i / w for i, w in zip(ipopt, warm)], ratio_cold=ipopt_s / cold,
        vehsim_t_f=rec["t_f"], vehsim_status=rec["status"], ipopt_t_f=ip["t_f"],
        ipopt_status=ip["status"], loadavg=os.getloadavg()[0],
    )), flush=True)


def multistart(problems, N: int, n: int = 8) -> None:
    """Per problem: vehsim's ``starts=n`` (the guesses and every start in one call, after
    compilation) against IPOPT solving from the same ``n`` guesses one after the other
    (solver calls only); the best value of each."""
    from vehsim.optimal.primitives import max_exit_primitive, min_time_primitive, multistart_guesses

    car = rally_gravel_car()
    for problem in problems:
        name, objective = problem.split(":")
        rd = road_by_name(name)
        print(f"# multistart {name} {objective}", file=sys.stderr, flush=True)
        f = min_time_primitive if objective == "min-time" else max_exit_primitive
        opts = primitive_options(objective, n)  # a multi-start's: mu0 0.1

        def call():
            return f(rd, num_stages=N, steps_per_stage=1, options=opts, starts=n, throw=False)

        prim = call()  # compile
        wall, prim = _best_time(lambda: call(), 1)
        xs0, us0 = multistart_guesses(car, rd, n, N, 1)
        if objective == "max-exit":
            xs0 = xs0.at[:, :, IDX_TF].set(np.minimum(xs0[:, :, IDX_TF], 0.98 * 4.0))
        val = (lambda x: x[-1, IDX_TF]) if objective == "min-time" else (
            lambda x: math.hypot(x[-1, 3], x[-1, 4]))
        ip_values, ip_ok, ip_wall = [], [], 0.0
        for i in range(n):
            ip = ipopt_solve(rd, objective, 0.52, N, xs0[i], us0[i])
            ip_wall += ip["wall"]
            ip_values.append(float(val(ip["xs"])))
            ip_ok.append(ip["ok"])
        ours = [float(val(np.asarray(x))) if bool(c) else math.nan
                for x, c in zip(prim.starts.xs, np.asarray(prim.starts.converged))]
        best = min if objective == "min-time" else max
        ip_best = best(v for v, ok in zip(ip_values, ip_ok) if ok)
        ours_best = float(val(np.asarray(prim.solution.xs)))
        print(json.dumps(dict(
            problem=f"{problem} multistart", segments=N, starts=n, vehsim_best=ours_best,
            ipopt_best=ip_best, rel_diff=(ours_best - ip_best) / abs(ip_best),
            vehsim_wall_s=wall, ipopt_sequential_s=ip_wall, ratio=ip_wall / wall,
            vehsim_values=ours, vehsim_statuses=result_name(prim.starts.result),
            ipopt_values=ip_values, ipopt_ok=ip_ok, devices=len(jax.devices()),
            device=jax.devices()[0].device_kind, loadavg=os.getloadavg()[0],
        )), flush=True)


def sweep(problems, sizes, mu0=None) -> None:
    """Solution quality over many instances: per problem (``road:objective``, or
    ``road:max-exit:tf_max`` for another time budget than 4 s) and number of segments,
    vehsim's primitive (the primitives' options, ``mu0`` replaced when given; the default
    point-mass seed) and IPOPT from the same guess; values, iterations, statuses and
    vehsim's relative shortfall (> 0: IPOPT's optimum is better), then one summary line."""
    from vehsim.optimal.primitives import max_exit_primitive, min_time_primitive

    car = rally_gravel_car()
    rows, failed = [], 0
    for N in sizes:
        for problem in problems:
            name, objective, *budget = problem.split(":")
            tf_max = float(budget[0]) if budget else 4.0
            rd = road_by_name(name)
            opts = primitive_options(objective, **({} if mu0 is None else {"mu0": mu0}))
            if objective == "min-time":
                prim = min_time_primitive(rd, num_stages=N, steps_per_stage=1, options=opts,
                                          throw=False)
            else:
                prim = max_exit_primitive(rd, num_stages=N, steps_per_stage=1, options=opts,
                                          tf_max=tf_max, throw=False)
            xs0, us0 = car_guess(car, rd, N, 1)
            if objective == "max-exit":
                xs0 = xs0.at[:, IDX_TF].set(np.minimum(xs0[:, IDX_TF], 0.98 * tf_max))
            ip = ipopt_solve(rd, objective, 0.52, N, xs0, us0, tf_max=tf_max)
            val = (lambda x: x[-1, IDX_TF]) if objective == "min-time" else (
                lambda x: -math.hypot(x[-1, 3], x[-1, 4]))
            ours, theirs = float(val(np.asarray(prim.solution.xs))), float(val(ip["xs"]))
            row = dict(problem=problem, segments=N, mu0=float(opts.mu0),
                       vehsim_value=abs(ours), ipopt_value=abs(theirs),
                       shortfall=(ours - theirs) / abs(theirs),
                       vehsim_status=result_name(prim.solution.result),
                       vehsim_iterations=int(prim.solution.iterations),
                       ipopt_status=ip["status"], ipopt_iterations=ip["iterations"])
            rows.append(row)
            failed += not bool(is_successful(prim.solution.result))
            print(json.dumps(row), flush=True)
        jax.clear_caches()
    short = [r["shortfall"] for r in rows]
    print(json.dumps(dict(
        problem="sweep summary", instances=len(rows),
        vehsim_worse_by_more_than_0_05_percent=sum(x > 5e-4 for x in short),
        vehsim_better_by_more_than_0_05_percent=sum(x < -5e-4 for x in short),
        largest_shortfall=max(short),
        vehsim_not_converged=failed,
        vehsim_iterations=sum(r["vehsim_iterations"] for r in rows),
        ipopt_iterations=sum(r["ipopt_iterations"] for r in rows),
    )), flush=True)


def road_arrays(prob) -> dict:
    """A curvilinear problem's road as plain data for `_casadi_spatial.ipopt_solve`."""
    start_speed = float(prob.start_speed) if prob.start_speed_fixed else None
    end_speed = float(prob.end_speed) if prob.end_speed_fixed else None
    return dict(length=float(prob.length), closed=bool(prob.closed),
                curvature=np.asarray(prob.curvature)[:, 0, :],
                corridor=np.asarray(prob.corridor), corridor_mid=np.asarray(prob.corridor_mid)[:, 0],
                start_lateral=np.asarray(prob.start_lateral).tolist(),
                end_lateral=np.asarray(prob.end_lateral).tolist(),
                start_speed=start_speed, end_speed=end_speed,
                stage_lengths=np.diff(prob.stage_edges()))


def long_problems(stages, road_name: str = "rally", coarse_above: int = 300) -> None:
    """The long problems: minimum time on the rally stage (or the small closed lap) of
    experiments/long_problems.py at each number of stages, vehsim's structured interior point
    against CasADi + IPOPT on the same transcription (`_casadi_spatial`) from the same start:
    the speed-profile guess, or above ``coarse_above`` stages the solution on a quarter of
    them resampled (both solvers then start with the barrier 1e-3). Per size: iterations,
    wall time (vehsim: compiled beforehand, the best of two solves) and time per iteration of
    both, ``ratio`` (IPOPT / vehsim wall time), the minimum times and the largest distance off
    the road between the nodes of both solutions (re-integrated by vehsim's `RoadPrimitive`);
    then the log-log slope of the time per iteration against the stages."""
    import _casadi_spatial
    import equinox as eqx

    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
    from long_problems import rally_stage, small_lap

    from vehsim.optimal.curvilinear import (
        CurvilinearManeuverOCP,
        RoadPrimitive,
        resample_drive,
        road_primitive,
        speed_profile_guess,
    )
    from vehsim.optimal.ip import IPOptions, compile_interior_point

    road = rally_stage() if road_name == "rally" else small_lap()
    car = rally_gravel_car()
    rows = []
    for M in stages:
        prob = CurvilinearManeuverOCP.from_road(road, car, num_stages=M)
        options = IPOptions(max_iter=500)
        xs0, us0 = speed_profile_guess(road, car, M)
        if M > coarse_above:
            first = road_primitive(road, car=car, num_stages=M // 4, options=options,
                                   throw=False)
            xs0, us0 = resample_drive(first.problem, first.solution.xs, prob)
            options = IPOptions(max_iter=500, mu0=1e-3)
        print(f"# long problem {road.name}, {M} stages", file=sys.stderr, flush=True)
        program = compile_interior_point(prob, xs0, us0, options)
        wall, sol = _best_time(lambda: program(prob, xs0, us0, options, throw=False), 2)
        ours = RoadPrimitive(problem=prob, solution=sol, road=road)
        # IPOPT's transcription states a lap's periodicity as X(L) = X(0) without vehsim's
        # copy of the start state (the last 8 of its 17): it gets the 9 physical states, and
        # its solution gets the copy back for the re-integration
        p = prob.physical_size
        ip = _casadi_spatial.ipopt_solve(road_arrays(prob), LIMITS, "min-time",
                                         float(car.tire.D), np.asarray(xs0)[:, :p],
                                         np.asarray(us0), rate_weight=float(prob.rate_weight),
                                         mu_init=float(options.mu0))
        ip_xs = np.concatenate([ip["xs"], np.broadcast_to(
            ip["xs"][:1, :prob.periodic_size], (ip["xs"].shape[0], prob.periodic_size))], 1)
        theirs = RoadPrimitive(problem=prob, solution=eqx.tree_at(
            lambda s: (s.xs, s.us), sol, (jax.numpy.asarray(ip_xs),
                                          jax.numpy.asarray(ip["us"]))), road=road)
        its = int(sol.iterations)
        row = dict(problem=f"{road.name}:min-time", stages=M, vehsim_status=str(sol.message),
                   vehsim_iterations=its, vehsim_wall_s=wall,
                   vehsim_per_iteration_s=wall / max(its, 1), vehsim_t_f=float(ours.t_f),
                   vehsim_between_nodes_m=ours.violations()["corridor_between_nodes"],
                   ipopt_status=ip["status"], ipopt_iterations=ip["iterations"],
                   ipopt_wall_s=ip["wall"],
                   ipopt_per_iteration_s=ip["wall"] / max(ip["iterations"], 1),
                   ipopt_t_f=float(ip["xs"][-1, 8]),
                   ipopt_between_nodes_m=theirs.violations()["corridor_between_nodes"],
                   ratio=ip["wall"] / wall,
                   ratio_per_iteration=(ip["wall"] / max(ip["iterations"], 1))
                   / (wall / max(its, 1)), loadavg=os.getloadavg()[0])
        rows.append(row)
        print(json.dumps(row), flush=True)
        jax.clear_caches()
    if len(rows) > 1:
        logs = np.log([r["stages"] for r in rows])
        print(json.dumps(dict(problem=f"{road.name}:min-time scaling", stages=list(stages),
                              **{f"{who}_per_iteration_log_log_slope": float(np.polyfit(
                                  logs, np.log([r[f"{who}_per_iteration_s"] for r in rows]),
                                  1)[0]) for who in ("vehsim", "ipopt")})), flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--segments", type=int, default=150)
    ap.add_argument("--method", choices=["rk4", "trapezoidal"], default="rk4")
    ap.add_argument("--problems", nargs="*",
                    default=["corner90:min-time", "corner90:max-exit", "uturn:min-time",
                             "sturn:min-time"])
    ap.add_argument("--batch", type=int, default=0, help="frictions in the batch benchmark")
    ap.add_argument("--end-to-end", action="store_true",
                    help="time `vehsim optimise corner90` (cold and warm cache) and IPOPT's "
                         "whole process")
    ap.add_argument("--multistart", type=int, default=0,
                    help="starts of the multi-start comparison (8 in the benchmark)")
    ap.add_argument("--sweep", default="",
                    help="comma-separated segment counts of the solution-quality sweep "
                         "(e.g. 30,50,100,150,200)")
    ap.add_argument("--mu0", type=float, default=None,
                    help="initial barrier of the sweep's solves (default: the primitives')")
    ap.add_argument("--stages", default="",
                    help="comma-separated stage counts of the long problems (e.g. "
                         "150,500,1000,2000): the rally stage of experiments/long_problems.py "
                         "in the road's frame, against IPOPT on the same transcription")
    ap.add_argument("--long-road", choices=["rally", "lap"], default="rally",
                    help="the road of --stages: the rally stage or the small closed lap")
    ap.add_argument("--no-corner-clearance", dest="corner_clearance", action="store_false",
                    help="both solvers: inner corners at the nodes only (ManeuverOCP)")
    ap.add_argument("--interior-points", type=int, default=0,
                    help="both solvers: the corridor at this many points inside each RK4 "
                         "step (ManeuverOCP)")
    args = ap.parse_args(argv)
    N = args.segments
    if args.stages:
        long_problems([int(n) for n in args.stages.split(",")], args.long_road)
        return
    if args.sweep:
        sweep(args.problems, [int(n) for n in args.sweep.split(",")], args.mu0)
        return
    if args.multistart:
        multistart(args.problems, N, args.multistart)
        return
    if args.batch:
        batch_benchmark(args.batch, N, args.method)
        return
    if args.end_to_end:
        end_to_end(N)
        return
    car = rally_gravel_car()
    for problem in args.problems:
        name, objective = problem.split(":")
        rd = road_by_name(name)
        print(f"# {name} {objective}", file=sys.stderr, flush=True)
        between = dict(corner_clearance=args.corner_clearance,
                       interior_points=args.interior_points)
        xs0, us0 = car_guess(car, rd, N, 1, **between)
        if objective == "max-exit":
            xs0 = xs0.at[:, IDX_TF].set(np.minimum(xs0[:, IDX_TF], 0.98 * 4.0))
        prob = ManeuverOCP(vehicle=car, road=rd, objective=objective, num_stages=N,
                           steps_per_stage=1, **between)
        opts = primitive_options(objective)  # the primitives' settings (max-exit: mu0 0.01)
        t0 = time.perf_counter()
        sol = interior_point(prob, xs0, us0, opts, throw=False)
        jax.block_until_ready(sol.xs)
        first = time.perf_counter() - t0
        ours, sol = _best_time(lambda: interior_point(prob, xs0, us0, opts, throw=False))
        xs = np.asarray(sol.xs)
        profile = iteration_profile(prob, sol, ours / max(int(sol.iterations), 1))
        t_build = time.perf_counter()
        ip = ipopt_solve(rd, objective, 0.52, N, xs0, us0, method=args.method, **between)
        ipopt_total = time.perf_counter() - t_build
        for _ in range(2):  # the best of three solver calls, as for vehsim
            again = ipopt_solve(rd, objective, 0.52, N, xs0, us0, method=args.method,
                                **between)
            ip["wall"] = min(ip["wall"], again["wall"])
        val = (lambda x: x[-1, IDX_TF]) if objective == "min-time" else (
            lambda x: math.hypot(x[-1, 3], x[-1, 4]))
        ours_v, ip_v = float(val(xs)), float(val(ip["xs"]))
        print(json.dumps(dict(
            problem=problem, segments=N, method=args.method,
            vehsim_value=ours_v, ipopt_value=ip_v, rel_diff=(ours_v - ip_v) / abs(ip_v),
            vehsim_status=result_name(sol.result), vehsim_iterations=int(sol.iterations),
            ipopt_status=ip["status"], ipopt_iterations=ip["iterations"],
            vehsim_corridor_violation=violations(rd, prob.nodes(sol.xs, sol.us).__array__()),
            ipopt_corridor_violation=violations(rd, ip["xs"]),
            vehsim_violation_between_nodes=violation_between_nodes(prob, xs, sol.us),
            ipopt_violation_between_nodes=violation_between_nodes(prob, ip["xs"], ip["us"]),
            **between, vehsim_wall_s=ours, ipopt_wall_s=ip["wall"], ratio=ip["wall"] / ours,
            vehsim_compile_s=first - ours, ipopt_build_s=ipopt_total - ip["wall"],
            profile=profile, loadavg=os.getloadavg()[0],
        )), flush=True)


def batch_benchmark(n: int, N: int, method: str) -> None:
    """corner90 min-time over ``n`` frictions D in [0.40, 0.64]: vehsim's warm-started
    continuation and vmapped batch against ``n`` sequential IPOPT solves (each warm-started
    from the previous solution, the fair counterpart of the continuation)."""
    from vehsim.optimal.primitives import continuation_primitives, vmap_primitives

    rd = road_by_name("corner90")
    Ds = np.linspace(0.40, 0.64, n)
    car = rally_gravel_car(float(Ds[0]))
    xs0, us0 = car_guess(car, rd, N, 1)
    for mode, batch in (("continuation", continuation_primitives), ("vmap", vmap_primitives)):
        t0 = time.perf_counter()
        out = batch(rd, Ds, num_stages=N)
        jax.block_until_ready(out if mode == "vmap" else [p.solution.xs for p in out])
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        out = batch(rd, Ds, num_stages=N)
        jax.block_until_ready(out if mode == "vmap" else [p.solution.xs for p in out])
        wall = time.perf_counter() - t0
        if mode == "vmap":
            tfs = np.asarray(out.solution.xs[:, -1, IDX_TF])
            ok = int(np.sum(np.asarray(out.solution.converged)))
        else:
            tfs = np.array([float(p.t_f) for p in out])
            ok = sum(bool(p.solution.converged) for p in out)
        if mode == "continuation":
            tf_cont = tfs
            wall_cont = wall
        else:
            wall_vmap, tf_vmap, ok_vmap = wall, tfs, ok
        print(f"# vehsim {mode}: {wall:.2f} s ({first - wall:.1f} s compile), {ok}/{n} ok",
              file=sys.stderr, flush=True)
    tf_ip, guess, wall_ip = [], (xs0, us0), 0.0
    for D in Ds:
        ip = ipopt_solve(rd, "min-time", float(D), N, *guess, method=method)
        wall_ip += ip["wall"]  # solver calls only (building each NLP is not counted)
        tf_ip.append(ip["xs"][-1, IDX_TF])
        if ip["ok"]:
            guess = (ip["xs"], np.diff(ip["xs"][:, 6:9], axis=0) * N)
    tf_ip = np.asarray(tf_ip)
    print(json.dumps(dict(
        problem="corner90:min-time batch", frictions=n, segments=N,
        vehsim_continuation_s=wall_cont, vehsim_vmap_s=wall_vmap, ipopt_sequential_s=wall_ip,
        ratio=wall_ip / min(wall_cont, wall_vmap), vmap_converged=ok_vmap,
        max_rel_diff_continuation=float(np.max(np.abs(tf_cont - tf_ip) / tf_ip)),
        max_rel_diff_vmap=float(np.max(np.abs(tf_vmap - tf_ip) / tf_ip)),
        loadavg=os.getloadavg()[0],
    )), flush=True)


if __name__ == "__main__":
    main()
