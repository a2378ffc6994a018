r"""Any longitudinal tire with its force scaled: $\mu = \lambda\,\mu_{tire}$.

The friction scale $\lambda > 0$ plays the part of the Magic Formula's $\lambda_{\mu x}$
(LMUX) for any tire: the friction state and its dynamics are the tire's own, the force is
multiplied by $\lambda$, so the steady-state force-slip curve is $\lambda$ times the tire's
(same peak slip, peak $\lambda\mu^*$). With a `slip_scale` $\rho > 0$ the curve is also
stretched along the slip axis, $\mu(s) = \lambda\mu_{tire}(s/\rho)$ in steady state (the
tire sees the relative velocity $v_r/\rho$: peak slip $\rho s^*$, initial slope
$\lambda/\rho$ times the tire's). An estimator that knows the curve's shape but not the road
estimates $\lambda$ (`vehsim.FrictionScale`).
"""

from __future__ import annotations

import equinox as eqx
from jaxtyping import Array, Float

from .._checks import check_positive
from .._fields import array_field
from .lugre import AbstractLongitudinalTire


class FrictionScaleParams(eqx.Module):
    r"""The friction scale `scale` $\lambda$ (> 0, default 1) and the slip scale
    `slip_scale` $\rho$ (> 0, default 1) of `ScaledFriction`."""

    scale: Float[Array, ""] = array_field(default=1.0)
    slip_scale: Float[Array, ""] = array_field(default=1.0)

    def __check_init__(self):
        check_positive("FrictionScaleParams", "scale", self.scale)
        check_positive("FrictionScaleParams", "slip_scale", self.slip_scale)


class ScaledFriction(AbstractLongitudinalTire):
    r"""`tire` with its force scaled by `scale` $\lambda$ and its slip axis stretched by
    `slip_scale` $\rho$ (`params`, a `FrictionScaleParams`): the tire runs at the wheel
    speed $\omega'$ with $r\omega' - v = (r\omega - v)/\rho$, and $\mu = \lambda
    \mu_{tire}$ (module docstring).

    **Arguments:** `tire` (any `AbstractLongitudinalTire`), `scale` (1), `slip_scale` (1).
    """

    params: FrictionScaleParams
    tire: AbstractLongitudinalTire

    def __init__(self, tire: AbstractLongitudinalTire, scale=1.0, slip_scale=1.0):
        self.tire = tire
        self.params = FrictionScaleParams(scale, slip_scale)

    def _omega(self, v, omega, r):
        return (v + (r * omega - v) / self.params.slip_scale) / r

    def init_state(self):
        return self.tire.init_state()

    def dynamics(self, state, v, omega, r):
        return self.tire.dynamics(state, v, self._omega(v, omega, r), r)

    def mu(self, state, v, omega, r):
        return self.params.scale * self.tire.mu(state, v, self._omega(v, omega, r), r)

    def steady_state_mu(self, v, omega, r):
        r"""$\lambda$ times the tire's steady-state force at the stretched wheel speed."""
        return self.params.scale * self.tire.steady_state_mu(v, self._omega(v, omega, r), r)
