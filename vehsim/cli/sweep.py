"""`vehsim sweep`: a grid of half-car maneuvers, sharded over every device, to one JSON file."""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "sweep",
        help="simulate a grid of half-car scenarios (sharded over all devices), write JSON",
        description=(
            "Run a grid of HalfCar maneuvers. --set NAME=V1,V2,... adds a grid axis; NAME "
            "is a HalfCarParams field (m, Iz, h, K_F, ...), a tire field (B, C, D for the "
            "friction-ellipse tire) or a maneuver argument (speed, delta, brake_torque, "
            "t_brake, drive_torque, ...). Every value is checked before the run."
        ),
    )
    p.add_argument("--maneuver", choices=["step_steer", "brake_in_turn"], default="step_steer")
    p.add_argument("--vehicle", default="rally_gravel", help="vehicle preset")
    p.add_argument("--tire", default="rally_gravel_tire", help="tire preset")
    p.add_argument("--set", dest="axes", action="append", default=[], metavar="NAME=V1,V2",
                   help="a grid axis (repeatable)")
    p.add_argument("--speed", type=float, default=20.0, help="initial speed [m/s]")
    p.add_argument("--duration", type=float, default=5.0, help="simulated time [s]")
    p.add_argument("--samples", type=int, default=101, help="saved time samples")
    p.add_argument("--signals", action="store_true", help="also write every signal's history")
    p.add_argument("--out", default="sweep.json", help="output JSON file")
    p.set_defaults(func=_sweep)


def parse_axes(items: list[str]) -> dict[str, list[float]]:
    """``["m=1200,1450", "delta=0.1"]`` -> ``{"m": [1200.0, 1450.0], "delta": [0.1]}``."""
    axes = {}
    for item in items:
        name, sep, values = item.partition("=")
        if not sep or not values:
            raise ValueError(f"--set expects NAME=V1,V2,..., got {item!r}")
        try:
            axes[name.strip()] = [float(v) for v in values.split(",")]
        except ValueError:
            raise ValueError(f"--set {name}: values must be numbers, got {values!r}") from None
    return axes


def summary(traj) -> dict[str, Any]:
    """Scalar outcomes of one half-car run (final speed and pose, peaks of sideslip, yaw
    rate, lateral acceleration and loads, solver steps)."""
    import jax.numpy as jnp

    s = traj.signals
    return {
        "final_speed": s["speed"][-1],
        "max_abs_sideslip": jnp.max(jnp.abs(s["sideslip"])),
        "max_abs_yaw_rate": jnp.max(jnp.abs(s["yaw_rate"])),
        "max_abs_ay": jnp.max(jnp.abs(s["ay"])),
        "max_Fz_F": jnp.max(s["Fz_F"]),
        "min_Fz_R": jnp.min(s["Fz_R"]),
        "max_theta": jnp.max(s["theta"]),
        "final_x": s["x"][-1],
        "final_y": s["y"][-1],
        "final_psi": s["psi"][-1],
        "num_steps": traj.num_steps,
    }


def _sweep(args: argparse.Namespace) -> int:
    import jax
    import jax.numpy as jnp

    from .._io import write_json
    from .._results import result_message_of_name, result_name
    from ..params import preset
    from ..sharding import num_members
    from ..sweep import sweep, sweep_grid
    from ..vehicle.maneuvers import half_car_scenario

    axes = parse_axes(args.axes)
    params, tire = preset(args.vehicle), preset(args.tire)
    members = sweep_grid(**axes) if axes else {"speed": jnp.asarray([args.speed])}
    names = list(members)
    n = num_members(members)
    scenario = half_car_scenario(params, tire, args.maneuver, args.speed, names)
    print(f"vehsim sweep: {n} members x {args.duration} s on {len(jax.devices())} device(s)",
          file=sys.stderr, flush=True)
    ts = jnp.linspace(0.0, args.duration, args.samples)
    t0 = time.perf_counter()
    res = sweep(scenario, members, ts)
    jax.block_until_ready(res.trajectories.states)
    wall = time.perf_counter() - t0
    stats = jax.vmap(summary)(res.trajectories)
    statuses = result_name(res.result)
    out = {
        "maneuver": args.maneuver, "vehicle": args.vehicle, "tire": args.tire,
        "speed": args.speed, "duration": args.duration, "axes": axes,
        "num_devices": res.num_devices, "wall_time_s": round(wall, 3),
        "members": [
            {
                **{k: float(members[k][i]) for k in names},
                "ok": statuses[i] == "successful",
                "status": statuses[i],
                "message": result_message_of_name(statuses[i]),
                **{k: v[i] for k, v in stats.items()},
                **({"signals": {k: v[i] for k, v in res.trajectories.signals.items()}}
                   if args.signals else {}),
            }
            for i in range(n)
        ],
    }
    if args.signals:
        out["ts"] = ts
    path = write_json(args.out, out)
    n_ok = statuses.count("successful")
    print(f"vehsim sweep: {n_ok}/{n} ok in {wall:.1f} s (compile included); wrote {path}",
          file=sys.stderr)
    return 0 if n_ok == n else 1
