r"""A shape-free estimate of each axle's peak friction: the utilised friction against the
combined slip, kept as a curve and fitted by Burckhardt's family.

**Why.** `AxleGripEstimator` reads the data through the assumed tire: it finds the friction
scale $\lambda$ whose LuGre steady state best explains the force at the measured slip. On a
tire of another shape that is the best-fitting $\lambda$ of the wrong curve, and the peak a
driver derives from it is biased: on a Magic Formula plant, whose lateral force peaks at
twice LuGre's slip angle and whose peak does not rise as the speed falls, the drives planned
with it left the slippery corners. This estimator assumes no tire: only that the axle's
friction rises with its combined slip to a peak and then falls or levels off.

**Data.** Each sample's utilised friction $\mu_i$ and combined slip $s_i = \|v_r\|/\max(\|V\|,
v_{min})$ per axle, as `AxleGripEstimator` measures them (`AbstractAxleEstimator`: the wheel
equations 52-53, the lateral equations 50-51, the suspension's loads of eqs. 54-60). With a
map of the road's relative grip $r$ (`surface`), $\mu_i$ is divided by the map's $\bar r_i$
under the axle over the sample (the geometric mean of its two ends): the curve is that of the
map's reference surface. The map's ratios are ratios of peaks: a map of the LuGre plant's
friction scales, as the scenarios' pace notes are, is turned into one by `PeakRatios`
(their icy patch's scale ratio 0.44 is a peak ratio of 0.50; `driver_estimator` does it).

**The curve.** As `vehsim.PeakEstimator` does for a braked wheel, per axle: `bins` bins over
the slip (edges $(j/B)^2$ on $[0, 1]$) hold the running means of $\mu$ and $s$ that fell in
them and their weights, every weight times the forgetting $\gamma$ at each informative
sample; the curve is fitted by Burckhardt's $\mu = c_1(1 - e^{-c_2 s}) - c_3 s$ by weighted
least squares with a ridge towards the prior (`fit_burckhardt`), on a grid of $c_2$, the
best member's peak $(s^*, \mu^*)$ in closed form (`burckhardt_peak`); a change of road (a
CUSUM on the fitted curve's normalised residual $e^2/\sigma_\mu^2$) discounts the old curve.
A sample is informative where the axle's force is measurable (`measurable`) and its slip is
at least `min_slip`: below, all roads share the slope and the noise's upward bias of the
slip's norm is as large as the slip.

**The belief.** The fitted peak is only as good as the data near it: the curve says nothing
about a peak at slips the axle has not reached. The estimate of $\log\mu^*$ combines the
prior $\log\mu^*_0$ (standard deviation $\sigma_0$, `prior_std`) with the fit's, weighted by
the data at or past 70 % of the fitted peak's slip, $w^* = \sum_{j: \bar s_j \ge 0.7 s^*}
w_j$:
$$\frac1{\sigma^2} = \frac1{\sigma_0^2} + w^*\Big(\frac{\mu^*}{\sigma_\mu}\Big)^2,\qquad
\log\hat\mu = \sigma^2\Big(\frac{\log\mu^*_0}{\sigma_0^2} + w^*\Big(\frac{\mu^*}
{\sigma_\mu}\Big)^2\log\mu^*\Big),$$
$\sigma_\mu$ = `noise_std` the utilised friction's noise (each datum's relative standard
deviation at the peak, $\sigma_\mu/\mu^*$). So the prior holds until an axle has been near its
peak (braking or cornering near the limit, or sliding past it), and a few samples there
replace it. A road much better than believed, driven below the believed peak, is not learnt
(the same blind spot as `AxleGripEstimator`'s).

**What it reports.** `GripEstimate.peak` $\hat\mu$ per axle (times the map's $r$ at the last
contact points) and `peak_std` $\hat\mu\sigma$; `scale`: the friction scale of `tire` whose
peak at `reference_speed` is $\hat\mu$ (`scale_of_peak`), for users of the estimate that
think in friction scales (the traction control of `RecedingHorizonDriver`), and `scale_std`
$\lambda\sigma$. A driver that plans with the peak itself, with no speed dependence, is
`RecedingHorizonDriver(peak_model="estimated")`.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._checks import check_positive, check_range
from .._fields import array_field
from ..control.estimation.peak_estimator import burckhardt_peak, fit_burckhardt
from ..tire.burckhardt import BURCKHARDT
from ..tire.lumped2d import LumpedLuGre2D
from ..tire.params import lugre2d_bakker1987
from ..vehicle.params import HalfCarParams, rally_gravel
from .estimator import (
    REFERENCE_SPEED,
    AbstractAxleEstimator,
    AbstractGripEstimator,
    AxleGripEstimator,
    AxleGripState,
    GripEstimate,
    scale_of_peak,
)
from .grip import AbstractGripField
from .sensors import DriveMeasurement


DRY_ASPHALT = BURCKHARDT["dry_asphalt"]
r"""Burckhardt's $(c_1, c_2, c_3)$ for dry asphalt: the prior curve's shape, scaled to
`AxlePeakEstimator.prior_peak`."""


def _default_shapes():
    return np.geomspace(4.0, 320.0, 12)


class AxlePeakState(eqx.Module):
    r"""Per axle (leading axis 2): the binned curve (`weight`, `bin_mu`, `bin_slip`, each
    (2, B)), the fitted members (`coefficients` (2, G, 2), `error` (2, G)), the change
    detector's statistic `change_statistic`, the belief `log_peak` $\log\hat\mu$ and its
    variance `variance` $\sigma^2$ (of the map's reference surface), the fitted peak's slip
    `peak_slip`, the last sample's measured `mu_used` and `slip`; and the last measurement
    `last` and the load model's heave and pitch `suspension`."""

    weight: Float[Array, "2 B"]
    bin_mu: Float[Array, "2 B"]
    bin_slip: Float[Array, "2 B"]
    coefficients: Float[Array, "2 G 2"]
    error: Float[Array, "2 G"]
    change_statistic: Float[Array, " 2"]
    log_peak: Float[Array, " 2"]
    variance: Float[Array, " 2"]
    peak_slip: Float[Array, " 2"]
    mu_used: Float[Array, " 2"]
    slip: Float[Array, " 2"]
    last: DriveMeasurement
    suspension: Float[Array, " 4"]


class AxlePeakEstimator(AbstractAxleEstimator):
    r"""The shape-free per-axle peak estimator of the module docstring.

    **Fields:** `params` (the nominal `HalfCarParams`, default `rally_gravel()`),
    `prior_peak` $\mu^*_0$ (0.52) and `prior_std` $\sigma_0$ of its logarithm (0.3), `prior`
    the prior curve's $(c_1, c_2, c_3)$ (default None: `DRY_ASPHALT` scaled to peak at
    $\mu^*_0$), `shapes` the grid of $c_2$ (12 values from 4 to 320), `bins` (static, 32),
    `forgetting` $\gamma$ (0.97), `ridge` (0.1, in samples), `noise_std` $\sigma_\mu$ (0.05),
    `min_slip` (0.02), `min_speed` [m/s] (3), `omega_eps` [rad/s] (0.5), the change
    detector's `change_drift` $\delta$ (5), `change_threshold` $h$ (100; `inf` turns it off)
    and `change_discount` (0.05), `dynamic_loads` (True), `load_substeps` (10), `surface`
    (None or an `AbstractGripField` of peak ratios, e.g. `PeakRatios`), `tire` (the
    `LumpedLuGre2D` through which `scale` is reported) and `reference_speed` [m/s] (20).
    """

    params: HalfCarParams = eqx.field(default_factory=rally_gravel)
    prior_peak: Float[Array, ""] = array_field(default=0.52)
    prior_std: Float[Array, ""] = array_field(default=0.3)
    prior: Float[Array, " 3"] | None = None
    shapes: Float[Array, " G"] = array_field(default_factory=_default_shapes)
    bins: int = eqx.field(static=True, default=32)
    forgetting: Float[Array, ""] = array_field(default=0.97)
    ridge: Float[Array, ""] = array_field(default=0.1)
    noise_std: Float[Array, ""] = array_field(default=0.05)
    min_slip: Float[Array, ""] = array_field(default=0.02)
    min_speed: Float[Array, ""] = array_field(default=3.0)
    omega_eps: Float[Array, ""] = array_field(default=0.5)
    change_drift: Float[Array, ""] = array_field(default=5.0)
    change_threshold: Float[Array, ""] = array_field(default=100.0)
    change_discount: Float[Array, ""] = array_field(default=0.05)
    dynamic_loads: bool = eqx.field(static=True, default=True)
    load_substeps: int = eqx.field(static=True, default=10)
    surface: AbstractGripField | None = None
    tire: LumpedLuGre2D = eqx.field(default_factory=lambda: LumpedLuGre2D(lugre2d_bakker1987()))
    reference_speed: Float[Array, ""] = array_field(default=REFERENCE_SPEED)

    def __post_init__(self):
        if self.prior is None:
            _, mu = burckhardt_peak(*DRY_ASPHALT)
            k = self.prior_peak / mu
            self.prior = jnp.stack([k * DRY_ASPHALT[0], jnp.asarray(DRY_ASPHALT[1]) + 0.0 * k,
                                    k * DRY_ASPHALT[2]])
        else:
            self.prior = jnp.asarray(self.prior, dtype=float)

    def __check_init__(self):
        owner = "AxlePeakEstimator"
        self.check_shared(owner)
        for name in ("prior_peak", "prior_std", "shapes", "ridge", "noise_std", "min_slip"):
            check_positive(owner, name, getattr(self, name))
        check_range(owner, "forgetting", self.forgetting, lower=0.0, upper=1.0,
                    lower_open=True)
        check_range(owner, "change_discount", self.change_discount, lower=0.0, upper=1.0)
        if not isinstance(self.bins, int) or self.bins < 2:
            raise ValueError(f"{owner}.bins must be an integer >= 2, got {self.bins!r}")

    def _member(self, coefficients, error):
        best = jnp.argmin(error)
        c1, c3 = coefficients[best, 0], coefficients[best, 1]
        return c1, self.shapes[best], c3

    def empty_curve(self):
        r"""One axle's curve before any data, as `curve_step` takes it: ``(weight, bin_mu,
        bin_slip, coefficients, error, g)``, the bins empty, every member at the prior's
        $(c_1, c_3)$ (the prior's nearest $c_2$ the best), the change statistic 0."""
        G, B = self.shapes.shape[0], self.bins
        c = jnp.broadcast_to(jnp.stack([self.prior[0], self.prior[2]]), (G, 2))
        error = jnp.abs(jnp.log(self.shapes / self.prior[1])) * 1e-9
        zb = jnp.zeros(B)
        return zb, zb, zb, c, error, jnp.zeros(())

    def init(self, measurement: DriveMeasurement) -> AxlePeakState:
        """`empty_curve` on both axles, the belief the prior's."""
        curve = jax.tree.map(lambda x: jnp.broadcast_to(x, (2, *x.shape)), self.empty_curve())
        z = jnp.zeros(2)
        s_star, _ = burckhardt_peak(*self.prior)
        return AxlePeakState(*curve, jnp.log(self.prior_peak) + z, self.prior_std**2 + z,
                             s_star + z, z, z, measurement, jnp.zeros(4))

    def curve_step(self, weight, bin_mu, bin_slip, coefficients, error, g, mu, slip,
                   informative):
        r"""One axle's sample (module docstring): its curve (`weight`, `bin_mu`, `bin_slip`,
        (B,)), the members' fit (`coefficients` (G, 2), `error` (G,)) and the change
        detector's `g` after the utilised friction `mu` at combined slip `slip`, taken in
        where `informative`; returns those and the belief $\log\hat\mu$, $\sigma^2$ and the
        fitted peak's slip $s^*$."""
        c1, c2, c3 = self._member(coefficients, error)
        e = mu - (c1 * (1.0 - jnp.exp(-c2 * slip)) - c3 * slip)
        g = jnp.maximum(g + jnp.where(informative, e * e / self.noise_std**2
                                      - self.change_drift, 0.0), 0.0)
        changed = g > self.change_threshold
        g = jnp.where(changed, 0.0, g)
        old = jnp.where(changed, self.change_discount, 1.0) * weight
        B = self.bins
        j = jnp.clip(jnp.floor(jnp.sqrt(jnp.clip(slip, 0.0, 1.0)) * B).astype(int), 0, B - 1)
        here = (jnp.arange(B) == j) & informative
        weight = jnp.where(informative, self.forgetting * old, old) + here
        w = jnp.where(here, weight, 1.0)
        bin_mu = jnp.where(here, bin_mu + (mu - bin_mu) / w, bin_mu)
        bin_slip = jnp.where(here, bin_slip + (slip - bin_slip) / w, bin_slip)
        fitted, fit_error = fit_burckhardt(self.shapes, self.prior, self.ridge, weight,
                                           bin_mu, bin_slip)
        coefficients = jnp.where(informative, fitted, coefficients)
        error = jnp.where(informative, fit_error, error)
        s_star, mu_star = burckhardt_peak(*self._member(coefficients, error))
        near = jnp.sum(jnp.where(bin_slip >= 0.7 * s_star, weight, 0.0))
        p0 = 1.0 / self.prior_std**2
        pd = near * (jnp.maximum(mu_star, 1e-3) / self.noise_std) ** 2
        var = 1.0 / (p0 + pd)
        log_peak = var * (p0 * jnp.log(self.prior_peak)
                          + pd * jnp.log(jnp.maximum(mu_star, 1e-3)))
        return weight, bin_mu, bin_slip, coefficients, error, g, log_peak, var, s_star

    def update(self, state: AxlePeakState, m: DriveMeasurement) -> AxlePeakState:
        mu, slip, _, _, susp = self.sample_friction(state.suspension, state.last, m)
        log_r = 0.5 * (self.log_surface(state.last) + self.log_surface(m))
        mu = mu * jnp.exp(-log_r)
        informative = self.measurable(state.last, m) & (slip >= self.min_slip)
        out = jax.vmap(self.curve_step)(state.weight, state.bin_mu, state.bin_slip,
                                   state.coefficients, state.error, state.change_statistic,
                                   mu, slip, informative)
        weight, bin_mu, bin_slip, coefficients, error, g, log_peak, var, s_star = out
        return AxlePeakState(weight, bin_mu, bin_slip, coefficients, error, g, log_peak, var,
                             s_star, jnp.where(informative, mu, 0.0), slip, m, susp)

    def estimate(self, state: AxlePeakState) -> GripEstimate:
        r"""The belief about the road under the axles at the last measurement: the peak
        $\hat\mu$ (with a map, times its $r$ there), and the friction scale of `tire` with
        that peak at `reference_speed`."""
        log_r = self.log_surface(state.last)
        peak = jnp.exp(state.log_peak + log_r)
        std = jnp.sqrt(state.variance)
        scale = jax.vmap(lambda p: scale_of_peak(self.tire, p, self.reference_speed))(peak)
        return GripEstimate(scale, scale * std, peak, peak * std)

    def signals(self, state: AxlePeakState) -> dict:
        """`peak_F`, `peak_R` (the belief $\\hat\\mu$ of the reference surface),
        `log_peak_variance_F`, `_R`, `peak_slip_F`, `_R` (the fit's $s^*$), `mu_used_F`,
        `_R`, `slip_F`, `_R`."""
        out = {}
        for i, axle in enumerate("FR"):
            out[f"peak_{axle}"] = jnp.exp(state.log_peak[i])
            out[f"log_peak_variance_{axle}"] = state.variance[i]
            out[f"peak_slip_{axle}"] = state.peak_slip[i]
            out[f"mu_used_{axle}"] = state.mu_used[i]
            out[f"slip_{axle}"] = state.slip[i]
        return out



class CautiousGripState(eqx.Module):
    """The states of `CautiousGripEstimator`'s two estimators: `model` and `shape_free`."""

    model: AxleGripState
    shape_free: AxlePeakState


class CautiousGripEstimator(AbstractGripEstimator):
    r"""Two beliefs run side by side on the same measurements: `model`, an
    `AxleGripEstimator` (the friction scale of the tire it assumes: exact on that tire's
    family, its peak rising as the speed falls as the LuGre peak does), and `shape_free`, an
    `AxlePeakEstimator` (the peak itself, from the measured curve: no tire assumed, no speed
    dependence). The estimate carries the first's `scale` and `scale_std` and the second's
    `peak` and `peak_std`; `RecedingHorizonDriver(peak_model='cautious')` plans each stage
    with the smaller of the two peaks they give there. On the assumed tire's family the
    model's peak is right and the shape-free one a check on it; on another family the
    model's peak at the corners' speeds can be far above the plant's (the LuGre peak at
    8 m/s is 15 % above its peak at 20 m/s; a Magic Formula's is not), and the shape-free
    one bounds it.

    **Fields:** `model` (default `AxleGripEstimator()`), `shape_free` (default
    `AxlePeakEstimator()`); give them the same map of the road's relative grip, the model
    as scale ratios and the shape-free one as peak ratios (`PeakRatios`; `driver_estimator`
    does)."""

    model: AxleGripEstimator = eqx.field(default_factory=AxleGripEstimator)
    shape_free: AxlePeakEstimator = eqx.field(default_factory=AxlePeakEstimator)

    def __check_init__(self):
        for name, kind in (("model", AxleGripEstimator), ("shape_free", AxlePeakEstimator)):
            if not isinstance(getattr(self, name), kind):
                raise TypeError(f"CautiousGripEstimator.{name} must be a {kind.__name__}, got "
                                f"{type(getattr(self, name)).__name__}")

    @property
    def surface(self) -> AbstractGripField | None:
        """The map of the road's relative grip: the model's."""
        return self.model.surface

    def init(self, measurement: DriveMeasurement) -> CautiousGripState:
        return CautiousGripState(self.model.init(measurement), self.shape_free.init(measurement))

    def update(self, state: CautiousGripState, m: DriveMeasurement) -> CautiousGripState:
        return CautiousGripState(self.model.update(state.model, m),
                                 self.shape_free.update(state.shape_free, m))

    def estimate(self, state: CautiousGripState) -> GripEstimate:
        """The model's `scale`, `scale_std`; the shape-free `peak`, `peak_std`."""
        a = self.model.estimate(state.model)
        b = self.shape_free.estimate(state.shape_free)
        return GripEstimate(a.scale, a.scale_std, b.peak, b.peak_std)

    def signals(self, state: CautiousGripState) -> dict:
        """The model's signals, and the shape-free one's prefixed `free_`."""
        out = dict(self.model.signals(state.model))
        out.update({f"free_{k}": v for k, v in self.shape_free.signals(state.shape_free).items()})
        return out
