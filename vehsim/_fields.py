"""Parameter fields: arrays inside `eqx.Module`s, with one converter.

A preset built from Python floats and the same module with values traced under
``jit``/``vmap``/``grad`` must have identical abstract values, so that they share one
compilation: ``jnp.asarray(1.0)`` is *weakly* typed while a traced float64 is not, so every
floating-point parameter is converted to a strongly typed array of the default float type.
"""

import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._checks import is_numeric


def float_array(x):
    """``x`` as a strongly typed floating-point array (float64 when x64 is on); a value
    that is not numeric is refused with a `ValueError` naming the field where it can."""
    if not is_numeric(x):  # NumPy would read "0.5" and True as numbers
        raise ValueError(f"{_field_being_converted()} must be a number or an array of "
                         f"numbers, got {x!r}")
    try:
        return jnp.asarray(x, dtype=jnp.result_type(float))
    except (TypeError, ValueError) as e:
        raise ValueError(f"{_field_being_converted()} must be a number or an array of "
                         f"numbers, got {x!r}") from e


def _field_being_converted() -> str:
    """``Owner.field`` of the `eqx.Module` whose converter is running (read from the
    converting frame of equinox's initialisation), or "a parameter field" if that frame is
    not one equinox's initialisation has."""
    try:
        frame = sys._getframe(2)
    except ValueError:  # called from the bottom of the stack
        return "a parameter field"
    field, owner = frame.f_locals.get("f"), frame.f_locals.get("cls")
    if isinstance(getattr(field, "name", None), str) and isinstance(owner, type):
        return f"{owner.__name__}.{field.name}"
    return "a parameter field"


def int_array(x):
    """``x`` as a strongly typed integer array; a non-integer ``x`` is left as it is, for
    the owner's ``__check_init__`` to refuse with the field's name."""
    a = jnp.asarray(x)
    if jnp.issubdtype(a.dtype, jnp.integer):
        return jnp.asarray(a, dtype=jnp.result_type(int))
    return a


def bool_array(x):
    """``x`` as a boolean array."""
    return jnp.asarray(x, dtype=bool)


def host_float_array(x):
    """``x`` as a NumPy float64 array, a JAX array (or tracer) kept as it is: for presets
    built when their module is imported, which must neither start JAX's backend nor fix
    the float width before the user chose it (JAX converts the array when it is used)."""
    return x if isinstance(x, jax.Array) else np.asarray(x, dtype=np.float64)


def host_array_field(**kwargs):
    """A floating-point field holding host data (`host_float_array` converter)."""
    return eqx.field(converter=host_float_array, **kwargs)


def array_field(**kwargs):
    """A floating-point parameter field (`float_array` converter); ``default=`` etc. as
    `eqx.field`."""
    return eqx.field(converter=float_array, **kwargs)


def int_field(**kwargs):
    """An integer parameter field (`int_array` converter)."""
    return eqx.field(converter=int_array, **kwargs)


def bool_field(**kwargs):
    """A boolean switch field (`bool_array` converter)."""
    return eqx.field(converter=bool_array, **kwargs)
