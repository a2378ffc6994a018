r"""A peak-seeking ABS: extremum seeking on the friction the wheel measures.

The wheel's own equation, $J\dot\omega = -rF - T_b\tanh(\omega/\omega_\epsilon)$ (eq. 22
with the brake's smoothing), gives the friction over the last sample from what the
controller knows: the mean brake torque $\bar T_b$ and the measured change of wheel speed,
$$\hat\mu_k = \frac{\bar T_b\tanh(\hat\omega_k/\omega_\epsilon) + J(\hat\omega_k -
\hat\omega_{k-1})/T}{rF_n},$$
paired with the braking slip at the middle of the sample, $\bar\lambda_k = -(\hat s_k +
\hat s_{k-1})/2$ (an error of $\hat\omega_k$ then enters the friction and the slip with
uncorrelated weights). The slope $d\mu/d\lambda$ at the target $\lambda^*$ is the
least-squares slope of $\hat\mu$ on $\bar\lambda$, each pair weighted by
$w_k = e^{-(\bar\lambda_k - \lambda^*)^2/2h^2}$ (kernel width $h$: only pairs near the
target count, not the onset's linear range nor an excursion past the peak) and forgotten
over `window` seconds,
$$b = \frac{C_{\lambda\mu}}{C_{\lambda\lambda} + \epsilon},\qquad
R^2 = \frac{C_{\lambda\mu}^2}{(C_{\lambda\lambda} + \epsilon)(C_{\mu\mu} + \epsilon_\mu)}$$
($C$ the weighted covariances, updated recursively; $R^2\in[0, 1]$ the fit's coefficient
of determination: near 1 where the pairs lie on a sloped line, near 0 where noise or a
flat curve decides them).

The braking slip target is a multiple of the peak of the belief's steady-state curve at
the speed of the onset $v_0$ (`peak_braking` of the belief: the estimate-based
controller's target at the onset),
$$\lambda^* = \kappa\,\lambda_b,\qquad \lambda_b = \lambda^*_{belief}(v_0),$$
so that a change of road, which moves the estimator's belief within a few samples, moves
the target with it (from the new road's peak, not from the old one). The multiple starts,
at the onset and whenever $\lambda_b$ has moved by more than a factor `change_ratio` from
where it last started (a new road: the multiple learnt on the old one is dropped),
below the belief's peak, $\kappa_0$ = `start_scale` (where the curve rises everywhere
below the peak, a loop held there is stable whatever the tire; past a sharp peak, the
actuator's delay and lag make the slip loop cycle), but not below the floor $\lambda_f$,
or at 1 where the belief's curve rises to the locked wheel, and climbs the measured curve,
$$\dot\lambda^* = \lambda_b\dot\kappa = \rho_\pm\,w_k R^2\tanh(b/b_0),\qquad
\lambda^*\in[\lambda_f, 1],\qquad \lambda_f = \begin{cases}\lambda^*_{belief}(v) &
\lambda_b < \lambda_s\\ \max(\lambda_{min}, \lambda_s) & \text{otherwise,}\end{cases}$$
$\lambda_s$ = `start_slip`: on a road whose peak lies at small slip, snow and ice, the
measured slopes are small against the measurement's errors and read downhill near the
peak, so the belief's peak at the present speed $v$ (which moves to larger slip as the
car slows) bounds the target from below; elsewhere the slip $\lambda_s$ does.
$\rho_+$ = `rate` uphill ($b > 0$), $\rho_-$ = `descent_rate` downhill, so it stops where
the measured slope vanishes, at the true tire's peak whatever its shape (a curve rising
to the locked wheel drives it to 1: full torque), and moves only as fast as the fit
explains the data. It moves only once the wheel has first reached it and only while the
wheel is near it ($w_k$). A sinusoidal dither of amplitude `dither` and frequency
`dither_frequency` on the target keeps the regression excited. The wheel is held at
$s^* = -(\lambda^* + \text{dither})$ by the slip-tracking PI law (`track_slip`), its
feedforward from the belief's curve at $s^*$; a target at the locked wheel
($\lambda^* = 1$) commands the full torque. The belief enters in the start, the
reference $\lambda_b$, the floor and the feedforward.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from ..._checks import check_nonnegative, check_positive, check_range
from ..._fields import array_field
from ..road.peak import braking_curve, peak_braking
from .braking import AbstractBrakeController, track_slip


class PeakSeekingState(eqx.Module):
    r"""The PI `integral` [N m], the braking slip `target` $\lambda^*$, its multiple `scale`
    $\kappa$ of the belief's peak $\lambda_b$ at the onset's `speed` $v_0$ [m/s], the
    `reference` $\lambda_b$ at the last start (onset or new road), the braking slip at
    the last sample `slip`, the kernel weights' forgotten sum `weight`, the weighted means
    (`mean_slip`, `mean_mu`), variances (`var_slip`, `var_mu`) and covariance `cov` of
    $(\bar\lambda, \hat\mu)$, `engaged` (1 once the wheel reached the target) and the
    `time` since the onset [s]."""

    integral: Float[Array, ""]
    target: Float[Array, ""]
    scale: Float[Array, ""]
    speed: Float[Array, ""]
    reference: Float[Array, ""]
    slip: Float[Array, ""]
    weight: Float[Array, ""]
    mean_slip: Float[Array, ""]
    mean_mu: Float[Array, ""]
    var_slip: Float[Array, ""]
    var_mu: Float[Array, ""]
    cov: Float[Array, ""]
    engaged: Float[Array, ""]
    time: Float[Array, ""]


class PeakSeekingABS(AbstractBrakeController):
    r"""Extremum seeking on the measured friction (module docstring).

    **Fields:** `rate` $\rho_+$ [1/s] (0.6), `descent_rate` $\rho_-$ [1/s] (0.3),
    `start_scale` $\kappa_0$ (0.7), `start_slip` $\lambda_s$ (0.1), `change_ratio` (1.5),
    `slope_scale` $b_0$ (0.5), `window` [s] (0.1), `kernel_width` $h$ (0.03),
    `variance_floor` $\epsilon$ (1e-6), `mu_variance_floor`
    $\epsilon_\mu$ (1e-8), `min_slip` $\lambda_{min}$ (0.02), `dither` (0.005),
    `dither_frequency` [Hz] (5), gains `kp` (60) and `ki` (600) as `SlipTracking`.
    """

    rate: Float[Array, ""] = array_field(default=0.6)
    slope_scale: Float[Array, ""] = array_field(default=0.5)
    window: Float[Array, ""] = array_field(default=0.1)
    kernel_width: Float[Array, ""] = array_field(default=0.03)
    variance_floor: Float[Array, ""] = array_field(default=1e-6)
    min_slip: Float[Array, ""] = array_field(default=0.02)
    dither: Float[Array, ""] = array_field(default=0.005)
    dither_frequency: Float[Array, ""] = array_field(default=5.0)
    mu_variance_floor: Float[Array, ""] = array_field(default=1e-8)
    start_scale: Float[Array, ""] = array_field(default=0.7)
    start_slip: Float[Array, ""] = array_field(default=0.1)
    change_ratio: Float[Array, ""] = array_field(default=1.5)
    descent_rate: Float[Array, ""] = array_field(default=0.3)
    kp: Float[Array, ""] = array_field(default=60.0)
    ki: Float[Array, ""] = array_field(default=600.0)

    def __check_init__(self):
        owner = "PeakSeekingABS"
        for name in ("slope_scale", "window", "kernel_width", "variance_floor",
                     "mu_variance_floor", "start_scale"):
            check_positive(owner, name, getattr(self, name))
        check_range(owner, "change_ratio", self.change_ratio, lower=1.0, lower_open=True)
        for name in ("rate", "descent_rate", "dither", "dither_frequency", "kp", "ki"):
            check_nonnegative(owner, name, getattr(self, name))
        check_range(owner, "min_slip", self.min_slip, lower=0.0, upper=1.0)
        check_range(owner, "start_slip", self.start_slip, lower=0.0, upper=1.0)

    def init(self, max_torque):
        z = jnp.zeros(())
        return PeakSeekingState(z, z, z, z, z, z, z, z, z, z, z, z, z, z)

    def _slope(self, st: PeakSeekingState, lam, mu, center, dt):
        r"""The weighted moments after the pair $(\bar\lambda, \hat\mu)$, the slope $b$,
        the pair's kernel weight and the fit's $R^2$."""
        w = jnp.exp(-0.5 * jnp.square((lam - center) / self.kernel_width))
        a = -jnp.expm1(-dt / self.window)
        weight = (1.0 - a) * st.weight + a * w
        g = a * w / jnp.maximum(weight, 1e-12)
        d_lam, d_mu = lam - st.mean_slip, mu - st.mean_mu
        mean_slip, mean_mu = st.mean_slip + g * d_lam, st.mean_mu + g * d_mu
        var = (1.0 - g) * (st.var_slip + g * d_lam * d_lam)
        var_mu = (1.0 - g) * (st.var_mu + g * d_mu * d_mu)
        cov = (1.0 - g) * (st.cov + g * d_lam * d_mu)
        fit = jnp.square(cov) / ((var + self.variance_floor) * (var_mu + self.mu_variance_floor))
        return ((weight, mean_slip, mean_mu, var, var_mu, cov), cov / (var + self.variance_floor),
                w, fit)

    def command(self, state, m, belief, car, dt, max_torque):
        st: PeakSeekingState = state
        r = car.radius
        v = jnp.maximum(m.v, 0.5)
        lam = -m.slip
        brake = m.brake_torque * jnp.tanh(m.omega / car.omega_eps)
        mu = (brake + car.inertia * m.wheel_accel / r) / (r * car.Fn_static)
        first = st.time == 0.0
        speed = jnp.where(first, v, st.speed)
        lam_belief = jnp.clip(-peak_braking(belief, speed, r)[0], self.min_slip, 1.0)
        # a new road (or the onset): the belief's peak moved by more than `change_ratio`
        new_road = first | (jnp.abs(jnp.log(lam_belief / jnp.where(first, 1.0, st.reference)))
                            > jnp.log(self.change_ratio))
        reference = jnp.where(new_road, lam_belief, st.reference)
        # the target's floor: `start_slip`, or on a road whose peak lies below it the
        # belief's peak at the present speed
        lam_now = jnp.clip(-peak_braking(belief, v, r)[0], self.min_slip, 1.0)
        floor = jnp.where(lam_belief < self.start_slip, lam_now,
                          jnp.maximum(self.min_slip, self.start_slip))
        start = jnp.maximum(self.start_scale, floor / lam_belief)
        start = jnp.where(lam_belief >= 1.0 - 1e-3, 1.0, start)
        scale = jnp.where(new_road, start, st.scale)
        center = jnp.where(new_road, scale * lam_belief, st.target)
        moments, slope, near, fit = self._slope(st, 0.5 * (lam + st.slip), mu, center, dt)
        rate = jnp.where(slope > 0, self.rate, self.descent_rate)
        step = st.engaged * near * fit * rate * dt * jnp.tanh(slope / self.slope_scale)
        scale = jnp.clip(scale + step / lam_belief, floor / lam_belief, 1.0 / lam_belief)
        lam_target = scale * lam_belief
        engaged = jnp.maximum(st.engaged, jnp.where(lam >= lam_target, 1.0, 0.0))
        dither = self.dither * jnp.sin(2.0 * jnp.pi * self.dither_frequency * st.time)
        s = -jnp.clip(lam_target + dither, 1e-3, 1.0)
        integral, torque = track_slip(st.integral, m, s, -braking_curve(belief, s, v, r), car,
                                      dt, max_torque, self.kp, self.ki)
        torque = jnp.where(s <= -1.0, max_torque, torque)  # a target at the locked wheel
        new = PeakSeekingState(integral, lam_target, scale, speed, reference, lam, *moments, engaged, st.time + dt)
        return new, torque, jnp.zeros((), int)
