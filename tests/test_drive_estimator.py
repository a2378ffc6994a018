"""The per-axle grip estimator on the move: it converges under excitation, holds its prior
without, tracks a change of road; its model is the tire's steady state."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs


N = 60  # samples (3 s at 20 Hz)


def _road(*scales, stations=(0.0, 1.0)):
    """A `GripProfile` along x (one structure for every road, so one compilation)."""
    if len(scales) == 1:
        scales = scales * 2
    return vs.GripProfile(stations=jnp.asarray(stations), scales=jnp.asarray(scales))


def _pulses(torque):
    """Straight line, braking pulses of `torque` per axle (0.2 s every 0.5 s)."""
    return vs.PathFollower(torque=jnp.array([0.0, 0.0]), pulse_torque=jnp.array([torque] * 2),
                           pulse_period=0.5, pulse_width=0.2, slalom_amplitude=0.03)


@pytest.fixture(scope="module")
def drive():
    run = jax.jit(lambda plant, ctrl, est, key: vs.simulate_drive(
        plant, ctrl, vs.init_drive(plant, vx=20.0), key, N, est))

    def go(road, ctrl, est=None, key=0):
        est = vs.AxleGripEstimator() if est is None else est
        return run(vs.DrivePlant(grip=road), ctrl, est, jax.random.key(key))
    return go


def test_steady_state_mu_is_the_tires_steady_state():
    """The estimator's model zeroes the tire's own friction-state derivative (eq. 35)."""
    tire = vs.DrivePlant().tire
    for lam, v_r, c in ((1.0, jnp.array([-2.0, 0.5]), 18.0), (0.5, jnp.array([0.3, -1.0]), 20.0),
                        (0.8, jnp.array([-15.0, 0.0]), 5.0)):
        t = vs.scale_friction(tire, lam)
        mu = vs.scaled_steady_state_mu(tire, lam, v_r, c)
        zb = mu / t.params.sigma0  # sigma2 = 0 for this tire
        z = jnp.concatenate([zb, jnp.zeros(1)])
        np.testing.assert_allclose(t.derivative(z, v_r, c)[:2], 0.0, atol=1e-12)
        np.testing.assert_allclose(t.mu(z, v_r, c)[:2], mu, rtol=1e-12)


@pytest.mark.parametrize("lam", [0.6, 1.0])
def test_converges_on_constant_grip_under_braking_pulses(drive, lam):
    est = vs.AxleGripEstimator()
    run = drive(_road(lam), _pulses(-3500.0 * lam), est)
    t = np.asarray(run.measurements.t)
    scale = np.asarray(run.estimates.scale)
    late = t >= 1.5
    np.testing.assert_allclose(scale[late], lam, rtol=0.15)
    np.testing.assert_allclose(np.asarray(run.estimates.peak)[late], float(est.peak(lam)),
                               rtol=0.15)
    assert np.all(np.asarray(run.estimates.scale_std)[-1] < 0.1 * lam)
    # the same drive with the gain switched off (infinite noise) stays at the prior
    off = drive(_road(lam), _pulses(-3500.0 * lam), vs.AxleGripEstimator(noise_std=1e6))
    np.testing.assert_allclose(np.asarray(off.estimates.scale), 1.0, atol=1e-6)


def test_holds_prior_without_excitation(drive):
    est = vs.AxleGripEstimator()
    # straight, coasting at 20 m/s (a far look-ahead: no steering from the position noise)
    run = drive(_road(0.6), vs.PathFollower(lookahead=1000.0), est)
    scale = np.asarray(run.estimates.scale)
    np.testing.assert_allclose(scale, 1.0, atol=0.02)
    var = np.asarray(run.estimates.scale_std / run.estimates.scale) ** 2
    assert np.all(var <= float(est.max_variance) * (1 + 1e-9))
    np.testing.assert_allclose(var[-1], float(est.max_variance), rtol=1e-3)  # widened to cap
    # the car did coast straight (no excitation): small utilised friction
    assert np.all(np.abs(np.asarray(run.measurements.ax)) < 0.6)


def test_tracks_a_change_of_grip(drive):
    road = _road(1.0, 0.5, stations=(22.0, 26.0))  # the front axle reaches it at ~1 s
    run = drive(road, _pulses(-3500.0))
    t = np.asarray(run.measurements.t)
    x = np.asarray(run.states.car[:, 0])
    scale = np.asarray(run.estimates.scale)
    before = (t > 0.6) & (x < 20.0)  # converged, both axles short of the change
    assert before.sum() >= 3
    np.testing.assert_allclose(np.median(scale[before], axis=0), 1.0, rtol=0.1)
    np.testing.assert_allclose(scale[before], 1.0, rtol=0.25)
    assert x[-5] - 1.4 > 30.0  # the rear axle is well onto the new road for the last samples
    np.testing.assert_allclose(scale[-5:], 0.5, rtol=0.1)


def test_counts_a_sample_by_the_peak_at_its_speed():
    """A steady corner at 4 m/s on the nominal road (peak 0.52 at 20 m/s, 0.65 at 4 m/s): an
    axle using 0.29 (more than half the peak at 20 m/s, less than half of it at 4 m/s) is
    not counted, one using 0.36 is."""
    lam0 = vs.nominal_scale()
    est = vs.AxleGripEstimator(prior_scale=lam0)
    p, V, g = est.params, 4.0, 9.81
    assert 0.29 > 0.5 * float(est.peak(lam0)) and 0.36 > 0.5 * float(est.peak(lam0, V)) > 0.29

    def sample(t, mu):
        return vs.DriveMeasurement(
            t=jnp.asarray(t), omega=jnp.full(2, V / p.r), yaw_rate=jnp.asarray(mu * g / V),
            ax=jnp.asarray(0.0), ay=jnp.asarray(mu * g), vx=jnp.asarray(V), vy=jnp.asarray(0.0),
            x=jnp.asarray(0.0), y=jnp.asarray(0.0), psi=jnp.asarray(0.0),
            delta=jnp.asarray(0.02), torque=jnp.zeros(2))

    for mu, counted in ((0.29, False), (0.36, True)):
        state = est.update(est.init(sample(0.0, mu)), sample(0.05, mu))
        used = np.asarray(state.mu_used)
        if counted:
            np.testing.assert_allclose(used, mu, rtol=0.02)
            assert np.all(np.asarray(state.gain) != 0.0)
        else:
            assert np.all(used == 0.0) and np.all(np.asarray(state.gain) == 0.0)


def test_sliding_samples_teach_a_road_below_the_gate(drive):
    """A prior of twice the road's grip and a gate of 70 % of the believed peak: braking
    pulses sized for the believed road slide the wheels, and the axles never use 70 % of
    the believed peak, so the gate alone learns nothing; counting the samples whose slip
    passes `sliding_slip` (0.1) takes the estimate to the road."""
    road, pulses = _road(0.5), _pulses(-3500.0)
    gated = drive(road, pulses, vs.AxleGripEstimator(min_utilisation=0.7))
    np.testing.assert_allclose(np.asarray(gated.estimates.scale), 1.0, atol=1e-6)
    sliding = drive(road, pulses, vs.AxleGripEstimator(min_utilisation=0.7, sliding_slip=0.1))
    scale = np.asarray(sliding.estimates.scale)
    np.testing.assert_allclose(scale[-5:], 0.5, rtol=0.15)
    # on the road it believes, the sliding samples do not bias it
    right = drive(_road(1.0), pulses, vs.AxleGripEstimator(min_utilisation=0.7,
                                                           sliding_slip=0.1))
    late = np.asarray(right.measurements.t) >= 1.5
    np.testing.assert_allclose(np.asarray(right.estimates.scale)[late], 1.0, rtol=0.15)


def test_a_surface_map_carries_the_estimate_onto_another_surface(drive):
    """A road of grip 0.6 that halves at x = 32-33 m, braking pulses sized for it, the prior
    1. With the road's map relative to its start (`RelativeGrip`: 1, then 0.5; how the
    surfaces compare, not their level) the estimator learns the level on the first surface
    exactly as the plain one does (the map is 1 there) and carries it onto the second as
    each axle reaches it, per axle; the plain one, told nothing, still believes the first
    surface when both axles have left it (and learns the second later, if at all). A
    uniform map changes nothing: with its multiplier's prior and bounds divided by the
    map's value, the same estimates to rounding."""
    road, pulses = _road(0.6, 0.3, stations=(32.0, 33.0)), _pulses(-2100.0)
    plain = drive(road, pulses)
    mapped = drive(road, pulses, vs.AxleGripEstimator(surface=vs.RelativeGrip(road, 0.6)))
    p = vs.AxleGripEstimator().params
    t = np.asarray(mapped.measurements.t)
    x = np.asarray(mapped.states.car[:, 0])
    # the same drive (the estimator does not steer this car), to rounding: two programs, whose
    # plant XLA may fuse differently (measured 7e-15 m apart after 3 s)
    np.testing.assert_allclose(x, np.asarray(plain.states.car[:, 0]), rtol=1e-13, atol=0)
    sp, sm = np.asarray(plain.estimates.scale), np.asarray(mapped.estimates.scale)
    first = (t > 1.0) & (x + p.lF < 32.0)
    assert first.sum() >= 10
    np.testing.assert_allclose(sm[first], sp[first], rtol=1e-12)
    np.testing.assert_allclose(sm[first], 0.6, rtol=0.05)
    front_only = (x + p.lF > 33.0) & (x - p.lR < 32.0)
    assert front_only.sum() >= 2
    np.testing.assert_allclose(sm[front_only, 0], 0.3, rtol=0.05)
    np.testing.assert_allclose(sm[front_only, 1], 0.6, rtol=0.05)
    second = x - p.lR > 33.5
    assert second.sum() >= 10
    np.testing.assert_allclose(sm[second], 0.3, rtol=0.05)
    assert np.all(sp[second][:3] > 0.45)  # without the map: the first surface's belief
    uniform = drive(road, pulses, vs.AxleGripEstimator(
        surface=vs.UniformGrip(0.5), prior_scale=2.0, scale_min=0.2, scale_max=6.0))
    np.testing.assert_allclose(np.asarray(uniform.estimates.scale), sp, rtol=1e-12)


def test_slip_noise_weighs_a_sample_by_the_slope_it_is_read_on():
    r"""The measured relative velocity's noise $\sigma_v$ enters the friction's variance as
    $\sigma_v^2\|\partial\mu_{ss}/\partial v_r\|^2$ (against central differences). A rear
    axle driving at 7.5 m/s and 1.2 % slip on the road the prior believes, its ground speed
    read 4 cm/s high (about one $\sigma_v$ of the default sensors): without the term the
    filter takes the small-slip sample at face value and moves by its largest step, with
    it by a small fraction of that; sliding at 10 % slip on a road of 80 % of the belief,
    where the curve is flat, the term leaves the step within 10 %."""
    lam0 = vs.nominal_scale()
    plain = vs.AxleGripEstimator(prior_scale=lam0, min_utilisation=0.5, dynamic_loads=False)
    sigma = vs.slip_velocity_std(vs.DriveSensors(), plain.params.r)
    np.testing.assert_allclose(float(sigma), np.sqrt((0.05**2 + (plain.params.r * 0.05)**2) / 2),
                               rtol=1e-12)
    noisy = vs.AxleGripEstimator(prior_scale=lam0, min_utilisation=0.5, dynamic_loads=False,
                                 slip_velocity_std=float(sigma))
    assert float(vs.slip_velocity_std(vs.DriveSensors(noise_on=False), plain.params.r)) == 0.0
    with pytest.raises(ValueError, match="slip_velocity_std"):
        vs.AxleGripEstimator(slip_velocity_std=-0.01)
    p, V, g = plain.params, 7.5, 9.81
    FzR = p.m * g * p.lF / (p.lF + p.lR)

    # the variance term against central differences of the model's friction
    th = jnp.log(jnp.array([lam0, lam0]))
    v_r = jnp.array([[0.02, -0.01], [0.09, 0.03]])
    c = jnp.array([V, V])
    h = 1e-6
    fd = sum(((plain.model_mu(th, v_r + h * e, c) - plain.model_mu(th, v_r - h * e, c)) / (2 * h))**2
             for e in (jnp.array([[1.0, 0.0], [1.0, 0.0]]), jnp.array([[0.0, 1.0], [0.0, 1.0]])))
    np.testing.assert_allclose(noisy.slip_variance(th, v_r, c), sigma**2 * fd, rtol=1e-6)
    np.testing.assert_array_equal(plain.slip_variance(th, v_r, c), 0.0)

    @eqx.filter_jit
    def update(est, lam_road, kappa, vx_error):
        wr = V * (1.0 + kappa)  # the rear wheel's rim speed
        mu = vs.scaled_steady_state_mu(est.tire, lam_road, jnp.array([wr - V, 0.0]), wr)[0]
        torque = jnp.stack([0.0 * mu, mu * FzR * p.r])

        def sample(t):
            return vs.DriveMeasurement(
                t=jnp.asarray(t), omega=jnp.array([V / p.r, wr / p.r]), yaw_rate=jnp.asarray(0.0),
                ax=jnp.asarray(0.0), ay=jnp.asarray(0.0), vx=V + jnp.asarray(vx_error),
                vy=jnp.asarray(0.0), x=jnp.asarray(0.0), y=jnp.asarray(0.0),
                psi=jnp.asarray(0.0), delta=jnp.asarray(0.0), torque=torque)
        return est.update(est.init(sample(0.0)), sample(0.05))

    def step(est, lam_road, kappa, vx_error):
        state = update(est, *map(jnp.asarray, (lam_road, kappa, vx_error)))
        assert float(state.gain[1]) != 0.0  # the rear's sample counts
        return float(state.log_scale[1] - jnp.log(lam0))

    big, small = step(plain, lam0, 0.012, 0.04), step(noisy, lam0, 0.012, 0.04)
    assert big > 0.15 and 0 < small < 0.3 * big, (big, small)
    # read right, neither moves
    assert abs(step(plain, lam0, 0.012, 0.0)) < 1e-6 and abs(step(noisy, lam0, 0.012, 0.0)) < 1e-6
    # sliding on a road worse than believed: the flat curve keeps the step
    flat_plain, flat_noisy = step(plain, 0.8 * lam0, 0.1, 0.0), step(noisy, 0.8 * lam0, 0.1, 0.0)
    assert flat_plain < -0.05
    np.testing.assert_allclose(flat_noisy, flat_plain, rtol=0.1)

    # differentiable in both modes through the weighed update (an error of 2 cm/s: the step
    # is not clipped), and finite where the slip is zero
    def rear(err, kappa=0.012):
        state = update(noisy, jnp.asarray(lam0), jnp.asarray(kappa), err)
        return state.log_scale[1] + state.variance[1]
    err = jnp.asarray(0.02)
    fd = (rear(err + 1e-6) - rear(err - 1e-6)) / 2e-6
    np.testing.assert_allclose(jax.grad(rear)(err), fd, rtol=1e-6)
    np.testing.assert_allclose(jax.jacfwd(rear)(err), fd, rtol=1e-6)
    assert abs(float(fd)) > 1.0
    for mode in (jax.grad, jax.jacfwd):
        assert np.isfinite(float(mode(lambda e: rear(e, 0.0))(jnp.asarray(0.0))))
