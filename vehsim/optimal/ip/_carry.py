"""Loop carries of the interior-point method."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def strong(tree):
    """Strongly typed copies of the array leaves of ``tree``: a weakly typed carry
    (``jnp.asarray(0.0)``) makes `lax.while_loop` trace its body a second time to fix the
    types."""
    return jax.tree.map(lambda a: jnp.asarray(a, dtype=jnp.result_type(a)), tree)
