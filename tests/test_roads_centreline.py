"""Centre-line roads: geometry against closed forms (circles, straights, annuli), the Frenet
round trip, files against roads built in code, validation messages, the shipped circuit."""

import math
import re
import warnings

import numpy as np
import pytest

import vehsim as vs
from vehsim import CentrelineRoad, Gate, read_road, write_road
from vehsim.optimal.centreline import _crossing, _segments_cross


def _wavy_loop(n=60):
    """A closed, non-circular loop (counter-clockwise) with widths that vary and differ."""
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    r = 60.0 + 8.0 * np.cos(3 * t)
    x, y = r * np.cos(t), 0.7 * r * np.sin(t)
    wr = 4.0 + 0.5 * np.sin(2 * t)
    wl = 3.0 + 0.4 * np.cos(t)
    return x, y, wr, wl


@pytest.fixture(scope="module")
def loop():
    return CentrelineRoad.from_points(*_wavy_loop(), closed=True, name="loop")


def _write_csv(path, header, rows, comments=("# a test road",)):
    lines = list(comments) + [header] + [",".join(repr(float(v)) for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_road_read_from_a_file_equals_the_same_road_built_in_code(tmp_path, loop):
    x, y, wr, wl = _wavy_loop()
    # columns in another order, an extra column, the header as a comment line
    rows = np.stack([wl, x, np.zeros_like(x), wr, y], axis=-1)
    path = _write_csv(tmp_path / "loop.csv", "# w_tr_left_m,x_m,z_m,w_tr_right_m,y_m", rows)
    road = read_road(path, closed=True)
    assert road.name == "loop" and road.closed
    rng = np.random.default_rng(1)
    s = rng.uniform(0, loop.length, 200)
    np.testing.assert_array_equal(road.knots, loop.knots)
    for f in ("position", "curvature", "heading", "width_left", "width_right"):
        np.testing.assert_allclose(getattr(road, f)(s), getattr(loop, f)(s), rtol=0, atol=1e-12)
    px, py = rng.uniform(-80, 80, (2, 300))
    np.testing.assert_allclose(road.distance_off_road(px, py), loop.distance_off_road(px, py),
                               atol=1e-12)
    # a plain header line works the same
    plain = _write_csv(tmp_path / "plain.csv", "x_m,y_m,w_tr_right_m,w_tr_left_m",
                       np.stack([x, y, wr, wl], axis=-1), comments=())
    np.testing.assert_allclose(read_road(plain, closed=True).curvature(s), loop.curvature(s),
                               atol=1e-12)


def test_written_roads_read_back_as_the_same_curve(tmp_path, loop):
    road = read_road(write_road(tmp_path / "w.csv", loop), closed=True)
    s = np.linspace(0, loop.length, 501)
    assert road.length == pytest.approx(loop.length, rel=1e-9)
    np.testing.assert_allclose(np.stack(road.position(s)), np.stack(loop.position(s)), atol=1e-6)
    # the spline's curvature has kinks at its points (a cubic's third derivative jumps),
    # which the spline through the dense written samples rounds off slightly
    np.testing.assert_allclose(road.curvature(s), loop.curvature(s), atol=2e-5)
    assert np.median(np.abs(road.curvature(s) - loop.curvature(s))) < 1e-6
    np.testing.assert_allclose(road.width_left(s), loop.width_left(s), atol=1e-5)


def test_written_roads_read_back_as_laps_or_stages_with_their_gates(tmp_path, loop):
    """The file's comment lines carry what its columns cannot: a lap reads back as a lap and
    a stage as a stage without being told, each with its gates (a lateral interval narrower
    than the road, a fixed speed, a gate inside the road), and an argument overrides the
    file's closed line."""
    lap = read_road(write_road(tmp_path / "lap.csv", loop))
    assert lap.closed
    assert lap.start == Gate.at(lap, 0.0) and lap.end == Gate.at(lap, lap.length)
    stage = CentrelineRoad.from_segments([("straight", 20.0), ("arc", 20.0, 90.0),
                                          ("straight", 20.0)], 8.0, name="stage")
    for start, end in [
        (Gate.at(stage, 0.0, speed=8.0), Gate.at(stage, stage.length, n_min=-1.0, n_max=2.5)),
        (Gate.at(stage, 12.5, n_min=0.5, n_max=3.0), Gate.at(stage, 60.0, speed=11.25)),
    ]:
        gated = stage.with_gates(start, end)
        back = read_road(write_road(tmp_path / "stage.csv", gated))
        assert not back.closed
        for written, read in ((gated.start, back.start), (gated.end, back.end)):
            # the end of the road is its end (the spline through the written points has
            # its length to 1e-7 here); a gate inside it keeps its arc length
            s = back.length if written.s == gated.length else written.s
            assert read.s == pytest.approx(s, rel=1e-12, abs=1e-12)
            assert read.lateral == pytest.approx(written.lateral, abs=1e-9)
            assert read.speed == written.speed
    assert not read_road(tmp_path / "lap.csv", closed=False).closed
    said_open = tmp_path / "said_open.csv"
    said_open.write_text((tmp_path / "lap.csv").read_text().replace("# closed: yes",
                                                                    "# closed: no"))
    assert not read_road(said_open).closed
    assert read_road(said_open, closed=True).closed


_BODY = "# x_m,y_m,w_tr_right_m,w_tr_left_m\n" + "".join(
    f"{10 * i},0,3,3\n" for i in range(5))


@pytest.mark.parametrize("meta, match", [
    ("# closed: maybe\n", r"bad.csv:1: closed must be yes or no, got 'maybe'"),
    ("# closed: no\n# closed: yes\n", r"bad.csv:2: closed given twice \(first on line "
                                       r".*bad.csv:1\)"),
    ("# start_gate: n_min=edge\n", r"bad.csv:1: start_gate: s=\.\.\. .* missing"),
    ("# end_gate: s=end width=3\n", r"bad.csv:1: end_gate: 'width=3' is not one of s=\.\.\."),
    ("# end_gate: s=end speed=fast\n", r"bad.csv:1: end_gate: speed must be a number or "
                                       r"free, got 'fast'"),
    ("# end_gate: s=end s=start\n", r"bad.csv:1: end_gate: s given twice"),
    ("# start_gate: s=nan\n", r"bad.csv:1: start_gate: s must be finite"),
    ("# c\n# start_gate: s=start n_max=4\n", r"bad.csv:2: start_gate: .*off the road"),
    ("# end_gate: s=50\n", r"bad.csv:1: end_gate: .*gate at s = 50 m is off the road"),
])
def test_bad_closed_and_gate_lines_are_refused_naming_the_line(tmp_path, meta, match):
    path = tmp_path / "bad.csv"
    path.write_text(meta + _BODY)
    with pytest.raises(ValueError, match=match):
        read_road(path)


@pytest.mark.parametrize("angle", [360.0, -360.0])
def test_a_circle_from_segments_has_curvature_one_over_r_and_length_two_pi_r(angle):
    R, th0 = 25.0, 0.3
    road = CentrelineRoad.from_segments([("arc", R, angle)], (1.0, 2.0), start=(1.0, -2.0),
                                        start_heading=th0, closed=True)
    assert road.length == pytest.approx(2 * math.pi * R, rel=1e-13)
    sign = math.copysign(1.0, angle)
    s = np.random.default_rng(0).uniform(0, road.length, 300)
    np.testing.assert_allclose(road.curvature(s), sign / R, rtol=1e-8)
    # independent: c(s) = c0 + R N0 sign + R (sin, -cos) of the turned angle
    centre = np.array([1.0, -2.0]) + sign * R * np.array([-math.sin(th0), math.cos(th0)])
    th = th0 + sign * s / R
    x, y = road.position(s)
    np.testing.assert_allclose(x, centre[0] + sign * R * np.sin(th), atol=1e-9)
    np.testing.assert_allclose(y, centre[1] - sign * R * np.cos(th), atol=1e-9)
    np.testing.assert_allclose(road.heading(s), th, atol=1e-9)


def test_straights_arcs_and_clothoids_compose_exactly():
    R, a, b = 10.0, 30.0, 20.0
    road = CentrelineRoad.from_segments(
        [("straight", a), ("arc", R, 90.0), ("straight", b), ("clothoid", 12.0, -0.05)],
        4.0, start=(0.0, 0.0))
    L1, L2 = a, a + R * math.pi / 2
    assert road.length == pytest.approx(L2 + b + 12.0, rel=1e-13)
    assert road.curvature(np.array([0.5 * a]))[0] == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(road.curvature(np.linspace(L1 + 0.01, L2 - 0.01, 50)), 1 / R,
                               rtol=1e-8)
    assert road.curvature(L2 + 0.5 * b) == pytest.approx(0.0, abs=1e-9)
    # after the quarter turn: at (a + R, R), heading +y; then b further up
    x, y = road.position(np.array([L2, L2 + b]))
    np.testing.assert_allclose(x, [a + R, a + R], atol=1e-9)
    np.testing.assert_allclose(y, [R, R + b], atol=1e-9)
    # clothoid from 0 to -0.05 over 12 m: kappa linear, theta = pi/2 - 0.05 t^2 / 24
    t = np.linspace(0.0, 12.0, 7)
    np.testing.assert_allclose(road.curvature(L2 + b + t[1:-1]), -0.05 * t[1:-1] / 12, atol=1e-7)
    tt = np.linspace(0.0, 12.0, 200001)  # independent: trapezoid rule on cos, sin of theta
    th = np.pi / 2 - 0.05 * tt**2 / 24
    dx = np.sum(0.5 * (np.cos(th[1:]) + np.cos(th[:-1])) * np.diff(tt))
    dy = np.sum(0.5 * (np.sin(th[1:]) + np.sin(th[:-1])) * np.diff(tt))
    end = road.position(road.length)
    np.testing.assert_allclose(end, [a + R + dx, R + b + dy], atol=1e-8)
    assert road.heading(road.length) == pytest.approx(np.pi / 2 - 0.05 * 12 / 2, abs=1e-9)


def test_from_points_on_a_circle_is_reparametrised_by_true_arc_length():
    R, n = 30.0, 48
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    road = CentrelineRoad.from_points(R * np.cos(t), R * np.sin(t), np.full(n, 2.0),
                                      np.full(n, 2.0), closed=True)
    # the polygon through the points is 0.07 % shorter; the spline within 1e-5 of 2 pi R
    assert road.length == pytest.approx(2 * np.pi * R, rel=1e-5)
    s = np.linspace(0, road.length, 400)
    np.testing.assert_allclose(road.curvature(s), 1 / R, rtol=3e-3)  # spline vs circle
    d = np.hypot(*np.diff(np.stack(road.position(s)), axis=1))
    ds = s[1] - s[0]  # unit speed in s: the chords of arcs ds long on a circle of radius ~R
    np.testing.assert_allclose(d, 2 * R * np.sin(ds / (2 * R)), rtol=1e-7)


def test_from_points_passes_through_its_points_with_their_widths(loop):
    x, y, wr, wl = _wavy_loop()
    s, n = loop.to_frenet(x, y)
    np.testing.assert_allclose(n, 0.0, atol=1e-9)
    np.testing.assert_allclose(np.stack(loop.position(s)), np.stack([x, y]), atol=1e-9)
    np.testing.assert_allclose(loop.width_right(s), wr, atol=1e-9)
    np.testing.assert_allclose(loop.width_left(s), wl, atol=1e-9)
    assert s[0] == pytest.approx(0.0, abs=1e-9) and np.all(np.diff(s) > 0)  # in order


def test_smoothing_is_the_rms_distance_of_the_points_from_the_curve():
    # a circle of radius 50 m through noisy points (0.27 m rms): interpolated, its curvature
    # wiggles beyond the 3 m widths' limit and the road is refused; smoothed by 0.25 m, the
    # points lie 0.25 m rms from the curve and its curvature is close to 1/R
    R, n = 50.0, 120
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    r = R + np.random.default_rng(5).normal(0.0, 0.3, n)
    x, y, w = r * np.cos(t), r * np.sin(t), np.full(n, 3.0)
    with pytest.raises(ValueError, match="reaches the radius of curvature"):
        CentrelineRoad.from_points(x, y, w, w, closed=True)
    road = CentrelineRoad.from_points(x, y, w, w, closed=True, smoothing=0.25)
    _, off = road.to_frenet(x, y)
    assert 0.9 * 0.25 < np.sqrt(np.mean(off**2)) <= 0.25 * 1.001
    s = np.linspace(0, road.length, 1000)
    np.testing.assert_allclose(road.curvature(s), 1 / R, atol=0.1 / R)


def test_to_frenet_inverts_to_cartesian_and_n_is_to_the_left(loop):
    rng = np.random.default_rng(2)
    s = rng.uniform(0, loop.length, 500)
    n = rng.uniform(-1, 1, 500) * np.where(rng.uniform(size=500) < 0.5, loop.width_right(s),
                                           loop.width_left(s))
    s2, n2 = loop.to_frenet(*loop.to_cartesian(s, n))
    np.testing.assert_allclose(s2, s, atol=1e-8)
    np.testing.assert_allclose(n2, n, atol=1e-8)
    straight = CentrelineRoad.from_segments([("straight", 10.0)], 4.0, start_heading=0.0)
    np.testing.assert_allclose(straight.to_cartesian(3.0, 1.5), (3.0, 1.5), atol=1e-12)


def test_distance_off_an_annulus_is_the_closed_form():
    R, wr, wl = 20.0, 3.0, 1.5  # counter-clockwise: left is inside
    road = CentrelineRoad.from_segments([("arc", R, 360.0)], (wr, wl), start=(0.0, -R),
                                        closed=True)
    rng = np.random.default_rng(3)
    p = rng.uniform(-30, 30, (2, 2000))
    r = np.hypot(*p)
    exact = np.maximum(np.maximum(R - wl - r, r - (R + wr)), 0.0)
    np.testing.assert_allclose(road.distance_off_road(*p), exact, atol=1e-7)
    assert np.any(exact == 0) and np.any(r < R - wl) and np.any(r > R + wr)


def test_distance_off_the_road_is_exact_within_millimetres_of_curved_edges():
    # a tight annulus: inner edge radius 1 m, outer 15 m; points 0.1 and 1 mm either side of
    # both edges (a polygon through the stored edge samples is off by up to 0.3 and 5 mm)
    R, wr, wl = 5.0, 10.0, 4.0
    road = CentrelineRoad.from_segments([("arc", R, 360.0)], (wr, wl), start=(0.0, -R),
                                        closed=True)
    phi = np.random.default_rng(6).uniform(0, 2 * np.pi, 800)
    r = np.concatenate([np.full(100, R + wr) + d for d in (-1e-3, -1e-4, 1e-4, 1e-3)]
                       + [np.full(100, R - wl) + d for d in (-1e-3, -1e-4, 1e-4, 1e-3)])
    exact = np.maximum(np.maximum(R - wl - r, r - (R + wr)), 0.0)
    got = road.distance_off_road(r * np.cos(phi), r * np.sin(phi))
    np.testing.assert_allclose(got, exact, atol=1e-9)


def test_distance_off_an_open_straight_is_the_distance_to_its_rectangle():
    road = CentrelineRoad.from_segments([("straight", 40.0)], (2.0, 3.0), start=(5.0, 1.0))
    x, y = np.random.default_rng(4).uniform(-10, 60, (2, 1000))
    dx = np.maximum(np.maximum(5.0 - x, x - 45.0), 0.0)
    dy = np.maximum(np.maximum(-1.0 - y, y - 4.0), 0.0)
    np.testing.assert_allclose(road.distance_off_road(x, y), np.hypot(dx, dy), atol=1e-9)
    np.testing.assert_array_equal(road.on_road(x, y), np.hypot(dx, dy) == 0)
    # just beyond the ends, beside the corners (the end line is the nearest side)
    x, y = np.array([45.01, 45.01, 4.99, 4.99, 45.001]), np.array([3.99, -0.99, 3.99, -0.99, 0.0])
    np.testing.assert_allclose(road.distance_off_road(x, y), [0.01] * 4 + [0.001], atol=1e-12)


def test_closed_roads_wrap_in_s(loop):
    s = np.linspace(0, loop.length, 37)
    L = loop.length
    for f in ("position", "curvature", "width_left", "width_right"):
        np.testing.assert_allclose(getattr(loop, f)(s + L), getattr(loop, f)(s), atol=1e-9)
        np.testing.assert_allclose(getattr(loop, f)(s - 3 * L), getattr(loop, f)(s), atol=1e-9)
    # the heading goes on turning: one counter-clockwise lap adds 2 pi
    np.testing.assert_allclose(loop.heading(s + L), loop.heading(s) + 2 * np.pi, atol=1e-9)
    np.testing.assert_allclose(loop.heading(s - 2 * L), loop.heading(s) - 4 * np.pi, atol=1e-9)
    # the seam is smooth: curvature and heading rate continuous across s = 0
    eps = 1e-4
    assert loop.curvature(-eps) == pytest.approx(loop.curvature(eps), abs=1e-3)
    assert loop.heading(L - eps) - loop.heading(0.0) == pytest.approx(2 * np.pi, abs=1e-3)
    # and so are the widths (periodic splines): at t = 0 of `_wavy_loop`, dw_l/dt = 0 and
    # dw_r/dt = 1, and ds/dt = 0.7 r(0) = 47.6 m
    h = 1e-3
    for f, slope in ((loop.width_left, 0.0), (loop.width_right, 1 / 47.6)):
        assert (f(h) - f(-h)) / (2 * h) == pytest.approx(slope, abs=1e-5)
        assert (f(h) - f(0.0)) / h == pytest.approx((f(0.0) - f(-h)) / h, abs=1e-6)


def test_gates_default_to_the_full_width_at_both_ends_and_can_be_set(loop):
    assert loop.start == Gate(s=0.0, n_min=-float(loop.width_right(0.0)),
                              n_max=float(loop.width_left(0.0)))
    assert loop.end.s == loop.length and loop.end.speed is None
    x, y = loop.to_cartesian(100.0, 1.0)
    road = loop.with_gates(start=Gate.at(loop, 10.0, n_min=-1.0, n_max=1.0, speed=20.0),
                           end=(float(x), float(y)))
    assert road.start == Gate(s=10.0, n_min=-1.0, n_max=1.0, speed=20.0)
    assert road.start.lateral == (-1.0, 1.0)
    assert road.end.s == pytest.approx(100.0, abs=1e-8)
    np.testing.assert_allclose(road.end.endpoints(road)[1],
                               loop.to_cartesian(100.0, loop.width_left(100.0)), atol=1e-9)


def _figure_eight(n=40):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return 50 * np.sin(t), 30 * np.sin(2 * t)


BAD_POINTS = [
    (dict(x=[0, 1, 2], y=[0, 0, 0]), "at least 4 centre-line points, got 3"),
    (dict(y=[0, 0, np.nan, 0, 0]), r"row 2, y is not finite"),
    (dict(width_left=[1, 0, 1, 1, 1]), r"row 1, width_left must be > 0 m, got 0"),
    (dict(width_right=[1, 1, 1, -2, 1]), r"row 3, width_right must be > 0 m, got -2"),
    (dict(x=[0, 10, 10, 30, 40]), r"rows 1 and 2 are the same point \(10, 0\)"),
]


@pytest.mark.parametrize("change, match", BAD_POINTS)
def test_bad_points_are_refused_naming_the_row_and_column(change, match):
    cols = dict(x=[0, 10, 20, 30, 40], y=[0, 0, 0, 0, 0], width_right=[1] * 5,
                width_left=[1] * 5)
    cols.update(change)
    n = len(cols["x"])
    cols = {k: v[:n] for k, v in cols.items()}
    with pytest.raises(ValueError, match=match):
        CentrelineRoad.from_points(**cols, name="bad")


def test_a_self_intersecting_centre_line_is_refused_naming_the_arc_lengths():
    x, y = _figure_eight()
    with pytest.raises(ValueError, match=r"'eight': the centre line crosses itself: between "
                                         r"s = [\d.]+ and [\d.]+ m and between s = "):
        CentrelineRoad.from_points(x, y, np.ones(40), np.ones(40), closed=True, name="eight")


def test_an_open_road_passing_again_through_its_start_is_refused():
    """An open figure eight whose second lobe runs back through the start point: the
    crossing falls on a knot of both passes (to rounding), and is refused like any other."""
    t = np.pi * np.arange(80) / 40  # through (0, 0) at t = 0 and at t = pi (row 40)
    x, y = 60.0 * np.sin(t), 30.0 * np.sin(2.0 * t)
    with pytest.raises(ValueError, match=r"'lobes': the centre line crosses itself: between "
                                         r"s = 0 and [\d.]+ m .*\(at s = 0 m and s = "):
        CentrelineRoad.from_points(x, y, np.full(80, 3.0), np.full(80, 3.0), name="lobes")


def test_widths_whose_spline_dips_below_zero_are_refused_saying_why():
    """Widths alternating between 0.1 and 50 m, every one positive: the cubic spline
    through them overshoots below zero between the points, refused with that reason (not
    as a width the file does not hold)."""
    x = np.arange(12) * 2.0
    w = np.where(np.arange(12) % 2 == 0, 0.1, 50.0)
    with pytest.raises(ValueError, match=r"'osc': width_(right|left) is -[\d.]+ m at s = "
                                         r"[\d.]+ m; must be > 0 \(the widths between the "
                                         r"points are a cubic spline through theirs, which "
                                         r"overshoots"):
        CentrelineRoad.from_points(x, 0.1 * x, w, w, name="osc")


def _straight_with_a_loop(length: float, radius: float = 2.0):
    """A straight of ``length`` [m] with a loop of ``radius`` [m] in its middle (the loop's
    ends pass each other 0.3 m apart, so the centre line crosses itself once)."""
    half = np.arange(0.0, length / 2, 1.0)
    t = np.linspace(0.6, 2 * np.pi - 0.6, 12)
    x = np.concatenate([half, length / 2 + radius * np.sin(t), half + length / 2 + 2.0])
    y = np.concatenate([np.zeros_like(half), radius * (1 - np.cos(t)),
                        np.full_like(half, 0.3)])
    return x, y


def test_a_small_loop_on_a_long_road_is_refused_at_the_knots_resolution():
    """A 2 m loop in the middle of a 1 km and of a 4 km straight (2,000 and 8,000 knots):
    refused naming the loop's two passes, as on a short road, and without a numerical
    warning (the straights on either side: thousands of parallel, collinear segments)."""
    for length in (1000.0, 4000.0):
        x, y = _straight_with_a_loop(length)
        w = np.full(len(x), 0.4)
        with pytest.raises(ValueError, match=r"'loop': the centre line crosses itself: between "
                                             r"s = (\d+)\.\d+ and [\d.]+ m and between s = ") as e, \
                warnings.catch_warnings():
            warnings.simplefilter("error")
            CentrelineRoad.from_points(x, y, w, w, name="loop")
        s_a, s_b = (float(v) for v in re.findall(r"\(at s = ([\d.]+) m and s = ([\d.]+) m",
                                                 str(e.value))[0])
        assert abs(s_a - length / 2) < 3.0 and 0 < s_b - s_a < 15.0, (length, str(e.value))
    x = np.arange(0.0, 4000.0, 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        road = CentrelineRoad.from_points(x, np.sin(x / 200.0), np.ones_like(x),
                                          np.ones_like(x), name="long")
    assert road.length > 3999.0


def test_crossing_search_finds_every_crossing_of_random_polylines():
    """The grid search against every pair of segments, on random walks that cross
    themselves often, rarely or never (their step 1-3 m, some turns sharp): the same first
    crossing, or none, for each."""
    rng = np.random.default_rng(0)
    found = 0
    for k in range(60):
        n = int(rng.integers(5, 120))
        turn = rng.normal(0.0, [0.05, 0.4, 1.2][k % 3], n)
        step = rng.uniform(1.0, 3.0, n)
        heading = np.cumsum(turn)
        p = np.cumsum(np.stack([step * np.cos(heading), step * np.sin(heading)], 1), 0)
        closed = bool(k % 5 == 0)
        expected = None
        for i in range(n - 1):  # every pair, first by i then by j
            js = [j for j in range(i + 2, n - 1) if not (closed and i == 0 and j == n - 2)]
            if not js:
                continue
            hit, t, u = _segments_cross(p[i], p[i + 1], p[js], p[np.array(js) + 1])
            if hit.any():
                m = int(np.argmax(hit))
                expected = (i, js[m], float(t[m]), float(u[m]))
                break
        got = _crossing(p, closed)
        assert (got is None) == (expected is None), (k, got, expected)
        if got is not None:
            found += 1
            assert got[:2] == expected[:2], (k, got, expected)
            np.testing.assert_allclose(got[2:], expected[2:], rtol=0, atol=1e-12)
    assert 10 < found < 55, found  # both kinds of walk were drawn


@pytest.mark.parametrize("key, value", [("x", 9e300), ("y", -2e7), ("width_left", 5e3)])
def test_coordinates_and_widths_beyond_a_local_frame_are_refused_naming_the_row(key, value):
    cols = dict(x=np.arange(5) * 10.0, y=np.zeros(5), width_right=np.ones(5),
                width_left=np.ones(5))
    cols[key] = cols[key].copy()
    cols[key][2] = value
    with pytest.raises(ValueError, match=rf"row 2, {key} must lie within"):
        CentrelineRoad.from_points(**cols, name="far")


def test_a_centre_line_doubling_back_along_itself_is_refused():
    """Back along the same line (100 m to 0, then on to 5 m): no crossing at an angle, but
    the road overlaps itself, refused as crossing itself (it was accepted and solved)."""
    x = np.array([100.0, 97.5, 95.0, 0.0, 2.5, 5.0])
    with pytest.raises(ValueError, match="'back': the centre line crosses itself"):
        CentrelineRoad.from_points(x, np.zeros(6), np.full(6, 4.0), np.full(6, 4.0),
                                   name="back")
    # a straight road (collinear segments that do not overlap) is a road
    CentrelineRoad.from_points(np.arange(6) * 10.0, np.zeros(6), np.ones(6), np.ones(6))


def test_a_closed_road_repeating_its_first_point_is_refused():
    t = np.linspace(0, 2 * np.pi, 20)
    with pytest.raises(ValueError, match="rows 19 and 0 .*first point is not repeated"):
        CentrelineRoad.from_points(np.cos(t) * 9, np.sin(t) * 9, np.ones(20), np.ones(20),
                                   closed=True)


@pytest.mark.parametrize("side, widths", [("width_left", (1.0, 10.5)),
                                          ("width_right", (10.5, 1.0))])
def test_a_width_beyond_the_radius_of_curvature_is_refused_naming_s(side, widths):
    # a left turn of radius 10 then a right turn of radius 10: the inside is left, then right
    segs = [("straight", 5.0), ("arc", 10.0, 90.0), ("straight", 5.0), ("arc", 10.0, -90.0)]
    with pytest.raises(ValueError, match=rf"{side} 10.5 m reaches the radius of curvature 10 m "
                                         r"at s = [\d.]+ m"):
        CentrelineRoad.from_segments(segs, widths, name="tight")
    CentrelineRoad.from_segments(segs, (9.9, 9.9))  # just inside: accepted


def test_gates_off_the_road_are_refused(loop):
    with pytest.raises(ValueError, match=r"gate at s = -5 m is off the road \(s must be in"):
        Gate.at(loop, -5.0)
    with pytest.raises(ValueError, match="gate at s = 10 m is off the road: its lateral"):
        Gate.at(loop, 10.0, n_max=float(loop.width_left(10.0)) + 0.1)
    x, y = loop.to_cartesian(50.0, -float(loop.width_right(50.0)) - 0.5)
    with pytest.raises(ValueError, match=r"gate point .* is off the road: [\d.]+ m from the "
                                         r"centre line at s = 50 m, .* to the right"):
        loop.with_gates(end=(float(x), float(y)))
    with pytest.raises(ValueError, match="off the road"):
        CentrelineRoad.from_points(*_wavy_loop(), closed=True, start=loop.length + 1.0)


@pytest.mark.parametrize("segs, match", [
    ([("spiral", 3.0)], "unknown kind 'spiral'"),
    ([("arc", -5.0, 90.0)], r"segment 0 \(arc\): radius must be > 0 m, got -5"),
    ([("straight", 5.0), ("straight", 0.0)], r"segment 1 \(straight\) has length 0 m"),
    ([("straight", 50.0), ("clothoid", 20.0, float("nan"))],
     r"segment 1 \(clothoid\): end_curvature must be finite \[1/m\], got nan"),
    ([("clothoid", 20.0, float("inf"))], r"segment 0 \(clothoid\): end_curvature must be finite"),
])
def test_bad_segments_are_refused(segs, match):
    with pytest.raises(ValueError, match=match):
        CentrelineRoad.from_segments(segs, 2.0)


def test_an_unclosed_closed_road_is_refused():
    with pytest.raises(ValueError, match="must end where it starts"):
        CentrelineRoad.from_segments([("arc", 10.0, 270.0)], 2.0, closed=True)


@pytest.mark.parametrize("text, match", [
    ("1,2,3\n4,5,6\n", r"bad.csv:1: no header line"),
    ("# x_m,y_m,w_tr_right_m\n0,0,1\n", r"missing column\(s\) w_tr_left_m"),
    ("# x_m,y_m,w_tr_right_m\n", r"missing column\(s\) w_tr_left_m"),  # and no rows
    # what Python's float reads but a data file does not mean: digit groups, other digits
    ("x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,1,1\n1,0,1,1\n2,4_0,1,1\n",
     r"bad.csv:4: y_m is not a number: '4_0'"),
    ("x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,1,1\n1,0,\uff11,1\n",
     r"bad.csv:3: w_tr_right_m is not a number: '\uff11'"),
    ("# end_gate: s=1_0\nx_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,1,1\n",
     r"bad.csv:1: end_gate: s must be a number or"),
    ("x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,1,1\n1,0,1,1\n2,zero,1,1\n",
     r"bad.csv:4: y_m is not a number: 'zero'"),
    ("x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,1,1\n1,0,1\n", r"bad.csv:3: 3 fields"),
    ("x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,1,1\n1,5,0,1,1\n",
     r"bad.csv:3: 5 fields, the header names 4 \(a decimal comma\?"),
    ("# c\nx_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,1,1\n1,0,1,1\n2,0,1,-1\n3,0,1,1\n",
     r"bad.csv: road 'bad': line 5, w_tr_left_m must be > 0 m"),
    ("x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,1,1\n1,0,1,1\n\n1,0,1,1\n3,0,1,1\n",
     r"lines 3 and 5 are the same point"),
    ("x_m,y_m,w_tr_right_m,w_tr_left_m\n0,0,1,1\n1,nan,1,1\n2,0,1,1\n3,0,1,1\n",
     r"line 3, y_m is not finite"),
])
def test_bad_files_are_refused_naming_the_line(tmp_path, text, match):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_road(path)


def test_empty_trailing_fields_are_read(tmp_path):
    """A spreadsheet's trailing commas are no extra data: the road reads as without them."""
    rows = "".join(f"{2 * i},0,1,1{',' if i % 2 else ',,'}\n" for i in range(4))
    text = "x_m,y_m,w_tr_right_m,w_tr_left_m\n" + rows
    path = tmp_path / "trailing.csv"
    path.write_text(text)
    road = read_road(path)
    assert road.length == pytest.approx(6.0)


def test_the_shipped_circuit_loads_closed_with_its_published_length():
    assert set(vs.shipped_tracks()) == {"Oschersleben"}
    head = vs.shipped_tracks()["Oschersleben"].read_text()[:600]
    assert "github.com/TUMFTM/racetrack-database" in head and "LGPL-3.0" in head
    road = vs.track("Oschersleben")
    assert road.closed and road.name == "Oschersleben"
    # Motorsport Arena Oschersleben, Grand Prix circuit: 3.696 km (the circuit's published
    # length, e.g. Wikipedia "Motorsport Arena Oschersleben"); the centre line is 3692.8 m
    assert road.length == pytest.approx(3696.0, rel=0.02)
    # one clockwise lap, and the seam of the periodic spline is closed
    assert road.heading(road.length) - road.heading(0.0) == pytest.approx(-2 * np.pi, abs=1e-9)
    assert road.heading(road.length - 1e-6) == pytest.approx(road.heading(road.length), abs=1e-6)
    np.testing.assert_allclose(road.position(road.length), road.position(0.0), atol=1e-9)
    with pytest.raises(ValueError, match="unknown track 'Monaco'"):
        vs.track("Monaco")


@pytest.mark.parametrize("which", ["centreline", "rectangle"])
def test_path_on_road_figure_draws_the_path_by_speed_and_every_footprint(which, loop):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from vehsim.plot import path_on_road_figure, road_figure

    road = loop if which == "centreline" else vs.road("corner90")
    if which == "centreline":
        s = np.linspace(0, 100, 51)
        x, y = loop.to_cartesian(s, 0.5)
        psi = loop.heading(s)
    else:
        x, y = np.linspace(-5, 9, 51), np.full(51, 9.0)
        psi = np.zeros(51)
    speed = np.linspace(5.0, 15.0, 51)
    fig = path_on_road_figure(road, x, y, psi, speed, footprint=(4.0, 2.0), every=10)
    ax = fig.axes[0]
    feet = [p for p in ax.patches if p.get_gid() == "footprint"]
    assert len(feet) == 6  # samples 0, 10, ..., 50
    # each footprint is the 4 m x 2 m rectangle centred on its sample, turned by psi
    corners = feet[1].get_xy()[:4]
    np.testing.assert_allclose(corners.mean(axis=0), [x[10], y[10]], atol=1e-9)
    np.testing.assert_allclose(np.hypot(*(corners[0] - corners[1])), 2.0, atol=1e-9)
    np.testing.assert_allclose(np.arctan2(*(corners[0] - corners[3])[::-1]), psi[10], atol=1e-9)
    lines = ax.collections[-1]
    np.testing.assert_allclose(lines.get_array(), 0.5 * (speed[1:] + speed[:-1]))
    assert fig.axes[1].get_ylabel() == "speed [m/s]"  # the colour bar
    plt.close(fig)
    fig = road_figure(road, path=(x, y))
    assert fig.axes[0].get_title() == road.name
    plt.close(fig)
