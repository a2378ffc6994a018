r"""A nonlinear observer of the friction state with an adaptive road parameter.

In the line of Canudas de Wit and Tsiotras (CDC 1999) and Canudas de Wit, Horowitz and
Tsiotras (1999, the report's ref. [35]): a copy of the wheel and the assumed tire (a
parametrisation, `vehsim.control.estimation.parametrisation`: by default the lumped tire of
eqs. 22-23, `UniformLumpedLuGre`, at the estimate $\hat\theta$; any LuGre tire with its
$\theta$, or any tire with a friction scale $\lambda$) runs beside the plant under the known
brake torque, its wheel speed is corrected by the measured one (output injection), and the
log-parameter $\vartheta$ ($\log\hat\theta$, or $\log\hat\lambda$) is adapted from the
wheel-speed innovation. Per sample $k$ (period $T$):

1. *predict*: integrate the copy $(\hat v, \hat\omega, F_n, \hat z)$ over the sample from
   $\hat v_{k-1}$, $\hat\omega_{k-1}$ and $\hat z_{k-1}$, under the brake torque the
   actuator model gives for the commands (the plant's integrator, so that the copy is exact
   when the assumed tire is the plant's), giving $\hat\omega_k^-$, $\hat z_k$, and the copy's
   wheel speed $\hat\omega^-(t_m)$ at the time $t_m$ the measurement stands for (the midpoint
   of the last tone-wheel edge interval, `vehsim.control.plant.sensors`; linear between
   sub-steps);
2. *adapt* $\vartheta$ by recursive least squares on the innovation
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

**Assumes** the plant's tire is the assumed one at some value of the parameter: the
estimate is that value where it is, and the best-fitting value of the wrong shape where it
is not (biased: a uniform-load LuGre assumed for a constant-$\kappa_0$ tire reads $\theta$
10 % high on Table 3's dry road with $\kappa_0$ = 2). **Blind** (the estimate holds) where the data carry no
information: the measured wheel speed only counts when a tone-wheel edge arrived in the
sample (a locked wheel sends none; its speed estimate is then a bound, not a measurement);
the regressor is small where the force does not depend on the parameter (at small slip the
curves of all roads share their slope, eq. 19): there the gain vanishes and the estimate
holds; with a constant speed and no braking nothing is identifiable, and nothing moves.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float, PyTree

from ..._checks import check_positive, check_range, is_concrete
from ..._fields import array_field
from ...tire.lugre import AbstractLongitudinalTire
from ...vehicle.quarter_car import QuarterCar, QuarterCarState
from ..plant.hardware import BrakeHardware, brake_torque
from ..plant.integrate import hermite, integrate_sample
from .base import AbstractFrictionEstimator
from .parametrisation import AbstractRoadParametrisation, as_parametrisation


class ObserverState(eqx.Module):
    r"""$\hat z$ (the assumed tire's friction state), $\hat\omega$, $\hat v$, $\vartheta =
    \log\hat\theta$ (the log of the estimated parameter, $\theta$ or $\lambda$), its
    covariance $P$, the sensitivities $\partial(\hat\omega, \hat z, \hat v)/\partial
    \vartheta$, the last innovation and the change detector's statistic $g$."""

    z: PyTree
    omega: Float[Array, ""]
    v: Float[Array, ""]
    log_theta: Float[Array, ""]
    covariance: Float[Array, ""]
    sensitivity: Float[Array, " n"]
    innovation: Float[Array, ""]
    change_statistic: Float[Array, ""]

    @property
    def theta(self):
        return jnp.exp(self.log_theta)


def _copy_rates(t, y, args):
    car, unravel, hardware, torque0, target, t0 = args
    qs = unravel(y)
    return ravel_pytree(car.dynamics(t, qs, brake_torque(hardware, torque0, target, t - t0)))[0]


class FrictionObserver(AbstractFrictionEstimator):
    r"""The observer of the module docstring.

    **Fields:** `model`, the assumed tire and its estimated parameter (an
    `AbstractRoadParametrisation` with one parameter, whose prior is $\hat\theta_0$; given
    `LuGreParams`, the `RoadCondition` of a `UniformLumpedLuGre` tire; a LuGre tire, its
    `RoadCondition`; any other tire, its `FrictionScale`), `theta_min`, `theta_max` (the
    projection range of the estimated parameter, containing the prior), `forgetting`
    $\lambda\in(0, 1]$ (0.98), `initial_covariance` $P_0$ (1, in $(\log\theta)^2$),
    `max_covariance` $P_{max}$ (10), `noise_variance` $R$ of the wheel-speed innovation
    [rad^2/s^2] (0.05), `max_step` $\Delta_{max}$ (0.2), `injection` $L\in[0, 1]$ (0.5),
    `speed_injection` $L_v\in[0, 1]$ (0.05), the change detector's `change_drift`
    $\delta$ (20) and `change_threshold` $h$ (200; `inf` turns it off), and
    `exact_derivatives` (False).

    **Derivatives of an update** (of a run through it). Its values use the exact derivative
    of the copy's steps. By default the update's own derivative holds the steps' Jacobians
    constant, as the plant's does: reverse mode then differentiates the tire model twice,
    not three times. That costs $10^{-4}$ to $9\times10^{-4}$ of each output's largest
    derivative in ordinary braking, but up to 4 % at a locked wheel, where the Jacobian
    changes fastest. The measurement's time stamp enters after the steps (the
    interpolation to it): its derivative is exact either way, however stiff the wheel.
    `exact_derivatives=True` differentiates the Jacobians too: the update's derivative is
    then the exact one (to $10^{-8}$ of the central differences at a locked wheel), with a
    larger program to compile.
    """

    model: AbstractRoadParametrisation = eqx.field(converter=as_parametrisation)
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
    exact_derivatives: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        owner = "FrictionObserver"
        if len(self.model.names) != 1:
            raise ValueError(f"FrictionObserver.model must estimate one parameter, got "
                             f"{self.model.names}")
        check_positive(owner, "theta_min", self.theta_min)
        prior = jnp.exp(self.model.prior()[0])
        if is_concrete(self.theta_min) and is_concrete(self.theta_max) and is_concrete(prior):
            check_range(owner, "theta_max", self.theta_max, lower=float(self.theta_min))
            check_range(owner, f"model.{self.model.names[0]} (the prior)", prior,
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
        log_prior = self.model.prior()[0]
        tire_state = self.belief_at(log_prior).init_state()
        n = ravel_pytree(tire_state)[0].shape[0]
        return ObserverState(tire_state, jnp.asarray(omega0, dtype=float),
                             jnp.asarray(v0, dtype=float), log_prior, self.initial_covariance,
                             jnp.zeros(n + 2), z, z)

    def belief(self, state: ObserverState) -> AbstractLongitudinalTire:
        """The tire the observer believes in at `state`: its model at the estimate."""
        return self.belief_at(state.log_theta)

    def signals(self, state: ObserverState) -> dict:
        """The filtered speed `v_hat`, the estimate `theta_hat`, the wheel-speed
        `innovation` and the covariance `theta_covariance` of the estimate's log."""
        return dict(v_hat=state.v, theta_hat=state.theta, innovation=state.innovation,
                    theta_covariance=state.covariance)

    def belief_at(self, log_theta) -> AbstractLongitudinalTire:
        """The assumed tire at the log-parameter `log_theta` (a scalar)."""
        return self.model.belief(log_theta[None])

    def _predict(self, car: QuarterCar, hardware: BrakeHardware, substeps, v, omega, z, log_theta,
                 torque0, target, t0, stamp, frozen_jacobian=False):
        """Step 1: ``(omega(stamp), omega_k^-, z_k, v_k^-)`` of the copy at $\\hat\\theta =
        e^\\vartheta$ (the stamp clipped to the sample)."""
        car = eqx.tree_at(lambda c: c.tire, car, self.belief_at(log_theta))
        y, unravel = ravel_pytree(QuarterCarState(v, omega, car.Fn_static, z))
        args = (car, unravel, hardware, torque0, target, t0)
        T = hardware.sample_time
        block = (0, 1) + tuple(range(3, y.shape[0]))
        y1, _ = integrate_sample(_copy_rates, y, args, t0, T, (block,), substeps,
                                 frozen_jacobian=frozen_jacobian)
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
        z_flat, unravel = ravel_pytree(state.z)
        n = z_flat.shape[0]
        x = jnp.concatenate([state.omega[None], z_flat, state.v[None], state.log_theta[None]])
        d = jnp.concatenate([state.sensitivity, jnp.ones(1)])
        args = (self, car, hardware, torque0, target, t0, stamp, x, d)
        if self.exact_derivatives:
            out, d_out = _predict_along(*args, substeps=substeps, unravel=unravel,
                                        frozen_jacobian=False)
        else:
            out, d_out = _predict_sensitivity(*args, substeps=substeps, unravel=unravel)
        omega_m, omega_pred, z, v_pred = out[0], out[1], unravel(out[2:n + 2]), out[n + 2]
        d_omega, d_end, dz, dv = d_out[0], d_out[1], d_out[2:n + 2], d_out[n + 2]
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
        # d omega_hat / d theta: of the correction (the innovation's regressor at the
        # measurement's time, not at the sample's end), or of the bound where it holds
        d_hat = jnp.where(fresh, d_end - L * d_omega, jnp.where(omega_pred <= omega, d_end, 0.0))
        sensitivity = jnp.concatenate([d_hat[None], dz,
                                       ((1.0 - self.speed_injection) * dv)[None]])
        return ObserverState(z, omega_hat, v_hat, log_theta, P, sensitivity, e, g)


def _predict_along(observer, car, hardware, torque0, target, t0, stamp, x, d, *, substeps, unravel,
                   frozen_jacobian):
    """The copy's prediction from ``x = (omega, z, v, log_theta)`` and its directional
    derivative along `d` (forward mode through the copy's integrator)."""
    n = x.shape[0] - 3

    def predict(x):
        at_stamp, omega_end, z_end, v_end = observer._predict(
            car, hardware, substeps, x[n + 1], x[0], unravel(x[1:n + 1]), x[n + 2], torque0,
            target, t0, stamp, frozen_jacobian)
        return jnp.concatenate([at_stamp[None], omega_end[None], ravel_pytree(z_end)[0],
                                v_end[None]])

    return jax.jvp(predict, (x,), (d,))


_STAMP = 6  # the position of `stamp` among `_predict_sensitivity`'s arguments


@eqx.filter_custom_jvp
def _predict_sensitivity(observer, car, hardware, torque0, target, t0, stamp, x, d, *, substeps,
                         unravel):
    """`_predict_along` with the exact derivative of the copy's steps (the values the observer
    runs on); differentiated in turn, with each step's Jacobian held constant."""
    return _predict_along(observer, car, hardware, torque0, target, t0, stamp, x, d,
                          substeps=substeps, unravel=unravel, frozen_jacobian=False)


@_predict_sensitivity.def_jvp
def _predict_sensitivity_jvp(primals, tangents, *, substeps, unravel):
    # the values exact; their derivative that of the steps with frozen Jacobians (the plant's
    # derivative, `advance`): differentiating the Jacobian inside the sensitivity is a third
    # derivative of the tire model, most of the reverse-mode program for a change of the
    # derivative of the order of the steps' local error
    tangents = list(jax.tree_util.tree_map(
        lambda p, t: jnp.zeros_like(p) if t is None and eqx.is_inexact_array(p) else t,
        primals, tangents, is_leaf=lambda a: a is None))
    # the measurement's time enters only the interpolation after the steps (`hermite`):
    # its derivative is taken exactly, at no cost in the steps (through the frozen steps it
    # would carry their error, times the wheel's stiff rate at a locked wheel)
    stamp = jnp.asarray(primals[_STAMP], dtype=float)
    stamp_tangent = jnp.zeros_like(stamp) if tangents[_STAMP] is None else tangents[_STAMP]
    tangents[_STAMP] = jax.tree_util.tree_map(jnp.zeros_like, tangents[_STAMP])

    def of_stamp(stamp):
        p = list(primals)
        p[_STAMP] = stamp
        return _predict_along(*p, substeps=substeps, unravel=unravel, frozen_jacobian=False)

    out, t_stamp = jax.jvp(of_stamp, (stamp,), (stamp_tangent,))
    _, t_steps = eqx.filter_jvp(
        lambda *p: _predict_along(*p, substeps=substeps, unravel=unravel, frozen_jacobian=True),
        tuple(primals), tuple(tangents))
    return out, jax.tree_util.tree_map(jnp.add, t_steps, t_stamp)
