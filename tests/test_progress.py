"""Progress on long work (vehsim.progress): the host-side bar, and the callbacks compiled into
chunked sharded runs, the robot grid and Levenberg-Marquardt; results never change."""

import io

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from vehsim import BoundedController, SystemII, simulate_robot_grid
from vehsim.identify.levenberg_marquardt import LevenbergMarquardt
from vehsim.progress import ProgressBar, progress_bar, resolve, set_default
from vehsim.sharding import pad_members, sharded_vmap


def test_bar_prints_a_line_per_tenth_in_logs_and_a_final_line():
    out = io.StringIO()  # not a terminal: a new line per 10 %, as in a batch job's log
    bar = ProgressBar("sweep", 20, "members", stream=out)
    for _ in range(7):
        bar.advance(3)  # 3, 6, ..., 21 -> clipped at 20
    bar.close()
    lines = out.getvalue().splitlines()
    assert [line.split(",")[0] for line in lines] == [
        "sweep: 15% (3/20 members)", "sweep: 30% (6/20 members)", "sweep: 45% (9/20 members)",
        "sweep: 60% (12/20 members)", "sweep: 75% (15/20 members)",
        "sweep: 90% (18/20 members)", "sweep: 100% (20/20 members)"]
    assert "left" not in lines[-1]
    out = io.StringIO()
    bar = ProgressBar("fit", 100, "steps", stream=out, value_name="loss", eta=False)
    for step, loss in [(1, np.inf), (2, 3.0), (12, 0.5), (9, 2.0)]:
        bar.reach(step, loss)  # positions only move forward; the least value is kept
    bar.close()
    last = out.getvalue().splitlines()[-1]
    assert last.startswith("fit: 12% (12/100 steps)") and last.endswith(", loss 0.5")


def test_library_default_is_off_and_the_command_line_default_is_restored():
    assert resolve(None) is False and resolve(True) is True
    previous = set_default(True)
    try:
        assert resolve(None) is True and resolve(False) is False
    finally:
        set_default(previous)
    assert resolve(None) is False


def test_chunked_sharded_run_counts_every_member_once_and_is_unchanged():
    def fn(member):
        return jnp.sin(member["a"]) * member["b"], jnp.cos(member["a"])

    members = pad_members({"a": jnp.linspace(0.0, 3.0, 11), "b": jnp.arange(11.0)}, 2)
    plain = jax.jit(sharded_vmap(fn, jax.devices(), batch_size=4))(members)
    out = io.StringIO()
    with progress_bar("run", 12, "members", stream=out) as bar:  # 6 per device: 4 + 2
        counted = jax.block_until_ready(
            jax.jit(sharded_vmap(fn, jax.devices(), batch_size=4, progress=True))(members))
        assert bar.done == 12
    for a, b in zip(plain, counted):
        np.testing.assert_array_equal(a, b)
    assert out.getvalue().splitlines()[-1].startswith("run: 100% (12/12 members)")


def test_robot_grid_progress_counts_samples_of_every_shard_and_keeps_results(capsys):
    poses = jnp.array([[-0.15, 0.03, 0.0], [0.1, 0.15, -1.0]])
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    args = ([BoundedController()], [SystemII()], poses, keys)
    plain = simulate_robot_grid(*args, duration=1.0)
    shown = simulate_robot_grid(*args, duration=1.0, devices=jax.devices(), progress=True)
    np.testing.assert_allclose(shown.final_pose, plain.final_pose, rtol=1e-12, atol=1e-14)
    # 50 samples at 50 Hz on each of 2 shards, reported per block of 50 samples
    assert capsys.readouterr().err.splitlines()[-1].startswith(
        "robot grid: 100% (100/100 samples)")


def test_levenberg_marquardt_reports_its_steps_and_its_least_loss():
    t = jnp.linspace(0.0, 1.0, 20)
    data = 2.0 * jnp.exp(-3.0 * t)

    def residual(u, args):
        return u[0] * jnp.exp(-u[1] * t) - data

    out = io.StringIO()
    with progress_bar("fit", 50, "steps", stream=out, value_name="loss") as bar:
        sol = optx.least_squares(residual, LevenbergMarquardt(1e-10, 1e-10, 1.0, True),
                                 jnp.array([1.0, 1.0]), max_steps=50)
        jax.block_until_ready(sol.value)
        assert bar.done == int(sol.stats["num_steps"])  # one report per step
        # the least loss seen is that of the last accepted step before the final one
        assert 0.0 <= bar.value < 0.5 * float(jnp.sum(residual(jnp.ones(2), None) ** 2))
    np.testing.assert_allclose(sol.value, [2.0, 3.0], rtol=1e-6)
