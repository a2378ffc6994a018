"""`vehsim optimise --road-file` / `--track`: a road read from the file the test writes is
driven as the library drives it (the record's time and violations are the library's), the
figure is written; bad roads and contradictory options end with exit 2, the option or the
row named, before anything is solved and with no file written.

Runs in the worker of tests/test_optimal_curvilinear.py (the same grid of 40 stages: one
compiled solver for both)."""

import json
from pathlib import Path

import numpy as np
import pytest

from vehsim import CentrelineRoad, Gate, cli, read_road, road_primitive, write_road


pytestmark = pytest.mark.xdist_group("curvilinear")

CORNER = [("straight", 20.0), ("arc", 20.0, 90.0), ("straight", 20.0)]
PNG = b"\x89PNG\r\n\x1a\n"


def _run(argv, capsys):
    code = cli.main(["--no-compilation-cache", *map(str, argv)])
    return code, capsys.readouterr().err


def test_road_file_drive_is_the_library_drive(tmp_path, capsys):
    path = tmp_path / "corner.csv"
    write_road(path, CentrelineRoad.from_segments(CORNER, 8.0, name="corner"))
    out = tmp_path / "out"
    code, err = _run(["optimise", "--road-file", path, "--segments", 40, "--start-speed", 8,
                      "--out", out, "--quiet"], capsys)
    assert code == 0, err
    rec = json.loads((out / "corner_min-time.json").read_text())
    assert (out / "corner_min-time.png").read_bytes()[:8] == PNG
    road = read_road(path)
    road = road.with_gates(Gate.at(road, 0.0, speed=8.0), None)
    lib = road_primitive(road, num_stages=40)
    assert rec["status"] == "successful" and not rec["closed"]
    assert (rec["segments"], rec["steps_per_stage"]) == (40, 1)
    assert rec["t_f"] == pytest.approx(float(lib.t_f), rel=1e-9)
    assert rec["units"]["max_corridor_violation_between_nodes"] == "m"
    v = lib.violations()
    assert rec["max_corridor_violation_between_nodes"] == pytest.approx(
        v["corridor_between_nodes"], abs=1e-12)
    assert rec["states"]["vx"][0] == pytest.approx(8.0, abs=1e-6)  # the start gate's speed
    # the file holds points of the centre line; the spline through them has its length to 1e-5
    assert rec["length"] == pytest.approx(20 + 20 * np.pi / 2 + 20, rel=1e-5)
    assert "40 stages" in err and "wrote" in err


def test_a_first_solve_that_stops_short_is_said_and_recorded(tmp_path, capsys, monkeypatch):
    """A road long enough for a coarse first solve (here forced onto the corner, 20 stages)
    whose first solve stops at --max-iter: the command says that the drive started from the
    speed profile instead, and why (the best iterate's infeasibility above the bound), and
    the record's ``coarse`` says so too; or, where the first
    solve's best iterate is taken, that it started from that, with its infeasibility."""
    from vehsim.cli import optimise_road

    path = tmp_path / "corner.csv"
    write_road(path, CentrelineRoad.from_segments(CORNER, 8.0, name="corner"))
    monkeypatch.setattr(optimise_road, "coarse_stages", lambda length, stages: 20)
    out = tmp_path / "out"
    code, err = _run(["optimise", "--road-file", path, "--segments", 40, "--start-speed", 8,
                      "--max-iter", 2, "--out", out, "--quiet"], capsys)
    assert code == 1, err
    rec = json.loads((out / "corner_min-time.json").read_text())["coarse"]
    assert ("the first solve, on 20 stages, stopped with ip_max_iterations after 2 "
            "iterations; the 40 stages started from the speed profile instead (its best "
            f"iterate's primal infeasibility {rec['inf_pr']:.1e}, above 1e-02)") in err, err
    assert (rec["segments"], rec["status"], rec["started_from"]) == (
        20, "ip_max_iterations", False)
    # a first solve whose best iterate is taken (here every one): the command says so
    from vehsim.optimal import curvilinear

    monkeypatch.setattr(curvilinear, "coarse_start", lambda sol, violation: True)
    code, err = _run(["optimise", "--road-file", path, "--segments", 40, "--start-speed", 8,
                      "--max-iter", 2, "--out", out, "--quiet"], capsys)
    assert code == 1, err
    inf_pr = json.loads((out / "corner_min-time.json").read_text())["coarse"]["inf_pr"]
    assert ("the first solve, on 20 stages, stopped with ip_max_iterations after 2 "
            f"iterations; the 40 stages started from its best iterate (primal "
            f"infeasibility {inf_pr:.1e})") in err, err


def _bad_file(tmp_path, rows, name="bad"):
    path = tmp_path / f"{name}.csv"
    path.write_text("# x_m,y_m,w_tr_right_m,w_tr_left_m\n"
                    + "".join(",".join(map(str, r)) + "\n" for r in rows))
    return path


GOOD = [(0, 0, 3, 3), (10, 0, 3, 3), (20, 0, 3, 3), (30, 0, 3, 3), (40, 0, 3, 3)]


@pytest.mark.parametrize("case, match", [
    ("negative width", "line 4, w_tr_right_m must be > 0"),
    ("too few points", "at least 4 centre-line points"),
    ("closed benchmark", "--closed applies to --road-file"),
    ("start speed on a lap", "--start-speed applies to an open road"),
    ("max-exit lap", "max-exit needs an open road"),
    ("max-exit on a file's lap", "(its '# closed: yes' line) names a lap"),
    ("start speed on a file's lap", "--start-speed applies to an open road, and "),
    ("starts", "--starts and --live"),
    ("corner options", "--interior-points and --no-corner-clearance apply"),
    ("two roads", "not allowed with"),
    ("no road", "one of the arguments"),
    ("fast gate", "fast.csv: the start_gate's speed 1e+06 m/s must lie in [1, 100] m/s"),
    ("standing gate", "standing.csv: the end_gate's speed 0 m/s must lie in [1, 100] m/s"),
    ("gate inside", "inside.csv: road 'inside': the start gate is at s = 10 m"),
])
def test_bad_roads_and_options_are_refused_before_solving(tmp_path, capsys, case, match):
    out = tmp_path / "out"
    good = _bad_file(tmp_path, GOOD, "good")
    ring = write_road(tmp_path / "ring.csv", CentrelineRoad.from_segments(
        [("arc", 20.0, 360.0)], 6.0, closed=True, name="ring"))  # says it is closed
    argv = {
        "negative width": ["--road-file", _bad_file(tmp_path, GOOD[:2] + [(20, 0, -1, 3)]
                                                    + GOOD[3:], "negative")],
        "too few points": ["--road-file", _bad_file(tmp_path, GOOD[:3], "short")],
        "closed benchmark": ["corner90", "--closed"],
        "start speed on a lap": ["--track", "Oschersleben", "--start-speed", "5"],
        "max-exit lap": ["--road-file", good, "--closed", "--objective", "max-exit"],
        "max-exit on a file's lap": ["--road-file", ring, "--objective", "max-exit",
                                     "--tf-max", "5"],
        "start speed on a file's lap": ["--road-file", ring, "--start-speed", "5"],
        "starts": ["--road-file", good, "--starts", "2"],
        "corner options": ["--road-file", good, "--interior-points", "2"],
        "two roads": ["corner90", "--road-file", good],
        "no road": [],
        **{case: ["--road-file", _gated_file(tmp_path, name, line)] for case, name, line in (
            ("fast gate", "fast", "# start_gate: s=start speed=1e6"),
            ("standing gate", "standing", "# end_gate: s=end speed=0"),
            ("gate inside", "inside", "# start_gate: s=10"))},
    }[case]
    code, err = _run(["optimise", *argv, "--out", out], capsys)
    assert code == 2 and match in err, err
    assert "Traceback" not in err and "compiling" not in err  # refused before
    assert not Path(out).exists()


def _gated_file(tmp_path, name, line):
    """The good road's file with a gate line the road-frame problem cannot pose."""
    path = _bad_file(tmp_path, GOOD, name)
    path.write_text(line + "\n" + path.read_text())
    return path


def test_a_road_file_says_whether_it_is_a_lap_and_where_its_gates_are(tmp_path, capsys,
                                                                        monkeypatch):
    """Both commands read a file's lap and gates as `write_road` wrote them (--closed only
    forces a lap), and `vehsim optimise --start-speed` sets the speed of the file's start gate,
    keeping its lateral interval: the road handed to the solver is captured (nothing solved)."""
    from types import SimpleNamespace

    from vehsim.cli import _drive_setup, optimise_road
    from vehsim.optimal import curvilinear

    ring = write_road(tmp_path / "ring.csv", CentrelineRoad.from_segments(
        [("arc", 20.0, 360.0)], 6.0, closed=True, name="ring"))
    args = SimpleNamespace(track=None, road_file=str(ring), closed=False, smoothing=0.0)
    assert optimise_road.road_from_args(args).closed and _drive_setup.road(args).closed
    plain = _bad_file(tmp_path, GOOD, "plain")  # a file without the line: open
    assert not _drive_setup.road(SimpleNamespace(road_file=str(plain), closed=False)).closed

    stage = CentrelineRoad.from_segments(CORNER, 8.0, name="gated")
    stage = stage.with_gates(Gate.at(stage, 0.0, n_min=-1.0, n_max=1.0),
                             Gate.at(stage, stage.length, n_min=-2.0, n_max=0.5, speed=9.0))
    path = write_road(tmp_path / "gated.csv", stage)
    seen = []

    class Captured(Exception):
        pass

    def capture(road, *a, **k):
        seen.append(road)
        raise Captured

    monkeypatch.setattr(curvilinear, "road_primitive", capture)
    with pytest.raises(Captured):
        cli.main(["--no-compilation-cache", "optimise", "--road-file", str(path),
                  "--start-speed", "5", "--out", str(tmp_path / "out"), "--quiet"])
    road = seen[0]
    assert not road.closed
    assert road.start == Gate(s=0.0, n_min=-1.0, n_max=1.0, speed=5.0)
    assert road.end.lateral == pytest.approx((-2.0, 0.5)) and road.end.speed == 9.0
