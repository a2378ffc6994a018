r"""The peak of a tire's steady-state force-slip curve at a given speed.

`braking_curve` is the steady-state $\mu(s)$ at braking slip $s = r\omega/v - 1\in[-1, 0]$
(negative: braking): eq. 19 for `UniformLumpedLuGre`, the lumped steady state for
`LumpedLuGre`, the formula itself for `RelaxedMagicFormula` (its transient slip tends to
$v_r/|v| = s$). `driving_curve` is eq. 18 at driving slip $s = 1 - v/(r\omega)\in[0, 1]$.
`peak_braking` and `peak_driving` find the slip of the largest $|\mu|$ by a grid (finer
near zero slip, where the peaks are) and Newton steps on $d\mu/ds = 0$ inside the best
grid cell: smooth in the tire's parameters and the speed (the estimate-based controller
differentiates through it), and the same code the physical limit uses.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..tire.lugre import AbstractLongitudinalTire, LumpedLuGre
from ..tire.magic_formula import magic_formula
from ..tire.relaxed_magic_formula import RelaxedMagicFormula
from .tire import UniformLumpedLuGre


_GRID = 64
_NEWTON_STEPS = 6


def braking_curve(tire: AbstractLongitudinalTire, s, v, r=0.3):
    r"""Steady-state $\mu = F/F_n$ at braking slip `s` and speed `v` [m/s] (module docstring;
    `r` [m] matters for `LumpedLuGre` only). Negative: a braking force."""
    if isinstance(tire, UniformLumpedLuGre):
        return tire.braking_mu(s, v)
    if isinstance(tire, RelaxedMagicFormula):
        p = tire.params
        return magic_formula(s, p.B, p.C, p.D, p.E)
    if isinstance(tire, LumpedLuGre):
        return tire.steady_state_mu(v, (1.0 + s) * v / r, r)
    raise TypeError(f"no steady-state curve for {type(tire).__name__}")


def driving_curve(tire: UniformLumpedLuGre, s, v):
    r"""Steady-state $\mu$ at driving slip `s` $\in[0, 1)$ and speed `v` (eq. 18, with
    $r\omega = v/(1-s)$)."""
    return tire.driving_mu(s, v / (1.0 - s), 1.0)


def _peak(curve, lo, hi):
    """Slip in [lo, hi] (magnitudes, hi <= 1) of the largest |curve|, and |curve| there."""
    u = jnp.linspace(0.0, 1.0, _GRID)
    grid = lo + (hi - lo) * u * u  # finer near zero slip
    values = jax.vmap(curve)(grid)
    i = jnp.argmax(values)
    a, b = grid[jnp.maximum(i - 1, 0)], grid[jnp.minimum(i + 1, _GRID - 1)]
    d1 = jax.grad(curve)
    d2 = jax.grad(d1)
    s = grid[i]
    for _ in range(_NEWTON_STEPS):
        step = -d1(s) / jnp.where(d2(s) < 0, d2(s), -1.0)  # ascent if not concave
        s = jnp.clip(s + step, a, b)
    return s, curve(s)


def peak_braking(tire: AbstractLongitudinalTire, v, r=0.3, max_slip=1.0):
    r"""Braking slip $s^* < 0$ of the largest braking force at speed `v`, and
    $\mu^* = |\mu(s^*)|$; slips beyond `max_slip` in magnitude are not considered."""
    lam, mu = _peak(lambda lam: -braking_curve(tire, -lam, v, r), 0.0, max_slip)
    return -lam, mu


def peak_driving(tire: UniformLumpedLuGre, v, max_slip=0.95):
    r"""Driving slip $s^* > 0$ of the largest traction force at speed `v`, and $\mu^*$."""
    return _peak(lambda s: driving_curve(tire, s, v), 0.0, max_slip)
