"""Long arc-length problems: how the structured interior point's cost per iteration grows
with the number of stages (it should grow linearly: one Riccati pass and per-stage
derivatives), on a rally stage of six corners (`rally_stage`) and a closed lap.

Prints one JSON line per solve: road, stages, iterations, wall_s (the solve, compiled
beforehand), compile_s, per_iteration_s (wall_s / iterations), per_iteration_best_s (the
best of 3 solves of 20 iterations from the same start), t_f, the point-mass bound's t_f (``--bound``), the
largest distance off the road at the nodes and between them (re-integration), the
periodicity residual of a lap; then a line with the slope of log(per-iteration time) against
log(stages) (least squares).

Usage: PYTHONPATH=. python experiments/long_problems.py [--stages 150 500 1000 2000]
       [--road rally|lap|both|track] [--track Oschersleben] [--bound] [--coarse 150]
"""

from __future__ import annotations

import argparse
import json
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


jax.config.update("jax_enable_x64", True)

RALLY_SEGMENTS = [
    ("straight", 120.0), ("arc", 30.0, 60.0), ("straight", 60.0), ("arc", 20.0, -90.0),
    ("straight", 80.0), ("arc", 40.0, 45.0), ("straight", 50.0), ("arc", 15.0, -120.0),
    ("straight", 100.0), ("arc", 25.0, 90.0), ("straight", 60.0), ("arc", 50.0, -30.0),
    ("straight", 80.0),
]
"""A gravel stage of about 740 m: six corners from a 15 m hairpin to a 50 m kink."""
LAP_SEGMENTS = [
    ("straight", 60.0), ("arc", 20.0, 90.0), ("straight", 30.0), ("arc", 15.0, 90.0),
    ("straight", 60.0), ("arc", 20.0, 90.0), ("straight", 30.0), ("arc", 15.0, 90.0),
]
"""A small closed circuit (about 290 m) of four corners."""
WIDTH = 8.0
TIMED_ITERATIONS, REPEATS = 20, 3
START_SPEED = 5.0


def rally_stage():
    """The rally stage (8 m wide; the start gate fixes 5 m/s)."""
    from vehsim import CentrelineRoad, Gate

    road = CentrelineRoad.from_segments(RALLY_SEGMENTS, WIDTH, name="rally_stage")
    return road.with_gates(Gate.at(road, 0.0, speed=START_SPEED), None)


def small_lap():
    """The closed circuit (8 m wide)."""
    from vehsim import CentrelineRoad

    return CentrelineRoad.from_segments(LAP_SEGMENTS, WIDTH, name="small_lap", closed=True)


def solve(road, name: str, M: int, bound: bool, coarse: int | None) -> dict:
    from vehsim.optimal.curvilinear import (
        CurvilinearManeuverOCP,
        RoadPrimitive,
        coarse_start,
        resample_drive,
        road_point_mass_bound,
        road_primitive,
        speed_profile_guess,
    )
    from vehsim.optimal.ip import IPOptions, compile_interior_point
    from vehsim.optimal.primitives import rally_gravel_car

    car = rally_gravel_car()
    options = IPOptions(max_iter=500)
    prob = CurvilinearManeuverOCP.from_road(road, car, num_stages=M)
    xs0, us0 = speed_profile_guess(road, car, M)
    if coarse is not None and coarse < M:  # start from the coarse solution (road_primitive)
        first = road_primitive(road, car=car, num_stages=coarse, throw=False,
                               options=IPOptions(max_iter=500, best_iterate=True))
        if coarse_start(first.solution):
            xs0, us0 = resample_drive(first.problem, first.solution.xs, prob)
            options = IPOptions(max_iter=500, mu0=1e-3)
    t0 = time.perf_counter()
    program = compile_interior_point(prob, xs0, us0, options)
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    sol = program(prob, xs0, us0, options, throw=False)
    jax.block_until_ready(sol.xs)
    wall = time.perf_counter() - t0
    # per-iteration time, robust to a busy machine: the best of REPEATS solves of
    # TIMED_ITERATIONS iterations from the same start (the same compiled program)
    short = eqx.tree_at(lambda o: o.max_iter, options, jnp.asarray(TIMED_ITERATIONS))
    best = np.inf
    for _ in range(REPEATS):
        t1 = time.perf_counter()
        jax.block_until_ready(program(prob, xs0, us0, short, throw=False).xs)
        best = min(best, time.perf_counter() - t1)
    prim = RoadPrimitive(problem=prob, solution=sol, road=road)
    v = prim.violations()
    xs = np.asarray(sol.xs)
    its = int(sol.iterations)
    rec = dict(road=name, stages=M, coarse_stages=coarse, status=str(sol.message), iterations=its,
               wall_s=round(wall, 3), compile_s=round(compile_s, 1),
               per_iteration_s=round(wall / max(its, 1), 5),
               per_iteration_best_s=round(best / TIMED_ITERATIONS, 5), t_f=float(prim.t_f),
               max_violation_nodes=v["corridor"],
               max_violation_between_nodes=v["corridor_between_nodes"])
    if prob.closed:
        rec["periodicity"] = float(np.max(np.abs(xs[-1, :8] - xs[0, :8])))
    if bound:
        pm = road_point_mass_bound(road, num_stages=M, throw=False)
        rec["point_mass_t_f"] = float(pm.t_f)
        rec["point_mass_status"] = str(pm.solution.message)
    return rec


def main(argv=None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--stages", type=int, nargs="+", default=[150, 500, 1000, 2000])
    ap.add_argument("--road", choices=("rally", "lap", "both", "track"), default="both")
    ap.add_argument("--track", default="Oschersleben", help="the shipped circuit of --road track")
    ap.add_argument("--bound", action="store_true", help="solve the point-mass bound too")
    ap.add_argument("--coarse", type=int, default=None,
                    help="start each solve from the solution on this many stages")
    args = ap.parse_args(argv)
    roads = []
    if args.road in ("rally", "both"):
        roads.append(("rally_stage", rally_stage()))
    if args.road in ("lap", "both"):
        roads.append(("small_lap", small_lap()))
    if args.road == "track":
        from vehsim import track

        roads.append((args.track, track(args.track)))
    for name, road in roads:
        rows = []
        for M in args.stages:
            rec = solve(road, name, M, args.bound, args.coarse)
            rows.append(rec)
            print(json.dumps(rec), flush=True)
        if len(rows) > 1:
            logs = np.log([r["stages"] for r in rows])
            slopes = {key: round(float(np.polyfit(logs, np.log([r[key] for r in rows]), 1)[0]), 3)
                      for key in ("per_iteration_s", "per_iteration_best_s")}
            print(json.dumps(dict(road=name, log_log_slope=slopes)), flush=True)


if __name__ == "__main__":
    main()
