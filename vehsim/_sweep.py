r"""Batched sweeps: many `simulate` runs at once, sharded across every JAX device.

`sweep(scenario, members, ts)` runs ``simulate(*scenario(member), ts, throw=False)`` for
every member (a PyTree of arrays with a leading batch axis, e.g. from `sweep_grid`),
vmapped and split across a one-dimensional device mesh (`vehsim.sharding`): each device
integrates its own slice (its adaptive solves stop when *its* members are done), and the
same call uses one CPU, several GPUs or several hosts. A failed member does not stop the
sweep: its `result` says why.

Before the batched run every member value is checked by building its scenario with
concrete numbers, so that a bad value (a negative mass) is refused with the same
`ValueError` as a single model, instead of failing inside the batch.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, PyTree

from ._checks import check_times, recheck_modules
from ._results import RESULTS
from ._simulate import Trajectory, _check_finite_start, simulate
from .progress import progress_bar, resolve
from .sharding import gather_members, num_members, pad_members, put_members, sharded_vmap


class SweepResult(eqx.Module):
    """Per-member results of `sweep` (every leaf has the member axis first).

    - `members`: the inputs, as given.
    - `trajectories`: a batched `Trajectory` (`trajectories["vx"]` has shape ``(N, T)``).
    - `result`: a batched `vehsim.RESULTS` (``RESULTS.nonfinite`` where a solve returned
      non-finite states); `vehsim.result_name` gives the names.
    - `num_devices`: how many devices the sweep was split across.
    """

    members: PyTree
    trajectories: Trajectory
    result: RESULTS
    num_devices: int = eqx.field(static=True)

    @property
    def ok(self) -> Bool[Array, " N"]:
        """Where the solve succeeded (and every state is finite)."""
        return self.result == RESULTS.successful

    def to_xarray(self, **kwargs):
        """The sweep as an `xarray.Dataset`: the swept parameters as coordinates, every
        signal over (members, ``t``) with its units, the per-member ``status``. Keyword
        arguments as `vehsim.labelled.sweep_to_xarray` (`signals`, `outputs`, `attrs`).
        Needs xarray (``pip install "vehsim[xarray]"``)."""
        from .labelled import sweep_to_xarray

        return sweep_to_xarray(self, **kwargs)

    def to_netcdf(self, path, **kwargs):
        """Write `to_xarray` (same keyword arguments) to a netCDF file at `path`
        (atomically); returns the path."""
        from .labelled import write_netcdf

        return write_netcdf(self.to_xarray(**kwargs), path)


def sweep_grid(**axes: Sequence[float]) -> dict[str, Array]:
    """Cartesian product of named value lists, flattened: ``sweep_grid(m=[1, 2], h=[3, 4, 5])``
    gives 6 members, ``{"m": [1, 1, 1, 2, 2, 2], "h": [3, 4, 5, 3, 4, 5]}``."""
    names = list(axes)
    values = [np.atleast_1d(np.asarray(axes[n], dtype=float)) for n in names]
    for n, v in zip(names, values, strict=True):
        if v.ndim != 1 or v.size == 0:
            raise ValueError(f"sweep_grid: axis {n!r} must be a non-empty list of values, got "
                             f"shape {v.shape}")
    rows = list(itertools.product(*values))
    return {n: jnp.asarray([r[i] for r in rows], dtype=float) for i, n in enumerate(names)}


def check_members(scenario: Callable, members: PyTree) -> None:
    r"""Build `scenario` eagerly for every value each leaf of `members` takes (the other
    leaves at their first member's value), or for every member when that is fewer: the
    models' construction checks then see concrete numbers and raise their `ValueError`
    (naming the field and its allowed range) before any batched work. Models the scenario
    edits with `eqx.tree_at` meet the same checks (`recheck_modules`), and the start state
    and input arrays must be finite, as `simulate` requires. The error is
    prefixed with the member's leaf and value that raised it (``m=-1: HalfCarParams.m must
    ...``), or with the member's index when every member is probed."""
    n = num_members(members)
    paths, treedef = jax.tree_util.tree_flatten_with_path(members)
    names = [_leaf_name(path) for path, _ in paths]
    arrays = [np.asarray(x) for _, x in paths]
    first = [a[0] for a in arrays]
    probes = []
    for i, a in enumerate(arrays):
        where = {}  # each distinct value's first member, NaN one value (np.unique's are not)
        for j, row in enumerate(a.reshape(n, -1)):
            where.setdefault(np.ascontiguousarray(row).tobytes(), j)
        probes += [(f"{names[i]}={_value_text(a[j])}", first[:i] + [a[j]] + first[i + 1:])
                   for j in sorted(where.values())]
    if len(probes) > n:
        probes = [(f"member {j}", [a[j] for a in arrays]) for j in range(n)]
    for label, probe in probes:
        try:
            built = scenario(jax.tree.unflatten(treedef, [jnp.asarray(x) for x in probe]))
            recheck_modules(built)  # models edited with eqx.tree_at ran no checks
            if isinstance(built, tuple) and len(built) == 3:
                vehicle, inputs, state0 = built
                _check_finite_start(vehicle, jnp.asarray(state0, dtype=float), inputs)
        except ValueError as e:
            raise ValueError(f"{label}: {e}") from None


def _leaf_name(path) -> str:
    """A member leaf's name: its dict key, or JAX's path text for other trees."""
    if len(path) == 1 and isinstance(path[0], jax.tree_util.DictKey):
        return str(path[0].key)
    return jax.tree_util.keystr(path) or "member"


def _value_text(value) -> str:
    value = np.asarray(value)
    return (f"{value.item():.12g}" if value.ndim == 0 else
            np.array2string(value, separator=",", precision=12))


def sweep(
    scenario: Callable[[PyTree], tuple[Any, Any, Any]],
    members: PyTree,
    ts,
    *,
    devices: Sequence[jax.Device] | None = None,
    batch_size: int | None = None,
    check: bool = True,
    progress: bool | None = None,
    **simulate_kwargs,
) -> SweepResult:
    r"""Simulate every member of a batch, sharded across devices, with per-member results.

    **Arguments:**

    - `scenario`: ``member -> (vehicle, inputs, state0)`` for one member (the arguments of
      `simulate`); traced once, under `vmap`.
    - `members`: a PyTree of arrays whose leading axis indexes the members (see
      `sweep_grid`).
    - `ts`: save times shared by all members.
    - `devices`: devices to split the members across (default: all, `jax.devices()`:
      after `jax.distributed.initialize`, the devices of every process, each process
      running the slices of its own devices). The member count is padded to a multiple of
      the device count (padding is dropped).
    - `batch_size`: members per vmapped chunk on each device (see
      `vehsim.sharding.sharded_vmap`; default: the device's whole slice at once).
    - `check`: first build the scenario of every member value with concrete numbers
      (`check_members`), so that an invalid value raises `ValueError` before the run.
    - `progress`: show the members done on stderr, counted per chunk (`vehsim.progress`;
      default off, on in the command line).
    - `simulate_kwargs`: passed to `simulate` (solver, tolerances, `max_steps`, ...);
      `throw` is always False.

    **Returns:** a `SweepResult`. In a run of several processes every process calls
    `sweep` with the same arguments and receives the whole result (gathered from all
    processes, `vehsim.sharding.gather_members`).
    """
    check_times("sweep", ts)
    devices = list(jax.devices() if devices is None else devices)
    n = num_members(members)
    if check:
        check_members(scenario, members)
    padded = put_members(pad_members(members, len(devices)), devices)
    ts = jnp.asarray(ts, dtype=float)
    simulate_kwargs = dict(simulate_kwargs, throw=False)
    progress = resolve(progress)
    local = sum(d.process_index == jax.process_index() for d in devices)
    total = num_members(padded)
    share = total * local // len(devices)
    m = total // len(devices)  # device j runs members j m ... (j + 1) m - 1
    padding = sum(max(0, min((j + 1) * m, total) - max(j * m, n)) for j, d in
                  enumerate(devices) if d.process_index == jax.process_index())
    unit = "members" if not padding else f"members, {padding} of them padding"
    with progress_bar("sweep", share, unit, enabled=progress):
        out = _sweep_run(scenario, padded, ts, tuple(devices), batch_size, progress,
                         simulate_kwargs)
        out = jax.block_until_ready(gather_members(out))
    traj, result = jax.tree.map(lambda x: x[:n], out)
    return SweepResult(members=members, trajectories=traj, result=result,
                       num_devices=len(devices))


@eqx.filter_jit
@eqx.debug.assert_max_traces(max_traces=None)  # counts traces: tests/test_sweep.py checks reuse
def _sweep_run(scenario, padded, ts, devices, batch_size, progress, simulate_kwargs):
    """The jitted body of `sweep`: compiled once per scenario function, shapes, devices and
    solver settings, so repeated sweeps (e.g. over other member values) reuse it."""
    def one(member):
        vehicle, inputs, state0 = scenario(member)
        traj = simulate(vehicle, ts, inputs, state0, **simulate_kwargs)
        finite = jnp.all(jnp.isfinite(traj.states))
        return traj, RESULTS.where(traj.ok & ~finite, RESULTS.nonfinite, traj.result)

    return sharded_vmap(one, list(devices), batch_size=batch_size, progress=progress)(padded)
