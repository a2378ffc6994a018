"""The controller grid (vehsim._controller_grid): each law on its own group of runs, with a
state of its own, between the plant's sense and act of all runs."""

import jax.numpy as jnp
import numpy as np

from vehsim._controller_grid import grid_sample, grouped_laws, split_groups, tile_groups


G, M = 3, 4


def _laws():
    # law g adds 100 g to what it sees; its state (of its own structure) counts its calls
    def stateless(state, x):
        return state, x

    def counter(state, x):
        return state + 1, x + 100.0

    def named(state, x):
        return {"calls": state["calls"] + 1, "last": x}, x + 200.0

    states = (None, jnp.zeros(M, int), {"calls": jnp.zeros(M, int), "last": jnp.zeros(M)})
    return (stateless, counter, named), states


def test_each_law_sees_its_own_group_and_keeps_its_own_state():
    laws, states = _laws()
    inputs = jnp.arange(G * M, dtype=float)
    states, commands = grouped_laws(laws, states, inputs)
    np.testing.assert_array_equal(commands, inputs + 100.0 * jnp.repeat(jnp.arange(G), M))
    assert states[0] is None
    np.testing.assert_array_equal(states[1], 1)
    np.testing.assert_array_equal(states[2]["calls"], 1)
    np.testing.assert_array_equal(states[2]["last"], inputs[2 * M:])


def test_a_sample_senses_then_commands_then_acts():
    laws, states = _laws()

    def sense(carry):
        return carry + 1.0, 10.0 * (carry + 1.0), carry  # what the laws see, what act needs

    def act(carry, seen, commands):
        return carry + commands, seen

    carry = jnp.arange(G * M, dtype=float)
    (new, states), out = grid_sample(sense, laws, act, carry, states)
    seen = 10.0 * (carry + 1.0)
    np.testing.assert_array_equal(new, carry + 1.0 + seen
                                  + 100.0 * jnp.repeat(jnp.arange(G), M))
    np.testing.assert_array_equal(out, carry)
    np.testing.assert_array_equal(states[1], 1)


def test_groups_tile_and_split():
    tree = {"a": jnp.arange(M), "b": jnp.ones((M, 2))}
    tiled = tile_groups(tree, G)
    assert tiled["a"].shape == (G * M,) and tiled["b"].shape == (G * M, 2)
    split = split_groups(tiled, G)
    assert split["b"].shape == (G, M, 2)
    np.testing.assert_array_equal(split["a"], jnp.broadcast_to(jnp.arange(M), (G, M)))
