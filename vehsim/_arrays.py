"""Array conversion for parameter fields."""

import jax.numpy as jnp


def float_array(x):
    """``x`` as a strongly typed floating-point array (float64 when x64 is on).

    Used as the converter of parameter fields: a preset built from Python floats and the
    same module with values traced under ``jit``/``vmap``/``grad`` then have identical
    abstract values, so they share one compilation (``jnp.asarray(1.0)`` is weakly typed).
    """
    return jnp.asarray(x, dtype=jnp.result_type(float))
