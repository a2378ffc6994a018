"""Numerically safe elementary functions: finite values *and* finite gradients everywhere.

Each uses the double-``where`` trick: the unsafe branch is evaluated on a harmless
substitute input where it would be singular, so neither the value nor the cotangent
carries a NaN.
"""

import jax
import jax.numpy as jnp


def safe_abs(x):
    """|x| with derivative sign(x) (0 at x = 0)."""
    return jnp.where(x == 0, jnp.zeros_like(x), jnp.abs(x))


def safe_sign(x):
    """sgn(x) with sgn(0) = 0 and zero derivative."""
    return jnp.sign(x)


def safe_pow_abs(x, p):
    """|x|**p for p > 0, with value and gradient 0 at x = 0 (in x and in p)."""
    is_zero = x == 0
    x_safe = jnp.where(is_zero, jnp.ones_like(x), jnp.abs(x))
    return jnp.where(is_zero, jnp.zeros_like(x_safe * p), x_safe**p)


def safe_norm(x, axis=-1):
    """Euclidean norm with zero gradient (not NaN) at the origin."""
    x = jnp.asarray(x)
    if x.shape[axis] <= 4:  # as adds of slices: cheaper than a reduction over a few
        # entries
        parts = jnp.moveaxis(x, axis, 0)
        sq = sum(parts[i] * parts[i] for i in range(x.shape[axis]))
    else:
        sq = jnp.sum(x * x, axis=axis)
    is_zero = sq == 0
    sq_safe = jnp.where(is_zero, jnp.ones_like(sq), sq)
    return jnp.where(is_zero, jnp.zeros_like(sq), jnp.sqrt(sq_safe))


def safe_div(num, den, fill=0.0):
    """num / den, equal to ``fill`` (with zero gradient) where den == 0."""
    is_zero = den == 0
    den_safe = jnp.where(is_zero, jnp.ones_like(den), den)
    return jnp.where(is_zero, jnp.full_like(num / den_safe, fill), num / den_safe)


def one_minus_exp_over(x):
    """(1 - exp(-x)) / x for x >= 0, equal to 1 at x = 0; smooth, with a series near 0."""
    small = x < 1e-4
    x_safe = jnp.where(small, jnp.ones_like(x), x)
    exact = -jnp.expm1(-x_safe) / x_safe
    series = 1.0 - x / 2.0 + x * x / 6.0 - x * x * x / 24.0
    return jnp.where(small, series, exact)


TRANSPORT_FLOOR = 1e-100
r"""Floor [m/s] of the transport speed $c = |\omega r|$ where it divides a boundary layer's
rate $k = C_0L/c$: below it the layer ($1/k$ of the contact) is thinner than any double
resolves, and the rate's derivative $-k/c$ would overflow (a NaN once a saturated
exponential multiplies it)."""


def floor_transport(c):
    r"""$\max(c,$ `TRANSPORT_FLOOR` $)$ in value, with derivative 1 in both modes: below the
    floor the derivatives are those at the floor, i.e. the limit $c \to 0^+$ to rounding,
    where a plain maximum would make them 0 and the unfloored quotient NaN."""
    return c + jax.lax.stop_gradient(jnp.maximum(c, TRANSPORT_FLOOR) - c)


def safe_sqrt(x):
    """sqrt(x) for x >= 0, with a zero (not infinite) derivative at x = 0."""
    is_zero = x == 0
    return jnp.where(is_zero, jnp.zeros_like(x), jnp.sqrt(jnp.where(is_zero, jnp.ones_like(x), x)))


def safe_hypot(x, y):
    """sqrt(x^2 + y^2), elementwise, with zero gradient (not NaN) at the origin."""
    return safe_sqrt(x * x + y * y)


def safe_arctan2(y, x):
    """arctan2(y, x), 0 at the origin with a zero gradient there (not NaN): the angle of a
    velocity of a car at rest."""
    origin = (x == 0) & (y == 0)
    return jnp.where(origin, jnp.zeros_like(x * y),
                     jnp.arctan2(y, jnp.where(origin, jnp.ones_like(x), x)))


def wrap_angle(angle):
    r"""The angle in $(-\pi, \pi]$."""
    return -jnp.remainder(-angle + jnp.pi, 2 * jnp.pi) + jnp.pi
