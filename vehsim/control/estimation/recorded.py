r"""The road estimated from a recorded braking: the friction observer, the peak estimator or
the moving-horizon estimator run over measured samples instead of the closed loop's sensors.

A `MeasuredBraking` (what was measured; the estimators read it as the `BrakingRecord` of
their sample rate, built here) holds samples at times $t_k$ of the vehicle speed $v$ [m/s], the wheel
speed $\omega$ [rad/s] (NaN where a sample is missing), the brake torque $T_b$ [N m] as it
acted, and optionally the friction force $F_x$ and normal load $F_n$ [N] (kept for the
reader; the estimators' quarter car has the constant load `QuarterCar.Fn_static`).

**Sample rate.** The record must be sampled uniformly (each step within 1 % of the mean
step $h$); it is not resampled, since interpolation would invent wheel-speed measurements
and change their noise. The estimator steps at its hardware's sample time $T$, an integer
multiple $n$ of $h$ (by default $T = h$, `ideal_hardware(sample_time=h)`): it takes every
$n$-th sample of $v$ and $\omega$.

**Brake torque.** No actuator model: the recorded torque is the torque that acted. Over
each of the estimator's samples $[t_j, t_j + T]$ it is held at its mean there, the
trapezoidal rule of the recorded values, so the wheel receives the impulse of the record
interpolated linearly between its samples. The hardware's delay, rate limit and lag must
therefore be off.

**Wheel speed.** Plain samples, not a tone wheel's edge timing: a sample stands for its own
time and is a measurement unless it is NaN. Through a missing sample the observer
predicts (no correction, no adaptation) and the moving-horizon fit leaves its residual out.
The first sample's wheel speed starts the estimators and must be present.

**Estimates.** The observer and the moving-horizon estimator estimate the parameter of
their assumed tire ($\theta$ of a LuGre tire, `RoadCondition`; a friction scale,
`FrictionScale`): right where the record's tire is the assumed one at some value of it, the
best fit of the wrong shape otherwise. The peak estimator assumes no tire and estimates the
peak of the force-slip curve.

**Uncertainty.** The observer's recursive least squares carries the covariance $P$ of
$\vartheta = \log\hat\theta$, in the units its `noise_variance` $R$ sets: with $R$ the
wheel-speed noise's variance, $\operatorname{se}(\hat\theta) = \hat\theta\sqrt P$ (to first
order), and with forgetting it is the error over the recent samples. The moving-horizon
estimator gives Gauss-Newton's standard error per window (`MovingHorizonEstimator`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..._checks import check_count, is_concrete
from ..._fields import array_field
from ..._results import RESULTS
from ...identify.braking import NONNEGATIVE
from ...vehicle.quarter_car import QuarterCar
from ..plant.hardware import BrakeHardware, ideal_hardware
from ..plant.integrate import SUBSTEPS
from ..plant.quarter_car import braking_quarter_car
from .base import AbstractFrictionEstimator, run_estimator
from .mhe import BrakingRecord, MovingHorizonEstimator
from .observer import FrictionObserver
from .peak_estimator import PeakEstimator


UNIFORM_TOLERANCE = 0.01
"""Largest relative deviation of a record's time step from its mean step."""

INFORMED_FRACTION = 0.5
r"""The observer's estimate counts from the first sample at which its covariance $P$ is at
most this fraction of the prior's $P_0$: where the data have carried at least as much
information on $\vartheta$ as the prior ($1/P \ge 2/P_0$). Before, the estimate rests
mostly on the prior, and its result is `not_identifiable`."""


def nonuniform_step(t) -> int | None:
    """The index $k$ of the first sample whose step $t_k - t_{k-1}$ is not positive or
    deviates from the mean step by more than `UNIFORM_TOLERANCE`; None if the sampling is
    uniform."""
    dt = np.diff(np.asarray(t, dtype=float))
    if dt.size == 0:
        return None
    h = (float(t[-1]) - float(t[0])) / dt.size
    bad = ~(dt > 0) | (np.abs(dt - h) > UNIFORM_TOLERANCE * abs(h))
    return int(np.argmax(bad)) + 1 if np.any(bad) else None


class MeasuredBraking(eqx.Module):
    r"""A recorded braking (module docstring): times `t` [s] (uniform), vehicle speed `v`
    [m/s] ($\ge 0$), wheel speed `omega` [rad/s] (NaN where missing), brake torque `torque` [N m]
    ($\ge 0$, as it acted), and optionally the friction force `F_x` and the normal load
    `F_n` [N] (`None` when not recorded). All arrays one-dimensional of one length, at
    least 3 samples."""

    t: Float[Array, " K"] = array_field()
    v: Float[Array, " K"] = array_field()
    omega: Float[Array, " K"] = array_field()
    torque: Float[Array, " K"] = array_field()
    F_x: Float[Array, " K"] | None = eqx.field(default=None, converter=lambda x: x if x is None
                                               else jnp.asarray(x, dtype=float))
    F_n: Float[Array, " K"] | None = eqx.field(default=None, converter=lambda x: x if x is None
                                               else jnp.asarray(x, dtype=float))

    def __check_init__(self):
        owner = "MeasuredBraking"
        named = {n: getattr(self, n) for n in ("t", "v", "omega", "torque", "F_x", "F_n")
                 if getattr(self, n) is not None}
        if not all(is_concrete(a) for a in named.values()):
            return
        K = self.t.shape[0] if self.t.ndim == 1 else -1
        if K < 3:
            raise ValueError(f"{owner}.t must be one-dimensional with at least 3 samples, got "
                             f"shape {self.t.shape}")
        for name, a in named.items():
            if a.shape != (K,):
                raise ValueError(f"{owner}.{name} must have the shape of t, {(K,)}, got "
                                 f"{a.shape}")
            values = np.asarray(a)
            bad = np.isinf(values) if name == "omega" else ~np.isfinite(values)
            if np.any(bad):
                k = int(np.argmax(bad))
                what = "finite or NaN (missing)" if name == "omega" else "finite"
                raise ValueError(f"{owner}.{name} must be {what}, got {values[k]} at sample {k}")
        k = nonuniform_step(self.t)
        if k is not None:
            raise ValueError(f"{owner}.t must be sampled uniformly (steps within "
                             f"{UNIFORM_TOLERANCE:.0%} of the mean, increasing): sample {k} "
                             f"steps by {float(self.t[k] - self.t[k - 1]):g} s against a mean "
                             f"of {self.sample_time:g} s; resample the record first")
        if np.isnan(float(self.omega[0])):
            raise ValueError(f"{owner}.omega: the first sample starts the estimators and must "
                             "be present, got NaN")
        for name, what in (("v", NONNEGATIVE["v"]), ("torque", "a magnitude"),
                           ("F_n", "a magnitude")):
            a = getattr(self, name)
            if a is not None and np.any(np.asarray(a) < 0):
                k = int(np.argmax(np.asarray(a) < 0))
                raise ValueError(f"{owner}.{name} must be >= 0 ({what}), got "
                                 f"{float(a[k])} at sample {k}")

    @property
    def sample_time(self) -> float:
        """The mean step $h$ [s]."""
        return (float(self.t[-1]) - float(self.t[0])) / (self.t.shape[0] - 1)

    def __len__(self) -> int:
        return int(self.t.shape[0])


class FrictionEstimate(eqx.Module):
    r"""The estimate over a recorded braking, at the times `ts` [s] (the estimator's
    samples, or the ends of the moving-horizon windows): the estimate `theta` of the
    assumed tire's parameter ($\theta$, or $\lambda$ for a `FrictionScale`) and its
    standard error `theta_se` (module docstring), or for a `PeakEstimator` (which assumes
    no tire) the estimated peak of the force-slip curve, `peak_slip` ($s^* < 0$) and
    `peak_mu` ($\mu^* > 0$), the fields it lacks `None`; and `result` (a `vehsim.RESULTS`
    item per time: `nonfinite` where a sample-by-sample estimate is not finite; for the
    observer, `not_identifiable` until its covariance first falls to `INFORMED_FRACTION` of
    the prior's (no excitation yet: standing still, rolling without braking, or no wheel
    speed measured); the window's result for the moving-horizon estimator, e.g.
    `not_identifiable`)."""

    ts: Float[Array, " N"]
    result: RESULTS
    theta: Float[Array, " N"] | None = None
    theta_se: Float[Array, " N"] | None = None
    peak_slip: Float[Array, " N"] | None = None
    peak_mu: Float[Array, " N"] | None = None


def _assumed_car(estimator) -> QuarterCar:
    """The scenarios' quarter car with the estimator's tire at its prior (for the
    sample-by-sample estimators, the belief they start from)."""
    if isinstance(estimator, MovingHorizonEstimator):
        tire = estimator.model.belief(estimator.model.prior())
    else:
        tire = estimator.belief(estimator.init(1.0, 1.0))
    return braking_quarter_car(tire)


def estimator_decimation(record_step: float, sample_time: float) -> int:
    """$n$: the estimator steps at every $n$-th sample of a record of step `record_step`
    [s], its `sample_time` [s] in whole record steps (rounded, at least 1)."""
    return max(int(round(sample_time / record_step)), 1)


def estimator_sample_count(samples: int, record_step: float, sample_time: float) -> int:
    """How many samples the estimator steps at in a record of `samples` samples of step
    `record_step` [s] at its `sample_time` [s]: every `estimator_decimation`-th, the first
    included."""
    n = estimator_decimation(record_step, sample_time)
    return -(-samples // n)


def _estimator_samples(record: MeasuredBraking, hardware: BrakeHardware):
    """``(n, indices)``: the decimation and the record's samples the estimator steps at."""
    h = record.sample_time
    T = float(hardware.sample_time)
    n = estimator_decimation(h, T)
    if abs(n * h - T) > UNIFORM_TOLERANCE * h:
        raise ValueError(f"estimate_friction: hardware.sample_time ({T:g} s) must be a whole "
                         f"multiple of the record's step ({h:g} s)")
    indices = np.arange(0, len(record), n)
    if indices.size < 2:
        raise ValueError(f"estimate_friction: the record ({len(record)} samples of {h:g} s) is "
                         f"shorter than one estimator sample of {T:g} s")
    return n, indices


def _mean_torque(record: MeasuredBraking, n: int, indices) -> np.ndarray:
    """The mean over each estimator sample of the linearly interpolated recorded torque
    (trapezoidal rule of the recorded values; the last sample's value for the last)."""
    Tb = np.asarray(record.torque, dtype=float)
    means = np.empty(indices.size)
    for j, i in enumerate(indices[:-1]):
        seg = Tb[i:i + n + 1]
        means[j] = (0.5 * (seg[0] + seg[-1]) + np.sum(seg[1:-1])) / n
    means[-1] = Tb[indices[-1]]
    return means


def _signals(record: MeasuredBraking, hardware: BrakeHardware) -> dict:
    n, idx = _estimator_samples(record, hardware)
    ts = np.asarray(record.t, dtype=float)[idx]
    omega = np.asarray(record.omega, dtype=float)[idx]
    fresh = ~np.isnan(omega)
    filled = omega.copy()  # forward-filled (the first sample is present)
    for k in range(1, filled.size):
        if not fresh[k]:
            filled[k] = filled[k - 1]
    torque = _mean_torque(record, n, idx)
    return dict(ts=ts, torque=torque, target=torque, omega_stamp=ts, omega_meas=filled,
                omega_missing=np.where(fresh, omega, np.inf),
                v_meas=np.asarray(record.v, dtype=float)[idx], fresh=fresh)


def _check_hardware(hardware: BrakeHardware) -> None:
    on = [n for n in ("delay", "rate_limit", "lag") if bool(np.any(getattr(hardware, n)))]
    if on:
        raise ValueError(f"estimate_friction: hardware.{on[0]} must be off: the recorded "
                         "torque is the torque that acted (use ideal_hardware(sample_time=...))")


@eqx.filter_jit
def _run(estimator: AbstractFrictionEstimator, car, hardware, substeps,
         record: BrakingRecord) -> FrictionEstimate:
    """`run_estimator`, the loop's order of updates; the states' estimates."""
    states = run_estimator(estimator, car, hardware, record, substeps)
    if isinstance(estimator, FrictionObserver):
        theta, P = states.theta, states.covariance
        values = dict(theta=theta, theta_se=theta * jnp.sqrt(P))
        # informed from the first sample whose covariance the data have brought to
        # INFORMED_FRACTION of the prior's or below, on
        informed = jnp.cumsum(P <= INFORMED_FRACTION * estimator.initial_covariance) > 0
    else:
        values = dict(peak_slip=states.peak_slip, peak_mu=states.peak_mu)
        informed = jnp.ones(record.ts.shape, dtype=bool)
    ok = jnp.all(jnp.stack([jnp.isfinite(a) for a in values.values()]), axis=0)
    result = jax.vmap(lambda o, i: RESULTS.where(
        o, RESULTS.where(i, RESULTS.successful, RESULTS.not_identifiable),
        RESULTS.nonfinite))(ok, informed)
    return FrictionEstimate(record.ts, result, **values)


def estimate_friction(record: MeasuredBraking,
                      estimator: FrictionObserver | MovingHorizonEstimator | PeakEstimator,
                      car: QuarterCar | None = None, hardware: BrakeHardware | None = None,
                      *, stride: int | None = None, substeps: int = SUBSTEPS
                      ) -> FrictionEstimate:
    r"""Estimate the road condition $\theta$ over a recorded braking (module docstring).

    **Arguments:**

    - `record`: a `MeasuredBraking`.
    - `estimator`: a `FrictionObserver` or a `PeakEstimator` (updated at every sample, as
      in the loop: `AbstractFrictionEstimator.update`), or a `MovingHorizonEstimator`
      (windows ending every `stride` samples, `MovingHorizonEstimator.estimate`).
    - `car`: the `QuarterCar` of the record (mass, inertia, radius, `Fn_static`; its tire
      is replaced by the estimator's belief); default `braking_quarter_car`.
    - `hardware`: its `sample_time` is the estimator's step, a whole multiple of the
      record's; delay, rate limit and lag off. Default `ideal_hardware` at the record's step.
    - `stride`: samples between the ends of consecutive moving-horizon windows (default
      half a window); the last window ends at the last sample.
    - `substeps`: integration steps of the estimator's model per sample.

    **Returns:** a `FrictionEstimate`.
    """
    if not isinstance(estimator, AbstractFrictionEstimator | MovingHorizonEstimator):
        raise TypeError(f"estimate_friction: estimator must be a FrictionObserver, a "
                        f"PeakEstimator or a MovingHorizonEstimator, got "
                        f"{type(estimator).__name__}")
    check_count("estimate_friction", "substeps", substeps, sep=": ")
    if stride is not None:
        check_count("estimate_friction", "stride", stride, sep=": ")
    car = _assumed_car(estimator) if car is None else car
    hardware = ideal_hardware(sample_time=record.sample_time) if hardware is None else hardware
    _check_hardware(hardware)
    s = _signals(record, hardware)
    if not isinstance(estimator, MovingHorizonEstimator):
        # a missing wheel speed is no measurement and bounds nothing: +inf (the loop's
        # samples without a tone-wheel edge carry a bound instead)
        s["omega_meas"] = s.pop("omega_missing")
        return _run(estimator, car, hardware, int(substeps), BrakingRecord.from_signals(s))
    N = s["ts"].size
    stride = max(estimator.window // 2, 1) if stride is None else int(stride)
    if N <= estimator.window:
        raise ValueError(f"estimate_friction: the record has {N} estimator samples, fewer than "
                         f"one window of {estimator.window} + 1")
    ends = np.arange(N - 1, estimator.window - 1, -stride)[::-1]
    out = estimator.estimate(car, hardware, s, ends)
    return FrictionEstimate(out.ts, out.result, theta=out.theta, theta_se=out.theta_se)
