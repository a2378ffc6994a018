r"""Levenberg-Marquardt through the simulator: $\min_u \tfrac12\|r(u)\|^2$, $r$ the scaled
residuals of a braking model and a weak prior, for a batch of starts in one `vmap`ped call.

The solver is optimistix's Gauss-Newton with a damped Newton descent and a classical trust
region, started from Marquardt's scale-aware damping (`LevenbergMarquardt`). The residual
carries its own forward-mode Jacobian (`residual_with_jacobian`). All of
`PARAMETER_NAMES` are always in $u$; the fixed ones are masked (zero Jacobian columns, so
they never move), which lets one compilation serve every choice of free parameters.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from .._results import RESULTS
from ..progress import reach
from ..tire.lugre import LumpedLuGre
from .base import AbstractBrakingModel
from .braking import BrakingData
from .parameters import PARAMETER_NAMES, from_unconstrained, keeps_mu_s


INITIAL_DAMPING = 1e-4


class ScaledTrustRegion(optx.ClassicalTrustRegion):
    r"""`optx.ClassicalTrustRegion` whose first step size (the inverse Levenberg-Marquardt
    damping $1/\lambda_0$) is given instead of 1."""

    initial_step_size: Any = 1.0

    def init(self, y, f_info_struct):
        state = super().init(y, f_info_struct)
        return eqx.tree_at(lambda s: s.step_size, state,
                           jnp.asarray(self.initial_step_size, dtype=float))


class LevenbergMarquardt(optx.AbstractGaussNewton):
    r"""`optx.LevenbergMarquardt` started from Marquardt's scale-aware damping
    $\lambda_0 = \tau\max_j(J^\top J)_{jj}$ (Nielsen 1999; $\tau$ = `INITIAL_DAMPING`)
    instead of $\lambda_0 = 1$, with the damped steps from the normal equations by Cholesky:
    with $p\le9$ unknowns that is cheaper than a QR of the tall Jacobian."""

    rtol: float
    atol: float
    norm: Any
    descent: Any
    search: Any
    verbose: Any

    def __init__(self, rtol, atol, initial_step_size, progress: bool = False):
        self.rtol, self.atol, self.norm = rtol, atol, optx.max_norm
        self.descent = optx.DampedNewtonDescent(linear_solver=lx.Normal(lx.Cholesky()))
        self.search = ScaledTrustRegion(initial_step_size=initial_step_size)
        self.verbose = _report_step if progress else (lambda **kwargs: None)


def _report_step(**info) -> None:
    """Optimistix's per-step report, as progress: the step and the last accepted loss."""
    loss = info["loss_last_accepted_step"][1]
    reach(info["num_steps"][1] + 1, jnp.where(info["accepted_steps"][1] > 0, loss, jnp.inf))


def residual_with_jacobian(braking: AbstractBrakingModel, mask, model: LumpedLuGre,
                           data: Sequence[BrakingData], scales, slots: int):
    r"""$u \mapsto r(u)$, the data residuals of `braking`, carrying its forward-mode Jacobian.

    Levenberg-Marquardt needs the whole Jacobian $J$ at every step. Through a forward-mode
    `while_loop`, `jax.linearize` re-runs the solve for every column and `jax.jacfwd`
    batches the solve's saved trajectory; so $J$ comes from `residuals_and_jacobian`, and
    the JVP rule is the product with $J$: optimistix's `linearize` keeps $J$, and its
    linear operator is a matrix product.
    """
    keep = keeps_mu_s(mask)

    def model_of(u):
        return from_unconstrained(u, model, PARAMETER_NAMES, keep)

    @jax.custom_jvp
    def r(u):
        return braking.residuals(model_of(u), data, scales, dfx.ForwardMode())

    @r.defjvp
    def r_jvp(primals, tangents):
        (u,), (du,) = primals, tangents
        r0, Jt = braking.residuals_and_jacobian(u, mask, model_of, data, scales, slots)
        return r0, du @ Jt

    return r


@eqx.filter_jit
@eqx.debug.assert_max_traces(max_traces=None)  # counts traces: the tests check for retraces
def solve_batch(u0s, u_fixed, mask, prior_weight, model, data, braking, scales, tol,
                max_steps, slots=7, progress=False):
    r"""Levenberg-Marquardt from each row of `u0s` on the residuals of `braking` and the
    prior $w(u - u_0)$ on the free entries ($w$ = `prior_weight`, $u_0$ = `u_fixed`, which
    also holds the fixed entries).

    **Returns:** per start, the solution $u$, its loss $\tfrac12\|r\|^2$, the solver's
    outcome (a `vehsim.RESULTS` item, batched), its number of steps, and the residuals and
    Jacobian (in $u$) at the solution, from the solver's state (no further solve).
    """
    data_residual = residual_with_jacobian(braking, mask, model, data, scales, slots)

    def residual(u, args):
        u = jnp.where(mask, u, u_fixed)
        prior = prior_weight * jnp.where(mask, u - u_fixed, 0.0)
        return jnp.concatenate([data_residual(u), prior])

    def one(u0):
        # the solver's fixed entries at a finite placeholder: a value held at 0 (sigma2,
        # kappa0) is u = -inf, whose differences would be NaN in the solver's steps and tests
        u0 = jnp.where(mask, u0, 0.0)
        J = jax.jacfwd(lambda u: residual(u, None))(u0)
        lambda_0 = INITIAL_DAMPING * jnp.max(jnp.sum(J**2, axis=0))
        solver = LevenbergMarquardt(tol, tol, 1.0 / lambda_0, progress)
        sol = optx.least_squares(residual, solver, u0, max_steps=max_steps, throw=False)
        r = sol.state.f_info.residual  # at the last accepted point, `sol.value`
        return jnp.where(mask, sol.value, u_fixed), 0.5 * jnp.sum(r**2), \
            RESULTS.promote(sol.result), sol.stats["num_steps"], r, \
            sol.state.f_info.jac.as_matrix()

    if u0s.shape[0] == 1:  # no batch: a smaller program to compile (closed loop)
        return jax.tree.map(lambda x: x[None], one(u0s[0]))
    return jax.vmap(one)(u0s)
