"""`vehsim optimise --road-file stage.csv [--closed]` and `vehsim optimise --track NAME`: the
minimum-time (or maximum-exit-speed) drive of the benchmark car along a road given by its
centre line and widths (`vehsim.road_primitive`), written as JSON (with the distance off the
road between the nodes) and a figure along the road (speed as colour, the car's footprint
at intervals)."""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path


STAGE_LENGTH = 2.5
"""Default stage length [m] of a centre-line road: ``--segments`` defaults to the road's
length over this, within `MIN_STAGES` and `MAX_STAGES`."""
MIN_STAGES, MAX_STAGES = 100, 2000
COARSE_STAGE_LENGTH = 4.5
"""Stage length [m] of the first solve (``coarse_stages`` of `vehsim.road_primitive`) where
the drive has more than 1.5 times as many stages and the first solve at least `MIN_STAGES`:
from the speed-profile guess a long fine problem may stall (a lap of a 3.7 km circuit
converges from it on 3.7 m stages, not on 9 m ones), and from the solution on
4.5 m stages it converges in tens of iterations."""


def coarse_stages(length: float, stages: int) -> int | None:
    """The stages of the first solve of a drive on ``stages`` (None: solved directly)."""
    coarse = math.ceil(length / COARSE_STAGE_LENGTH)
    return coarse if coarse >= MIN_STAGES and stages > 1.5 * coarse else None


def road_from_args(args):
    """The road the options name (read and checked before anything compiles)."""
    from .._road_files import read_road, track
    from ._options import input_file

    if args.track is not None:
        return track(args.track, smoothing=args.smoothing)
    return read_road(input_file("--road-file", args.road_file),
                     closed=True if args.closed else None,  # else as the file says
                     smoothing=args.smoothing)


def _check_margin(road, margin: float) -> None:
    """``--margin`` below half the road's width everywhere (sampled every 0.5 m or finer, so
    that the problem's own check at its nodes, which names its keyword rather than the
    option, is left only margins within a fraction of a millimetre of the limit), before
    anything compiles. The limit is written rounded down to the millimetre."""
    import numpy as np

    s = np.linspace(0.0, road.length, max(2001, math.ceil(road.length / 0.5) + 1))
    half = 0.5 * float(np.min(np.asarray(road.width_left(s)) + np.asarray(road.width_right(s))))
    if margin >= half:
        raise ValueError(f"--margin {margin:g} m leaves no road: it must be below half the "
                         f"road's width, {math.floor(1e3 * half) / 1e3:g} m where it is "
                         "narrowest")


GATE_SPEEDS = (1.0, 100.0)
"""The speeds [m/s] a road file's gate may fix: the range of ``--start-speed``."""


def _check_gates(road, where: str) -> None:
    """The road's gates as the road-frame problem can pose them (at the road's ends, a lap's
    free, speeds above its floor) and their speeds in `GATE_SPEEDS`, checked before anything
    compiles and refused naming the file (``where``)."""
    from ..optimal.curvilinear import _check_road

    lo, hi = GATE_SPEEDS
    for which, gate in (("start", road.start), ("end", road.end)):
        if gate.speed is not None and not lo <= gate.speed <= hi:
            raise ValueError(f"{where}: the {which}_gate's speed {gate.speed:g} m/s must lie in "
                             f"[{lo:g}, {hi:g}] m/s (the range of --start-speed)")
    try:
        _check_road(road)
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None


def default_stages(length: float) -> int:
    """Stages for a road of ``length`` [m]: one per `STAGE_LENGTH`, within the limits."""
    return int(min(MAX_STAGES, max(MIN_STAGES, math.ceil(length / STAGE_LENGTH))))


def _refuse_on_a_lap(args, said: str) -> None:
    """The options that need an open road, refused on the lap that ``said`` names."""
    if args.start_speed is not None:
        raise ValueError(f"--start-speed applies to an open road, and {said} names a lap (a "
                         "lap ends in the state it starts, at a speed of its own)")
    if args.objective == "max-exit":
        raise ValueError(f"--objective max-exit needs an open road, and {said} names a lap "
                         "(a lap has no exit); use --objective min-time")


def optimise_road(args) -> int:
    import jax

    from .._io import write_json_and_figure
    from .._result_files import with_units
    from ..optimal.curvilinear import (
        coarse_refusal,
        road_point_mass_bound,
        road_primitive,
    )
    from ..optimal.ip import IPOptions
    from ..optimal.primitives import rally_gravel_car
    from ..plot import path_on_road_figure
    from .optimise import MAX_ITER_OPTION, UNITS

    units = {**UNITS, "length": "m", "s": "m", "states.n": "m", "states.xi": "rad",
             "violations.speed_floor": "m/s", "start_speed": "m/s", "coarse.inf_pr": "1"}
    if args.starts != 1 or args.live:
        raise ValueError("--starts and --live apply to the benchmark roads; a road file or "
                         "track starts from its speed profile")
    if args.interior_points or not args.corner_clearance:
        raise ValueError("--interior-points and --no-corner-clearance apply to the benchmark "
                         "roads' corners; on a road file the corridor holds at each step's "
                         "midpoint as well as at the nodes")
    said = args.closed or args.track is not None  # known before the road is read
    if said:
        _refuse_on_a_lap(args, "--track" if args.track is not None else "--closed")
    road = road_from_args(args)  # read and checked, nothing compiled: a file says if closed
    if road.closed and not said:
        _refuse_on_a_lap(args, f"{args.road_file} (its '# closed: yes' line)")
    _check_margin(road, args.margin)
    if args.start_speed is not None:
        from ..optimal.centreline import Gate

        g = road.start  # the file's start gate, at the speed asked for
        road = road.with_gates(Gate.at(road, g.s, n_min=g.n_min, n_max=g.n_max,
                                       speed=args.start_speed), road.end)
    _check_gates(road, args.road_file if args.track is None else f"--track {args.track}")
    stages = args.segments if args.segments is not None else default_stages(road.length)
    coarse = coarse_stages(road.length, stages)
    kind = "lap" if road.closed else "stage"
    print(f"vehsim optimise {road.name}: a {road.length:.1f} m {kind}, {stages} stages of "
          f"{road.length / stages:.2f} m"
          + (f" (first solved on {coarse})" if coarse else "")
          + "; compiling the interior-point solver (about a minute on 2 cores), then solving",
          file=sys.stderr, flush=True)
    car = rally_gravel_car(args.friction)
    options = IPOptions(max_iter=args.max_iter, verbose=not args.quiet)
    t0 = time.perf_counter()
    prim = road_primitive(road, args.objective, car=car, num_stages=stages,
                          steps_per_stage=args.steps_per_stage,
                          margin=args.margin, tf_max=args.tf_max, coarse_stages=coarse,
                          options=options, throw=False)
    jax.block_until_ready(prim.solution.xs)
    wall = time.perf_counter() - t0
    if prim.coarse is not None and not bool(prim.coarse.converged):
        from .._results import result_name

        inf_pr = float(prim.coarse.inf_pr)
        start = (f"its best iterate (primal infeasibility {inf_pr:.1e})"
                 if prim.started_from_coarse else
                 f"the speed profile instead ({coarse_refusal(prim.coarse)})")
        print(f"vehsim optimise {road.name}: the first solve, on {coarse} stages, stopped with "
              f"{result_name(prim.coarse.result)} after {int(prim.coarse.iterations)} "
              f"iterations; the {stages} stages started from {start}", file=sys.stderr)
    bound = road_point_mass_bound(road, args.objective, D=args.friction,
                                  num_stages=min(stages, 500), tf_max=args.tf_max, throw=False)
    rec = prim.record(bound)
    rec["wall_time_s"] = wall
    rec["start_speed"] = road.start.speed  # --start-speed, or the file's start gate
    out = Path(args.out)
    stem = f"{road.name}_{args.objective}"
    st = rec["states"]
    speed = rec["signals"]["speed"]
    title = (f"{road.name}, {args.objective}: t = {rec['t_f']:.2f} s"
             + ("" if road.closed else f", exit {rec['exit_speed']:.1f} m/s")
             + f", off the road {100 * rec['max_corridor_violation_between_nodes']:.1f} cm")
    fig = path_on_road_figure(road, st["x"], st["y"], st["psi"], speed, title=title)
    write_json_and_figure(out / f"{stem}.json", with_units(rec, units), out / f"{stem}.png", fig)
    from ._status import unconverged_note

    print(f"status {rec['status']} ({rec['message']}), t_f = {rec['t_f']:.3f} s, exit speed "
          f"{rec['exit_speed']:.2f} m/s, off the road at the nodes "
          f"{rec['max_corridor_violation']:.2e} m and between them "
          f"{rec['max_corridor_violation_between_nodes']:.2e} m, {rec['iterations']} "
          f"iterations, {wall:.1f} s; wrote {out / stem}.json/.png"
          f"{unconverged_note(rec)}", file=sys.stderr)
    from ._status import exit_status

    return exit_status("optimise", prim.solution.result, options=MAX_ITER_OPTION)
