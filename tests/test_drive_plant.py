"""The drive plant: agreement with the half-car, actuators against their closed form, grip
fields, sensor noise, a batch of drives in one call, and gradients through a drive."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs
from vehsim.drive.actuators import actuator_target, applied


N = 12  # samples per drive (0.6 s at 20 Hz)


def _quiet(**changes):
    return vs.DrivePlant(sensors=vs.DriveSensors(noise_on=False), **changes)


@pytest.fixture(scope="module")
def run_schedule():
    """One compiled drive under a command table (shared by the tests below)."""
    return jax.jit(lambda plant, ctrl, s0, key: vs.simulate_drive(plant, ctrl, s0, key, N))


def _commands():
    k = jnp.arange(N)
    return jnp.stack([300.0 + 0 * k, 600.0 + 20.0 * k, 0.04 * jnp.sin(0.5 * k)], axis=1)


def _sample_magic_formula():
    from vehsim.tire.tir import read_tir, shipped_tires

    return vs.MFParams.from_tir(read_tir(shipped_tires()["sample_185_80R14_mf61"]))


@pytest.mark.parametrize("tire", ["lugre", "magic-formula"])
def test_ideal_plant_agrees_with_half_car(run_schedule, tire):
    """The plant with ideal actuators against the half car integrated adaptively under the
    same command table: on its own LuGre tire, and on a Magic Formula with relaxed slips
    (the shipped .tir file, a tire of another family) on a road of friction scale 0.5
    (`scale_friction`: its LMUX and LMUY halved)."""
    changes = {}
    if tire == "magic-formula":
        changes = dict(tire=vs.RelaxedMFTire(_sample_magic_formula(), limits=False),
                       grip=vs.UniformGrip(scale=0.5))
    plant = _quiet(actuators=vs.ideal_actuators(), **changes)
    s0 = vs.init_drive(plant, vx=15.0)
    run = run_schedule(plant, vs.CommandSchedule(_commands()), s0, jax.random.key(0))
    car = plant.car_at(s0.car)
    T = float(plant.actuators.sample_time)
    table = _commands()

    def u(t, y):
        return table[jnp.clip(jnp.floor(t / T + 1e-9).astype(int), 0, N - 1)]

    ts = jnp.arange(N + 1) * T
    traj = vs.simulate(car, ts, u, s0.car, solver=vs.ROS34PW2(car.stiff_blocks), rtol=1e-8,
                       atol=1e-8, jump_ts=ts, max_steps=100_000)
    direct = np.asarray(traj.states[1:])
    ours = np.asarray(run.states.car)
    head = slice(0, 8)  # pose, velocities, wheel speeds
    np.testing.assert_allclose(ours[:, head], direct[:, head], rtol=2e-5, atol=2e-5)
    np.testing.assert_allclose(ours, direct, rtol=1e-3, atol=1e-4)
    # and the measurement is the state (noise off)
    np.testing.assert_allclose(np.asarray(run.measurements.omega), ours[:, 6:8], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(run.measurements.x), ours[:, 0], rtol=1e-12)


def test_actuators_step_response_closed_form():
    """Torque channels: delay then lag (no rate limit); steering: delay then rate limit
    (no lag); against the closed forms."""
    T, tau, rate, d = 0.05, 0.12, 0.5, 2
    act = vs.DriveActuators(sample_time=T, delay=(d * T,) * 3, time_constant=(tau, tau, 0.05),
                            rate=(1e9, 1e9, rate), lag_on=jnp.array([True, True, False]),
                            rate_limit_on=jnp.array([False, False, True]))
    A = jnp.array([1000.0, -800.0, 0.2])

    def sample(state, k):
        new, target = actuator_target(act, state, k, A)
        u0 = state.applied
        mid = applied(act, u0, target, 0.5 * T)
        end = applied(act, u0, target, T)
        return vs.DriveActuatorState(new.buffer, target, end), (mid, end)

    _, (mid, end) = jax.lax.scan(sample, vs.DriveActuatorState.init(), jnp.arange(12))
    t_end = (np.arange(12) + 1) * T
    for tt, got in ((t_end, end), (t_end - 0.5 * T, mid)):
        lag = np.where(tt > d * T, 1.0 - np.exp(-(tt - d * T) / tau), 0.0)
        np.testing.assert_allclose(got[:, 0], 1000.0 * lag, atol=1e-9)
        np.testing.assert_allclose(got[:, 1], -800.0 * lag, atol=1e-9)
    ramp = np.clip((np.arange(12) - d + 1) * rate * T, 0.0, 0.2)  # held over sample k
    np.testing.assert_allclose(end[:, 2], ramp, atol=1e-12)
    np.testing.assert_allclose(mid[:, 2], ramp, atol=1e-12)
    # saturation
    sat = vs.DriveActuators(delay_on=False, rate_limit_on=False, lag_on=False)
    _, target = actuator_target(sat, vs.DriveActuatorState.init(), 0, jnp.array([1e5, -1e5, 3.0]))
    np.testing.assert_allclose(target, [4000.0, -4000.0, 0.6])


def test_grip_profile_transitions():
    prof = vs.GripProfile(stations=jnp.array([0.0, 10.0, 30.0]), scales=jnp.array([0.4, 1.0, 0.8]))
    f = jnp.vectorize(lambda s: prof.scale_at(s, 5.0))
    s = jnp.array([-50.0, 0.0, 5.0, 10.0, 20.0, 30.0, 100.0])
    np.testing.assert_allclose(f(s), [0.4, 0.4, 0.7, 1.0, 0.9, 0.8, 0.8], atol=1e-12)
    # C1: the slope is 0 at the stations and 1.5 (max-min)/length at a ramp's middle
    g = jax.vmap(jax.grad(lambda s: prof.scale_at(s, 0.0)))
    np.testing.assert_allclose(g(jnp.array([0.0, 10.0, 30.0, 5.0])),
                               [0.0, 0.0, 0.0, 1.5 * 0.6 / 10.0], atol=1e-12)
    # rotated: the station is along `direction`
    rot = vs.GripProfile(stations=jnp.array([0.0, 10.0]), scales=jnp.array([0.4, 1.0]),
                         origin=jnp.array([1.0, 1.0]), direction=jnp.pi / 2)
    np.testing.assert_allclose(rot.scale_at(100.0, 6.0), 0.7, atol=1e-12)


def test_grip_patches_and_axles():
    patches = vs.GripPatches(centres=jnp.array([[20.0, 0.0], [0.0, 50.0]]),
                             radii=jnp.array([5.0, 3.0]), scales=jnp.array([0.3, 1.2]),
                             base=0.8, width=0.5)
    np.testing.assert_allclose(patches.scale_at(20.0, 0.0), 0.3, atol=1e-6)
    np.testing.assert_allclose(patches.scale_at(-40.0, 0.0), 0.8, atol=1e-12)
    np.testing.assert_allclose(patches.scale_at(25.0, 0.0), 0.55, atol=1e-12)  # edge: mean
    np.testing.assert_allclose(patches.scale_at(0.0, 50.0), 1.2, atol=1e-4)
    grad = jax.grad(lambda x: patches.scale_at(x, 0.0))(20.0)  # at a centre: finite, 0
    assert np.isfinite(grad) and abs(grad) < 1e-9
    # each axle reads the field at its own contact point
    plant = vs.DrivePlant(grip=patches)
    lF, lR = float(plant.params.lF), float(plant.params.lR)
    s = vs.init_drive(plant, vx=10.0, x=25.0 - lF, psi=0.0).car
    lamF, lamR = plant.grip_scales(s)
    np.testing.assert_allclose([lamF, lamR],
                               [0.55, patches.scale_at(25.0 - lF - lR, 0.0)], atol=1e-12)
    s = vs.init_drive(plant, vx=10.0, y=50.0 - lR, psi=-jnp.pi / 2).car  # heading -y
    np.testing.assert_allclose(plant.grip_scales(s)[1], 1.2, atol=1e-4)
    # and the tire under the front axle has its friction scaled by lambda_F
    tF = plant.car_at(vs.init_drive(plant, vx=10.0, x=20.0 - lF).car).tires[0]
    np.testing.assert_allclose(tF.params.mu_s, plant.tire.params.mu_s * patches.scale_at(20.0, 0.0))


def test_sensor_noise_statistics():
    sensors = vs.DriveSensors()
    plant = vs.DrivePlant(sensors=sensors)
    state = vs.init_drive(plant, vx=12.0, x=3.0, y=-2.0, psi=0.3)
    keys = jax.random.split(jax.random.key(7), 4000)
    ms = jax.jit(jax.vmap(lambda k: vs.measure_drive(plant, state, k)))(keys)
    truth = vs.measure_drive(vs.DrivePlant(sensors=vs.DriveSensors(noise_on=False)), state,
                             keys[0])
    n = keys.shape[0]
    for name, std in (("omega", sensors.wheel_speed_std), ("yaw_rate", sensors.yaw_rate_std),
                      ("ax", sensors.acceleration_std), ("ay", sensors.acceleration_std),
                      ("vx", sensors.velocity_std), ("vy", sensors.velocity_std),
                      ("x", sensors.position_std), ("y", sensors.position_std),
                      ("psi", sensors.heading_std)):
        err = (np.asarray(getattr(ms, name)) - np.asarray(getattr(truth, name))).reshape(n, -1)
        assert np.all(np.abs(err.mean(0)) < 4 * float(std) / np.sqrt(n)), name
        np.testing.assert_allclose(err.std(0), float(std), rtol=0.06, err_msg=name)
    # channels are independent draws
    c = np.corrcoef(np.asarray(ms.x) - float(truth.x), np.asarray(ms.y) - float(truth.y))[0, 1]
    assert abs(c) < 0.1


def test_continued_drive_draws_the_longer_drives_noise(run_schedule):
    """The noise of sample k is keyed by the plant's own sample count: a noisy drive
    continued from a mid-drive state with the same key measures what the one drive
    measured (a constant command, so the continued controller issues the same)."""
    plant = vs.DrivePlant()
    ctrl = vs.CommandSchedule(_commands()[:1])
    key = jax.random.key(3)
    whole = run_schedule(plant, ctrl, vs.init_drive(plant, vx=12.0), key)
    half = N // 2
    middle = jax.tree_util.tree_map(lambda a: a[half - 1], whole.states)
    assert int(middle.k) == half
    rest = run_schedule(plant, ctrl, middle, key)
    for name in ("omega", "vx", "x", "ay"):
        np.testing.assert_allclose(np.asarray(getattr(rest.measurements, name))[:half],
                                   np.asarray(getattr(whole.measurements, name))[half:],
                                   rtol=1e-9, atol=1e-9, err_msg=name)


def test_batch_of_256_drives_in_one_call():
    plant = vs.DrivePlant(grip=vs.GripPatches(centres=jnp.array([[8.0, 0.0]]),
                                              radii=jnp.array([3.0]), scales=jnp.array([0.3]),
                                              base=0.8))
    ctrl = vs.PathFollower(curvature=0.02, torque=jnp.array([0.0, 400.0]),
                           pulse_torque=jnp.array([-1500.0, -1500.0]), pulse_width=0.2,
                           pulse_period=0.4)
    speeds = jnp.full(256, 12.0).at[0].set(20.0)
    keys = jax.random.split(jax.random.key(1), 256)

    def one(v, key):
        run = vs.simulate_drive(plant, ctrl, vs.init_drive(plant, vx=v), key, 6)
        return run.final.car, run.measurements.ay

    final, ay = jax.jit(jax.vmap(one))(speeds, keys)
    assert final.shape == (256, plant.nominal_car.state_size)
    assert np.all(np.isfinite(final)) and np.all(np.isfinite(ay))
    # the same car under 255 seeds: the sensor noise steers each drive its own way
    assert np.unique(np.asarray(final[1:, 1])).size == 255
    assert final[0, 0] > final[1:, 0].max()  # the faster car went further


def test_forward_gradient_of_final_x_wrt_torque(run_schedule):
    plant = _quiet()
    s0 = vs.init_drive(plant, vx=10.0)
    key = jax.random.key(0)

    def final_x(T):
        table = _commands().at[:, 1].set(T)
        return run_schedule(plant, vs.CommandSchedule(table), s0, key).final.car[0]

    T0, h = 500.0, 1.0
    fd = (final_x(T0 + h) - final_x(T0 - h)) / (2 * h)
    _, fwd = jax.jvp(final_x, (T0,), (1.0,))
    assert np.isfinite(fwd) and fwd > 0
    np.testing.assert_allclose(fwd, fd, rtol=1e-4)
    # reverse mode works too, but its compilation takes minutes: not tested here


def test_a_magic_formulas_road_friction_factors_scale_its_peaks_not_its_stiffness():
    """`scale_friction` on a Magic Formula (the shipped .tir file) multiplies LMUX and LMUY:
    on a road of scale 0.6 the pure-slip peaks of $F_x$ and $F_y$ are 0.6 times the
    nominal ones and the slopes at zero slip are the same to the vertical shifts (as for
    LuGre, where they are the same exactly); a
    tire it cannot scale is refused, naming the families it can."""
    P = _sample_magic_formula()
    tire = vs.MFTire(P)
    lam, Fz, V, r = 0.6, 3500.0, 15.0, 0.3

    def forces(t, kappa, tan_alpha):
        return jax.vmap(lambda k, a: t.forces(t.init_state(), V, a * V, (1.0 + k) * V / r,
                                              r, Fz))(kappa, tan_alpha)

    k = jnp.linspace(-0.6, 0.6, 4801)
    a = jnp.tan(jnp.linspace(-0.5, 0.5, 4001))
    scaled = vs.scale_friction(tire, lam)
    for t, ratio in ((tire, 1.0), (scaled, lam)):
        Fx = forces(t, k, 0.0 * k)[:, 0]
        Fy = forces(t, 0.0 * a, a)[:, 1]
        if ratio == 1.0:
            peaks = float(jnp.max(jnp.abs(Fx))), float(jnp.max(jnp.abs(Fy)))
        else:
            np.testing.assert_allclose(float(jnp.max(jnp.abs(Fx))), lam * peaks[0], rtol=1e-4)
            np.testing.assert_allclose(float(jnp.max(jnp.abs(Fy))), lam * peaks[1], rtol=1e-4)
    # the slopes at zero slip: the stiffnesses, which LMUX and LMUY leave alone (they move
    # only through the vertical shifts, which scale with the peaks: measured 0.19 % in Fx)
    for i, (kk, aa) in enumerate(((1.0, 0.0), (0.0, 1.0))):
        stiff = [jax.jacfwd(lambda s: forces(t, kk * s, aa * s)[:, i])(jnp.zeros(1))[0, 0]
                 for t in (tire, scaled)]
        assert abs(float(stiff[0])) > 1e4
        np.testing.assert_allclose(float(stiff[1]), float(stiff[0]), rtol=5e-3)
    # the relaxed tire is scaled the same way, and the plant takes either
    relaxed = vs.scale_friction(vs.RelaxedMFTire(P), lam)
    assert float(relaxed.params.LMUX) == pytest.approx(lam * float(P.LMUX))
    assert float(relaxed.params.LMUY) == pytest.approx(lam * float(P.LMUY))
    vs.DrivePlant(tire=vs.RelaxedMFTire(P))
    with pytest.raises(TypeError, match="Magic Formula"):
        vs.scale_friction(vs.LinearTire(5e4, 4e4), 0.5)


def test_the_planners_tire_on_the_plant_keeps_its_peak_on_the_nominal_road():
    """A plant on the planning car's own tire (`FrictionEllipseTire`, B = 7, C = 1.6,
    D = 0.52): `scale_friction` scales its peak D and keeps B and C; `plant_surface_factor`
    puts it on the scenarios' surfaces by their peaks, so on the nominal road (scale
    `nominal_scale`) the plant's tire is the planner's, with the benchmark's 0.52, and on
    20 % less grip its peak is the LuGre plant's ratio of peaks (0.8)."""
    tire = vs.FrictionEllipseTire(B=7.0, C=1.6, D=0.52)
    scaled = vs.scale_friction(tire, 0.6)
    assert (float(scaled.B), float(scaled.C)) == (7.0, 1.6)
    assert float(scaled.D) == pytest.approx(0.312, rel=1e-12)
    sc = vs.drive_scenario("corner90", "nominal", tire=tire)
    m = sc.plant.surface_factor
    assert m is not None and float(m(vs.nominal_scale())) == pytest.approx(1.0, rel=1e-9)
    lam = vs.scale_for_peak(0.8 * 0.52)
    assert float(m(lam)) == pytest.approx(0.8, rel=2e-3)
    assert vs.plant_surface_factor(None) is None  # the LuGre plant: the scales themselves
