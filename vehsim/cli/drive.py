"""`vehsim drive`: the car driven along a road by a sampled controller on the move (the
receding-horizon driver with grip estimation, or a baseline), on a road of uniform grip or
with icy patches, written as ``drive.json`` (drive time, completion, distance off the road,
the controller's compute time per sample, the grip estimate and the planner's friction over
time, the settings), ``drive.png`` (`vehsim.plot.drive_figure`) and an animation
``drive.gif`` (`vehsim.plot.drive_animation`).

The compute time is measured here, above the simulation: the drive is `simulate_drive`'s,
run one sample at a time (`timed_drive`), the controller's sample (the estimator's update on
the new measurement, then the command) and the plant's each compiled once and called in
turn, each controller call timed to its result, so that what is timed is what drove.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from .._io import parse_number
from ..tire.tir import shipped_tires
from ._drive_setup import MAX_DURATION


ROADS = ("corner90", "uturn", "sturn", "stage")
CONTROLLERS = ("rh", "rh-nominal", "rh-oracle", "tracking", "open-loop")
RH_CONTROLLERS = ("rh", "rh-nominal", "rh-oracle")
MODES = ("rti", "converged")
ESTIMATORS = ("axle-grip", "axle-peak", "cautious")  # `driver_estimator`'s kinds
CONDITIONS = ("nominal", "minus20", "icy", "rising")
FORMATS = ("gif", "mp4")
SHIPPED_TIRE_NAMES = tuple(shipped_tires())
"""The .tir files shipped with vehsim that ``--plant-tire`` takes by name (`shipped_tires`)."""
MIN_PASSES, MAX_PASSES = 2, 100
"""The interior-point passes per sample `--passes` takes (the last pass only evaluates the
plan, so at least 2; at 100, the converged mode's cap, a sample is no longer real time)."""
MIN_GRIP, MAX_GRIP = 0.1, 3.0
"""The peak frictions `--grip` and `--patch` take, relative to the nominal road's (0.52):
from glare ice (0.052) to three times gravel's. Below the floor the tire is outside any
road it was made for (at 0.004 a drive on corner90 became non-finite within 0.8 s)."""
UNITS = {
    "drive_time": "s", "nonfinite_from": "s", "nominal_plan.t_f": "s",
    "nominal_plan.iterations": "1", "max_distance_off_road": "m", "duration": "s",
    "length": "m",
    "compute_time.p50": "s", "compute_time.p99": "s", "compute_time.max": "s",
    "compute_time.mean": "s", "compute_time.compile": "s", "sample_time": "s",
    "real_time_factor": "1 (controller time per sample / sample period, at the p50; < 1: "
                        "faster than real time)",
    "estimate.t": "s", "estimate.peak": "1 (peak friction mu*, per axle: front, rear)",
    "estimate.peak_std": "1", "estimate.scale": "1 (grip scale lambda, per axle)",
    "estimate.scale_std": "1", "planner_D.t": "s", "planner_D.D": "1", "truth.peak": "1",
    "trajectory.t": "s", "trajectory.x": "m", "trajectory.y": "m", "trajectory.psi": "rad",
    "trajectory.speed": "m/s", "trajectory.s": "m", "trajectory.n": "m",
    "trajectory.slip": "1 (the wheels' longitudinal slip omega r / V_x - 1, front and rear: "
                       "above 1 a spinning wheel, -1 a locked one)",
    "compute_time.samples": "1", "start_speed": "m/s", "truth.t": "s", "truth.scale": "1",
    "solver.iterations": "1", "solver.converged": "1 (true or false)",
    "solver.kkt": "1 (the largest scaled residual)", "settings.seed": "1", "settings.frame_every": "1",
    "settings.passes": "1 (interior-point passes per sample, rti mode)",
    "settings.grip": "1 (relative to the nominal road)", "nominal_scale": "1",
    "nominal_D": "1", "settings.patches": "m, m, m, 1 (x, y, radius, scale)",
    "settings.preview": "m (how far ahead the oracle knows the grip, or the pace notes the "
                        "surface; null: the whole horizon)",
}


def patch(text: str) -> tuple[float, float, float, float]:
    """``X,Y,RADIUS,SCALE``: an icy (or grippy) circular patch, centre [m], radius [m] > 0 and
    peak friction SCALE in [`MIN_GRIP`, `MAX_GRIP`] relative to the nominal road's."""
    rule = (f"must be X,Y,RADIUS,SCALE: four finite numbers, the centre [m], RADIUS > 0 m and "
            f"SCALE in [{MIN_GRIP:g}, {MAX_GRIP:g}] (relative to the nominal road)")
    try:
        values = tuple(parse_number(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{rule}, got {text!r}") from None
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"{rule}, got {text!r}")
    x, y, radius, scale = values
    if radius <= 0 or not MIN_GRIP <= scale <= MAX_GRIP:
        raise argparse.ArgumentTypeError(f"{rule}, got {text!r}")
    return values


def register(subparsers) -> None:
    from ._options import choice_of, integer, number

    p = subparsers.add_parser(
        "drive", help="drive a road on the move: the receding-horizon driver with grip "
                      "estimation, or a baseline",
        description="Drive the half car (noisy sensors, actuators with delay) along a road "
                    "with a sampled controller and write drive.json (drive time, completion, "
                    "distance off the road, compute time per sample, the grip estimate and "
                    "the planner's friction over time, settings), drive.png and an animation "
                    "drive.gif. See docs/driver.md.")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--road", type=choice_of(ROADS, "road"),
                       help=f"a scenario road: {', '.join(ROADS)} (docs/driver.md)")
    where.add_argument("--road-file", metavar="CSV",
                       help="a road given by its centre line and widths (columns x_m, y_m, "
                            "w_tr_right_m, w_tr_left_m; docs/roads.md), driven from its first "
                            "point (--closed: a circuit)")
    p.add_argument("--closed", action="store_true",
                   help="with --road-file: the road is a circuit (default: as the file's "
                        "'# closed:' line says, which vehsim's road files have; else open)")
    p.add_argument("--conditions", type=choice_of(CONDITIONS, "conditions"), default=None,
                   help="a named grip scenario instead of --grip/--patch: nominal, minus20 "
                        "(20 %% less grip everywhere), icy (a patch of half the grip on the "
                        "main corner; on a road file at its middle) or rising (60 %% of the "
                        "grip at the start, all of it from a third of the road on; open roads "
                        "that run towards their end); docs/driver.md")
    p.add_argument("--grip", type=number(MIN_GRIP, MAX_GRIP), default=None,
                   help="the peak friction everywhere, relative to the nominal road's (gravel, "
                        f"0.52), in [{MIN_GRIP:g}, {MAX_GRIP:g}] (default 1; 0.8: 20 %% less; "
                        f"{MIN_GRIP:g}: glare ice)")
    p.add_argument("--patch", type=patch, action="append", default=[], metavar="X,Y,R,SCALE",
                   help="a circular patch of radius R [m] centred at (X, Y) [m] whose peak "
                        "friction is SCALE times the nominal road's; repeat for several")
    p.add_argument("--plant-tire", default="lugre", metavar="TIRE",
                   help="the plant's tire: lugre (the report's lumped 2D LuGre, the family "
                        "the drivers assume; default), or a Magic Formula tyre property file "
                        "(.tir, or the shipped " + ", ".join(SHIPPED_TIRE_NAMES) + "), its "
                        "peaks made the nominal road's 0.52 at the car's static front axle "
                        "load and each surface's peak on the others, the curves' shapes the "
                        "file's (docs/drive.md)")
    p.add_argument("--controller", type=choice_of(CONTROLLERS, "controller"), default="rh",
                   help="rh: receding horizon with the grip estimate (default); rh-nominal: "
                        "with the nominal friction; rh-oracle: with the true grip along the "
                        "horizon; tracking: the nominal plan tracked; open-loop: the nominal "
                        "plan's inputs replayed")
    p.add_argument("--preview", type=number(0.0, None, unit="m", allow_inf=True),
                   default=None, metavar="M",
                   help="with --controller rh-oracle: how far ahead of the car [m] the "
                        "oracle knows the grip (beyond, the grip last seen; 0: the grip "
                        "under the car at once), with --pace-notes the surface; default: "
                        "the whole horizon")
    p.add_argument("--pace-notes", action="store_true",
                   help="with --controller rh: the driver and its estimator know how the "
                        "road's surfaces compare (the grip relative to the road's best "
                        "surface, as pace notes give it: they only warn), not their level; "
                        "--preview limits how far ahead")
    p.add_argument("--estimator", type=choice_of(ESTIMATORS, "estimator"), default=None,
                   help="with --controller rh: axle-grip (the plant's LuGre family assumed, "
                        "the default), axle-peak (shape-free: the measured curve's peak, "
                        "planned with at every speed) or cautious (both; each stage planned "
                        "with the smaller peak)")
    p.add_argument("--mode", type=choice_of(MODES, "mode"), default=None,
                   help="with an rh controller: rti (a few interior-point iterations per "
                        "sample, the default) or converged (to tolerance)")
    p.add_argument("--passes", type=integer(MIN_PASSES, MAX_PASSES), default=None,
                   metavar="N",
                   help="with an rh controller in rti mode: interior-point passes per "
                        f"sample, {MIN_PASSES} to {MAX_PASSES} (default: the road's driver, "
                        "4 on the benchmark corners, 10 on the stage, 16 on a road file; "
                        "more passes cost compute per sample, docs/driver.md)")
    p.add_argument("--keep-hessian", action=argparse.BooleanOptionalAction, default=None,
                   help="with an rh controller: keep each sample's first Hessian for its "
                        "later passes (cheaper passes) or take a fresh one every pass "
                        "(default: fresh with --mode converged; in rti mode the road's "
                        "driver, fresh on the benchmark corners, kept on the stage and on a "
                        "road file)")
    p.add_argument("--seed", type=integer(0, 2**31 - 1), default=None,
                   help="seed of the sensor noise (0; not with --no-noise)")
    p.add_argument("--noise", action=argparse.BooleanOptionalAction, default=True,
                   help="noisy sensors (default) or exact measurements")
    p.add_argument("--duration", type=number(0.05, MAX_DURATION, unit="s"),
                   default=None,
                   help="time budget of the drive [s], at least one sample of the drive's "
                        "0.05 s (default: the scenario's)")
    p.add_argument("--out", default="results/drive",
                   help="output folder (default: results/drive)")
    p.add_argument("--no-animation", dest="animation", action="store_false",
                   help="write no animation")
    p.add_argument("--animation-format", type=choice_of(FORMATS, "animation format"),
                   default=None,
                   help="gif (default; no external program) or mp4 (needs ffmpeg)")
    p.add_argument("--frame-every", type=integer(1, 100), default=None,
                   help="one animation frame per this many samples (default 2, more on a "
                        "long drive: at most 600 frames)")
    p.set_defaults(func=_drive)


def _check(args) -> None:
    """Checks between options (before anything is computed)."""
    if args.conditions is not None and (args.grip is not None or args.patch):
        raise ValueError(f"--conditions {args.conditions} names the grip; leave out --grip "
                         "and --patch (or give those without --conditions)")
    if args.grip is None:
        args.grip = 1.0
    if args.seed is not None and not args.noise:
        raise ValueError("--seed seeds the sensor noise; leave it out with --no-noise")
    if args.seed is None:
        args.seed = 0
    if args.closed and args.road_file is None:
        raise ValueError("--closed applies to --road-file (a scenario road knows its shape)")
    for option, value in (("--mode", args.mode), ("--passes", args.passes),
                          ("--keep-hessian", args.keep_hessian)):
        if value is not None and args.controller not in RH_CONTROLLERS:
            raise ValueError(f"{option} applies to the receding-horizon controllers "
                             f"({', '.join(RH_CONTROLLERS)}), not --controller "
                             f"{args.controller}")
    if args.passes is not None and args.mode == "converged":
        raise ValueError("--passes sets the passes of a real-time iteration (--mode rti); "
                         "--mode converged iterates to tolerance")
    if args.pace_notes and args.controller != "rh":
        raise ValueError("--pace-notes carries the grip estimate along the road: it applies "
                         f"to --controller rh, not --controller {args.controller}")
    if args.estimator is not None and args.controller != "rh":
        raise ValueError("--estimator chooses the grip estimator: it applies to --controller "
                         f"rh, not --controller {args.controller}")
    if args.preview is not None and not (args.controller == "rh-oracle" or args.pace_notes):
        raise ValueError("--preview limits what the oracle (or the pace notes) know ahead: it "
                         "applies to --controller rh-oracle or --pace-notes, not --controller "
                         f"{args.controller}")
    for option, value in (("--animation-format", args.animation_format),
                          ("--frame-every", args.frame_every)):
        if not args.animation and value is not None:
            raise ValueError(f"{option} applies to the animation; leave out --no-animation")
    if args.animation and args.animation_format == "mp4":
        from matplotlib import animation

        if not animation.writers.is_available("ffmpeg"):
            raise ValueError("--animation-format mp4 needs the ffmpeg program, which was not "
                             "found; use --animation-format gif (no external program)")


def _patches_reach_road(road, patches) -> None:
    import numpy as np

    for x, y, radius, scale in patches:
        off = float(np.asarray(road.distance_off_road(x, y)))
        if off >= radius:
            raise ValueError(f"--patch {x:g},{y:g},{radius:g},{scale:g}: the patch lies "
                             f"{off:.1f} m off the road (it must reach it: radius > "
                             f"{off:.1f} m, or a centre on the road)")


def timed_drive(plant, controller, state0, key, num_samples: int, estimator=None) -> dict:
    r"""The drive of `vehsim.simulate_drive` (the same samples, sensor noise and records,
    with the poses at every integration step), run one sample at a time from here so that
    the controller's compute time is that of the commands that drove.

    Two compiled programs, called alternately: the controller's sample (the estimator's
    update on the new measurement, its estimate, the command) and the plant's sample
    (`drive_step`). Each controller call is timed until its command is ready; the first
    sample (the controller's and the estimator's `init`, then the command) and the
    compilations are timed apart (``compile``). The estimate after the last measurement
    takes one more controller call, whose command is not issued and not timed.

    **Returns** ``{"run": DriveRun, "times": (N - 1,), "compile": s}`` [s]."""
    import jax
    import numpy as np

    from ..drive.plant import drive_step, measure_drive
    from ..drive.simulate import DriveRun

    info = getattr(controller, "info", None)

    def recorded(cs):
        return None if info is None else info(cs)

    @jax.jit
    def first(m):
        es = None if estimator is None else estimator.init(m)
        estimate = None if estimator is None else estimator.estimate(es)
        cs, command = controller.command(controller.init(m), m, estimate)
        return cs, es, command, recorded(cs)

    @jax.jit
    def sample(cs, es, m):
        estimate = None
        if estimator is not None:
            es = estimator.update(es, m)
            estimate = estimator.estimate(es)
        cs, command = controller.command(cs, m, estimate)
        return cs, es, command, recorded(cs), estimate

    @jax.jit
    def plant_sample(state, command):
        return drive_step(plant, state, command, jax.random.fold_in(key, state.k + 1),
                          substep_poses=True)

    m0 = measure_drive(plant, state0, jax.random.fold_in(key, state0.k))
    t0 = time.perf_counter()
    cs, es, command, record = jax.block_until_ready(first(m0))
    sample_compiled = sample.lower(cs, es, m0).compile()
    compile_s = time.perf_counter() - t0
    plant_compiled = plant_sample.lower(state0, command).compile()
    state, rows, times = state0, [], []
    with _progress("driving", num_samples, "samples") as bar:
        for k in range(num_samples):
            # the plant's sample finished before the controller's clock starts
            state, m, poses = jax.block_until_ready(plant_compiled(state, command))
            issued, issued_record = command, record
            t0 = time.perf_counter()
            cs, es, command, record, estimate = jax.block_until_ready(
                sample_compiled(cs, es, m))
            if k < num_samples - 1:  # the last call only takes in the last measurement
                times.append(time.perf_counter() - t0)
            rows.append((state, m, issued, estimate, issued_record, poses))
            if bar is not None:
                bar.advance(1)
    states, ms, commands, estimates, infos, poses = jax.tree.map(  # None stays None
        lambda *a: np.stack(a), *rows)
    return {"run": DriveRun(states, ms, commands, estimates, state, infos, poses),
            "times": np.asarray(times), "compile": compile_s}


def _progress(label: str, total: int, unit: str):
    """A host-side `ProgressBar` on stderr where progress is on (the command line's
    default; ``vehsim --no-progress`` turns it off), else a block yielding None."""
    from ..progress import progress_bar, resolve

    return progress_bar(label, total, unit, enabled=resolve(None))


def timing_record(times, sample_time: float, compile_s: float) -> dict:
    """p50, p99, max and mean of the per-sample `times` [s], and the real-time factor
    (p50 over the sample period)."""
    import numpy as np

    times = np.asarray(times, float)
    if times.size == 0:
        return {"compute_time": None, "real_time_factor": None}
    p50, p99 = (float(v) for v in np.percentile(times, [50, 99]))
    return {"compute_time": {"p50": p50, "p99": p99, "max": float(times.max()),
                             "mean": float(times.mean()), "samples": int(times.size),
                             "compile": compile_s},
            "real_time_factor": p50 / sample_time}


def _drive(args) -> int:
    _check(args)
    from . import _drive_setup as setup

    road = setup.road(args)
    _patches_reach_road(road, args.patch)
    rh = args.controller in RH_CONTROLLERS
    grip = (f"conditions {args.conditions}" if args.conditions else f"grip {args.grip:g}"
            + (f" with {len(args.patch)} patch(es)" if args.patch else ""))
    sc = setup.scenario(args, road)
    T = sc.sample_time
    print(f"vehsim drive {road.name}: a {road.length:.1f} m {'lap' if road.closed else 'road'}"
          f", {args.controller}" + (f" ({args.mode or 'rti'})" if rh else "") + f", {grip}, "
          + ("" if args.plant_tire == "lugre" else f"the plant's tire {Path(args.plant_tire).name}, ")
          + f"{sc.num_samples} samples of {T:g} s; "
          + ("" if rh else "solving the nominal plan, then ")
          + "compiling the controller (a minute or more on 2 cores), then driving",
          file=sys.stderr, flush=True)
    import jax
    import numpy as np

    from .._io import write_json_and_figure
    from .._result_files import with_units
    from ..drive.scenarios import BENCHMARK_PEAK, nominal_scale
    from ..plot import animation_frames, drive_animation, drive_figure, drive_trace, frame_every_for

    t0 = time.perf_counter()
    driver, estimator = setup.controller(args, sc)
    note = plan_note(args.controller, args.nominal_plan)
    if note:
        print(note, file=sys.stderr, flush=True)
    timing = timed_drive(sc.plant, driver, sc.state0, jax.random.key(args.seed),
                         sc.num_samples, estimator)
    run = timing["run"]
    wall = time.perf_counter() - t0
    result = setup.outcome(sc, run)
    t = np.asarray(run.states.t)
    nonfinite = first_nonfinite_time(run.states, t)
    upto = None if result["drive_time"] is None else int(
        min(len(t), np.searchsorted(t, result["drive_time"]) + 1))
    tr = drive_trace(road, run, sc.plant, upto)
    every = args.frame_every or frame_every_for(len(tr["t"]))
    info = run.controller_info
    rec = {
        "road": road.name, "length": road.length, "closed": road.closed,
        "controller": args.controller, "mode": (args.mode or "rti") if rh else None,
        "completed": result["completed"], "drive_time": result["drive_time"],
        "max_distance_off_road": result["max_distance_off_road"],
        "nonfinite_from": nonfinite, "nominal_plan": args.nominal_plan,
        "sample_time": T, "duration": sc.num_samples * T,
        "start_speed": sc.start_speed, "nominal_D": BENCHMARK_PEAK,
        "nominal_scale": nominal_scale(),
        **timing_record(timing["times"], T, timing["compile"]),
        "estimate": None if "peak_est" not in tr else {
            "t": tr["t"], "peak": tr["peak_est"], "peak_std": tr["peak_std"],
            "scale": tr["scale_est"], "scale_std": np.asarray(run.estimates.scale_std)},
        "planner_D": None if "planner_D" not in tr else {"t": tr["t"], "D": tr["planner_D"]},
        "solver": None if not isinstance(info, dict) else {
            k: np.asarray(info[k]) for k in ("iterations", "converged", "kkt", "probing")
            if k in info},
        "truth": {"t": tr["t"], "peak": tr["peak_true"], "scale": tr["scale_true"]},
        "trajectory": {**{k: tr[k] for k in ("t", "x", "y", "psi", "speed", "s", "n")},
                       "slip": tr["slip_true"]},
        "settings": {"road": args.road, "road_file": args.road_file, "closed": args.closed,
                     "plant_tire": args.plant_tire,
                     "conditions": args.conditions, "grip": args.grip,
                     "patches": [list(p) for p in args.patch],
                     "controller": args.controller, "pace_notes": args.pace_notes,
                     "estimator": (args.estimator or "axle-grip") if args.controller == "rh"
                     else None,
                     "mode": args.mode,
                     "passes": driver.iterations if rh and driver.mode == "rti" else None,
                     "keep_hessian": driver.hessian_update == "first" if rh else None,
                     "preview": (None if args.preview is None or math.isinf(args.preview)
                                 else args.preview), "seed": args.seed,
                     "noise": args.noise, "duration": args.duration,
                     "animation": args.animation and (args.animation_format or "gif"),
                     "frame_every": every},
        "wall_time_s": wall,
    }
    out = Path(args.out)
    status = (f"completed in {result['drive_time']:.2f} s" if result["completed"] else
              "crossed the end in " + f"{result['drive_time']:.2f} s" if result["drive_time"]
              else "did not reach the end")
    who = (args.controller + (" with pace notes" if args.pace_notes else "")
           + ("" if args.plant_tire == "lugre" else f" (plant tire {Path(args.plant_tire).stem})"))
    title = (f"{road.name}, {who}: {status}, off the road "
             f"{100 * result['max_distance_off_road']:.1f} cm")
    write_json_and_figure(out / "drive.json", with_units(rec, UNITS), out / "drive.png",
                          drive_figure(road, run, sc.plant, title=title,
                                       grip_vmax=nominal_scale(), upto=upto))
    written = ["drive.json", "drive.png"]
    if args.animation:
        name = f"drive.{args.animation_format or 'gif'}"
        print(f"drawing the animation ({name})", file=sys.stderr, flush=True)
        extent = max(np.ptp(tr["x"]), np.ptp(tr["y"]))
        with _progress(f"drawing {name}", len(animation_frames(len(tr["t"]), every)),
                       "frames") as bar:
            drive_animation(road, run, out / name, sc.plant, every=every, title=title,
                            grip_vmax=nominal_scale(), window=40.0 if extent > 120.0 else None,
                            upto=upto, progress=None if bar is None else
                            (lambda done, total: bar.reach(done)))
        written.append(name)
    ct = rec["compute_time"]
    print(f"{status}, off the road {result['max_distance_off_road']:.3f} m"
          + ("" if ct is None else f", controller {1e3 * ct['p50']:.2f} ms p50, "
             f"{1e3 * ct['p99']:.2f} ms p99 per {1e3 * T:g} ms sample")
          + f"; wrote {', '.join(str(out / w) for w in written)}", file=sys.stderr)
    return nonfinite_status(nonfinite)


def plan_note(controller: str, plan: dict | None) -> str | None:
    """A line for stderr when a baseline's nominal plan (`plan_record`) did not converge: the
    baseline then drives the solver's last iterate, which the drive's outcome alone would
    not tell."""
    if plan is None or plan["status"] == "successful":
        return None
    return (f"vehsim drive: note: the nominal plan that --controller {controller} drives did "
            f"not converge ({plan['status']} after {plan['iterations']} iterations: "
            f"{plan['message']}); it drives the solver's last iterate")


def nonfinite_status(nonfinite: float | None) -> int:
    """The drive's exit status: 0 for any drive whose states stayed finite (on the road or
    off it, a result), else 1 after a line on stderr saying from when they were not."""
    if nonfinite is None:
        return 0
    print(f"vehsim drive: nonfinite: the plant's state is not finite from t = {nonfinite:.2f} s "
          "on (a drive that diverged, not a result; the figures stop there)", file=sys.stderr)
    return 1


def first_nonfinite_time(states, t) -> float | None:
    """The first sample time at which any of the plant's `states` is NaN or infinite (None:
    finite throughout)."""
    import jax
    import numpy as np

    bad = np.zeros(len(t), bool)
    for leaf in jax.tree.leaves(states):
        leaf = np.asarray(leaf)
        if np.issubdtype(leaf.dtype, np.inexact):
            bad |= ~np.isfinite(leaf.reshape(len(t), -1)).all(axis=1)
    return float(t[np.argmax(bad)]) if bad.any() else None
