"""Labelled results (vehsim.labelled): sweeps, robot grids and primitives as xarray datasets,
and their netCDF round trip. The batches are built by hand with values that encode their
member, so a value landing in the wrong cell fails (no solve to compile)."""

import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim import (
    RESULTS,
    HalfCar,
    ReducedHalfCar,
    SweepResult,
    Trajectory,
    rally_gravel,
    rally_gravel_tire,
    sweep_grid,
)
from vehsim.labelled import (
    UNITS,
    member_axes,
    primitives_to_xarray,
    robot_grid_to_xarray,
    units_of,
)
from vehsim.optimal.ip import IPSolution
from vehsim.optimal.ip.solver import IPLog
from vehsim.optimal.primitive import Primitive
from vehsim.optimal.primitives import rally_gravel_car
from vehsim.optimal.roads import road
from vehsim.optimal.shooting import IDX_TF, NU, NX, ManeuverOCP
from vehsim.robot.khepera import RobotRun
from vehsim.robot.scoring import RunStats


xr = pytest.importorskip("xarray")


def _results(where, a, b):
    """A batch of `RESULTS`: `a` where `where`, else `b`."""
    return jax.vmap(lambda w: RESULTS.where(w, a, b))(where)


def _fake_sweep(members, ts, failed=()):
    """A `SweepResult` whose signal ``x`` is m * t + delta, ``speed`` is -m: every value
    says which member it belongs to."""
    m, d = np.asarray(members["m"]), np.asarray(members["delta"])
    n, T = len(m), len(ts)
    names = HalfCar(rally_gravel(), rally_gravel_tire()).signals(
        jnp.zeros(12), jnp.zeros(3)).keys()
    signals = {k: jnp.zeros((n, T)) for k in names}
    signals["x"] = jnp.asarray(m[:, None] * ts[None] + d[:, None])
    signals["speed"] = jnp.asarray(np.repeat(-m[:, None], T, 1))
    result = _results(jnp.isin(jnp.arange(n), jnp.asarray(failed, int)),
                      RESULTS.max_steps_reached, RESULTS.successful)
    traj = Trajectory(ts=jnp.tile(ts, (n, 1)), states=jnp.zeros((n, T, 12)),
                      controls=jnp.zeros((n, T, 3)), signals=signals, result=result,
                      stats={"num_steps": jnp.arange(n) + 10})
    return SweepResult(members=members, trajectories=traj, result=result, num_devices=2)


def test_every_vehicle_signal_has_units():
    for car in (HalfCar(rally_gravel(), rally_gravel_tire()), ReducedHalfCar(rally_gravel(),
                                                                            rally_gravel_tire())):
        n, m = len(car.state_names), len(car.control_names)
        missing = [k for k in car.signals(jnp.ones(n), jnp.ones(m) * 0.1) if k not in UNITS]
        assert not missing, f"{type(car).__name__} signals without units: {missing}"
    assert units_of("max_abs_ay") == {"units": "m/s^2",
                                      "long_name": "peak |lateral acceleration (body frame)|"}
    assert units_of("final_speed")["units"] == "m/s" and units_of("nonsense") == {}


def test_sweep_grid_becomes_dimensions_with_units_status_and_netcdf_round_trip(tmp_path):
    members = sweep_grid(m=[1200.0, 1450.0], delta=[0.02, 0.04, 0.08])
    ts = jnp.linspace(0.0, 1.0, 5)
    res = _fake_sweep(members, ts, failed=[4])  # member 4: m = 1450, delta = 0.04
    ds = res.to_xarray(outputs={"final_speed": -members["m"]}, attrs={"maneuver": "test"})
    assert ds["x"].dims == ("m", "delta", "t") and ds.sizes == {"m": 2, "delta": 3, "t": 5}
    np.testing.assert_array_equal(ds["delta"], [0.02, 0.04, 0.08])
    cell = ds.sel(m=1450.0, delta=0.08)
    np.testing.assert_allclose(cell["x"], 1450.0 * np.asarray(ts) + 0.08)
    # the steering signal is named like the swept delta: it becomes delta_t
    assert ds["delta_t"].dims == ("m", "delta", "t") and ds["delta_t"].attrs["units"] == "rad"
    np.testing.assert_array_equal(ds["speed"].sel(delta=0.04, t=0.5), [-1200.0, -1450.0])
    np.testing.assert_array_equal(ds["final_speed"].sel(delta=0.02), [-1200.0, -1450.0])
    assert ds["x"].attrs["units"] == "m" and ds["m"].attrs["units"] == "kg"
    assert ds["delta"].attrs["units"] == "rad" and ds["t"].attrs["units"] == "s"
    assert ds["status"].sel(m=1450.0, delta=0.04).item() == "max_steps_reached"
    assert int((ds["status"] == "successful").sum()) == 5 and not bool(ds["ok"][1, 1])
    np.testing.assert_array_equal(ds["num_steps"].values.ravel(), np.arange(6) + 10)
    assert ds.attrs["maneuver"] == "test" and ds.attrs["num_devices"] == 2
    path = res.to_netcdf(tmp_path / "sub" / "sweep.nc", outputs={"final_speed": -members["m"]},
                         attrs={"maneuver": "test"})
    back = xr.load_dataset(path)
    xr.testing.assert_identical(back, ds)


def test_members_that_are_not_a_grid_keep_a_member_dimension():
    members = {"m": jnp.array([1200.0, 1450.0, 1450.0]), "delta": jnp.array([0.1, 0.1, 0.2])}
    assert member_axes(members) is None
    assert member_axes(sweep_grid(a=[1, 2], b=[3, 4, 5])) is not None
    ts = jnp.linspace(0.0, 1.0, 3)
    ds = _fake_sweep(members, ts).to_xarray(signals=["x"])
    assert ds["x"].dims == ("member", "t") and list(ds.data_vars) == ["status", "ok",
                                                                      "num_steps", "x"]
    np.testing.assert_array_equal(ds["m"], members["m"])
    assert ds["m"].dims == ("member",) and ds["m"].attrs["units"] == "kg"
    np.testing.assert_allclose(ds["x"].sel(member=2), 1450.0 * np.asarray(ts) + 0.2)
    # one name as a string is that signal, not its letters; a name not saved is refused
    one = _fake_sweep(members, ts).to_xarray(signals="vx")
    assert list(one.data_vars) == ["status", "ok", "num_steps", "vx"]
    with pytest.raises(ValueError, match=r"signals \['v_x'\] are not in the sweep's"):
        _fake_sweep(members, ts).to_xarray(signals=["x", "v_x"])


def test_missing_xarray_says_how_to_install_it(monkeypatch):
    members = sweep_grid(m=[1.0], delta=[0.1])
    res = _fake_sweep(members, jnp.linspace(0.0, 1.0, 2))
    monkeypatch.setitem(sys.modules, "xarray", None)
    with pytest.raises(ImportError, match=r"pip install 'vehsim\[xarray\]'"):
        res.to_xarray()


def test_robot_grid_labels_controllers_systems_missions_and_seeds():
    C, S, M, seeds = 2, 2, 3, 2
    P = M * seeds
    code = np.arange(C * S * P, dtype=float).reshape(C, S, P)  # which run, as a number
    stats = jax.vmap(jax.vmap(jax.vmap(RunStats.init)))(jnp.full((C, S, P), 40.0))
    # converged at t_c = code / 10 s (well within 10 s: E or G), one run non-finite
    stats = stats.__class__(**{**{k: getattr(stats, k) for k in stats.__dataclass_fields__},
                               "t_out_position": jnp.asarray(code / 10),
                               "finite": jnp.asarray(code != 7)})
    # the status is each run's result, as the run reports it: run 7 non-finite, and run 5
    # with another case (as a plant with an adaptive integrator could report), which no
    # finiteness flag would give
    def result(c):
        return RESULTS.where(c == 7, RESULTS.nonfinite, RESULTS.where(
            c == 5, RESULTS.max_steps_reached, RESULTS.successful))

    run = RobotRun(None, None, None, None, jnp.stack([code, -code, 0 * code], -1), stats,
                   stats, jax.vmap(jax.vmap(jax.vmap(result)))(jnp.asarray(code)))
    ds = robot_grid_to_xarray(run, ["c1", "c2"], ["I", "II"], missions=["E", "N", "S"])
    assert ds["final_x"].dims == ("controller", "system", "mission", "seed")
    # run 7 = controller 0, system 1, pose index 1 = mission E, seed 1
    assert ds["final_x"].sel(controller="c1", system="II", mission="E", seed=1).item() == 7
    assert ds["status"].sel(controller="c1", system="II", mission="E", seed=1).item() \
        == "nonfinite"
    assert int((ds["status"] == "nonfinite").sum()) == 1
    assert ds["status"].sel(controller="c1", system="I", mission="S", seed=1).item() \
        == "max_steps_reached"
    np.testing.assert_allclose(ds["convergence_time"].sel(controller="c2").values.ravel(),
                               code[1].ravel() / 10)
    assert set(np.unique(ds["score"])) <= set("EGSCOU")
    assert ds["convergence_time"].attrs["units"] == "s" and ds["final_gamma"].attrs["units"] \
        == "rad"
    with pytest.raises(ValueError, match="missions x seeds"):
        robot_grid_to_xarray(run, ["c1", "c2"], ["I", "II"], missions=["E", "N", "S", "L"])


def test_batched_primitives_split_over_the_friction():
    D = jnp.array([0.4, 0.52])
    prob = ManeuverOCP(vehicle=rally_gravel_car(), road=road("corner90"), num_stages=4,
                       steps_per_stage=1)
    probs = eqx.tree_at(lambda p: p.vehicle.tire.D, prob, D)  # as vmap_primitives batches
    xs = jnp.zeros((2, 5, NX)).at[:, :, 3].set(8.0).at[:, :, IDX_TF].set(jnp.array([[3.0],
                                                                                     [4.0]]))
    sol = IPSolution(xs=xs, us=jnp.zeros((2, 4, NU)), lam=jnp.zeros((2, 5, NX)),
                     nu=jnp.zeros((2, 1)), z=jnp.zeros((2, 1)),
                     result=_results(jnp.array([True, False]), RESULTS.successful,
                                     RESULTS.ip_max_iterations),
                     iterations=jnp.array([12, 500]), objective=jnp.zeros(2),
                     inf_pr=jnp.zeros(2), inf_du=jnp.zeros(2), compl=jnp.zeros(2),
                     log=jax.vmap(lambda _: IPLog.empty(3))(D))
    ds = primitives_to_xarray(Primitive(problem=probs, solution=sol))
    np.testing.assert_allclose(ds["D"], D)
    np.testing.assert_allclose(ds["t_f"], [3.0, 4.0])
    np.testing.assert_allclose(ds["exit_speed"], [8.0, 8.0])
    assert list(ds["status"].values) == ["successful", "ip_max_iterations"]
    np.testing.assert_array_equal(ds["iterations"], [12, 500])
    np.testing.assert_allclose(ds["t"].sel(D=0.52)[-1], 4.0)
    assert ds["vx"].dims == ("D", "node") and ds["Fz_F"].attrs["units"] == "N"
    assert ds.attrs["road"] == "corner90" and ds.attrs["objective"] == "min-time"
