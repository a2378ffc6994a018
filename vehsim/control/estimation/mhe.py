r"""A moving-horizon estimator of the road condition: Levenberg-Marquardt through the simulator.

Over a window of the last $N$ samples of a braking (a `BrakingRecord`: measured wheel speeds
at their time stamps, measured vehicle speeds, and the brake torque the actuator model gives
for the commands), fit
$$u = (\log\theta,\ [\log\mu_s,\ \log\mu_c],\ \bar z_0/z_s,\ \omega_0,\ v_0)$$
(the log-parameters of the assumed model, a parametrisation of
`vehsim.control.estimation.parametrisation`: by default the lumped tire `UniformLumpedLuGre`
with its $\theta$; any LuGre tire with a scalar friction state, or any such tire with a
friction scale $\lambda$, and $z_s$ the model's typical deflection) so that the quarter car
with the assumed tire, started from $(v_0, \omega_0, \bar z_0)$ at the window's start and
driven by that torque, reproduces the measurements: residuals $(\omega(t_j) -
\omega_j)/\sigma_\omega$ where the wheel speed is a measurement (`fresh`) and $(v(t_j) -
v_j)/\sigma_v$. The simulation is the plant's own integrator (`integrate_sample`), so that
on noise-free data of the assumed model the fit recovers $\theta$ to the solver's
tolerance; on data of another tire it returns the assumed tire's best fit (biased: a
uniform-load LuGre assumed for a constant-$\kappa_0$ tire reads $\theta$ 10 % high on
Table 3's dry road with $\kappa_0$ = 2, `vehsim.control.experiments.estimators`). Past
the peak the wheel's dynamics are unstable and the fit has local minima, so it starts from
`starts` values of $\theta$ spaced logarithmically over $[\theta_{min}, \theta_{max}]$ and
keeps the best; optimistix's
Levenberg-Marquardt solves every start of every window of a braking at once (`jax.vmap`).
Its Jacobian comes from forward differences of the simulation, all columns in one vmapped
call (a custom JVP rule): a few parameters, and the simulation compiled once rather than
differentiated through its implicit steps.

A window counts as solved when Levenberg-Marquardt stops or when MINPACK's gradient test
holds (largest cosine between the residuals and a Jacobian column below 1e-6): on noise-free
data the optimum has zero residual, where the solver's own test stalls. A window whose
solve fails otherwise than by running out of steps (e.g. `RESULTS.nonfinite` on a
non-finite measurement) returns the solver's result.

**Standard errors** are Gauss-Newton's, $\operatorname{se}(\log\theta) = \sqrt{s^2[(J^\top
J)^{-1}]_{\theta\theta}}$ with $s^2$ the residuals' mean square over the observations
(the speed and the fresh wheel speeds, less the unknowns); $\operatorname{se}(\theta)
= \theta\operatorname{se}(\log\theta)$. **Identifiability** is judged with $s^2 = 1$ (the
sensors' stated noise): a window whose $\operatorname{se}(\log\theta)$ would exceed
`max_log_se` (10 %) cannot determine $\theta$ and returns `RESULTS.not_identifiable`. That
is the case with no braking (no slip: the force, and with it every residual, does not
depend on $\theta$) and at small slip, where all roads share the curves' initial slope.
$\theta$ scales the friction level as $g/\theta$, so freeing $\mu_s$ and $\mu_c$ together
with it is degenerate (only $\mu_s/\theta$ and $\mu_c/\theta$ are determined); freeing
one of them is not.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Bool, Float

from ..._checks import check_integer, check_order, check_positive
from ..._fields import array_field
from ..._optimality import max_gradient_cosine
from ..._results import RESULTS, is_successful
from ...vehicle.quarter_car import QuarterCar, QuarterCarState
from ..plant.hardware import BrakeHardware
from ..plant.integrate import SUBSTEPS, hermite, integrate_sample
from .observer import _copy_rates
from .parametrisation import AbstractRoadParametrisation, as_parametrisation, steady_state


_DIFFERENCE_STEP = 1e-7
_GTOL = 1e-6


class BrakingRecord(eqx.Module):
    r"""The signals of a braking an estimator reads, per control sample $k$ (length K):
    the sample times `ts` [s], the brake `torque` [N m] the actuator applied at the sample
    and the `target` it lagged towards over the sample (the actuator model's, for the
    commands), the measured wheel speed `omega_meas` [rad/s] standing for time
    `omega_stamp` [s] (a measurement only if `fresh`: a tone-wheel edge arrived in the
    sample) and the measured vehicle speed `v_meas` [m/s]. `BrakingRecord.from_signals`
    takes them from a saved run's signals (`BrakingRun.signals`)."""

    ts: Float[Array, " K"]
    torque: Float[Array, " K"]
    target: Float[Array, " K"]
    omega_stamp: Float[Array, " K"]
    omega_meas: Float[Array, " K"]
    v_meas: Float[Array, " K"]
    fresh: Bool[Array, " K"]

    @classmethod
    def from_signals(cls, signals: dict) -> BrakingRecord:
        """The record of a saved run's `signals` (a dict with these names)."""
        return cls(**{n: jnp.asarray(signals[n]) for n in _WINDOW_SIGNALS})

    def window(self, end, length: int) -> BrakingRecord:
        """The `length` + 1 samples ending at index `end` (traceable)."""
        return jax.tree_util.tree_map(
            lambda a: jax.lax.dynamic_slice_in_dim(a, end - length, length + 1), self)


class MHEResult(eqx.Module):
    r"""Per window: the end time `ts` [s], the estimate `theta` (of the model's first
    parameter: $\theta$, or $\lambda$ for a `FrictionScale`), its standard error
    `theta_se`, the final normalised cost `cost`, `result` (a `vehsim.RESULTS` item) and
    all the estimated parameters `values` (W, p: in the order of the model's `names`)."""

    ts: Float[Array, " W"]
    theta: Float[Array, " W"]
    theta_se: Float[Array, " W"]
    cost: Float[Array, " W"]
    result: RESULTS
    values: Float[Array, "W p"]


class MovingHorizonEstimator(eqx.Module):
    r"""The estimator of the module docstring.

    **Fields:** `model`, the assumed tire and what of it is estimated (an
    `AbstractRoadParametrisation`: its prior values other than the first are the initial
    guesses, e.g. `RoadCondition(tire, free=("theta", "mu_s"))`; given `LuGreParams`, the
    `RoadCondition` of a `UniformLumpedLuGre` tire; a LuGre tire, its `RoadCondition`; any
    other tire, its `FrictionScale`; the tire's friction state must be a scalar),
    `theta_min`, `theta_max` (the range of the starts of the first parameter), `starts`
    (static, 5), `window` (samples, static, 20), `wheel_noise` $\sigma_\omega$ [rad/s]
    (0.1), `speed_noise` $\sigma_v$ [m/s] (0.05), `max_log_se` (0.1), `max_steps` (static,
    40).
    """

    model: AbstractRoadParametrisation = eqx.field(converter=as_parametrisation)
    theta_min: Float[Array, ""] = array_field(default=0.3)
    theta_max: Float[Array, ""] = array_field(default=40.0)
    starts: int = eqx.field(static=True, default=5)
    window: int = eqx.field(static=True, default=20)
    wheel_noise: Float[Array, ""] = array_field(default=0.1)
    speed_noise: Float[Array, ""] = array_field(default=0.05)
    max_log_se: Float[Array, ""] = array_field(default=0.1)
    max_steps: int = eqx.field(static=True, default=40)

    def __check_init__(self):
        state = self.model.belief(self.model.prior()).init_state()
        if ravel_pytree(state)[0].shape != (1,):
            raise ValueError("MovingHorizonEstimator.model must be a tire with a scalar "
                             "friction state (the window's initial state is one unknown)")
        if self.window < 2:
            raise ValueError(f"MovingHorizonEstimator.window must be at least 2 samples, got "
                             f"{self.window}")
        for name in ("wheel_noise", "speed_noise", "max_log_se", "theta_min", "theta_max"):
            check_positive("MovingHorizonEstimator", name, getattr(self, name))
        check_order("MovingHorizonEstimator", "theta_min", self.theta_min, "theta_max",
                    self.theta_max)
        check_integer("MovingHorizonEstimator", "starts", self.starts, lower=1)

    def _simulate(self, u, car: QuarterCar, hardware: BrakeHardware, data: BrakingRecord):
        """Wheel speeds at the stamps and vehicle speeds at the samples 1..N of a window."""
        k = len(self.model.names)
        z_scale = self.model.state_scale()
        car = eqx.tree_at(lambda c: c.tire, car, self.model.belief(u[:k]))
        y0, unravel = ravel_pytree(QuarterCarState(u[k + 2], u[k + 1], car.Fn_static,
                                                   z_scale * u[k]))
        T = hardware.sample_time

        def sample(y, d):
            t0, torque0, target, stamp = d
            args = (car, unravel, hardware, torque0, target, t0)
            y1, _ = integrate_sample(_copy_rates, y, args, t0, T, ((0, 1, 3),), SUBSTEPS)
            r0, r1 = _copy_rates(t0, y, args), _copy_rates(t0 + T, y1, args)
            omega = hermite(jnp.clip((stamp - t0) / T, 0.0, 1.0), T, y[1], y1[1], r0[1],
                            r1[1])
            return y1, (omega, y1[0])

        xs = (data.ts[:-1], data.torque[:-1], data.target[:-1], data.omega_stamp[1:])
        return jax.lax.scan(sample, y0, xs)[1]

    def _residuals(self, u, car, hardware, data):
        omega, v = self._simulate(u, car, hardware, data)
        r_omega = jnp.where(data.fresh[1:], (omega - data.omega_meas[1:]) / self.wheel_noise,
                            0.0)
        return jnp.concatenate([r_omega, (v - data.v_meas[1:]) / self.speed_noise])

    def initial_guess(self, car: QuarterCar, data: BrakingRecord, theta):
        """At the first parameter `theta`: the model's other values, the measured speeds at
        the window's start and the steady friction state at the measured slip."""
        v, omega = data.v_meas[0], data.omega_meas[0]
        logs = self.model.prior().at[0].set(jnp.log(theta))
        z_ss = steady_state(self.model.prior_with(theta), v, omega, car.radius)
        z_scale = self.model.state_scale()
        return jnp.concatenate([logs, jnp.stack([z_ss / z_scale, omega, v])])

    def _residuals_and_jacobian(self, u, car, hardware, data):
        """The residuals and their forward-difference Jacobian, one vmapped simulation."""
        # 1e-7 in float64; in float32 that is below the rounding, so its square root of eps
        step = max(_DIFFERENCE_STEP, float(np.sqrt(np.finfo(u.dtype).eps)))
        h = step * jnp.maximum(jnp.abs(u), 1.0)
        points = jnp.concatenate([u[None], u[None] + jnp.diag(h)])
        rs = jax.vmap(lambda v: self._residuals(v, car, hardware, data))(points)
        return rs[0], ((rs[1:] - rs[0][None]) / h[:, None]).T

    def fit_window(self, car: QuarterCar, hardware: BrakeHardware, data: BrakingRecord | dict):
        """``(theta, theta_se, cost, result)`` of one window (`data`: the record of the
        window's N + 1 samples, or a dict of its signals)."""
        if not isinstance(data, BrakingRecord):
            data = BrakingRecord.from_signals(data)
        return self._fit(car, hardware, data)[:4]

    def _fit(self, car, hardware, data: BrakingRecord):

        @jax.custom_jvp
        def residuals(u):
            return self._residuals(u, car, hardware, data)

        @residuals.defjvp
        def _(primals, tangents):
            r, J = self._residuals_and_jacobian(primals[0], car, hardware, data)
            return r, J @ tangents[0]

        def solve(theta):
            u0 = self.initial_guess(car, data, theta)
            sol = optx.least_squares(lambda u, _: residuals(u),
                                     optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8), u0,
                                     max_steps=self.max_steps, throw=False)
            r = residuals(sol.value)
            return sol.value, jnp.sum(r * r), RESULTS.promote(sol.result)

        thetas = jnp.geomspace(self.theta_min, self.theta_max, self.starts)
        values, costs, results = jax.vmap(solve)(thetas)
        best = jnp.argmin(jnp.where(jnp.isfinite(costs), costs, jnp.inf))
        u = values[best]
        lm_result = jax.tree.map(lambda x: x[best], results)
        r, J = self._residuals_and_jacobian(u, car, hardware, data)
        # the observations: the speed rows and the wheel rows of fresh samples (the rest of
        # the wheel rows are zeros that carry no data)
        n_obs = data.v_meas.shape[0] - 1 + jnp.sum(data.fresh[1:])
        s2 = jnp.sum(r * r) / jnp.maximum(n_obs - u.shape[0], 1)
        # information on log(theta) left after the other unknowns: the Schur complement
        J_t, J_n = J[:, 0], J[:, 1:]
        projected = J_t - J_n @ (jnp.linalg.pinv(J_n) @ J_t)
        info = jnp.sum(projected * projected)
        log_se_prior = 1.0 / jnp.sqrt(jnp.where(info > 0, info, 1e-300))
        theta = jnp.exp(u[0])
        theta_se = theta * jnp.sqrt(s2) * log_se_prior
        identifiable = jnp.isfinite(log_se_prior) & (log_se_prior <= self.max_log_se)
        # MINPACK's gtol test: Levenberg-Marquardt's own test stalls on noise-free data
        stationary = (max_gradient_cosine(J, r) <= _GTOL) | (jnp.mean(r * r) <= 1e-12)
        solved = RESULTS.where(stationary, RESULTS.successful, lm_result)
        # identifiability judges a solve that succeeded or ran out of steps; another failure
        # (non-finite values, a linear solve) stands: its point says nothing
        judged = is_successful(solved) | (solved == RESULTS.nonlinear_max_steps_reached)
        result = RESULTS.where(identifiable | ~judged, solved, RESULTS.not_identifiable)
        k = len(self.model.names)
        return theta, theta_se, jnp.sum(r * r) / n_obs, result, jnp.exp(u[:k]), u

    def estimate(self, car: QuarterCar, hardware: BrakeHardware,
                 record: BrakingRecord | dict, ends) -> MHEResult:
        """Fit the windows ending at the sample indices `ends` (each at least `window`) of
        a `BrakingRecord` (or a saved run's `signals`), all in one vmapped, jitted call
        (compiled once per window, run length and number of windows)."""
        if not isinstance(record, BrakingRecord):
            record = BrakingRecord.from_signals(record)
        return _estimate(self, car, hardware, record, jnp.asarray(ends))


_WINDOW_SIGNALS = ("ts", "torque", "target", "omega_stamp", "omega_meas", "v_meas", "fresh")


@eqx.filter_jit
def _estimate(mhe: MovingHorizonEstimator, car, hardware, record: BrakingRecord,
              ends) -> MHEResult:
    def one(end):
        return mhe._fit(car, hardware, record.window(end, mhe.window))[:5]

    theta, se, cost, result, values = jax.vmap(one)(ends)
    return MHEResult(record.ts[ends], theta, se, cost, result, values)
