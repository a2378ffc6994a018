"""Minimum-time drives on centre-line roads in the road's frame (arc length as the
independent variable): the point mass against its closed form, the car against an
independent Cartesian re-simulation in time, a periodic lap, the speed-profile guess.

The roads here are a stand-in written in the test (straights and circular arcs with
analytic curvature, positions and a brute-force distance off the road), independent of the
library's road classes."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vehsim import CentrelineRoad, Gate
from vehsim._constants import GRAVITY as G
from vehsim.optimal.curvilinear import (
    COARSE_START_VIOLATION,
    CurvilinearManeuverOCP,
    CurvilinearPointMassOCP,
    coarse_refusal,
    coarse_start,
    resample_drive,
    road_point_mass_bound,
    road_primitive,
    speed_profile,
    speed_profile_guess,
)
from vehsim.optimal.primitives import rally_gravel_car


pytestmark = pytest.mark.xdist_group("curvilinear")  # with tests/test_cli_roads.py


class _Gate:
    def __init__(self, s, lateral, speed=None):
        self.s, self.lateral, self.speed = s, lateral, speed


class _ArcsRoad:
    """Straights and arcs ("straight", L) / ("arc", R, degrees, left positive), constant
    width, gates at both ends."""

    def __init__(self, segments, width, closed=False, start_speed=None):
        self.pieces = []
        s0, x0, y0, th0 = 0.0, 0.0, 0.0, 0.0
        for seg in segments:
            if seg[0] == "straight":
                L, k = float(seg[1]), 0.0
            else:
                L, k = seg[1] * abs(math.radians(seg[2])), math.copysign(1 / seg[1], seg[2])
            self.pieces.append((s0, L, k, x0, y0, th0))
            x0, y0, th0 = self._pose(k, L, x0, y0, th0)
            s0 += L
        self.length, self.closed, self.w = s0, closed, width / 2
        lateral = (-self.w, self.w) if closed else (-0.8 * self.w, 0.8 * self.w)  # a lap: full
        self.start = _Gate(0.0, lateral, start_speed)
        self.end = _Gate(s0, lateral)
        self._dense = np.stack(self.position(np.linspace(0, s0, int(s0 / 0.01) + 1)), 1)

    @staticmethod
    def _pose(k, d, x0, y0, th0):
        kk = np.where(k == 0, 1.0, k)
        th = th0 + k * d
        x = np.where(k == 0, x0 + d * np.cos(th0), x0 + (np.sin(th) - np.sin(th0)) / kk)
        y = np.where(k == 0, y0 + d * np.sin(th0), y0 - (np.cos(th) - np.cos(th0)) / kk)
        return x, y, th

    def _piece(self, s):
        s = np.mod(s, self.length) if self.closed else np.asarray(s, float)
        starts = np.array([p[0] for p in self.pieces])
        i = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(starts) - 1)
        return s, np.array(self.pieces)[i]

    def curvature(self, s):
        return self._piece(s)[1][..., 2]

    def curvature_jumps(self):
        starts, k = np.array([p[0] for p in self.pieces]), np.array([p[2] for p in self.pieces])
        return starts[1:][np.diff(k) != 0]

    def width_left(self, s):
        return np.full(np.shape(s), self.w)

    width_right = width_left

    def _all(self, s):
        s, P = self._piece(s)
        return self._pose(P[..., 2], s - P[..., 0], P[..., 3], P[..., 4], P[..., 5])

    def position(self, s):
        return self._all(s)[:2]

    def heading(self, s):
        return self._all(s)[2]

    def to_cartesian(self, s, n):
        x, y, th = self._all(s)
        return x - n * np.sin(th), y + n * np.cos(th)

    def distance_off_road(self, x, y):
        p = np.stack([np.ravel(x), np.ravel(y)], 1)
        d = np.concatenate([np.min(np.hypot(q[:, None, 0] - self._dense[None, :, 0],
                                            q[:, None, 1] - self._dense[None, :, 1]), 1)
                            for q in np.array_split(p, max(1, len(p) // 200))])
        return np.maximum(d - self.w, 0.0).reshape(np.shape(x))


CORNER = [("straight", 20.0), ("arc", 20.0, 90.0), ("straight", 20.0)]
OVAL = [("straight", 30.0), ("arc", 12.0, 180.0), ("straight", 30.0), ("arc", 12.0, 180.0)]
M_OPEN = 40


@pytest.fixture(scope="module")
def corner():
    road = _ArcsRoad(CORNER, 8.0, start_speed=8.0)
    return road, road_primitive(road, num_stages=M_OPEN)


@pytest.fixture(scope="module")
def lap():
    road = _ArcsRoad(OVAL, 8.0, closed=True)
    return road, road_primitive(road, num_stages=50)


@pytest.mark.parametrize("steps", [1, 2])
def test_point_mass_on_a_straight_is_the_closed_form(steps):
    D, v0, L = 0.52, 5.0, 100.0
    road = _ArcsRoad([("straight", L)], 8.0, start_speed=v0)
    M = M_OPEN // steps
    pm = road_point_mass_bound(road, D=D, num_stages=M, steps_per_stage=steps)
    a = D * float(pm.problem.g)
    exact = (math.sqrt(v0**2 + 2 * a * L) - v0) / a
    assert float(pm.t_f) == pytest.approx(exact, rel=1e-5)
    assert float(pm.exit_speed) == pytest.approx(math.sqrt(v0**2 + 2 * a * L), rel=1e-5)


def test_car_is_slower_than_the_point_mass_and_on_the_road(corner):
    road, prim = corner
    assert bool(prim.solution.converged)
    pm = road_point_mass_bound(road, num_stages=M_OPEN)
    assert float(pm.t_f) < float(prim.t_f) < 1.1 * float(pm.t_f)
    v = prim.violations()
    assert v["corridor"] < 1e-6 and v["corridor_between_nodes"] < 0.01
    assert v["boundary"] < 1e-8 and v["defects"] < 1e-8
    xs = np.asarray(prim.solution.xs)
    assert xs[0, 2] == pytest.approx(8.0) and abs(xs[-1, 1]) < 1e-8 and abs(xs[-1, 4]) < 1e-8


def _cartesian_drive(car, z0, t_knots, inputs, substeps):
    """The Cartesian reduced half-car (x, y, psi, vx, vy, r) integrated in time by RK4 with
    inputs linear in time between the knot times; returns every substep's state."""
    f = jax.jit(lambda z, u: car.f(z, u))
    z = np.asarray(z0, float)
    out = [z]
    for k in range(len(t_knots) - 1):
        dt = (t_knots[k + 1] - t_knots[k]) / substeps
        for j in range(substeps):
            u = lambda a: inputs[k] + (inputs[k + 1] - inputs[k]) * (j + a) / substeps
            k1 = np.asarray(f(z, u(0.0)))
            k2 = np.asarray(f(z + 0.5 * dt * k1, u(0.5)))
            k3 = np.asarray(f(z + 0.5 * dt * k2, u(0.5)))
            k4 = np.asarray(f(z + dt * k3, u(1.0)))
            z = z + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            out.append(z)
    return np.array(out)


def _cartesian_knots(road, xs, s):
    x, y = road.to_cartesian(s, xs[:, 0])
    return np.stack([x, y, np.unwrap(road.heading(s)) + xs[:, 1], xs[:, 2], xs[:, 3],
                     xs[:, 4]], 1)


def test_cartesian_re_simulation_stays_on_the_road_and_ends_at_the_gate(corner):
    road, prim = corner
    car = prim.problem.vehicle
    xs = np.asarray(prim.solution.xs)
    cart = _cartesian_knots(road, xs, prim.problem.stage_edges())
    # stage by stage from each knot: the path between the nodes, and the next knot
    f = jax.jit(jax.vmap(lambda z0, t, u: _stage_rk4(car, z0, t, u, 20)))
    ends, path = f(cart[:-1], np.stack([xs[:-1, 8], xs[1:, 8]], 1),
                   np.stack([xs[:-1, 5:8], xs[1:, 5:8]], 1))
    ends, path = np.asarray(ends), np.asarray(path)
    assert np.max(np.hypot(*(ends[:, :2] - cart[1:, :2]).T)) < 0.01
    assert np.max(road.distance_off_road(path[..., 0], path[..., 1])) < 0.01
    # the whole drive in time from the first knot ends at the end gate
    drive = _cartesian_drive(car, cart[0], xs[:, 8], xs[:, 5:8], 10)
    end_x, end_y = road.position(road.length)
    heading = road.heading(road.length)
    along = (drive[-1, 0] - end_x) * np.cos(heading) + (drive[-1, 1] - end_y) * np.sin(heading)
    across = -(drive[-1, 0] - end_x) * np.sin(heading) + (drive[-1, 1] - end_y) * np.cos(heading)
    assert abs(along) < 0.15 and abs(across - xs[-1, 0]) < 0.3
    assert road.end.lateral[0] - 0.01 < across < road.end.lateral[1] + 0.01


def _stage_rk4(car, z0, t, u, substeps):
    dt = (t[1] - t[0]) / substeps

    def step(z, j):
        inp = lambda a: u[0] + (u[1] - u[0]) * (j + a) / substeps
        k1 = car.f(z, inp(0.0))
        k2 = car.f(z + 0.5 * dt * k1, inp(0.5))
        k3 = car.f(z + 0.5 * dt * k2, inp(0.5))
        k4 = car.f(z + dt * k3, inp(1.0))
        z = z + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return z, z

    return jax.lax.scan(step, z0, jnp.arange(substeps, dtype=float))


def test_cartesian_path_of_the_primitive_is_the_road_frame_path(corner):
    road, prim = corner
    pose = prim.cartesian()
    xs = np.asarray(prim.nodes())
    # independent: the stand-in's own frame, offset n along the left normal, at the knots
    # (a node on each of the corner's two curvature jumps)
    s = prim.arc_length()
    assert np.isin(road.curvature_jumps(), s).all()
    cx, cy = road.position(s)
    th = road.heading(s)
    np.testing.assert_allclose(pose["x"], cx - xs[:, 0] * np.sin(th), atol=1e-12)
    np.testing.assert_allclose(pose["y"], cy + xs[:, 0] * np.cos(th), atol=1e-12)
    rec = prim.record()
    assert rec["status"] == "successful" and rec["t_f"] == pytest.approx(float(prim.t_f))
    assert rec["max_corridor_violation_between_nodes"] < 0.01
    assert rec["t"][-1] == pytest.approx(rec["t_f"]) and np.all(np.diff(rec["t"]) > 0)


def test_stages_at_curvature_jumps_are_as_accurate_as_the_others(corner):
    """Each stage re-integrated from its knot by an independent integrator (SciPy's DOP853
    at 1e-11, the road-frame equations written out here with the stand-in's exact
    piecewise-constant curvature) ends at the next knot. A node sits on each of the
    corner's two jumps, so the stages there are as accurate as the rest; a stage across a
    jump was off by millimetres."""
    from scipy.integrate import solve_ivp

    road, prim = corner
    xs, us = np.asarray(prim.solution.xs), np.asarray(prim.solution.us)
    edges = prim.problem.stage_edges()
    body = jax.jit(lambda v, u: prim.problem.vehicle.f(jnp.concatenate([jnp.zeros(2), v]),
                                                       u)[3:6])

    def rhs(s, X, u, kappa):
        n, xi, vx, vy, r = X[:5]
        sdot = (vx * math.cos(xi) - vy * math.sin(xi)) / (1.0 - n * kappa)
        ndot = vx * math.sin(xi) + vy * math.cos(xi)
        rates = np.asarray(body(jnp.asarray(X[1:5]), jnp.asarray(X[5:8])))
        return np.concatenate([[ndot / sdot, r / sdot - kappa], rates / sdot, u, [1 / sdot]])

    def error(k):
        kappa = float(road.curvature(0.5 * (edges[k] + edges[k + 1])))
        end = solve_ivp(rhs, (edges[k], edges[k + 1]), xs[k, :9], args=(us[k], kappa),
                        method="DOP853", rtol=1e-11, atol=1e-11).y[:, -1]
        return np.max(np.abs(end[:2] - xs[k + 1, :2]))  # n [m] and xi [rad]

    jumps = road.curvature_jumps()
    at_jumps = [k for k in range(len(us)) if np.any((edges[k] <= jumps + 1e-9)
                                                     & (jumps - 1e-9 <= edges[k + 1]))]
    assert len(at_jumps) == 4  # a node on each jump: the stages either side of it
    errors = [error(k) for k in at_jumps]
    assert max(errors) < 1e-5, errors
    assert np.median([error(k) for k in range(0, len(us), 5)]) < 1e-5


def test_the_library_road_gives_the_stand_in_drive(corner):
    """The same corner as a `CentrelineRoad` (its own curvature, widths, frame and distance
    off the road): the same problem arrays, the same optimum and violations."""
    road, prim = corner
    lib = CentrelineRoad.from_segments(CORNER, 8.0)
    w = 0.8 * road.w
    lib = lib.with_gates(Gate.at(lib, 0.0, n_min=-w, n_max=w, speed=8.0),
                         Gate.at(lib, lib.length, n_min=-w, n_max=w))
    assert lib.length == pytest.approx(road.length, rel=1e-12)
    other = road_primitive(lib, num_stages=M_OPEN)
    np.testing.assert_allclose(other.problem.curvature, prim.problem.curvature, atol=1e-9)
    assert float(other.t_f) == pytest.approx(float(prim.t_f), rel=1e-7)
    v, w2 = prim.violations(), other.violations()
    assert w2["corridor_between_nodes"] == pytest.approx(v["corridor_between_nodes"], abs=2e-4)
    np.testing.assert_allclose(other.cartesian()["x"], prim.cartesian()["x"], atol=1e-6)


def test_a_coarse_first_solve_starts_the_drive_where_it_converged(corner):
    """``coarse_stages``: the drive starts from the coarse solution where that converged (the
    same optimum, from another first iterate); where it stopped short, from its best iterate
    if that is within ``coarse_violation`` (one iteration short of convergence), else from
    the speed profile (two iterations, or a bound of 0: the first iterate is the direct
    solve's); the primitive and its record say which."""
    from vehsim.optimal.ip import IPOptions, interior_point

    road, prim = corner
    warm = road_primitive(road, num_stages=M_OPEN, coarse_stages=20)
    assert bool(warm.coarse.converged) and bool(warm.solution.converged)
    assert float(warm.t_f) == pytest.approx(float(prim.t_f), rel=1e-7)
    first = float(prim.solution.log.objective[0])
    assert abs(float(warm.solution.log.objective[0]) - first) > 1e-3
    rec = warm.record()["coarse"]
    assert (rec["segments"], rec["status"], rec["started_from"]) == (20, "successful", True)
    assert rec["iterations"] == int(warm.coarse.iterations)
    short = road_primitive(road, num_stages=M_OPEN, coarse_stages=20, throw=False,
                           options=IPOptions(max_iter=2))
    assert not bool(short.coarse.converged)
    assert float(short.solution.log.objective[0]) == pytest.approx(first, rel=1e-12)
    rec = rec_short = short.record()["coarse"]
    assert (rec["status"], rec["iterations"], rec["started_from"]) == (
        "ip_max_iterations", 2, False)
    assert rec["inf_pr"] > COARSE_START_VIOLATION and short.started_from_coarse is False
    assert "coarse" not in prim.record()
    # one iteration short: the best iterate is nearly feasible, and the drive starts there
    # (its first iterate the resampled best one, near the converged start's), unless the
    # bound is 0
    n = int(warm.coarse.iterations) - 1
    near = road_primitive(road, num_stages=M_OPEN, coarse_stages=20, throw=False,
                          options=IPOptions(max_iter=n))
    assert not bool(near.coarse.converged) and near.started_from_coarse is True
    rec = near.record()["coarse"]
    assert (rec["status"], rec["iterations"], rec["started_from"]) == (
        "ip_max_iterations", n, True)
    assert 0.0 < rec["inf_pr"] <= COARSE_START_VIOLATION
    start = float(near.solution.log.objective[0])
    assert abs(start - first) > 1e-3
    assert start == pytest.approx(float(warm.solution.log.objective[0]), rel=1e-3)
    # why a start is refused, in words: the infeasibility against the bound, or an iterate
    # that is not finite, however small its infeasibility
    assert coarse_refusal(warm.coarse) is None and coarse_refusal(near.coarse) is None
    assert coarse_refusal(short.coarse) == (
        f"its best iterate's primal infeasibility {rec_short['inf_pr']:.1e}, above 1e-02")
    assert coarse_refusal(near.coarse, 0.0).endswith(", above 0e+00")
    assert coarse_refusal(near.coarse, rec["inf_pr"]) is None  # the bound is inclusive
    assert coarse_start(near.coarse, rec["inf_pr"]) and not coarse_start(near.coarse,
                                                                         0.5 * rec["inf_pr"])
    lost = eqx.tree_at(lambda s: s.us, near.coarse, near.coarse.us.at[3, 0].set(jnp.nan))
    assert float(lost.inf_pr) <= COARSE_START_VIOLATION and not coarse_start(lost)
    assert coarse_refusal(lost) == "its best iterate is not finite"
    none = road_primitive(road, num_stages=M_OPEN, coarse_stages=20, throw=False,
                          options=IPOptions(max_iter=n), coarse_violation=0.0)
    assert none.started_from_coarse is False and not none.record()["coarse"]["started_from"]
    assert float(none.solution.log.objective[0]) == pytest.approx(first, rel=1e-12)
    # the first solve keeps its best iterate, the fine one does not need to
    kept = []

    def recording(prob, xs0, us0, options, throw=True):
        kept.append(options.best_iterate)
        return interior_point(prob, xs0, us0, options, throw=throw)

    road_primitive(road, num_stages=M_OPEN, coarse_stages=20, solver=recording)
    assert kept == [True, False]


def test_closed_lap_is_periodic(lap):
    road, prim = lap
    assert bool(prim.solution.converged)
    xs = np.asarray(prim.solution.xs)
    assert np.max(np.abs(xs[-1, :8] - xs[0, :8])) < 1e-8
    assert xs[0, 8] == 0.0 or abs(xs[0, 8]) < 1e-10
    v = prim.violations()
    assert v["corridor_between_nodes"] < 0.01
    # the lap beats the quasi-steady speed profile it started from
    s, vel = speed_profile(road, 0.52, 0.8)
    t_profile = np.sum(np.diff(s) * 0.5 * (1 / vel[1:] + 1 / vel[:-1]))
    assert float(prim.t_f) < t_profile


def test_speed_profile_closed_forms():
    D, f, v0 = 0.52, 0.8, 5.0
    a = f * D * G
    road = _ArcsRoad([("straight", 60.0), ("arc", 20.0, 90.0), ("straight", 30.0)], 8.0,
                     start_speed=v0)
    s, v = speed_profile(road, D, f, g=G)
    # steady cornering in the middle of the arc, free acceleration from the start
    mid = (s > 60 + 0.4 * 31.4) & (s < 60 + 0.6 * 31.4)
    np.testing.assert_allclose(v[mid], math.sqrt(a * 20.0), rtol=1e-12)
    early = s < 5.0
    np.testing.assert_allclose(v[early], np.sqrt(v0**2 + 2 * a * s[early]), rtol=1e-9)
    # and braking into the arc: v^2 = a R + 2 a (s_b - s) (s_b the straight's last sample:
    # each step brakes with the friction left where the speed is known, none on the arc)
    late = (s > 55.0) & (s < 60.0)
    s_b = s[s < 60.0].max()
    np.testing.assert_allclose(v[late], np.sqrt(a * 20.0 + 2 * a * (s_b - s[late])), rtol=1e-9)
    # the guess of the car: centre line, yaw rate v kappa, times of 1/v
    xs, us = speed_profile_guess(road, rally_gravel_car(), 30, f)
    xs = np.asarray(xs)
    assert xs.shape == (31, 9) and us.shape == (30, 3)
    assert np.all(xs[:, 0] == 0) and xs[0, 8] == 0 and np.all(np.diff(xs[:, 8]) > 0)


def test_bad_arguments_are_refused():
    road = _ArcsRoad(CORNER, 8.0)
    with pytest.raises(ValueError, match="objective"):
        CurvilinearManeuverOCP.from_road(road, rally_gravel_car(), objective="fast")
    with pytest.raises(ValueError, match="margin"):
        CurvilinearPointMassOCP.from_road(road, margin=4.0)
    with pytest.raises(ValueError, match="num_stages"):
        CurvilinearPointMassOCP.from_road(road, num_stages=1)


def test_gates_the_road_frame_cannot_pose_are_refused_not_ignored():
    lib = CentrelineRoad.from_segments(CORNER, 8.0)
    car = rally_gravel_car()
    build = lambda r: CurvilinearManeuverOCP.from_road(r, car, num_stages=10)
    build(lib)  # the default gates: full width at both ends
    with pytest.raises(ValueError, match=r"start gate is at s = 30 m.*must be at s = 0 m"):
        build(lib.with_gates(30.0, None))
    with pytest.raises(ValueError, match=r"end gate is at s = 40 m.*must be at s = 71.4159"):
        CurvilinearPointMassOCP.from_road(lib.with_gates(None, 40.0), num_stages=10)
    with pytest.raises(ValueError, match=r"start gate's speed must be at least 1 m/s.*got 0.5"):
        build(lib.with_gates(Gate.at(lib, 0.0, speed=0.5), None))
    lap = CentrelineRoad.from_segments(OVAL, 8.0, closed=True)
    build(lap)
    with pytest.raises(ValueError, match="closed road's lap is periodic"):
        build(lap.with_gates(Gate.at(lap, 0.0, n_min=-1.0, n_max=1.0), None))
    with pytest.raises(ValueError, match="closed road's lap is periodic"):
        build(lap.with_gates(Gate.at(lap, 0.0, speed=10.0), None))
    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.raises(ValueError, match="needs float64"):
            build(lib)
    finally:
        jax.config.update("jax_enable_x64", True)


def test_stage_edges_put_a_node_on_every_curvature_jump():
    from vehsim.drive.scenarios import scenario_road
    from vehsim.optimal.curvilinear import stage_edges

    road = scenario_road("stage")  # six arcs between straights: ten jumps
    jumps = road.curvature_jumps()
    assert len(jumps) == 10
    M = 60
    edges = stage_edges(road, M)
    assert len(edges) == M + 1 and edges[0] == 0.0 and edges[-1] == road.length
    assert np.all(np.diff(edges) > 0)
    bounds = np.concatenate([[0.0], jumps, [road.length]])
    for a, b in zip(bounds[:-1], bounds[1:]):
        inside = edges[(edges >= a - 1e-9) & (edges <= b + 1e-9)]
        assert inside[0] == pytest.approx(a, abs=1e-9) and inside[-1] == pytest.approx(b, abs=1e-9)
        steps = np.diff(inside)
        np.testing.assert_allclose(steps, steps[0], rtol=1e-12)  # equal within a piece
        assert len(steps) == pytest.approx((b - a) / road.length * M, abs=1.0)
    smooth = CentrelineRoad.from_segments(
        [("straight", 10.0), ("clothoid", 10.0, 0.1), ("clothoid", 10.0, 0.0),
         ("straight", 10.0)], 8.0)
    assert len(smooth.curvature_jumps()) == 0 and stage_edges(smooth, M) is None
    with pytest.warns(UserWarning, match="more than num_stages=8"):
        assert stage_edges(road, 8) is None


def test_guess_and_resampling_follow_the_problems_knots():
    """On a road with curvature jumps the knots are not uniform: the speed-profile guess's
    rates are its input differences over each stage's own length, and resampling a drive
    onto the problem it came from gives it back."""
    lib = CentrelineRoad.from_segments(CORNER, 8.0)
    car = rally_gravel_car()
    prob = CurvilinearManeuverOCP.from_road(lib, car, num_stages=40)
    ds = np.diff(prob.stage_edges())
    assert np.ptp(ds) > 0.01  # not uniform
    xs, us = (np.asarray(a) for a in speed_profile_guess(lib, car, 40))
    np.testing.assert_allclose(us * ds[:, None], np.diff(xs[:, 5:8], axis=0), atol=1e-12)
    np.testing.assert_allclose(xs[:, 4], xs[:, 2] * lib.curvature(prob.stage_edges()),
                               atol=1e-12)  # r = v kappa at the knots' own arc lengths
    xs2, us2 = (np.asarray(a) for a in resample_drive(prob, xs, prob))
    np.testing.assert_allclose(xs2, xs, atol=1e-12)
    np.testing.assert_allclose(us2, us, atol=1e-9)


def _knots(lay, seed=0):
    """Knots near a car at 12 m/s on the centre line, every state and control perturbed (a
    closed road's periodic copy too): a point of the problems' domain."""
    rng = np.random.default_rng(seed)
    x = np.array([0.1, 0.02, 12.0, 0.3, 0.2, 0.01, 0.02, 0.03, 1.0])
    xs = np.concatenate([x, x[:8]])[: lay.nx]
    ys = np.concatenate([np.broadcast_to(xs, (lay.M + 1, lay.nx)), np.zeros((lay.M + 1, lay.nu))],
                        1)
    return jnp.asarray(ys + 0.05 * rng.standard_normal(ys.shape))


def test_the_hessian_skips_the_directions_declared_linear_and_gives_the_same_numbers(
        monkeypatch):
    """`linear_variables`: the time (and a closed road's periodic copy, a horizon problem's
    corridor slack) is declared, and `check_linear_variables` confirms the declarations (the
    Hessian with random weights on every output has zero rows there). On a closed lap, 9 of
    the 20 directions, the stage derivatives take the Hessian along the other 11 only
    (`curved_variables`), and every value, Jacobian and Hessian is the full computation's to
    rounding (1e-12: XLA fuses the two passes differently); where the declared share is
    below `LINEAR_SHARE_MIN` (a horizon problem's 1 of 12) every direction is taken."""
    from vehsim import drive_scenario, horizon_problem
    from vehsim.optimal.ip import derivatives as dv, problem as pm

    car = rally_gravel_car()
    lap = CurvilinearManeuverOCP.from_road(_ArcsRoad(OVAL, 8.0, closed=True), car, num_stages=8)
    open_road = CurvilinearManeuverOCP.from_road(_ArcsRoad(CORNER, 8.0, start_speed=8.0), car,
                                                 num_stages=8)
    table = drive_scenario("corner90", "nominal").table
    state8 = jnp.asarray([0.1, 0.02, 12.0, 0.3, 0.2, 0.01, 0.02, 0.03])
    hard = horizon_problem(table, car, 5.0, state8, jnp.full(6, 0.52), horizon=20.0)
    soft = horizon_problem(table, car, 5.0, state8, jnp.full(6, 0.52), horizon=20.0,
                           corridor_penalty=1.0, soft_stages=3)
    assert lap.linear_variables() == (8, *range(9, 17))
    assert open_road.linear_variables() == hard.linear_variables() == (8,)
    assert soft.linear_variables() == (8, 12)
    point_lap = CurvilinearPointMassOCP.from_road(_ArcsRoad(OVAL, 8.0, closed=True),
                                                  num_stages=8)
    assert point_lap.linear_variables() == (3, 4, 5, 6)  # of 9: skipped
    assert pm.curved_variables(point_lap, pm.stage_layout(point_lap)) == (0, 1, 2, 7, 8)
    # each declaration checked once: the lap's covers the open road's t, the soft horizon's
    # the hard one's (a wrong declaration refused: test_optimal_nlp's linear program test)
    for prob in (lap, soft, point_lap):
        dv.check_linear_variables(prob, _knots(pm.stage_layout(prob)))

    class Bad(type(hard)):
        def linear_variables(self):
            return (8, 8)

    bad = Bad(**{f: getattr(hard, f) for f in hard.__dataclass_fields__})
    with pytest.raises(ValueError, match=r"must be distinct indices into y = \(x, u\), 0..11"):
        pm.curved_variables(bad, pm.stage_layout(bad))

    lay = pm.stage_layout(lap)
    assert pm.curved_variables(lap, lay) == (*range(8), 17, 18, 19)
    assert pm.curved_variables(hard, pm.stage_layout(hard)) is None  # 1 of 12: all taken
    taken = []
    forward_over_reverse = dv._forward_over_reverse
    monkeypatch.setattr(dv, "_forward_over_reverse",
                        lambda vec, y, k, w, curved=None: taken.append(curved)
                        or forward_over_reverse(vec, y, k, w, curved))

    class Full(type(lap)):
        def linear_variables(self):
            return ()

    full = Full(**{f: getattr(lap, f) for f in lap.__dataclass_fields__})
    ys = _knots(lay, seed=1)
    rng = np.random.default_rng(2)
    lam, nu, z = (jnp.asarray(rng.standard_normal((lay.M + 1, n)))
                  for n in (lay.nx, lay.ne, lay.ng))
    split, every = (jax.jit(lambda ys, lam, nu, z, p=p: dv.stage_derivatives(p, lay, ys, lam,
                                                                             nu, z))(
        ys, lam, nu, z) for p in (lap, full))
    assert taken == [pm.curved_variables(lap, lay), None]
    for name in ("objective", "c", "e", "g", "grad_f", "A", "Je", "Jg", "H"):
        a, b = np.asarray(getattr(split, name)), np.asarray(getattr(every, name))
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * np.max(np.abs(b), initial=0.0))
    assert float(jnp.max(jnp.abs(split.H[:, 8:17]))) == 0.0
    assert float(jnp.max(jnp.abs(split.H))) > 1.0  # the curved part is there
