r"""A shape-free estimator of the force-slip curve's peak: measured friction against measured
slip, fitted by recursive least squares on a moving window.

**Measured friction.** The wheel's dynamics $J\dot\omega = -rF_x - T_b\tanh(\omega/
\omega_\epsilon)$ (`QuarterCar`) give the friction force from the known brake torque and the
measured wheel acceleration: between two fresh tone-wheel measurements $\omega_{k-1}$,
$\omega_k$ (standing for their time stamps),
$$\mu_k = -\frac{J(\omega_k - \omega_{k-1})/\Delta t + \bar T_b\tanh(\omega_k/\omega_\epsilon)}
  {rF_n},$$
$\bar T_b$ the mean brake torque over the sample (the actuator model's, Simpson's rule). The
vehicle speed is filtered with the measured friction, $\hat v^-_k = \hat v_{k-1} +
\mu_kF_nT/m$ ($m\dot v = F_x$; at a sample with no new tone-wheel edge, such as a locked
wheel's, $\mu_k$ is the last one measured), $\hat v_k = \hat v_k^- + L_v(v_k - \hat v_k^-)$,
and the braking slip is $\lambda_k = 1 - r\omega_k/\hat v_k$. Nothing here assumes a tire model.

**The curve.** The measured points are kept as a curve over the slip axis: `bins` bins
(finer near zero slip, edges $(i/B)^2$), each holding the running means of the measured
$|\mu|$ and $\lambda$ that fell in it and their weight, every weight multiplied by the
forgetting $\gamma$ at each informative sample (a moving window of about $1/(1-\gamma)$
samples that keeps the slips the wheel has left: a sweep through the peak is remembered
while the wheel works elsewhere). The binned curve is fitted by Burckhardt's family
$$|\mu| = c_1(1 - e^{-c_2\lambda}) - c_3\lambda,$$
a flexible three-parameter curve (a rise to a peak or a plateau and a linear fall; it
describes dry, wet, snowy and icy roads alike, `vehsim.tire.burckhardt`), by weighted least
squares, linear in $(c_1, c_3)$ for each $c_2$ of a logarithmic grid (a ridge `ridge`
towards the prior, $c_1, c_3\ge0$), keeping the $c_2$ of the smallest weighted residual.
A change of road shows as measured friction far off the fitted curve: a CUSUM detector on
$\nu = e^2/R$, $e$ the measured minus the fitted $|\mu|$ at the measured slip,
$g \leftarrow \max(0, g + \nu - \delta)$, forgets the old curve (every weight times
`change_discount`) when $g > h$ and restarts. Its peak is
$$\lambda^* = \frac{\ln(c_1c_2/c_3)}{c_2},\qquad \mu^* = c_1(1 - e^{-c_2\lambda^*}) -
c_3\lambda^*$$
(a curve still rising at $\lambda = 1$: $\lambda^* = 1$), and its slope at the measured slip
$d|\mu|/d\lambda = c_1c_2e^{-c_2\lambda} - c_3$ (> 0 below the peak).

**Assumes** the curve is a steady-state one (the tire's transient lags the slip by its
relaxation, $L/|\omega r|$, a few milliseconds at speed) and that the family fits it near
the data; the peak is extrapolated from the data, so it is only measured where the slip has
been near it (an ABS cycling through the peak; a peak-seeking controller); before that it is
the prior's. **Blind** (the estimate holds) on a locked wheel (no tone-wheel edges: no
measured acceleration), below `min_slip` (all roads share the initial slope: the friction
level is not in the data) and below `min_speed`; at a constant slip the data fill one bin
and hold no slope: the ridge keeps the fit near the prior's shape through that point.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ..._checks import check_nonnegative, check_positive, check_range, is_concrete
from ..._fields import array_field
from ..._math import one_minus_exp_over, safe_abs
from ...tire.lugre import AbstractLongitudinalTire, relative_velocity
from ...vehicle.quarter_car import QuarterCar
from ..plant.hardware import BrakeHardware, brake_torque
from .base import AbstractFrictionEstimator


GRAVITY = 9.81


def burckhardt_peak(c1, c2, c3):
    r"""$(\lambda^*, \mu^*)$ of $c_1(1 - e^{-c_2\lambda}) - c_3\lambda$ on $[0, 1]$ (module
    docstring; $\lambda^* = 1$ where the curve still rises there, 0 where it never rises)."""
    rises = c1 * c2 > c3
    interior = rises & (c3 > 0) & (c1 * c2 * jnp.exp(-c2) < c3)
    ratio = jnp.where(interior, c1 * c2 / jnp.where(interior, c3, 1.0), jnp.e)
    lam = jnp.where(interior, jnp.log(ratio) / c2, jnp.where(rises, 1.0, 0.0))
    return lam, c1 * (1.0 - jnp.exp(-c2 * lam)) - c3 * lam


def fit_burckhardt(shapes, prior, ridge, weight, mu, slip):
    r"""``(coefficients, error)``: for each $c_2$ of `shapes` (G,), the $(c_1, c_3) \ge 0$
    of Burckhardt's curve $c_1(1 - e^{-c_2\lambda}) - c_3\lambda$ minimising
    $\sum_j w_j(\mu_j - \mu_B(\lambda_j))^2 + \rho\|(c_1, c_3) - (c_1, c_3)_0\|^2$ over the
    points (`slip` $\lambda_j$, `mu` $\mu_j$, `weight` $w_j$), $\rho$ = `ridge` and $(c_1,
    c_3)_0$ those of `prior` $(c_1, c_2, c_3)$ (linear least squares per $c_2$, clamped at
    0), shape (G, 2), and that sum at the clamped coefficients, shape (G,)."""
    p = jnp.stack([prior[0], prior[2]])

    def one(c2):
        phi = jnp.stack([1.0 - jnp.exp(-c2 * slip), -slip], axis=-1)  # (B, 2)
        A = phi.T @ (weight[:, None] * phi) + ridge * jnp.eye(2)
        b = phi.T @ (weight * mu) + ridge * p
        c = jnp.maximum(jnp.linalg.solve(A, b), 0.0)
        e = mu - phi @ c
        return c, jnp.sum(weight * e * e) + ridge * jnp.sum((c - p) ** 2)

    return jax.vmap(one)(shapes)


def check_burckhardt(owner: str, name: str, coefficients) -> None:
    r"""Refuse Burckhardt coefficients that are not $(c_1, c_2, c_3)$ (a last axis of 3) with
    $c_2 > 0$ and $c_1, c_3 \ge 0$ (the fit clamps $c_1$ and $c_3$ at 0)."""
    if jnp.shape(coefficients)[-1:] != (3,):
        raise ValueError(f"{owner}.{name} must be Burckhardt's (c1, c2, c3), got shape "
                         f"{jnp.shape(coefficients)}")
    c = jnp.moveaxis(jnp.asarray(coefficients), -1, 0) if is_concrete(coefficients) else None
    if c is not None:
        check_nonnegative(owner, f"{name} c1", c[0])
        check_positive(owner, f"{name} c2", c[1])
        check_nonnegative(owner, f"{name} c3", c[2])


class BurckhardtBelief(AbstractLongitudinalTire):
    r"""The tire the peak estimator believes in: Burckhardt's curve $(c_1, c_2, c_3)$ as the
    steady state of a transient slip with relaxation length `relaxation_length` (0.25 m),
    $\dot u = v_r - |v|u/\sigma$, $\mu = \operatorname{sign}(u)\,\mu_B(|u|/\sigma)$ (as
    `RelaxedMagicFormula`). `params` holds $(c_1, c_2, c_3)$."""

    params: Float[Array, " 3"]
    relaxation_length: Float[Array, ""] = array_field(default=0.25)

    def __check_init__(self):
        check_burckhardt("BurckhardtBelief", "params", self.params)
        check_positive("BurckhardtBelief", "relaxation_length", self.relaxation_length)

    def init_state(self):
        return jnp.zeros(())

    def dynamics(self, state, v, omega, r):
        return relative_velocity(v, omega, r) - safe_abs(v) * state / self.relaxation_length

    def _curve(self, s):
        c1, c2, c3 = self.params
        # sgn(s) (c1 (1 - exp(-c2 |s|)) - c3 |s|), |s| capped at 1, written as
        # c1 c2 s phi(c2 |s|) - c3 s: the same values, and the slope c1 c2 - c3 at s = 0
        # (the product of sgn and |.| has derivative 0 there in both modes)
        sc = jnp.clip(s, -1.0, 1.0)
        return c1 * c2 * sc * one_minus_exp_over(c2 * safe_abs(sc)) - c3 * sc

    def mu(self, state, v, omega, r):
        return self._curve(state / self.relaxation_length)

    def peak(self):
        """``(s*, mu*)``: the braking slip ($< 0$) and friction of the curve's peak, in
        closed form (`burckhardt_peak`; `peak_braking` of this tire finds the same)."""
        lam, mu = burckhardt_peak(*self.params)
        return -lam, mu

    def slope(self, s):
        r"""$d|\mu|/d\lambda$ at braking slip `s` ($\lambda = -s$; > 0 below the peak)."""
        c1, c2, c3 = self.params
        return c1 * c2 * jnp.exp(-c2 * jnp.abs(s)) - c3

    def steady_state_mu(self, v, omega, r):
        """$\\mu_B$ at the slip $v_r/|v|$ (with the sign of $v_r$)."""
        return self._curve(relative_velocity(v, omega, r) / jnp.maximum(safe_abs(v), 1e-9))


class PeakEstimatorState(eqx.Module):
    r"""The filtered speed `v` [m/s]; the last fresh wheel speed `omega` [rad/s], its
    `stamp` [s] and whether one has been seen (`primed`); the measured friction `mu` and
    braking slip `slip` of the last update; the change detector's statistic
    `change_statistic` $g$; the binned curve: per bin the `weight` and the
    mean measured `bin_mu` $|\mu|$ and `bin_slip` $\lambda$; per $c_2$ of the grid the
    fitted `coefficients` $(c_1, c_3)$ and the weighted squared residual `error`; and the
    estimate: the `best` member, the `peak_slip` $s^* < 0$, the `peak_mu` $\mu^* > 0$ and
    the `slope` $d|\mu|/d\lambda$ at the measured slip."""

    v: Float[Array, ""]
    omega: Float[Array, ""]
    stamp: Float[Array, ""]
    primed: Array
    mu: Float[Array, ""]
    slip: Float[Array, ""]
    change_statistic: Float[Array, ""]
    weight: Float[Array, " B"]
    bin_mu: Float[Array, " B"]
    bin_slip: Float[Array, " B"]
    coefficients: Float[Array, "G 2"]
    error: Float[Array, " G"]
    best: Int[Array, ""]
    peak_slip: Float[Array, ""]
    peak_mu: Float[Array, ""]
    slope: Float[Array, ""]


def _default_grid():
    return np.geomspace(4.0, 320.0, 12)


class PeakEstimator(AbstractFrictionEstimator):
    r"""The estimator of the module docstring.

    **Fields:** `prior` $(c_1, c_2, c_3)$ (dry asphalt's, (1.2801, 23.99, 0.52): every member
    starts from $(c_1, c_3)$ of it, the prior's nearest $c_2$ as the best), `shapes` the grid
    of $c_2$ (12 values from 4 to 320, static length), `bins` (static, 32), `forgetting`
    $\gamma\in(0, 1]$ (0.99), `ridge` (the weight of the prior's $(c_1, c_3)$, in samples,
    0.1), `noise_variance` $R$ of the measured friction (4e-4), the change detector's
    `change_drift` $\delta$ (5), `change_threshold` $h$ (200; `inf` turns it off) and
    `change_discount` (0.01), `speed_injection` $L_v\in[0, 1]$ (0.05), `min_slip` (0.01),
    `min_speed` [m/s] (3), `relaxation_length` of the belief [m] (0.25).
    """

    prior: Float[Array, " 3"] = array_field(default=(1.2801, 23.99, 0.52))
    shapes: Float[Array, " G"] = array_field(default_factory=_default_grid)
    bins: int = eqx.field(static=True, default=32)
    forgetting: Float[Array, ""] = array_field(default=0.99)
    ridge: Float[Array, ""] = array_field(default=0.1)
    noise_variance: Float[Array, ""] = array_field(default=4e-4)
    change_drift: Float[Array, ""] = array_field(default=5.0)
    change_threshold: Float[Array, ""] = array_field(default=200.0)
    change_discount: Float[Array, ""] = array_field(default=0.01)
    speed_injection: Float[Array, ""] = array_field(default=0.05)
    min_slip: Float[Array, ""] = array_field(default=0.01)
    min_speed: Float[Array, ""] = array_field(default=3.0)
    relaxation_length: Float[Array, ""] = array_field(default=0.25)

    def __check_init__(self):
        owner = "PeakEstimator"
        check_burckhardt(owner, "prior", self.prior)
        check_range(owner, "forgetting", self.forgetting, lower=0.0, upper=1.0,
                    lower_open=True)
        check_range(owner, "speed_injection", self.speed_injection, lower=0.0, upper=1.0)
        if self.bins < 2:
            raise ValueError(f"PeakEstimator.bins must be at least 2, got {self.bins}")
        check_range(owner, "change_discount", self.change_discount, lower=0.0, upper=1.0)
        for name in ("shapes", "ridge", "noise_variance", "change_drift",
                     "min_slip", "min_speed", "relaxation_length"):
            check_positive(owner, name, getattr(self, name))
        check_range(owner, "change_threshold", self.change_threshold, lower=0.0, lower_open=True,
                    allow_inf=True)  # inf: no change detection

    def _estimate(self, coefficients, error, slip):
        best = jnp.argmin(error)
        c1, c3 = coefficients[best, 0], coefficients[best, 1]
        c2 = self.shapes[best]
        lam_star, mu_star = burckhardt_peak(c1, c2, c3)
        slope = c1 * c2 * jnp.exp(-c2 * slip) - c3
        return best, -lam_star, mu_star, slope

    def init(self, omega0, v0) -> PeakEstimatorState:
        """The measured speeds; an empty curve; every member at the prior, the prior's
        nearest $c_2$ the best."""
        G, B = self.shapes.shape[0], self.bins
        c = jnp.broadcast_to(jnp.stack([self.prior[0], self.prior[2]]), (G, 2))
        error = jnp.abs(jnp.log(self.shapes / self.prior[1])) * 1e-9
        z, zb = jnp.zeros(()), jnp.zeros(B)
        best, s_star, mu_star, slope = self._estimate(c, error, z)
        return PeakEstimatorState(jnp.asarray(v0, dtype=float), jnp.asarray(omega0, dtype=float),
                                  z, jnp.asarray(False), z, z, z, zb, zb, zb, c, error, best,
                                  s_star, mu_star, slope)

    def _fit(self, weight, bin_mu, bin_slip):
        """Weighted least squares of every member on the binned curve, with the ridge."""
        return fit_burckhardt(self.shapes, self.prior, self.ridge, weight, bin_mu, bin_slip)

    def update(self, state: PeakEstimatorState, car: QuarterCar, hardware: BrakeHardware,
               substeps: int, v, omega, stamp, fresh, torque0, target, t0):
        """One sample (`AbstractFrictionEstimator.update`; `substeps` unused)."""
        T = hardware.sample_time
        torque = (brake_torque(hardware, torque0, target, 0.0)
                  + 4.0 * brake_torque(hardware, torque0, target, 0.5 * T)
                  + brake_torque(hardware, torque0, target, T)) / 6.0
        dt = stamp - state.stamp
        valid_rate = fresh & state.primed & (dt > 0)
        accel = jnp.where(valid_rate, (omega - state.omega) / jnp.where(valid_rate, dt, 1.0), 0.0)
        Fn, r = car.Fn_static, car.radius
        mu = -(car.inertia * accel + torque * jnp.tanh(omega / car.omega_eps)) / (r * Fn)
        # the car decelerates every sample: between edges with the last friction measured
        v_pred = state.v + jnp.where(valid_rate, mu, state.mu) * Fn * T / car.mass
        v_hat = v_pred + self.speed_injection * (v - v_pred)
        slip = jnp.clip(1.0 - r * omega / jnp.maximum(v_hat, 1e-3), 0.0, 1.0)
        informative = valid_rate & (slip > self.min_slip) & (v_hat > self.min_speed)

        c_old = state.coefficients[state.best]
        fitted_mu = c_old[0] * (1.0 - jnp.exp(-self.shapes[state.best] * slip)) - c_old[1] * slip
        e = -mu - fitted_mu
        g = jnp.maximum(state.change_statistic + jnp.where(
            informative, e * e / self.noise_variance - self.change_drift, 0.0), 0.0)
        changed = g > self.change_threshold
        g = jnp.where(changed, 0.0, g)
        old = jnp.where(changed, self.change_discount, 1.0) * state.weight

        B = self.bins
        i = jnp.clip(jnp.floor(jnp.sqrt(slip) * B).astype(int), 0, B - 1)
        here = (jnp.arange(B) == i) & informative
        weight = jnp.where(informative, self.forgetting * old, old)
        weight = weight + here
        w = jnp.where(here, weight, 1.0)
        bin_mu = jnp.where(here, state.bin_mu + (-mu - state.bin_mu) / w, state.bin_mu)
        bin_slip = jnp.where(here, state.bin_slip + (slip - state.bin_slip) / w, state.bin_slip)

        fitted, error = self._fit(weight, bin_mu, bin_slip)
        coefficients = jnp.where(informative, fitted, state.coefficients)
        error = jnp.where(informative, error, state.error)
        best, s_star, mu_star, slope = self._estimate(coefficients, error, slip)
        return PeakEstimatorState(
            v_hat, jnp.where(fresh, omega, state.omega), jnp.where(fresh, stamp, state.stamp),
            state.primed | fresh, jnp.where(valid_rate, mu, state.mu), slip, g, weight, bin_mu,
            bin_slip, coefficients, error, best, s_star, mu_star, slope)

    def belief(self, state: PeakEstimatorState) -> BurckhardtBelief:
        """The best member's curve as a tire (`BurckhardtBelief`): `peak_braking` of it is
        the state's peak."""
        c = state.coefficients[state.best]
        return BurckhardtBelief(jnp.stack([c[0], self.shapes[state.best], c[1]]),
                                self.relaxation_length)

    def signals(self, state: PeakEstimatorState) -> dict:
        """The filtered speed `v_hat`, the measured friction `mu_meas` and slip
        `slip_meas`, and the estimate: `peak_slip`, `peak_mu`, `slope`."""
        return dict(v_hat=state.v, mu_meas=state.mu, slip_meas=-state.slip,
                    peak_slip=state.peak_slip, peak_mu=state.peak_mu, slope=state.slope)

