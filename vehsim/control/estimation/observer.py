r"""A nonlinear observer of the friction state with an adaptive road condition $\theta$.

In the line of Canudas de Wit and Tsiotras (CDC 1999) and Canudas de Wit, Horowitz and
Tsiotras (1999, the report's ref. [35]): a copy of the wheel and the lumped tire (eqs.
22-23, `UniformLumpedLuGre` at the estimate $\hat\theta$) runs beside the plant under the
known brake torque, its wheel speed is corrected by the measured one (output injection), and
$\theta$ is adapted from the wheel-speed innovation. Per sample $k$ (period $T$):

1. *predict*: integrate the copy $(\hat v, \hat\omega, F_n, \hat z)$ over the sample from
   $\hat v_{k-1}$, $\hat\omega_{k-1}$ and $\hat z_{k-1}$, under the brake torque the
   actuator model gives for the commands (the plant's integrator, so that the copy is exact
   when $\hat\theta = \theta$), giving $\hat\omega_k^-$, $\hat z_k$, and the copy's wheel
   speed $\hat\omega^-(t_m)$ at the time $t_m$ the measurement stands for (the midpoint of
   the last tone-wheel edge interval, `vehsim.control.plant.sensors`; linear between sub-steps);
2. *adapt* $\vartheta = \log\hat\theta$ by recursive least squares on the innovation
   $e = \omega_m - \hat\omega^-(t_m)$ with the regressor $\phi = \partial\hat\omega^-(t_m)/
   \partial\vartheta$ (carried through the copy by sensitivity states; the directional
   derivative by forward-mode differentiation through the copy's integrator, exact in
   any precision, where a finite difference of wheel speeds near 100 rad/s cancels to
   nothing in float32):
   $K = P\phi/(R + \phi^2P)$, $\vartheta \leftarrow \Pi(\vartheta + \operatorname{clip}(Ke,
   \pm\Delta_{max}))$, $P \leftarrow \min((1 - fK\phi)P/\lambda, P_{max})$, with $\Pi$ the
   projection onto $[\log\theta_{min}, \log\theta_{max}]$, $\Delta_{max}$ a step bound
   against outliers and $f\in[0, 1]$ the fraction of the step taken (a step cut short
   leaves the covariance large, so that a far-off prior is left at the step bound's pace);
   A change of road shows as innovations far larger than the covariance expects, when
   $P$ has long since shrunk: a CUSUM detector on the normalised innovation squared
   $\nu = e^2/(R + \phi^2P)$, $g \leftarrow \max(0, g + \nu - \delta)$, raises $P$ to
   $P_0$ when $g > h$ and restarts (covariance resetting), so the estimate leaves the old
   road in a few samples instead of at the pace of forgetting;
3. *correct*: $\hat\omega_k = \hat\omega_k^- + Le$, $\hat v_k = \hat v_k^- + L_v(v_k -
   \hat v_k^-)$ with the measured (noisy) vehicle speed $v_k$: a filtered speed, which the
   controllers use.

The measured wheel speed only counts when a tone-wheel edge arrived in the sample (a locked
wheel sends none; its speed estimate is then a bound, not a measurement). The regressor is
small where the force does not depend on $\theta$ (at small slip the curves of all roads
share their slope, eq. 19): there the gain vanishes and the estimate holds; with a constant
speed and no braking nothing is identifiable, and nothing moves.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float

from ..._checks import check_positive, check_range, is_concrete
from ..._fields import array_field
from ...tire.lugre import LuGreParams
from ...tire.uniform_lumped import UniformLumpedLuGre
from ...vehicle.quarter_car import QuarterCar, QuarterCarState
from ..plant.hardware import BrakeHardware, brake_torque
from ..plant.integrate import hermite, integrate_sample


class ObserverState(eqx.Module):
    r"""$\hat z$, $\hat\omega$, $\hat v$, $\vartheta = \log\hat\theta$, its covariance
    $P$, the sensitivities $\partial(\hat\omega, \hat z, \hat v)/\partial\vartheta$, the
    last innovation and the change detector's statistic $g$."""

    z: Float[Array, ""]
    omega: Float[Array, ""]
    v: Float[Array, ""]
    log_theta: Float[Array, ""]
    covariance: Float[Array, ""]
    sensitivity: Float[Array, " 3"]
    innovation: Float[Array, ""]
    change_statistic: Float[Array, ""]

    @property
    def theta(self):
        return jnp.exp(self.log_theta)


def _copy_rates(t, y, args):
    car, unravel, hardware, torque0, target, t0 = args
    qs = unravel(y)
    return ravel_pytree(car.dynamics(t, qs, brake_torque(hardware, torque0, target, t - t0)))[0]


class FrictionObserver(eqx.Module):
    r"""The observer of the module docstring.

    **Fields:** `model` (`LuGreParams` of the tire; its `theta` is the prior $\hat\theta_0$),
    `theta_min`, `theta_max` (the projection range, containing the prior), `forgetting`
    $\lambda\in(0, 1]$ (0.98), `initial_covariance` $P_0$ (1, in $(\log\theta)^2$),
    `max_covariance` $P_{max}$ (10), `noise_variance` $R$ of the wheel-speed innovation
    [rad^2/s^2] (0.05), `max_step` $\Delta_{max}$ (0.2), `injection` $L\in[0, 1]$ (0.5),
    `speed_injection` $L_v\in[0, 1]$ (0.05), the change detector's `change_drift`
    $\delta$ (20) and `change_threshold` $h$ (200; `inf` turns it off).
    """

    model: LuGreParams
    theta_min: Float[Array, ""] = array_field(default=0.3)
    theta_max: Float[Array, ""] = array_field(default=40.0)
    forgetting: Float[Array, ""] = array_field(default=0.98)
    initial_covariance: Float[Array, ""] = array_field(default=1.0)
    max_covariance: Float[Array, ""] = array_field(default=10.0)
    noise_variance: Float[Array, ""] = array_field(default=0.05)
    max_step: Float[Array, ""] = array_field(default=0.2)
    injection: Float[Array, ""] = array_field(default=0.5)
    speed_injection: Float[Array, ""] = array_field(default=0.05)
    change_drift: Float[Array, ""] = array_field(default=20.0)
    change_threshold: Float[Array, ""] = array_field(default=200.0)

    def __check_init__(self):
        owner = "FrictionObserver"
        check_positive(owner, "theta_min", self.theta_min)
        if is_concrete(self.theta_min) and is_concrete(self.theta_max):
            check_range(owner, "theta_max", self.theta_max, lower=float(self.theta_min))
            check_range(owner, "model.theta (the prior)", self.model.theta,
                        lower=float(self.theta_min), upper=float(self.theta_max))
        check_range(owner, "forgetting", self.forgetting, lower=0.0, upper=1.0,
                    lower_open=True)
        for name in ("initial_covariance", "max_covariance", "noise_variance", "max_step",
                     "change_drift", "change_threshold"):
            check_positive(owner, name, getattr(self, name))
        check_range(owner, "injection", self.injection, lower=0.0, upper=1.0)
        check_range(owner, "speed_injection", self.speed_injection, lower=0.0, upper=1.0)

    def init(self, omega0, v0) -> ObserverState:
        """Undeflected tire, the measured speeds, the prior $\\hat\\theta_0$."""
        z = jnp.zeros(())
        return ObserverState(z, jnp.asarray(omega0, dtype=float), jnp.asarray(v0, dtype=float),
                             jnp.log(self.model.theta), self.initial_covariance, jnp.zeros(3), z,
                             z)

    def _predict(self, car: QuarterCar, hardware: BrakeHardware, substeps, v, omega, z, log_theta,
                 torque0, target, t0, stamp):
        """Step 1: ``(omega(stamp), omega_k^-, z_k, v_k^-)`` of the copy at $\\hat\\theta =
        e^\\vartheta$ (the stamp clipped to the sample)."""
        tire = UniformLumpedLuGre(eqx.tree_at(lambda p: p.theta, self.model,
                                              jnp.exp(log_theta)))
        car = eqx.tree_at(lambda c: c.tire, car, tire)
        y, unravel = ravel_pytree(QuarterCarState(v, omega, car.Fn_static, z))
        args = (car, unravel, hardware, torque0, target, t0)
        T = hardware.sample_time
        y1, _ = integrate_sample(_copy_rates, y, args, t0, T, ((0, 1, 3),), substeps)
        rate0, rate1 = _copy_rates(t0, y, args), _copy_rates(t0 + T, y1, args)
        tau = jnp.clip((stamp - t0) / T, 0.0, 1.0)
        at_stamp = hermite(tau, T, y[1], y1[1], rate0[1], rate1[1])
        qs = unravel(y1)
        return at_stamp, qs.omega, qs.tire, qs.v

    def update(self, state: ObserverState, car: QuarterCar, hardware: BrakeHardware, substeps: int,
               v, omega, stamp, fresh, torque0, target, t0):
        """One sample: the copy advanced over the last sample from `t0` (brake torque from
        `torque0` lagging towards `target`), compared with the measured wheel speed `omega`
        standing for time `stamp` (a measurement only if `fresh`) and the measured vehicle
        speed `v` at the sample's end."""
        x = jnp.stack([state.omega, state.z, state.v, state.log_theta])
        d = jnp.concatenate([state.sensitivity, jnp.ones(1)])

        def predict(x):
            return jnp.stack(self._predict(car, hardware, substeps, x[2], x[0], x[1], x[3], torque0,
                                           target, t0, stamp))

        (omega_m, omega_pred, z, v_pred), (d_omega, d_end, dz, dv) = jax.jvp(predict, (x,),
                                                                              (d,))
        e = jnp.where(fresh, omega - omega_m, 0.0)
        P = state.covariance
        nis = e * e / (self.noise_variance + d_omega * d_omega * P)
        g = jnp.maximum(state.change_statistic + jnp.where(fresh, nis - self.change_drift, 0.0),
                        0.0)
        changed = g > self.change_threshold
        P = jnp.where(changed, jnp.maximum(P, self.initial_covariance), P)
        g = jnp.where(changed, 0.0, g)
        K = jnp.where(fresh, P * d_omega / (self.noise_variance + d_omega * d_omega * P), 0.0)
        full = K * e
        step = jnp.clip(full, -self.max_step, self.max_step)
        taken = jnp.where(full == 0, 1.0, step / jnp.where(full == 0, 1.0, full))
        log_theta = jnp.clip(state.log_theta + step, jnp.log(self.theta_min),
                             jnp.log(self.theta_max))
        P = jnp.minimum((1.0 - taken * K * d_omega) * P / self.forgetting, self.max_covariance)
        L = jnp.where(fresh, self.injection, 0.0)
        omega_hat = jnp.where(fresh, omega_pred + L * e, jnp.minimum(omega_pred, omega))
        v_hat = v_pred + self.speed_injection * (v - v_pred)
        sensitivity = jnp.stack([(1.0 - L) * d_end, dz, (1.0 - self.speed_injection) * dv])
        return ObserverState(z, omega_hat, v_hat, log_theta, P, sensitivity, e, g)
