"""`vehsim brake --surface wet_asphalt --controller estimate --speed 30`: one closed-loop
braking on a named surface (optionally changing to another), with a locked wheel beside it,
judged against the physical limit (`vehsim.control`)."""

from __future__ import annotations

import math
import sys
from pathlib import Path


CONTROLLER_NAMES = ("locked", "rule", "fixed", "estimate", "seek")
"""The keys of `vehsim.control.experiments.scenarios.CONTROLLERS`, spelled out here so that building the
command line does not import the controllers (which would slow down every command)."""


UNITS = {"theta_true": "1", "theta_estimate": "1", "theta_bias": "1"}
"""Units of brake.json's fields that their names do not carry (the road condition theta of
the LuGre tire is dimensionless; the bias is relative)."""

MAX_SPEED = 100.0
"""Largest initial speed [m/s] the command accepts (360 km/h)."""


def register(subparsers) -> None:
    from ..control.loop import STOP_SPEED
    from ..control.road.surfaces import SURFACES
    from ._options import choice_of, integer, number

    p = subparsers.add_parser(
        "brake", help="closed-loop braking: ABS, slip tracking, friction estimation",
        description="Brake the quarter car with the lumped LuGre tire on a named surface "
        "through the realistic hardware (actuator delay, rate limit and lag; tone wheel; "
        "speed noise) and write brake.json (stopping_distance_m, bound_distance_m, "
        "distance_over_bound, the same against the limit on this hardware "
        "(actuated_bound_distance_m, distance_over_actuated_bound), the locked wheel "
        "beside them, the estimate of theta, status) "
        "and brake.png (speed, wheel slip, friction used vs available, estimated theta, "
        "brake command, distance).")
    surfaces = choice_of(SURFACES, "surface")
    p.add_argument("--surface", default="dry_asphalt", type=surfaces,
                   help=f"road surface: one of {', '.join(SURFACES)} (dry_asphalt)")
    p.add_argument("--controller", default="estimate",
                   type=choice_of(CONTROLLER_NAMES, "controller"),
                   help=f"one of: {', '.join(CONTROLLER_NAMES)} (default: estimate)")
    p.add_argument("--speed", type=number(STOP_SPEED, MAX_SPEED, lower_open=True, unit="m/s"),
                   default=30.0,
                   help=f"initial speed [m/s], above the stop speed {STOP_SPEED:g} and at most "
                        f"{MAX_SPEED:g} (30)")
    p.add_argument("--change-to", default=None, type=surfaces,
                   help="a surface the road changes to (needs --change-distance or "
                        "--change-time)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--change-distance", type=number(0.0, unit="m", allow_inf=True),
                       default=math.inf, help="distance [m] at which the surface changes")
    where.add_argument("--change-time", type=number(0.0, unit="s", allow_inf=True),
                       default=math.inf, help="time [s] at which the surface changes")
    p.add_argument("--ideal-hardware", action="store_true",
                   help="switch every hardware effect off (the 200 Hz sampling remains)")
    p.add_argument("--seed", type=integer(0, 2**32 - 1), default=0,
                   help="sensor noise seed (0)")
    p.add_argument("--out", default="brake_results", help="output folder (brake_results/)")
    p.set_defaults(func=_brake)


def figure_title(args) -> str:
    """The brake figure's title: controller, hardware, road (and its change), speed."""
    where = ""
    if args.change_to:
        where = (f" at {args.change_distance:g} m" if math.isfinite(args.change_distance)
                 else f" at {args.change_time:g} s")
        where = f", changing to {args.change_to}{where} (dash-dot line)"
    hardware = "ideal" if args.ideal_hardware else "realistic"
    return (f"controller {args.controller!r} (beside a locked wheel), {hardware} hardware: "
            f"{args.surface}{where}, from {args.speed:g} m/s")


def _brake(args) -> int:
    import jax
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import write_json_and_figure
    from .._result_files import with_units
    from ..control.experiments.experiment import braking_experiment
    from ..control.plant.hardware import ideal_hardware, realistic_hardware
    from ..plot import braking_figure
    from ._status import waiting_line

    if args.change_to is not None and math.isinf(args.change_distance) \
            and math.isinf(args.change_time):
        raise ValueError("--change-to needs a finite --change-distance or --change-time "
                         "(inf, their default, is a change that never comes)")
    if args.change_to is not None and args.change_to == args.surface:
        raise ValueError(f"--change-to {args.change_to} is the --surface already: a change "
                         "needs another surface")
    if args.change_to is None and not (math.isinf(args.change_distance)
                                       and math.isinf(args.change_time)):
        raise ValueError("--change-distance and --change-time need --change-to")
    hw = ideal_hardware() if args.ideal_hardware else realistic_hardware()
    print(f"vehsim brake: {args.controller} on {args.surface} from {args.speed:g} m/s; "
          + waiting_line(getattr(args, "cache_dir", None), "closed loop and its limits",
                         "jit_closed_loop_grid", "30-60 s on 2 cores"),
          file=sys.stderr, flush=True)
    record, signals = braking_experiment(
        args.surface, args.controller, args.speed, args.change_to, args.change_distance,
        args.change_time, hw, jax.random.PRNGKey(args.seed))
    folder = Path(args.out)
    fig = braking_figure(signals, title=figure_title(args))
    write_json_and_figure(folder / "brake.json", with_units(record, UNITS),
                          folder / "brake.png", fig)
    plt.close(fig)
    print(f"wrote {folder / 'brake.json'} and {folder / 'brake.png'}", file=sys.stderr)
    print(f"  stopping distance {record['stopping_distance_m']:.2f} m, limit "
          f"{record['bound_distance_m']:.2f} m: {record['distance_over_bound']:.4f} of it "
          f"(locked wheel {record['locked_wheel']['distance_over_bound']:.4f}); limit on this "
          f"hardware {record['actuated_bound_distance_m']:.2f} m: "
          f"{record['distance_over_actuated_bound']:.4f}",
          file=sys.stderr)
    from .._results import result_of_record
    from ._status import exit_status

    return exit_status("brake", result_of_record(record))
