r"""The peak of a tire's steady-state force-slip curve at a given speed.

`braking_curve` is the steady-state $\mu(s)$ at braking slip $s = r\omega/v - 1\in[-1, 0]$
(negative: braking) of any tire, its `braking_mu`: eq. 19 for `UniformLumpedLuGre`, the
lumped steady state for `LumpedLuGre`, the formula itself for `RelaxedMagicFormula` (its
transient slip tends to $v_r/|v| = s$), one linear solve for `DistributedLuGre`, and for
`ScaledFriction` the wrapped tire's scaled and stretched, and for any other tire
(`MFLongitudinalTire`, `RelaxedBurckhardt`, ...) its state brought to rest at fixed slip and
speed by Newton's method (`solve_steady_state`).
`driving_curve` is the same at driving slip $s = 1 - v/(r\omega)\in[0, 1]$ (eq. 18 for
`UniformLumpedLuGre`).
`peak_braking` and `peak_driving` find the slip of the largest $|\mu|$ by a grid (finer
near zero slip, where the peaks are) and a golden-section search inside the best grid
cell; the derivative of the peak slip with respect to the tire's parameters and the speed
is that of the implicit function $\partial\mu/\partial s = 0$,
$ds^*/dp = -\mu_{sp}/\mu_{ss}$ (zero at the ends of the slip range), so the estimate-based
controller is differentiable through it. The physical limit uses the same code.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..._checks import check_nonnegative, check_positive, check_range
from ...tire.lugre import AbstractLongitudinalTire
from ...tire.uniform_lumped import UniformLumpedLuGre


_GRID = 64
_GOLDEN_STEPS = 40
_INVERSE_GOLDEN = 0.5 * (5.0**0.5 - 1.0)


def braking_curve(tire: AbstractLongitudinalTire, s, v, r=0.3):
    r"""Steady-state $\mu = F/F_n$ at braking slip `s` and speed `v` [m/s] of any
    `AbstractLongitudinalTire` (module docstring; the wheel radius `r` [m] fixes
    $\omega = (1 + s)v/r$ where the model needs it). Negative: a braking force."""
    return tire.braking_mu(s, v, r)


def driving_curve(tire: AbstractLongitudinalTire, s, v, r=0.3):
    r"""Steady-state $\mu$ at driving slip `s` $\in[0, 1)$ and speed `v` [m/s] of any
    `AbstractLongitudinalTire`: eq. 18 for `UniformLumpedLuGre` (with $r\omega = v/(1-s)$),
    for any other tire its `steady_state_mu` at $\omega = v/((1 - s)r)$ (the wheel radius `r`
    [m]). Positive: a driving force."""
    if isinstance(tire, UniformLumpedLuGre):
        return tire.driving_mu(s, v / (1.0 - s), 1.0)
    return tire.steady_state_mu(v, v / ((1.0 - s) * r), r)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1, 2))
def _argmax(curve, lo, hi, args):
    """Slip in [lo, hi] of the largest `curve(s, args)` (module docstring)."""
    u = jnp.linspace(0.0, 1.0, _GRID)
    grid = lo + (hi - lo) * u * u  # finer near zero slip
    i = jnp.argmax(jax.vmap(lambda s: curve(s, args))(grid))
    a, b = grid[jnp.maximum(i - 1, 0)], grid[jnp.minimum(i + 1, _GRID - 1)]

    def shrink(_, ab):
        a, b = ab
        c, d = b - _INVERSE_GOLDEN * (b - a), a + _INVERSE_GOLDEN * (b - a)
        left = curve(c, args) >= curve(d, args)
        return jnp.where(left, a, c), jnp.where(left, d, b)

    a, b = jax.lax.fori_loop(0, _GOLDEN_STEPS, shrink, (a, b))
    s = 0.5 * (a + b)
    # a peak at an end of the range (a curve still rising at lock) is that end, exactly:
    # the search stops a bracket short of it, where the derivative rule would take the
    # nearest point for an interior peak
    return jnp.where(curve(hi, args) >= curve(s, args), hi, s)


@_argmax.defjvp
def _argmax_jvp(curve, lo, hi, primals, tangents):
    (args,), (d_args,) = primals, tangents
    s = _argmax(curve, lo, hi, args)
    slope = jax.grad(curve, argnums=0)
    curvature = jax.grad(slope, argnums=0)(s, args)
    d_slope = jax.jvp(lambda a: slope(s, a), (args,), (d_args,))[1]
    interior = (s > lo) & (s < hi) & (curvature < 0)
    return s, jnp.where(interior, -d_slope / jnp.where(interior, curvature, -1.0), 0.0)


def _braking_magnitude(lam, args):
    tire, v, r = args
    return -braking_curve(tire, -lam, v, r)


def _driving_magnitude(s, args):
    tire, v, r = args
    return driving_curve(tire, s, v, r)


def _check_peak_search(owner, v, r, max_slip, upper_open) -> None:
    check_nonnegative(owner, "v", v)
    check_positive(owner, "r", r)
    check_range(owner, "max_slip", max_slip, lower=0.0, upper=1.0, lower_open=True,
                upper_open=upper_open)


def peak_braking(tire: AbstractLongitudinalTire, v, r=0.3, max_slip=1.0):
    r"""Braking slip $s^* < 0$ of the largest braking force at speed `v`, and
    $\mu^* = |\mu(s^*)|$; slips beyond `max_slip` in magnitude are not considered
    (`max_slip` in (0, 1], 1: the locked wheel; `v` >= 0, `r` > 0)."""
    _check_peak_search("peak_braking", v, r, max_slip, upper_open=False)
    args = (tire, jnp.asarray(v, dtype=float), jnp.asarray(r, dtype=float))
    lam = _argmax(_braking_magnitude, 0.0, float(max_slip), args)
    return -lam, _braking_magnitude(lam, args)


def peak_driving(tire: AbstractLongitudinalTire, v, max_slip=0.99, r=0.3):
    r"""Driving slip $s^* > 0$ of the largest traction force at speed `v` [m/s] of any tire
    (`driving_curve`; wheel radius `r` [m]), and $\mu^*$; slips up to `max_slip` in (0, 1)
    are considered (a driving slip of 1 is a wheel spinning on a car at rest)."""
    _check_peak_search("peak_driving", v, r, max_slip, upper_open=True)
    args = (tire, jnp.asarray(v, dtype=float), jnp.asarray(r, dtype=float))
    s = _argmax(_driving_magnitude, 0.0, float(max_slip), args)
    return s, _driving_magnitude(s, args)
