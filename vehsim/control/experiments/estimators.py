r"""Estimators against the tire they assume: a braking from dry to slippery on a tire that is
not the estimators' default.

The plant is the lumped LuGre tire with a constant $\kappa_0$ (`LumpedLuGre`, eqs. 22-23
with eq. 25; 2 by default, the report's upper value) with the report's Table 3 parameters
(`vehsim.tire.params.table3`) on a dry road ($\theta$ = 1) changing to a slippery one
($\theta$ = 2.5, the most slippery of Fig. 7b) at a fixed distance; the braking is recorded
under the rule-based ABS (which reads no estimate, so every estimator sees the same record
and replays exactly as it would run in the loop, `run_estimator`). Each estimator assuming
(a) the default `UniformLumpedLuGre` tire (the steady state of eq. 19, $\kappa_0$ from 2 at
small slip to 1 locked) and (b) the plant's structure (`LumpedLuGre` with the plant's
$\kappa_0$) estimates $\theta$; the shape-free `PeakEstimator` estimates the peak. Measured:
the relative bias on the dry part (the median of estimate/truth - 1 once the braking is
under way) and, after the change, the settling time to within `tol` of the truth and the
bias from then on (`settling`).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..._results import RESULTS
from ...tire.lugre import LuGreParams, LumpedLuGre
from ...tire.params import table3
from ...tire.uniform_lumped import UniformLumpedLuGre
from ..controllers.braking import RuleBasedABS
from ..estimation.base import run_estimator
from ..estimation.mhe import BrakingRecord, MovingHorizonEstimator
from ..estimation.observer import FrictionObserver
from ..estimation.parametrisation import RoadCondition
from ..estimation.peak_estimator import PeakEstimator
from ..loop import simulate_braking
from ..plant.hardware import BrakeHardware
from ..plant.quarter_car import BrakingScenario, SurfaceChange, braking_quarter_car
from ..road.peak import peak_braking
from .metrics import settling
from .scenarios import true_theta


def constant_kappa_scenario(params: LuGreParams | None = None, theta_then: float = 2.5,
                            kappa0=2.0, speed: float = 30.0, change_distance: float = 30.0):
    """The braking of the module docstring: the `LumpedLuGre` tire with `kappa0` and
    `params` (default Table 3's, at their $\\theta$), changing to $\\theta$ = `theta_then` at
    `change_distance` [m], from `speed` [m/s]."""
    params = table3() if params is None else params
    slippery = eqx.tree_at(lambda p: p.theta, params, jnp.asarray(theta_then, dtype=float))
    change = SurfaceChange(LumpedLuGre(slippery, kappa0=kappa0), distance=change_distance)
    return BrakingScenario(braking_quarter_car(LumpedLuGre(params, kappa0=kappa0)), speed,
                           change)


def assumed_models(params: LuGreParams | None = None, kappa0=2.0) -> dict:
    """The two `RoadCondition` models of the estimators, at the prior `params` (default
    Table 3's, $\\theta$ = 1: the dry road): the default ``"uniform"`` (`UniformLumpedLuGre`)
    and the plant's ``"constant_kappa"`` (`LumpedLuGre` with `kappa0`)."""
    params = table3() if params is None else params
    return {"uniform": RoadCondition(UniformLumpedLuGre(params)),
            "constant_kappa": RoadCondition(LumpedLuGre(params, kappa0=kappa0))}


def _measures(ts, estimate, truth, t_from, t_change, t_end, tol):
    ts, est, tru = (np.asarray(a, dtype=float) for a in (ts, estimate, truth))
    dry = (ts >= t_from) & (ts < t_change - 0.05)
    bias = float(np.median(est[dry] / tru[dry] - 1.0)) if dry.any() else math.nan
    settle, after = settling(ts, est, tru, t_change, t_end, tol)
    return {"bias_dry": bias, "settling_time_s": settle, "bias_after": after}


def compare_estimators(scenario: BrakingScenario, hardware: BrakeHardware, models: dict,
                       theta_range=(0.3, 40.0), key=None, duration: float = 3.0,
                       t_from: float = 0.3, mhe_stride: int = 8, tol: float = 0.1) -> dict:
    r"""The table of the module docstring for one record of `scenario` under `hardware`.

    **Arguments:** `models` (name: `RoadCondition`, e.g. `assumed_models`), `theta_range`
    (the estimators' projection range of $\theta$), `key` (sensor noise),
    `duration` [s], `t_from` [s] (the dry part's start), `mhe_stride` (samples between
    windows), `tol` (the settling tolerance, relative).

    **Returns:** ``{(estimator, model): {"bias_dry", "settling_time_s", "bias_after"}}``
    for the estimators ``"observer"`` and ``"mhe"`` (of $\theta$) under each model and
    ``("peak", "shape_free")`` (of the peak friction $\mu^*$; its peak slip's bias as
    ``"slip_bias_dry"``), and ``"change_time_s"``.
    """
    lo, hi = theta_range
    run = simulate_braking(scenario, RuleBasedABS(),
                           FrictionObserver(models[next(iter(models))], theta_min=lo,
                                            theta_max=hi),
                           hardware, key, duration=duration)
    s = {k: np.asarray(v) for k, v in run.signals.items()}
    record = BrakingRecord.from_signals(s)
    ts, x, v = s["ts"], s["x"], s["v"]
    moving = v > 3.0
    t_end = float(ts[moving][-1]) if moving.any() else float(ts[-1])
    crossed = x >= float(scenario.change.distance)
    t_change = float(ts[crossed][0]) if crossed.any() else math.inf
    theta = np.asarray(true_theta(scenario, ts, x))
    car = scenario.car
    out = {"change_time_s": t_change}
    for name, model in models.items():
        ob = FrictionObserver(model, theta_min=lo, theta_max=hi)
        states = _replay(ob, car, hardware, record)
        out[("observer", name)] = _measures(ts, np.exp(np.asarray(states.log_theta)), theta,
                                            t_from, t_change, t_end, tol)
        mhe = MovingHorizonEstimator(model, lo, hi)
        ends = np.arange(mhe.window, ts.shape[0], mhe_stride)
        res = mhe.estimate(car, hardware, record, ends)
        ok = np.asarray(res.result == RESULTS.successful)
        out[("mhe", name)] = _measures(np.asarray(res.ts)[ok], np.asarray(res.theta)[ok],
                                       theta[ends][ok], t_from, t_change, t_end, tol)
    pe = PeakEstimator()
    states = _replay(pe, car, hardware, record)
    truth_slip, truth_mu = (np.asarray(a) for a in _true_peaks(scenario, ts, x, v))
    rec = _measures(ts, np.asarray(states.peak_mu), truth_mu, t_from, t_change, t_end, tol)
    slip = _measures(ts, np.asarray(states.peak_slip), truth_slip, t_from, t_change, t_end, tol)
    out[("peak", "shape_free")] = rec | {"slip_bias_dry": slip["bias_dry"]}
    return out


_replay = eqx.filter_jit(run_estimator)


@eqx.filter_jit
def _true_peaks(scenario, ts, x, v):
    def one(t, xx, vv):
        return peak_braking(scenario.tire_at(t, xx, vv), jnp.maximum(vv, 0.5),
                            scenario.car.radius)

    return jax.vmap(one)(ts, x, v)
