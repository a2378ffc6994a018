"""`vehsim optimise ROAD --objective min-time|max-exit`: solve a maneuver primitive, write the
solution (JSON) and a Fig. 20-like figure."""

from __future__ import annotations

import importlib
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path


UNITS = {
    "residuals.inf_pr": "1", "residuals.inf_du": "1", "residuals.compl": "1",
    "violations.corridor": "m", "violations.corridor_between_nodes": "m",
    "violations.boundary": "m, rad or m/s (the largest)", "violations.defects": "1",
    "violations.inputs": "1 or rad (the largest)", "violations.axle_speed_floor": "m/s",
    "violations.time_budget": "s", "max_corridor_violation": "m",
    "max_corridor_violation_between_nodes": "m", "point_mass_t_f": "s",
    "point_mass_exit_speed": "m/s", "t_f_over_bound": "1", "exit_speed_over_bound": "1",
    "starts[].objective": "s (min-time) or -m/s (max-exit)", "interior_points": "1",
}
"""Units of the optimise JSON's fields that `vehsim.labelled.UNITS` and their names do not
give (the interior point's residuals are scaled, dimensionless)."""


MAX_ITER_OPTION = {"`IPOptions.max_iter`": "--max-iter"}
"""The solver setting a failed solve's message names, as the command's option."""


def register(subparsers) -> None:
    from ._options import integer, number

    p = subparsers.add_parser(
        "optimise", help="optimal driving primitive (min-time / max-exit) on a benchmark "
                         "road, a road file or a shipped track")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("road", nargs="?", choices=["corner90", "uturn", "sturn"],
                       help="benchmark road (docs/maneuvers.md): corner90, uturn or sturn")
    where.add_argument("--road-file", metavar="CSV",
                       help="a road given by its centre line and widths (columns x_m, y_m, "
                            "w_tr_right_m, w_tr_left_m, one row per point; docs/roads.md), "
                            "driven from its first to its last point (--closed: a lap)")
    where.add_argument("--track", choices=sorted(_shipped_tracks()),
                       help="a circuit shipped with vehsim, driven as a lap")
    p.add_argument("--closed", action="store_true",
                   help="with --road-file: the road is a circuit and the drive a lap (periodic: "
                        "it ends in the state it started; default: as the file's '# closed:' "
                        "line says, which vehsim's road files have; else open)")
    p.add_argument("--smoothing", type=number(0.0, 10.0, unit="m"), default=None,
                   help="with --road-file or --track: the rms distance [m] allowed between the "
                        "file's points and the smoothed centre line (0: through the points)")
    p.add_argument("--start-speed", type=number(1.0, 100.0, unit="m/s"), default=None,
                   help="with --road-file: the speed at the start line [m/s] (default: free, a "
                        "flying start as on the benchmark roads)")
    p.add_argument("--margin", type=number(0.0, 10.0, unit="m"), default=None,
                   help="with --road-file or --track: keep the centre of gravity this far "
                        "inside the edges [m] (0)")
    p.add_argument("--objective", choices=["min-time", "max-exit"], default="min-time",
                   help="min-time: reach the exit line soonest; max-exit: the largest exit "
                        "speed within --tf-max (default: min-time)")
    p.add_argument("--tf-max", type=number(0.0, 60.0, lower_open=True, unit="s"), default=None,
                   help="time budget of max-exit [s], in (0, 60] (a benchmark road: 4.0, the "
                        "benchmark's, docs/maneuvers.md; a road file: required)")
    p.add_argument("--friction", type=number(0.0, 2.0, lower_open=True), default=0.52,
                   help="tire peak friction D, in (0, 2] (0.52)")
    p.add_argument("--segments", type=integer(2, 20_000), default=None,
                   help="shooting segments (one RK4 node each; the benchmark roads: 150, the "
                        "benchmark's; a road file: one per 2.5 m, 100 to 2000)")
    p.add_argument("--steps-per-stage", type=integer(1, 20), default=1,
                   help="RK4 steps per segment, each step's start a node (1)")
    p.add_argument("--interior-points", type=integer(0, 8), default=0,
                   help="corridor also at this many points inside every RK4 step, on RK4's "
                        "continuous extension (0)")
    p.add_argument("--no-corner-clearance", dest="corner_clearance", action="store_false",
                   help="impose the inner corners at the nodes only, without the clearance "
                        "(the depth by which the chord between consecutive nodes could cut "
                        "a corner) that keeps the path on the road between them")
    p.add_argument("--max-iter", type=integer(1, 100_000), default=500,
                   help="interior-point iteration limit (500)")
    p.add_argument("--starts", type=integer(1, 1024), default=1,
                   help="starting guesses solved together in one batched call (point-mass "
                        "seeds and centreline runs; the best is kept, every start's value "
                        "and status in the JSON), split over JAX's devices (on a CPU, "
                        "JAX_NUM_CPU_DEVICES=2 before the command gives two cores two "
                        "devices); 1: the default point-mass seed")
    p.add_argument("--out", default="results/optimise",
                   help="output folder (default: results/optimise)")
    p.add_argument("--quiet", action="store_true",
                   help="no iteration log (printed when the solve returns; with --starts, a "
                        "line per start)")
    p.add_argument("--live", action="store_true",
                   help="print each iteration's line while the solve runs (one solve; the "
                        "solver then compiles on every run, about a minute: a program with "
                        "host callbacks is not kept in the cache)")
    p.set_defaults(func=_optimise)


def _shipped_tracks() -> list[str]:
    """The shipped circuits' names (the CSV files of vehsim/data/tracks; read without importing
    the numerical packages, so that the command line answers at once)."""
    return [p.stem for p in (Path(__file__).resolve().parent.parent / "data" / "tracks").glob(
        "*.csv")]


def _optimise(args) -> int:
    if args.live and args.quiet:
        raise ValueError("--live prints every iteration and --quiet none: give one")
    if args.objective == "min-time" and args.tf_max is not None:
        raise ValueError("--tf-max is the time budget of --objective max-exit; the "
                         "minimum-time drive has none")
    if args.objective == "max-exit" and args.tf_max is None and args.road_file is not None \
            and not args.closed:  # a lap has no exit: refused with that reason below
        raise ValueError("--objective max-exit on a road file needs --tf-max, the time "
                         "budget [s] in (0, 60]: at least the road's minimum time "
                         "(--objective min-time gives it)")
    if args.tf_max is None:  # the benchmark's budget (unused by min-time)
        args.tf_max = 4.0
    if args.road is None:
        from .optimise_road import optimise_road

        args.smoothing = args.smoothing or 0.0
        args.margin = args.margin or 0.0
        return optimise_road(args)
    if args.closed:
        raise ValueError("--closed applies to --road-file (a benchmark road is a stage)")
    for option, value in (("--smoothing", args.smoothing), ("--margin", args.margin),
                          ("--start-speed", args.start_speed)):
        if value is not None:  # a benchmark road has its own edges, centre line and start
            raise ValueError(f"{option} applies to --road-file or --track, not to the "
                             f"benchmark road {args.road}")
    if args.segments is None:
        args.segments = 150
    import jax

    from .._compilation import primitive_and_bound
    from .._io import write_json_and_figure
    from .._result_files import with_units
    from ..optimal.primitive import solution_record
    from ..optimal.primitives import primitive_options, rally_gravel_car
    from ..plot import primitive_figure
    from ._status import waiting_line

    car = rally_gravel_car(args.friction)
    starts = {} if args.starts == 1 else {"starts": args.starts}
    live = args.live
    if live and args.starts > 1:
        raise ValueError("--live logs one solve; with --starts, each start's line is printed "
                         "when the solves return")
    opts = primitive_options(args.objective, args.starts, max_iter=args.max_iter,
                             verbose=not args.quiet and not live, live=live)
    print(f"vehsim optimise {args.road} --objective {args.objective}, {args.segments} segments: "
          + waiting_line(getattr(args, "cache_dir", None), "interior-point solver",
                         "exported/interior_point", "about a minute on 2 cores")
          + "; then solving" + ("" if live else " (the iteration log follows the solve; "
                                "--live prints it as it runs)"), file=sys.stderr, flush=True)
    # the plotting library is imported on another thread while the solver runs (its compiled
    # loop does not hold the interpreter's lock)
    with ThreadPoolExecutor(1) as pool:
        plotting = pool.submit(importlib.import_module, "matplotlib.pyplot")
        t0 = time.perf_counter()
        prim, bound = primitive_and_bound(
            args.road, args.objective, car=car, tf_max=args.tf_max, num_stages=args.segments,
            steps_per_stage=args.steps_per_stage, options=opts, throw=False,
            corner_clearance=args.corner_clearance, interior_points=args.interior_points,
            **starts)
        jax.block_until_ready(prim.solution.xs)
        wall = time.perf_counter() - t0
        plotting.result()
    rec = solution_record(prim, bound)
    rec["wall_time_s"] = wall
    out = Path(args.out)
    stem = f"{args.road}_{args.objective}"
    fig = primitive_figure(prim, title=f"{args.road}, {args.objective}: t_f = {rec['t_f']:.3f} s, "
                            f"exit {rec['exit_speed']:.2f} m/s")
    write_json_and_figure(out / f"{stem}.json", with_units(rec, UNITS), out / f"{stem}.png", fig)
    from ._status import unconverged_note

    print(f"status {rec['status']} ({rec['message']}), t_f = {rec['t_f']:.4f} s, exit speed "
          f"{rec['exit_speed']:.3f} m/s, max corridor violation "
          f"{rec['max_corridor_violation']:.2e} m at the nodes, "
          f"{rec['max_corridor_violation_between_nodes']:.2e} m between them, "
          f"{rec['iterations']} iterations, {wall:.1f} s; wrote {out / stem}.json/.png"
          f"{unconverged_note(rec)}",
          file=sys.stderr)
    from ._status import exit_status

    return exit_status("optimise", prim.solution.result, options=MAX_ITER_OPTION)
