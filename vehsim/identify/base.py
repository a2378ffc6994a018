r"""What a fit needs of a braking model: its scaled residuals, and their Jacobian.

A braking model says how the measurements of a braking are predicted from the tire:
`OpenLoopBraking` (the force, driven by the measured speeds) or `ClosedLoopBraking` (speeds
and force, driven by the brake torque). The residuals $r_k(\theta)$ are prediction errors
divided by the peak measured $|F_x|$ (and $|v|$, $|\omega|$): `peak_scales`.
"""

from __future__ import annotations

import abc
from collections.abc import Sequence
from typing import Any

import equinox as eqx
import jax.numpy as jnp

from ..tire.lugre import LumpedLuGre
from .braking import BrakingData


def peak_scales(data: Sequence[BrakingData], xp: Any = jnp):
    """Peak |F_x|, |v|, |omega| over the brakings, in the array namespace `xp` (`jax.numpy`:
    traceable; `numpy`: no JAX dispatches)."""
    def peak(field):
        return xp.max(xp.stack([xp.max(xp.abs(xp.asarray(getattr(d, field)))) for d in data]))
    return peak("F_x"), peak("v"), peak("omega")


class AbstractBrakingModel(eqx.Module):
    """How the measurements of a braking are predicted from a `LumpedLuGre` tire.

    `name` is the mode written in result files (``"open_loop"``, ``"closed_loop"``).
    """

    name: eqx.AbstractClassVar[str]

    @abc.abstractmethod
    def predict_force(self, model: LumpedLuGre, data: BrakingData):
        r"""Predicted $F_x(t_k)$ [N] on one braking (compiled)."""

    @abc.abstractmethod
    def residuals(self, model: LumpedLuGre, data: Sequence[BrakingData], scales,
                  adjoint=None):
        r"""$r$: the scaled prediction errors of every braking, concatenated. `scales` from
        `peak_scales`; `adjoint` a diffrax adjoint (or `None`: the default)."""

    @abc.abstractmethod
    def residuals_and_jacobian(self, u, mask, model_of, data: Sequence[BrakingData], scales,
                               slots: int):
        r"""$r(u)$ and $J^\top = (\partial r/\partial u)^\top$, shape (len(u), len(r)), zero
        rows where `mask` is false. `model_of(u)` is the tire; `slots` (static, 5 or 7) rows are
        reserved for the free directions that move the friction state (open loop)."""

    @abc.abstractmethod
    def fitted_forces(self, model: LumpedLuGre, data: Sequence[BrakingData], r, scales):
        r"""Predicted $F_x$ of every braking at the optimum `model`, where the data part of
        the residuals there is `r` (NumPy arrays)."""
