r"""Braking controllers, sampled at the hardware's rate, commanding a brake torque $T_c\ge0$.

Each sees the `Measurement` of the sample (measured wheel and vehicle speed, the wheel slip
$\hat s = r\hat\omega/\hat v - 1$, the wheel's peripheral acceleration $r\Delta\hat\omega/T$
and the mean brake torque $\bar T_b$ the actuator applied over the last sample, known from
the commands through the actuator's model as the estimators know it) and the estimator's
*belief*: the tire it currently believes in (its assumed model at the current estimate, e.g.
`UniformLumpedLuGre` at $\hat\theta$; `vehsim.control.estimation`). An estimate-based target
is read off the belief's steady-state curve (`braking_curve`, `peak_braking`), whatever the
belief's family.
Below `handback_speed` (3 m/s by default) every controller hands back to plain braking (the
full torque): there slip measurement is poor and a locked wheel costs little distance.

- `LockedWheel`: the full torque from the start, no ABS (the wheel locks).
- `RuleBasedABS`: the classic build / hold / dump cycle on wheel-deceleration and slip
  thresholds (after the Bosch cycle of the *Automotive Handbook*).
- `SlipTracking`: the wheel held at a fixed target slip $s^*$ by the torque that would hold
  it there on the estimated road plus PI feedback,
  $T_c = T_{ff} + K_pe + I$, $\dot I = K_ie$, on the error in wheel peripheral speed
  $\epsilon = r\hat\omega - (1 + s^*)\hat v$ [m/s] (so that the gains do not change with
  speed), taken as $e = e_{max}\tanh(\epsilon/e_{max})$ when the wheel is too fast
  ($\epsilon > 0$, saturating at $e_{max}$ = 1 m/s, so that the feedback corrects the
  feedforward rather than overriding it at the onset) and $e = \epsilon$ when it slips too
  much (a wheel running away past the peak is pulled back at full gain), with
  $T_{ff} = \hat\mu(s^*)F_n\,(r + J(1+s^*)/(mr))$, $\hat\mu$ the belief's steady-state
  curve at $\hat v$ (eq. 19 at $\hat\theta$ for a `UniformLumpedLuGre` belief): the brake
  torque that balances the friction torque and decelerates the wheel
  with the car ($J\dot\omega = -rF - T_b$, $\dot\omega = (1+s^*)\dot v/r$, $m\dot v = F$).
- `PeakSlipTracking`: the same with $s^*$ the peak of the belief's curve at the measured
  speed (`peak_braking`), scaled by `slip_scale`.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..._checks import check_nonnegative, check_positive, check_range
from ..._fields import array_field
from ..._math import safe_div
from ...tire.lugre import AbstractLongitudinalTire
from ...vehicle.quarter_car import QuarterCar
from ..road.peak import braking_curve, peak_braking


class Measurement(eqx.Module):
    """What the controller sees at a sample (see the module docstring)."""

    omega: Float[Array, ""]
    v: Float[Array, ""]
    slip: Float[Array, ""]
    wheel_accel: Float[Array, ""]
    brake_torque: Float[Array, ""]


class AbstractBrakeController(eqx.Module):
    """A sampled braking controller: `init` gives its state, `command` the brake torque."""

    @abc.abstractmethod
    def init(self, max_torque):
        """The controller's state before the first sample."""

    @abc.abstractmethod
    def command(self, state, m: Measurement, belief: AbstractLongitudinalTire, car: QuarterCar,
                dt, max_torque):
        """``(state, torque [N m], phase)`` for this sample (phase: an integer label);
        `belief` is the tire the estimator currently believes in (module docstring)."""


class LockedWheel(AbstractBrakeController):
    """The full torque from the start (no ABS)."""

    def init(self, max_torque):
        return jnp.zeros(())

    def command(self, state, m, belief, car, dt, max_torque):
        return state, max_torque, jnp.zeros((), int)


BUILD, HOLD, DUMP, HOLD_AFTER_DUMP, REBUILD, SLOW_BUILD = range(6)
"""Phases of `RuleBasedABS`."""


class RuleBasedABS(AbstractBrakeController):
    r"""Build / hold / dump on the wheel's peripheral acceleration $a_w$ and slip $\lambda$.

    Phases: *build* (the torque rises at `build_rate` until $a_w < -$`decel_threshold`),
    *hold* (until $\lambda >$ `slip_threshold`: dump; if the wheel stabilises below it, slow
    build), *dump* (falls at `dump_rate` until $a_w > -$`decel_threshold`), *hold after
    dump* (while the wheel re-accelerates, until $a_w <$ `accel_threshold` or $\lambda <$
    `slip_threshold`/2), *rebuild* (fast, to `rebuild_fraction` of the torque at which the
    last dump began: the memory of production ABS logic), *slow build* (at `slow_rate` until
    $a_w < -$`decel_threshold`: dump, the next cycle). In every phase $\lambda >$
    `lock_slip` dumps. $a_w$ is filtered with time constant `filter_time`. Defaults:
    thresholds 25 and 5 m/s^2, rates 30 000, 15 000 and 3000 N m/s, slips 0.2 and 0.5,
    fraction 0.8, 5 ms (thresholds chosen on the named surfaces from 30 m/s among a few
    settings; the cycle itself has no model of the road).
    """

    decel_threshold: Float[Array, ""] = array_field(default=25.0)
    accel_threshold: Float[Array, ""] = array_field(default=5.0)
    build_rate: Float[Array, ""] = array_field(default=30_000.0)
    dump_rate: Float[Array, ""] = array_field(default=15_000.0)
    slow_rate: Float[Array, ""] = array_field(default=3000.0)
    slip_threshold: Float[Array, ""] = array_field(default=0.2)
    lock_slip: Float[Array, ""] = array_field(default=0.5)
    rebuild_fraction: Float[Array, ""] = array_field(default=0.8)
    filter_time: Float[Array, ""] = array_field(default=0.005)

    def __check_init__(self):
        for name in ("decel_threshold", "accel_threshold", "build_rate", "dump_rate",
                     "slow_rate", "filter_time"):
            check_positive("RuleBasedABS", name, getattr(self, name))
        for name in ("slip_threshold", "lock_slip", "rebuild_fraction"):
            check_range("RuleBasedABS", name, getattr(self, name), lower=0, upper=1)

    def init(self, max_torque):
        z = jnp.zeros(())
        return jnp.asarray(BUILD), z, z, jnp.asarray(max_torque, dtype=float)

    def _next_phase(self, phase, a, lam, torque, reference):
        decel, stable = a < -self.decel_threshold, a > -self.decel_threshold
        nxt = jnp.select(
            [phase == BUILD, phase == HOLD, phase == DUMP, phase == HOLD_AFTER_DUMP,
             phase == REBUILD],
            [jnp.where(decel, HOLD, BUILD),
             jnp.where(lam > self.slip_threshold, DUMP, jnp.where(stable & (
                 a < self.accel_threshold), SLOW_BUILD, HOLD)),
             jnp.where(stable, HOLD_AFTER_DUMP, DUMP),
             jnp.where((a < self.accel_threshold) | (lam < 0.5 * self.slip_threshold),
                       REBUILD, HOLD_AFTER_DUMP),
             jnp.where(torque >= self.rebuild_fraction * reference, SLOW_BUILD, REBUILD)],
            jnp.where(decel, DUMP, SLOW_BUILD))
        return jnp.where(lam > self.lock_slip, DUMP, nxt)

    def command(self, state, m, belief, car, dt, max_torque):
        phase, torque, a, reference = state
        a = a + (m.wheel_accel - a) * (1.0 - jnp.exp(-dt / self.filter_time))
        new = self._next_phase(phase, a, -m.slip, torque, reference)
        reference = jnp.where((new == DUMP) & (phase != DUMP), torque, reference)
        rate = jnp.select([(new == BUILD) | (new == REBUILD), new == SLOW_BUILD, new == DUMP],
                          [self.build_rate, self.slow_rate, -self.dump_rate], 0.0)
        torque = jnp.clip(torque + rate * dt, 0.0, max_torque)
        return (new, torque, a, reference), torque, new


ERROR_SCALE = 1.0
"""$e_{max}$ [m/s] of the slip-tracking controllers' saturated error."""


class AbstractSlipTracking(AbstractBrakeController):
    r"""PI control of the wheel peripheral speed to $(1 + s^*)\hat v$ around the feedforward
    (module docstring), the integral clamped to $[-T_{ff}, T_{max} - T_{ff}]$ (anti-windup:
    it never asks for a torque the actuator cannot give)."""

    kp: eqx.AbstractVar[Float[Array, ""]]
    ki: eqx.AbstractVar[Float[Array, ""]]

    @abc.abstractmethod
    def target(self, m: Measurement, belief: AbstractLongitudinalTire, radius):
        r"""$(s^*, \hat\mu(s^*))$ at this sample: the target slip ($< 0$) and the friction
        magnitude the belief's steady-state curve gives there."""

    def init(self, max_torque):
        return jnp.zeros(())

    def command(self, state, m, belief, car, dt, max_torque):
        s_target, mu_target = self.target(m, belief, car.radius)
        integral, torque = track_slip(state, m, s_target, mu_target, car, dt, max_torque,
                                      self.kp, self.ki)
        return integral, torque, jnp.zeros((), int)


def track_slip(integral, m: Measurement, s_target, mu_target, car: QuarterCar, dt, max_torque,
               kp, ki):
    r"""``(integral, torque)``: the PI law of `AbstractSlipTracking` holding the wheel at the
    slip `s_target` around the feedforward of the friction magnitude `mu_target` there."""
    r = car.radius
    feedforward = mu_target * car.Fn_static * (r + car.inertia * (1.0 + s_target) / (
        car.mass * r))
    eps = r * m.omega - (1.0 + s_target) * m.v
    e = jnp.where(eps > 0, ERROR_SCALE * jnp.tanh(eps / ERROR_SCALE), eps)
    integral = jnp.clip(integral + ki * e * dt, -feedforward, max_torque - feedforward)
    torque = jnp.clip(feedforward + integral + kp * e, 0.0, max_torque)
    return integral, torque


class SlipTracking(AbstractSlipTracking):
    r"""Fixed target slip `slip` $s^*$ (-0.15); gains `kp` [N m s/m] (60) and `ki`
    [N m/m] (600)."""

    slip: Float[Array, ""] = array_field(default=-0.15)
    kp: Float[Array, ""] = array_field(default=60.0)
    ki: Float[Array, ""] = array_field(default=600.0)

    def __check_init__(self):
        check_range("SlipTracking", "slip", self.slip, lower=-1.0, upper=0.0,
                    upper_open=True)
        check_nonnegative("SlipTracking", "kp", self.kp)
        check_nonnegative("SlipTracking", "ki", self.ki)

    def target(self, m, belief, radius):
        return self.slip, -braking_curve(belief, self.slip, jnp.maximum(m.v, 0.5), radius)


class PeakSlipTracking(AbstractSlipTracking):
    r"""Target slip: `slip_scale` times the peak of the belief's steady-state curve at the
    measured speed (eq. 19 at $\hat\theta$ for a `UniformLumpedLuGre` belief); gains `kp`
    (60) and `ki` (600) as `SlipTracking`."""

    slip_scale: Float[Array, ""] = array_field(default=1.0)
    kp: Float[Array, ""] = array_field(default=60.0)
    ki: Float[Array, ""] = array_field(default=600.0)

    def __check_init__(self):
        check_positive("PeakSlipTracking", "slip_scale", self.slip_scale)
        check_nonnegative("PeakSlipTracking", "kp", self.kp)
        check_nonnegative("PeakSlipTracking", "ki", self.ki)

    def target(self, m, belief, radius):
        v = jnp.maximum(m.v, 0.5)
        s_peak, _ = peak_braking(belief, v, radius)
        s = jnp.clip(self.slip_scale * s_peak, -1.0, -1e-3)
        return s, -braking_curve(belief, s, v, radius)


def measurement(omega, v, omega_prev, radius, dt, brake_torque=0.0) -> Measurement:
    """The `Measurement` of a sample from the measured speeds and the mean brake torque
    [N m] the actuator applied over the last sample."""
    slip = safe_div(radius * omega, v, fill=1.0) - 1.0
    return Measurement(omega, v, jnp.clip(slip, -1.0, 1.0), radius * (omega - omega_prev) / dt,
                       jnp.asarray(brake_torque, dtype=jnp.result_type(omega, float)))
