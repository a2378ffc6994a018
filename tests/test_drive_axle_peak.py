"""The shape-free axle peak estimator: it finds the peak of curves of families it does not
assume, holds its prior where the data do not reach the peak, and the driver that plans with
its peak uses it as it stands."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs


SIGMA = 0.05  # the utilised friction's noise, as the estimator's default assumes


def _magic_formula(s):
    """A pure-slip Magic Formula curve (B 8, C 1.65, D 0.45, E 0.3): peak 0.45 at 20 % slip,
    a fall of a quarter by slip 1 (not of Burckhardt's family)."""
    Bs = 8.0 * s
    return 0.45 * jnp.sin(1.65 * jnp.arctan(Bs - 0.3 * (Bs - jnp.arctan(Bs))))


def _lugre(s):
    """The drive plant's LuGre on the nominal road in braking at 20 m/s (peak 0.52 at 4 % slip)."""
    tire, V = vs.DrivePlant().tire, 20.0
    lam = vs.nominal_scale()
    v_r = jnp.stack([-s * V, 0.0 * s])
    return jnp.linalg.norm(vs.scaled_steady_state_mu(tire, lam, v_r, (1.0 - s) * V))


def _true_peak(curve):
    s = jnp.linspace(1e-3, 1.0, 20001)
    mu = jax.vmap(curve)(s)
    return float(jnp.max(mu)), float(s[jnp.argmax(mu)])


def _run(est, curve, slips, key=0):
    """The estimator's per-axle step over samples at ``slips``, the friction the curve's
    plus noise of standard deviation `SIGMA`: ``(log peak, variance, peak slip)`` after
    each."""
    noise = SIGMA * jax.random.normal(jax.random.key(key), slips.shape)
    carry0 = est.empty_curve()

    def step(carry, x):
        s, e = x
        out = est.curve_step(*carry, curve(s) + e, s, jnp.asarray(True))
        return out[:6], out[6:]

    return jax.lax.scan(step, carry0, (slips, noise))[1]


def _sweeps(top, n=8, points=25):
    """``n`` braking sweeps from 2 % slip to ``top``."""
    return jnp.tile(jnp.linspace(0.02, top, points), n)


@pytest.mark.parametrize("curve", [_magic_formula, _lugre], ids=["magic-formula", "lugre"])
def test_finds_the_peak_of_a_curve_of_another_family(curve):
    est = vs.AxlePeakEstimator(prior_peak=0.8)  # far from both curves' peaks
    peak, s_peak = _true_peak(curve)
    log_peak, var, s_star = _run(est, curve, _sweeps(min(1.0, 4 * s_peak)))
    # 200 samples through the peak and past it: within 5 % of the true peak, the belief's
    # standard deviation a few percent, the fitted peak's slip near the true one
    np.testing.assert_allclose(np.exp(float(log_peak[-1])), peak, rtol=0.05)
    assert float(jnp.sqrt(var[-1])) < 0.05
    np.testing.assert_allclose(float(s_star[-1]), s_peak, rtol=0.5)


def test_holds_its_prior_below_the_peak():
    """Data at slips well below the peak (at most a third of its slip) leave the belief at
    the prior, with the prior's width: the curve says nothing about a peak it has not
    reached."""
    est = vs.AxlePeakEstimator(prior_peak=0.6)
    _, s_peak = _true_peak(_magic_formula)
    log_peak, var, _ = _run(est, _magic_formula, _sweeps(s_peak / 3))
    np.testing.assert_allclose(np.exp(np.asarray(log_peak)), 0.6, rtol=0.02)
    np.testing.assert_allclose(np.sqrt(np.asarray(var[-1])), 0.3, rtol=0.05)


def _changed_road(est):
    """12 sweeps on the Magic Formula curve whose peak falls to 40 % after the 8th: the
    belief after each sample."""
    _, s_peak = _true_peak(_magic_formula)
    slips = _sweeps(3 * s_peak, n=12)
    after = jnp.arange(slips.shape[0]) >= 8 * 25
    noise = SIGMA * jax.random.normal(jax.random.key(1), slips.shape)
    mu = jnp.where(after, 0.4, 1.0) * _magic_formula(slips) + noise
    carry = est.empty_curve()

    def step(carry, x):
        out = est.curve_step(*carry, x[0], x[1], jnp.asarray(True))
        return out[:6], out[6]

    return np.exp(np.asarray(jax.lax.scan(step, carry, (mu, slips))[1]))


def test_a_change_of_road_is_learnt_within_a_sweep():
    """The change detector discounts the old curve: one sweep after the peak falls to 40 %
    the belief is within 15 % of the new peak; without the detector (`change_threshold`
    inf: forgetting alone) it is still more than 30 % above it."""
    peak, _ = _true_peak(_magic_formula)
    with_detector = _changed_road(vs.AxlePeakEstimator())
    np.testing.assert_allclose(with_detector[8 * 25 - 1], peak, rtol=0.05)
    np.testing.assert_allclose(with_detector[9 * 25], 0.4 * peak, rtol=0.15)
    forgetting_only = _changed_road(vs.AxlePeakEstimator(change_threshold=float("inf")))
    assert forgetting_only[9 * 25] > 1.3 * 0.4 * peak


def test_the_estimated_peak_model_plans_with_the_estimate_itself():
    """`peak_model='estimated'`: every stage's D is the smaller axle's estimated peak (less
    the backoff's standard deviations), whatever the stages' speeds; the 'plant' model's D
    rises as the speed falls (the LuGre peak)."""
    table = vs.RoadTable.from_road(vs.scenario_road("corner90"), spacing=0.5)
    est = vs.GripEstimate(scale=jnp.array([0.4, 0.5]), scale_std=jnp.array([0.04, 0.05]),
                          peak=jnp.array([0.47, 0.41]), peak_std=jnp.array([0.02, 0.03]))
    speeds = jnp.linspace(4.0, 16.0, 30)
    shape_free = vs.RecedingHorizonDriver(table=table, friction="estimate",
                                          peak_model="estimated", estimate_backoff=1.0)
    D = np.asarray(shape_free.planner_friction(jnp.asarray(0.0), est, speeds))
    np.testing.assert_allclose(D, 0.41 - 0.03, rtol=1e-12)
    lugre = vs.RecedingHorizonDriver(table=table, friction="estimate")
    D_lugre = np.asarray(lugre.planner_friction(jnp.asarray(0.0), est, speeds))
    assert D_lugre[0] > D_lugre[-1] * 1.05  # slower stages, more grip


def test_the_estimated_peak_model_needs_an_estimate():
    table = vs.RoadTable.from_road(vs.scenario_road("corner90"), spacing=0.5)
    with pytest.raises(ValueError, match="peak_model='estimated'.*friction='estimate'"):
        vs.RecedingHorizonDriver(table=table, friction="oracle", peak_model="estimated")
    with pytest.raises(ValueError, match="peak_model must be 'plant', 'estimated' or 'cautious'"):
        vs.RecedingHorizonDriver(table=table, friction="estimate", peak_model="lugre")


def test_scenario_driver_with_the_shape_free_estimator():
    sc = vs.drive_scenario("corner90", "minus20")
    driver, est = vs.scenario_driver(sc, "estimate", pace_notes=True, estimator="axle-peak")
    assert isinstance(est, vs.AxlePeakEstimator) and driver.peak_model == "estimated"
    assert est.surface is not None
    driver, est = vs.scenario_driver(sc, "estimate")
    assert isinstance(est, vs.AxleGripEstimator) and driver.peak_model == "plant"
    with pytest.raises(ValueError, match="unknown estimator 'peak'; allowed: axle-grip, "
                                         "axle-peak"):
        vs.scenario_driver(sc, "estimate", estimator="peak")


def test_refuses_bad_settings():
    with pytest.raises(ValueError, match="AxlePeakEstimator.prior_peak"):
        vs.AxlePeakEstimator(prior_peak=-0.1)
    with pytest.raises(ValueError, match="AxlePeakEstimator.forgetting"):
        vs.AxlePeakEstimator(forgetting=1.5)
    with pytest.raises(ValueError, match="AxlePeakEstimator.bins"):
        vs.AxlePeakEstimator(bins=1)
    with pytest.raises(TypeError, match="AxlePeakEstimator.tire must be a LumpedLuGre2D"):
        vs.AxlePeakEstimator(tire=vs.LinearTire(1e5, 8e4))
    with pytest.raises(ValueError, match=r"AxleGripEstimator.change_threshold must lie in \(0"):
        vs.AxleGripEstimator(change_threshold=0.0)
    # an infinite threshold, which the estimators' docstrings name as "off", is accepted
    for make in (vs.AxlePeakEstimator, vs.AxleGripEstimator, vs.PeakEstimator):
        assert np.isinf(float(make(change_threshold=float("inf")).change_threshold))


def test_a_map_refers_the_curve_to_its_reference_surface():
    """With a map of the relative grip $r$ the measured friction is divided by $r$ under
    the axle (the curve of the map's reference surface), and the reported peak is the
    belief times $r$ under the car; `scale` is the tire's friction scale of that peak."""
    V, g, mu = 6.0, 9.81, 0.3

    def sample(t):
        return vs.DriveMeasurement(
            t=jnp.asarray(t), omega=jnp.full(2, V / 0.3), yaw_rate=jnp.asarray(mu * g / V),
            ax=jnp.asarray(0.0), ay=jnp.asarray(mu * g), vx=jnp.asarray(V), vy=jnp.asarray(0.0),
            x=jnp.asarray(0.0), y=jnp.asarray(0.0), psi=jnp.asarray(0.0),
            delta=jnp.asarray(0.05), torque=jnp.zeros(2))

    plain = vs.AxlePeakEstimator(prior_peak=0.6)
    mapped = vs.AxlePeakEstimator(prior_peak=0.6, surface=vs.UniformGrip(0.5))
    used = []
    for est in (plain, mapped):
        state = est.update(est.init(sample(0.0)), sample(0.05))
        assert np.all(np.asarray(state.slip) >= float(est.min_slip))  # informative
        used.append(np.asarray(state.mu_used))
        e = est.estimate(state)
        r = 1.0 if est.surface is None else 0.5
        np.testing.assert_allclose(np.asarray(e.peak), r * np.exp(np.asarray(state.log_peak)),
                                   rtol=1e-12)
        ref = vs.scale_of_peak(est.tire, r * np.exp(np.asarray(state.log_peak[0])))
        np.testing.assert_allclose(float(e.scale[0]), float(ref), rtol=1e-9)
    np.testing.assert_allclose(used[1], 2.0 * used[0], rtol=1e-12)
    assert np.all(used[0] > 0.1)


def test_the_cautious_peak_model_plans_with_the_smaller_peak():
    """`peak_model='cautious'`: each stage's D is the smaller of the 'plant' model's (the
    LuGre peak of the estimate's scale at the stage's speed, higher at the slow stages) and
    the estimate's peak; here the peak bounds the slow stages and not the fast ones."""
    table = vs.RoadTable.from_road(vs.scenario_road("corner90"), spacing=0.5)
    lam = vs.nominal_scale()
    est = vs.GripEstimate(scale=jnp.array([lam, lam]), scale_std=jnp.array([0.0, 0.0]),
                          peak=jnp.array([0.58, 0.6]), peak_std=jnp.array([0.0, 0.0]))
    speeds = jnp.linspace(4.0, 20.0, 30)
    plant = vs.RecedingHorizonDriver(table=table, friction="estimate")
    cautious = vs.RecedingHorizonDriver(table=table, friction="estimate", peak_model="cautious")
    D_plant = np.asarray(plant.planner_friction(jnp.asarray(0.0), est, speeds))
    D = np.asarray(cautious.planner_friction(jnp.asarray(0.0), est, speeds))
    np.testing.assert_allclose(D, np.minimum(D_plant, 0.58), rtol=1e-12)
    assert D_plant[0] > 0.58 > D_plant[-1]  # both sides of the bound are exercised


def test_the_cautious_estimator_carries_both_beliefs():
    sc = vs.drive_scenario("corner90", "minus20")
    driver, est = vs.scenario_driver(sc, "estimate", pace_notes=True, estimator="cautious")
    assert isinstance(est, vs.CautiousGripEstimator) and driver.peak_model == "cautious"
    assert est.model.surface is not None and est.shape_free.surface is not None
    est = vs.CautiousGripEstimator(vs.AxleGripEstimator(prior_scale=0.2),
                                   vs.AxlePeakEstimator(prior_peak=0.45))
    m = vs.measure_drive(sc.plant, sc.state0, jax.random.key(0))
    m1 = eqx.tree_at(lambda q: q.t, m, m.t + 0.05)
    e = est.estimate(est.update(est.init(m), m1))
    a = est.model.estimate(est.model.update(est.model.init(m), m1))
    b = est.shape_free.estimate(est.shape_free.update(est.shape_free.init(m), m1))
    np.testing.assert_array_equal(np.asarray(e.scale), np.asarray(a.scale))
    np.testing.assert_array_equal(np.asarray(e.peak), np.asarray(b.peak))
    np.testing.assert_allclose(np.asarray(e.peak), 0.45)
    assert np.all(np.abs(np.asarray(a.peak) - 0.45) > 0.05)  # the two beliefs differ
    signals = est.signals(est.init(m))
    assert "scale_F" in signals and "free_peak_F" in signals
    with pytest.raises(TypeError, match="CautiousGripEstimator.shape_free must be a "
                                        "AxlePeakEstimator"):
        vs.CautiousGripEstimator(shape_free=vs.AxleGripEstimator())


def test_pace_notes_reach_the_shape_free_parts_as_peak_ratios():
    """The scenarios' pace notes are ratios of the LuGre plant's friction scales (0.44 on
    the icy patch); the shape-free estimator gets them as ratios of its peaks (`PeakRatios`:
    0.50 there, the scenario's half the grip) and the driver's 'estimated' peak carries the
    measured peak along the map by peak ratios too; the LuGre estimator keeps the scale
    ratios it multiplies scales by."""
    sc = vs.drive_scenario("corner90", "icy")
    notes = sc.surface_map()
    s_apex = float(np.mean(vs.main_corner("corner90")))
    x, y = sc.road.position(s_apex)
    x, y = jnp.asarray(float(x)), jnp.asarray(float(y))
    scale_ratio = float(notes.scale_at(x, y))
    peak_ratio = float(sc.grip.peak_at(s_apex)) / 0.52
    assert scale_ratio == pytest.approx(0.44, abs=0.01) and peak_ratio == pytest.approx(
        0.5, abs=0.01)
    for kind in ("axle-peak", "cautious"):
        driver, est = vs.scenario_driver(sc, "estimate", pace_notes=True, estimator=kind)
        free = est if kind == "axle-peak" else est.shape_free
        assert isinstance(free.surface, vs.PeakRatios)
        assert float(free.surface.scale_at(x, y)) == pytest.approx(peak_ratio, rel=7e-3)
        if kind == "cautious":
            assert float(est.model.surface.scale_at(x, y)) == scale_ratio
            continue
        # the driver: a measured peak of 0.5 on the nominal surface at the start, carried
        # to the stages over the patch
        lam = vs.nominal_scale()
        e = vs.GripEstimate(scale=jnp.array([lam, lam]), scale_std=jnp.zeros(2),
                            peak=jnp.array([0.5, 0.5]), peak_std=jnp.zeros(2))
        assert driver.peak_model == "estimated"
        driver = eqx.tree_at(lambda d: d.estimate_backoff, driver, jnp.asarray(0.0))
        s0 = jnp.asarray(s_apex - 0.5 * float(driver.horizon))
        D = np.asarray(driver.planner_friction(s0, e, jnp.full(driver.num_stages, 8.0)))
        ratios = np.asarray(driver.table.scale_at(s0 + float(driver.horizon) / driver.num_stages
                                                  * (np.arange(driver.num_stages) + 0.5)))
        k = int(np.argmin(ratios))
        assert ratios[k] == pytest.approx(scale_ratio, abs=0.01)
        want = 0.5 * vs.plant_peak(lam * ratios[k]) / vs.plant_peak(lam)
        assert D[k] == pytest.approx(want, rel=1e-7) and D[k] > 0.5 * ratios[k] * 1.1
