"""Bad values given to the library (not the command line) are refused at once, by a
`ValueError` that names the function or field and the allowed range: before a solve that
would spend its step budget, report success on nothing, or return NaN."""

import dataclasses
import functools
import re

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs
from vehsim.cli import main
from vehsim.control.controllers.braking import RuleBasedABS
from vehsim.control.estimation.mhe import MovingHorizonEstimator
from vehsim.control.experiments.half_car_abs import turn_scenario
from vehsim.control.experiments.scenarios import braking_scenario
from vehsim.control.loop import simulate_braking
from vehsim.identify.braking import load_braking, save_braking, shipped_brakings
from vehsim.optimal.curvilinear import speed_profile
from vehsim.optimal.ip.solver import IPOptions
from vehsim.optimal.primitives import point_mass_bound
from vehsim.optimal.shooting import ManeuverOCP
from vehsim.robot.controllers import DiscontinuousController
from vehsim.robot.khepera import ideal_plant, simulate_robot
from vehsim.robot.unicycle import SystemI
from vehsim.tire.mf6 import MFParams


P = vs.params.table3()
TS = jnp.linspace(0.0, 0.1, 11)


def _car():
    return vs.QuarterCar(vs.LumpedLuGre(P), mass=350.0, inertia=1.0, radius=0.3)


def _half_car():
    return vs.HalfCar(vs.params.rally_gravel(), vs.rally_gravel_tire())


def _braking():
    scenario, observer = braking_scenario("dry_asphalt", 30.0)
    return scenario, RuleBasedABS(), observer


def _robot(**kw):
    return simulate_robot(DiscontinuousController(), SystemI(), jnp.array([0.0, 0.1, 0.0]),
                          plant=ideal_plant(), **kw)


def _road():
    return vs.CentrelineRoad.from_segments([("straight", 20.0), ("arc", 15.0, 90.0)], 4.0)


CASES = {
    "a NaN speed into a tire": (
        lambda: vs.simulate_tire(vs.LumpedLuGre(P), TS, np.nan, 60.0, 0.3),
        "simulate_tire: vx must be finite, got nan"),
    "an infinite sample of the wheel speed": (
        lambda: vs.simulate_tire(vs.LumpedLuGre(P), TS, 20.0, jnp.full(11, 60.0).at[3].set(
            np.inf), 0.3), "simulate_tire: omega must be finite, got inf"),
    "save times backwards": (
        lambda: vs.simulate_tire(vs.LumpedLuGre(P), TS[::-1], 20.0, 60.0, 0.3),
        "simulate_tire: ts must be increasing, got 0.09 after 0.1 (index 1)"),
    "a NaN save time": (
        lambda: vs.simulate_quarter_car(_car(), TS.at[4].set(np.nan), 800.0, 20.0),
        "simulate_quarter_car: ts must be finite, got nan at index 4"),
    "a NaN start speed of the quarter car": (
        lambda: vs.simulate_quarter_car(_car(), TS, 800.0, np.nan),
        "simulate_quarter_car: v0 must be finite"),
    "a braking of negative duration": (
        lambda: simulate_braking(*_braking(), duration=-1.0),
        "simulate_braking: duration [s] must lie in (0, inf), got -1"),
    "a braking of no substeps": (
        lambda: simulate_braking(*_braking(), substeps=0),
        "simulate_braking: substeps must be an integer >= 1, got 0"),
    "a robot run of NaN duration": (
        lambda: _robot(duration=np.nan), "simulate_robot: duration [s] must lie in (0, inf)"),
    "a robot run shorter than a sample": (
        lambda: _robot(duration=1e-6), "simulate_robot: duration (1e-06 s) must be at least"),
    "a NaN braking speed": (
        lambda: braking_scenario("dry_asphalt", speed=np.nan),
        "BrakingScenario.speed must be finite"),
    "a turn backwards": (
        lambda: turn_scenario(speed=-25.0), "TurnScenario.speed must lie in (0, inf)"),
    "a rear brake share above 1": (
        lambda: turn_scenario(rear_share=2.0), "TurnScenario.rear_share must lie in [0, 1]"),
    "a braking that never starts": (
        lambda: turn_scenario(brake_time=np.nan), "TurnScenario.brake_time must be finite"),
    "a misspelt objective of the bound": (
        lambda: point_mass_bound("corner90", objective="min_time"),
        "PointMassOCP.objective must be 'min-time' or 'max-exit', got 'min_time'"),
    "a negative friction of the bound": (
        lambda: point_mass_bound("corner90", D=-0.5),
        "PointMassOCP.friction must lie in (0, inf), got -0.5"),
    "a negative initial barrier": (
        lambda: IPOptions(mu0=-0.1), "IPOptions.mu0 must lie in (0, inf)"),
    "a negative tolerance": (lambda: IPOptions(tol=-1.0), "IPOptions.tol must lie in (0, inf)"),
    "a backward error accepted of 1": (
        lambda: IPOptions(backward_error_singular=1.0),
        "IPOptions.backward_error_singular must lie in (0, 1), got 1"),
    "a backward error accepted as text": (
        lambda: IPOptions(backward_error_singular="1e-5"),
        "IPOptions.backward_error_singular must be a number, got '1e-5'"),
    "no refinement step": (
        lambda: IPOptions(max_refinement_steps=0),
        "IPOptions.max_refinement_steps must be an integer >= 1, got 0"),
    "a fractional iteration cap": (
        lambda: IPOptions(max_iter=2.5), "IPOptions.max_iter must be an integer >= 1, got 2.5"),
    "no log": (lambda: IPOptions(log_size=0), "IPOptions.log_size must be an integer >= 1"),
    "estimator bounds the wrong way round": (
        lambda: MovingHorizonEstimator(P, 5.0, 1.0),
        "MovingHorizonEstimator needs theta_min <= theta_max, got theta_min = 5"),
    "no estimator starts": (
        lambda: MovingHorizonEstimator(P, starts=0),
        "MovingHorizonEstimator.starts must be an integer >= 1, got 0"),
    "a NaN Magic Formula coefficient": (
        lambda: MFParams(PDX1=np.nan), "MFParams.PDX1 must be finite, got nan"),
    "a negative shape factor": (
        lambda: MFParams(PCX1=-1.0), "MFParams.PCX1 must lie in [0, inf), got -1"),
    "load limits the wrong way round": (
        lambda: MFParams(FZMIN=5000.0, FZMAX=100.0),
        "MFParams needs FZMIN <= FZMAX, got FZMIN = 5000, FZMAX = 100"),
    "a speed profile for negative friction": (
        lambda: speed_profile(_road(), -0.5), "speed_profile.D must lie in (0, inf), got -0.5"),
    "an arc without its angle": (
        lambda: vs.CentrelineRoad.from_segments([("straight", 10.0), ("arc", 10.0)], 4.0),
        "road 'road': segment 1 must be ('arc', radius, angle_deg), got ('arc', 10.0)"),
    "a clothoid with a value too many": (
        lambda: vs.CentrelineRoad.from_segments([("clothoid", 10.0, 0.1, 2.0)], 4.0),
        "segment 0 must be ('clothoid', length, end_curvature), got ('clothoid', 10.0, 0.1, "
        "2.0)"),
    "a margin as wide as half the road": (
        lambda: vs.CurvilinearPointMassOCP.from_road(_road(), num_stages=10, margin=2.0),
        "margin=2 m leaves no road: it must be below half the road's width, 2 m where it is "
        "narrowest"),
    "a speed profile at no fraction of the friction": (
        lambda: speed_profile(_road(), 0.5, 0.0), "speed_profile.fraction must lie in (0, 1]"),
}


def test_a_shipped_magic_formula_file_and_the_default_pass_the_checks():
    MFParams()
    for path in vs.shipped_tires().values():
        MFParams.from_tir(vs.read_tir(path))


def _measured():
    """A short braking as a recorder writes it."""
    t = np.linspace(0.0, 0.2, 201)
    v = 30.0 - 15.0 * t
    return vs.MeasuredBraking(t, v, v / 0.3 * 0.92, np.full_like(t, 800.0))


def _record(**changes):
    d = load_braking(next(iter(shipped_brakings().values())))
    for name, value in changes.items():
        d = eqx.tree_at(lambda x, name=name: getattr(x, name), d, value)
    return d


@pytest.mark.parametrize(("changes", "metadata", "message"), [
    ({}, {"source": object()}, "save_braking: metadata must be JSON"),
    ({"r": jnp.asarray(10.0)}, None, "save_braking: r [m] must lie in (0, 5], got 10"),
    ({"F_n": "nan at 3"}, None, "row 3, column 'F_n': value must be finite, got nan; not saved"),
], ids=["metadata", "radius", "nan"])
def test_save_braking_refuses_what_load_braking_would_and_writes_nothing(tmp_path, changes,
                                                                         metadata, message):
    if changes.get("F_n") == "nan at 3":
        changes["F_n"] = _record().F_n.at[2].set(np.nan)
    with pytest.raises(ValueError) as err:
        save_braking(_record(**changes), tmp_path / "b.csv", metadata=metadata)
    assert message in str(err.value), str(err.value)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(("name", "kw", "message"), [
    ("run.json", {}, "run.json is the name of a side file; give the CSV's path"),
    ("b.csv", {"digits": 2}, "save_braking: digits=2 round the record into one that "
     "load_braking refuses (" ),
    ("b.csv", {"digits": True}, "save_braking: digits must be an integer >= 1, got True"),
    ("b.csv", {"digits": -1}, "save_braking: digits must be an integer >= 1, got -1"),
    ("b.csv", {"metadata": {"r": -1, "units": 5}}, "save_braking: metadata may not set r, "
     "units: the side file's wheel data and units come from the record"),
], ids=["json-path", "ties", "bool-digits", "negative-digits", "reserved-metadata"])
def test_save_braking_refuses_a_side_file_path_rounding_ties_and_reserved_metadata(
        tmp_path, name, kw, message):
    """What would lose the samples (a CSV written under the side file's name), write a
    record `load_braking` refuses (times rounded into ties) or replace the checked wheel
    data, is refused; nothing is written."""
    with pytest.raises(ValueError) as err:
        save_braking(_record(), tmp_path / name, **kw)
    assert message in str(err.value), str(err.value)
    assert list(tmp_path.iterdir()) == []


def test_csv_readers_take_old_mac_line_endings_and_name_an_unreadable_line(tmp_path):
    """Lines ending in a lone \r (old Mac files) read as lines; a field past the csv
    module's size limit is a ValueError naming the file and line, not `_csv.Error`."""
    road = tmp_path / "r.csv"
    road.write_bytes(b"x_m,y_m,w_tr_right_m,w_tr_left_m\r" + b"".join(
        f"{5 * i},0,4,4\r".encode() for i in range(6)))
    assert vs.read_road(road).length == pytest.approx(25.0, rel=1e-6)
    src = next(iter(shipped_brakings().values()))
    mac = tmp_path / "mac.csv"
    mac.write_bytes(src.read_bytes().replace(b"\r\n", b"\n").replace(b"\n", b"\r"))
    (tmp_path / "mac.json").write_bytes(src.with_suffix(".json").read_bytes())
    np.testing.assert_array_equal(load_braking(mac).F_x, load_braking(src).F_x)
    for path, head in ((road, "x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,4,4\n"),
                       (mac, "t,v,omega,F_x,F_n\n")):
        path.write_text(head + "1," + "9" * 200_000 + "\n")
        reader = vs.read_road if path is road else load_braking
        with pytest.raises(ValueError, match=rf"{path.name}:\d+: cannot read this line as CSV"):
            reader(path)


def test_a_side_file_number_past_the_double_range_is_refused_naming_the_key(tmp_path):
    src = next(iter(shipped_brakings().values()))
    (tmp_path / "b.csv").write_bytes(src.read_bytes())
    (tmp_path / "b.json").write_text('{"r": 1' + "0" * 400 + "}")
    with pytest.raises(ValueError, match=r"b.json: 'r' \[m\] must lie in \(0, 5\], got inf"):
        load_braking(tmp_path / "b.csv")


def test_load_result_names_a_json_file_that_is_not_utf8(tmp_path):
    path = tmp_path / "b.json"
    path.write_bytes(b"\xff\xfe{")
    with pytest.raises(ValueError, match="b.json: not a JSON file vehsim wrote"):
        vs.load_result(path)


def test_reader_options_of_the_wrong_kind_are_refused(tmp_path):
    """`closed="no"` would read as a closed road, ``r=True`` as a 1 m wheel."""
    road = tmp_path / "r.csv"
    vs.write_road(road, _road())
    for kw, message in (({"closed": "no"}, "read_road: closed must be True, False or None"),
                        ({"smoothing": "abc"}, "read_road: smoothing [m] must be a number")):
        with pytest.raises(TypeError, match=re.escape(message)):
            vs.read_road(road, **kw)
    assert vs.read_road(road, closed=np.bool_(False), smoothing=np.float64(0.0)).length > 0
    with pytest.raises(ValueError, match="load_braking: r must be a number, got True"):
        load_braking(next(iter(shipped_brakings().values())), r=True)


def test_write_road_refuses_what_read_road_could_not_read_back(tmp_path):
    with pytest.raises(TypeError, match="write_road.road must be a CentrelineRoad, got str"):
        vs.write_road(tmp_path / "r.csv", "notaroad")
    road = vs.CentrelineRoad.from_segments([("straight", 20.0)], 4.0, name="two\nlines")
    with pytest.raises(ValueError, match="holds a line break"):
        vs.write_road(tmp_path / "r.csv", road)
    assert list(tmp_path.iterdir()) == []


def test_save_braking_round_trips_the_pair(tmp_path):
    d = _record()
    save_braking(d, tmp_path / "b.csv", metadata={"source": "a test"})
    back = load_braking(tmp_path / "b.csv")
    np.testing.assert_allclose(back.F_x, d.F_x, rtol=1e-9)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.csv", "b.json"]


def test_load_braking_refuses_the_radius_its_side_file_would(tmp_path):
    path = next(iter(shipped_brakings().values()))
    with pytest.raises(ValueError, match=r"load_braking: r \[m\] must lie in \(0, 5\], got 10"):
        load_braking(path, r=10.0)


def test_save_braking_leaves_no_csv_when_its_side_file_cannot_be_written(tmp_path):
    (tmp_path / "b.json").mkdir()  # the side file's name is taken by a folder
    with pytest.raises(OSError):
        save_braking(_record(), tmp_path / "b.csv")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.json"]


CASES |= {
    "a negative prescribed load": (
        lambda: vs.PrescribedLoad(jnp.array([0.0, 1.0]), jnp.array([3000.0, -3000.0])),
        "PrescribedLoad.values must lie in [0, inf), got [3000, -3000]"),
    "prescribed load times backwards": (
        lambda: vs.PrescribedLoad(jnp.array([1.0, 0.0]), jnp.array([3000.0, 3000.0])),
        "PrescribedLoad: ts must be increasing, got 0 after 1"),
    "a road from a NaN heading": (
        lambda: vs.CentrelineRoad.from_segments([("straight", 20.0)], 4.0,
                                                start_heading=np.nan),
        "start must be a finite point (x, y) [m] and start_heading a finite angle"),
    "a road shorter than a car": (
        lambda: vs.CentrelineRoad.from_segments([("straight", 3.0)], 4.0),
        "road 'road': the centre line is 3 m long; a road must be 5 m to 100000 m long"),
    "a road longer than 100 km": (
        lambda: vs.CentrelineRoad.from_segments([("straight", 6e4), ("arc", 1e3, 90.0),
                                                 ("straight", 6e4)], 4.0),
        "the centre line is 121571 m long at segment 2; a road must be 5 m to 100000 m"),
    "an open road closed by a straight in no file": (
        lambda: vs.CentrelineRoad.from_points(
            40 * np.cos(np.linspace(0, np.pi / 2, 30)), 40 * np.sin(np.linspace(0, np.pi / 2, 30)),
            np.full(30, 4.0), np.full(30, 4.0), closed=True),
        "a closed road, but its last point (row 29) is 56.57 m from its first, 26 times"),
    "a Magic Formula without regularising speed": (
        lambda: vs.MagicFormula1987(vs.params.bakker1987(), v_eps=0.0),
        "MagicFormula1987.v_eps must lie in (0, inf), got 0"),
    "a plant peak on a road of no grip": (
        lambda: vs.plant_peak(0.0), "plant_peak: scale must lie in (0, inf), got 0"),
    "an empty sweep axis": (
        lambda: vs.sweep_grid(m=[1000.0, 1200.0], h=[]),
        "sweep_grid: axis 'h' must be a non-empty list of values"),
    "a sweep in batches of none": (
        lambda: vs.sharded_vmap(lambda x: x, batch_size=0),
        "batch_size must be an integer >= 1 (or None), got 0"),
}


def _fields_of(module):
    return {k: getattr(module, k) for k, f in module.__dataclass_fields__.items() if f.init}


def _braking_of(**columns):
    d = _record()
    return vs.BrakingData(**({c: getattr(d, c) for c in ("t", "v", "omega", "F_x", "F_n", "r",
                                                            "T_b")} | columns))


CASES |= {
    "a braking whose force column is short": (
        lambda: _braking_of(F_x=_record().F_x[:-1]),
        "BrakingData.F_x must have t's shape"),
    "a braking whose torque column is short": (
        lambda: _braking_of(T_b=_record().T_b[1:]), "BrakingData.T_b must have t's shape"),
    "a fit of no starts": (
        lambda: vs.fit_open_loop(_record(), n_starts=0),
        "fit.n_starts must be an integer >= 1, got 0"),
    "a fit with a negative spread": (
        lambda: vs.fit_open_loop(_record(), spread=-0.3), "fit.spread must lie in [0, inf)"),
    "a fit to tolerance 0": (
        lambda: vs.fit_open_loop(_record(), tol=0.0), "fit.tol must lie in (0, 1), got 0"),
    "a fit of a fractional step count": (
        lambda: vs.fit_closed_loop(_record(), max_steps=10.5),
        "fit.max_steps must be an integer >= 1, got 10.5"),
    "a fit with a negative prior": (
        lambda: vs.fit_open_loop(_record(), prior_weight=-1.0),
        "fit.prior_weight must lie in [0, inf)"),
    "an open-loop fit of no substeps": (
        lambda: vs.fit_open_loop(_record(), substeps=0),
        "OpenLoopBraking.substeps must be an integer >= 1, got 0"),
    "a tire started from a state of another shape": (
        lambda: vs.simulate_tire(vs.LumpedLuGre(P), TS, 20.0, 60.0, 0.3, state0=jnp.zeros(3)),
        "simulate_tire: state0 must be shaped as LumpedLuGre.init_state(), (), got (3,)"),
    "a tire of negative radius": (
        lambda: vs.simulate_tire(vs.LumpedLuGre(P), TS, 20.0, -60.0, -0.3),
        "simulate_tire.r must lie in (0, inf), got -0.3"),
    "a word in a parameter field": (
        lambda: type(P)(**{**_fields_of(P), "sigma0": "stiff"}),
        "LuGreParams.sigma0 must be a number or an array of numbers, got 'stiff'"),
    "a word in a car's field": (
        lambda: type(vs.params.rally_gravel())(**{**_fields_of(vs.params.rally_gravel()),
                                                 "m": "heavy"}),
        "HalfCarParams.m must be a number or an array of numbers, got 'heavy'"),
    "a moment model of ill-conditioned degree": (
        lambda: vs.MomentLuGre2D(vs.params.lugre2d_bakker1987(), vs.QuarticLoad(), degree=16),
        "MomentLuGre2D.degree must be at most 12 (the moment tables' conditioning), got 16"),
    "a moment model of a load of ill-conditioned degree": (
        lambda: vs.MomentLuGre2D(vs.params.lugre2d_bakker1987(),
                                 vs.PolynomialLoad(jnp.ones(15))),
        "MomentLuGre2D: the load's polynomial degree 14 exceeds 12"),
    "a moment model of fractional degree": (
        lambda: vs.MomentLuGre2D(vs.params.lugre2d_bakker1987(), vs.QuarticLoad(), degree=4.5),
        "MomentLuGre2D.degree must be an integer >= 0, got 4.5"),
    "a closed-loop fit to a relative tolerance of 1": (
        lambda: vs.fit_closed_loop(_record(), rtol=1.0),
        "ClosedLoopBraking.rtol must lie in (0, 1), got 1"),
}


@functools.lru_cache(maxsize=1)
def _table():
    return vs.RoadTable.from_road(_road(), 0.5)


def _rh_driver(**kw):
    return vs.RecedingHorizonDriver(_table(), **kw)


def _patches(**kw):
    return vs.GripPatches(**({"centres": jnp.array([[10.0, 0.0]]), "radii": jnp.array([3.0]),
                              "scales": jnp.array([0.5])} | kw))


CASES |= {
    "a NaN corridor margin of the driver": (
        lambda: _rh_driver(margin=np.nan), "RecedingHorizonDriver.margin must be finite"),
    "a negative corridor margin of the driver": (
        lambda: _rh_driver(margin=-0.1),
        "RecedingHorizonDriver.margin must lie in [0, inf), got -0.1"),
    "a NaN margin power of the driver": (
        lambda: _rh_driver(margin_grip_power=np.nan),
        "RecedingHorizonDriver.margin_grip_power must be finite"),
    "a negative rate weight of the driver": (
        lambda: _rh_driver(rate_weight=-1e-4),
        "RecedingHorizonDriver.rate_weight must lie in [0, inf)"),
    "a NaN backoff of the driver's estimate": (
        lambda: _rh_driver(estimate_backoff=np.nan),
        "RecedingHorizonDriver.estimate_backoff must be finite"),
    "a negative slip gain of the driver": (
        lambda: _rh_driver(slip_gain=-5.0), "RecedingHorizonDriver.slip_gain must lie in [0, inf)"),
    "a NaN lead of the driver": (
        lambda: _rh_driver(lead=np.nan), "RecedingHorizonDriver.lead must be finite"),
    "a NaN tolerance of the driver": (
        lambda: _rh_driver(tol=np.nan), "RecedingHorizonDriver.tol must be a number in (0, inf)"),
    "a driver that plans first in no iterations": (
        lambda: _rh_driver(init_iterations=0),
        "RecedingHorizonDriver.init_iterations must be an integer >= 1, got 0"),
    "a converged driver of no iterations": (
        lambda: _rh_driver(mode="converged", max_iterations=0),
        "RecedingHorizonDriver.max_iterations must be an integer >= 1, got 0"),
    "a driver of negative delay": (
        lambda: _rh_driver(delay_samples=-1),
        "RecedingHorizonDriver.delay_samples must be an integer >= 0, got -1"),
    "an icy patch at a NaN centre": (
        lambda: _patches(centres=jnp.array([[np.nan, 0.0]])),
        "GripPatches.centres must be finite"),
    "a grip profile from a NaN origin": (
        lambda: vs.GripProfile(stations=jnp.array([0.0, 10.0]), scales=jnp.array([1.0, 0.5]),
                               origin=jnp.array([np.nan, 0.0])),
        "GripProfile.origin must be finite"),
    "a grip profile in a NaN direction": (
        lambda: vs.GripProfile(stations=jnp.array([0.0, 10.0]), scales=jnp.array([1.0, 0.5]),
                               direction=np.nan),
        "GripProfile.direction must be finite"),
    "a grip profile with a NaN station": (
        lambda: vs.GripProfile(stations=jnp.array([np.nan]), scales=jnp.array([1.0])),
        "GripProfile.stations must be finite"),
    "a drive started at a NaN speed": (
        lambda: vs.init_drive(vs.DrivePlant(), vx=np.nan), "init_drive.vx must be finite"),
    "a drive started backwards": (
        lambda: vs.init_drive(vs.DrivePlant(), vx=-5.0),
        "init_drive.vx must lie in [0, inf), got -5"),
    "a drive started at a NaN heading": (
        lambda: vs.init_drive(vs.DrivePlant(), vx=5.0, psi=np.nan),
        "init_drive.psi must be finite"),
    "a scenario of a million hours": (
        lambda: vs.drive_scenario("corner90", time_budget=1e12),
        "drive_scenario: time_budget must lie in (0, 3600] s, got 1e+12"),
    "the settings of an unknown planner friction": (
        lambda: vs.driver_settings("corner90", "nope"),
        "unknown friction 'nope'; allowed: estimate, nominal, oracle"),
    "an estimator whose scale bounds cross": (
        lambda: vs.AxleGripEstimator(scale_min=3.0, scale_max=0.5),
        "AxleGripEstimator needs scale_min <= scale_max, got scale_min = 3, scale_max = 0.5"),
    "an estimator of no load substeps": (
        lambda: vs.AxleGripEstimator(load_substeps=0),
        "AxleGripEstimator.load_substeps must be an integer >= 1, got 0"),
    "the scale of a list of peaks": (
        lambda: vs.scale_for_peak([0.5]),
        "scale_for_peak: peak must be one number, got shape (1,)"),
    "the plant peak of a word": (
        lambda: vs.plant_peak("wet"), "plant_peak: scale must be one number, got 'wet'"),
}


@functools.lru_cache(maxsize=1)
def _mf():
    return MFParams.from_tir(vs.read_tir(next(iter(vs.shipped_tires().values()))))


def _closed_loop(**kw):
    return vs.closed_loop(*_braking(), vs.realistic_hardware(), jax.random.PRNGKey(0),
                          **(dict(n_steps=10) | kw))


CASES |= {
    "members padded to a fractional multiple": (
        lambda: vs.pad_members(jnp.arange(5.0), 2.5),
        "pad_members: multiple must be an integer >= 1, got 2.5"),
    "members padded to a multiple of 0": (
        lambda: vs.pad_members(jnp.arange(5.0), 0),
        "pad_members: multiple must be an integer >= 1, got 0"),
    "a closed loop of no substeps": (
        lambda: _closed_loop(substeps=0), "closed_loop: substeps must be an integer >= 1, got 0"),
    "a closed loop of no samples": (
        lambda: _closed_loop(n_steps=0), "closed_loop: n_steps must be an integer >= 1, got 0"),
    "a closed loop handing back at NaN": (
        lambda: _closed_loop(handback_speed=np.nan), "closed_loop.handback_speed must be finite"),
    "a braking handing back at a negative speed": (
        lambda: simulate_braking(*_braking(), handback_speed=-1.0),
        "simulate_braking.handback_speed must lie in [0, inf), got -1"),
    "a braking of a billion seconds": (
        lambda: simulate_braking(*_braking(), duration=1e9),
        "simulate_braking: duration (1e+09 s) is 2e+11 samples of 0.005 s; at most 1,000,000"),
    "a robot run of a billion seconds": (
        lambda: _robot(duration=1e9), "simulate_robot: duration (1e+09 s) is"),
    "a negative corridor margin in the road frame": (
        lambda: vs.CurvilinearPointMassOCP.from_road(_road(), num_stages=10, margin=-1.0),
        "CurvilinearPointMassOCP.margin must lie in [0, inf), got -1"),
    "a NaN corridor margin of the car's problem": (
        lambda: vs.CurvilinearManeuverOCP.from_road(_road(), vs.ReducedHalfCar(
            vs.params.rally_gravel(), vs.rally_gravel_tire()), num_stages=10, margin=np.nan),
        "CurvilinearManeuverOCP.margin must be finite"),
    "a negative time budget in the road frame": (
        lambda: vs.CurvilinearPointMassOCP.from_road(_road(), num_stages=10, tf_max=-1.0),
        "CurvilinearPointMassOCP.tf_max must lie in (0, inf), got -1"),
    "a NaN rate weight in the road frame": (
        lambda: vs.CurvilinearPointMassOCP.from_road(_road(), num_stages=10, rate_weight=np.nan),
        "CurvilinearPointMassOCP.rate_weight must be finite"),
    "a fractional stage count in the road frame": (
        lambda: vs.CurvilinearPointMassOCP.from_road(_road(), num_stages=10.0),
        "CurvilinearPointMassOCP.num_stages must be an integer >= 2, got 10.0"),
    "a speed profile without gravity": (
        lambda: speed_profile(_road(), 0.5, g=0.0), "speed_profile.g must lie in (0, inf), got 0"),
    "a NaN start pose of the robot": (
        lambda: simulate_robot(DiscontinuousController(), SystemI(),
                               jnp.array([np.nan, 0.1, 0.0]), plant=ideal_plant()),
        "simulate_robot.pose0 must be finite"),
    "a start pose of four values": (
        lambda: simulate_robot(DiscontinuousController(), SystemI(), jnp.zeros(4),
                               plant=ideal_plant()),
        "simulate_robot: pose0 must have shape (3,), (x [m], y [m], gamma [rad]), got (4,)"),
    "a robot grid of one-dimensional poses": (
        lambda: vs.simulate_robot_grid([DiscontinuousController()], [SystemI()], jnp.zeros(3),
                                       jnp.zeros((1, 2), jnp.uint32), plant=ideal_plant()),
        "simulate_robot_grid: poses0 must have shape (P, 3)"),
    "a driving peak searched up to a slip of 1": (
        lambda: vs.peak_driving(vs.LumpedLuGre(P), 20.0, max_slip=1.0),
        "peak_driving.max_slip must lie in (0, 1), got 1"),
    "a braking peak searched past the locked wheel": (
        lambda: vs.peak_braking(vs.LumpedLuGre(P), 20.0, max_slip=5.0),
        "peak_braking.max_slip must lie in (0, 1], got 5"),
    "a braking peak of a wheel of no radius": (
        lambda: vs.peak_braking(vs.LumpedLuGre(P), 20.0, r=0.0),
        "peak_braking.r must lie in (0, inf), got 0"),
    "a surface change at a NaN distance": (
        lambda: braking_scenario("dry_asphalt", change_to="ice", change_distance=np.nan),
        "SurfaceChange.distance must lie in [0, inf], got nan"),
    "a Magic Formula tire at a NaN camber": (
        lambda: vs.MFTire(_mf(), camber=np.nan), "MFTire.camber must be finite"),
    "a relaxed Magic Formula tire of no relaxation floor": (
        lambda: vs.RelaxedMFTire(_mf(), sigma_min=0.0),
        "RelaxedMFTire.sigma_min must lie in (0, inf), got 0"),
    "a longitudinal Magic Formula tire at a NaN load": (
        lambda: vs.MFLongitudinalTire(_mf(), Fz=np.nan), "MFLongitudinalTire.Fz must be finite"),
    "a Magic Formula tire at a negative pressure": (
        lambda: vs.MFTire(_mf(), pressure=-1.0), "MFTire.pressure must lie in (0, inf), got -1"),
    "a Magic Formula summary at no load": (
        lambda: vs.mf_summary(_mf(), Fz=0.0), "mf_summary.Fz must lie in (0, inf), got 0"),
    "a tire under a negative load": (
        lambda: vs.simulate_tire(vs.LumpedLuGre(P), TS, 20.0, 60.0, 0.3, Fz=-1.0),
        "simulate_tire.Fz must lie in [0, inf), got -1"),
    "steady forces under a negative load": (
        lambda: vs.steady_state_forces(vs.params.lugre2d_bakker1987(), vs.UniformLoad(), 20.0,
                                       0.05, 0.0, -1000.0),
        "steady_state_forces.Fz must lie in [0, inf), got -1000"),
    "a braking record in memory with a NaN speed": (
        lambda: _braking_of(v=_record().v.at[3].set(np.nan)), "BrakingData.v must be finite"),
    "a braking record in memory with time running back": (
        lambda: _braking_of(t=_record().t[::-1]), "BrakingData.t must increase strictly"),
    "a braking record in memory on a wheel of negative radius": (
        lambda: _braking_of(r=jnp.asarray(-0.3)), "BrakingData.r must lie in (0, inf), got -0.3"),
    "a braking record in memory with a negative load": (
        lambda: _braking_of(F_n=-_record().F_n), "BrakingData.F_n must lie in [0, inf)"),
    "an empty braking record in memory": (
        lambda: vs.BrakingData(*(jnp.zeros(0),) * 5, r=0.3),
        "BrakingData.t must be a 1-D array of at least 2 times [s], got shape (0,)"),
    "a half car without load iterations": (
        lambda: vs.HalfCar(vs.params.rally_gravel(), vs.rally_gravel_tire(), suspension=False,
                           load_iterations=0),
        "HalfCar.load_iterations must be an integer >= 1, got 0"),
    "a steady state in no Newton steps": (
        lambda: vs.solve_steady_state(vs.LumpedLuGre(P), 20.0, 60.0, 0.3, steps=0),
        "solve_steady_state: steps must be an integer >= 1, got 0"),
    "a Burckhardt fit of no steps": (
        lambda: vs.fit_burckhardt_family(max_steps=-1),
        "fit_burckhardt_family: max_steps must be an integer >= 1, got -1"),
    "a homogeneous-norm controller of no Newton steps": (
        lambda: vs.MCloskeyMurray97Controller(newton_steps=0),
        "MCloskeyMurray97Controller.newton_steps must be an integer >= 1, got 0"),
    "a solve to a negative tolerance": (
        lambda: vs.simulate_tire(vs.LumpedLuGre(P), TS, 20.0, 60.0, 0.3, rtol=-1.0),
        "simulate_tire.rtol must lie in (0, inf), got -1"),
    "a solve of no steps": (
        lambda: vs.simulate_tire(vs.LumpedLuGre(P), TS, 20.0, 60.0, 0.3, max_steps=0),
        "simulate_tire.max_steps must be an integer >= 1, got 0"),
    "a quarter car's step ceiling of zero": (
        lambda: vs.simulate_quarter_car(
            vs.QuarterCar(vs.LumpedLuGre(P), mass=400.0, inertia=1.2, radius=0.3), TS, 0.0,
            20.0, dtmax=0.0),
        "simulate_quarter_car.dtmax must lie in (0, inf), got 0"),
}


CASES |= {
    "a max-exit problem of a negative time budget": (
        lambda: ManeuverOCP(vehicle=vs.ReducedHalfCar(vs.params.rally_gravel(),
                                                      vs.rally_gravel_tire()),
                            road=vs.road("corner90"), objective="max-exit", tf_max=-1.0),
        "ManeuverOCP.tf_max must lie in (0, inf), got -1"),
    "a gate at a NaN arc length": (
        lambda: vs.Gate(s=np.nan, n_min=-1.0, n_max=1.0), "Gate.s must be finite, got nan"),
    "a gate whose lateral bounds cross": (
        lambda: vs.Gate(s=0.0, n_min=1.0, n_max=-1.0),
        "Gate needs n_min <= n_max, got n_min = 1, n_max = -1"),
    "a gate at a negative speed": (
        lambda: vs.Gate(s=0.0, n_min=-1.0, n_max=1.0, speed=-3.0),
        "Gate.speed must be None (free) or a speed in [0, inf) m/s, got -3.0"),
    "a change of surface at a distance, to no surface": (
        lambda: braking_scenario("dry_asphalt", change_distance=5.0),
        "braking_scenario: change_distance and change_time place a change of surface: give "
        "the surface with change_to"),
    "a braking bound stopping at NaN": (
        lambda: vs.actuated_limit(_braking()[0], vs.realistic_hardware(), stop_speed=np.nan),
        "actuated_limit.stop_speed must be finite"),
    "a braking bound stopping above the start speed": (
        lambda: vs.actuated_limit(_braking()[0], vs.realistic_hardware(), stop_speed=100.0),
        "actuated_limit needs stop_speed <= speed, got stop_speed = 100, speed = 30"),
    "a physical bound stopping at a negative speed": (
        lambda: vs.physical_limit(_braking()[0], stop_speed=-1.0),
        "physical_limit.stop_speed must lie in [0, inf), got -1"),
    "a physical bound stopping above the start speed": (
        lambda: vs.physical_limit(_braking()[0], stop_speed=31.0),
        "physical_limit needs stop_speed <= speed, got stop_speed = 31, speed = 30"),
    "a speed-profile guess of no stages": (
        lambda: vs.speed_profile_guess(_road(), vs.ReducedHalfCar(vs.params.rally_gravel(),
                                                                 vs.rally_gravel_tire()), 0),
        "speed_profile_guess: num_stages must be an integer >= 1, got 0"),
    "an open-loop prediction of no substeps": (
        lambda: vs.predict_open_loop(vs.LumpedLuGre(P), _record(), substeps=0),
        "predict_open_loop: substeps must be an integer >= 1, got 0"),
    "a fit holding kappa0 at NaN": (
        lambda: vs.fit_open_loop(_record(), fixed={"kappa0": float("nan")}),
        "fixed.kappa0 must be finite, got nan"),
    "a fit holding kappa0 below 0": (
        lambda: vs.fit_open_loop(_record(), fixed={"kappa0": -1.0}),
        "fixed.kappa0 must lie in [0, inf), got -1"),
    "a fit holding mu_c at 0": (
        lambda: vs.fit_open_loop(_record(), fixed={"mu_c": 0.0}, max_steps=2),
        "fixed.mu_c must lie in (0, inf), got 0"),
    "a control function that is NaN at the start": (
        lambda: vs.simulate(vs.HalfCar(vs.rally_gravel(), vs.rally_gravel_tire()),
                            jnp.linspace(0.0, 1.0, 3), lambda t, y: jnp.array([0.0, 0.0, jnp.nan]),
                            vs.HalfCar(vs.rally_gravel(), vs.rally_gravel_tire()).init_state(
                                vx=15.0)),
        "simulate: inputs(t0, state0) must be finite; non-finite values in delta"),
    "a drive table too coarse for the road's corners": (
        lambda: vs.drive_scenario("corner90", table_spacing=1e300),
        "RoadTable.from_road: spacing must lie in (0, 1] m (the table resolves the road's "
        "corners), got 1e+300"),
    "a drive starting faster than the planners' cap": (
        lambda: vs.drive_scenario("corner90", start_speed=1e300),
        "drive_scenario: start_speed must lie in (0, 80] m/s, got 1e+300"),
    "an estimate of no substeps": (
        lambda: vs.estimate_friction(_measured(), vs.FrictionObserver(vs.LumpedLuGre(P)),
                                     substeps=0),
        "estimate_friction: substeps must be an integer >= 1, got 0"),
    "an estimate of fractional substeps": (
        lambda: vs.estimate_friction(_measured(), vs.FrictionObserver(vs.LumpedLuGre(P)),
                                     substeps=2.7),
        "estimate_friction: substeps must be an integer >= 1, got 2.7"),
    "a moving-horizon stride of a fraction": (
        lambda: vs.estimate_friction(_measured(), vs.MovingHorizonEstimator(vs.LumpedLuGre(P)),
                                     stride=2.5),
        "estimate_friction: stride must be an integer >= 1, got 2.5"),
    "a road of negative friction scale": (
        lambda: vs.scale_friction(vs.LumpedLuGre(P), -1.0),
        "scale_friction.scale must lie in (0, inf), got -1"),
    "a primitive from no seeds": (
        lambda: vs.min_time_primitive("corner90", num_stages=10, starts=()),
        "starts must be a whole number >= 1 or a non-empty sequence of (margin, friction "
        "fraction) seeds, got an empty one"),
}


CASES |= {
    "a peak estimator of a NaN prior": (
        lambda: vs.PeakEstimator(prior=(np.nan, 23.99, 0.52)),
        "PeakEstimator.prior c1 must be finite, got nan"),
    "a peak estimator of two coefficients": (
        lambda: vs.PeakEstimator(prior=(1.28, 23.99)),
        "PeakEstimator.prior must be Burckhardt's (c1, c2, c3), got shape (2,)"),
    "a Burckhardt belief of negative shape": (
        lambda: vs.BurckhardtBelief(jnp.array([1.28, -23.99, 0.52])),
        "BurckhardtBelief.params c2 must lie in (0, inf), got -23.99"),
    "a mission from a NaN pose": (
        lambda: vs.Mission("m", jnp.array([np.nan, 0.0, 0.0]), jnp.zeros(3)),
        "Mission.pose0 must be finite"),
    "a mission of negative spread": (
        lambda: vs.Mission("m", jnp.zeros(3), jnp.array([0.1, -0.1, 0.0])),
        "Mission.spread must lie in [0, inf)"),
    "a mission of a pose of another shape": (
        lambda: vs.Mission("m", (0.0, 0.1), (0.01, 0.01, 0.01)),
        "Mission.pose0 must have shape (3,), (x [m], y [m], gamma [rad]), got (2,)"),
    "a mission of a spread of another shape": (
        lambda: vs.Mission("m", (0.0, 0.1, 0.0), (0.01, 0.01)),
        "Mission.spread must have shape (3,), (x [m], y [m], gamma [rad]), got (2,)"),
    "a surface whose condition range is reversed": (
        lambda: dataclasses.replace(vs.surface("dry_asphalt"), theta_range=(4.0, 0.5)),
        "Surface 'dry_asphalt' needs theta_range[0] <= theta_range[1], got theta_range[0] = 4"),
    "a surface whose prior lies outside its range": (
        lambda: dataclasses.replace(vs.surface("dry_asphalt"), prior_theta=100.0),
        "Surface 'dry_asphalt'.prior_theta must lie in"),
    "a compilation cache with a negative threshold": (
        lambda: vs.enable_compilation_cache(min_compile_time=-1.0),
        "enable_compilation_cache.min_compile_time must lie in [0, inf), got -1"),
    "a sharded map along a second axis": (
        lambda: vs.sharded_vmap(lambda x: x, in_axes=5),
        "sharded_vmap: in_axes must be 0 (the member axis leads), None (not mapped)"),
    "a road primitive's first-solve start bound below zero": (
        lambda: vs.road_primitive(vs.CentrelineRoad.from_segments([("straight", 20.0)], 8.0),
                                  coarse_violation=-1.0),
        "road_primitive.coarse_violation must lie in [0, inf), got -1"),
}


CASES |= {
    "a quarter car started from a state of another shape": (
        lambda: vs.simulate_quarter_car(_car(), TS, 800.0, 20.0, state0=jnp.zeros(3)),
        "simulate_quarter_car: state0 must be shaped as QuarterCar.init_state(v0)"),
    "a half car started from a state of another length": (
        lambda: vs.simulate(vs.HalfCar(vs.params.rally_gravel(), vs.rally_gravel_tire()), TS,
                            jnp.zeros(3), jnp.zeros(5)),
        "simulate: state0 must have shape (12,), the state of HalfCar, got (5,)"),
    "a half car's step ceiling of zero": (
        lambda: vs.simulate(_half_car(), TS, jnp.zeros(3), _half_car().init_state(vx=20.0),
                            dtmax=0.0),
        "simulate.dtmax must lie in (0, inf), got 0"),
    "a step ceiling beside a step-size controller of one's own": (
        lambda: vs.simulate(_half_car(), TS, jnp.zeros(3), _half_car().init_state(vx=20.0),
                            dtmax=0.01, stepsize_controller=dfx.PIDController(1e-6, 1e-8)),
        "simulate: dtmax bounds the default PIDController's steps; with a stepsize_controller"
        " of your own, give the bound there"),
}


CASES |= {
    "a NaN time where the inputs jump": (
        lambda: vs.simulate(_car(), TS, jnp.array([800.0]), _car().init_state(20.0),
                            jump_ts=[np.nan]),
        "simulate.jump_ts must be finite, got [nan]"),
    "a reduced half car's rates of a state of another length": (
        lambda: vs.ReducedHalfCar(vs.params.rally_gravel(), vs.rally_gravel_tire()).f(
            jnp.array([0.0, 0.0, 10.0]), jnp.zeros(3)),
        "ReducedHalfCar.f: state must have shape (6,), the model's states, got shape (3,)"),
    "a half car's rates of controls of another length": (
        lambda: vs.HalfCar(vs.params.rally_gravel(), vs.rally_gravel_tire()).f(
            jnp.zeros(12), jnp.zeros(2)),
        "HalfCar.f: controls must have shape (3,), the model's controls, got shape (2,)"),
    "a 2D steady state of one relative velocity": (
        lambda: vs.steady_state_mu_2d(vs.params.lugre2d_bakker1987(), vs.UniformLoad(), 1.0,
                                      20.0),
        "steady_state_mu_2d: v_r must have shape (2,), the longitudinal and lateral"),
    "a robot with three motor time constants": (
        lambda: vs.KheperaPlant(motor_time_constant=(0.06, 0.09, 0.1)),
        "KheperaPlant.motor_time_constant must be one value or a (left, right) pair, got "
        "shape (3,)"),
    "a robot with one wheel scale in a list": (
        lambda: vs.KheperaPlant(wheel_scale=(1.0,)),
        "KheperaPlant.wheel_scale must be one value or a (left, right) pair, got shape (1,)"),
    "a tone wheel with a fraction of a tooth": (
        lambda: vs.BrakeHardware(encoder_pulses=2.5),
        "BrakeHardware.encoder_pulses must be an integer >= 1, got [2.5]"),
    "a sweep of no members": (
        lambda: vs.sweep(lambda m: None, {"m": jnp.zeros(0)}, TS),
        "a batch needs at least one member, got none (a leading axis of 0)"),
}


def test_options_switches_must_be_booleans():
    """A string is truthy: ``verbose="no"`` would have printed the log."""
    for name in ("verbose", "live", "best_iterate"):
        with pytest.raises(TypeError, match=f"IPOptions.{name} must be True or False, got 'no'"):
            IPOptions(**{name: "no"})
    assert IPOptions(verbose=True).verbose


def test_a_robot_plant_takes_one_value_for_both_wheels():
    """A scalar pair field stays allowed (both wheels alike)."""
    plant = vs.KheperaPlant(motor_time_constant=0.07, wheel_scale=1.0)
    assert plant.motor_time_constant.shape == ()


def test_a_numpy_integer_count_of_starts_is_a_multistart():
    """``starts=np.int64(4)`` is a count of starts, as ``starts=4`` is, not a sequence of
    seeds: it keeps the multistart's initial barrier."""
    from vehsim.optimal.primitives import MAX_EXIT_MU0
    for starts in (4, np.int64(4), jnp.asarray(4)):
        assert float(vs.primitive_options("max-exit", starts).mu0) == 0.1
    for starts in (None, 1, np.int64(1), [(0.5, 0.9)]):
        assert float(vs.primitive_options("max-exit", starts).mu0) == MAX_EXIT_MU0


def test_a_nan_transport_speed_gives_nan_not_a_locked_wheel():
    params, load = vs.params.lugre2d_bakker1987(), vs.UniformLoad()
    v_r = jnp.array([-2.0, 0.5])
    assert np.all(np.isnan(vs.steady_state_mu_2d(params, load, v_r, jnp.nan)))
    locked = vs.steady_state_mu_2d(params, load, v_r, 0.0)
    assert np.all(np.isfinite(locked)) and np.all(locked != 0.0)


def test_burckhardt_curve_is_odd_and_smooth_through_zero_slip():
    """Driving slip mirrors braking slip (the formula itself grows as exp(c2 |slip|)); the
    derivative at zero slip is c1 c2 - c3 from both sides and in both modes."""
    c = jnp.array([1.2801, 23.99, 0.52])  # dry asphalt
    lam = jnp.array([0.01, 0.1, 0.5, 1.0])
    np.testing.assert_allclose(vs.burckhardt_mu(c, lam),
                               c[0] * (1 - np.exp(-c[1] * lam)) - c[2] * lam, rtol=1e-14)
    np.testing.assert_allclose(vs.burckhardt_mu(c, -lam), -vs.burckhardt_mu(c, lam), rtol=1e-14)
    slope = float(c[0] * c[1] - c[2])
    f = functools.partial(vs.burckhardt_mu, c)
    assert float(jax.grad(f)(0.0)) == pytest.approx(slope, rel=1e-14)
    assert float(jax.jvp(f, (0.0,), (1.0,))[1]) == pytest.approx(slope, rel=1e-14)
    h = 1e-9
    assert float((f(h) - f(-h)) / (2 * h)) == pytest.approx(slope, rel=1e-6)
    # far out (exp(c2 |slip|) overflows on the other side's branch) still finite slopes
    for lam in (-50.0, 50.0):
        assert float(jax.grad(f)(lam)) == pytest.approx(-float(c[2]), rel=1e-12)


def test_checks_pass_traced_values_and_whole_numbers_of_any_kind():
    """The checks skip a tracer also inside a container (a start whose steering is traced),
    and a count may be a NumPy or 0-d JAX integer."""
    plant = vs.DrivePlant()
    steer = jax.jit(lambda d: vs.init_drive(plant, vx=10.0, u0=(0.0, 0.0, d)).actuators.applied)
    np.testing.assert_allclose(steer(0.1), [0.0, 0.0, 0.1])
    for multiple in (np.int64(2), jnp.asarray(2)):
        assert vs.pad_members(jnp.arange(5.0), multiple).shape == (6,)


@pytest.mark.parametrize(("build", "message"), [
    (lambda: vs.QuarterCar("dry", mass=350.0, inertia=1.0, radius=0.3),
     "QuarterCar.tire must be an AbstractLongitudinalTire, got str"),
    (lambda: vs.HalfCar("x", vs.rally_gravel_tire()),
     "HalfCar.params must be a HalfCarParams, got str"),
    (lambda: vs.HalfCar(vs.params.rally_gravel(), vs.LumpedLuGre(P)),
     "HalfCar.tire must be an AbstractTire, got LumpedLuGre"),
    (lambda: vs.ReducedHalfCar(vs.params.rally_gravel(), "car"),
     "ReducedHalfCar.tire must be an AbstractTire, got str"),
    (lambda: vs.LumpedLuGre("dry"), "LumpedLuGre.params must be a LuGreParams, got str"),
    (lambda: vs.LumpedLuGre(None), "LumpedLuGre.params must be a LuGreParams, got NoneType"),
    (lambda: vs.MFTire(vs.params.table3()), "MFTire.params must be a MFParams, got LuGreParams"),
], ids=["quarter car tire", "half car params", "half car 1-D tire", "reduced car tire",
        "LuGre params", "no LuGre params", "MF params"])
def test_models_of_the_wrong_kind_are_refused_naming_the_field(build, message):
    with pytest.raises(TypeError) as err:
        build()
    assert message in str(err.value), str(err.value)


def test_parse_tir_refuses_what_is_not_text():
    with pytest.raises(TypeError, match=r"parse_tir needs the file's text \(a str; read_tir "
                                        r"reads a path\), got PosixPath"):
        vs.parse_tir(next(iter(vs.shipped_tires().values())))


def test_sharded_vmap_refuses_what_is_not_a_function():
    with pytest.raises(TypeError, match="sharded_vmap needs a function to map, got int"):
        vs.sharded_vmap(3)


def test_close_times_that_float32_rounds_into_one_say_so(tmp_path):
    """With x64 off, times 10 microseconds apart at 1000 s round into one float32: the
    record is refused naming float32 and the switch; in float64 it reads."""
    path = tmp_path / "close.csv"
    path.write_text("t,v,omega,F_x,F_n\n" + "".join(
        f"{1000 + i * 1e-5:.5f},20,60,-100,3000\n" for i in range(5)))
    assert len(vs.load_braking(path, r=0.3).t) == 5
    with jax.enable_x64(False):
        with pytest.raises(ValueError, match=r"BrakingData.t must increase strictly, got "
                           r"1000 after 1000 \(index 1\): in float32, .*jax_enable_x64"):
            vs.load_braking(path, r=0.3)


def test_a_braking_timed_in_other_units_is_refused_on_reading_and_on_saving(tmp_path):
    """Times in milliseconds read as seconds (a 2 s step) or in units of 1e-9 s: refused
    naming column t and the step, by load_braking and by save_braking (what load_braking
    would refuse is not saved), and by vehsim fit."""
    for scale, step in ((1000.0, "2 s"), (1e-6, "2e-09 s")):
        path = tmp_path / "b.csv"
        path.write_text("t,v,omega,F_x,F_n\n" + "".join(
            f"{i * 0.002 * scale!r},20,60,-100,3000\n" for i in range(5)))
        message = (f"{path}: row 2, column 't': the sample step is {step}; it must lie in "
                   "[1e-05, 1] s (100 kHz to 1 Hz): is the time in seconds?")
        with pytest.raises(ValueError) as err:
            load_braking(path, r=0.3)
        assert str(err.value) == message
        assert main(["fit", str(path), "--radius", "0.3", "--out", str(tmp_path / "o")]) == 2
        with pytest.raises(ValueError, match="the sample step is"):
            save_braking(_record(t=_record().t * scale), tmp_path / "saved.csv")
        assert sorted(p.name for p in tmp_path.iterdir()) == ["b.csv"]


def test_write_tir_refuses_what_read_tir_would_and_writes_nothing(tmp_path):
    tir = vs.read_tir(next(iter(vs.shipped_tires().values())))
    out = tmp_path / "bad.tir"
    with pytest.raises(vs.TirError, match="FNOMIN"):  # replace reads its result again
        tir.replace(FNOMIN=-5.0)
    # a TirFile changed behind replace's back (its entry's text edited)
    sec = next(s for s in tir.sections if "FNOMIN" in s.entries)
    e = sec.entries["FNOMIN"]
    bad_entry = dataclasses.replace(e, value=-5.0, text=e.text.replace(str(e.value), "-5.0"))
    bad_sec = dataclasses.replace(sec, items=tuple(bad_entry if it is e else it
                                                   for it in sec.items))
    bad = dataclasses.replace(tir, sections=tuple(bad_sec if s is sec else s
                                                  for s in tir.sections))
    with pytest.raises(vs.TirError, match="FNOMIN"):
        vs.write_tir(out, bad)
    assert not out.exists()
    vs.write_tir(out, tir)
    assert vs.read_tir(out).get("FNOMIN") == tir.get("FNOMIN")


def test_a_bad_pad_leaves_later_sweeps_working():
    """A refused float multiple is refused before JAX sees it, so it cannot poison the
    caches of the sweeps that follow in the same process."""
    with pytest.raises(ValueError, match="multiple"):
        vs.pad_members(jnp.arange(5.0), 2.5)
    padded = vs.pad_members(jnp.arange(5.0), 2)
    np.testing.assert_array_equal(padded, [0.0, 1.0, 2.0, 3.0, 4.0, 4.0])


def test_road_frame_tools_refuse_a_road_of_rectangular_legs():
    with pytest.raises(TypeError, match="speed_profile needs a centre-line road"):
        speed_profile(vs.road("corner90"), 0.5)
    with pytest.raises(TypeError, match="the road-frame problem needs a centre-line road"):
        vs.CurvilinearPointMassOCP.from_road(vs.road("corner90"), num_stages=10)


def test_distance_off_a_road_of_a_point_that_is_not_finite_is_nan_or_inf():
    """A NaN point is at NaN (not on the road, nor an index error), an infinite one at inf;
    the finite points beside them keep their distances."""
    road = _road()
    d = road.distance_off_road([np.nan, 10.0, np.inf, 10.0], [0.0, 0.0, 0.0, 10.0])
    assert np.isnan(d[0]) and d[1] == 0.0 and d[2] == np.inf
    np.testing.assert_allclose(d[3], 8.0, atol=1e-9)
    assert np.isnan(road.distance_off_road(np.nan, 0.0))
    assert not road.on_road(np.nan, 0.0)


CASES |= {
    # text and truth values, which NumPy reads as numbers, are refused where numbers go
    "a friction level as text": (
        lambda: vs.LuGreParams(**{**{f.name: getattr(P, f.name)
                                     for f in dataclasses.fields(vs.LuGreParams)},
                                  "mu_c": "0.5"}),
        "LuGreParams.mu_c must be a number or an array of numbers, got '0.5'"),
    "an iteration cap of True": (
        lambda: IPOptions(max_iter=True), "IPOptions.max_iter must be an integer >= 1, got True"),
    "a tolerance as text": (
        lambda: IPOptions(tol="1e-8"), "IPOptions.tol must be a number, got '1e-8'"),
    "a straight's length as text": (
        lambda: vs.CentrelineRoad.from_segments([("straight", "50")], 4.0),
        "road 'road': segment 0 must be ('straight', length) with numbers, got ('straight', "
        "'50')"),
    "an arc's angle of True": (
        lambda: vs.CentrelineRoad.from_segments([("arc", 20.0, True)], 4.0),
        "segment 0 must be ('arc', radius, angle_deg) with numbers"),
    "a width pair of one value": (
        lambda: vs.CentrelineRoad.from_segments([("straight", 50.0)], (4.0,)),
        "road 'road': width must be a number or a pair (width_right, width_left) [m], got "
        "(4.0,)"),
    "a smoothing past the points' length": (
        lambda: vs.CentrelineRoad.from_points(np.linspace(0.0, 100.0, 30), np.zeros(30),
                                              np.full(30, 4.0), np.full(30, 4.0),
                                              smoothing=1e300),
        "road 'road': smoothing must lie in [0, 100] m (the points' path length), got 1e+300"),
    "a fit seeded with text": (
        lambda: vs.fit_open_loop(_record(), key="a"),
        "fit.key must be an integer >= 0, got 'a'"),
    "a primitive's guess of the wrong shape": (
        lambda: vs.min_time_primitive("corner90", num_stages=10,
                                      guess=(np.zeros((3, 10)), np.zeros((10, 3)))),
        "guess must be a pair (xs, us) of knots (11, 10) and controls (10, 3) for 10 stages, "
        "got ((3, 10), (10, 3))"),
}


def test_diffrax_settings_given_by_name_are_refused_naming_the_setting():
    car = _half_car()
    for key, value, kind in (("solver", "Tsit5", "AbstractSolver"),
                             ("adjoint", "forward", "AbstractAdjoint"),
                             ("stepsize_controller", 1e-3, "AbstractStepSizeController"),
                             ("progress_meter", True, "AbstractProgressMeter")):
        with pytest.raises(TypeError, match=re.escape(
                f"simulate.{key} must be a diffrax.{kind} (e.g. diffrax.")):
            vs.simulate(car, TS, jnp.zeros(3), car.init_state(vx=20.0), **{key: value})
    with pytest.raises(TypeError, match=re.escape("simulate_quarter_car.solver must be a")):
        vs.simulate_quarter_car(_car(), TS, 800.0, 20.0, solver="Tsit5")
    with pytest.raises(TypeError, match=re.escape("simulate_tire.adjoint must be a")):
        vs.simulate_tire(vs.LumpedLuGre(P), TS, 20.0, 60.0, 0.3, adjoint="forward")


@pytest.mark.parametrize("case", list(CASES), ids=list(CASES))
def test_bad_values_are_refused_naming_the_field_and_its_range(case):
    call, message = CASES[case]
    with pytest.raises(ValueError) as err:
        call()
    assert message in str(err.value), str(err.value)
