r"""First-order optimality of a least-squares problem $\min_u \tfrac12\|r(u)\|^2$, as
MINPACK tests it (Moré, Garbow and Hillstrom 1980), for the fits that judge their optimum
beyond their solver's own stopping test.

At a minimum the gradient $J^\top r$ vanishes; scale-free, every column of $J$ is
orthogonal to $r$. Near a zero-residual optimum (exact data) $r$ shrinks with the gradient,
so the cosine, not the gradient's size, is the test: it holds where a solver that stops on
small steps or small changes of the loss stalls.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np


def max_gradient_cosine(J, r):
    r"""MINPACK's gtol test: $\max_j |J_{:j}^\top r| / (\|J_{:j}\|\,\|r\|)$, the largest
    cosine between the residuals `r` (N) and a column of the Jacobian `J` (N, p); 0 for a
    zero column, zero residuals or no columns, NaN where `J` or `r` is not finite.

    NumPy arrays give a NumPy scalar (no JAX dispatch); JAX arrays, traced ones included,
    a JAX scalar."""
    xp = jnp if isinstance(J, jax.Array) or isinstance(r, jax.Array) else np
    norms = xp.linalg.norm(J, axis=0) * xp.linalg.norm(r)
    return xp.max(xp.abs(J.T @ r) / xp.where(norms > 0, norms, 1.0), initial=0.0)
