"""The receding-horizon driver: its road table against the NumPy road, the drive against the
offline primitive, warm starts, real-time iterations and derivatives of a drive."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs


pytestmark = pytest.mark.xdist_group("drive")

V0 = 12.0
HORIZON = 60.0
STAGES = 30
MARGIN = 0.2


# ---- the road table ---------------------------------------------------------------------


@pytest.mark.parametrize("closed", [False, True])
def test_road_table_matches_centreline_road(closed):
    if closed:
        road = vs.CentrelineRoad.from_segments(
            [("straight", 10), ("arc", 8, 180), ("straight", 10), ("arc", 8, 180)], 3.0,
            closed=True)
    else:
        road = vs.CentrelineRoad.from_segments(
            [("straight", 10), ("arc", 10, 90), ("clothoid", 8, -0.05), ("straight", 5)],
            (3.0, 2.0))
    table = vs.RoadTable.from_road(road)
    rng = np.random.default_rng(1)
    s = rng.uniform(0.0, road.length, 300)
    n = rng.uniform(-1.5, 1.5, 300)
    x, y = road.to_cartesian(s, n)
    xt, yt = jax.vmap(table.to_cartesian)(jnp.asarray(s), jnp.asarray(n))
    assert np.max(np.hypot(x - xt, y - yt)) < 1e-4
    psi = np.asarray(road.heading(s)) + rng.uniform(-0.5, 0.5, 300)
    guess = s + rng.uniform(-3.0, 3.0, 300)
    sf, nf, xif = jax.jit(jax.vmap(table.to_frenet))(jnp.asarray(x), jnp.asarray(y),
                                                     jnp.asarray(psi), jnp.asarray(guess))
    sr, nr = road.to_frenet(x, y)
    ds = np.asarray(sf) - sr
    if closed:
        ds = (ds + road.length / 2) % road.length - road.length / 2
    assert np.max(np.abs(ds)) < 1e-4 and np.max(np.abs(np.asarray(nf) - nr)) < 1e-4
    xi = np.asarray(psi) - np.asarray(road.heading(sr))
    assert np.max(np.abs(np.asarray(xif) - xi)) < 1e-3
    # curvature: linear between samples (a jump of joined segments spreads over one)
    smooth = np.abs(road.curvature(s - 0.1) - road.curvature(s + 0.1)) < 0.01
    kap = np.asarray(table.curvature_at(jnp.asarray(s)))
    np.testing.assert_allclose(kap[smooth], road.curvature(s[smooth]), atol=1e-3)
    lo_hi = np.asarray(table.corridor_at(jnp.asarray(s), 0.1))
    np.testing.assert_allclose(lo_hi[:, 0], -road.width_right(s) + 0.1, atol=1e-9)
    np.testing.assert_allclose(lo_hi[:, 1], road.width_left(s) - 0.1, atol=1e-9)
    # the projection is differentiable: d n / d y is the normal's y component
    dn = jax.grad(lambda yy: table.to_frenet(x[0], yy, psi[0], guess[0])[1])(y[0])
    assert abs(float(dn) - np.cos(road.heading(sr[0]))) < 1e-3
    if closed:
        assert abs(float(table.wrap(road.length + 1.0)) - 1.0) < 1e-12
    else:  # past the end: the straight extension of the end's heading and width
        (xe, ye), th = road.position(road.length), road.heading(road.length)
        xp, yp = table.to_cartesian(road.length + 10.0, 0.5)
        assert abs(float(xp) - (xe + 10 * np.cos(th) - 0.5 * np.sin(th))) < 1e-9
        assert abs(float(yp) - (ye + 10 * np.sin(th) + 0.5 * np.cos(th))) < 1e-9


# ---- drives on a corner -----------------------------------------------------------------


@pytest.fixture(scope="module")
def corner():
    """The corner, the plant (noise off) on the road of scale 0.52/mu*(1) (its peak 0.59 at
    20 m/s, 0.65 at 12 m/s: more than the planner believes), the planner's car (its tire's
    shape fitted to the plant's steady state at 12 m/s, the corner's speeds; the peak the
    nominal 0.52), the primitive of that car, the table with the true grip. The drives plan
    with the car's D = 0.52 at every stage (the nominal road's peak at 20 m/s, `peak_speed`),
    the D of the primitive they are compared with."""
    road = vs.CentrelineRoad.from_segments([("straight", 15), ("arc", 15, 90), ("straight", 15)],
                                           4.0)
    road = road.with_gates(vs.Gate.at(road, 0.0, n_min=0.0, n_max=0.0, speed=V0), None)
    mu1 = float(vs.AxleGripEstimator().peak(1.0))
    lam0 = 0.52 / mu1
    plant = vs.DrivePlant(grip=vs.UniformGrip(scale=lam0),
                          sensors=vs.DriveSensors(noise_on=False))
    tire = vs.fit_planner_tire(0.52, lam0, speed=12.0)
    car = vs.ReducedHalfCar(params=vs.rally_gravel(), tire=tire)
    # the primitive on the driver's corridor (the road less the margin on each side)
    prim = vs.road_primitive(road, car=car, num_stages=100, margin=MARGIN, fraction=0.6)
    table = vs.RoadTable.from_road(road).with_grip(plant.grip)
    num = int(np.ceil(1.12 * float(prim.t_f) / 0.05))
    return dict(road=road, plant=plant, car=car, prim=prim, table=table, num=num)


@eqx.filter_jit
def _drive(plant, driver, state0, key, num):
    return vs.simulate_drive(plant, driver, state0, key, num)


def _driver(corner, **kw):
    kw = dict(horizon=HORIZON, num_stages=STAGES, margin=MARGIN, friction="nominal",
              peak_speed=20.0) | kw
    return vs.RecedingHorizonDriver(corner["table"], corner["car"], **kw)


def _run(corner, driver):
    plant = corner["plant"]
    return _drive(plant, driver, vs.init_drive(plant, vx=V0), jax.random.key(0), corner["num"])


def _reading(road, run):
    """Drive time (the CG crossing s = L, interpolated) and the largest distance off the
    road until then."""
    car = np.asarray(run.states.car)
    t = np.concatenate([[0.0], np.asarray(run.states.t)])
    x = np.concatenate([[0.0], car[:, 0]])
    y = np.concatenate([[0.0], car[:, 1]])
    s, _ = road.to_frenet(x, y)
    L = road.length
    (xe, ye), th = road.position(L), road.heading(L)
    past = (x - xe) * np.cos(th) + (y - ye) * np.sin(th)  # along the end's tangent
    s = np.where(s >= L - 1e-9, L + np.maximum(past, 0.0), s)
    assert s[-1] > L, "the drive did not reach the end"
    i = int(np.argmax(s > L))
    tc = t[i - 1] + (road.length - s[i - 1]) / (s[i] - s[i - 1]) * (t[i] - t[i - 1])
    return tc, float(np.max(road.distance_off_road(x[:i], y[:i])))


def test_drive_reading():
    """The reading of a drive: a car at 10 m/s along a straight road's centre line."""
    road = vs.CentrelineRoad.from_segments([("straight", 10.0)], 4.0)
    t = 0.05 * np.arange(1, 31)
    car = np.zeros((30, 3))
    car[:, 0] = 10.0 * t - 0.3
    car[:, 1] = 0.1
    run = type("Run", (), {"states": type("S", (), {"car": car, "t": t})})
    tc, off = _reading(road, run)
    assert tc == pytest.approx(1.03) and off == 0.0


@pytest.fixture(scope="module")
def converged_run(corner):
    driver = _driver(corner, mode="converged", max_iterations=40)
    return driver, _run(corner, driver)


@pytest.mark.slow  # a drive: one compilation of a few minutes
def test_fixed_grip_driver_reproduces_primitive(corner, converged_run):
    """The driver (converged mode, D fixed at its car's) against the offline primitive of its
    planning car on the same corridor. The goal is 2 %; measured 3.3 % (4.642 s against 4.495 s)
    with no departure, so the bound here is 4 %: a regression test of the drive, not yet
    the goal."""
    driver, run = converged_run
    tc, off = _reading(corner["road"], run)
    t_prim = float(corner["prim"].t_f)
    print("oracle drive", tc, "primitive", t_prim, "off", off,
          "iterations", np.asarray(run.controller_info["iterations"]).tolist())
    assert abs(tc / t_prim - 1.0) < 0.04, (tc, t_prim)
    assert off < 0.05
    info = run.controller_info
    assert info["plan_s"].shape == (corner["num"], STAGES + 1)
    assert np.all(np.asarray(info["D"]) == pytest.approx(float(corner["car"].tire.D), rel=1e-9))
    # the table's peak is the plant's at the speed asked for, not the planner's 0.52
    assert float(corner["table"].peak_at(10.0, 20.0)) == pytest.approx(0.59, abs=0.01)
    # the converged mode reaches its cap on most samples (31 % converged): see docs/drive.md
    assert np.all(np.asarray(info["iterations"]) <= 40)


@pytest.mark.slow  # a drive: one compilation of a few minutes
def test_warm_start_lowers_iterations(corner, converged_run):
    """Per sample, the converged solve from the shifted plan against the one from the
    speed-profile guess, on the same problems (the drive's); one compilation for all."""
    driver, run = converged_run
    info = jax.tree.map(np.asarray, run.controller_info)
    samples = np.arange(3, corner["num"] - 10, 12)
    table, car = corner["table"], corner["car"]

    @eqx.debug.assert_max_traces(max_traces=1)
    def cold(s0, state8, D):
        prob = driver.problem(s0, state8, D)
        xs0, us0 = vs.profile_guess(table, car, s0, state8, D, horizon=driver.horizon)
        return vs.interior_point(prob, xs0, us0, driver.options(first=True), throw=False)

    sol = jax.jit(jax.vmap(cold))(info["plan_s"][samples, 0], info["start"][samples],
                                   info["D"][samples])
    iters = np.asarray(sol.iterations)
    warm = info["iterations"][samples]
    print("iterations per sample: warm", warm.tolist(), "cold", iters.tolist())
    assert np.sum(warm) < 0.7 * np.sum(iters), (warm, iters)


@pytest.mark.slow  # a drive: one compilation of a few minutes
def test_rti_drives_the_road(corner, converged_run):
    _, run = converged_run
    t_conv, _ = _reading(corner["road"], run)
    rti = _run(corner, _driver(corner, mode="rti", iterations=4))
    t_rti, off = _reading(corner["road"], rti)
    assert off < 0.05
    # measured: 4.944 s against 4.642 s (+6.5 %; 4.821 s, +3.9 %, compiled with XLA's
    # default flags: real-time iterations are sensitive to rounding); 8 iterations: 5.029 s
    assert abs(t_rti / t_conv - 1.0) < 0.08, (t_rti, t_conv)
    assert np.all(np.asarray(rti.controller_info["iterations"]) <= 4)


def test_reverse_mode_is_refused_with_the_mode_to_use(corner):
    driver = _driver(corner, mode="rti", iterations=2, init_iterations=5)
    plant = corner["plant"]
    m0 = vs.measure_drive(plant, vs.init_drive(plant, vx=V0), jax.random.key(0))
    state = driver.init(m0)

    def steer(w):
        d = eqx.tree_at(lambda d: d.rate_weight, driver, w)
        return d.command(state, m0, None)[1][2]

    with pytest.raises(TypeError, match="forward mode"):
        jax.grad(steer)(1e-4)
