r"""One control sample of a stiff plant: fixed steps of `vehsim.ROS34PW2`.

The wheel-tire block is stiff, and how stiff changes by orders of magnitude within a sample:
the bristle decay $\theta\sigma_0|v_r|/g$ runs from $10^2$ 1/s for a rolling wheel to
$10^5$ 1/s for one sliding on ice. The linearly implicit steps take their Jacobian at the
start of each step, so a wheel that locks within a few milliseconds must not outrun it:
`SUBSTEPS` = 8 steps per 5 ms sample (0.625 ms) hold a wheel locked on ice by an instant
full brake torque, where 4 steps blow up (and an adaptive `diffrax.diffeqsolve` per sample,
robust too, costs several times as much in a batch, whose members wait for the slowest).
Within the sample, `hermite` interpolates a state from its values and rates at both ends
(the tone wheel's edges, the observer's time stamps).
"""

from __future__ import annotations

import diffrax as dfx
import jax
import jax.numpy as jnp

from ..._results import RESULTS
from ...solvers import ROS34PW2


SUBSTEPS = 8
"""Integration steps per control sample."""


def integrate_sample(vector_field, y0, args, t0, T, blocks, substeps: int = SUBSTEPS,
                     save_substeps: bool = False, frozen_jacobian: bool = False):
    r"""Integrate $\dot y$ = `vector_field(t, y, args)` over $[t_0, t_0 + T]$ by `substeps`
    equal steps of `ROS34PW2`, implicit in the stiff `blocks` (index tuples of one length);
    with `frozen_jacobian`, derivatives hold each step's Jacobian constant
    (`ROS34PW2.frozen_jacobian`: the same values, a cheaper derivative).

    **Returns:** ``(y1, result)``: the state at $t_0 + T$ and `RESULTS.nonfinite` if it is
    not finite (else `successful`); with `save_substeps`, ``(y1, result, ys)``, `ys` the
    states at the end of every step, $t_0 + jT/$`substeps`, $j = 1..$`substeps` (the last
    row is `y1`).
    """
    h = T / substeps
    solver = ROS34PW2(tuple(tuple(b) for b in blocks), frozen_jacobian)
    term = dfx.ODETerm(vector_field)

    def sub(y, j):
        t = t0 + j * h
        y = solver.step(term, t, t + h, y, args, None, False)[0]
        return y, (y if save_substeps else None)

    # reverse mode keeps one state per step and recomputes the step on the way back, instead
    # of stacking every intermediate of the step (its Jacobian, the stages, the solves) over
    # the steps: a smaller program to compile (docs/differentiating.md); no effect on values,
    # on plain runs or on forward mode
    sub = jax.checkpoint(sub, prevent_cse=False)
    y1, ys = jax.lax.scan(sub, y0, jnp.arange(substeps))
    ok = jnp.all(jnp.isfinite(y1))
    result = RESULTS.where(ok, RESULTS.successful, RESULTS.nonfinite)
    return (y1, result, ys) if save_substeps else (y1, result)


def hermite(tau, T, p0, p1, d0, d1):
    r"""The cubic through $p_0$, $p_1$ with rates $d_0$, $d_1$ at the ends of a sample of
    length $T$, at the fraction `tau` of the sample."""
    t2, t3 = tau * tau, tau * tau * tau
    return ((2 * t3 - 3 * t2 + 1) * p0 + (t3 - 2 * t2 + tau) * T * d0
            + (3 * t2 - 2 * t3) * p1 + (t3 - t2) * T * d1)
