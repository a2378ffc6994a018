"""`vehsim drive`: a short drive writes the JSON with its documented fields and units, the
figure and the animation (one frame per `--frame-every` samples, and the last), the
controller timed sample by sample issues the drive's own commands, the truth the record
reports is the grip the options ask for; every bad option ends with exit 2 naming it, no
traceback and nothing written; the figure's footprints and the animation's frames are
where the drive put them."""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vehsim as vs
from vehsim import cli
from vehsim.plot import (
    animation_frames,
    drive_animation,
    drive_figure,
    drive_trace,
    frame_every_for,
)
from vehsim.tire.tir import shipped_tires


# its own worker group: its drives are the command line's programs, which no other drive test
# compiles, so sharing the drive tests' worker only lengthens that worker
pytestmark = pytest.mark.xdist_group("drive_cli")

SAMPLE_TIR = shipped_tires()["sample_185_80R14_mf61"]
PNG = b"\x89PNG\r\n\x1a\n"
GIF = (b"GIF87a", b"GIF89a")
SEGMENTS = [("straight", 10.0), ("arc", 25.0, 30.0), ("straight", 10.0)]
DURATION, EVERY = 1.0, 4
KEYS = {"road", "length", "closed", "controller", "mode", "completed", "drive_time",
        "max_distance_off_road", "nonfinite_from", "nominal_plan", "sample_time", "duration",
        "start_speed", "nominal_scale",
        "nominal_D", "compute_time", "real_time_factor",
        "estimate", "planner_D", "solver", "truth", "trajectory", "settings", "wall_time_s",
        "units"}


def _run(argv, capsys):
    try:
        code = cli.main(["--no-compilation-cache", *map(str, argv)])
    except SystemExit as e:  # argparse's own errors
        code = e.code
    return code, capsys.readouterr().err


@pytest.fixture(scope="module")
def road_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("road") / "bend.csv"
    vs.write_road(path, vs.CentrelineRoad.from_segments(SEGMENTS, 6.0, name="bend"))
    return path


def _drive(argv, out):
    code = cli.main(["--no-compilation-cache", "drive", *map(str, argv), "--out", str(out)])
    assert code == 0
    return json.loads((out / "drive.json").read_text())


@pytest.fixture(scope="module")
def rh_drive(tmp_path_factory):
    """The receding-horizon driver with the estimate on the icy corner, for a second: (output
    folder, record)."""
    out = tmp_path_factory.mktemp("rh")
    return out, _drive(["--road", "corner90", "--conditions", "icy", "--duration", DURATION,
                        "--frame-every", EVERY, "--seed", 3], out)


def test_drive_test_brakes_until_the_front_axle_knows_the_grip(rh_drive):
    """The scenarios' driver with the estimate brakes its front axle on a corner's first
    metres (`DRIVER_PROBE_DISTANCE`) until the front axle's belief narrows below
    `probe_std`: the record's `solver.probing` is on for the first samples only, the car
    has not yet covered the distance when it stops, and the front's belief was wide on
    the last probing command and narrow on the first one after (the estimate a command
    sees is the one after the previous sample)."""
    _, rec = rh_drive
    assert rec["settings"]["controller"] == "rh"
    probing = np.asarray(rec["solver"]["probing"], bool)
    sigma = np.asarray(rec["estimate"]["scale_std"]) / np.asarray(rec["estimate"]["scale"])
    k = int(np.argmin(probing))  # the first command that does not brake to probe
    assert probing[:k].all() and not probing[k:].any()
    assert 2 <= k <= 5
    assert sigma[k - 2, 0] >= 0.25 > sigma[k - 1, 0]
    assert rec["trajectory"]["s"][k - 1] < vs.DRIVER_PROBE_DISTANCE


@pytest.fixture(scope="module")
def tracking_drive(road_file, tmp_path_factory):
    """The nominal plan tracked on a road file of 80 % of the nominal grip, the plant on the
    shipped .tir file's Magic Formula: (output folder, record)."""
    out = tmp_path_factory.mktemp("tracking")
    return out, _drive(["--road-file", road_file, "--controller", "tracking", "--grip", 0.8,
                        "--plant-tire", SAMPLE_TIR, "--duration", 0.5, "--no-animation"], out)


def test_drive_writes_the_documented_record_figure_and_animation(rh_drive):
    out, rec = rh_drive
    assert set(rec) == KEYS
    n = round(DURATION / 0.05)
    assert len(rec["trajectory"]["t"]) == n and rec["duration"] == pytest.approx(DURATION)
    assert rec["road"] == "corner90" and rec["controller"] == "rh" and rec["mode"] == "rti"
    assert rec["settings"]["seed"] == 3 and rec["settings"]["conditions"] == "icy"
    # the corners' driver as it drove: its passes per sample and Hessian update
    assert rec["settings"]["passes"] == vs.CORNER_DRIVER.get("iterations", 4)
    assert rec["settings"]["keep_hessian"] is False
    assert rec["nominal_plan"] is None and rec["nonfinite_from"] is None
    for key in ("max_distance_off_road", "compute_time.p50", "compute_time.p99",
                "trajectory.x", "estimate.peak", "planner_D.D", "truth.peak"):
        assert key in rec["units"], key
    ct = rec["compute_time"]
    assert ct["samples"] == n - 1 and 0 < ct["p50"] <= ct["p99"] <= ct["max"]
    assert rec["real_time_factor"] == pytest.approx(ct["p50"] / 0.05)
    est = np.asarray(rec["estimate"]["peak"])
    std = np.asarray(rec["estimate"]["peak_std"])
    assert est.shape == (n, 2) and np.all(std > 0)
    # the planner's D (its mean over the stages) is the estimate it was given (the one after
    # the previous sample), the smaller axle's, at the stages' speeds: below the reported
    # peak's 20 m/s on this corner, so above the reported peak (and its lower edge), and at
    # least 1 m/s, so below the peak there
    D = np.asarray(rec["planner_D"]["D"])
    assert np.all(D[1:] > np.min(est - std, axis=1)[:-1])
    tire = vs.DrivePlant().tire
    slowest = np.asarray([[float(vs.peak_friction(tire, lam, 1.0)) for lam in row]
                          for row in np.asarray(rec["estimate"]["scale"])])
    assert np.all(D[1:] < np.min(slowest, axis=1)[:-1])
    assert len(rec["solver"]["iterations"]) == n
    # the wheels' true slip: the test brake's front wheel braking, and no wheel spinning up
    # or locking (the traction control)
    slip = np.asarray(rec["trajectory"]["slip"])
    assert slip.shape == (n, 2) and "trajectory.slip" in rec["units"]
    probing = np.asarray(rec["solver"]["probing"], bool)
    print("true slips: front", slip[:8, 0], "largest", np.max(np.abs(slip), axis=0))
    k = int(np.argmin(probing))
    assert np.min(slip[:k + 3, 0]) < -0.015  # the command acts after the actuators' delay
    assert np.max(np.abs(slip)) < 0.3
    assert (out / "drive.png").read_bytes()[:8] == PNG
    gif = out / "drive.gif"
    assert gif.read_bytes()[:6] in GIF
    from PIL import Image

    with Image.open(gif) as im:
        assert im.n_frames == len(animation_frames(n, EVERY)) == math.ceil(n / EVERY) + 1
    assert sorted(p.name for p in out.iterdir()) == ["drive.gif", "drive.json", "drive.png"]


def test_tracking_record_reports_the_grip_asked_for(tracking_drive):
    """--grip 0.8 of the nominal road: the true peak under both axles is 0.8 x 0.52 = 0.416
    (the scale solved for it, the peak not being proportional to it; the Magic Formula
    plant's too, `test_drive_puts_the_plant_on_the_tire_given`); no estimator, no planner,
    no animation."""
    out, rec = tracking_drive
    assert set(rec) == KEYS
    assert rec["settings"]["plant_tire"] == str(SAMPLE_TIR)
    assert rec["nonfinite_from"] is None and np.all(np.isfinite(rec["trajectory"]["x"]))
    peak = np.asarray(rec["truth"]["peak"])
    assert peak.shape == (10, 2)
    # the Magic Formula made 0.52 on the nominal road, times the LuGre peak's ratio on the
    # scale solved for 0.416, which peak_friction's 96 slips read 0.16 % high there
    m = vs.peak_surface_factor(vs.nominal_scale())
    np.testing.assert_allclose(peak, 0.52 * float(m(vs.scale_for_peak(0.8 * 0.52))),
                               rtol=1e-6)
    np.testing.assert_allclose(peak, 0.8 * 0.52, rtol=2e-3)
    assert rec["nominal_D"] == 0.52 and rec["mode"] is None
    assert rec["estimate"] is None and rec["planner_D"] is None and rec["solver"] is None
    plan = rec["nominal_plan"]  # the plan the tracker drives, and how it was solved
    assert plan["status"] == "successful" and plan["iterations"] > 0 and plan["t_f"] > 0
    assert rec["units"]["nominal_plan.t_f"] == "s"
    assert sorted(p.name for p in out.iterdir()) == ["drive.json", "drive.png"]
    # the frame step not given: the default for a drive this short, recorded as used
    assert rec["settings"]["frame_every"] == 2


BAD = {
    "unknown road": (["--road", "moon"], "--road"),
    "no road": ([], "--road"),
    "closed without a file": (["--road", "corner90", "--closed"], "--closed"),
    "missing road file": (["--road-file", "{tmp}/missing.csv"], "missing.csv"),
    "zero grip": (["--road", "corner90", "--grip", "0"], "--grip"),
    "nan grip": (["--road", "corner90", "--grip", "nan"], "--grip"),
    "too much grip": (["--road", "corner90", "--grip", "4"], "--grip"),
    "grip below glare ice": (["--road", "corner90", "--grip", "0.004"],
                             "--grip: must be a finite number in [0.1, 3]"),
    "patch below glare ice": (["--road", "corner90", "--patch", "1,2,3,0.05"],
                              "SCALE in [0.1, 3]"),
    "a seed without noise": (["--road", "corner90", "--no-noise", "--seed", "7"],
                             "--seed seeds the sensor noise; leave it out with --no-noise"),
    "patch of three numbers": (["--road", "corner90", "--patch", "1,2,3"], "--patch"),
    "patch of no radius": (["--road", "corner90", "--patch", "1,2,0,0.5"], "--patch"),
    "patch of no grip": (["--road", "corner90", "--patch", "1,2,3,0"], "--patch"),
    "patch not a number": (["--road", "corner90", "--patch", "1,a,3,0.5"], "--patch"),
    "patch off the road": (["--road", "corner90", "--patch", "500,500,5,0.5"], "--patch"),
    "unknown controller": (["--road", "corner90", "--controller", "pid"], "--controller"),
    "unknown mode": (["--road", "corner90", "--mode", "fast"], "--mode"),
    "mode without rh": (["--road", "corner90", "--controller", "tracking", "--mode", "rti"],
                        "--mode"),
    "preview without oracle": (["--road", "corner90", "--preview", "5"], "--preview"),
    "one pass": (["--road", "corner90", "--passes", "1"],
                 "--passes: must be an integer in [2, 100]"),
    "fractional passes": (["--road", "corner90", "--passes", "4.5"], "--passes"),
    "passes without rh": (["--road", "corner90", "--controller", "tracking", "--passes",
                           "6"], "--passes applies to the receding-horizon controllers"),
    "passes converged": (["--road", "corner90", "--mode", "converged", "--passes", "6"],
                         "--passes sets the passes of a real-time iteration"),
    "kept Hessian without rh": (["--road", "corner90", "--controller", "open-loop",
                                 "--keep-hessian"], "--keep-hessian applies to"),
    "pace notes without rh": (["--road", "corner90", "--controller", "rh-oracle",
                               "--pace-notes"], "--pace-notes"),
    "estimator without rh": (["--road", "corner90", "--controller", "rh-nominal",
                              "--estimator", "axle-peak"], "--estimator chooses the grip"),
    "unknown estimator": (["--road", "corner90", "--estimator", "burckhardt"],
                          "--estimator"),
    "missing plant tire": (["--road", "corner90", "--plant-tire", "{tmp}/none.tir"],
                           "--plant-tire: no such file"),
    "plant tire a folder": (["--road", "corner90", "--plant-tire", "{tmp}"],
                            "--plant-tire: "),
    "negative preview": (["--road", "corner90", "--controller", "rh-oracle", "--preview",
                          "-1"], "--preview"),
    "negative seed": (["--road", "corner90", "--seed", "-1"],
                      "--seed: must be an integer in [0, 2147483647]"),
    "zero duration": (["--road", "corner90", "--duration", "0"], "--duration"),
    "endless duration": (["--road", "corner90", "--duration", "inf"], "--duration"),
    "unknown animation format": (["--road", "corner90", "--animation-format", "avi"],
                                 "--animation-format"),
    "format without animation": (["--road", "corner90", "--no-animation",
                                  "--animation-format", "gif"], "--animation-format"),
    "no frames": (["--road", "corner90", "--frame-every", "0"], "--frame-every"),
    "unknown conditions": (["--road", "corner90", "--conditions", "mud"], "--conditions"),
    "conditions and grip": (["--road", "corner90", "--conditions", "icy", "--grip", "0.5"],
                            "--conditions"),
    "conditions and patch": (["--road", "corner90", "--conditions", "icy", "--patch",
                              "9,9,2,0.5"], "--conditions"),
}


@pytest.mark.parametrize("case", list(BAD), ids=list(BAD))
def test_bad_option_exits_2_naming_it_and_writes_nothing(case, tmp_path, capsys, monkeypatch):
    argv, option = BAD[case]
    monkeypatch.chdir(tmp_path)
    argv = ["drive", *(a.format(tmp=tmp_path) for a in argv), "--out", str(tmp_path / "out")]
    code, err = _run(argv, capsys)
    assert code == 2, err
    assert option in err, err
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.rglob("*")) == [], "a file was written"


@pytest.mark.parametrize("text, message", [
    ("x_m,y_m\n0,0\n", "is not a tyre property file"),
    ("[MDI_HEADER]\nFILE_TYPE = 'tir'\n[MODEL]\nFITTYP = 61\nLONGVL = abc\n",
     "--plant-tire {path}: {path}:"),
])
def test_a_bad_plant_tire_file_exits_2_naming_the_option(text, message, tmp_path_factory,
                                                         capsys):
    """A file that is not a .tir, or a .tir that cannot be read (the reader's message, with
    the file and line), is refused before anything compiles, naming ``--plant-tire``."""
    folder = tmp_path_factory.mktemp("tires")
    path = folder / ("tire.csv" if "x_m" in text else "broken.tir")
    path.write_text(text)
    out = folder / "out"
    code, err = _run(["drive", "--road", "corner90", "--plant-tire", path, "--out", out],
                     capsys)
    assert code == 2 and "Traceback" not in err, err
    assert message.format(path=path) in err and "--plant-tire" in err, err
    assert not out.exists()


def test_drive_puts_the_plant_on_the_tire_given(tmp_path):
    """``--plant-tire``: lugre (default) the LuGre plant on the grip's scales; a shipped
    .tir file's name, or any .tir file's path, its Magic Formula (`mf_plant_tire`) with the
    scenario's peak on every surface (`peak_surface_factor`); built without driving."""
    from vehsim.cli import _drive_setup as setup
    from vehsim.cli.drive import SHIPPED_TIRE_NAMES, _check

    assert SHIPPED_TIRE_NAMES == tuple(shipped_tires())
    copy = tmp_path / "mine.tir"
    copy.write_text(SAMPLE_TIR.read_text())
    want = vs.mf_plant_tire(SAMPLE_TIR)
    for given in ([], ["--plant-tire", "lugre"], ["--plant-tire", SHIPPED_TIRE_NAMES[0]],
                  ["--plant-tire", str(copy)]):
        args = cli.build_parser().parse_args(["drive", "--road", "corner90", "--grip", "0.8",
                                              *given])
        _check(args)
        sc = setup.scenario(args, setup.road(args))
        plant = sc.plant
        if given[1:] in ([], ["lugre"]):
            assert type(plant.tire) is vs.LumpedLuGre2D and plant.surface_factor is None
            continue
        assert type(plant.tire) is vs.RelaxedMFTire
        assert float(plant.tire.params.LMUX) == float(want.params.LMUX)
        lam = plant.grip_scales(sc.state0.car)[0]
        # the Magic Formula's factor gives it the peak asked for, 0.8 of the nominal road's
        # (of the tire's own peak; 0.16 % below peak_friction's reading, which solved lam)
        assert float(plant.surface_factor(lam)) == pytest.approx(0.8, rel=2e-3)
        assert float(plant.surface_factor(lam)) != 1.0


def test_mp4_without_ffmpeg_is_refused_before_driving(tmp_path, capsys, monkeypatch):
    from matplotlib import animation

    monkeypatch.setattr(animation.writers, "is_available", lambda name: False)
    code, err = _run(["drive", "--road", "corner90", "--animation-format", "mp4", "--out",
                      tmp_path / "out"], capsys)
    assert code == 2 and "--animation-format mp4" in err and "ffmpeg" in err, err
    assert not (tmp_path / "out").exists()


class EstimateFollower(vs.AbstractDriveController):
    """A test driver whose command depends on its state, the measurement and the estimate."""

    def init(self, measurement):
        return jnp.zeros(())

    def command(self, state, m, estimate):
        # the standard deviation grows at every update (forgetting), learning or not
        torque = 400.0 * estimate.peak + 1000.0 * estimate.peak_std + 10.0 * state
        return state + 1.0, jnp.stack([torque[0], torque[1], 0.02 * jnp.sin(m.t) + 0.01 * m.y])


def test_timed_drive_is_the_library_drive(capsys):
    """The drive run sample by sample to time the controller is `simulate_drive`'s, record
    for record (states, measurements, commands, estimates, the controller's info, the poses
    at every integration step, the final state), for a controller that reads its state, the
    measurement and the estimate; every sample after the first is timed, and with progress
    on (the command line's default) the samples driven are reported."""
    from vehsim.cli.drive import timed_drive, timing_record

    class Recording(EstimateFollower):
        def info(self, state):
            return {"state": state}

    plant = vs.DrivePlant()
    state0 = vs.init_drive(plant, vx=15.0)
    key = jax.random.key(2)
    est = vs.AxleGripEstimator()
    run = jax.jit(lambda k: vs.simulate_drive(plant, Recording(), state0, k, 12,
                                              estimator=est, substep_poses=True))(key)
    before = vs.progress.set_default(True)
    try:
        out = timed_drive(plant, Recording(), state0, key, 12, est)
    finally:
        vs.progress.set_default(before)
    assert "driving: 100% (12/12 samples)" in capsys.readouterr().err
    for name in ("states", "measurements", "commands", "estimates", "final",
                 "controller_info", "poses"):
        got, want = getattr(out["run"], name), getattr(run, name)
        assert jax.tree.structure(got) == jax.tree.structure(want), name
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
            if jnp.issubdtype(jnp.asarray(b).dtype, jax.dtypes.prng_key):
                continue
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12,
                                       err_msg=name)
    assert out["times"].shape == (11,) and np.all(out["times"] > 0)
    rec = timing_record(out["times"], 0.05, out["compile"])
    assert rec["compute_time"]["p50"] == pytest.approx(np.median(out["times"]))
    assert rec["real_time_factor"] == pytest.approx(np.median(out["times"]) / 0.05)


@pytest.fixture(scope="module")
def small_run():
    """A drive of 13 samples on a bend with an icy patch, the estimator on."""
    road = vs.CentrelineRoad.from_segments(SEGMENTS, 6.0, name="bend")
    plant = vs.DrivePlant(grip=vs.GripPatches(centres=jnp.array([[8.0, 0.0]]),
                                              radii=jnp.array([3.0]),
                                              scales=jnp.array([0.2]), base=0.5))
    driver = vs.PathFollower(curvature=1 / 25, torque=jnp.array([0.0, 200.0]))
    run = jax.jit(lambda k: vs.simulate_drive(plant, driver, vs.init_drive(plant, vx=10.0), k,
                                              13, estimator=vs.AxleGripEstimator()))(
        jax.random.key(0))
    return road, plant, run


@pytest.mark.parametrize("every", [1, 4, 13])
def test_animation_has_one_frame_per_subsample(small_run, tmp_path, every):
    from PIL import Image

    road, plant, run = small_run
    path = tmp_path / "a.gif"
    frames = drive_animation(road, run, path, plant, every=every, dpi=30)
    expected = sorted(set(range(0, 13, every)) | {12})
    assert animation_frames(13, every) == expected
    with Image.open(path) as im:
        assert frames == im.n_frames == len(expected)


@pytest.mark.parametrize("num_samples, every", [(13, 2), (1199, 2), (1200, 3), (4000, 7),
                                                (4000, 9), (24000, 41)])
def test_long_drives_get_at_most_600_frames(num_samples, every):
    """`frame_every_for`: the frame step asked for (2) where it gives at most 600 frames, the
    least step that does on a longer drive (a 200 s drive at 20 Hz: every 7th sample), and a
    larger step asked for as it is."""
    asked = 9 if every == 9 else 2
    got = frame_every_for(num_samples, asked)
    assert got == every
    assert len(animation_frames(num_samples, got)) <= 600
    if got > asked:  # the least such step
        assert len(animation_frames(num_samples, got - 1)) > 600


def test_animation_reports_each_frame_drawn(small_run, tmp_path):
    road, plant, run = small_run
    calls = []
    frames = drive_animation(road, run, tmp_path / "p.gif", plant, every=4, dpi=30,
                             progress=lambda done, total: calls.append((done, total)))
    assert calls == [(k, frames) for k in range(1, frames + 1)]


def test_windowed_animation_follows_the_car_without_warnings(small_run, tmp_path, caplog,
                                                             monkeypatch):
    """With ``window`` each frame's view is the square of that half-width centred on the
    car, drawn to scale, and matplotlib logs nothing (a data-limited aspect with both
    limits fixed logged a warning per frame)."""
    import logging

    import matplotlib.axes

    road, plant, run = small_run
    car = np.asarray(run.states.car)
    views = []
    draw = matplotlib.axes.Axes.draw

    def record(ax, renderer):
        draw(ax, renderer)
        views.append((ax.get_xlim(), ax.get_ylim(), ax.get_data_ratio()))

    monkeypatch.setattr(matplotlib.axes.Axes, "draw", record)
    with caplog.at_level(logging.WARNING):
        frames = drive_animation(road, run, tmp_path / "w.gif", plant, every=4, window=15.0,
                                 dpi=30)
    assert not [r for r in caplog.records if r.name.startswith("matplotlib")]
    shown = animation_frames(13, 4)
    assert frames == len(shown)
    # every view drawn (matplotlib draws some frames more than once) is a square of
    # half-width 15 m on the car at a frame written, and every frame's car has one
    centres = set()
    for xlim, ylim, ratio in views:
        assert np.diff(xlim)[0] == pytest.approx(30.0) and np.diff(ylim)[0] == pytest.approx(30.0)
        assert ratio == pytest.approx(1.0)
        centres.add((round(float(np.mean(xlim)), 9), round(float(np.mean(ylim)), 9)))
    assert centres == {(round(float(car[k, 0]), 9), round(float(car[k, 1]), 9)) for k in shown}


def test_figure_footprints_sit_at_the_poses(small_run):
    """Each footprint drawn is a 4.2 m x 1.8 m rectangle centred on a sample's centre of
    gravity, its long side along that sample's heading."""
    import matplotlib.pyplot as plt

    road, plant, run = small_run
    fig = drive_figure(road, run, plant, every=3)
    car = np.asarray(run.states.car)
    feet = [p.get_xy()[:4] for a in fig.axes for p in a.patches if p.get_gid() == "footprint"]
    assert len(feet) == len(range(0, 13, 3)) + (12 % 3 != 0)
    for k, corners in zip(sorted(set(range(0, 13, 3)) | {12}), feet):
        np.testing.assert_allclose(corners.mean(axis=0), car[k, :2], atol=1e-9)
        long_side = corners[0] - corners[3]
        np.testing.assert_allclose(np.hypot(*long_side), 4.2, rtol=1e-12)
        short_side = corners[0] - corners[1]
        np.testing.assert_allclose(np.hypot(*short_side), 1.8, rtol=1e-12)
        assert abs(np.dot(long_side, short_side)) < 1e-9  # a rectangle
        np.testing.assert_allclose(np.arctan2(long_side[1], long_side[0]), car[k, 2],
                                   atol=1e-12)
    plt.close(fig)


def test_trace_truth_and_planned_horizon(small_run):
    """The truth under each axle is the tire's peak on the grip field at that axle's contact
    point (front: lF ahead of the centre of gravity along the heading); a planned horizon
    (s, n) (`RecedingHorizonDriver.info`) is drawn at the road's c(s) + n N(s)."""
    road, plant, run = small_run
    M = 5
    info = {"plan_s": np.linspace(0, 20, 13 * (M + 1)).reshape(13, M + 1),
            "plan_n": np.full((13, M + 1), 0.7), "D": np.full((13, M), 0.4)}
    run = vs.DriveRun(run.states, run.measurements, run.commands, run.estimates, run.final,
                      controller_info=info)
    tr = drive_trace(road, run, plant)
    car = np.asarray(run.states.car)
    lF = float(plant.params.lF)
    xF = car[:, 0] + lF * np.cos(car[:, 2])
    yF = car[:, 1] + lF * np.sin(car[:, 2])
    peak = jax.vmap(vs.AxleGripEstimator().peak)
    np.testing.assert_allclose(tr["peak_true"][:, 0], peak(plant.grip.scale_at(xF, yF)),
                               rtol=1e-12)
    on_patch = float(peak(jnp.array([0.3]))[0])
    assert tr["peak_true"][:, 0].min() < on_patch < tr["peak_true"][:, 0].max()  # the patch
    s, n = info["plan_s"], info["plan_n"]
    cx, cy = road.position(s)
    th = road.heading(s)
    np.testing.assert_allclose(tr["horizon_x"], cx - n * np.sin(th), atol=1e-9)
    np.testing.assert_allclose(tr["horizon_y"], cy + n * np.cos(th), atol=1e-9)
    np.testing.assert_allclose(tr["planner_D"], 0.4)
    head = drive_trace(road, run, plant, upto=5)  # up to the end gate, say
    for key, value in head.items():
        np.testing.assert_array_equal(value, tr[key][:5], err_msg=key)


@pytest.mark.parametrize("road, expect", [("stage", vs.FAST_ROAD_DRIVER),
                                          ("sturn", vs.CORNER_DRIVER),
                                          ("file", vs.FILE_ROAD_DRIVER)])
def test_drive_builds_the_scenarios_driver_settings(road, expect, road_file):
    """`vehsim drive` drives each road with the scenarios' driver (`driver_settings`: more
    passes and a friction margin on the fast stage and a road from a file, a corridor
    margin wider than the driver's default on all of them, narrowing with the grip on the
    corners, where the planning tire also keeps its slip stiffness; a lost plan planned
    again on the stage and a road from a file; on a road from a file a lower terminal
    speed bound, a tighter slip bound and a soft corridor), built without compiling
    anything."""
    from vehsim.cli import _drive_setup as setup
    from vehsim.cli.drive import _check

    where = ["--road-file", str(road_file)] if road == "file" else ["--road", road]
    args = cli.build_parser().parse_args(["drive", *where])
    _check(args)
    sc = setup.scenario(args, setup.road(args))
    driver, estimator = setup.controller(args, sc)
    default = vs.RecedingHorizonDriver(table=sc.table)
    want = {"iterations": default.iterations, "hessian_update": default.hessian_update,
            "peak_fraction": 1.0,
            "margin": float(default.margin),
            "margin_grip_power": float(default.margin_grip_power)} | expect
    assert driver.iterations == want["iterations"]
    assert driver.hessian_update == want["hessian_update"]
    assert float(driver.peak_fraction) == want["peak_fraction"]
    assert float(driver.margin) == want["margin"]
    assert float(driver.margin_grip_power) == want["margin_grip_power"]
    assert want["margin"] >= 0.3 > float(default.margin)
    for name in ("terminal_backoff", "replan_kkt", "replan_iterations", "slip_limit"):
        # the defaults but on a file
        assert float(getattr(driver, name)) == float(expect.get(name, getattr(default, name)))
    # a lost plan planned again on the stage and a road from a file, not on the corners
    assert (float(driver.replan_kkt) < math.inf) == (road != "sturn")
    assert (float(driver.slip_limit) < float(default.slip_limit)) == (road == "file")
    # a soft corridor on a road from a file only
    assert (driver.corridor_penalty is None) == (road != "file")
    if road == "file":
        assert float(driver.corridor_penalty) == expect["corridor_penalty"] > 0
    # the corners' margin narrows with the grip (0.4 m on gravel, 0.21-0.23 m on the icy
    # patch), the stage's does not
    assert want["margin_grip_power"] == (1.0 if road == "sturn" else 0.0)
    # every road's planning tire keeps its B (its slip stiffness falls with the grip)
    assert driver.stiffness_power is None
    # the default controller: the estimate, with the scenarios' gate and sliding samples
    assert float(estimator.min_utilisation) == 0.7 and float(estimator.sliding_slip) == 0.1
    # a test brake on the corners' first metres, for the estimate only
    probe = None if driver.probe_distance is None else float(driver.probe_distance)
    assert probe == (vs.DRIVER_PROBE_DISTANCE if road == "sturn" else None)
    # not balanced by the rear axle driving (on a Magic Formula plant that lost the corners
    # of 20 % less grip)
    assert driver.probe_direction == "brake"
    args = cli.build_parser().parse_args(["drive", *where, "--controller", "rh-oracle"])
    assert setup.controller(args, sc)[0].probe_distance is None


@pytest.mark.parametrize("given, kept", [([], False), (["--keep-hessian"], True),
                                         (["--no-keep-hessian"], False)])
def test_a_converged_drive_takes_a_fresh_hessian_unless_asked_to_keep_it(given, kept,
                                                                          road_file):
    """A road from a file keeps each sample's first Hessian in rti mode (a real-time
    iteration's economy); ``--mode converged`` takes a fresh one every pass unless
    ``--keep-hessian`` says otherwise: with the kept Hessian 332 of the 386 converged solves
    of docs/cli.md's example ran to their cap of 100 passes, with a fresh one 2."""
    from vehsim.cli import _drive_setup as setup
    from vehsim.cli.drive import _check

    where = ["drive", "--road-file", str(road_file), "--controller", "rh-oracle"]
    rti = cli.build_parser().parse_args(where)
    _check(rti)
    sc = setup.scenario(rti, setup.road(rti))
    assert setup.controller(rti, sc)[0].hessian_update == "first"
    args = cli.build_parser().parse_args([*where, "--mode", "converged", *given])
    _check(args)
    driver = setup.controller(args, sc)[0]
    assert driver.mode == "converged"
    assert driver.hessian_update == ("first" if kept else "every")


@pytest.mark.parametrize("given, preview", [([], math.inf), (["--preview", "10"], 10.0),
                                            (["--preview", "0"], 0.0)])
def test_drive_gives_the_oracle_its_preview(given, preview):
    """``--preview`` reaches the oracle's `RecedingHorizonDriver.preview` (default: the whole
    horizon), built without compiling anything."""
    from vehsim.cli import _drive_setup as setup
    from vehsim.cli.drive import _check

    args = cli.build_parser().parse_args(["drive", "--road", "sturn", "--controller",
                                          "rh-oracle", *given])
    _check(args)
    driver, _ = setup.controller(args, setup.scenario(args, setup.road(args)))
    assert driver.friction == "oracle" and float(driver.preview) == preview


@pytest.mark.parametrize("road, given, passes, kept", [
    ("corner90", [], vs.CORNER_DRIVER.get("iterations", 4), False),
    ("corner90", ["--passes", "6", "--keep-hessian"], 6, True),
    ("stage", [], vs.FAST_ROAD_DRIVER["iterations"], True),
    ("stage", ["--passes", "8", "--no-keep-hessian"], 8, False)])
def test_drive_sets_the_passes_per_sample(road, given, passes, kept):
    """``--passes`` and ``--keep-hessian`` reach the driver's `iterations` and
    `hessian_update` over the road's settings (and nothing else of them), built without
    compiling anything."""
    from vehsim.cli import _drive_setup as setup
    from vehsim.cli.drive import _check

    args = cli.build_parser().parse_args(["drive", "--road", road, *given])
    _check(args)
    driver, _ = setup.controller(args, setup.scenario(args, setup.road(args)))
    assert driver.iterations == passes
    assert driver.hessian_update == ("first" if kept else "every")
    assert float(driver.margin) == vs.driver_settings(road)["margin"]


def test_drive_gives_the_estimate_pace_notes():
    """``--pace-notes`` (with ``--preview``): the driver plans with the estimate carried
    along the map of the relative grip (`DriveScenario.surface_map`, 1 at the start), and the
    estimator reads the same map; without it neither has one."""
    from vehsim.cli import _drive_setup as setup
    from vehsim.cli.drive import _check

    given = ["drive", "--road", "sturn", "--conditions", "icy"]
    args = cli.build_parser().parse_args([*given, "--pace-notes", "--preview", "10"])
    _check(args)
    sc = setup.scenario(args, setup.road(args))
    driver, estimator = setup.controller(args, sc)
    assert driver.friction == "estimate" and driver.surface_map
    assert float(driver.preview) == 10.0
    truth = np.asarray(sc.table.scale)
    # (relative to the best surface, the gravel around the patch)
    np.testing.assert_allclose(np.asarray(driver.table.scale), truth / truth.max(), rtol=1e-6)
    assert truth.min() < 0.6 * truth[0]  # the patch: the map says how it compares
    assert isinstance(estimator.surface, vs.RelativeGrip)
    assert float(estimator.surface.reference) == pytest.approx(truth.max(), rel=1e-6)
    # The rising road: warnings only, the slippery start below the grip further on, so the
    # prior (the nominal road) times the map is the true grip where the car starts.
    args = cli.build_parser().parse_args(["drive", "--road", "sturn", "--conditions",
                                          "rising", "--pace-notes"])
    _check(args)
    sc = setup.scenario(args, setup.road(args))
    driver, estimator = setup.controller(args, sc)
    notes = np.asarray(driver.table.scale)
    assert notes.max() == pytest.approx(1.0, rel=1e-6)
    x0, y0 = sc.state0.car[0], sc.state0.car[1]
    assert float(estimator.prior_scale * estimator.surface.scale_at(x0, y0)) == pytest.approx(
        float(sc.grip.field.scale_at(x0, y0)), rel=1e-6)
    assert float(estimator.surface.scale_at(x0, y0)) < 0.6
    args = cli.build_parser().parse_args(given)
    _check(args)
    driver, estimator = setup.controller(args, setup.scenario(args, setup.road(args)))
    assert not driver.surface_map and estimator.surface is None


def test_drive_chooses_the_grip_estimator():
    """``--estimator``: the kinds of `driver_estimator`, the driver's peak model with them;
    the default the LuGre family's."""
    from vehsim.cli import _drive_setup as setup
    from vehsim.cli.drive import ESTIMATORS, _check

    assert ESTIMATORS == vs.drive.scenarios.ESTIMATORS
    expected = {None: (vs.AxleGripEstimator, "plant"),
                "axle-peak": (vs.AxlePeakEstimator, "estimated"),
                "cautious": (vs.CautiousGripEstimator, "cautious")}
    for kind, (cls, model) in expected.items():
        extra = [] if kind is None else ["--estimator", kind]
        args = cli.build_parser().parse_args(["drive", "--road", "corner90", "--pace-notes",
                                              *extra])
        _check(args)
        driver, estimator = setup.controller(args, setup.scenario(args, setup.road(args)))
        assert type(estimator) is cls and driver.peak_model == model


def test_figure_shades_the_test_brake(small_run):
    """A planner's test brake (`RecedingHorizonDriver.info`'s ``probing``) reaches the trace
    and is shaded on the figure's grip and torque panels, from the first probing command's
    sample time to the state after the last one; a drive without one has no shading."""
    import matplotlib.pyplot as plt

    road, plant, run = small_run
    probing = np.zeros(13, bool)
    probing[[1, 2, 3, 7]] = True
    braked = vs.DriveRun(run.states, run.measurements, run.commands, run.estimates,
                         run.final, controller_info={"probing": probing})
    np.testing.assert_array_equal(drive_trace(road, braked, plant)["probing"], probing)
    t = np.asarray(run.states.t)
    fig = drive_figure(road, braked, plant)
    spans = [p for a in fig.axes for p in a.patches if p.get_gid() == "test-brake"]
    assert len(spans) == 4  # two runs of samples on two panels
    got = sorted({(round(p.get_x(), 12), round(p.get_x() + p.get_width(), 12)) for p in spans})
    want = sorted({(round(t[1] - 0.05, 12), round(t[3], 12)), (round(t[7] - 0.05, 12),
                                                               round(t[7], 12))})
    assert got == want
    plt.close(fig)
    fig = drive_figure(road, run, plant)
    assert not [p for a in fig.axes for p in a.patches if p.get_gid() == "test-brake"]
    plt.close(fig)


def test_the_first_non_finite_state_is_found_at_its_sample_time(capsys):
    """`first_nonfinite_time` (what makes `vehsim drive` exit 1, naming the time, where a drive
    diverged): the first sample at which any floating state leaf is NaN or infinite; integer
    leaves are not looked at; None when every state is finite."""
    import jax.numpy as jnp

    from vehsim.cli.drive import first_nonfinite_time

    t = np.arange(6) * 0.05
    states = {"x": jnp.zeros((6, 3)).at[4, 1].set(jnp.nan), "y": jnp.zeros(6).at[5].set(jnp.inf),
              "k": jnp.arange(6)}
    assert first_nonfinite_time(states, t) == pytest.approx(0.2)
    assert first_nonfinite_time({"x": jnp.zeros((6, 3)), "k": jnp.arange(6)}, t) is None
    assert first_nonfinite_time({"y": states["y"]}, t) == pytest.approx(0.25)
    from vehsim.cli.drive import nonfinite_status

    assert nonfinite_status(None) == 0 and capsys.readouterr().err == ""
    from vehsim.cli.drive import plan_note

    assert plan_note("tracking", None) is None
    assert plan_note("tracking", {"status": "successful", "iterations": 40}) is None
    note = plan_note("open-loop", {"status": "ip_max_iterations", "iterations": 500,
                                   "message": "The interior-point method reached ..."})
    assert note.startswith("vehsim drive: note: the nominal plan that --controller open-loop "
                           "drives did not converge (ip_max_iterations after 500 iterations")
    assert nonfinite_status(0.8) == 1
    assert "nonfinite: the plant's state is not finite from t = 0.80 s" in capsys.readouterr().err


def test_a_long_road_files_default_duration_is_capped_at_the_options_limit(tmp_path):
    """A road file's default time budget is its length at 5 m/s plus 5 s: 65 s for 300 m,
    and for 4 km the 600 s that ``--duration`` itself allows, not 805 s."""
    from vehsim.cli import _drive_setup as setup, build_parser

    for length, budget in ((300.0, 65.0), (4000.0, 600.0)):
        path = tmp_path / f"straight_{length:g}.csv"
        xs = np.linspace(0.0, length, 201)
        path.write_text("x_m,y_m,w_tr_right_m,w_tr_left_m\n"
                        + "".join(f"{x:.3f},0,3,3\n" for x in xs))
        args = build_parser().parse_args(["drive", "--road-file", str(path), "--no-animation"])
        cli.drive._check(args)  # the options' defaults, as the command sets them
        sc = setup.scenario(args, setup.road(args))
        assert sc.num_samples * sc.sample_time == pytest.approx(budget, abs=sc.sample_time)
