r"""A moving-horizon estimator of the road condition: Levenberg-Marquardt through the simulator.

Over a window of the last $N$ samples of a braking (measured wheel speeds at their time
stamps, measured vehicle speeds, and the brake torque the actuator model gives for the
commands), fit
$$u = (\log\theta,\ [\log\mu_s,\ \log\mu_c],\ \bar z_0,\ \omega_0,\ v_0)$$
so that the quarter car with the lumped tire (`UniformLumpedLuGre`), started from
$(v_0, \omega_0, \bar z_0)$ at the window's start and driven by that torque, reproduces the
measurements: residuals $(\omega(t_j) - \omega_j)/\sigma_\omega$ where the wheel speed is a
measurement (`fresh`) and $(v(t_j) - v_j)/\sigma_v$. The simulation is the plant's own
integrator (`integrate_sample`), so that on noise-free data of the lumped model the fit
recovers $\theta$ to the solver's tolerance. Past the peak the wheel's dynamics are unstable
and the fit has local minima, so it starts from `starts` values of $\theta$ spaced
logarithmically over $[\theta_{min}, \theta_{max}]$ and keeps the best; optimistix's
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
J)^{-1}]_{\theta\theta}}$ with $s^2$ the residuals' mean square; $\operatorname{se}(\theta)
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
import optimistix as optx
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float

from ..._checks import check_positive
from ..._fields import array_field
from ..._optimality import max_gradient_cosine
from ..._results import RESULTS, is_successful
from ...tire.lugre import LuGreParams
from ...tire.uniform_lumped import UniformLumpedLuGre, decay
from ...vehicle.quarter_car import QuarterCar, QuarterCarState
from ..plant.hardware import BrakeHardware
from ..plant.integrate import SUBSTEPS, hermite, integrate_sample
from .observer import _copy_rates


FREE_NAMES = ("theta", "mu_s", "mu_c")
_DIFFERENCE_STEP = 1e-7
_GTOL = 1e-6


class MHEResult(eqx.Module):
    """Per window: the end time `ts` [s], the estimate `theta`, its standard error
    `theta_se`, the final normalised cost `cost` and `result` (a `vehsim.RESULTS` item)."""

    ts: Float[Array, " W"]
    theta: Float[Array, " W"]
    theta_se: Float[Array, " W"]
    cost: Float[Array, " W"]
    result: RESULTS


class MovingHorizonEstimator(eqx.Module):
    r"""The estimator of the module docstring.

    **Fields:** `model` (`LuGreParams` of the tire; `mu_s`, `mu_c` are the initial
    guesses), `theta_min`, `theta_max` (the range of the starts), `starts` (static, 5),
    `window` (samples, static, 20), `free` (a subset of ``("theta", "mu_s", "mu_c")``
    containing ``"theta"``, static), `wheel_noise` $\sigma_\omega$ [rad/s] (0.1),
    `speed_noise` $\sigma_v$ [m/s] (0.05), `max_log_se` (0.1), `max_steps` (static, 40).
    """

    model: LuGreParams
    theta_min: Float[Array, ""] = array_field(default=0.3)
    theta_max: Float[Array, ""] = array_field(default=40.0)
    starts: int = eqx.field(static=True, default=5)
    window: int = eqx.field(static=True, default=20)
    free: tuple[str, ...] = eqx.field(static=True, default=("theta",))
    wheel_noise: Float[Array, ""] = array_field(default=0.1)
    speed_noise: Float[Array, ""] = array_field(default=0.05)
    max_log_se: Float[Array, ""] = array_field(default=0.1)
    max_steps: int = eqx.field(static=True, default=40)

    def __check_init__(self):
        if "theta" not in self.free or not set(self.free) <= set(FREE_NAMES):
            raise ValueError(f"MovingHorizonEstimator.free must contain 'theta' and only "
                             f"names of {FREE_NAMES}, got {self.free}")
        if self.window < 2:
            raise ValueError(f"MovingHorizonEstimator.window must be at least 2 samples, got "
                             f"{self.window}")
        for name in ("wheel_noise", "speed_noise", "max_log_se", "theta_min", "theta_max"):
            check_positive("MovingHorizonEstimator", name, getattr(self, name))

    def _params(self, u):
        values = {n: jnp.exp(u[i]) for i, n in enumerate(self.free)}
        return eqx.tree_at(lambda p: [getattr(p, n) for n in values], self.model,
                           list(values.values()))

    def _simulate(self, u, car: QuarterCar, hardware: BrakeHardware, data):
        """Wheel speeds at the stamps and vehicle speeds at the samples 1..N of a window."""
        k = len(self.free)
        z_scale = self.model.mu_s / (self.model.theta * self.model.sigma0)
        car = eqx.tree_at(lambda c: c.tire, car, UniformLumpedLuGre(self._params(u)))
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

        xs = (data["ts"][:-1], data["torque"][:-1], data["target"][:-1],
              data["omega_stamp"][1:])
        return jax.lax.scan(sample, y0, xs)[1]

    def _residuals(self, u, car, hardware, data):
        omega, v = self._simulate(u, car, hardware, data)
        r_omega = jnp.where(data["fresh"][1:], (omega - data["omega_meas"][1:])
                            / self.wheel_noise, 0.0)
        return jnp.concatenate([r_omega, (v - data["v_meas"][1:]) / self.speed_noise])

    def initial_guess(self, car: QuarterCar, data, theta):
        """At road condition `theta`: the model's other values, the measured speeds at the
        window's start and the steady friction state at the measured slip."""
        v, omega = data["v_meas"][0], data["omega_meas"][0]
        p = eqx.tree_at(lambda q: q.theta, self.model, theta)
        z_ss = (car.radius * omega - v) / decay(p, v, omega, car.radius)
        z_scale = self.model.mu_s / (self.model.theta * self.model.sigma0)
        logs = [jnp.log(getattr(p, n)) for n in self.free]
        return jnp.stack(logs + [z_ss / z_scale, omega, v])

    def _residuals_and_jacobian(self, u, car, hardware, data):
        """The residuals and their forward-difference Jacobian, one vmapped simulation."""
        h = _DIFFERENCE_STEP * jnp.maximum(jnp.abs(u), 1.0)
        points = jnp.concatenate([u[None], u[None] + jnp.diag(h)])
        rs = jax.vmap(lambda v: self._residuals(v, car, hardware, data))(points)
        return rs[0], ((rs[1:] - rs[0][None]) / h[:, None]).T

    def fit_window(self, car: QuarterCar, hardware: BrakeHardware, data):
        """``(theta, theta_se, cost, result)`` of one window (`data`: the run's signals
        over the window's N + 1 samples)."""

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
        s2 = jnp.sum(r * r) / jnp.maximum(r.shape[0] - u.shape[0], 1)
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
        return theta, theta_se, jnp.sum(r * r) / r.shape[0], result

    def estimate(self, car: QuarterCar, hardware: BrakeHardware, signals: dict, ends) -> MHEResult:
        """Fit the windows ending at the sample indices `ends` (each at least `window`) of
        a saved run's `signals`, all in one vmapped, jitted call (compiled once per window,
        run length and number of windows)."""
        data = {n: jnp.asarray(signals[n]) for n in _WINDOW_SIGNALS}
        return _estimate(self, car, hardware, data, jnp.asarray(ends))


_WINDOW_SIGNALS = ("ts", "torque", "target", "omega_stamp", "omega_meas", "v_meas", "fresh")


@eqx.filter_jit
def _estimate(mhe: MovingHorizonEstimator, car, hardware, signals, ends) -> MHEResult:
    def one(end):
        data = {n: jax.lax.dynamic_slice_in_dim(signals[n], end - mhe.window, mhe.window + 1)
                for n in _WINDOW_SIGNALS}
        return mhe.fit_window(car, hardware, data)

    theta, se, cost, result = jax.vmap(one)(ends)
    return MHEResult(signals["ts"][ends], theta, se, cost, result)
