r"""Open loop, as the report fitted (section 2.2): the force of eq. 23,
$F = (\sigma_0\bar z + \sigma_1\dot{\bar z} + \sigma_2 v_r)F_n$ with the measured $F_n$, the
friction state driven by the measured $v(t)$, $\omega(t)$ (`friction_state`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import ClassVar

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._checks import check_count
from ..tire.lugre import LumpedLuGre
from .base import AbstractBrakingModel
from .braking import BrakingData
from .friction_state import friction_state
from .sensitivities import FORCE_ONLY, open_loop_sensitivities


def predict_open_loop(model: LumpedLuGre, data: BrakingData, substeps: int = 2, *,
                      adjoint=None):
    r"""Predicted $F_x(t_k)$ [N]: eqs. 22-23 driven by measured $v$, $\omega$, $F_n$.

    The friction state starts from the steady state at $t_0$ and takes `substeps` steps of
    the exponential midpoint rule per sample interval (`friction_state`). `adjoint`: a
    diffrax adjoint (default `RecursiveCheckpointAdjoint`: reverse mode; forward mode
    through it raises `vehsim._integrate.FORWARD_MODE_MESSAGE`; `diffrax.ForwardMode()`
    for forward-mode Jacobians).
    """
    return _forces(model, [data], substeps, adjoint)[0]


def _forces(model: LumpedLuGre, data: Sequence[BrakingData], substeps: int, adjoint=None):
    """`predict_open_loop` of several brakings (one diffrax solve each)."""
    check_count("predict_open_loop", "substeps", substeps, sep=": ")
    adjoint = dfx.RecursiveCheckpointAdjoint() if adjoint is None else adjoint
    out = []
    for d in data:
        z = friction_state(model, d, substeps, adjoint)
        r = jnp.broadcast_to(d.r, d.t.shape)
        out.append(jax.vmap(model.mu)(z, d.v, d.omega, r) * d.F_n)
    return out


_predict_open_loop_jit = eqx.filter_jit(predict_open_loop)


class OpenLoopBraking(AbstractBrakingModel):
    r"""The force of eq. 23 predicted from the measured $v$, $\omega$, $F_n$; residuals
    $(F - F_x)/\max|F_x|$.

    `substeps`: exponential midpoint steps per sample interval. The Jacobian comes from the
    forward sensitivities of the discrete scheme (`open_loop_sensitivities`).
    """

    substeps: int = eqx.field(static=True, default=2)
    name: ClassVar[str] = "open_loop"

    def __check_init__(self):
        check_count("OpenLoopBraking", "substeps", self.substeps)

    def predict_force(self, model, data):
        return _predict_open_loop_jit(model, data, self.substeps, adjoint=dfx.ForwardMode())

    def residuals(self, model, data, scales, adjoint=None):
        F = _forces(model, data, self.substeps, adjoint)
        return jnp.concatenate([(Fi - d.F_x) / scales[0] for Fi, d in zip(F, data)])

    def residuals_and_jacobian(self, u, mask, model_of, data, scales, slots):
        # the free directions that move the friction state gathered into `slots` rows
        # (padding rows are zero), then sigma1 and sigma2 (zero rows unless free): with at
        # most 5 state directions the state and its tangents share one solve per braking
        z_mask = mask & ~FORCE_ONLY
        rows = jnp.concatenate([jnp.nonzero(z_mask, size=slots, fill_value=0)[0],
                                jnp.asarray(np.flatnonzero(FORCE_ONLY))])
        used = jnp.concatenate([jnp.arange(slots) < jnp.sum(z_mask),
                                mask[FORCE_ONLY]])[:, None]
        directions = jnp.eye(u.shape[0], dtype=u.dtype)[rows] * used
        out = open_loop_sensitivities(u, directions, model_of, data, self.substeps, slots)
        r0 = jnp.concatenate([(F - d.F_x) / scales[0] for (F, _), d in zip(out, data)])
        dF = jnp.concatenate([dF / scales[0] for _, dF in out], axis=1) * used
        return r0, jnp.zeros((u.shape[0], dF.shape[1]), dF.dtype).at[rows].add(dF)

    def fitted_forces(self, model, data, r, scales):
        # the force residuals are r: no further solve
        ends = np.cumsum([len(d) for d in data])
        return [np.asarray(d.F_x) + float(scales[0]) * ri
                for ri, d in zip(np.split(r, ends[:-1]), data)]
