"""What `vehsim.simulate` drives: a vector field with named states, controls and signals."""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float


class AbstractVehicle(eqx.Module):
    r"""A vehicle model $\dot y = f(y, u)$ with a flat state vector and a flat control vector.

    Subclasses define `state_names` (the first entries of the state; tire friction states,
    if any, follow), `control_names`, `f` and `signals`.
    """

    state_names: ClassVar[tuple[str, ...]]
    control_names: ClassVar[tuple[str, ...]]

    @abc.abstractmethod
    def f(self, state: Float[Array, " n"], controls: Float[Array, " m"]) -> Float[Array, " n"]:
        """Time derivative of the state for the given controls."""

    @abc.abstractmethod
    def signals(self, state: Float[Array, " n"], controls: Float[Array, " m"]) -> dict:
        """Named scalar signals (positions, velocities, sideslip, slips, forces, loads)."""

    @property
    def state_size(self) -> int:
        """The length of the state vector (`state_names`, and the tires' states if any)."""
        return len(self.state_names)

    def check_shapes(self, state, controls) -> None:
        """Refuse a state or control vector of the wrong length (static shapes: this runs
        under `jax.jit` and `jax.vmap` too, on one member's shapes)."""
        for what, x, size, names in (("state", state, self.state_size, "states"),
                                     ("controls", controls, len(self.control_names),
                                      "controls")):
            if jnp.shape(x) != (size,):
                raise ValueError(
                    f"{type(self).__name__}.f: {what} must have shape ({size},), the model's "
                    f"{names}, got shape {jnp.shape(x)} (batches: jax.vmap)")

    def vector_field(self, t, state, controls):
        """diffrax-style ``f(t, y, args)`` with the controls as ``args``."""
        return self.f(state, controls)
