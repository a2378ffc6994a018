"""Batched sweeps sharded across (2 forced host) devices, and the `vehsim sweep` command."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim import HalfCar, rally_gravel, rally_gravel_tire, result_name, simulate
from vehsim._sweep import _sweep_run, sweep, sweep_grid
from vehsim.cli import main
from vehsim.sharding import pad_members, sharded_vmap
from vehsim.vehicle.maneuvers import half_car_scenario, step_steer


ROOT = Path(__file__).parent.parent


def test_grid_is_a_cartesian_product():
    g = sweep_grid(m=[1.0, 2.0], h=[3.0, 4.0, 5.0])
    np.testing.assert_array_equal(g["m"], [1, 1, 1, 2, 2, 2])
    np.testing.assert_array_equal(g["h"], [3, 4, 5, 3, 4, 5])


def test_sweep_is_sharded_equals_loop_and_reports_failures():
    assert jax.device_count() == 2  # tests/conftest.py forces 2 host devices
    base = HalfCar(rally_gravel(), rally_gravel_tire())
    ts = jnp.linspace(0.0, 1.5, 16)

    def scenario(member):  # inputs sampled on ts (linearly interpolated)
        car = eqx.tree_at(lambda c: (c.params.m, c.params.K_F), base,
                          (member["m"], member["K_F"]))
        inputs = jax.vmap(lambda t: step_steer(member["delta"], t_step=0.2)(t, None))(ts)
        return car, inputs, car.init_state(vx=15.0)

    # 3 members (padded to 4 over 2 devices); the last has a 1e11 N/m front suspension:
    # too stiff for an explicit solver in 3000 steps, so it fails alone.
    members = {"m": jnp.array([1200.0, 1450.0, 1450.0]), "delta": jnp.array([0.05, 0.1, 0.1]),
               "K_F": jnp.array([65e3, 65e3, 1e11])}
    res = sweep(scenario, members, ts, max_steps=3000)
    assert res.num_devices == 2
    assert len(res.trajectories.states.sharding.device_set) == 2
    assert res.trajectories.states.shape == (3, 16, 12)
    np.testing.assert_array_equal(res.ok, [True, True, False])
    assert result_name(res.result) == ["successful", "successful", "max_steps_reached"]
    @eqx.filter_jit
    def alone(member):  # the loop's body: one member, not batched, on one device
        car, u, y0 = scenario(member)
        return simulate(car, ts, u, y0, max_steps=3000).states

    for i in range(2):
        states = alone(jax.tree.map(lambda x: x[i], members))
        np.testing.assert_allclose(res.trajectories.states[i], states, rtol=1e-9, atol=1e-9)
    # another sweep of the same scenario over other member values reuses the compiled run
    traces = eqx.debug.get_num_traces(_sweep_run)
    again = sweep(scenario, jax.tree.map(lambda x: x[::-1], members), ts, max_steps=3000)
    assert eqx.debug.get_num_traces(_sweep_run) == traces
    np.testing.assert_array_equal(again.ok, [False, True, True])
    with pytest.raises(ValueError, match="same leading axis"):
        sweep(scenario, {"m": jnp.zeros(2), "delta": jnp.zeros(3)}, ts)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_cli_sweep_json_and_the_same_sweep_on_two_processes(tmp_path, capsys):
    """One process writes JSON; two CPU processes on the loopback interface, one device
    each (jax.distributed), run the same sweep and gather it into one netCDF file."""
    grid = ["sweep", "--maneuver", "step_steer", "--set", "delta=0.02,0.04,0.08",
            "--duration", "2", "--samples", "11", "--speed", "15", "--signals"]
    env = dict(os.environ, PYTHONPATH=str(ROOT), JAX_NUM_CPU_DEVICES="1",  # one device each
               XLA_FLAGS="--xla_backend_optimization_level=0")
    port = _free_port()
    procs = [subprocess.Popen(
        [sys.executable, "-m", "vehsim", *grid, "--coordinator", f"127.0.0.1:{port}",
         "--num-processes", "2", "--process-id", str(i), "--out", str(tmp_path / "two.nc")],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for i in range(2)]
    try:
        out = tmp_path / "sweep.json"
        rc = main(grid + ["--out", str(out)])
        outs, logs = zip(*(p.communicate(timeout=600) for p in procs))
    finally:
        for p in procs:
            p.kill()
    assert rc == 0
    assert capsys.readouterr().err.count(  # 3 padded to 4 for 2 devices, and said so
        "sweep: 100% (4/4 members, 1 of them padding)") == 1
    data = json.loads(out.read_text())
    assert data["num_devices"] == 2 and data["axes"] == {"delta": [0.02, 0.04, 0.08]}
    rows = data["members"]
    assert [r["delta"] for r in rows] == [0.02, 0.04, 0.08]
    assert all(r["ok"] and r["status"] == "successful" for r in rows)
    yaw = [r["max_abs_yaw_rate"] for r in rows]
    assert yaw[0] < yaw[1] < yaw[2]  # more steering, more yaw
    print("\n".join(f"--- process {i}:\n{log}" for i, log in enumerate(logs)))
    assert [p.returncode for p in procs] == [0, 0], logs
    # a sweep writes its file and nothing on stdout, not even the collectives' connection
    # lines (gloo prints "[Gloo] Rank 0 is connected ..." on the C library's stdout)
    assert outs == ("", ""), outs
    assert "of 2 processes (this is process 1)" in logs[1]
    assert "sweep: 100% (2/2 members)," in logs[0]  # each process runs its own half,
    assert "sweep: 100% (2/2 members, 1 of them padding)" in logs[1]  # the padding its last
    xr = pytest.importorskip("xarray")
    two = xr.load_dataset(tmp_path / "two.nc")
    assert two.attrs["num_devices"] == 2 and list(two["status"].values) == ["successful"] * 3
    np.testing.assert_array_equal(two["delta"], [0.02, 0.04, 0.08])
    for name in ("yaw_rate", "Fz_F", "x"):  # the gathered result equals the single process's
        np.testing.assert_allclose(two[name], [r["signals"][name] for r in rows],
                                   rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(two["max_abs_yaw_rate"], yaw, rtol=1e-12)
    assert two["yaw_rate"].attrs["units"] == "rad/s"
    assert main(["sweep", "--set", "nonsense=1", "--out", str(out)]) == 2


def test_sharded_vmap_in_chunks_equals_vmap():
    # 7 members padded to 8 over 2 devices, 4 per device run in chunks of 3 (a remainder
    # chunk of 1), a replicated argument; an adaptive solve per member
    def fn(member, scale):
        sol = dfx.diffeqsolve(dfx.ODETerm(lambda t, y, k: -k * y + jnp.sin(t)), dfx.Tsit5(),
                              0.0, 2.0, None, member["y0"], args=member["k"],
                              stepsize_controller=dfx.PIDController(rtol=1e-8, atol=1e-8))
        return scale * sol.ys[-1], sol.stats["num_steps"]

    members = {"y0": jnp.linspace(-1.0, 1.0, 7), "k": jnp.geomspace(0.1, 100.0, 7)}
    expected = jax.vmap(fn, in_axes=(0, None))(members, 2.0)
    run = jax.jit(sharded_vmap(fn, jax.devices(), in_axes=(0, None), batch_size=3))
    got = jax.tree.map(lambda x: x[:7], run(pad_members(members, 2), 2.0))
    np.testing.assert_allclose(got[0], expected[0], rtol=1e-12)
    np.testing.assert_array_equal(got[1], expected[1])
    assert len(set(np.asarray(got[1]))) > 3  # the members take different step counts


@pytest.mark.parametrize("maneuver, axis, message", [
    ("brake_in_turn", "delta=0.1,100", r"brake_in_turn.delta must lie in [-1.5708, 1.5708], got 100"),
    ("brake_in_turn", "t_brake=-1", "brake_in_turn.t_brake must lie in [0, inf), got -1"),
    ("brake_in_turn", "brake_torque=-100", "brake_in_turn.brake_torque must lie in [0, inf)"),
    ("brake_in_turn", "front_share=1.5", "brake_in_turn.front_share must lie in [0, 1]"),
    ("step_steer", "rise=0", "step_steer.rise must lie in (0, inf), got 0"),
])
def test_bad_maneuver_values_are_refused_before_the_run(maneuver, axis, message, capsys,
                                                        tmp_path):
    """The maneuvers check their arguments as the models do: a sweep over a steering angle
    of 100 rad or a negative braking time ends with exit 2 naming it, before any run."""
    rc = main(["sweep", "--maneuver", maneuver, "--set", axis,
               "--out", str(tmp_path / "unused.json")])
    assert rc == 2
    err = capsys.readouterr().err
    assert message in err and f"--set {axis.split('=')[0]}=" in err, err  # the axis named
    assert not (tmp_path / "unused.json").exists()


def test_bad_member_values_are_refused_before_the_run(capsys, tmp_path):
    """A negative mass is refused with the single model's error (field and range), from the
    library and from the command line (exit status 2), before any batched work."""
    scenario = half_car_scenario(rally_gravel(), rally_gravel_tire(), "brake_in_turn", 20.0,
                                 ["m", "delta"])
    traces = eqx.debug.get_num_traces(_sweep_run)
    with pytest.raises(ValueError,
                       match=r"^m=-5: HalfCarParams\.m must lie in \(0, inf\), got -5$"):
        sweep(scenario, sweep_grid(m=[1200.0, -5.0], delta=[0.02, 0.04]), jnp.linspace(0, 1, 3))
    assert eqx.debug.get_num_traces(_sweep_run) == traces  # nothing was compiled or run
    rc = main(["sweep", "--maneuver", "brake_in_turn", "--set", "m=-5",
               "--out", str(tmp_path / "unused.json")])
    assert rc == 2
    assert "--set m=-5: HalfCarParams.m must lie in (0, inf), got -5" in capsys.readouterr().err


def test_members_set_with_tree_at_meet_the_constructors_checks_before_the_run():
    """The scenario of docs/sweeps.md edits the car with `eqx.tree_at`, which runs no
    construction check: a NaN mass, a negative peak friction or a NaN start speed is still
    refused before the run with the single model's error, not run into max_steps_reached
    or a successful drive on negative grip."""
    base = HalfCar(rally_gravel(), rally_gravel_tire())

    def scenario(member):
        car = eqx.tree_at(lambda c: (c.params.m, c.tire.D), base, (member["m"], member["D"]))
        return car, step_steer(0.06, t_step=0.2), car.init_state(vx=member["speed"])

    traces = eqx.debug.get_num_traces(_sweep_run)
    ts = jnp.linspace(0.0, 1.0, 3)
    for grid, message in (
            (dict(m=[1200.0, np.nan], D=[0.5, 0.6], speed=[10.0, 20.0]),
             r"^m=nan: HalfCarParams\.m must be finite, got nan$"),
            (dict(m=[1450.0, 1200.0], D=[0.5, -1.0], speed=[10.0, 20.0]),
             r"^D=-1: FrictionEllipseTire\.D must lie in \(0, inf\), got -1$"),
            (dict(m=[1450.0, 1200.0], D=[0.5, 0.6], speed=[10.0, np.nan]),
             r"^speed=nan: simulate: state0 must be finite; non-finite values in vx, ")):
        with pytest.raises(ValueError, match=message):
            sweep(scenario, sweep_grid(**grid), ts)
    assert eqx.debug.get_num_traces(_sweep_run) == traces  # nothing was compiled or run


def test_cli_sweep_notes_a_lifted_axle_and_writes_netcdf_for_an_upper_case_suffix(tmp_path,
                                                                                capsys):
    """Braking in a turn with the centre of mass 30 m up lifts both axles' loads below 0
    (the model runs them unloaded): the member is still a successful solve, and the command
    says how many members lifted an axle; 0.5 m lifts none. ``.NC`` is netCDF."""
    xr = pytest.importorskip("xarray")
    out = tmp_path / "lift.NC"
    assert main(["sweep", "--maneuver", "brake_in_turn", "--set", "h=0.5,30", "--duration",
                 "2", "--samples", "11", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "note: in 1 of 2 members an axle lifted (min_Fz_F or min_Fz_R below 0)" in err
    data = xr.load_dataset(out)  # netCDF, not JSON
    np.testing.assert_array_equal(data["h"], [0.5, 30.0])
    assert list(data["status"].values) == ["successful"] * 2
    low, tall = (min(float(data["min_Fz_F"][i]), float(data["min_Fz_R"][i])) for i in (0, 1))
    assert low > 0 > tall
