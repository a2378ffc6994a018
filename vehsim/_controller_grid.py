r"""A grid of closed loops: G control laws, each on its own group of M runs of one plant.

The runs are laid out along one leading axis of G x M (group g: runs g M to (g + 1) M - 1).
Per sample, the plant's part (sense, then act) is one function of a run, evaluated once for
all G x M runs (vmapped); each law is evaluated on its own group only (vmapped over its M
runs). A `lax.switch` on a batched law index would evaluate every law for every run. The
robot grid (`vehsim.robot.khepera`) and the braking grid (`vehsim.control.loop`) are both
scans of `grid_sample`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
from jaxtyping import PyTree


def tile_groups(tree: PyTree, groups: int) -> PyTree:
    """Every leaf's leading axis (M runs) repeated for each of `groups` groups: G x M."""
    return jax.tree_util.tree_map(lambda a: jnp.concatenate([a] * groups), tree)


def split_groups(tree: PyTree, groups: int) -> PyTree:
    """Every leaf's leading axis of G x M runs split into (G, M)."""
    def split(a):
        return a.reshape((groups, a.shape[0] // groups) + a.shape[1:])

    return jax.tree_util.tree_map(split, tree)


def grouped_laws(laws: Sequence[Callable], states: Sequence[PyTree], inputs: PyTree):
    r"""Law $g$ on the $g$-th group of runs: ``law(state, input) -> (state, command)`` of one
    run, vmapped over the group's M runs.

    **Arguments:** `laws` (G functions), `states` (G PyTrees with a leading axis of M: each
    law's own state, of its own structure; `None` for a law without state), `inputs` (a
    PyTree whose leaves have a leading axis of G x M).
    **Returns:** ``(states, commands)``: the G new states, and the commands of all runs
    concatenated in group order (leading axis G x M).
    """
    G = len(laws)
    M = jax.tree_util.tree_leaves(inputs)[0].shape[0] // G
    new_states, commands = [], []
    for g, (law, state) in enumerate(zip(laws, states)):
        part = jax.tree_util.tree_map(lambda a: a[g * M:(g + 1) * M], inputs)
        state, command = jax.vmap(law)(state, part)
        new_states.append(state)
        commands.append(command)
    return tuple(new_states), jax.tree_util.tree_map(lambda *c: jnp.concatenate(c), *commands)


def grid_sample(sense: Callable, laws: Sequence[Callable], act: Callable, carry: PyTree,
                states: Sequence[PyTree]):
    r"""One sample of every run of the grid: sense, each law on its group, act.

    **Arguments:** `sense(carry) -> (carry, inputs, seen)` and `act(carry, seen, commands)
    -> (carry, out)`, both of all G x M runs at once (the caller vmaps its per-run plant);
    `inputs` is what the laws see (`grouped_laws`), `seen` what `act` needs besides the
    commands; `laws` and their `states` as in `grouped_laws`.
    **Returns:** ``((carry, states), out)``, a scan's step.
    """
    carry, inputs, seen = sense(carry)
    states, commands = grouped_laws(laws, states, inputs)
    carry, out = act(carry, seen, commands)
    return (carry, states), out
