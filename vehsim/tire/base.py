r"""The interface every combined-slip tire offers to the vehicle models.

A tire sees the wheel-frame velocity $(v_x, v_y)$ of the wheel centre ($x$ along the wheel
heading, $y$ to its left), the wheel angular speed $\omega$, the rolling radius $r$ and the
normal load $F_z$. It returns the forces *on the tire from the road* in the wheel frame,
$F_x$ (positive = traction, accelerating the vehicle), $F_y$ (positive to the left) and the
aligning moment $M_z$ about the vertical axis (positive counter-clockwise seen from above).
With these signs a wheel sliding to its right ($v_y < 0$) gets $F_y > 0$.

Dynamic tires (LuGre) carry a friction state; static tires (Magic Formula) carry an empty
state of shape ``(0,)`` so vehicle models treat both alike.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
from jaxtyping import Array, Float, PyTree


class AbstractTire(eqx.Module):
    """Combined-slip tire model used by `vehsim` vehicle models.

    ``load_proportional``: the forces are $F_z$ times a function of the kinematics alone
    (friction coefficients that do not depend on the load), so a vehicle model may evaluate
    the tire once at unit load and scale it by the load it solves for."""

    load_proportional: ClassVar[bool] = False

    @abc.abstractmethod
    def init_state(self) -> PyTree:
        """Friction state at rest (shape ``(0,)`` for static tires)."""

    @abc.abstractmethod
    def dynamics(self, state: PyTree, vx, vy, omega, r, Fz) -> PyTree:
        """Time derivative of the friction state (zeros of shape ``(0,)`` if static)."""

    @abc.abstractmethod
    def forces(self, state: PyTree, vx, vy, omega, r, Fz) -> Float[Array, 3]:
        """``(F_x, F_y, M_z)`` on the tire, wheel frame [N, N, N m]."""
