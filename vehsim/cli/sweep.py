"""`vehsim sweep`: a grid of half-car maneuvers, sharded over every device, to one JSON or
netCDF file."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from .._io import parse_number
from ._options import number


SPEED = number(0.0, 100.0, lower_open=True, unit="m/s")
"""The initial speed's type: a number in (0, 100] m/s (``--speed`` and ``--set speed``)."""


def register(subparsers) -> None:
    from ._options import integer

    p = subparsers.add_parser(
        "sweep",
        help="simulate a grid of half-car scenarios (sharded over all devices), write JSON or netCDF",
        description=(
            "Run a grid of HalfCar maneuvers. --set NAME=V1,V2,... adds a grid axis; NAME "
            "is a HalfCarParams field (m, Iz, h, K_F, ...), a tire field (B, C, D for the "
            "friction-ellipse tire) or a maneuver argument (speed, delta, brake_torque, "
            "t_brake, drive_torque, ...). Every value is checked before the run."
        ),
    )
    p.add_argument("--maneuver", choices=["step_steer", "brake_in_turn"], default="step_steer",
                   help="the maneuver (step_steer)")
    p.add_argument("--vehicle", default="rally_gravel", type=preset_of_kind("vehicle_params"),
                   help=f"vehicle preset: {', '.join(presets_of_kind('vehicle_params'))} "
                        "(rally_gravel)")
    p.add_argument("--tire", default="rally_gravel_tire", type=preset_of_kind("tire"),
                   help=f"tire preset: {', '.join(presets_of_kind('tire'))} (rally_gravel_tire)")
    p.add_argument("--set", dest="axes", action="append", default=[], metavar="NAME=V1,V2",
                   help="a grid axis (repeatable)")
    p.add_argument("--speed", type=SPEED, default=None,
                   help="initial speed [m/s], in (0, 100] (20); a --set speed axis, which "
                        "takes the same range, replaces it")
    p.add_argument("--duration", type=number(0.0, 600.0, lower_open=True, unit="s"),
                   default=5.0, help="simulated time [s], in (0, 600] (5)")
    p.add_argument("--samples", type=integer(2, 100_000), default=101,
                   help="saved time samples, at least 2 (101)")
    p.add_argument("--signals", action="store_true", help="also write every signal's history")
    p.add_argument("--batch-size", type=integer(0), default=None,
                   help="members per vmapped chunk on each device (progress is counted per "
                        "chunk; default: a tenth of a device's share, at most 64; 0: the "
                        "whole share at once, better on a GPU)")
    g = p.add_argument_group(
        "several processes or hosts (jax.distributed.initialize; docs/sweeps.md)")
    g.add_argument("--distributed", action="store_true",
                   help="join a multi-process run, its settings detected from the cluster "
                        "(SLURM, Open MPI, ...)")
    g.add_argument("--coordinator", metavar="HOST:PORT",
                   help="address of process 0's coordinator service (implies --distributed)")
    g.add_argument("--num-processes", type=integer(1), help="number of processes in the run")
    g.add_argument("--process-id", type=integer(0),
                   help="this process's id, 0 to num-processes - 1")
    p.add_argument("--out", default="sweep.json",
                   help="output file: .json, or netCDF if it ends in .nc (needs vehsim[xarray])")
    p.set_defaults(func=_sweep, out_kind="file")


def parse_axes(items: list[str]) -> dict[str, list[float]]:
    """``["m=1200,1450", "delta=0.1"]`` -> ``{"m": [1200.0, 1450.0], "delta": [0.1]}``;
    an axis named twice, or a value that is not a finite number, is refused."""
    import math

    axes = {}
    for item in items:
        name, sep, values = item.partition("=")
        name = name.strip()
        if not sep or not values or not name:
            raise ValueError(f"--set expects NAME=V1,V2,..., got {item!r}")
        if name in axes:
            raise ValueError(f"--set {name}: the axis is given twice; list its values in one "
                             f"flag, --set {name}=V1,V2,...")
        try:
            axes[name] = [parse_number(v) for v in values.split(",")]
        except ValueError:
            raise ValueError(f"--set {name}: values must be numbers, got {values!r}") from None
        if not all(math.isfinite(v) for v in axes[name]):
            raise ValueError(f"--set {name}: values must be finite numbers, got {values!r}")
    return axes


def presets_of_kind(kind: str) -> list[str]:
    """The names of the presets of `kind` (`vehsim.params.PRESET_KINDS`)."""
    from ..params import PRESET_KINDS

    return [name for name, k in PRESET_KINDS.items() if k == kind]


def preset_of_kind(kind: str):
    """An argparse type: the name of a preset of `kind`."""
    from ._options import choice_of

    return choice_of(presets_of_kind(kind), f"{kind.replace('_', ' ')} preset")


def summary(traj) -> dict[str, Any]:
    """Scalar outcomes of one half-car run (final speed and pose, peaks of sideslip, yaw
    rate, lateral acceleration and loads, solver steps). A negative least load is an axle
    that lifted (the model clips its load at 0: no friction on it, `HalfCar`)."""
    import jax.numpy as jnp

    s = traj.signals
    return {
        "final_speed": s["speed"][-1],
        "max_abs_sideslip": jnp.max(jnp.abs(s["sideslip"])),
        "max_abs_yaw_rate": jnp.max(jnp.abs(s["yaw_rate"])),
        "max_abs_ay": jnp.max(jnp.abs(s["ay"])),
        "max_Fz_F": jnp.max(s["Fz_F"]),
        "min_Fz_F": jnp.min(s["Fz_F"]),
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

    from .._results import is_successful
    from .._sweep import check_members, sweep, sweep_grid
    from ..params import preset
    from ..sharding import num_members
    from ..vehicle.maneuvers import half_car_scenario
    from ._options import output_file
    from ._status import exit_status

    axes = parse_axes(args.axes)
    if "speed" in axes and args.speed is not None:
        raise ValueError("--speed and --set speed both give the initial speed: give one "
                         "(--set speed=V1,V2,... for an axis)")
    args.speed = 20.0 if args.speed is None else args.speed
    for v in axes.get("speed", []):
        try:
            SPEED(repr(v))
        except argparse.ArgumentTypeError as e:
            raise ValueError(f"--set speed: {e}") from None
    output_file("--out", args.out, {".json": "json", ".nc": "netcdf"})
    check_process_ids(args)
    if args.distributed or args.coordinator:
        join_distributed(args)
    params, tire = preset(args.vehicle), preset(args.tire)
    members = sweep_grid(**axes) if axes else {"speed": jnp.asarray([args.speed])}
    n = num_members(members)
    scenario = half_car_scenario(params, tire, args.maneuver, args.speed, list(members))
    try:  # every value's range, before the run is announced
        check_members(scenario, members)
    except ValueError as e:  # "NAME=VALUE: <the model's check>": the axis that gave it
        raise ValueError(f"--set {e}" if axes else str(e)) from None
    where = f"{len(jax.devices())} device(s)" + (
        f" of {jax.process_count()} processes (this is process {jax.process_index()})"
        if jax.process_count() > 1 else "")
    print(f"vehsim sweep: {n} members x {args.duration} s on {where}", file=sys.stderr,
          flush=True)
    ts = jnp.linspace(0.0, args.duration, args.samples)
    t0 = time.perf_counter()
    batch_size = default_batch_size(n) if args.batch_size is None else args.batch_size or None
    res = sweep(scenario, members, ts, batch_size=batch_size, check=False)
    wall = time.perf_counter() - t0
    n_ok = int(jnp.sum(is_successful(res.result)))
    if jax.process_index() != 0:  # every process has the gathered result; process 0 writes
        return exit_status("sweep", res.result)
    stats = jax.vmap(summary)(res.trajectories)
    info = {"maneuver": args.maneuver, "vehicle": args.vehicle, "tire": args.tire,
            "duration": args.duration} | ({} if "speed" in axes else {"speed": args.speed})
    if Path(args.out).suffix.lower() == ".nc":  # as `output_file` reads it
        path = res.to_netcdf(args.out, signals=args.signals, outputs=stats,
                             attrs=info | {"wall_time_s": round(wall, 3)})
    else:
        path = _write_json(args.out, res, stats, info | {"axes": axes}, wall, args.signals)
    print(f"vehsim sweep: {n_ok}/{n} ok in {wall:.1f} s (compile included); wrote {path}",
          file=sys.stderr)
    lifted = int(jnp.sum((stats["min_Fz_F"] < 0) | (stats["min_Fz_R"] < 0)))
    if lifted:
        print(f"vehsim sweep: note: in {lifted} of {n} members an axle lifted (min_Fz_F or "
              "min_Fz_R below 0): the half car then runs that axle unloaded, without "
              "friction", file=sys.stderr)
    return exit_status("sweep", res.result)


_BOOT = ("import json, os, sys\nos.dup2(2, 1)\nimport jax\ntry:\n"
         "    jax.distributed.initialize(**json.loads(sys.argv[1]))\n"
         "except (ValueError, RuntimeError) as e:\n"
         "    print(f'vehsim: error: --distributed: the multi-process runtime did not start: {e}',"
         " file=sys.stderr)\n    sys.exit(2)\n"
         "from vehsim.cli import main\nsys.exit(main(sys.argv[2:]))")
"""The restarted process: JAX's multi-process runtime first (a failure to start it, such as
no cluster detected, ends with exit status 2 and its reason), then the command. Its stdout
is joined to stderr first: a sweep writes nothing there, and the CPU collectives (gloo)
print their connection line ("[Gloo] Rank 0 is connected to ...") on the C library's
stdout, where a log and its data would mix."""


def check_process_ids(args: argparse.Namespace) -> None:
    """--coordinator as HOST:PORT; --process-id in [0, --num-processes - 1]; both only with
    --distributed or --coordinator (a single process has neither)."""
    given = args.num_processes is not None or args.process_id is not None
    if given and not (args.distributed or args.coordinator):
        raise ValueError("--num-processes and --process-id belong to a multi-process run: "
                         "give --distributed or --coordinator too")
    if args.coordinator is not None:
        host, sep, port = args.coordinator.rpartition(":")
        if not (sep and host and port.isdigit() and 0 < int(port) < 65536):
            raise ValueError(f"--coordinator must be HOST:PORT with PORT in [1, 65535], got "
                             f"{args.coordinator!r}")
    if (args.num_processes is not None and args.process_id is not None
            and args.process_id >= args.num_processes):
        raise ValueError(f"--process-id must be in [0, {args.num_processes - 1}] "
                         f"(--num-processes {args.num_processes}), got {args.process_id}")


def join_distributed(args: argparse.Namespace) -> None:
    """Join a multi-process run (`jax.distributed.initialize`). JAX's runtime must start
    before the first array exists, and vehsim's modules create arrays when imported (presets,
    default options): so, unless it is already started, the command restarts its process
    (same process id, same arguments) with the runtime started first."""
    import jax

    if jax.distributed.is_initialized():
        return
    if args.coordinator and (args.num_processes is None or args.process_id is None):
        raise ValueError("--coordinator needs --num-processes and --process-id")
    settings = {"coordinator_address": args.coordinator, "num_processes": args.num_processes,
                "process_id": args.process_id}
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(sys.executable, [sys.executable, "-c", _BOOT, json.dumps(settings), *args.argv])


def default_batch_size(n: int) -> int:
    """Members per chunk on each device: about a tenth of a device's share (so progress
    moves in steps of about 10 %), at most 64 (a good chunk on a CPU core)."""
    import jax

    share = -(-n // len(jax.devices()))
    return max(1, min(64, -(-share // 10)))


def _write_json(out, res, stats, info, wall, signals) -> Path:
    """The sweep as JSON: one record per member (parameters, status, summary outputs)."""
    import numpy as np

    from .._io import write_json
    from .._result_files import with_units
    from .._results import is_successful, result_message_of_name, result_name

    members, statuses = res.members, result_name(res.result)
    ok = np.asarray(is_successful(res.result))
    rows = [
        {
            **{k: float(v[i]) for k, v in members.items()},
            "ok": bool(ok[i]),
            "status": statuses[i],
            "message": result_message_of_name(statuses[i]),
            **{k: v[i] for k, v in stats.items()},
            **({"signals": {k: v[i] for k, v in res.trajectories.signals.items()}}
               if signals else {}),
        }
        for i in range(len(statuses))
    ]
    out_data = {**info, "num_devices": res.num_devices, "wall_time_s": round(wall, 3),
                "members": rows}
    if signals:
        out_data["ts"] = res.trajectories.ts[0]
    # the axes are any model field or maneuver argument: those vehsim knows get their units
    return write_json(out, with_units(out_data, {"duration": "s"}, strict=False))
