"""An identity that refuses reverse-mode differentiation with a message saying what to do.

Reverse mode through a `jax.lax.while_loop` fails inside JAX, after the caller's function
has returned, with JAX's generic words about loops. An output passed through
`forward_mode_only` fails there instead with the caller's ``message`` (a `TypeError`),
because transposition, which runs from the outputs back, meets it first. Its value, its
forward-mode derivative and its batching are those of the identity, and it compiles to
nothing.
"""

import jax
from jax.extend.core import Primitive
from jax.interpreters import ad, batching, mlir


_forward_mode_only = Primitive("forward_mode_only")
_forward_mode_only.def_impl(lambda x, *, message: x)
_forward_mode_only.def_abstract_eval(lambda x, *, message: x)
mlir.register_lowering(_forward_mode_only,
                       mlir.lower_fun(lambda x, *, message: x, multiple_results=False))


def _jvp(primals, tangents, *, message):
    (x,), (t,) = primals, tangents
    out = _forward_mode_only.bind(x, message=message)
    if type(t) is ad.Zero:  # an output that does not depend on what is differentiated
        return out, t
    return out, _forward_mode_only.bind(t, message=message)


def _transpose(cotangent, x, *, message):
    raise TypeError(message)


def _batch(args, dims, *, message):
    return _forward_mode_only.bind(args[0], message=message), dims[0]


ad.primitive_jvps[_forward_mode_only] = _jvp
ad.primitive_transposes[_forward_mode_only] = _transpose
batching.primitive_batchers[_forward_mode_only] = _batch


def forward_mode_only(tree, message: str):
    """``tree`` unchanged; differentiating any of its inexact arrays in reverse mode
    (`jax.grad`, `jax.vjp`, `jax.jacrev`) raises ``TypeError(message)``. Forward mode
    (`jax.jvp`, `jax.jacfwd`) passes through."""

    def guard(leaf):
        if isinstance(leaf, jax.Array | jax.core.Tracer) and jax.numpy.issubdtype(
                leaf.dtype, jax.numpy.inexact):
            return _forward_mode_only.bind(leaf, message=message)
        return leaf

    return jax.tree.map(guard, tree)
