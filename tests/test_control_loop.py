"""The closed braking loop: the rule-based ABS cycling without locking, the observer
converging, the moving-horizon estimator recovering theta, and the gradient of a stopping
distance with respect to a gain against finite differences. One compiled program serves the
loop's tests: the forward-mode derivative of a grid (two roads x two controllers) with
respect to the estimate-based controller's log K_p, which returns the runs too; it is called
with three hardware settings and three gains (array fields: no recompilation). The
controllers regulate down to 0.5 m/s (no hand-back before the stop, whose switch would make
the distance jump). The distances against the limits, on every named surface and from a
prior far from the road, are in tests/test_control_tires.py."""

import functools
import os
import pathlib
import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim._results import RESULTS
from vehsim.control.controllers.braking import BUILD, DUMP, REBUILD, PeakSlipTracking, RuleBasedABS
from vehsim.control.estimation.mhe import MovingHorizonEstimator
from vehsim.control.experiments.scenarios import braking_scenario
from vehsim.control.loop import closed_loop_grid, stack
from vehsim.control.plant.hardware import realistic_hardware
from vehsim.control.road.surfaces import surface


ROOT = pathlib.Path(__file__).resolve().parents[1]
ROADS = ("dry_asphalt", "snow")
N_STEPS = 540  # 2.7 s at 200 Hz: dry asphalt stops from 30 m/s in 2.6 s


@functools.cache
def _scenarios():
    return [braking_scenario(r, 30.0) for r in ROADS]


HARDWARE = {"realistic": realistic_hardware(), "noise-free": realistic_hardware(noise=False),
            "ideal sensors": realistic_hardware(noise=False, encoder=False)}


@functools.cache
def _program():
    pairs = _scenarios()
    scenarios, observers = stack([p[0] for p in pairs]), stack([p[1] for p in pairs])
    keys = jax.random.split(jax.random.PRNGKey(0), len(pairs))

    def runs(log_kp, hw):
        estimate = PeakSlipTracking(kp=jnp.exp(log_kp))
        return closed_loop_grid(scenarios, [RuleBasedABS(), estimate], observers, hw, keys,
                                N_STEPS, save=True, handback_speed=0.5)

    return eqx.filter_jit(lambda g, hw: jax.jvp(lambda x: runs(x, hw), (g,), (jnp.ones(()),)))


LOG_KP = float(np.log(PeakSlipTracking().kp))


@functools.cache
def _runs(label, log_kp=LOG_KP):
    return _program()(jnp.asarray(log_kp), HARDWARE[label])


def _run(label, controller, road):
    return jax.tree_util.tree_map(lambda a: np.asarray(a[controller, road]), _runs(label)[0])


@pytest.mark.parametrize("road", [0, 1])
def test_rule_based_abs_cycles_and_never_locks_above_5_m_s(road):
    # locked: slip -1 (the wheel creeps at ~1e-3 of the speed); the cycles on dry asphalt,
    # whose curve falls slowly past its peak, reach -0.94
    s = _run("realistic", 0, road).signals
    moving = s["v"] > 5.0
    phase = s["phase"][moving]
    dumps = np.sum((phase[1:] == DUMP) & (phase[:-1] != DUMP))
    builds = np.sum(np.isin(phase[1:], (BUILD, REBUILD)) & ~np.isin(phase[:-1], (BUILD, REBUILD)))
    assert dumps >= 3 and builds >= 3  # the pressure phases alternate
    assert np.min(s["slip"][moving]) > -0.98  # the wheel turns at 2 % of the speed at least


def test_observer_converges_to_theta_on_a_noise_free_braking():
    # snow from the dry-asphalt prior: within 1 % of the truth from 0.5 s on
    s = _run("noise-free", 1, 1).signals
    theta = float(surface("snow").params.theta)
    late = (s["ts"] >= 0.5) & (s["v"] > 3.0)
    assert abs(np.log(s["theta_hat"][0] / theta)) > 1.5  # far off at the start
    np.testing.assert_allclose(s["theta_hat"][late], theta, rtol=0.01)


@functools.cache
def _mhe():
    srf = surface("snow")
    mhe = MovingHorizonEstimator(srf.with_theta(srf.prior_theta), *srf.theta_range, starts=3)
    return mhe, eqx.filter_jit(mhe.fit_window)


def _window(signals, end, n):
    names = ("ts", "torque", "target", "omega_stamp", "omega_meas", "v_meas", "fresh")
    return {k: jnp.asarray(signals[k][end - n:end + 1]) for k in names}


def test_moving_horizon_estimate_recovers_theta_on_noise_free_lumped_data():
    mhe, fit = _mhe()
    s = _run("ideal sensors", 1, 1).signals
    car, hw = _scenarios()[1][0].car, HARDWARE["ideal sensors"]
    theta, se, cost, result = fit(car, hw, _window(s, 100, mhe.window))
    assert result == RESULTS.successful
    assert float(theta) == pytest.approx(float(surface("snow").params.theta), rel=1e-3)
    assert float(cost) < 1e-6


def _rolling_window(n, v=20.0, T=0.005):
    """A window of free rolling at `v` [m/s]: no braking, no slip."""
    ts = jnp.asarray(T * np.arange(n))  # strongly typed, as a run's signals: no recompile
    return dict(ts=ts, torque=jnp.zeros(n), target=jnp.zeros(n), omega_stamp=ts,
                omega_meas=jnp.asarray(np.full(n, v / 0.3)), v_meas=jnp.asarray(np.full(n, v)),
                fresh=jnp.ones(n, bool))


def test_moving_horizon_estimate_refuses_a_window_without_braking():
    mhe, fit = _mhe()
    result = fit(_scenarios()[1][0].car, realistic_hardware(), _rolling_window(mhe.window + 1))[3]
    assert result == RESULTS.not_identifiable


def test_moving_horizon_estimate_reports_the_solver_failure_it_met():
    # a non-finite speed at the window's start makes every start's initial guess non-finite:
    # Levenberg-Marquardt stops with `nonfinite`, which the window returns (not "ran out of
    # steps", nor "not identifiable" from a Jacobian of NaNs)
    mhe, fit = _mhe()
    data = _rolling_window(mhe.window + 1)
    data["v_meas"] = data["v_meas"].at[0].set(jnp.nan)
    result = fit(_scenarios()[1][0].car, realistic_hardware(), data)[3]
    assert result == RESULTS.nonfinite


def test_stopping_distance_gradient_matches_finite_differences():
    # d(stopping distance)/d(log K_p) of the estimate-based ABS on dry asphalt, ideal sensors
    ad = float(_runs("ideal sensors")[1].stopping_distance[1, 0])
    h = 1e-3
    up, down = (float(_runs("ideal sensors", LOG_KP + d)[0].stopping_distance[1, 0])
                for d in (h, -h))
    assert np.isfinite(ad) and abs(ad) > 1e-3
    assert ad == pytest.approx((up - down) / (2 * h), rel=2e-3)


OBSERVER_STEP = """
import jax, jax.numpy as jnp, equinox as eqx
from vehsim.control.plant.hardware import ideal_hardware
from vehsim.control.experiments.scenarios import braking_scenario
scenario, observer = braking_scenario("snow", 30.0)  # the dry-asphalt prior: far off
v, omega = jnp.asarray(28.0), jnp.asarray(28.0 / 0.3 * 0.95)
state = observer.init(omega, v)
state = eqx.tree_at(lambda s: s.sensitivity, state, jnp.asarray([-0.5, 0.0, 0.0]))
hw, torque = ideal_hardware(), jnp.asarray(600.0)
new = eqx.filter_jit(lambda st, c, h, *a: observer.update(st, c, h, 8, *a))(
    state, scenario.car, hw, v, omega - 0.02, hw.sample_time, jnp.asarray(True), torque,
    torque, jnp.asarray(0.0))
step = new.log_theta - state.log_theta
print(step.dtype, float(step), float(new.covariance))
"""


def test_observer_step_is_the_same_in_float32_as_in_float64(capsys):
    # the regressor is a forward-mode derivative: a finite difference of wheel speeds near
    # 90 rad/s would cancel to nothing in float32 and the estimate would never move. The
    # same update (a wheel 0.02 rad/s slower than the copy starts) here in float64 and in a
    # process in JAX's default float32
    exec(OBSERVER_STEP, {})
    dtype64, step64, cov64 = capsys.readouterr().out.split()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    env.pop("JAX_ENABLE_X64", None)
    out = subprocess.run([sys.executable, "-c", OBSERVER_STEP], env=env, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    dtype32, step32, cov32 = out.stdout.split()
    assert (dtype32, dtype64) == ("float32", "float64")
    # a slower wheel than predicted: a more slippery road; the covariance (1 at the start,
    # forgetting 0.98) shrinks by what the sample told
    assert float(step64) > 1e-3 and float(cov64) < 0.9
    assert float(step32) == pytest.approx(float(step64), rel=1e-3)
    assert float(cov32) == pytest.approx(float(cov64), rel=1e-3)


@functools.cache
def _after_change():
    """Snow to dry asphalt at 20 m from 30 m/s, the estimate-based ABS on noise-free
    hardware, the observer with its change detector and without it."""
    scenario, observer = braking_scenario("snow", 30.0, "dry_asphalt", 20.0)
    observers = stack([observer, eqx.tree_at(lambda o: o.change_threshold, observer,
                                             jnp.asarray(jnp.inf))])
    runs = eqx.filter_jit(closed_loop_grid)(
        stack([scenario] * 2), [PeakSlipTracking()], observers, HARDWARE["noise-free"],
        jax.random.split(jax.random.PRNGKey(0), 2), N_STEPS, save=True, handback_speed=0.5)
    theta = float(surface("dry_asphalt").params.theta)
    return [jax.tree_util.tree_map(lambda a: np.asarray(a[0, i]), runs) for i in (0, 1)], theta


def test_change_detector_lets_the_estimate_leave_the_old_road_at_once():
    (on, off), theta = _after_change()
    settle = []
    for run in (on, off):
        s = run.signals
        t_change = s["ts"][np.argmax(s["x"] >= 20.0)]
        t, est = s["ts"], s["theta_hat"]
        window = (t >= t_change) & (s["v"] > 3.0)
        outside = window & (np.abs(est / theta - 1.0) > 0.05)
        settle.append(t[outside][-1] - t_change)
    assert settle[0] < 0.15  # with the detector: within 5 % in a few samples
    assert settle[1] > 2.0 * settle[0]  # without it, at the pace of forgetting
