r"""Labelled results: batched runs as `xarray.Dataset`s, written as netCDF.

A sweep, a robot Monte-Carlo grid or a batch of primitives returns arrays whose axes are
members, controllers or frictions. Here they become datasets whose dimensions carry those
names and values: the swept parameters are coordinates (a Cartesian grid from `sweep_grid`
becomes one dimension per parameter), each output is a variable with its ``units`` and
``long_name`` in its attributes (CF conventions, SI units as in the report), and the
per-member outcome is the string variable ``status`` (the `vehsim.RESULTS` case name).
netCDF, through xarray, is the format of the climate and energy-system communities for
exactly this kind of labelled array.

xarray is an optional dependency: ``pip install "vehsim[xarray]"`` (xarray and netCDF4).
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import equinox as eqx
import jax
import numpy as np

from ._io import atomic_path
from ._results import result_name


UNITS: dict[str, tuple[str, str]] = {
    # half-car and reduced-model signals (`HalfCar.signals`, `ReducedHalfCar.signals`)
    "x": ("m", "x position of the centre of gravity"),
    "y": ("m", "y position of the centre of gravity"),
    "psi": ("rad", "yaw angle"),
    "vx": ("m/s", "longitudinal velocity (body frame)"),
    "vy": ("m/s", "lateral velocity (body frame)"),
    "yaw_rate": ("rad/s", "yaw rate"),
    "speed": ("m/s", "speed of the centre of gravity"),
    "sideslip": ("rad", "vehicle sideslip angle"),
    "ax": ("m/s^2", "longitudinal acceleration (body frame)"),
    "ay": ("m/s^2", "lateral acceleration (body frame)"),
    "T_F": ("N m", "front axle torque"), "T_R": ("N m", "rear axle torque"),
    "delta": ("rad", "steering angle"),
    "omega_F": ("rad/s", "front wheel speed"), "omega_R": ("rad/s", "rear wheel speed"),
    "kappa_F": ("1", "front longitudinal slip"), "kappa_R": ("1", "rear longitudinal slip"),
    "alpha_F": ("rad", "front slip angle"), "alpha_R": ("rad", "rear slip angle"),
    "Vx_F": ("m/s", "front axle longitudinal speed (wheel frame)"),
    "Vx_R": ("m/s", "rear axle longitudinal speed (wheel frame)"),
    "Fx_F": ("N", "front longitudinal tire force"), "Fx_R": ("N", "rear longitudinal tire force"),
    "Fy_F": ("N", "front lateral tire force"), "Fy_R": ("N", "rear lateral tire force"),
    "Mz_F": ("N m", "front aligning moment"), "Mz_R": ("N m", "rear aligning moment"),
    "Fz_F": ("N", "front normal load"), "Fz_R": ("N", "rear normal load"),
    "z": ("m", "heave of the centre of gravity"), "theta": ("rad", "pitch angle"),
    # half-car parameters (`HalfCarParams`)
    "m": ("kg", "vehicle mass"), "Iz": ("kg m^2", "yaw moment of inertia"),
    "Iy": ("kg m^2", "pitch moment of inertia"),
    "lF": ("m", "centre of gravity to front axle"), "lR": ("m", "centre of gravity to rear axle"),
    "h": ("m", "centre-of-gravity height"), "r": ("m", "wheel radius"),
    "Iw_F": ("kg m^2", "front axle spin inertia"), "Iw_R": ("kg m^2", "rear axle spin inertia"),
    "K_F": ("N/m", "front suspension stiffness"), "K_R": ("N/m", "rear suspension stiffness"),
    "C_F": ("N s/m", "front suspension damping"), "C_R": ("N s/m", "rear suspension damping"),
    "g": ("m/s^2", "gravitational acceleration"),
    # tires: friction-ellipse Magic Formula, LuGre (eqs. 8-10, 22-25)
    "B": ("1", "Magic Formula stiffness factor"), "C": ("1", "Magic Formula shape factor"),
    "D": ("1", "peak friction coefficient"),
    "sigma0": ("1/m", "rubber stiffness"), "sigma1": ("s/m", "rubber damping"),
    "sigma2": ("s/m", "viscous relative damping"), "mu_c": ("1", "Coulomb friction"),
    "mu_s": ("1", "static friction"), "v_s": ("m/s", "Stribeck velocity"),
    "alpha": ("1", "Stribeck exponent"), "L": ("m", "contact patch length"),
    "kappa0": ("1", "lumped-model constant kappa0 (eq. 25)"),
    # maneuvers (`vehsim.vehicle.maneuvers`)
    "brake_torque": ("N m", "brake torque"), "drive_torque": ("N m", "drive torque"),
    "t_brake": ("s", "braking onset"), "t_step": ("s", "steering step time"),
    "t_steer": ("s", "steering onset"), "rise": ("s", "input rise time"),
    "front_share": ("1", "front share of the brake torque"),
    "omega_lock": ("rad/s", "wheel speed of the brake's tanh"),
    # outcomes
    "t": ("s", "time"), "t_f": ("s", "final time"), "exit_speed": ("m/s", "exit speed"),
    "num_steps": ("1", "solver steps"), "iterations": ("1", "interior-point iterations"),
    "convergence_time": ("s", "convergence time t_c (Table 2 scoring)"),
    "gamma": ("rad", "robot heading"), "peak_v": ("m/s", "peak |v| command"),
    "peak_omega": ("rad/s", "peak |omega| command"),
}
"""Units (CF spelling, ``"1"`` for dimensionless) and long names of the outputs and
parameters vehsim knows, by name."""

_PREFIXES = {"final_": "final ", "max_abs_": "peak |{}|", "max_": "maximum ", "min_": "minimum "}


def units_of(name: str) -> dict[str, str]:
    """``{"units": ..., "long_name": ...}`` of a known output or parameter, also through the
    prefixes ``final_``, ``max_abs_``, ``max_``, ``min_`` (``max_abs_ay`` has the units of
    ``ay``); empty for an unknown name."""
    if name in UNITS:
        units, long_name = UNITS[name]
        return {"units": units, "long_name": long_name}
    for prefix, words in _PREFIXES.items():
        if name.startswith(prefix) and name[len(prefix):] in UNITS:
            units, long_name = UNITS[name[len(prefix):]]
            text = words.format(long_name) if "{}" in words else words + long_name
            return {"units": units, "long_name": text}
    return {}


def require_xarray():
    """Import xarray, or raise an `ImportError` that says how to install it."""
    try:
        import xarray
    except ImportError:
        raise ImportError(
            "labelled results need xarray (and netCDF4 to write .nc files): "
            "pip install 'vehsim[xarray]'") from None
    return xarray


def member_axes(members: Mapping[str, Any]) -> dict[str, np.ndarray] | None:
    """The axes of a Cartesian grid laid out as `sweep_grid` lays it out (the first name
    slowest), ``{name: values}``; None if `members` is not such a grid."""
    columns = {k: np.asarray(v) for k, v in members.items()}
    if not columns or any(c.ndim != 1 for c in columns.values()):
        return None
    axes = {k: c[np.sort(np.unique(c, return_index=True)[1])] for k, c in columns.items()}
    if int(np.prod([len(a) for a in axes.values()])) != len(next(iter(columns.values()))):
        return None
    rows = np.asarray(list(itertools.product(*axes.values())))
    table = np.stack(list(columns.values()), axis=1)
    return axes if np.array_equal(rows, table) else None


def _member_coords(members) -> tuple[tuple[str, ...], dict, Any]:
    """Dimensions, coordinates and a reshaping function for per-member arrays."""
    if isinstance(members, Mapping):
        axes = member_axes(members)
        if axes is not None:
            shape = tuple(len(a) for a in axes.values())
            coords = {k: (k, a, units_of(k)) for k, a in axes.items()}
            return tuple(axes), coords, lambda x: x.reshape(shape + x.shape[1:])
        leaves = dict(members)
    else:
        leaves = {jax.tree_util.keystr(p).strip("[]'.\""): v
                  for p, v in jax.tree_util.tree_flatten_with_path(members)[0]}
    coords = {k: ("member", np.asarray(v), units_of(k)) for k, v in leaves.items()
              if np.ndim(v) == 1}
    n = len(next(iter(jax.tree.leaves(members))))
    coords["member"] = ("member", np.arange(n), {"long_name": "member index"})
    return ("member",), coords, lambda x: x


def _variable(dims, values, name, extra_dims=()):
    values = np.asarray(values)
    return (tuple(dims) + tuple(extra_dims), values, units_of(name))


def sweep_to_xarray(result, *, signals: bool | Sequence[str] = True,
                    outputs: Mapping[str, Any] | None = None, attrs: Mapping | None = None):
    r"""A `SweepResult` as an `xarray.Dataset` (what `SweepResult.to_xarray` returns).

    **Arguments:**

    - `result`: a `SweepResult`.
    - `signals`: the trajectory signals to include as variables over (members..., ``t``):
      all (True), none (False), or the name or names given.
    - `outputs`: more per-member outputs ``{name: array with the member axis first}``,
      e.g. scalar summaries.
    - `attrs`: global attributes (the maneuver, the presets, ...).

    **Returns:** a `Dataset` whose dimensions are the swept parameters (a `sweep_grid`
    grid; otherwise one ``member`` dimension with the parameters as coordinates along it)
    and ``t``; variables ``status`` (the `vehsim.RESULTS` case of each member), ``ok``,
    ``num_steps``, the signals and the `outputs`, each with ``units`` and ``long_name``.
    A signal named like a swept parameter takes the suffix ``_t`` (sweeping the maneuver's
    ``delta``, the steering angle over time is ``delta_t``).
    """
    xr = require_xarray()
    dims, coords, shape = _member_coords(result.members)
    traj = result.trajectories
    if signals is True:
        names = list(traj.signals)
    else:
        names = [signals] if isinstance(signals, str) else list(signals or [])
        unknown = [k for k in names if k not in traj.signals]
        if unknown:
            raise ValueError(f"sweep_to_xarray: signals {unknown} are not in the sweep's "
                             f"trajectories; they hold {list(traj.signals)}")
    data = {"status": (dims, shape(np.asarray(result_name(result.result), dtype=str)),
                       {"long_name": "solver outcome (vehsim.RESULTS case)"}),
            "ok": (dims, shape(np.asarray(result.ok)), {"long_name": "solve succeeded"}),
            "num_steps": _variable(dims, shape(np.asarray(traj.num_steps)), "num_steps")}
    for k in names:  # a signal named like a swept parameter (delta, speed) gets "_t"
        data[k + "_t" if k in coords else k] = _variable(
            dims, shape(np.asarray(traj.signals[k])), k, ("t",))
    for k, v in (outputs or {}).items():
        v = shape(np.asarray(v))
        data[k] = _variable(dims, v, k, tuple(f"{k}_dim{i}" for i in range(v.ndim - len(dims))))
    if names:
        coords["t"] = ("t", np.asarray(traj.ts[0]), units_of("t"))
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update({"title": "vehsim sweep", "num_devices": int(result.num_devices),
                     **dict(attrs or {})})
    return ds


def _label(item) -> str:
    return item if isinstance(item, str) else type(item).__name__


def robot_grid_to_xarray(run, controllers: Sequence, systems: Sequence,
                         missions: Sequence | None = None, attrs: Mapping | None = None):
    r"""The `RobotRun` of `simulate_robot_grid` as an `xarray.Dataset`.

    **Arguments:**

    - `run`: the grid's `RobotRun` (leading axes controllers x systems x runs).
    - `controllers`, `systems`: those of the grid, or their labels (coordinates
      ``controller`` and ``system``: the class names, or the strings given).
    - `missions`: the `Mission`s (or labels) whose initial poses, each followed by its
      seeds, made the runs (as ``missions x seeds`` flattened): the run axis becomes
      ``mission`` x ``seed``. Default: one ``run`` dimension.
    - `attrs`: global attributes.

    **Returns:** a `Dataset` over (``controller``, ``system``, runs) with the Table 2
    ``score`` (letters E, G, S, C, O, U of `vehsim.robot.scoring`), ``status`` (the
    `vehsim.RESULTS` case of each run: ``successful``, or ``nonfinite`` where the run left
    the numbers), the
    ``convergence_time``, the final pose (``final_x``, ``final_y``, ``final_gamma``) and
    the peak commands; with saved trajectories also ``x``, ``y``, ``gamma`` over ``t``.
    """
    xr = require_xarray()
    C, S, P = np.shape(run.final_pose)[:3]
    coords = {"controller": [_label(c) for c in controllers],
              "system": [_label(s) for s in systems]}
    if missions is None:
        runs = {"run": np.arange(P)}
    else:
        n_seeds, rem = divmod(P, len(missions))
        if rem:
            raise ValueError(f"{P} runs are not missions x seeds for {len(missions)} missions")
        runs = {"mission": [getattr(m, "name", m) for m in missions],
                "seed": np.arange(n_seeds)}
    coords |= runs
    dims = ("controller", "system") + tuple(runs)
    shape = (C, S) + tuple(len(v) for v in runs.values())
    data = {k: _variable(dims, v.reshape(shape), k) for k, v in _run_fields(run).items()}
    data["score"][2].update(long_name="Table 2 letter (E, G, S, C, O, U)")
    if run.ts is not None:
        coords["t"] = np.asarray(run.ts).reshape((-1, np.shape(run.ts)[-1]))[0]
        for i, k in enumerate(("x", "y", "gamma")):
            data[k] = _variable(dims, np.asarray(run.pose[..., i]).reshape(shape + (-1,)), k,
                                ("t",))
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update({"title": "vehsim robot Monte-Carlo grid", **dict(attrs or {})})
    return ds


def _run_fields(run) -> dict[str, np.ndarray]:
    """Per-run outcomes of a robot grid (leading axes controllers x systems x runs)."""
    from .robot.scoring import letters, score_run

    stats = run.stats
    flat = jax.tree.map(lambda a: a.reshape((-1,) + a.shape[3:]), stats)
    codes = np.asarray(jax.jit(jax.vmap(score_run))(flat))
    fields = {
        "score": np.asarray(letters(codes), dtype=str),
        "status": np.asarray(result_name(run.result), dtype=str),
        "convergence_time": np.asarray(stats.convergence_time()),
        "peak_v": np.asarray(stats.peak_command[..., 0]),
        "peak_omega": np.asarray(stats.peak_command[..., 1]),
    }
    for i, k in enumerate(("x", "y", "gamma")):
        fields[f"final_{k}"] = np.asarray(run.final_pose[..., i])
    return fields


def _primitive_members(prims) -> list:
    """A batch of primitives as a list: a `Primitive` batched over the tire friction `D`
    (`vmap_primitives`) is split into its members."""
    if isinstance(prims, Sequence):
        return list(prims)
    D = np.asarray(prims.problem.vehicle.tire.D)
    return [eqx.tree_at(lambda p: (p.solution, p.problem.vehicle.tire.D), prims,
                        (jax.tree.map(lambda x, i=i: x[i], prims.solution), D[i]))
            for i in range(len(D))]


@eqx.filter_jit
def _node_signals(prim):
    n = prim.nodes()  # states (6) and inputs (3) first, as `Primitive.signals` reads them
    return prim.time(), jax.vmap(prim.problem.vehicle.signals)(n[:, :6], n[:, 6:9])


def _primitive_trajectory(prim):
    """`Primitive.time` and `Primitive.signals` at every node, in one compiled call."""
    t, signals = _node_signals(prim)
    return np.asarray(t), {k: np.asarray(v) for k, v in signals.items()}


def primitives_to_xarray(prims, attrs: Mapping | None = None):
    r"""Optimal primitives over a batch of road frictions as an `xarray.Dataset`.

    **Arguments:**

    - `prims`: what `vehsim.optimal.primitives.continuation_primitives` (a list of
      `Primitive`) or `vmap_primitives` (one `Primitive` batched over the friction) returns.
    - `attrs`: global attributes.

    **Returns:** a `Dataset` over the friction ``D`` (the tire's peak coefficient) with
    ``t_f``, ``exit_speed``, ``status``, ``iterations`` and the residuals per member, and
    every node signal (pose, speeds, slips, forces, loads) and the time ``t`` over
    (``D``, ``node``).
    """
    xr = require_xarray()
    members = _primitive_members(prims)
    D = np.asarray([float(p.problem.vehicle.tire.D) for p in members])
    sol = [p.solution for p in members]
    fields = {"t_f": [float(p.t_f) for p in members],
              "exit_speed": [float(p.exit_speed) for p in members],
              "iterations": [int(s.iterations) for s in sol]}
    data = {k: _variable(("D",), v, k) for k, v in fields.items()}
    data["status"] = (("D",), np.asarray([result_name(s.result) for s in sol], dtype=str),
                      {"long_name": "solver outcome (vehsim.RESULTS case)"})
    for k in ("inf_pr", "inf_du", "compl"):
        data[k] = (("D",), np.asarray([float(getattr(s, k)) for s in sol]),
                   {"long_name": f"interior-point residual {k}"})
    runs = [_primitive_trajectory(p) for p in members]
    data["t"] = _variable(("D",), np.stack([t for t, _ in runs]), "t", ("node",))
    for k in runs[0][1]:
        data[k] = _variable(("D",), np.stack([sig[k] for _, sig in runs]), k, ("node",))
    ds = xr.Dataset(data, coords={"D": ("D", D, units_of("D"))})
    ds.attrs.update({"title": "vehsim optimal primitives",
                     "road": members[0].problem.road.name,
                     "objective": members[0].problem.objective, **dict(attrs or {})})
    return ds


def write_netcdf(dataset, path: str | os.PathLike) -> Path:
    """Write `dataset` to a netCDF file at `path`, atomically (a temporary file in the same
    folder, then a rename); the folder is created if needed."""
    require_xarray()
    with atomic_path(path) as tmp:
        dataset.to_netcdf(tmp)
    return Path(path)
