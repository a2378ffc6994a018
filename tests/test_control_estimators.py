"""Estimators over the tire they assume, and the shape-free peak estimator.

One braking record of a lumped LuGre plant with a constant kappa0 = 2 and the report's Table
3 parameters (not the estimators' default uniform-load tire, whose kappa0 runs from 2 at
small slip to 1 locked), and one of a relaxed Magic Formula plant on the dry-asphalt
quarter car, each under the rule-based ABS (which reads no estimate: every estimator replays the same record
exactly as it would run in the loop) with ideal sensors. The estimators assuming the plant's
structure recover its parameter; the default one is biased, and the difference is the point.
"""

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs
from vehsim._results import RESULTS
from vehsim.control.controllers.braking import Measurement, PeakSlipTracking, RuleBasedABS
from vehsim.control.estimation.base import run_estimator
from vehsim.control.estimation.mhe import BrakingRecord, MovingHorizonEstimator
from vehsim.control.estimation.observer import FrictionObserver
from vehsim.control.estimation.parametrisation import (
    FrictionScale,
    RoadCondition,
    steady_state,
)
from vehsim.control.estimation.peak_estimator import PeakEstimator, burckhardt_peak
from vehsim.control.experiments.scenarios import braking_scenario
from vehsim.control.loop import simulate_braking
from vehsim.control.plant.hardware import ideal_hardware
from vehsim.control.road.peak import braking_curve, peak_braking
from vehsim.control.road.surfaces import surface
from vehsim.tire.magic_formula import magic_formula
from vehsim.tire.params import table3
from vehsim.tire.scaled import ScaledFriction


KAPPA0 = 2.0
THETA_RANGE = (0.3, 40.0)
HARDWARE = ideal_hardware()
DURATION = 1.0  # 200 samples: from 30 m/s on dry asphalt, well before the stop
MF_PLANT = vs.MagicFormulaParams(D=0.8)


def _record(tire):
    scenario, observer = braking_scenario("dry_asphalt", 30.0, tire=tire)
    run = simulate_braking(scenario, RuleBasedABS(), observer, HARDWARE, duration=DURATION)
    return scenario, {k: np.asarray(v) for k, v in run.signals.items()}


@functools.cache
def _lugre_record():
    return _record(vs.LumpedLuGre(table3(), kappa0=KAPPA0))


@functools.cache
def _mf_record():
    return _record(vs.RelaxedMagicFormula(MF_PLANT))


def _models():
    return {"uniform": RoadCondition(vs.UniformLumpedLuGre(table3())),
            "constant_kappa": RoadCondition(vs.LumpedLuGre(table3(), kappa0=KAPPA0))}


_replay = eqx.filter_jit(run_estimator)


@functools.cache
def _observer_estimates():
    scenario, s = _lugre_record()
    lo, hi = THETA_RANGE
    record = BrakingRecord.from_signals(s)
    late = s["ts"] >= 0.5
    return {name: np.exp(np.asarray(_replay(FrictionObserver(m, theta_min=lo, theta_max=hi),
                                            scenario.car, HARDWARE, record).log_theta))[late]
            for name, m in _models().items()}


def test_observer_assuming_the_plants_structure_is_unbiased_where_the_default_is_not():
    theta = 1.0  # Table 3's
    est = _observer_estimates()
    right = np.median(est["constant_kappa"]) / theta - 1.0
    default = np.median(est["uniform"]) / theta - 1.0
    assert abs(right) < 0.01
    assert np.max(np.abs(est["constant_kappa"] / theta - 1.0)) < 0.02
    assert default > 0.04  # the uniform-load tire reads the road more slippery than it is


@functools.cache
def _mhe_fits():
    scenario, s = _lugre_record()
    lo, hi = THETA_RANGE
    record = BrakingRecord.from_signals(s)
    ends = np.asarray([199])
    return {name: MovingHorizonEstimator(m, lo, hi, starts=2).estimate(scenario.car, HARDWARE,
                                                                          record, ends)
            for name, m in _models().items()}


def test_moving_horizon_estimator_assuming_the_plants_structure_is_unbiased():
    theta = 1.0
    fits = _mhe_fits()
    right, default = fits["constant_kappa"], fits["uniform"]
    assert np.all(np.asarray(right.result == RESULTS.successful))
    np.testing.assert_allclose(np.asarray(right.theta), theta, rtol=1e-3)
    assert np.all(np.asarray(default.theta) / theta - 1.0 > 0.05)
    assert right.values.shape == (1, 1)


def test_friction_scale_observer_recovers_the_scale_of_a_magic_formula_road():
    scenario, s = _mf_record()
    shape = vs.RelaxedMagicFormula(vs.MagicFormulaParams(D=1.0))
    ob = FrictionObserver(FrictionScale(shape), theta_min=0.1, theta_max=3.0)
    states = _replay(ob, scenario.car, HARDWARE, BrakingRecord.from_signals(s))
    late = s["ts"] >= 0.5
    np.testing.assert_allclose(np.exp(np.asarray(states.log_theta))[late], 0.8, rtol=0.01)


@functools.cache
def _peaks(which):
    scenario, s = _lugre_record() if which == "lugre" else _mf_record()
    record = BrakingRecord.from_signals(s)
    return scenario, s, _replay(PeakEstimator(), scenario.car, HARDWARE, record)


@pytest.mark.parametrize("which", ["lugre", "mf"])
def test_peak_estimator_finds_the_peak_of_curves_of_different_shapes(which):
    # once the ABS has swept through the peak (from 0.5 s): the estimated peak friction
    # within 5 % of the true curve's at the true speed, and the true curve at the estimated
    # peak slip within 5 % of its peak (the Table 3 curve is flat-topped: its peak slip
    # itself is ill-determined, -0.51 where -0.33 gives 99 % of the peak); the Magic
    # Formula's sharp peak slip within 30 %
    scenario, s, states = _peaks(which)
    late = s["ts"] >= 0.5
    v, tire, r = s["v"][late], scenario.car.tire, scenario.car.radius
    s_true, mu_true = (np.asarray(a) for a in jax.vmap(lambda vv: peak_braking(tire, vv, r))(v))
    slip, mu = np.asarray(states.peak_slip)[late], np.asarray(states.peak_mu)[late]
    np.testing.assert_allclose(mu, mu_true, rtol=0.05)
    at_slip = -np.asarray(jax.vmap(lambda ss, vv: braking_curve(tire, ss, vv, r))(slip, v))
    assert np.all(at_slip >= 0.95 * mu_true)
    if which == "mf":
        np.testing.assert_allclose(slip, s_true, rtol=0.3)


def test_peak_estimator_holds_on_a_locked_wheel():
    # the tone wheel of a locked wheel sends no edges: from sample 100 on nothing is fresh
    # and the measured wheel speed is frozen; the estimate must hold, not drift, and the
    # speed estimate go on decelerating with the last friction measured (without it, it
    # ran 0.6-0.9 m/s above the true speed)
    scenario, s, _ = _peaks("lugre")
    k = 100
    locked = dict(s, fresh=np.where(np.arange(len(s["ts"])) >= k, False, s["fresh"]),
                  omega_meas=np.where(np.arange(len(s["ts"])) >= k, s["omega_meas"][k - 1],
                                      s["omega_meas"]))
    states = _replay(PeakEstimator(), scenario.car, HARDWARE, BrakingRecord.from_signals(locked))
    for name in ("peak_slip", "peak_mu", "coefficients"):
        a = np.asarray(getattr(states, name))
        assert np.all(np.isfinite(a))
        np.testing.assert_array_equal(a[k:], np.broadcast_to(a[k - 1], a[k:].shape))
    np.testing.assert_allclose(np.asarray(states.v)[k:], s["v"][k:], atol=0.05)


def test_steady_state_of_a_point_tire_at_zero_slip_is_the_undeflected_state():
    # every state of a point LuGre tire is steady at zero relative velocity (its rates do
    # not depend on it there): the undeflected one, finite with finite derivatives, as the
    # moving-horizon estimator's first guess of a free-rolling window; elsewhere the state
    # where the rates vanish
    tire, r = vs.PointLuGre(table3()), 0.3
    z = lambda v, omega: steady_state(tire, v, omega, r)  # noqa: E731
    assert float(z(20.0, 20.0 / r)) == 0.0
    g = jax.grad(z, argnums=(0, 1))(20.0, 20.0 / r)
    assert np.all(np.isfinite(np.asarray(g)))  # (the steady state jumps there: g/sigma0 sgn v_r)
    zb = z(20.0, 0.9 * 20.0 / r)
    assert float(zb) != 0.0
    assert abs(float(tire.dynamics(zb, 20.0, 0.9 * 20.0 / r, r))) < 1e-12


@pytest.mark.filterwarnings("ignore:Explicitly requested dtype float64")
def test_moving_horizon_jacobian_in_float32_is_the_float64_one():
    # the forward-difference step of the window's Jacobian: 1e-7 in float64; in float32,
    # where 1e-7 is below the rounding, its square root of eps (with 1e-7 the float32
    # column was noise, multiples of the rounding step: -763 where -60)
    from vehsim.control.plant.quarter_car import braking_quarter_car

    def column():
        srf = surface("dry_asphalt")
        car, N = braking_quarter_car(srf.tire()), 6
        ts = jnp.arange(N + 1) * 0.005
        v = 20.0 - 8.0 * ts
        record = BrakingRecord(ts, jnp.full(N + 1, 1200.0), jnp.full(N + 1, 1200.0), ts,
                               0.85 * v / 0.3, v, jnp.ones(N + 1, bool))
        mhe = MovingHorizonEstimator(srf.params, window=N)
        u = mhe.initial_guess(car, record, 0.8)
        _, J = mhe._residuals_and_jacobian(u, car, ideal_hardware(), record)
        return np.asarray(J[:N, 0]), u.dtype

    exact, dtype = column()
    with jax.enable_x64(False):
        single, single_dtype = column()
    assert (dtype, single_dtype) == (np.float64, np.float32)
    assert np.all(np.abs(exact) > 50.0)
    np.testing.assert_allclose(single, exact, rtol=0.01)


def test_moving_horizon_cost_and_error_count_only_the_observations():
    # a window whose tone wheel sent an edge only every other sample: its wheel rows without
    # an edge are zeros, not observations. The cost is the mean square over the speed rows
    # and the fresh wheel rows, and s^2 of the standard error their sum of squares over
    # their number less the unknowns (counting the zeros made both smaller)
    from vehsim.control.plant.quarter_car import braking_quarter_car

    srf = surface("dry_asphalt")
    car, N, hw = braking_quarter_car(srf.tire()), 8, ideal_hardware()
    k = jnp.arange(N + 1)
    ts = k * 0.005
    v = 20.0 - 8.0 * ts + 0.01 * jnp.sin(7.0 * k)
    omega = 0.85 * (20.0 - 8.0 * ts) / 0.3 + 0.05 * jnp.cos(5.0 * k)
    record = BrakingRecord(ts, jnp.full(N + 1, 1200.0), jnp.full(N + 1, 1200.0), ts, omega, v,
                           k % 2 == 0)
    mhe = MovingHorizonEstimator(srf.params, window=N)
    theta, se, cost, _, _, u = mhe._fit(car, hw, record)
    r, J = mhe._residuals_and_jacobian(u, car, hw, record)
    n_obs = N + N // 2
    assert r.shape[0] == 2 * N and int(np.sum(np.asarray(r) == 0.0)) == N // 2
    np.testing.assert_allclose(float(cost), float(jnp.sum(r * r)) / n_obs, rtol=1e-12)
    # se(theta) = theta s sqrt([(J^T J)^-1]_00), s^2 = sum r^2 / (n_obs - unknowns)
    s2 = float(jnp.sum(r * r)) / (n_obs - u.shape[0])
    gauss_newton = float(jnp.linalg.inv(J.T @ J)[0, 0])
    np.testing.assert_allclose(float(se), float(theta) * np.sqrt(s2 * gauss_newton), rtol=1e-6)


def test_burckhardt_peak_is_where_the_slope_vanishes():
    c1, c2, c3 = 1.2801, 23.99, 0.52  # dry asphalt
    lam, mu = burckhardt_peak(c1, c2, c3)
    assert float(c1 * c2 * jnp.exp(-c2 * lam) - c3) == pytest.approx(0.0, abs=1e-12)
    grid = np.linspace(0.0, 1.0, 100001)
    assert float(mu) == pytest.approx(np.max(c1 * (1 - np.exp(-c2 * grid)) - c3 * grid),
                                      abs=1e-9)
    assert float(burckhardt_peak(0.05, 306.39, 0.0)[0]) == 1.0  # ice: a plateau, no peak


def test_scaled_friction_curve_is_the_tires_scaled_and_stretched():
    p = vs.MagicFormulaParams()
    tire = ScaledFriction(vs.RelaxedMagicFormula(p), 0.7, 1.3)
    s = jnp.asarray(-0.08)
    expected = 0.7 * magic_formula(s / 1.3, p.B, p.C, p.D, p.E)
    assert float(braking_curve(tire, s, 20.0)) == pytest.approx(float(expected), rel=1e-12)
    # and the dynamic tire in steady state: its state at rest gives the same force
    v, r = 20.0, 0.3
    omega = (1.0 + s) * v / r
    u = tire.tire.params.relaxation_length * (r * omega - v) / 1.3 / v
    assert float(tire.mu(u, v, omega, r)) == pytest.approx(float(expected), rel=1e-9)
    assert float(tire.dynamics(u, v, omega, r)) == pytest.approx(0.0, abs=1e-12)


def test_peak_slip_tracking_aims_at_the_peak_of_the_belief():
    mf = vs.RelaxedMagicFormula(vs.MagicFormulaParams())
    m = Measurement(jnp.asarray(60.0), jnp.asarray(20.0), jnp.asarray(-0.1), jnp.asarray(0.0),
                    jnp.asarray(0.0))
    s, mu = PeakSlipTracking().target(m, mf, 0.3)
    s_mf, mu_mf = peak_braking(mf, 20.0)
    assert float(s) == pytest.approx(float(s_mf), rel=1e-9)
    assert float(mu) == pytest.approx(float(mu_mf), rel=1e-9)


def test_estimators_refuse_what_they_cannot_estimate():
    srf = surface("dry_asphalt")
    with pytest.raises(ValueError, match="must estimate one parameter"):
        FrictionObserver(RoadCondition(srf.tire(), free=("theta", "mu_s")))
    with pytest.raises(ValueError, match="RoadCondition.free must start with 'theta'"):
        RoadCondition(srf.tire(), free=("mu_s",))
    with pytest.raises(TypeError, match="RoadCondition.tire must be a LuGre tire"):
        RoadCondition(vs.RelaxedMagicFormula(vs.MagicFormulaParams()))
    with pytest.raises(ValueError, match="scalar friction state"):
        MovingHorizonEstimator(vs.DistributedLuGre(srf.params, n=8))


def test_peak_estimator_leaves_the_old_road_after_a_change():
    # Table 3's dry road to theta = 2.5 at 15 m (the same program as the records above): the
    # change detector forgets the dry curve, so the peak friction follows within 0.25 s
    scenario, _ = _lugre_record()
    slippery = vs.LumpedLuGre(eqx.tree_at(lambda p: p.theta, table3(), jnp.asarray(2.5)),
                              kappa0=KAPPA0)
    scenario = eqx.tree_at(lambda sc: sc.change, scenario,
                           vs.SurfaceChange(slippery, distance=15.0))
    run = simulate_braking(scenario, RuleBasedABS(), braking_scenario("dry_asphalt")[1],
                           HARDWARE, duration=DURATION)
    s = {k: np.asarray(v) for k, v in run.signals.items()}
    states = _replay(PeakEstimator(), scenario.car, HARDWARE, BrakingRecord.from_signals(s))
    t_change = s["ts"][np.argmax(s["x"] >= 15.0)]
    after = (s["ts"] >= t_change + 0.25) & (s["v"] > 3.0)
    mu_true = np.asarray(jax.vmap(lambda v: peak_braking(slippery, v, 0.3)[1])(s["v"][after]))
    assert after.sum() > 20
    np.testing.assert_allclose(np.asarray(states.peak_mu)[after], mu_true, rtol=0.1)


def test_observer_update_exact_sensitivity_and_derivative_with_frozen_jacobians():
    # the observer's regressor is the exact derivative of its copy's steps (central
    # differences of the prediction agree to 1e-7); the update's own derivative holds the
    # steps' Jacobians constant (as the plant's does): forward = reverse, off central
    # differences of the update by the steps' sensitivity to their Jacobians (measured: at
    # most 9e-4 of each output's largest derivative, 1e-4 typical; the exact derivative
    # agrees to 1e-7)
    scenario, observer = braking_scenario("dry_asphalt", 30.0)
    car = scenario.car
    st0 = observer.init(jnp.asarray(29.0 / car.radius), jnp.asarray(30.0))

    def update(p):  # p = (target torque [kN m], log theta, wheel speed [rad/s])
        st = eqx.tree_at(lambda s: (s.log_theta, s.omega), st0, (p[1], p[2]))
        return observer.update(st, car, HARDWARE, 8, jnp.asarray(29.9), jnp.asarray(95.0),
                               0.0025, True, 800.0, 1000.0 * p[0], 0.0)

    def flat(p):
        return jnp.concatenate([jnp.atleast_1d(a) for a in jax.tree_util.tree_leaves(update(p))])

    p = jnp.array([1.2, float(st0.log_theta), 29.0 / float(car.radius)])
    st = eqx.filter_jit(update)(p)

    L = float(observer.injection)

    def predicted(log_theta):  # (at the measurement's time, at the sample's end)
        out = observer._predict(car, HARDWARE, 8, st0.v, p[2], st0.z, log_theta, 800.0, 1200.0,
                                0.0, 0.0025)
        return np.array([float(out[0]), float(out[1])])

    def corrected(log_theta):  # the estimate after the correction, omega_end + L e
        at_stamp, at_end = predicted(log_theta)
        return at_end + L * (95.0 - at_stamp)

    eps = 1e-5
    fd = (corrected(p[1] + eps) - corrected(p[1] - eps)) / (2 * eps)
    stamp, end = (predicted(p[1] + eps) - predicted(p[1] - eps)) / (2 * eps)
    assert abs(fd) > 1e-3 and abs(stamp - end) > 0.1 * abs(end)  # the times differ
    assert float(st.sensitivity[0]) == pytest.approx(fd, rel=1e-7)
    # no edge: the estimate is the prediction, bounded by the last measured speed; where
    # the bound holds (a wheel measured slower, 0 here) it does not depend on theta
    for omega_m, expected in ((0.0, 0.0), (1e6, end)):
        st_b = observer.update(eqx.tree_at(lambda s: (s.log_theta, s.omega), st0, (p[1], p[2])),
                               car, HARDWARE, 8, jnp.asarray(29.9), jnp.asarray(omega_m), 0.0025,
                               False, 800.0, 1200.0, 0.0)
        assert float(st_b.sensitivity[0]) == pytest.approx(expected, rel=1e-7, abs=1e-12)

    fwd = np.asarray(eqx.filter_jit(jax.jacfwd(flat))(p))
    rev = np.asarray(eqx.filter_jit(jax.jacrev(flat))(p))
    np.testing.assert_allclose(rev, fwd, rtol=1e-9, atol=1e-12 * np.max(np.abs(fwd)))
    f, h = eqx.filter_jit(flat), np.array([1e-4, 1e-5, 1e-4])
    cd = np.stack([(np.asarray(f(p + h[i] * e)) - np.asarray(f(p - h[i] * e))) / (2 * h[i])
                   for i, e in enumerate(np.eye(3))], axis=-1)
    scale = np.max(np.abs(cd), axis=1, keepdims=True) + 1e-12
    assert np.max(np.abs(cd)) > 1e-3 and np.all(np.isfinite(fwd))
    np.testing.assert_allclose(fwd / scale, cd / scale, atol=2e-3)


def test_observer_exact_derivatives_at_a_locked_wheel():
    """At a locked wheel the steps' Jacobians change fastest: the default update's
    derivative (Jacobians held constant) is off the central differences by up to 3.6 % of
    an output's largest derivative there (measured); ``exact_derivatives=True`` gives the
    exact one, in both modes (reverse mode as one gradient of a weighted sum: its program
    is the costly one to compile). The measurement's time enters after the steps: its
    derivative is exact in both."""
    scenario, observer = braking_scenario("dry_asphalt", 30.0)
    car = scenario.car
    st0 = observer.init(jnp.asarray(0.0), jnp.asarray(30.0))
    exact = dataclasses.replace(observer, exact_derivatives=True)

    def flat(p, ob=exact):  # p = (target torque [kN m], log theta, wheel speed [rad/s],
        st = eqx.tree_at(lambda s: (s.log_theta, s.omega), st0, (p[1], p[2]))  # stamp [ms])
        out = ob.update(st, car, HARDWARE, 8, jnp.asarray(29.9), jnp.asarray(0.0),
                        1e-3 * p[3], True, 2000.0, 1000.0 * p[0], 0.0)
        return jnp.concatenate([jnp.atleast_1d(a) for a in jax.tree_util.tree_leaves(out)])

    p = jnp.array([3.0, float(st0.log_theta), 0.0, 2.5])
    f, h = eqx.filter_jit(flat), np.array([1e-4, 1e-5, 1e-4, 1e-4])
    np.testing.assert_allclose(np.asarray(f(p)), np.asarray(eqx.filter_jit(flat)(p, observer)),
                               rtol=1e-14)  # the same values
    cd = np.stack([(np.asarray(f(p + h[i] * e)) - np.asarray(f(p - h[i] * e))) / (2 * h[i])
                   for i, e in enumerate(np.eye(4))], axis=-1)
    scale = np.max(np.abs(cd), axis=1, keepdims=True) + 1e-12
    w = jnp.asarray(1.0 / scale[:, 0])
    fwd, rev = eqx.filter_jit(lambda p: (jax.jacfwd(flat)(p),
                                         jax.grad(lambda q: w @ flat(q))(p)))(p)
    np.testing.assert_allclose(np.asarray(fwd) / scale, cd / scale, atol=1e-6)
    np.testing.assert_allclose(np.asarray(rev), np.asarray(w) @ cd,
                               atol=1e-6 * np.max(np.abs(np.asarray(w) @ cd)))
    frozen = np.asarray(eqx.filter_jit(jax.jacfwd(lambda q: flat(q, observer)))(p)) / scale
    err = np.max(np.abs(frozen - cd / scale), axis=0)
    assert np.max(np.abs(cd[:, 3])) > 1.0 and err[3] < 1e-6  # the stamp's: exact
    assert 1e-3 < np.max(err[:3]) < 0.04  # the steps': frozen
