r"""What a braking is judged by: its distance against the physical limit, and how fast and
how truly an estimate of $\theta$ settles.

- `braking_record`: ``stopping_distance_m`` and ``stopping_time_s`` (until the speed falls
  below `STOP_SPEED`), ``bound_distance_m`` and ``bound_time_s`` (`physical_limit`), and
  ``distance_over_bound`` = stopping distance / bound distance ($\ge 1$ up to the limit's
  quadrature and the plant's transients); given the hardware, also
  ``actuated_bound_distance_m`` (`actuated_limit`: the same limit with the brake torque's
  rise on that hardware) and ``distance_over_actuated_bound``.
- `settling`: the time from ``t_from`` after which the estimate stays within ``tol`` (5 %)
  of the truth up to ``t_to`` (the time of its first sample if it never leaves), and its
  bias (mean relative error) from then on; `inf` and the bias over the whole window when
  it never settles.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..loop import BrakingRun
from ..plant.hardware import BrakeHardware
from ..plant.quarter_car import BrakingScenario
from ..road.bound import actuated_limit, physical_limit
from ..road.peak import peak_braking


def braking_record(run: BrakingRun, scenario: BrakingScenario,
                   hardware: BrakeHardware | None = None) -> dict[str, float]:
    """The distances and times of a run beside its physical limit, and beside the limit on
    `hardware` if given (module docstring)."""
    bound_distance, bound_time = (float(v) for v in physical_limit(scenario))
    distance = float(run.stopping_distance)
    record = {
        "stopping_distance_m": distance,
        "stopping_time_s": float(run.stopping_time),
        "bound_distance_m": bound_distance,
        "bound_time_s": bound_time,
        "distance_over_bound": distance / bound_distance,
    }
    if hardware is not None:
        actuated = float(actuated_limit(scenario, hardware)[0])
        record |= {"actuated_bound_distance_m": actuated,
                   "distance_over_actuated_bound": distance / actuated}
    return record


def settling(ts, estimate, truth, t_from: float, t_to: float, tol: float = 0.05):
    """``(settling time [s] after t_from, bias)`` of `estimate` against `truth` on the
    samples in [t_from, t_to] (module docstring)."""
    ts, est, tru = (np.asarray(a, dtype=float) for a in (ts, estimate, truth))
    window = (ts >= t_from) & (ts <= t_to)
    ts, rel = ts[window], est[window] / tru[window] - 1.0
    if ts.size == 0:
        return math.inf, math.nan
    outside = np.nonzero(np.abs(rel) > tol)[0]
    if outside.size == 0:
        return float(ts[0] - t_from), float(np.mean(rel))
    last = outside[-1]
    if last == ts.size - 1:
        return math.inf, float(np.mean(rel))
    return float(ts[last + 1] - t_from), float(np.mean(rel[last + 1:]))


@functools.cache
def _available():
    def fn(scenario, ts, x, v):
        def one(t, xx, vv):
            return peak_braking(scenario.tire_at(t, xx, vv), jnp.maximum(vv, 0.5),
                                scenario.car.radius)

        return jax.vmap(one)(ts, x, v)

    return eqx.filter_jit(fn)


def available_friction(scenario: BrakingScenario, signals: dict):
    """``(peak slip, peak |mu|)`` of the true surface at each saved sample: what the tire
    could deliver at the current speed (the physical limit's integrand)."""
    ts, x, v = (jnp.asarray(signals[k]) for k in ("ts", "x", "v"))
    return tuple(np.asarray(a) for a in _available()(scenario, ts, x, v))


def estimate_record(ts, theta_hat, theta_true, t_from: float, t_to: float) -> dict:
    """The settling time and bias of an estimate (`settling`; NaN where the truth is NaN
    throughout), with the final estimate."""
    if np.all(np.isnan(np.asarray(theta_true, dtype=float))):  # no truth to settle on
        t_settle, bias = math.nan, math.nan
    else:
        t_settle, bias = settling(ts, theta_hat, theta_true, t_from, t_to)
    ts = np.asarray(ts)
    last = np.nonzero(ts <= t_to)[0]
    return {"theta_settling_time_s": t_settle, "theta_bias": bias,
            "theta_estimate": float(np.asarray(theta_hat)[last[-1]]) if last.size else math.nan}
