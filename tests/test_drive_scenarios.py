"""Drive scenarios: the roads against the benchmark's numbers, the grips' peaks, the drive
measurements against closed forms and brute force, and the open-loop replay of the nominal
minimum-time drive."""

import math
import types

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs
from vehsim.drive import baselines
from vehsim.drive.scenarios import GRIP_NAMES, ROAD_NAMES
from vehsim.optimal.roads import road as benchmark_road
from vehsim.tire.params import lugre2d_bakker1987


pytestmark = pytest.mark.xdist_group("drive")


@pytest.fixture(scope="module")
def roads():
    return {name: vs.scenario_road(name) for name in ROAD_NAMES}


# ---- roads ---------------------------------------------------------------------------------

# start point, start heading, end point, end heading of the benchmark's gates (maneuvers.md)
GATES = {"corner90": ((-5.0, 9.0), 0.0, (9.0, -5.0), -math.pi / 2),
         "uturn": ((-9.0, -5.0), math.pi / 2, (9.0, -5.0), -math.pi / 2),
         "sturn": ((-14.0, -9.0), 0.0, (14.0, 9.0), 0.0)}


@pytest.mark.parametrize("name", ["corner90", "uturn", "sturn"])
def test_benchmark_roads_have_the_benchmarks_gates_legs_and_width(roads, name):
    road, bench = roads[name], benchmark_road(name)
    (p0, th0, p1, th1) = GATES[name]
    np.testing.assert_allclose(np.ravel(road.position(0.0)), p0, atol=1e-9)
    np.testing.assert_allclose(np.ravel(road.position(road.length)), p1, atol=1e-9)
    assert float(road.heading(0.0)) == pytest.approx(th0, abs=1e-9)
    assert math.remainder(float(road.heading(road.length)) - th1, 2 * math.pi) == \
        pytest.approx(0.0, abs=1e-9)
    # the gates span the benchmark's 2 m boundary sets, the speed free
    for gate, bset in ((road.start, bench.start), (road.end, bench.end)):
        assert gate.speed is None
        ends = np.sort(gate.endpoints(road), axis=0)
        np.testing.assert_allclose(ends, np.sort(np.array(bset.points()), axis=0), atol=1e-9)
    # 2 m wide, and no fold: |n kappa| < 1 everywhere
    s = np.linspace(0.0, road.length, 2001)
    np.testing.assert_allclose(road.width_left(s), 1.0)
    np.testing.assert_allclose(road.width_right(s), 1.0)
    # the legs' centre lines joined by arcs of 4 m: |n kappa| <= 1/4, and the length is the
    # legs' minus what the arcs cut (2 - pi/2) R per corner
    assert np.max(np.abs(road.curvature(s))) == pytest.approx(0.25)
    legs = {"corner90": 28.0, "uturn": 46.0, "sturn": 46.0}[name]
    corners = 1 if name == "corner90" else 2
    assert road.length == pytest.approx(legs - corners * (2.0 - math.pi / 2) * 4.0)
    # on the straight parts the road's edges are the benchmark legs' walls: the edge is on
    # the benchmark road, 1 cm beyond it is not
    straight = np.abs(road.curvature(s)) < 1e-12
    s_str = s[straight]
    for n, inside in ((0.999, True), (-0.999, True), (1.01, False), (-1.01, False)):
        off = bench.distance_off_road(*road.to_cartesian(s_str, np.full_like(s_str, n)))
        assert np.all(off == 0.0) if inside else np.all(off > 0.009)


def test_stage_is_a_rally_stage(roads):
    road = roads["stage"]
    assert 150.0 <= road.length <= 250.0
    s = np.linspace(0.0, road.length, 20001)
    np.testing.assert_allclose(road.width_left(s) + road.width_right(s), 4.0)
    kap = road.curvature(s)
    radii = 1.0 / np.abs(kap[np.abs(kap) > 1e-9])
    assert radii.min() == pytest.approx(10.0) and radii.max() == pytest.approx(40.0)
    assert np.any(kap > 0) and np.any(kap < 0)  # left and right corners
    s0, s1 = vs.main_corner("stage")  # the hairpin
    assert float(road.heading(s1) - road.heading(s0)) == pytest.approx(math.pi)
    assert np.max(np.abs(kap)) * 2.0 < 1.0


def test_unknown_names_list_the_allowed_ones(roads):
    with pytest.raises(ValueError, match="corner90, uturn, sturn, stage"):
        vs.scenario_road("hairpin")
    with pytest.raises(ValueError, match="nominal, minus20, icy, rising"):
        vs.scenario_grip("wet", roads["corner90"])
    with pytest.raises(ValueError, match="allowed"):
        vs.drive_scenario("corner90", "snow")


# ---- grip ----------------------------------------------------------------------------------


def _peak_by_scan(scale):
    """The plant tire's peak braking friction at 20 m/s by a dense slip scan (independent of
    the estimator's grid and parabola)."""
    tire = vs.AxleGripEstimator().tire
    kap = jnp.linspace(1e-4, 0.6, 60001)
    V = 20.0

    def mu(k):
        return jnp.linalg.norm(vs.scaled_steady_state_mu(tire, scale, jnp.stack([-k * V, 0.0]),
                                                         (1.0 - k) * V))

    return float(jnp.max(jax.vmap(mu)(kap)))


def test_nominal_scale_gives_the_plant_a_peak_of_052():
    lam0 = vs.nominal_scale()
    assert vs.plant_peak(lam0) == pytest.approx(0.52, abs=1e-9)
    assert _peak_by_scan(lam0) == pytest.approx(0.52, rel=1e-3)
    # the peak is not proportional to the scale: 0.52 / mu*(1) would be off by > 10 %
    assert _peak_by_scan(0.52 / vs.plant_peak(1.0)) > 0.57


def test_a_scenario_on_a_tire_of_another_family():
    """``drive_scenario(..., tire=)``: the plant runs on the given tire (a relaxed Magic
    Formula from the shipped .tir file), its initial state has that tire's states (2 per
    axle, where the LuGre plant's has its own), the grip field is the scenario's; a tire
    `scale_friction` cannot scale is refused before anything is built."""
    from vehsim.tire.tir import read_tir, shipped_tires

    mf = vs.RelaxedMFTire(vs.MFParams.from_tir(
        read_tir(shipped_tires()["sample_185_80R14_mf61"])), limits=False)
    lugre = vs.drive_scenario("corner90", "icy")
    sc = vs.drive_scenario("corner90", "icy", tire=mf)
    assert sc.plant.tire is mf
    assert sc.state0.car.shape[0] == lugre.state0.car.shape[0] - 2 * (
        lugre.plant.tire.init_state().shape[0] - 2)
    np.testing.assert_array_equal(sc.state0.car[:10], lugre.state0.car[:10])
    assert sc.plant.grip is sc.grip.field
    with pytest.raises(TypeError, match="scale_friction needs"):
        vs.drive_scenario("corner90", tire=vs.LinearTire(5e4, 4e4))


@pytest.fixture(scope="module")
def grips(roads):
    return {(r, g): vs.scenario_grip(g, roads[r]) for r in ROAD_NAMES for g in GRIP_NAMES}


@pytest.mark.parametrize("road", ROAD_NAMES)
def test_icy_patch_lowers_the_peak_inside_the_main_corner_only(roads, grips, road):
    rd = roads[road]
    plant = vs.DrivePlant(grip=grips[road, "icy"].field)
    s0, s1 = vs.main_corner(road)
    apex = 0.5 * (s0 + s1)

    def axle_peaks(s):
        x, y = rd.position(s)
        state = vs.init_drive(plant, vx=5.0, x=float(x), y=float(y),
                              psi=float(rd.heading(s))).car
        return [vs.plant_peak(float(lam)) for lam in plant.grip_scales(state)]

    # at the apex both axles (1.3 m and 1.4 m from the centre) are on the patch: peak 0.26,
    # raised a little by the tanh edge (on the benchmark corners' 3 m patch)
    assert all(0.259 < p < 0.28 for p in axle_peaks(apex))
    assert axle_peaks(0.0) == pytest.approx([0.52, 0.52], abs=1e-6)
    # the true peak along the centre line: 0.52 at the start, 0.26 at the apex
    g = grips[road, "icy"]
    assert float(g.peak_at(0.0)) == pytest.approx(0.52, abs=1e-6)
    assert float(g.peak_at(apex)) == pytest.approx(0.26, abs=0.005)


@pytest.mark.parametrize("road", ROAD_NAMES)
def test_uniform_and_rising_grips_have_their_peaks_along_the_road(roads, grips, road):
    L = roads[road].length
    s = np.asarray(grips[road, "rising"].arc_length)
    rising = np.asarray(grips[road, "rising"].peak)
    assert rising[0] == pytest.approx(0.6 * 0.52, abs=1e-6)
    assert np.all(np.diff(rising) > -1e-3)  # rises (the peak's own grid jitters by 1e-4)
    np.testing.assert_allclose(rising[s >= L / 3 + 0.5], 0.52, atol=1e-6)
    np.testing.assert_allclose(np.asarray(grips[road, "nominal"].peak), 0.52, atol=1e-6)
    np.testing.assert_allclose(np.asarray(grips[road, "minus20"].peak), 0.416, atol=1e-6)


def test_a_file_road_named_like_a_scenario_road_gets_the_file_roads_patch(tmp_path):
    """A road read from ``stage.csv`` is named ``stage`` but is not the stage: its icy patch
    sits at its middle with a 3 m radius (the stage's would be on the stage's hairpin, 8 m),
    the same as under any other name."""
    text = "x_m,y_m,w_tr_right_m,w_tr_left_m\n" + "".join(
        f"{x},0,2,2\n" for x in np.linspace(0.0, 211.0, 300))
    fields = {}
    for stem in ("stage", "mystage"):
        (tmp_path / f"{stem}.csv").write_text(text)
        road = vs.read_road(tmp_path / f"{stem}.csv")
        fields[stem] = vs.scenario_grip("icy", road).field
    assert vs.read_road(tmp_path / "stage.csv").name == "stage"
    for f in fields.values():
        np.testing.assert_allclose(np.asarray(f.centres[0]), [105.5, 0.0], atol=1e-6)
        assert float(f.radii[0]) == 3.0
    stage = vs.scenario_grip("icy", vs.scenario_road("stage")).field
    assert float(stage.radii[0]) == 8.0  # the scenario road itself keeps its own


def test_rising_grip_is_refused_where_the_road_does_not_run_towards_its_end():
    back = vs.CentrelineRoad.from_segments([("straight", 20.0), ("arc", 10.0, 180.0),
                                            ("straight", 40.0)], 8.0)  # a hairpin
    with pytest.raises(ValueError, match=r"grip 'rising'.*behind its start"):
        vs.scenario_grip("rising", back)
    lap = vs.CentrelineRoad.from_segments([("straight", 30.0), ("arc", 12.0, 180.0),
                                           ("straight", 30.0), ("arc", 12.0, 180.0)], 8.0,
                                          closed=True)
    with pytest.raises(ValueError, match="a closed road has no such line"):
        vs.scenario_grip("rising", lap)


# ---- measurements --------------------------------------------------------------------------


def test_scenario_driver_is_paced_to_the_plant_and_shares_the_pace_notes():
    """`scenario_driver`: the driver samples at the actuators' period and knows their delay
    in whole samples; with pace notes its table's `scale` column and the estimator's map
    are the scenario's relative grip (1 on the best surface, below 0.6 on the icy patch);
    only the estimating driver has an estimator; an unknown friction is refused."""
    act = vs.DriveActuators(sample_time=0.04, delay=(0.08, 0.08, 0.08))
    sc = vs.drive_scenario("sturn", "icy", actuators=act)
    driver, estimator = vs.scenario_driver(sc, pace_notes=True, margin=0.25)
    assert float(driver.sample_time) == 0.04 and int(driver.delay_samples) == 2
    assert float(driver.margin) == 0.25 and driver.surface_map and driver.friction == "estimate"
    notes = sc.surface_map()
    assert eqx.tree_equal(estimator.surface, notes)
    scale = np.asarray(driver.table.scale)
    np.testing.assert_allclose(scale, np.asarray(sc.table.with_grip(notes).scale))
    assert np.max(scale) == pytest.approx(1.0) and 0.3 < np.min(scale) < 0.6
    plain, none = vs.scenario_driver(sc, "oracle")
    assert none is None and not plain.surface_map
    np.testing.assert_array_equal(np.asarray(plain.table.scale), np.asarray(sc.table.scale))
    with pytest.raises(ValueError, match="friction 'guess'; allowed: estimate, nominal, oracle"):
        vs.scenario_driver(sc, "guess")


@pytest.mark.parametrize("road", ["stage", "corner90", None])
def test_a_converged_drivers_settings_take_a_fresh_hessian(road):
    """`driver_settings` with ``mode``: the real-time settings keep what the road's driver
    keeps (the stage and a road file keep each sample's first Hessian), a converged driver
    takes a fresh Hessian every pass whatever the road (a kept one makes its solves creep to
    their cap) and plans a lost plan again from the cold start (the corners' real-time
    settings never do; the stage's and a road file's keep their threshold), and
    `scenario_driver` builds the driver of that mode from them alone."""
    base = vs.driver_settings(road)
    assert "mode" not in base
    assert vs.driver_settings(road, mode="rti") == base | {"mode": "rti"}
    conv = vs.driver_settings(road, "oracle", mode="converged")
    replan = base.get("replan_kkt", vs.CONVERGED_REPLAN_KKT)
    assert ("replan_kkt" in base) == (road != "corner90")
    assert conv == base | {"mode": "converged", "hessian_update": "every",
                           "replan_kkt": replan} and replan == 100.0
    sc = vs.drive_scenario(road or "sturn", "nominal")
    driver, _ = vs.scenario_driver(sc, "oracle", **conv)
    assert driver.mode == "converged" and driver.hessian_update == "every"
    assert float(driver.replan_kkt) == 100.0
    assert vs.scenario_driver(sc, "oracle", **vs.driver_settings(road, mode="rti"))[
        0].hessian_update == base.get("hessian_update", "every")
    with pytest.raises(ValueError, match="unknown mode 'fast'; allowed: rti, converged"):
        vs.driver_settings(road, mode="fast")


def test_the_stages_driver_plans_a_lost_plan_again_within_a_short_cap():
    """The stage's driver takes fewer passes per sample than a road file's (10 keeping the
    first Hessian, against 16) and plans a lost plan (KKT residual past 100) again from the
    cold start, its re-plan capped at 20 passes (the circuit's at 40), so that a re-plan
    fits the 50 ms period; the cap reaches the interior point's options of a re-plan, and
    an ordinary sample's stay at the 10 passes (docs/drive.md, "Ten passes and a re-plan")."""
    stage, file = vs.driver_settings("stage"), vs.driver_settings(None)
    assert stage["iterations"] == 10 < file["iterations"] == 16
    assert stage["replan_kkt"] == file["replan_kkt"] == 100.0
    assert stage["replan_iterations"] == 20 < file["replan_iterations"] == 40
    driver, _ = vs.scenario_driver(vs.drive_scenario("stage", "nominal"), "estimate", **stage)
    assert float(driver.replan_kkt) == 100.0 and driver.hessian_update == "first"
    assert int(driver.options(False, True).max_iter) == 20
    assert int(driver.options(False, False).max_iter) == 10


def test_drive_time_interpolates_the_gate_crossing():
    road = vs.CentrelineRoad.from_segments([("straight", 20.0)], 2.0)
    h = 0.1
    t = np.arange(0.0, 5.0, h)
    a, v0 = 2.0, 1.3  # crossing at t = 3.869 s, between samples
    x = v0 * t + 0.5 * a * t**2  # crosses x = 20 between two samples
    i = np.searchsorted(x, 20.0) - 1
    expected = t[i] + h * (20.0 - x[i]) / (x[i + 1] - x[i])  # linear between the poses
    assert vs.drive_time(road, t, x, 0.3 + 0 * t) == pytest.approx(expected, rel=1e-12)
    # closed form of the exact crossing, within the chord error a h^2 / 8 / v
    exact = (-v0 + math.sqrt(v0**2 + 2 * a * 20.0)) / a
    assert abs(vs.drive_time(road, t, x, 0 * t) - exact) < a * h**2 / 8 / (v0 + a * exact)
    # never crossing: no time; crossing the gate's line far off the road: not a crossing
    assert vs.drive_time(road, t, 0.5 * x / x.max() * 19.0, 0 * t) is None
    assert vs.drive_time(road, t, x, 5.0 + 0 * t) is None
    # the JAX form (no None): crossed False, the last time
    crossed, tc, _ = vs.EndGate.of(road).crossing(jnp.asarray(t), jnp.asarray(x),
                                                  jnp.asarray(5.0 + 0 * t))
    assert not bool(crossed) and float(tc) == pytest.approx(t[-1])


def _brute_distance(road, x, y, step=2e-3):
    """Distance off the road region by brute force: inside or outside by ray casting on a
    dense boundary polygon, the distance to its nearest vertex (spacing `step`)."""
    s = np.linspace(0.0, road.length, int(road.length / step) + 1)
    left = np.stack(road.to_cartesian(s, road.width_left(s)), -1)
    right = np.stack(road.to_cartesian(s, -road.width_right(s)), -1)
    def cap(sv):  # the gate's line at arc length sv, from the right edge to the left
        n = np.linspace(-road.width_right(sv), road.width_left(sv), 1001)
        return np.stack(road.to_cartesian(np.full_like(n, sv), n), -1)

    # left edge forwards, the end line leftwards to right, right edge backwards, start line
    poly = np.concatenate([left, cap(road.length)[::-1], right[::-1], cap(0.0)])
    out = []
    for px, py in zip(x, y):
        a, b = poly, np.roll(poly, -1, axis=0)
        crosses = ((a[:, 1] > py) != (b[:, 1] > py)) & (
            px < a[:, 0] + (py - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1] + 1e-300))
        inside = np.count_nonzero(crosses) % 2 == 1
        out.append(0.0 if inside else float(np.min(np.hypot(poly[:, 0] - px,
                                                            poly[:, 1] - py))))
    return np.array(out)


def test_departure_is_the_exact_distance_off_the_road(roads):
    road = roads["corner90"]
    rng = np.random.default_rng(0)
    s = rng.uniform(0.3, road.length - 0.3, 120)
    n = rng.uniform(-2.5, 2.5, 120)
    x, y = road.to_cartesian(s, n)
    brute = _brute_distance(road, x, y)
    assert np.any(brute > 0.5) and np.any(brute == 0.0)
    got = [vs.max_distance_off_road(road, [a], [b]) for a, b in zip(x, y)]
    np.testing.assert_allclose(got, brute, atol=2e-3)
    assert vs.max_distance_off_road(road, x, y) == pytest.approx(brute.max(), abs=2e-3)
    assert vs.max_distance_off_road(road, [0.0, np.nan], [9.0, 9.0]) == math.inf


def test_jax_departure_agrees_with_the_exact_one(roads):
    sc = vs.drive_scenario("corner90")
    road = sc.road
    # a path weaving across the edges: N samples of S poses
    N, S = 30, 8
    s = np.linspace(0.0, road.length - 0.5, N * S)
    n = 1.4 * np.sin(s / 2.0)
    x, y = road.to_cartesian(s, n)
    got = vs.path_departure(sc.table, jnp.asarray(x).reshape(N, S), jnp.asarray(y).reshape(N, S),
                            N * S - 1)
    assert float(got) == pytest.approx(vs.max_distance_off_road(road, x, y), abs=2e-4)
    assert float(got) > 0.3
    # only the poses up to `upto` count
    cut = int(np.argmax(np.abs(n) > 1.0)) - 1
    early = vs.path_departure(sc.table, jnp.asarray(x).reshape(N, S),
                              jnp.asarray(y).reshape(N, S), cut)
    assert float(early) == 0.0


def test_pose_departures_are_each_poses_distance_and_differentiable(roads):
    """Each pose's own distance off the road (not only the path's largest), and its gradient
    in the pose: a unit vector along the outward normal off the road (central differences),
    zero on the road. The departure penalty of `experiments/plant_bound.py` descends it."""
    sc = vs.drive_scenario("corner90")
    road = sc.road
    s = np.linspace(1.0, road.length - 1.0, 40)
    n = 2.4 * np.sin(s / 1.7)
    x, y = road.to_cartesian(s, n)
    got = np.asarray(vs.pose_departures(sc.table, jnp.asarray(x), jnp.asarray(y)))
    exact = road.distance_off_road(x, y)
    assert np.sum(exact > 0.2) > 10 and np.sum(exact == 0.0) >= 8
    np.testing.assert_allclose(got, exact, atol=2e-4)
    grad = jax.vmap(jax.grad(lambda a, b: vs.pose_departures(sc.table, a[None], b[None])[0],
                             argnums=(0, 1)))(jnp.asarray(x), jnp.asarray(y))
    gx, gy = (np.asarray(g) for g in grad)
    h = 1e-5
    fdx = (road.distance_off_road(x + h, y) - road.distance_off_road(x - h, y)) / (2 * h)
    fdy = (road.distance_off_road(x, y + h) - road.distance_off_road(x, y - h)) / (2 * h)
    off = exact > 1e-3
    np.testing.assert_allclose(gx[off], fdx[off], atol=1e-3)
    np.testing.assert_allclose(gy[off], fdy[off], atol=1e-3)
    np.testing.assert_allclose(np.hypot(gx[off], gy[off]), 1.0, atol=1e-3)
    assert np.all(gx[exact == 0.0] == 0.0) and np.all(gy[exact == 0.0] == 0.0)


@pytest.mark.parametrize("name", ["corner90", "uturn"])
def test_jax_departure_is_exact_metres_off_the_road(name):
    """Poses scattered over the road's bounding box widened by 12 m (past its ends, inside
    the hairpin, far off), each measured alone (no path to follow): the JAX departure is
    the exact distance off the road region to the table's interpolation error (measured:
    3e-5 m at most over 600 poses each), however far the pose is from where the road was
    last seen and past the start and end lines, where the table extends the road and the
    road does not."""
    sc = vs.drive_scenario(name)
    road = sc.road
    cx, cy = road.to_cartesian(np.linspace(0.0, road.length, 2000), np.zeros(2000))
    rng = np.random.default_rng(1)
    x = rng.uniform(cx.min() - 12.0, cx.max() + 12.0, 600)
    y = rng.uniform(cy.min() - 12.0, cy.max() + 12.0, 600)
    alone = jax.jit(jax.vmap(lambda a, b: vs.path_departure(sc.table, a[None, None],
                                                            b[None, None], 0)))
    got = np.asarray(alone(jnp.asarray(x), jnp.asarray(y)))
    exact = road.distance_off_road(x, y)
    assert np.sum(exact > 4.0) > 300 and np.sum(exact == 0.0) > 10
    # poses past the ends: nearer the start or end line than the rest of the centre line
    d = np.hypot(x[:, None] - cx[None], y[:, None] - cy[None])
    assert np.sum(np.isin(np.argmin(d, axis=1), [0, 1999])) > 50
    np.testing.assert_allclose(got, exact, atol=2e-4)


def test_the_nominal_reference_takes_the_drives_newton_acceptance(monkeypatch):
    """The nominal primitive (the open-loop replay's and the tracker's reference, the offline
    bound's start) and the offline bound's solves are solved with the drive's
    `PLAN_BACKWARD_ERROR` and `PLAN_REFINEMENT_STEPS`, as the driver's plans are, not the
    library primitives' defaults."""
    import vehsim.drive.baselines as baselines
    from vehsim.drive.horizon import PLAN_BACKWARD_ERROR, PLAN_REFINEMENT_STEPS

    seen = {}
    monkeypatch.setattr(baselines, "road_primitive", lambda road, **kw: seen.update(kw))
    baselines.nominal_primitive(vs.drive_scenario("corner90", "nominal"))
    assert seen["options"].backward_error_singular == PLAN_BACKWARD_ERROR
    assert seen["options"].max_refinement_steps == PLAN_REFINEMENT_STEPS
    assert int(seen["options"].max_iter) == 500
    bound = baselines.bound_options()  # the offline bound's solves: the same acceptance
    assert bound.backward_error_singular == PLAN_BACKWARD_ERROR
    assert bound.max_refinement_steps == PLAN_REFINEMENT_STEPS
    assert float(bound.mu0) == 1e-3 and int(bound.max_iter) == 500


# ---- the drive and the open-loop replay ----------------------------------------------------


@pytest.fixture(scope="module")
def replay():
    """The nominal primitive of corner90 replayed open loop (ideal actuators, no noise) on
    the nominal and the minus20 road: one compiled drive."""
    quiet = dict(actuators=vs.ideal_actuators(), sensors=vs.DriveSensors(noise_on=False))
    nominal = vs.drive_scenario("corner90", "nominal", **quiet)
    minus20 = vs.drive_scenario("corner90", "minus20", **quiet)
    prim = vs.nominal_primitive(nominal)
    ref = vs.primitive_reference(prim)
    drive = jax.jit(lambda plant, ctrl, s0: vs.simulate_drive(
        plant, ctrl, s0, jax.random.key(0), nominal.num_samples, substep_poses=True))
    sched = vs.open_loop_schedule(ref, nominal.plant.actuators, nominal.num_samples)
    out = {}
    for sc in (nominal, minus20):
        run = drive(sc.plant, sched, sc.state0)
        out[sc.grip_name] = (sc, run, vs.drive_outcome(sc.road, *vs.drive_path(run, sc.state0)))
    return prim, ref, out


@pytest.mark.slow  # the primitive's solve and a drive's compilation, a few minutes
def test_substep_poses_are_the_integrators_states(replay):
    _, _, out = replay
    sc, run, _ = out["nominal"]
    poses = np.asarray(run.poses)
    assert poses.shape == (sc.num_samples, sc.plant.substeps, 2)
    np.testing.assert_array_equal(poses[:, -1], np.asarray(run.states.car)[:, :2])
    t, x, y = vs.drive_path(run, sc.state0)
    assert len(t) == 1 + poses.shape[0] * poses.shape[1]
    np.testing.assert_allclose(np.diff(t), sc.sample_time / sc.plant.substeps, rtol=1e-9)
    np.testing.assert_allclose(t[sc.plant.substeps::sc.plant.substeps], np.asarray(run.states.t),
                               rtol=1e-12)
    # consecutive poses are a step's travel apart (< 12 m/s x 1.25 ms)
    assert np.max(np.hypot(np.diff(x), np.diff(y))) < 12.0 * sc.sample_time / sc.plant.substeps


def test_drive_path_of_one_sample_continued_from_a_later_state():
    """A run of one sample has no period to read from its times: its substeps divide the
    time from `state0`'s (a run continued from a later `DriveState`), not from 0."""
    S = 4
    run = types.SimpleNamespace(states=types.SimpleNamespace(t=np.array([1.05])),
                                poses=np.arange(2.0 * S).reshape(1, S, 2))
    state0 = types.SimpleNamespace(t=1.0, car=np.array([-1.0, -2.0, 0.0]))
    t, x, y = vs.drive_path(run, state0)
    np.testing.assert_allclose(t, 1.0 + 0.05 * np.arange(S + 1) / S, rtol=1e-12)
    np.testing.assert_array_equal(x, [-1.0, 0.0, 2.0, 4.0, 6.0])
    run.states.t = np.array([0.05])  # no start given: from 0
    t, _, _ = vs.drive_path(run)
    np.testing.assert_allclose(t, 0.05 * np.arange(1, S + 1) / S, rtol=1e-12)


@pytest.mark.slow
def test_open_loop_replay_follows_the_primitive_on_its_road_and_not_on_less_grip(replay):
    prim, ref, out = replay
    tt = np.linspace(0.0, float(ref.duration), 4000)
    table = np.asarray(ref.table)
    path = np.stack([np.interp(tt, np.asarray(ref.time), table[:, j]) for j in (0, 1)], 1)

    def deviation(name):
        sc, run, res = out[name]
        t, x, y = vs.drive_path(run, sc.state0)
        keep = t <= (res.time if res.time is not None else t[-1])
        x, y = x[keep], y[keep]
        return np.max(np.min(np.hypot(x[:, None] - path[None, :, 0],
                                      y[:, None] - path[None, :, 1]), axis=1))

    nominal = out["nominal"][2]
    # the offline bound on the nominal grip: every stage's peak is the road's at the
    # bound's own speed there (the fixed point), above the 0.52 of 20 m/s at the corner's
    # speeds, so the bound is faster than this one-peak primitive
    bound, D, exact = vs.offline_bound(out["nominal"][0])
    sol = bound.solution
    v = np.hypot(np.asarray(sol.xs[:, 2]), np.asarray(sol.xs[:, 3]))
    speeds = np.maximum(0.5 * (v[:-1] + v[1:]), 1.0)
    D_stage = np.asarray(bound.problem.grip) * float(bound.problem.vehicle.tire.D)
    lam = float(vs.nominal_scale())
    tire = vs.LumpedLuGre2D(lugre2d_bakker1987())
    expected = [float(vs.peak_friction(tire, lam, V))
                for V in speeds[::10]]
    assert exact and bool(sol.converged) and D == pytest.approx(float(np.min(D_stage)))
    np.testing.assert_allclose(D_stage[::10], expected, rtol=2e-3)
    assert np.min(D_stage) > 0.53
    print("bound", float(bound.t_f), "one-peak primitive", float(prim.t_f))
    assert float(bound.t_f) < 0.97 * float(prim.t_f)
    # the plant's dynamic LuGre tire is not the planner's friction ellipse: the replay
    # keeps within 0.7 m of the primitive's path (measured 0.60 m), crossing within 5 %
    # of its time
    assert deviation("nominal") < 0.7
    assert nominal.time == pytest.approx(float(prim.t_f), rel=0.05)
    # with 20 % less grip the same commands leave the road by metres and never arrive
    assert deviation("minus20") > 3.0
    assert out["minus20"][2].max_off_road > 3.0 and not out["minus20"][2].completed


@pytest.mark.slow  # two fixed points of whole-road solves, about a minute
def test_bound_under_the_drivers_constraints_keeps_them(replay, monkeypatch):
    """`offline_bound` with a driver: the minimum-time drive under the receding-horizon
    driver's corridor margin, slip bound and steering rate keeps each of them where the
    horizon problem bounds them,
    where the unconstrained bound breaks at least one, and costs time: it lies between the
    bound and the bound plus 10 % (measured on corner90: +4.3 %). Its stages have the
    driver's planning tire (`stiffness_power`). The free bound with a tire of the plant's
    shape (``car``) takes the same time at the slips where that tire peaks."""
    sc = replay[2]["nominal"][0]
    driver = vs.RecedingHorizonDriver(table=sc.table)
    free, _, exact_free = vs.offline_bound(sc)
    bound, D, exact = vs.offline_bound(sc, driver=driver)
    assert exact and exact_free and bool(bound.solution.converged)
    assert float(free.t_f) * 1.01 < float(bound.t_f) < float(free.t_f) * 1.10

    end_limit = float(bound.problem.end_slip_limit())  # the gravel tire's peak slip, 0.214
    assert end_limit == pytest.approx(float(vs.rally_gravel_tire().peak_slip), rel=1e-12)

    def worst(prim):
        """The largest excess over the margin, the slip bound and the steering rate."""
        xs, us = np.asarray(prim.solution.xs), np.asarray(prim.solution.us)
        M = us.shape[0]
        s = np.linspace(0.0, float(sc.road.length), M + 1)
        lo, hi = np.asarray(sc.table.corridor_at(jnp.asarray(s), float(driver.margin))).T
        n, xi, vx, vy = xs[:, 0], xs[:, 1], xs[:, 2], xs[:, 3]
        corridor = np.max(np.maximum(lo - n, n - hi))
        slips = np.asarray(jax.vmap(lambda X: vs.axle_slips(driver.vehicle, X))(
            jnp.asarray(xs)))
        kap = np.asarray(sc.table.curvature_at(jnp.asarray(s)))
        sdot = (vx * np.cos(xi) - vy * np.sin(xi)) / (1.0 - n * kap)
        rate = np.abs(us[:, 2] * sdot[:-1])
        # the steering-rate rows are path constraints, at each stage's first knot; the slip
        # bound holds at every stage's first knot (the first too: the driver's bound starts
        # rolling), and the end knot's at the last stage tire's peak slip
        return (corridor, np.max(slips[:-1]) - float(driver.slip_limit),
                np.max(slips[-1]) - end_limit,
                np.max(rate) - float(driver.steer_rate))

    assert max(worst(free)) > 0.01
    assert max(worst(bound)) < 1e-6, worst(bound)

    # the free bound with a tire of the plant's shape (`planner_car`, peaking at 5-6 %
    # slip): the same time within 1 % (measured +0.03 %), its slips where that tire
    # peaks (90th percentile 0.05 and 0.07 against the gravel tire's 0.21 and 0.23)
    shaped, _, exact_shaped = vs.offline_bound(sc, car=vs.planner_car(0.52))
    assert exact_shaped and float(shaped.problem.vehicle.tire.B) > 30.0
    assert float(shaped.t_f) == pytest.approx(float(free.t_f), rel=0.01)

    def slip_p90(prim):
        xs = prim.solution.xs
        return np.percentile(np.asarray(jax.vmap(
            lambda X: vs.axle_slips(prim.problem.vehicle, X))(xs)), 90, axis=0)

    assert np.all(slip_p90(shaped) < 0.1) and np.all(slip_p90(free) > 0.15)

    # another margin is one more fixed point of the same compiled solve (every number of
    # the problem an array: a long sweep of bounds neither recompiles nor fills the
    # process with programs), and a wider corridor margin costs time
    traces = []
    original = baselines.horizon_problem
    monkeypatch.setattr(baselines, "horizon_problem",
                        lambda *a, **k: traces.append(k["margin"]) or original(*a, **k))
    wider, _, exact_wider = vs.offline_bound(
        sc, driver=vs.RecedingHorizonDriver(table=sc.table, margin=0.3, margin_grip_power=1.0,
                                            peak_fraction=0.9))
    assert traces == [] and exact_wider
    assert float(wider.t_f) > float(bound.t_f) * 1.005
    # the margin narrowed where the planned grip (90 % of the peak) is below the car's:
    # near the end, where the drive is fastest (by 3.6 mm: the corridor is compared exactly)
    g = np.minimum(np.asarray(wider.problem.grip), 1.0)
    assert np.min(g) < 0.995
    s = np.linspace(0.0, float(sc.road.length), g.size + 1)
    lo, hi = np.asarray(sc.table.corridor_at(jnp.asarray(s), 0.3 * np.append(g, g[-1]))).T
    np.testing.assert_allclose(np.asarray(wider.problem.corridor), np.stack([lo, hi], -1),
                               rtol=1e-12, atol=1e-12)

    # a driver whose planning tire keeps its slip stiffness: its bound's stages have that
    # tire (the problem's first trace is enough to see it, so it stops there)
    class Traced(Exception):
        pass

    def first_trace(*a, **k):
        raise Traced(k["stiffness_power"])

    monkeypatch.setattr(baselines, "horizon_problem", first_trace)
    with pytest.raises(Traced) as traced:
        vs.offline_bound(sc, driver=vs.RecedingHorizonDriver(table=sc.table,
                                                             stiffness_power=1.0))
    assert traced.value.args[0] is not None
