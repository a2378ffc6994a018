r"""Batched sweeps: many `simulate` runs at once, sharded across every JAX device.

`sweep(scenario, members, ts)` runs ``simulate(*scenario(member), ts, throw=False)`` for
every member (a PyTree of arrays with a leading batch axis, e.g. from `grid`), vmapped and
split across a one-dimensional device mesh with `jax.shard_map`: each device integrates
its own slice (its adaptive solves stop when *its* members are done), and the same call
uses one CPU, several GPUs or several hosts. A failed member does not stop the sweep: it
gets ``ok = False`` and its diffrax status.

`vehsim sweep` (command line) runs a grid of vehicle, tire and maneuver parameters through
the `HalfCar` and writes one JSON file.
"""

from __future__ import annotations

import argparse
import functools
import itertools
import math
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
from jaxtyping import Array, Bool, PyTree

from .simulate import Trajectory, simulate


class SweepResult(eqx.Module):
    """Per-member results of `sweep` (every leaf has the member axis first).

    - `members`: the inputs, as given.
    - `trajectories`: a batched `Trajectory` (`trajectories["vx"]` has shape ``(N, T)``).
    - `ok`: the solve succeeded and every state is finite.
    - `status`: diffrax result codes (0 = successful); see `status_message`.
    - `num_devices`: how many devices the sweep was split across.
    """

    members: PyTree
    trajectories: Trajectory
    ok: Bool[Array, " N"]
    status: Array
    num_devices: int = eqx.field(static=True)


_NONFINITE = 9  # diffrax's code for "non-finite values detected"


def status_message(code: int) -> str:
    """The diffrax message for a result code ('successful' for 0)."""
    try:
        msg = dfx.RESULTS._index_to_message[int(code)]  # noqa: SLF001 (no public map)
    except (AttributeError, IndexError):
        return f"status {int(code)}"
    return "successful" if not msg else msg.split("\n")[0]


def grid(**axes: Sequence[float]) -> dict[str, Array]:
    """Cartesian product of named value lists, flattened: ``grid(m=[1, 2], h=[3, 4, 5])``
    gives 6 members, ``{"m": [1, 1, 1, 2, 2, 2], "h": [3, 4, 5, 3, 4, 5]}``."""
    names = list(axes)
    values = [np.atleast_1d(np.asarray(axes[n], dtype=float)) for n in names]
    rows = list(itertools.product(*values))
    return {n: jnp.asarray([r[i] for r in rows], dtype=float) for i, n in enumerate(names)}


def _num_members(members) -> int:
    leaves = jax.tree.leaves(members)
    if not leaves:
        raise ValueError("sweep needs at least one array in `members`")
    n = {jnp.shape(x)[0] if jnp.ndim(x) else -1 for x in leaves}
    if len(n) != 1 or -1 in n:
        raise ValueError(f"every leaf of `members` needs the same leading axis, got sizes {n}")
    return n.pop()


def pad_members(members: PyTree, multiple: int) -> PyTree:
    """Pad the leading (member) axis of every leaf to a multiple of `multiple` by repeating
    the last member (drop the padding from the results with ``x[:n]``)."""
    n = _num_members(members)
    n_pad = math.ceil(n / multiple) * multiple
    return jax.tree.map(
        lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], n_pad - n, axis=0)]), members
    )


def sharded_vmap(
    fn: Callable,
    devices: Sequence[jax.Device] | None = None,
    in_axes: int | None | tuple = 0,
    batch_size: int | None = None,
) -> Callable:
    r"""``jax.vmap(fn, in_axes)`` with the member axis split across `devices`.

    A one-dimensional mesh (axis ``"members"``) and `jax.shard_map`: each device runs the
    vmapped `fn` on its own slice of the members (an adaptive solve inside stops when *its*
    members are done), arguments with ``in_axes`` None are replicated; every output has the
    member axis first. The member count must be a multiple of the device count (see
    `pad_members`). Wrap the result in `jax.jit`. On a CPU host, forcing one host device
    per core (``XLA_FLAGS=--xla_force_host_platform_device_count=N`` before JAX starts)
    runs one shard per core.

    `batch_size`: if given, each device runs its slice in vmapped chunks of this many
    members one after another (`jax.lax.map`): each chunk's adaptive solves stop at the
    chunk's slowest member instead of the slice's, and a chunk's working set stays in
    cache (on CPU; on a GPU keep the whole slice in one chunk).
    """
    devices = list(jax.devices() if devices is None else devices)
    mesh = Mesh(np.asarray(devices), ("members",))

    def run(*args):
        axes = in_axes if isinstance(in_axes, tuple) else (in_axes,) * len(args)
        specs = tuple(P() if a is None else P("members") for a in axes)
        return jax.shard_map(functools.partial(_chunked_vmap, fn, axes, batch_size),
                             mesh=mesh, in_specs=specs, out_specs=P("members"),
                             check_vma=False)(*args)

    return run


def _chunked_vmap(fn, axes, batch_size, *args):
    if batch_size is None:
        return jax.vmap(fn, in_axes=axes)(*args)
    mapped = [a for a, ax in zip(args, axes) if ax is not None]

    def one(member_args):
        it = iter(member_args)
        return fn(*(a if ax is None else next(it) for a, ax in zip(args, axes)))

    return jax.lax.map(one, mapped, batch_size=batch_size)


def sweep(
    scenario: Callable[[PyTree], tuple[Any, Any, Any]],
    members: PyTree,
    ts,
    *,
    devices: Sequence[jax.Device] | None = None,
    batch_size: int | None = None,
    **simulate_kwargs,
) -> SweepResult:
    r"""Simulate every member of a batch, sharded across devices, with per-member status.

    **Arguments:**

    - `scenario`: ``member -> (vehicle, inputs, state0)`` for one member (the arguments of
      `simulate`); traced once, under `vmap`.
    - `members`: a PyTree of arrays whose leading axis indexes the members (see `grid`).
    - `ts`: save times shared by all members.
    - `devices`: devices to split the members across (default: all, `jax.devices()`).
      The member count is padded to a multiple of the device count (padding is dropped).
    - `batch_size`: members per vmapped chunk on each device (see `sharded_vmap`; default:
      the device's whole slice at once).
    - `simulate_kwargs`: passed to `simulate` (solver, tolerances, `max_steps`, ...);
      `throw` is always False.

    **Returns:** a `SweepResult`.
    """
    devices = list(jax.devices() if devices is None else devices)
    n_dev = len(devices)
    n = _num_members(members)
    padded = pad_members(members, n_dev)
    ts = jnp.asarray(ts, dtype=float)
    simulate_kwargs = dict(simulate_kwargs, throw=False)
    padded = jax.device_put(padded, NamedSharding(Mesh(np.asarray(devices), ("members",)),
                                                  P("members")))
    traj, ok, code = _sweep_run(scenario, padded, ts, tuple(devices), batch_size,
                                simulate_kwargs)
    traj, ok, code = jax.tree.map(lambda x: x[:n], (traj, ok, code))
    return SweepResult(members=members, trajectories=traj, ok=ok, status=code, num_devices=n_dev)


@eqx.filter_jit
@eqx.debug.assert_max_traces(max_traces=None)  # counts traces: tests/test_sweep.py checks reuse
def _sweep_run(scenario, padded, ts, devices, batch_size, simulate_kwargs):
    """The jitted body of `sweep`: compiled once per scenario function, shapes, devices and
    solver settings, so repeated sweeps (e.g. over other member values) reuse it."""
    def one(member):
        vehicle, inputs, state0 = scenario(member)
        traj = simulate(vehicle, ts, inputs, state0, **simulate_kwargs)
        finite = jnp.all(jnp.isfinite(traj.states))
        ok = traj.ok & finite
        code = jnp.where(traj.ok & ~finite, _NONFINITE, traj.result._value)  # noqa: SLF001
        return traj, ok, code

    return sharded_vmap(one, list(devices), batch_size=batch_size)(padded)


# ----------------------------------------------------------------------------- CLI


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "sweep",
        help="simulate a grid of half-car scenarios (sharded over all devices), write JSON",
        description=(
            "Run a grid of HalfCar maneuvers. --set NAME=V1,V2,... adds a grid axis; NAME "
            "is a HalfCarParams field (m, Iz, h, K_F, ...), a tire field (B, C, D for the "
            "friction-ellipse tire) or a maneuver argument (speed, delta, brake_torque, "
            "t_brake, drive_torque, ...)."
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
    p.set_defaults(func=_cli)


def _parse_axes(items: list[str]) -> dict[str, list[float]]:
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


def half_car_scenario(params, tire, maneuver: str, speed: float, axes: Sequence[str]):
    """``member -> (HalfCar, inputs, state0)`` for a grid over vehicle/tire/maneuver names."""
    import inspect

    from .vehicle.half_car import HalfCar
    from .vehicle.maneuvers import MANEUVERS

    build = MANEUVERS[maneuver]
    maneuver_args = set(inspect.signature(build).parameters) | {"speed"}
    vehicle_fields = set(type(params).__dataclass_fields__)
    tire_fields = {k for k, v in vars(tire).items() if eqx.is_array(v)}
    for name in axes:
        if name not in vehicle_fields | tire_fields | maneuver_args:
            raise ValueError(
                f"unknown sweep axis {name!r}; vehicle fields {sorted(vehicle_fields)}, "
                f"tire fields {sorted(tire_fields)}, maneuver arguments {sorted(maneuver_args)}"
            )
    defaults = {"delta": 0.1, "brake_torque": 1500.0}

    def scenario(member):
        p = eqx.tree_at(lambda q: [getattr(q, k) for k in axes if k in vehicle_fields],
                        params, [member[k] for k in axes if k in vehicle_fields])
        t = eqx.tree_at(lambda q: [getattr(q, k) for k in axes if k in tire_fields],
                        tire, [member[k] for k in axes if k in tire_fields])
        kw = {k: member[k] for k in axes if k in maneuver_args and k != "speed"}
        for k, v in defaults.items():
            if k in inspect.signature(build).parameters:
                kw.setdefault(k, v)
        car = HalfCar(p, t)
        v0 = member["speed"] if "speed" in member else speed
        return car, build(**kw), car.init_state(vx=v0)

    return scenario


def _summary(traj: Trajectory) -> dict[str, Any]:
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


def _cli(args: argparse.Namespace) -> int:
    from ._io import write_json
    from .params import preset

    axes = _parse_axes(args.axes)
    params, tire = preset(args.vehicle), preset(args.tire)
    members = grid(**axes) if axes else {"speed": jnp.asarray([args.speed])}
    names = list(members)
    n = _num_members(members)
    print(f"vehsim sweep: {n} members x {args.duration} s on {len(jax.devices())} device(s)",
          file=sys.stderr, flush=True)
    scenario = half_car_scenario(params, tire, args.maneuver, args.speed, names)
    ts = jnp.linspace(0.0, args.duration, args.samples)
    t0 = time.perf_counter()
    res = sweep(scenario, members, ts)
    jax.block_until_ready(res.ok)
    wall = time.perf_counter() - t0
    summary = jax.vmap(_summary)(res.trajectories)
    out = {
        "maneuver": args.maneuver, "vehicle": args.vehicle, "tire": args.tire,
        "speed": args.speed, "duration": args.duration, "axes": axes,
        "num_devices": res.num_devices, "wall_time_s": round(wall, 3),
        "members": [
            {
                **{k: float(members[k][i]) for k in names},
                "ok": bool(res.ok[i]),
                "status": status_message(int(res.status[i])),
                **{k: float(v[i]) for k, v in summary.items()},
                **({"signals": {k: v[i] for k, v in res.trajectories.signals.items()}}
                   if args.signals else {}),
            }
            for i in range(n)
        ],
    }
    if args.signals:
        out["ts"] = ts
    path = write_json(args.out, out)
    n_ok = int(jnp.sum(res.ok))
    print(f"vehsim sweep: {n_ok}/{n} ok in {wall:.1f} s (compile included); wrote {path}",
          file=sys.stderr)
    return 0 if n_ok == n else 1
