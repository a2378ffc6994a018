r"""How a wheel's normal load $F_n$ evolves during a braking: constant, relaxing to a
load-transfer target, or prescribed (measured). Used by `QuarterCar`."""

from __future__ import annotations

import abc

import diffrax as dfx
import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_nonnegative, check_positive, check_range, check_times
from .._fields import array_field


class AbstractNormalLoad(eqx.Module):
    r"""How the wheel's normal load $F_n$ evolves: $\dot F_n = \phi(t, F_n, F_x)$."""

    @abc.abstractmethod
    def rate(self, t, Fn, Fx, Fn_static):
        """$\\dot F_n$ [N/s] of the load state."""

    def value(self, t, Fn):
        """The load acting at time `t` given the load state `Fn` (the state itself here)."""
        return Fn

    def initial(self, t0, Fn_static):
        """$F_n(t_0)$ [N]."""
        return Fn_static


class ConstantLoad(AbstractNormalLoad):
    r"""$F_n = F_{n,\text{static}}$ throughout."""

    def rate(self, t, Fn, Fx, Fn_static):
        return jnp.zeros_like(Fn)


class LoadRelaxation(AbstractNormalLoad):
    r"""Load transfer with a lag: $\tau\dot F_n = F_{n,\text{static}} - k F_x - F_n$.

    Braking ($F_x < 0$) loads the wheel by $k|F_x|$ (for a front wheel of a car whose four
    wheels brake alike, $k \approx 2h/\ell$ with $h$ the CG height and $\ell$ the wheelbase);
    $\tau$ [s] is the pitch/suspension lag.
    """

    gain: Float[Array, ""] = array_field(default=0.4)
    tau: Float[Array, ""] = array_field(default=0.08)

    def __check_init__(self):
        check_range("LoadRelaxation", "gain", self.gain, lower=0.0)
        check_positive("LoadRelaxation", "tau", self.tau)

    def rate(self, t, Fn, Fx, Fn_static):
        return (Fn_static - self.gain * Fx - Fn) / self.tau


class PrescribedLoad(AbstractNormalLoad):
    r"""A given (e.g. measured) $F_n(t)$, linear between samples, used as an input.

    The load state is unused (held constant); `value` interpolates the samples, so a
    noisy measured load does not enter the stiff part of the solve as a state.
    """

    ts: Float[Array, " T"] = array_field()
    values: Float[Array, " T"] = array_field()

    def __check_init__(self):
        if self.ts.shape != self.values.shape or self.ts.ndim != 1:
            raise ValueError(
                f"PrescribedLoad.ts and .values must be 1-D of equal length, got "
                f"{self.ts.shape} and {self.values.shape}"
            )
        check_times("PrescribedLoad", self.ts)
        check_nonnegative("PrescribedLoad", "values", self.values)

    def _interp(self):
        return dfx.LinearInterpolation(ts=self.ts, ys=self.values)

    def rate(self, t, Fn, Fx, Fn_static):
        return jnp.zeros_like(Fn)

    def value(self, t, Fn):
        return self._interp().evaluate(t)

    def initial(self, t0, Fn_static):
        return self._interp().evaluate(t0)
