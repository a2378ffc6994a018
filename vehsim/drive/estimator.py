r"""Grip estimated on the move, per axle, from the forces the axles carry.

**Utilised friction.** Over a sample $[t_{k-1}, t_k]$ ($\Delta t$) the measurements give
each axle's force and load, with the nominal car (`HalfCarParams`) and no tire model:

- longitudinal, from the wheel equations 52-53, $I_i\dot\omega_i = T_i - rF_{ix}$:
  $F_{ix} = (\bar T_i - I_i(\omega_{i,k} - \omega_{i,k-1})/\Delta t)/r$, with $\bar T_i$
  the mean axle torque of the sample (a negative one, a brake, times
  $\tanh(\bar\omega_i/\omega_\epsilon)$ as in the plant) - exact for the sample mean;
- lateral, from eqs. 50-51 with the measured lateral acceleration and the yaw
  acceleration $\dot r = (r_k - r_{k-1})/\Delta t$ (two equations, two axles):
  $F^b_{Fy} = (m a_y\ell_R + J\dot r)/\ell$, $F_{Ry} = (m a_y\ell_F - J\dot r)/\ell$,
  $F^b_{Fy}$ the front force's body-$y$ part, $F^b_{Fy} = F_{Fx}\sin\delta + F_{Fy}
  \cos\delta$, giving $F_{Fy}$;
- loads from the suspension of eqs. 54-60 driven by the measured longitudinal
  acceleration: the body's heave and pitch $(z, \dot z, \theta, \dot\theta)$ integrated
  over the sample (classical Runge-Kutta, `load_substeps` steps) with
  $\Sigma f_x = ma_x$ in eq. 55 ($a_x$ linear between the samples), the loads of eqs.
  59-60 averaged over the sample; with `dynamic_loads=False`, the quasi-static load
  transfer $F_{Fz} = m(g\ell_R - a_xh)/\ell$, $F_{Rz} = m(g\ell_F + a_xh)/\ell$ (the reduced
  model's), which runs ahead of the real one by the pitch dynamics (15 % of the front load
  at the onset of a braking pulse);

so $\mu_i = \sqrt{F_{ix}^2 + F_{iy}^2}/F_{iz}$, with $a_x$, $a_y$, speeds and yaw rates
averaged over the sample's two ends.

**The model.** The assumed tire (the plant's family, `LumpedLuGre2D`, with its nominal
parameters) on a road of friction scale $\lambda = e^\vartheta$ (`vehsim.scale_friction`,
$\theta = 1/\lambda$) has in steady state (eq. 35 with $\dot{\bar z} = 0$)
$\bar z = v_r/(C_0(v_r)/\lambda + \kappa c)$, $\mu_{ss} = \|\sigma_0\bar z + \sigma_2
v_r\|$, at the axle's relative velocity $v_r = (\omega r - V_x, -V_y)$ (eq. 34; $V$ from
the measured ground velocity, yaw rate and steering angle, `axle_velocities`) and $c =
|\omega r|$. Per axle, an extended Kalman filter on $\vartheta$ with a random walk by
forgetting: $P^- = \min(P/\gamma, P_{max})$; $H = \partial\mu_{ss}/\partial\vartheta$
(forward mode); $K = P^-H/(H^2P^- + R)$ with $R = \sigma_\mu^2 +
\sigma_v^2\|\partial\mu_{ss}/\partial v_r\|^2$ ($\sigma_\mu$ the utilised friction's noise;
$\sigma_v$ that of each component of the measured $v_r$, read through the curve's slope:
at small slip, where the curve is steep, a few cm/s of velocity noise are a large error in
$\mu_{ss}$, so the sample weighs little; near and past the peak, where it is flat, the
term vanishes. It is first order: where $\sigma_v$ is as large as $\|v_r\|$ itself it is
rough, and it does not remove the upward bias of a noisy slip's norm, which the gate below
is for); $\vartheta \leftarrow \Pi(\vartheta +
\operatorname{clip}(K(\mu_i - \mu_{ss}), \pm\Delta_{max}))$, $\Pi$ the projection onto
$[\log\lambda_{min}, \log\lambda_{max}]$; $P = (1 - KH)P^-$. A change of road shows as
innovations far larger than the covariance expects once $P$ has shrunk: a CUSUM detector
on the normalised innovation squared $\nu = e^2/(H^2P^- + R)$, $g \leftarrow \max(0, g +
\nu - \delta)$, raises $P^-$ to $P_0$ when $g > h$ and restarts (covariance resetting, as
`FrictionObserver` does), so the estimate leaves the old road within a few informative
samples instead of at the pace of forgetting.

**A map of the surface.** With `surface` (an `AbstractGripField` $r(x, y)$: the road's
grip *relative* to some reference, as a co-driver's pace notes or a camera's surface
classification give it, not its level) the filter estimates the road-wide multiplier $c$
of $\lambda(p) = c\,r(p)$ instead: $\vartheta = \log c$, and the model above is evaluated
at $\lambda = c\,\bar r_i$, $\log\bar r_i$ the mean of $\log r$ at axle $i$'s contact
point (the pose measured, `params`' $\ell_F$, $\ell_R$) at the sample's two ends. What is
learnt on one surface then carries over to the others by the map's ratios, and the
estimate reports $\lambda = c\,r$ at the last measured contact points: the grip under the
car at once when it crosses onto another surface, where without a map it lags until the
new surface excites the filter.

**What it estimates.** The road condition $\lambda$ (equivalently $\theta = 1/\lambda$),
with the standard deviation $\lambda\sqrt P$; the measurements at every speed inform the
same $\lambda$, since the model is evaluated at the sample's own relative velocity. The
peak friction is a function of $\lambda$ *and* of the speed (`peak_friction`: the LuGre
friction rises as the sliding speed falls, eq. 21; on the road whose peak is 0.52 at
20 m/s it is 0.56 at 12 m/s, 0.65 at 4 m/s): the estimate reports it at `reference_speed`
(`GripEstimate.peak`, with the standard deviation $|\partial\mu^*/\partial\vartheta|
\sqrt P$), and a user of the estimate at another speed evaluates $\mu^*(\lambda, V)$
(`RecedingHorizonDriver` does, at each stage's planned speed).

**Excitation.** The data say something about the peak only where the friction used
approaches it: at small slip all roads share the slope (eq. 19; $\bar z \approx
v_r/(\kappa c)$, independent of $\lambda$), so $H \approx 0$ and the gain vanishes by
itself; $H$ grows to about $\mu_{ss}$ as the slip nears and passes the peak (braking or
driving pulses, a slalom or a corner near the limit). The filter takes a sample in only
where the axle uses at least `min_utilisation` of the estimated peak at the sample's speed
($\mu_i \ge u_{min}\mu^*(\lambda, \bar V)$, $\bar V$ the mean of its two ends' speeds,
at least `min_speed`): below, the model's slip comes from noisy velocities and is biased
upwards (the norm of a noise), so that small-slip data, informative or not, would pull the
estimate down. So it **needs** an axle using at least half of its peak: braking or driving
near the limit, or cornering near it. A road much worse than believed never gives that
fraction of the believed peak; with `sliding_slip` set, a sample also counts where the
axle slides (combined slip at least `sliding_slip`, far past the peak's few percent, where
the noise's upward bias of the slip is small against the slip itself). **Without excitation** (straight, constant speed;
slips small; or a driver that keeps well below the peak) the estimate holds its prior or
last value, and its variance grows by forgetting up to $P_{max}$ (the belief widens to the
cap, never further): it does not drift, but it does not learn that the road is better than
believed either, and a driver that plans with the lower edge of the belief then stays
slower than the road allows; below `min_speed` nothing is measured (the slip is
ill-defined) and the same holds. **Blind
spots:** a tire whose shape differs from the assumed one is read as the best-fitting
$\lambda$ of the wrong shape (biased; `AxlePeakEstimator` assumes no shape); the loads follow the suspension's
dynamics only as far as the nominal suspension and the measured $a_x$ describe them
(no road profile, no unmeasured pitch disturbance), the force is the sample's mean against
the slip at its midpoint, so fast transients (a wheel locking within a sample) read as noise; a brake
holding a locked wheel transmits less than its torque (the plant's $\tanh$ brake, within
the wheel-speed noise of the lock speed): a braked wheel turning slower than
$5\omega_\epsilon$ at either end of the sample is not measured.
"""

from __future__ import annotations

import abc
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._checks import check_count, check_nonnegative, check_order, check_positive, check_range
from .._fields import array_field, float_array
from .._math import safe_abs, safe_div, safe_norm, safe_sqrt
from ..tire.lugre2d import decay_rates
from ..tire.lumped2d import LumpedLuGre2D
from ..tire.params import lugre2d_bakker1987
from ..vehicle.params import HalfCarParams, rally_gravel
from ..vehicle.planar import axle_velocities
from .grip import AbstractGripField, scale_friction
from .sensors import DriveMeasurement, DriveSensors


class GripEstimate(eqx.Module):
    r"""A belief about the grip per axle (front, rear): the friction scale `scale`
    $\lambda$ ($= 1/\theta$) and its standard deviation `scale_std`, the peak friction
    `peak` $\mu^*$ and its standard deviation `peak_std` (each shape (2,))."""

    scale: Float[Array, " 2"]
    scale_std: Float[Array, " 2"]
    peak: Float[Array, " 2"]
    peak_std: Float[Array, " 2"]


class AbstractGripEstimator(eqx.Module):
    """An estimator of the road's grip run on the drive's measurements, sample by sample."""

    @abc.abstractmethod
    def init(self, measurement: DriveMeasurement):
        """The state before the first sample, from the first measurement."""

    @abc.abstractmethod
    def update(self, state, measurement: DriveMeasurement):
        """The state after the sample that ends at `measurement`."""

    @abc.abstractmethod
    def estimate(self, state) -> GripEstimate:
        """The belief at `state`."""

    @abc.abstractmethod
    def signals(self, state) -> dict:
        """What a saved run keeps of the state, by name."""


def scaled_steady_state_mu(tire: LumpedLuGre2D, scale, v_r, c):
    r"""$(\mu_x, \mu_y)$ of the lumped 2D LuGre in steady state on a road of friction scale
    $\lambda$ = `scale` (module docstring)."""
    t = scale_friction(tire, scale)
    den = decay_rates(t.params, v_r) + t.gains(v_r, c)[:2] * c
    zb = safe_div(v_r, den)
    return t.params.sigma0 * zb + t.params.sigma2 * v_r


def slip_velocity_std(sensors: DriveSensors, radius) -> Float[Array, ""]:
    r"""$\sigma_v$ [m/s]: the standard deviation of each component of the relative
    velocity $v_r$ that `AxleGripEstimator` measures over a sample (the mean of its two
    ends) with `sensors` on wheels of `radius` [m]: $\sigma_v^2 = (\sigma_V^2 +
    r^2\sigma_\omega^2)/2$, the ground velocity's and the wheel speed's noises independent
    at the two ends (3.7 cm/s with the default `DriveSensors` and 0.3 m wheels; 0 with
    their noise off). Exact for the longitudinal component; the lateral one has the yaw
    rate's noise times the axle's lever in place of the wheel speed's (3.6 cm/s with the
    defaults)."""
    on = jnp.where(sensors.noise_on, 1.0, 0.0)
    return on * safe_sqrt((sensors.velocity_std**2 + (radius * sensors.wheel_speed_std)**2) / 2)


REFERENCE_SPEED = 20.0
"""Speed [m/s] at which a peak friction is stated when no speed is named: the estimator's
reported `GripEstimate.peak`, the scenarios' grips, the driver's `nominal_peak`."""


PEAK_SPEED_FLOOR = 1e-6
"""Speed [m/s] below which `peak_friction` is taken at this speed: at $V = 0$ every slip
velocity is 0, so the steady state has no friction to find a peak of."""


def peak_friction(tire: LumpedLuGre2D, scale, speed):
    r"""$\mu^*(\lambda, V)$: the largest steady-state friction $\|\mu_{ss}\|$
    (`scaled_steady_state_mu`) of `tire` on a road of friction scale $\lambda$ = `scale` in
    pure braking at the ground speed $V$ = `speed` [m/s] ($v_r = (-\kappa V, 0)$, $c = (1 -
    \kappa)V$; $\kappa$ on `peak_slips`, the largest refined by a parabola through it and
    its neighbours). Against 4001 slips from $10^{-5}$ (`vehsim.drive.plant_tires.
    dense_peak`), on roads whose peaks run from 0.008 to 2.3: within 0.1 % where the peak
    is 0.52 or above, 0.8 % down to 0.26 and 0.9 % below, at 4, 20 and 40 m/s; on the
    slippery roads, whose peaks lie at slips below 1/96, within 0.5 % (the 96 uniform slips
    alone read them up to 21 % low at 20 m/s and 27 % at 40 m/s).

    The LuGre friction rises as the sliding speed falls (the Stribeck curve, eq. 21), so the
    peak depends on $V$: on the road whose peak is 0.52 at 20 m/s it is 0.56 at 12 m/s and
    0.65 at 4 m/s; and it is not proportional to $\lambda$ (the edge term $\kappa c$ of
    the lumped model does not scale). Towards standstill it rises to a limit (2.60 on the
    road of friction scale 1) with a slope that grows without bound (-1.4 per m/s at
    0.1 m/s, -1830 at $10^{-6}$): below `PEAK_SPEED_FLOOR`, standstill included, the peak
    is the one at that floor, with slope 0."""
    V = jnp.maximum(speed, PEAK_SPEED_FLOOR)
    return braking_peak_on(tire, scale, V, peak_slips())


def peak_slips() -> Float[Array, " 112"]:
    r"""`peak_friction`'s slips, increasing: 96 uniform from 1/96 to 1 and below them 16
    geometrically spaced from $10^{-4}$, where the peaks of slippery roads lie. A largest
    friction sampled at 2/96 or above is refined from the uniform slips alone (the parabola
    through it and its neighbours), as without the slips below: those change only the peaks
    sampled largest at 1/96 or below."""
    return jnp.concatenate([jnp.geomspace(1e-4, 1.0 / 96, 17)[:-1],
                            jnp.linspace(0.0, 1.0, 97)[1:]])


def braking_peak_on(tire: LumpedLuGre2D, scale, speed, kappa):
    r"""The largest steady-state friction $\|\mu_{ss}\|$ of `tire` on a road of friction
    scale `scale` in pure braking at `speed` [m/s] over the slips `kappa` (increasing), the
    largest refined by a parabola through it and its neighbours (in the grid's index: for a
    geometric grid, in $\log\kappa$). `peak_friction`'s grid is `peak_slips`."""

    def mu_at(kap):
        v_r = jnp.stack([-kap * speed, jnp.zeros_like(kap)])
        return safe_norm(scaled_steady_state_mu(tire, scale, v_r, (1.0 - kap) * speed))

    return _refined_max(jax.vmap(mu_at)(kappa))


def _refined_max(mus):
    """The largest of ``mus`` refined by the parabola through it and its neighbours."""
    i = jnp.clip(jnp.argmax(mus), 1, mus.shape[0] - 2)
    a, b, cc = mus[i - 1], mus[i], mus[i + 1]
    den = a - 2 * b + cc
    shift = jnp.clip(safe_div(0.5 * (a - cc), den), -1.0, 1.0)
    return b - 0.25 * (a - cc) * shift


def side_peak_friction(tire: LumpedLuGre2D, scale, speed):
    r"""The largest steady-state friction $\|\mu_{ss}\|$ of `tire` on a road of friction
    scale `scale` in pure side slip at the ground speed $V$ = `speed` [m/s], the wheel
    rolling freely ($v_r = (0, -V\tan\alpha)$, $c = V$; $\tan\alpha$ on `peak_slips`,
    refined as `peak_friction`). The drive plant's tire (fitted to Bakker's Magic Formula,
    whose side force peaks below its braking force) is anisotropic: on the nominal road its
    side peak is 0.93 of its braking peak `peak_friction` at 5 m/s and 0.90 at 15 m/s, the
    `FrictionEllipseTire.lateral_ratio` of a planning tire with the plant's peaks
    (docs/driver.md)."""
    V = jnp.maximum(speed, PEAK_SPEED_FLOOR)

    def mu_at(t):
        v_r = jnp.stack([jnp.zeros_like(t), -V * t])
        return safe_norm(scaled_steady_state_mu(tire, scale, v_r, V))

    return _refined_max(jax.vmap(mu_at)(peak_slips()))


def longitudinal_capacity(tire: LumpedLuGre2D, scale, vx, vy):
    r"""$(\mu_{x,drive}, \mu_{x,brake})$: the largest steady-state longitudinal friction
    $|\mu_x|$ (`scaled_steady_state_mu`) of `tire` on a road of friction scale
    $\lambda$ = `scale` at the wheel-frame ground velocity $(v_x, v_y)$ [m/s] of its axle,
    over the driving slips $\kappa > 0$ and over the braking ones $\kappa < 0$ ($v_r =
    (\kappa v_x, -v_y)$, $c = (1 + \kappa)v_x$; $|\kappa|$ on 48 points from $10^{-3}$ to 1,
    geometrically spaced; $v_x$ floored at 1 m/s).

    A wheel whose torque asks more than $r F_z$ times this of its tire has no steady slip:
    beyond the LuGre peak the force falls as the slip grows, so the wheel spins up (or
    locks). With lateral slip the capacity is below the pure-slip peak `peak_friction`
    (the friction is shared with $\mu_y$)."""
    vx = jnp.maximum(vx, 1.0)
    kap = jnp.geomspace(1e-3, 1.0, 48)

    def mu_x(k):
        v_r = jnp.stack([k * vx, -vy + 0.0 * k])
        return scaled_steady_state_mu(tire, scale, v_r, (1.0 + k) * vx)[0]

    drive = jnp.max(jax.vmap(mu_x)(kap))
    brake = jnp.max(-jax.vmap(mu_x)(-kap))
    return drive, brake


_SCALE_RANGE = (1e-3, 10.0)
r"""The friction scales $\lambda$ `scale_of_peak` searches."""


def scale_of_peak(tire: LumpedLuGre2D, peak, speed=REFERENCE_SPEED, steps: int = 60):
    r"""The friction scale $\lambda$ with $\mu^*(\lambda, V)$ = `peak` (`peak_friction`
    at $V$ = `speed` [m/s]): bisection on $\log\lambda \in [\log 10^{-3}, \log 10]$, where
    $\mu^*$ increases, `steps` halvings (60: to rounding). JAX; a peak outside
    $(\mu^*(10^{-3}), \mu^*(10))$ gives the nearer end.

    Derivatives (forward and reverse mode) in `peak`, `speed` and the tire's parameters
    are the implicit function theorem's at the root, $d\log\lambda = (dp - d\mu^*|_
    \lambda) / (\partial\mu^*/\partial\log\lambda)$, not those of the bisection (which
    are zero); zero where the peak is outside the range and the end is returned."""
    return _scale_of_peak(tire, jnp.asarray(peak, float), jnp.asarray(speed, float), steps)


@functools.partial(jax.custom_jvp, nondiff_argnums=(3,))
def _scale_of_peak(tire, peak, speed, steps):
    def step(bounds, _):
        lo, hi = bounds
        mid = 0.5 * (lo + hi)
        below = peak_friction(tire, jnp.exp(mid), speed) < peak
        return (jnp.where(below, mid, lo), jnp.where(below, hi, mid)), None

    lo = jnp.log(_SCALE_RANGE[0]) + 0.0 * peak
    hi = jnp.log(_SCALE_RANGE[1]) + 0.0 * peak
    (lo, hi), _ = jax.lax.scan(step, (lo, hi), None, length=steps)
    return jnp.exp(0.5 * (lo + hi))


@_scale_of_peak.defjvp
def _scale_of_peak_jvp(steps, primals, tangents):
    tire, peak, speed = primals
    d_tire, d_peak, d_speed = tangents
    lam = _scale_of_peak(tire, peak, speed, steps)
    theta = jnp.log(lam)
    mu = lambda tr, th, v: peak_friction(tr, jnp.exp(th), v)
    # d mu* along the log scale, and along the tire's and the speed's tangents at fixed scale
    _, slope = jax.jvp(lambda th: mu(tire, th, speed), (theta,), (jnp.ones_like(theta),))
    _, moved = jax.jvp(lambda tr, v: mu(tr, theta, v), (tire, speed), (d_tire, d_speed))
    inside = (lam > 1.0001 * _SCALE_RANGE[0]) & (lam < 0.9999 * _SCALE_RANGE[1])
    d_theta = jnp.where(inside, (d_peak - moved) / jnp.where(inside, slope, 1.0), 0.0)
    return lam, lam * d_theta


class AbstractAxleEstimator(AbstractGripEstimator):
    r"""A grip estimator that reads each axle's utilised friction from the measurements
    (module docstring, "Utilised friction"): the measurement half shared by the estimators
    of this module, whatever they then fit to it. Needs the nominal car `params`, the brake
    smoothing `omega_eps` [rad/s], the speed `min_speed` [m/s] below which a slip is not
    measured, the load model (`dynamic_loads`, `load_substeps`), the optional map of the
    road's relative grip `surface`, a `tire` (the `LumpedLuGre2D` its friction scales refer
    to), a change detector (`change_drift`, `change_threshold`) and the `reference_speed`
    of its reported peak."""

    params: eqx.AbstractVar[HalfCarParams]
    omega_eps: eqx.AbstractVar[Float[Array, ""]]
    min_speed: eqx.AbstractVar[Float[Array, ""]]
    dynamic_loads: eqx.AbstractVar[bool]
    load_substeps: eqx.AbstractVar[int]
    surface: eqx.AbstractVar[AbstractGripField | None]
    tire: eqx.AbstractVar[LumpedLuGre2D]
    change_drift: eqx.AbstractVar[Float[Array, ""]]
    change_threshold: eqx.AbstractVar[Float[Array, ""]]
    reference_speed: eqx.AbstractVar[Float[Array, ""]]

    def _loads(self, q):
        p = self.params
        z, z_dot, theta, theta_dot = q[0], q[1], q[2], q[3]
        FzF0, FzR0 = p.static_loads()
        sn, cs = jnp.sin(theta), jnp.cos(theta)
        FzF = FzF0 - p.K_F * (z - p.lF * sn) - p.C_F * (z_dot - p.lF * cs * theta_dot)
        FzR = FzR0 - p.K_R * (z + p.lR * sn) - p.C_R * (z_dot + p.lR * cs * theta_dot)
        return jnp.stack([FzF, FzR])

    def _suspension_rates(self, q, ax):
        p = self.params
        Fz = self._loads(q)
        z_dd = (Fz[0] + Fz[1]) / p.m - p.g
        theta_dd = ((Fz[1] * p.lR - Fz[0] * p.lF) * jnp.cos(q[2])
                    - p.m * ax * (p.h + q[0])) / p.Iy
        return jnp.stack([q[1], z_dd, q[3], theta_dd])

    def axle_loads(self, q, ax0, ax1, dt):
        r"""``(mean loads, q at the end)``: the suspension (eqs. 54-60) from `q` over a
        sample of length `dt`, $a_x$ going linearly from `ax0` to `ax1` (module docstring).
        """
        n = self.load_substeps
        h = dt / n

        def step(q, j):
            def a(tau):
                return ax0 + (ax1 - ax0) * tau
            t = j / n
            k1 = self._suspension_rates(q, a(t))
            k2 = self._suspension_rates(q + 0.5 * h * k1, a(t + 0.5 / n))
            k3 = self._suspension_rates(q + 0.5 * h * k2, a(t + 0.5 / n))
            k4 = self._suspension_rates(q + h * k3, a(t + 1.0 / n))
            q1 = q + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
            return q1, 0.5 * (self._loads(q) + self._loads(q1))

        q1, loads = jax.lax.scan(step, q, jnp.arange(n))
        return jnp.mean(loads, axis=0), q1

    def utilised_friction(self, m0: DriveMeasurement, m1: DriveMeasurement, Fz=None):
        r"""``(mu, slip, v_r, c)`` per axle over the sample from `m0` to `m1` (module
        docstring); `mu` = $\|F_i\|/F_{iz}$, `v_r` shape (2, 2). `Fz`: the axle loads
        (default the quasi-static ones)."""
        p = self.params
        dt = m1.t - m0.t
        dt = jnp.where(dt > 0, dt, 1.0)
        omega = 0.5 * (m0.omega + m1.omega)
        T = m1.torque
        T = jnp.maximum(T, 0.0) + jnp.minimum(T, 0.0) * jnp.tanh(omega / self.omega_eps)
        Iw = jnp.stack([p.Iw_F, p.Iw_R])
        Fx = (T - Iw * (m1.omega - m0.omega) / dt) / p.r
        ay, ax = 0.5 * (m0.ay + m1.ay), 0.5 * (m0.ax + m1.ax)
        r_dot = (m1.yaw_rate - m0.yaw_rate) / dt
        ell = p.lF + p.lR
        FyF_body = (p.m * ay * p.lR + p.Iz * r_dot) / ell
        FyR = (p.m * ay * p.lF - p.Iz * r_dot) / ell
        delta = 0.5 * (m0.delta + m1.delta)
        FyF = (FyF_body - Fx[0] * jnp.sin(delta)) / jnp.cos(delta)
        if Fz is None:
            Fz = jnp.stack([p.m * (p.g * p.lR - ax * p.h), p.m * (p.g * p.lF + ax * p.h)]) / ell
        force = safe_norm(jnp.stack([Fx, jnp.stack([FyF, FyR])], axis=-1))
        mu = safe_div(force, jnp.maximum(Fz, 0.0))
        vx, vy = 0.5 * (m0.vx + m1.vx), 0.5 * (m0.vy + m1.vy)
        yaw = 0.5 * (m0.yaw_rate + m1.yaw_rate)
        VFx, VFy, VRx, VRy = axle_velocities(p, vx, vy, yaw, delta)
        V = jnp.stack([jnp.stack([VFx, VFy]), jnp.stack([VRx, VRy])])
        v_r = jnp.stack([omega * p.r - V[:, 0], -V[:, 1]], axis=-1)
        c = safe_abs(omega * p.r)
        slip = safe_norm(v_r) / jnp.maximum(safe_norm(V), self.min_speed)
        return mu, slip, v_r, c

    def log_surface(self, m: DriveMeasurement) -> Float[Array, " 2"]:
        r"""$\log r$ of `surface` at the front and rear contact points of the pose in `m`
        (0 without a map)."""
        if self.surface is None:
            return jnp.zeros(2) + 0.0 * m.x
        p = self.params
        c, s = jnp.cos(m.psi), jnp.sin(m.psi)
        return jnp.log(jnp.stack([self.surface.scale_at(m.x + p.lF * c, m.y + p.lF * s),
                                  self.surface.scale_at(m.x - p.lR * c, m.y - p.lR * s)]))

    def check_shared(self, owner: str) -> None:
        """Refuse a `tire` that is not a `LumpedLuGre2D`, a `surface` that is not a map, a
        nonpositive `min_speed`, `omega_eps`, `change_drift`, `reference_speed` or
        `change_threshold` (inf: no change detection), a `load_substeps` below 1."""
        if not isinstance(self.tire, LumpedLuGre2D):
            raise TypeError(f"{owner}.tire must be a LumpedLuGre2D, got "
                            f"{type(self.tire).__name__}")
        if self.surface is not None and not isinstance(self.surface, AbstractGripField):
            raise TypeError(f"{owner}.surface must be None or an AbstractGripField (a map "
                            f"of the road's relative grip), got {type(self.surface).__name__}")
        for name in ("min_speed", "omega_eps", "change_drift", "reference_speed"):
            check_positive(owner, name, getattr(self, name))
        check_range(owner, "change_threshold", self.change_threshold, lower=0.0,
                    lower_open=True, allow_inf=True)
        check_count(owner, "load_substeps", self.load_substeps)

    def sample_friction(self, suspension, m0: DriveMeasurement, m1: DriveMeasurement):
        r"""``(mu, slip, v_r, c, suspension)``: `utilised_friction` over the sample from `m0`
        to `m1` with the loads of the load model (from the heave and pitch `suspension`,
        returned at the sample's end)."""
        dt = jnp.where(m1.t > m0.t, m1.t - m0.t, 0.0)
        if self.dynamic_loads:
            Fz, suspension = self.axle_loads(suspension, m0.ax, m1.ax, dt)
        else:
            Fz = None
        return (*self.utilised_friction(m0, m1, Fz), suspension)

    def measurable(self, m0: DriveMeasurement, m1: DriveMeasurement):
        r"""Per axle, whether the sample from `m0` to `m1` measures a force: both ends above
        `min_speed`, time advancing, and not a braked wheel near lock (its brake torque is
        not what it transmits: the $\tanh$ brake within the wheel-speed noise of its lock
        speed, below $5\omega_\epsilon$ at either end)."""
        valid = (m1.speed > self.min_speed) & (m0.speed > self.min_speed) & (m1.t > m0.t)
        locked = jnp.minimum(jnp.abs(m0.omega), jnp.abs(m1.omega)) < 5 * self.omega_eps
        return valid & ((m1.torque >= 0) | ~locked)


class AxleGripState(eqx.Module):
    r"""$\vartheta = \log\lambda$ and its variance $P$ per axle, the last measurement, the
    heave and pitch `suspension` $(z, \dot z, \theta, \dot\theta)$ of the load model, and
    the last utilised friction `mu_used`, model friction `mu_model`, combined slip `slip`
    ($\|v_r\|/\max(|V|, v_{min})$), gain `gain` and the change detector's statistic
    `change_statistic` $g$ (each (2,))."""

    log_scale: Float[Array, " 2"]
    variance: Float[Array, " 2"]
    last: DriveMeasurement
    suspension: Float[Array, " 4"]
    mu_used: Float[Array, " 2"]
    mu_model: Float[Array, " 2"]
    slip: Float[Array, " 2"]
    gain: Float[Array, " 2"]
    change_statistic: Float[Array, " 2"]


class AxleGripEstimator(AbstractAxleEstimator):
    r"""The per-axle grip estimator of the module docstring.

    **Fields:** `params` (the nominal `HalfCarParams`, default `rally_gravel()`), `tire`
    (the assumed `LumpedLuGre2D`, default the plant's), `prior_scale` $\lambda_0$ (1),
    `initial_variance` $P_0$ of $\log\lambda$ (0.09), `max_variance` $P_{max}$ (0.25),
    `forgetting` $\gamma\in(0, 1]$ (0.97), `noise_std` $\sigma_\mu$ of the utilised friction
    (0.05), `max_step` $\Delta_{max}$ (0.2), `scale_min`, `scale_max` (0.1, 3),
    `min_speed` [m/s] (3), `min_utilisation` (0.5: an axle's data count only where it uses
    at least this fraction of the estimated peak at its speed), `sliding_slip` (None: off;
    a number: a sample also counts where the axle's combined slip $\|v_r\|/\|V\|$ is at
    least this, sliding far past the peak's few percent, whatever friction it uses: on a
    road much worse than believed the axles never reach the gate, but they slide),
    `slip_velocity_std` $\sigma_v$ [m/s] (None: the measured relative velocity taken as
    exact; a number: the standard deviation of each of its components, weighing each
    sample by the slope it is read on, module docstring; the function `slip_velocity_std`
    gives it for a set of sensors), `omega_eps` [rad/s] (the plant's brake smoothing,
    0.5), the change detector's
    `change_drift` $\delta$ (10) and `change_threshold` $h$ (80; `inf` turns it off),
    `reference_speed` [m/s] of the reported peak (`REFERENCE_SPEED`, 20), `dynamic_loads` (True: the
    suspension's loads; False: quasi-static), `load_substeps` (10), `surface` (None, or an
    `AbstractGripField`: the map of the road's relative grip of the module docstring;
    `prior_scale`, `scale_min` and `scale_max` are then those of the multiplier $c$).
    """

    params: HalfCarParams = eqx.field(default_factory=rally_gravel)
    tire: LumpedLuGre2D = eqx.field(default_factory=lambda: LumpedLuGre2D(lugre2d_bakker1987()))
    prior_scale: Float[Array, ""] = array_field(default=1.0)
    initial_variance: Float[Array, ""] = array_field(default=0.09)
    max_variance: Float[Array, ""] = array_field(default=0.25)
    forgetting: Float[Array, ""] = array_field(default=0.97)
    noise_std: Float[Array, ""] = array_field(default=0.05)
    max_step: Float[Array, ""] = array_field(default=0.2)
    scale_min: Float[Array, ""] = array_field(default=0.1)
    scale_max: Float[Array, ""] = array_field(default=3.0)
    min_speed: Float[Array, ""] = array_field(default=3.0)
    min_utilisation: Float[Array, ""] = array_field(default=0.5)
    sliding_slip: Float[Array, ""] | None = eqx.field(
        default=None, converter=lambda x: None if x is None else float_array(x))
    slip_velocity_std: Float[Array, ""] | None = eqx.field(
        default=None, converter=lambda x: None if x is None else float_array(x))
    omega_eps: Float[Array, ""] = array_field(default=0.5)
    change_drift: Float[Array, ""] = array_field(default=10.0)
    change_threshold: Float[Array, ""] = array_field(default=80.0)
    reference_speed: Float[Array, ""] = array_field(default=REFERENCE_SPEED)
    dynamic_loads: bool = eqx.field(static=True, default=True)
    load_substeps: int = eqx.field(static=True, default=10)
    surface: AbstractGripField | None = None

    def __check_init__(self):
        owner = "AxleGripEstimator"
        self.check_shared(owner)
        for name in ("prior_scale", "initial_variance", "max_variance", "noise_std",
                     "max_step", "scale_min", "scale_max", "min_utilisation"):
            check_positive(owner, name, getattr(self, name))
        if self.sliding_slip is not None:
            check_positive(owner, "sliding_slip", self.sliding_slip)
        if self.slip_velocity_std is not None:
            check_nonnegative(owner, "slip_velocity_std", self.slip_velocity_std)
        check_range(owner, "forgetting", self.forgetting, lower=0.0, upper=1.0,
                    lower_open=True)
        check_order(owner, "scale_min", self.scale_min, "scale_max", self.scale_max)

    def init(self, measurement: DriveMeasurement) -> AxleGripState:
        """The prior $\\lambda_0$ with variance $P_0$ on both axles."""
        z = jnp.zeros(2)
        lam = jnp.log(self.prior_scale) * jnp.ones(2)
        return AxleGripState(lam, self.initial_variance * jnp.ones(2), measurement,
                             jnp.zeros(4), z, z, z, z, z)

    def _axle_mu(self, th, vr, cc):
        return safe_norm(scaled_steady_state_mu(self.tire, jnp.exp(th), vr, cc))

    def model_mu(self, log_scale, v_r, c):
        r"""$\mu_{ss}$ of the assumed tire at $\lambda = e^\vartheta$ per axle."""
        return jax.vmap(self._axle_mu)(log_scale, v_r, c)

    def slip_variance(self, log_scale, v_r, c):
        r"""$\sigma_v^2\|\partial\mu_{ss}/\partial v_r\|^2$ per axle: the variance the
        noise of the measured relative velocity (`slip_velocity_std` $\sigma_v$ per
        component) gives the model's friction (0 without it)."""
        if self.slip_velocity_std is None:
            return jnp.zeros(2) + 0.0 * log_scale

        def one(th, vr, cc):
            return jnp.sum(jax.jacfwd(self._axle_mu, argnums=1)(th, vr, cc) ** 2)
        return self.slip_velocity_std**2 * jax.vmap(one)(log_scale, v_r, c)

    def update(self, state: AxleGripState, m: DriveMeasurement) -> AxleGripState:
        mu, slip, v_r, c, susp = self.sample_friction(state.suspension, state.last, m)
        # the road under the axles over the sample: c r, r the map's (1 without one)
        log_road = state.log_scale + 0.5 * (self.log_surface(state.last) + self.log_surface(m))
        h, H = jax.jvp(lambda th: self.model_mu(th, v_r, c), (log_road,), (jnp.ones(2),))
        speed = jnp.maximum(0.5 * (m.speed + state.last.speed), self.min_speed)
        peak = jax.vmap(lambda th: self.peak(jnp.exp(th), speed))(log_road)
        informative = mu >= self.min_utilisation * peak
        if self.sliding_slip is not None:  # or sliding far past the believed peak's slip
            informative = informative | (slip >= self.sliding_slip)
        valid = self.measurable(state.last, m) & informative
        P = jnp.minimum(state.variance / self.forgetting, self.max_variance)
        R = self.noise_std**2 + self.slip_variance(log_road, v_r, c)
        e = mu - h
        nis = e * e / (H * H * P + R)
        g = jnp.maximum(state.change_statistic + jnp.where(valid, nis - self.change_drift, 0.0),
                        0.0)
        changed = g > self.change_threshold
        P = jnp.where(changed, jnp.maximum(P, self.initial_variance), P)
        g = jnp.where(changed, 0.0, g)
        K = jnp.where(valid, P * H / (H * H * P + R), 0.0)
        step = jnp.clip(K * e, -self.max_step, self.max_step)
        log_scale = jnp.clip(state.log_scale + step, jnp.log(self.scale_min),
                             jnp.log(self.scale_max))
        P = (1.0 - K * H) * P
        return AxleGripState(log_scale, P, m, susp, jnp.where(valid, mu, 0.0), h, slip, K, g)

    def peak(self, scale, speed=None):
        r"""$\mu^*(\lambda, V)$ of the assumed tire (`peak_friction`) at the speed `speed`
        [m/s] (default `reference_speed`)."""
        return peak_friction(self.tire, scale, self.reference_speed if speed is None else speed)

    def estimate(self, state: AxleGripState) -> GripEstimate:
        r"""The belief about the road under the axles at the last measurement: $\lambda$
        (with a map, $c\,r$ there) and its peak at `reference_speed`."""
        log_road = state.log_scale + self.log_surface(state.last)
        lam = jnp.exp(log_road)
        std = jnp.sqrt(state.variance)
        peak, dpeak = jax.vmap(lambda th: jax.jvp(lambda t: self.peak(jnp.exp(t)), (th,),
                                                  (jnp.ones(()),)))(log_road)
        return GripEstimate(lam, lam * std, peak, jnp.abs(dpeak) * std)

    def signals(self, state: AxleGripState) -> dict:
        """`scale_F`, `scale_R` ($\\lambda$), `log_scale_variance_F`, `_R`, `mu_used_F`,
        `_R`, `mu_model_F`, `_R`, `slip_F`, `_R`."""
        out = {}
        log_road = state.log_scale + self.log_surface(state.last)
        for i, axle in enumerate("FR"):
            out[f"scale_{axle}"] = jnp.exp(log_road[i])
            out[f"log_scale_variance_{axle}"] = state.variance[i]
            out[f"mu_used_{axle}"] = state.mu_used[i]
            out[f"mu_model_{axle}"] = state.mu_model[i]
            out[f"slip_{axle}"] = state.slip[i]
        return out
