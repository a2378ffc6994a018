"""What `vehsim.simulate` drives: a vector field with named states, controls and signals."""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
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

    def vector_field(self, t, state, controls):
        """diffrax-style ``f(t, y, args)`` with the controls as ``args``."""
        return self.f(state, controls)
