r"""Batches split across devices: the runner under `vehsim.sweep` and the robot grid.

A batch is a PyTree whose leaves share a leading *member* axis. `shard_members` splits that
axis over a one-dimensional device mesh with `jax.shard_map`, so that each device works on
its own slice (an adaptive solve inside stops when *its* members are done), and the same
call uses one CPU, several GPUs or several hosts. `sharded_vmap` is the common case: the
per-member function vmapped on each device. On a CPU host, forcing one host device per
core (``XLA_FLAGS=--xla_force_host_platform_device_count=N`` before JAX starts) runs one
shard per core.

After `jax.distributed.initialize`, the mesh may hold the devices of several processes
(machines): every process calls the same function with the same members, `put_members`
places the slices of each process's own devices, each process runs them, and
`gather_members` brings the whole result to every process (docs/sweeps.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from jaxtyping import PyTree

from ._checks import check_count
from .progress import advance


AXIS = "members"
"""Name of the mesh axis the members are split along."""


def num_members(members: PyTree) -> int:
    """The length of the leading axis shared by every leaf of `members`."""
    leaves = jax.tree.leaves(members)
    if not leaves:
        raise ValueError("a batch needs at least one array (no leaves in `members`)")
    n = {jnp.shape(x)[0] if jnp.ndim(x) else -1 for x in leaves}
    if len(n) != 1 or -1 in n:
        raise ValueError(f"every leaf of `members` needs the same leading axis, got sizes {n}")
    if 0 in n:
        raise ValueError("a batch needs at least one member, got none (a leading axis of 0)")
    return n.pop()


def pad_members(members: PyTree, multiple: int) -> PyTree:
    """Pad the leading (member) axis of every leaf to a multiple of `multiple` by repeating
    the last member (drop the padding from the results with ``x[:n]``); `multiple` an
    integer >= 1."""
    check_count("pad_members", "multiple", multiple, sep=": ")
    multiple = int(multiple)
    n = num_members(members)
    n_pad = math.ceil(n / multiple) * multiple
    return jax.tree.map(
        lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], n_pad - n, axis=0)]), members
    )


def device_mesh(devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A one-dimensional mesh (axis `AXIS`) over `devices` (default: all)."""
    return Mesh(np.asarray(list(jax.devices() if devices is None else devices)), (AXIS,))


def put_members(members: PyTree, devices: Sequence[jax.Device] | None = None) -> PyTree:
    """`members` placed on `devices`, split along the member axis. With devices of several
    processes, each process places the slices of its own devices (every process passes
    the same `members`)."""
    sharding = NamedSharding(device_mesh(devices), PartitionSpec(AXIS))
    if all(d.process_index == jax.process_index() for d in sharding.device_set):
        return jax.device_put(members, sharding)
    return jax.tree.map(lambda x: jax.make_array_from_callback(
        np.shape(x), sharding, lambda index: np.asarray(x)[index]), members)


def gather_members(tree: PyTree) -> PyTree:
    """`tree` with every leaf whole on this process: leaves split over the devices of
    several processes (a sweep after `jax.distributed.initialize`) are gathered from all
    of them (`jax.experimental.multihost_utils.process_allgather`; every process must
    call this); other leaves are returned as they are."""
    if all(x.is_fully_addressable for x in jax.tree.leaves(tree) if isinstance(x, jax.Array)):
        return tree
    from jax.experimental import multihost_utils

    return jax.tree.map(jnp.asarray, multihost_utils.process_allgather(tree, tiled=True))


def shard_members(
    fn: Callable,
    devices: Sequence[jax.Device] | None = None,
    in_axes: int | None | tuple = 0,
    out_axis: int = 0,
) -> Callable:
    r"""Run the *batched* `fn` on each device's slice of the member axis.

    Arguments with ``in_axes`` 0 are split along their leading axis, those with None are
    replicated; every output has the member axis at `out_axis`. The member count must be a
    multiple of the device count (see `pad_members`). Wrap the result in `jax.jit`.
    """
    mesh = device_mesh(devices)
    out_spec = PartitionSpec(*((None,) * out_axis + (AXIS,)))

    def run(*args):
        axes = in_axes if isinstance(in_axes, tuple) else (in_axes,) * len(args)
        specs = tuple(PartitionSpec() if a is None else PartitionSpec(AXIS) for a in axes)
        return jax.shard_map(fn, mesh=mesh, in_specs=specs, out_specs=out_spec,
                             check_vma=False)(*args)

    return run


def sharded_vmap(
    fn: Callable,
    devices: Sequence[jax.Device] | None = None,
    in_axes: int | None | tuple = 0,
    batch_size: int | None = None,
    progress: bool = False,
) -> Callable:
    r"""``jax.vmap(fn, in_axes)`` with the member axis split across `devices`
    (`shard_members`); every output has the member axis first. Wrap the result in `jax.jit`.

    `batch_size`: if given, each device runs its slice in vmapped chunks of this many
    members one after another (as `jax.lax.map` with `batch_size`): each chunk's adaptive
    solves stop at the chunk's slowest member instead of the slice's, and a chunk's
    working set stays in cache (on CPU; on a GPU keep the whole slice in one chunk).

    `progress`: after each chunk, count its members on the open `vehsim.progress` bar (one
    host callback per chunk; without `batch_size`, one per device).
    """

    if not callable(fn):
        raise TypeError(f"sharded_vmap needs a function to map, got {type(fn).__name__}")
    axes = in_axes if isinstance(in_axes, tuple) else (in_axes,)
    if not all(a is None or (type(a) is int and a == 0) for a in axes):
        raise ValueError("sharded_vmap: in_axes must be 0 (the member axis leads), None (not "
                         f"mapped), or a tuple of them (one per argument), got {in_axes!r}")
    if batch_size is not None and (isinstance(batch_size, bool) or int(batch_size) != batch_size
                                   or batch_size < 1):
        raise ValueError(f"batch_size must be an integer >= 1 (or None), got {batch_size!r}")

    def batched(*args):
        axes = in_axes if isinstance(in_axes, tuple) else (in_axes,) * len(args)
        return _chunked_vmap(fn, axes, batch_size, progress, *args)

    return shard_members(batched, devices, in_axes)


def _chunked_vmap(fn, axes, batch_size, progress, *args):
    mapped = [a for a, ax in zip(args, axes) if ax is not None]

    def chunk(member_args):  # vmapped over a chunk of members, reported when done
        def one(margs):
            it = iter(margs)
            return fn(*(a if ax is None else next(it) for a, ax in zip(args, axes)))

        out = jax.vmap(one)(member_args)
        size = jax.tree.leaves(member_args)[0].shape[0]
        return advance(size, out) if progress else out

    n = num_members(mapped)
    if batch_size is None or batch_size >= n:
        return chunk(mapped)
    n_full = n // batch_size * batch_size
    head = jax.tree.map(lambda x: x[:n_full].reshape((-1, batch_size) + x.shape[1:]), mapped)
    out = jax.tree.map(lambda y: y.reshape((n_full,) + y.shape[2:]), jax.lax.map(chunk, head))
    if n_full == n:
        return out
    tail = chunk(jax.tree.map(lambda x: x[n_full:], mapped))
    return jax.tree.map(lambda a, b: jnp.concatenate([a, b]), out, tail)


__all__ = ["device_mesh", "gather_members", "num_members", "pad_members", "put_members",
           "shard_members", "sharded_vmap"]
