"""The Khepera plant: each effect against its closed form, and headline findings of 2.1."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import tree_allclose

from vehsim import RESULTS
from vehsim.robot.controllers import (
    AbstractController,
    BoundedController,
    DiscontinuousController,
    PolarController,
)
from vehsim.robot.khepera import (
    KheperaPlant,
    ideal_plant,
    realistic_plant,
    simulate_robot,
    simulate_robot_grid,
)
from vehsim.robot.missions import EASY, LONG_DISTANCE
from vehsim.robot.scoring import score_run
from vehsim.robot.unicycle import SystemI, SystemII


class _Constant(AbstractController):
    v: jax.Array = eqx.field(converter=jnp.asarray)
    omega: jax.Array = eqx.field(converter=jnp.asarray)

    def velocity(self, t, pose, system):
        return self.v + 0 * pose[0], self.omega + 0 * pose[0]


T_FINAL = 1.0
N = 50
B = 0.053


def _run(v, omega, **effects):
    plant = ideal_plant(**effects)
    return simulate_robot(_Constant(v, omega), SystemII(), jnp.zeros(3), plant=plant,
                    duration=T_FINAL)


def test_ideal_plant_is_exact_arc():
    run = _run(0.1, 0.8)
    t = T_FINAL
    expected = [0.1 / 0.8 * np.sin(0.8 * t), 0.1 / 0.8 * (1 - np.cos(0.8 * t)), 0.8 * t]
    np.testing.assert_allclose(run.final_pose, expected, atol=1e-13)
    np.testing.assert_allclose(run.measured, run.pose, atol=0)


def test_a_run_reports_its_result():
    assert _run(0.1, 0.8).result == RESULTS.successful
    assert _run(jnp.nan, 0.8).result == RESULTS.nonfinite  # a command that leaves the numbers


def test_motor_lags_differ_per_wheel():
    """Each wheel follows the command through its own exact first-order lag, sampled at the
    sub-steps (h = T/4): speed v (1 - q^n), q = exp(-h/tau_i), so the robot turns on a
    straight command because the motors differ (report: 'different motor dynamics')."""
    run = _run(0.1, 0.0, motor_dynamics=True)
    tau = np.array([0.06, 0.09])
    h, n = 0.02 / 4, 4 * N
    q = np.exp(-h / tau)
    travel = 0.1 * h * (n - q * (1 - q**n) / (1 - q))           # rectangle sum of speeds
    np.testing.assert_allclose(run.final_pose[2], (travel[1] - travel[0]) / B, rtol=1e-10)
    continuous = 0.1 * (T_FINAL - tau * (1 - np.exp(-T_FINAL / tau)))
    np.testing.assert_allclose(travel, continuous, rtol=5e-3)    # O(h) from the lag ODE


def test_delay_shifts_motion():
    run = _run(0.1, 0.0, delay=True, delay_samples=3)
    np.testing.assert_allclose(run.final_pose[0], 0.1 * (T_FINAL - 3 * 0.02), rtol=1e-12)
    assert float(run.pose[3, 0]) == 0.0 and float(run.pose[4, 0]) > 0.0


def test_read_delay_returns_the_pose_of_d_samples_ago():
    """The link reports the pose `read_delay_samples` samples old; before the first reading
    arrives the host holds the initial pose."""
    plant = ideal_plant(delay=True, delay_samples=0, read_delay_samples=3)
    pose0 = jnp.array([0.01, -0.02, 0.3])
    run = simulate_robot(_Constant(0.1, 0.8), SystemII(), pose0, plant=plant, duration=T_FINAL)
    np.testing.assert_array_equal(run.measured[3:], run.pose[:-3])
    np.testing.assert_array_equal(run.measured[:3], jnp.tile(pose0, (3, 1)))


@pytest.mark.parametrize("v,expected", [(0.004, 0.0), (0.013, 2 / 120), (5.0, None)])
def test_quantization_and_saturation(v, expected):
    run = _run(v, 0.0, quantization=True, saturation=True)
    speed = float(run.final_pose[0]) / T_FINAL
    if expected is None:
        np.testing.assert_allclose(speed, 127 / 120, rtol=1e-12)
    else:
        np.testing.assert_allclose(speed, expected, atol=1e-14)


def test_encoder_odometry_quantised():
    run = _run(0.1, 0.8, encoders=True)
    err = np.abs(np.asarray(run.measured - run.pose))
    assert err[:, :2].max() < 2 / 12000          # within two encoder pulses
    assert err[:, :2].max() > 1e-6               # but not exact: counts are quantised


def test_wheel_mismatch_odometry_sees_a_line_the_robot_drives_an_arc():
    """Wheel diameters 1 % apart and a wheel base 3 % larger than the nominal ones: the
    encoders count the commanded pulses, so the odometry (nominal geometry) reads a straight
    line, while the ground moves at v s_{L,R} under the wheels: an exact arc with
    v = v_c (s_L + s_R)/2 and omega = v_c (s_R - s_L)/(1.03 b)."""
    scale = np.array([0.995, 1.005])
    run = _run(0.1, 0.0, encoders=True, mismatch=True, wheel_scale=scale,
               wheel_base_scale=1.03)
    v, w = 0.1 * scale.mean(), 0.1 * (scale[1] - scale[0]) / (1.03 * B)
    t = T_FINAL
    expected = [v / w * np.sin(w * t), v / w * (1 - np.cos(w * t)), w * t]
    np.testing.assert_allclose(run.final_pose, expected, rtol=1e-12)
    ts = np.asarray(run.ts)
    np.testing.assert_allclose(run.measured[:, 0], 0.1 * ts, atol=1 / 12000)  # one pulse
    np.testing.assert_array_equal(run.measured[:, 1:], 0.0)
    # turning on the spot: the odometry's heading is the commanded one (to a pulse), the
    # true heading 1/1.03 of it
    turn = _run(0.0, 0.8, encoders=True, mismatch=True, wheel_scale=(1.0, 1.0),
                wheel_base_scale=1.03)
    np.testing.assert_allclose(turn.final_pose[2], 0.8 * t / 1.03, rtol=1e-12)
    np.testing.assert_allclose(turn.measured[-1, 2], 0.8 * (t - 0.02), atol=2 / 12000 / B)


def test_wheel_slip_moves_the_robot_and_not_the_odometry():
    """Random slip s_{i,k} ~ N(0, slip_std^2) per wheel and sample (the last two of the five
    normal numbers drawn from fold_in(key, k)):
    on a straight command the true heading is exactly sum_k v T (s_L,k - s_R,k) / b, and
    the encoders, on the motor axes, do not see it."""
    key = jax.random.PRNGKey(7)
    plant = ideal_plant(encoders=True, slip=True, slip_std=0.05)
    run = simulate_robot(_Constant(0.1, 0.0), SystemII(), jnp.zeros(3), plant=plant,
                         duration=T_FINAL, key=key)
    s = 0.05 * jax.vmap(lambda k: jax.random.normal(jax.random.fold_in(key, k), (5,))[3:])(
        jnp.arange(N))
    np.testing.assert_allclose(run.final_pose[2], np.sum(0.1 * 0.02 * (s[:, 0] - s[:, 1])) / B,
                               rtol=1e-12)
    assert abs(float(run.final_pose[2])) > 1e-3                 # the slip did turn it
    no_slip = _run(0.1, 0.0, encoders=True)
    np.testing.assert_array_equal(run.measured, no_slip.measured)


def test_sensor_noise_is_the_documented_draw():
    """White noise on the measured pose: sample k adds sigma * N(0, 1), the first three of
    the five normal numbers drawn from fold_in(key, k), exactly (position 1 mm, heading
    0.01 rad)."""
    key = jax.random.PRNGKey(3)
    plant = ideal_plant(noise=True, noise_position=1e-3, noise_heading=0.01)
    run = simulate_robot(_Constant(0.0, 0.0), SystemII(), jnp.zeros(3), plant=plant,
                         duration=T_FINAL, key=key)
    draws = jax.vmap(lambda k: jax.random.normal(jax.random.fold_in(key, k), (5,))[:3])(
        jnp.arange(N))
    np.testing.assert_array_equal(run.pose, 0.0)
    np.testing.assert_allclose(run.measured, draws * jnp.array([[1e-3, 1e-3, 0.01]]),
                               rtol=1e-15, atol=0)


def test_slip_leaves_the_noise_draws_as_they_are():
    """With the slip off only the pose noise's three numbers are drawn; they are the first
    three of the five drawn with the slip on, so switching the slip on changes no noise."""
    key = jax.random.PRNGKey(4)
    runs = [simulate_robot(_Constant(0.0, 0.0), SystemII(), jnp.zeros(3), key=key,
                           duration=T_FINAL, plant=ideal_plant(noise=True, slip=slip))
            for slip in (False, True)]
    np.testing.assert_array_equal(runs[0].measured, runs[1].measured)
    assert np.all(np.asarray(runs[0].measured) != 0)


def test_plant_validation():
    with pytest.raises(ValueError, match="delay_samples"):
        KheperaPlant(delay_samples=20)
    with pytest.raises(ValueError, match="motor_time_constant"):
        KheperaPlant(motor_time_constant=(0.05, -1.0))
    with pytest.raises(ValueError, match="read_delay_samples"):
        KheperaPlant(read_delay_samples=1.5)
    with pytest.raises(ValueError, match="wheel_scale"):
        KheperaPlant(wheel_scale=(1.0, 0.0))
    with pytest.raises(ValueError, match="slip_std"):
        KheperaPlant(slip_std=-0.1)


def test_controller4_heading_is_noise_sensitive():
    """Report: controller 4 'sensitive to sensor noise resulting in relatively large limit
    cycles of the heading angle around the origin'. Position converges either way; the
    heading over the last 5 s is far worse with white noise on the pose than with the
    odometry alone."""
    c = PolarController()
    noisy = simulate_robot(c, SystemII(), EASY.pose0, plant=realistic_plant(noise=True),
                           save=False)
    quiet = simulate_robot(c, SystemII(), EASY.pose0, plant=realistic_plant(), save=False)
    for run in (noisy, quiet):
        assert float(run.stats.window_position) < 0.01
    assert float(noisy.stats.window_heading) > 5 * float(quiet.stats.window_heading)
    assert float(noisy.stats.window_heading) > 0.5          # > 30 deg excursions


def test_controller2_commands_within_limits_where_controller1_saturates():
    """Report: controller 2's 'velocity commands were always within acceptable limits'.
    On the long-distance mission its commanded speed stays below the Khepera's wheel
    saturation, while the unbounded eq. 1 asks for more than the robot can do."""
    peak = {}
    for name, c in (("1", DiscontinuousController()), ("2", BoundedController())):
        run = simulate_robot(c, SystemI(), LONG_DISTANCE.pose0, plant=realistic_plant(),
                       save=False)
        peak[name] = float(run.stats.peak_command[0])
    assert peak["2"] < 127 / 120 < peak["1"]


def test_grid_equals_single_runs():
    """`simulate_robot_grid` (noise and slip drawn in blocks per initial pose, each law evaluated
    on its own group) gives the same runs as `simulate_robot` one at a time: realistic plant
    with noise and slip, a sample count (115 = 5 x 23) that is not a multiple of the 50-sample noise block."""
    controllers = (DiscontinuousController(), PolarController())
    systems = (SystemII(),)
    poses = jnp.array([[-0.15, 0.03, 0.1], [0.1, 0.15, -1.0]])
    keys = jax.random.split(jax.random.PRNGKey(5), 2)
    plant = realistic_plant(noise=True, slip=True)
    grid = simulate_robot_grid(controllers, systems, poses, keys, plant=plant, duration=2.3,
                               save=True)
    assert grid.pose.shape == (2, 1, 2, 115, 3)
    for c, s, p in [(0, 0, 0), (1, 0, 1)]:
        one = simulate_robot(controllers[c], systems[s], poses[p], key=keys[p], plant=plant,
                             duration=2.3)
        np.testing.assert_allclose(grid.pose[c, s, p], one.pose, rtol=0, atol=1e-14)
        np.testing.assert_allclose(grid.measured[c, s, p], one.measured, rtol=0, atol=1e-14)
        np.testing.assert_allclose(grid.command[c, s, p], one.command, rtol=0, atol=1e-12)
        stats = jax.tree_util.tree_map(lambda a: a[c, s, p], grid.stats)
        assert tree_allclose(stats, one.stats, rtol=0, atol=1e-12)
        odometry_stats = jax.tree_util.tree_map(lambda a: a[c, s, p], grid.odometry_stats)
        assert tree_allclose(odometry_stats, one.odometry_stats, rtol=0, atol=1e-12)
        assert int(score_run(stats)) == int(score_run(one.stats))


def test_grid_sharded_across_devices_equals_single_device():
    """`simulate_robot_grid(..., devices=...)` shards the poses over a device mesh (conftest forces
    2 host devices); 3 poses are padded to 4 and the padding dropped. Same runs, same result."""
    from vehsim.robot.controllers import default_controllers

    assert jax.device_count() == 2
    controllers = default_controllers()[:2]
    poses = jnp.array([[0.3, -0.2, 0.5], [-0.4, 0.1, -1.0], [0.05, 0.3, 2.0]])
    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    single = simulate_robot_grid(controllers, [SystemI()], poses, keys, duration=2.0)
    sharded = simulate_robot_grid(controllers, [SystemI()], poses, keys, duration=2.0,
                            devices=jax.devices())
    assert sharded.final_pose.shape == single.final_pose.shape == (2, 1, 3, 3)
    assert tree_allclose(sharded, single, rtol=0.0, atol=1e-12)
    # the runs really moved (a grid that did nothing would also agree)
    assert np.all(np.abs(np.asarray(single.final_pose - poses[None, None])).max(axis=-1) > 1e-3)


def test_grid_reports_each_runs_result():
    """In a grid, each run's own result: the runs of a law whose command is not a number
    are non-finite, the others successful."""
    controllers = (_Constant(0.1, 0.8), _Constant(jnp.nan, 0.8))
    poses = jnp.array([[0.1, 0.0, 0.0], [0.0, -0.1, 1.0]])
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    grid = simulate_robot_grid(controllers, [SystemII()], poses, keys, duration=0.5)
    successful = np.asarray(grid.result == RESULTS.successful)
    assert successful.shape == (2, 1, 2)
    assert np.all(successful[0])
    assert np.all(np.asarray(grid.result == RESULTS.nonfinite)[1])


def test_statistics_are_those_of_the_samples():
    """The run's statistics are those `accumulate` makes of its saved samples (true pose and
    commands); the odometry's, scored under the same commands, share their command
    statistics (reversals, peak, last command and increment), not those of the pose."""
    from vehsim.robot.controllers import default_controllers
    from vehsim.robot.scoring import RunStats, accumulate

    run = simulate_robot(default_controllers()[0], SystemI(), jnp.array([0.2, -0.1, 0.4]),
                         plant=realistic_plant(noise=True), duration=12.0)
    stats = accumulate(run.ts, run.pose, run.command)
    assert tree_allclose(run.stats, stats, rtol=0, atol=0)
    for name in ("previous_command", "previous_increment", "reversals", "peak_command",
                 "started"):
        np.testing.assert_array_equal(getattr(run.odometry_stats, name), getattr(stats, name))
    assert bool(stats.started) and float(jnp.min(stats.peak_command)) > 0
    initial = RunStats.init(run.stats.t_final)
    assert not tree_allclose(run.odometry_stats.with_command_statistics(initial),
                             run.odometry_stats)
    # and the pose's are the odometry's own (over the last 5 s it is not the true pose)
    assert run.odometry_stats.window_position != stats.window_position
