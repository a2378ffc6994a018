"""Inputs given as constants, samples or callables, turned into functions of time."""

from __future__ import annotations

from collections.abc import Callable

import diffrax as dfx
import jax.numpy as jnp


def as_signal(ts, x, shape: tuple[int, ...] = (), name: str = "input") -> Callable:
    """A callable ``t -> x(t)``: `x` is a callable already, a constant of `shape`, or samples
    of shape ``(T,) + shape`` on `ts` (linearly interpolated)."""
    if callable(x):
        return x
    x = jnp.asarray(x, dtype=float)
    if x.shape == shape:
        return lambda t: x
    if x.shape == jnp.shape(ts) + shape:
        return dfx.LinearInterpolation(ts=ts, ys=x).evaluate
    raise ValueError(
        f"{name} must be a constant of shape {shape}, samples of shape "
        f"{jnp.shape(ts) + shape} on ts, or a callable of t; got shape {x.shape}"
    )


def as_controls(ts, inputs, n_controls: int) -> tuple[Callable, bool]:
    r"""Turn `inputs` into a control law $u(t, y)$; also say whether it is sampled on `ts`.

    `inputs` is a constant vector ``(m,)``, samples ``(T, m)`` on `ts` (linear
    interpolation), or a callable ``u(t, state) -> (m,)`` (a time function that ignores
    the state, or a state feedback).
    """
    if callable(inputs):
        return inputs, False
    u = as_signal(ts, inputs, (n_controls,), name="inputs")
    return (lambda t, y: u(t)), jnp.shape(inputs) != (n_controls,)
