r"""First-order optimality of a least-squares problem $\min_u \tfrac12\|r(u)\|^2$, as
MINPACK tests it (Moré, Garbow and Hillstrom 1980), for the fits that judge their optimum
beyond their solver's own stopping test.

At a minimum the gradient $J^\top r$ vanishes; scale-free, every column of $J$ is
orthogonal to $r$. Near a zero-residual optimum (exact data) $r$ shrinks with the gradient,
so the cosine, not the gradient's size, is the test: it holds where a solver that stops on
small steps or small changes of the loss stalls.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np


GTOL = 1e-6  # the largest gradient cosine of a stationary point (MINPACK's gtol)
FTOL = 1e-6  # the largest predicted relative loss reduction of one (MINPACK's ftol)


def max_gradient_cosine(J, r):
    r"""MINPACK's gtol test: $\max_j |J_{:j}^\top r| / (\|J_{:j}\|\,\|r\|)$, the largest
    cosine between the residuals `r` (N) and a column of the Jacobian `J` (N, p); 0 for a
    zero column, zero residuals or no columns, NaN where `J` or `r` is not finite.

    NumPy arrays give a NumPy scalar (no JAX dispatch); JAX arrays, traced ones included,
    a JAX scalar."""
    xp = jnp if isinstance(J, jax.Array) or isinstance(r, jax.Array) else np
    norms = xp.linalg.norm(J, axis=0) * xp.linalg.norm(r)
    return xp.max(xp.abs(J.T @ r) / xp.where(norms > 0, norms, 1.0), initial=0.0)


def predicted_reduction(J, r):
    r"""MINPACK's ftol test: the loss reduction the Gauss-Newton model predicts for its full
    (undamped) step $\delta = -(J^\top J)^{+}J^\top r$, relative to the loss:
    $(\|r\|^2 - \|r + J\delta\|^2)/\|r\|^2$; $\infty$ where `J` or `r` is not finite.

    NumPy arrays give a float (no JAX dispatch); JAX arrays, traced ones included, a JAX
    scalar."""
    if not J.shape[1]:
        return 0.0
    xp = jnp if isinstance(J, jax.Array) or isinstance(r, jax.Array) else np
    finite = xp.all(xp.isfinite(J)) & xp.all(xp.isfinite(r))
    if xp is np and not finite:
        return math.inf
    if xp is jnp:  # keep NaN out of the linear solve
        J, r = jnp.where(finite, J, 0.0), jnp.where(finite, r, 0.0)
    # the normal equations (p x p): the test needs few digits, and they are cheaper than a
    # tall LAPACK call
    step = xp.linalg.lstsq(J.T @ J, -(J.T @ r), rcond=None)[0]
    loss = xp.sum(r**2)
    reduction = (loss - xp.sum((r + J @ step) ** 2)) / xp.maximum(loss, 1e-300)
    if xp is np:
        return float(reduction)
    return jnp.where(finite, reduction, jnp.inf)
