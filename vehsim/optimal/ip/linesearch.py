r"""Step length: the fraction-to-boundary rule and a filter line search.

The filter method of Wächter and Biegler (2006), without its restoration phase,
on the barrier objective and the $\ell_1$ constraint violation

$$\varphi_\mu(y, s) = f(y) - \mu \sum \ln s,\qquad
\theta(y, s) = \|c\|_1 + \|e\|_1 + \|g - s\|_1 .$$

Backtracking from the largest step that keeps $s > 0$ (halving, at most `MAX_TRIALS`; when
the full step is rejected for a larger constraint violation, its second-order correction is
tried first, as in IPOPT, against the Maratos effect), a trial
is accepted by the Armijo condition on $\varphi_\mu$ when the switching condition holds and
$\theta \le \theta_{min}$ ("f-type"), otherwise when it improves $\theta$ or $\varphi_\mu$
sufficiently and is not dominated by the filter (both with $\theta \le \theta_{max}$).
Accepted non-f-type steps add the current point to the filter. When no trial is accepted the
shortest one is taken and the filter is forgotten, so that the next iteration is not blocked by
its own history; the filter is also cleared when the barrier parameter changes.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from ._carry import strong
from .derivatives import stage_values
from .kkt import Iterate, NewtonStep
from .problem import AbstractStagewiseNLP, StageLayout


FILTER_SIZE = 64
"""Entries of the filter (a ring: the oldest is overwritten)."""
MAX_TRIALS = 30
ETA_PHI = 1e-4
"""Armijo constant."""
GAMMA = 1e-5
"""Sufficient-decrease margins $\\gamma_\\theta = \\gamma_\\varphi$."""
DELTA_SWITCH, S_THETA, S_PHI = 1.0, 1.1, 2.3
"""Switching condition $\\alpha(-\\nabla\\varphi^T d)^{s_\\varphi} > \\delta\\theta^{s_\\theta}$."""
THETA_MIN_FACTOR, THETA_MAX_FACTOR = 1e-4, 1e4
"""$\\theta_{min}$, $\\theta_{max}$ relative to $\\max(1, \\theta)$ at the initial point."""


class Filter(eqx.Module):
    """Filter entries $(\\theta, \\varphi)$ (unused ones are $+\\infty$), the count of entries
    added (the next slot of the ring), and the bounds $\\theta_{min}$, $\\theta_{max}$."""

    theta: Float[Array, " F"]
    phi: Float[Array, " F"]
    count: Int[Array, ""]
    theta_min: Float[Array, ""]
    theta_max: Float[Array, ""]

    @classmethod
    def initial(cls, theta0) -> Filter:
        """An empty filter for a start with constraint violation ``theta0``."""
        return cls(theta=jnp.full((FILTER_SIZE,), jnp.inf), phi=jnp.full((FILTER_SIZE,), jnp.inf),
                   count=jnp.asarray(0), theta_min=THETA_MIN_FACTOR * jnp.maximum(1.0, theta0),
                   theta_max=THETA_MAX_FACTOR * jnp.maximum(1.0, theta0))

    def cleared_where(self, pred) -> Filter:
        """The filter emptied where ``pred`` (its bounds and count kept)."""
        theta = jnp.where(pred, jnp.inf, self.theta)
        phi = jnp.where(pred, jnp.inf, self.phi)
        return eqx.tree_at(lambda f: (f.theta, f.phi), self, (theta, phi))

    def dominates(self, theta, phi):
        return jnp.any((theta >= self.theta) & (phi >= self.phi))

    def augmented_where(self, pred, theta0, phi0) -> Filter:
        """The filter with the margin-shifted point $((1-\\gamma)\\theta_0,
        \\varphi_0 - \\gamma\\theta_0)$ added where ``pred``."""
        slot = self.count % self.theta.shape[0]
        theta = jnp.where(pred, self.theta.at[slot].set((1 - GAMMA) * theta0), self.theta)
        phi = jnp.where(pred, self.phi.at[slot].set(phi0 - GAMMA * theta0), self.phi)
        return eqx.tree_at(lambda f: (f.theta, f.phi, f.count), self,
                           (theta, phi, self.count + pred.astype(jnp.int32)))


def constraint_violation(c, e, g, s, mask_g):
    """$\\theta = \\|c\\|_1 + \\|e\\|_1 + \\|g - s\\|_1$ (inequalities in use only)."""
    return jnp.sum(jnp.abs(c)) + jnp.sum(jnp.abs(e)) + jnp.sum(jnp.abs((g - s) * mask_g))


def fraction_to_boundary(v, dv, mask, tau) -> Float[Array, ""]:
    """Largest $\\alpha \\le 1$ with $v + \\alpha\\,dv \\ge (1 - \\tau) v$ on the rows in use."""
    if v.size == 0:  # no inequalities: nothing bounds the step
        return jnp.ones((), v.dtype)
    ratio = jnp.where((dv < 0) & (mask > 0), -tau * v / jnp.where(dv < 0, dv, -1.0), jnp.inf)
    return jnp.minimum(1.0, jnp.min(ratio))


def filter_line_search(prob: AbstractStagewiseNLP, lay: StageLayout, it: Iterate,
                       step: NewtonStep, values, grad_f, mu, filt: Filter, alpha_max,
                       correction, tau):
    """Backtrack from ``alpha_max`` along ``step``; when the full trial is rejected for a
    larger constraint violation, first try its second-order correction: the step of
    ``correction(c, e, g - s)`` (the same KKT matrix with the trial's constraint residuals
    added to $\alpha$ times the current ones), cut by the fraction to the boundary (``tau``).
    ``values``: the objective, defects, equalities and inequalities at the iterate (those of
    its `StageDerivatives`).

    **Returns:** the step length, the number of trials, whether a trial was accepted, the
    updated filter and the primal direction taken with its multiplier steps
    ``(dy, ds, dlam, dnu)``."""
    mg = lay.masks().g
    sg = jnp.where(mg > 0, it.s, 1.0)
    f0, c0, e0, g0 = values
    phi0, theta0 = _merit(f0, c0, e0, g0, it.s, mg, mu)
    dphi = jnp.sum(grad_f * step.dy) - mu * jnp.sum(jnp.where(mg > 0, step.ds / sg, 0.0))

    def acceptable(alpha, phi, theta):
        switching = (dphi < 0) & (
            alpha * (-dphi) ** S_PHI > DELTA_SWITCH * jnp.maximum(theta0, 0.0) ** S_THETA
        )
        armijo = phi <= phi0 + ETA_PHI * alpha * dphi
        f_type = switching & (theta0 <= filt.theta_min)
        suff = (theta <= (1 - GAMMA) * theta0) | (phi <= phi0 - GAMMA * theta0)
        ok_h = suff & ~filt.dominates(theta, phi) & (theta <= filt.theta_max)
        ok = jnp.where(f_type, armijo & (theta <= filt.theta_max), ok_h)
        return ok & jnp.isfinite(phi) & jnp.isfinite(theta), f_type

    def at(dy, ds, alpha):
        s = it.s + alpha * ds
        f, c, e, g = stage_values(prob, lay, it.ys + alpha * dy)
        return _merit(f, c, e, g, s, mg, mu), (c, e, g - s)

    # the full trial, and its second-order correction if it raised the violation
    (phi1, theta1), (c1, e1, gs1) = at(step.dy, step.ds, alpha_max)
    ok1, f1 = acceptable(alpha_max, phi1, theta1)
    try_soc = (~ok1) & (theta1 >= theta0)

    def soc(_):
        dy, ds, dlam, dnu = correction(alpha_max * c0 + c1, alpha_max * e0 + e1,
                                       (alpha_max * (g0 - it.s) + gs1) * mg)
        a = fraction_to_boundary(it.s, ds, mg, tau)
        (phi, theta), _ = at(dy, ds, a)
        ok, f_type = acceptable(alpha_max, phi, theta)
        return ok, f_type, a, (dy, ds, dlam, dnu)

    def no_soc(_):
        return jnp.asarray(False), jnp.asarray(False), alpha_max, (
            step.dy, step.ds, step.dlam, step.dnu)

    ok_soc, f_soc, alpha_soc, soc_dir = jax.lax.cond(try_soc, soc, no_soc, None)

    def cond(carry):
        _, n, accepted, _ = carry
        return (~accepted) & (n < MAX_TRIALS)

    def body(carry):
        alpha, n, _, _ = carry
        alpha = 0.5 * alpha
        (phi, theta), _ = at(step.dy, step.ds, alpha)
        ok, f_type = acceptable(alpha, phi, theta)
        return alpha, n + 1, ok, f_type

    first = strong((alpha_max, 1, ok1 | ok_soc, jnp.where(ok1, f1, f_soc)))
    alpha, n, accepted, f_type = jax.lax.while_loop(cond, body, first)
    filt = filt.augmented_where(~f_type & accepted, theta0, phi0).cleared_where(~accepted)
    use_soc = ok_soc & ~ok1
    direction = jax.tree_util.tree_map(lambda a, b: jnp.where(use_soc, a, b), soc_dir,
                                       (step.dy, step.ds, step.dlam, step.dnu))
    return jnp.where(use_soc, alpha_soc, alpha), n + try_soc, accepted, filt, direction


def _merit(f, c, e, g, s, mg, mu):
    logs = jnp.where(mg > 0, jnp.log(jnp.where(mg > 0, s, 1.0)), 0.0)
    return f - mu * jnp.sum(logs), constraint_violation(c, e, g, s, mg)
