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


def register(subparsers) -> None:
    from ..control.road.surfaces import SURFACES

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
    p.add_argument("--surface", default="dry_asphalt", help=f"one of: {', '.join(SURFACES)}")
    p.add_argument("--controller", default="estimate",
                   help=f"one of: {', '.join(CONTROLLER_NAMES)} (default: estimate)")
    p.add_argument("--speed", type=float, default=30.0, help="initial speed [m/s] (30)")
    p.add_argument("--change-to", default=None, help="a surface the road changes to")
    p.add_argument("--change-distance", type=float, default=math.inf,
                   help="distance [m] at which the surface changes")
    p.add_argument("--change-time", type=float, default=math.inf,
                   help="time [s] at which the surface changes")
    p.add_argument("--ideal-hardware", action="store_true",
                   help="switch every hardware effect off (the 200 Hz sampling remains)")
    p.add_argument("--seed", type=int, default=0, help="sensor noise seed (0)")
    p.add_argument("--out", default="brake_results", help="output folder (brake_results/)")
    p.set_defaults(func=_brake)


def _brake(args) -> int:
    import jax
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import save_figure, write_json
    from ..control.experiments.experiment import braking_experiment
    from ..control.plant.hardware import ideal_hardware, realistic_hardware
    from ..plot import braking_figure

    if args.change_to is not None and math.isinf(args.change_distance) \
            and math.isinf(args.change_time):
        raise ValueError("--change-to needs --change-distance or --change-time")
    hw = ideal_hardware() if args.ideal_hardware else realistic_hardware()
    print(f"vehsim brake: {args.controller} on {args.surface} from {args.speed:g} m/s",
          file=sys.stderr, flush=True)
    record, signals = braking_experiment(
        args.surface, args.controller, args.speed, args.change_to, args.change_distance,
        args.change_time, hw, jax.random.PRNGKey(args.seed))
    folder = Path(args.out)
    write_json(folder / "brake.json", record)
    change = f", to {args.change_to}" if args.change_to else ""
    fig = braking_figure(signals, title=f"{args.surface}{change} from {args.speed:g} m/s")
    save_figure(fig, folder / "brake.png")
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
