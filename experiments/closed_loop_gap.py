"""How close can a closed loop come to the free bound? The oracle with each imperfection
removed in turn.

The free bound (`vehsim.offline_bound`) is the planning model's minimum-time drive with the
true grip, the road's full width, no slip bound and no actuators. The receding-horizon
driver that knows the true grip (the oracle) drives the plant instead, whose tires, wheel
spin and suspension are not the planning model's, through actuators with delay, rate
limits and lag, measured by noisy sensors, and keeps a corridor margin and a slip bound.
This script drives the oracle on the nominal corners (seed 0) under these conditions:

- ``shipped``: the scenarios' sensors and actuators;
- ``exact sensing``: the sensors' noise off (`DriveSensors.noise_on`);
- ``exact sensing, ideal actuators``: also no delay, rate limit or lag
  (`ideal_actuators`; the driver then predicts over no delay);
- (``--conditions``) ``exact sensing, ideal actuators, quasi-static loads``: also the
  plant's suspension off (`DrivePlant.suspension`: the loads of the planning model's
  quasi-static load transfer), leaving its tires and wheel spin as what differs;
- (``--conditions``) ``the planner's model``: that plant on the planning car's own tire
  (`rally_gravel_tire`, put on the road by its peak, `plant_surface_factor`), so that only
  the wheel spin through which the torques realise the planned slips differs; the driver
  plans every stage with the peak at the reference speed (the tire's D, 0.52, at every
  speed) and without the traction control, and the drives are compared with this car's
  own free bound (`nominal_primitive` at 0.52),

each with the road's settings (`driver_settings`; on the corners 0.4 m narrowing with the
grip, and the slip bound) and with the margin ``--margins`` (held on every stage), and with
ideal actuators also without the slip bound at the smallest two margins. What is left
between the best completed drive with exact sensing and ideal actuators and the free bound
is what the plant's being another model than the planner's costs, with nothing else in the
way. The first three conditions are the default.

One JSON line per drive (time at the end gate, largest distance off the road, completed,
and the time above the free bound) and one per road for the free bound go to stdout; the
measured lines are in experiments/closed_loop_gap_results.jsonl (docs/driver.md, "With
nothing else in the way").

``--planning-car plant-shape`` drives the same with the planning car of the plant tire's
shape (`planner_car`: the LuGre steady state's $B$, $C$, peaking at 5-6 % slip) in place
of the benchmark's gravel tire (``plant-shape-anisotropic``: with the side curve's own peak
and stiffness, `fit_planner_tire`), the free bound staying the gravel car's (the two free
bounds agree within 0.6 %, docs/drive.md, "Baselines").

``--steps-per-stage S`` plans with S RK4 steps per stage of the horizon problems (the tire
of the plant's shape needs several: `horizon_problem`), ``--set NAME=VALUE`` changes any
other driver setting, and ``--trace`` also writes, for each drive, every sample's
prediction of the time at the end gate (the sample's time plus its plan's time to the
gate): where it rises, the drive lost time its plans did not foresee.

Usage: PYTHONPATH=. python experiments/closed_loop_gap.py [--roads corner90 uturn sturn]
       [--margins 0.3 0.2 0.1 0.0] [--seed 0] [--planning-car gravel] [--mode rti]
       [--iterations N] [--conditions ...] [--steps-per-stage 1] [--set NAME=VALUE ...]
       [--lateral-ratio 1] [--trace]
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


jax.config.update("jax_enable_x64", True)

import vehsim as vs  # noqa: E402
from vehsim.drive.estimator import REFERENCE_SPEED  # noqa: E402
from vehsim.drive.scenarios import BENCHMARK_PEAK, ROAD_NAMES  # noqa: E402
from vehsim.optimal.primitives import rally_gravel_car  # noqa: E402


CONDITIONS = {  # what each condition removes (module docstring)
    "shipped": frozenset(),
    "exact sensing": frozenset({"noise"}),
    "exact sensing, ideal actuators": frozenset({"noise", "actuators"}),
    "exact sensing, ideal actuators, quasi-static loads":
        frozenset({"noise", "actuators", "suspension"}),
    "the planner's model": frozenset({"noise", "actuators", "suspension", "tire"}),
}


@eqx.filter_jit
def _drive(plant, controller, state0, key, num_samples):
    return vs.simulate_drive(plant, controller, state0, key, num_samples, None,
                             substep_poses=True)


class Traced(eqx.Module):
    """A `RecedingHorizonDriver` whose drive records, after each command, the sample's
    time, its arc length and its plan (the knots' arc lengths and times)."""

    driver: vs.RecedingHorizonDriver

    def init(self, m):
        return self.driver.init(m)

    def command(self, state, m, estimate):
        return self.driver.command(state, m, estimate)

    def info(self, state):
        knots = state.s_plan + jnp.linspace(0.0, self.driver.horizon, self.driver.num_stages + 1)
        return dict(t=state.t, s=state.s, knots=knots, times=state.xs[:, 8])


def predicted_finish(info, length: float) -> list[float]:
    """Each sample's prediction of the time at the end gate (arc length ``length``): its
    time plus its plan's time from the car's arc length to the gate, until the car passes
    the gate (`Traced`)."""
    out = []
    for t, s, knots, times in zip(*(np.asarray(info[k]) for k in ("t", "s", "knots", "times"))):
        if s > length:
            break
        out.append(float(t + np.interp(length, knots, times) - np.interp(s, knots, times)))
    return out


def scenario(road: str, condition: str) -> vs.DriveScenario:
    """The nominal scenario of ``road`` under ``condition`` (module docstring)."""
    off = CONDITIONS[condition]
    sc = vs.drive_scenario(
        road, "nominal", sensors=vs.DriveSensors(noise_on=False) if "noise" in off else None,
        actuators=vs.ideal_actuators() if "actuators" in off else None,
        tire=vs.rally_gravel_tire() if "tire" in off else None)
    if "suspension" in off:
        sc = dataclasses.replace(sc, plant=dataclasses.replace(sc.plant, suspension=False))
    return sc


def variants(road: str, condition: str, margins, car: str = "gravel", mode: str = "rti",
             iterations: int | None = None, steps: int = 1,
             lateral_ratio: float = 1.0) -> list[tuple[str, dict]]:
    """``(label, settings)`` of the drives of ``road`` under ``condition`` with the
    planning car ``car`` ("gravel": the driver's default; "plant-shape": `planner_car`;
    "plant-shape-anisotropic": `planner_car` with the side curve's own peak and stiffness),
    in ``mode`` (`driver_settings`' "rti" or "converged") with ``iterations`` passes per
    sample (None: the road's) and ``steps`` RK4 steps per stage of its horizon problems,
    its tire's side force times ``lateral_ratio`` (`FrictionEllipseTire.lateral_ratio`)."""
    shipped = vs.driver_settings(road, "oracle", mode=mode) | {"steps_per_stage": steps}
    if iterations is not None:
        shipped = shipped | {"iterations": iterations}
    if "tire" in CONDITIONS[condition]:  # the plant's peak is the tire's D at every speed,
        # its force the planner's: each stage plans with the peak at the reference speed,
        # unclipped
        shipped = shipped | {"peak_speed": REFERENCE_SPEED, "traction_limit": None}
    if car.startswith("plant-shape"):
        shipped = shipped | {"vehicle": vs.planner_car(
            BENCHMARK_PEAK, anisotropic=car == "plant-shape-anisotropic")}
    if lateral_ratio != 1.0:
        vehicle = shipped.get("vehicle", rally_gravel_car())
        shipped = shipped | {"vehicle": eqx.tree_at(lambda c: c.tire.lateral_ratio, vehicle,
                                                     jnp.asarray(lateral_ratio, float))}
    out = [("the road's settings", shipped)]
    out += [(f"margin {m:g}", shipped | {"margin": m, "margin_grip_power": 0.0})
            for m in margins]
    if "actuators" in CONDITIONS[condition]:
        out += [(f"margin {m:g}, no slip bound", shipped | {
            "margin": m, "margin_grip_power": 0.0, "slip_limit": None})
            for m in sorted(margins)[:2]]
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--roads", nargs="+", default=["corner90", "uturn", "sturn"],
                    choices=ROAD_NAMES)
    ap.add_argument("--margins", nargs="+", type=float, default=[0.3, 0.2, 0.1, 0.0],
                    help="corridor margins [m], each held on every stage")
    ap.add_argument("--seed", type=int, default=0, help="the sensors' noise seed")
    ap.add_argument("--conditions", nargs="+", choices=list(CONDITIONS),
                    default=list(CONDITIONS)[:3],
                    help="the conditions to drive (module docstring)")
    ap.add_argument("--planning-car", choices=("gravel", "plant-shape",
                                               "plant-shape-anisotropic"), default="gravel",
                    help="the driver's planning tire: the benchmark's gravel tire, or one "
                         "of the plant tire's shape (planner_car), with its side curve's own "
                         "peak and stiffness (anisotropic)")
    ap.add_argument("--mode", choices=("rti", "converged"), default="rti",
                    help="the driver's mode (driver_settings)")
    ap.add_argument("--iterations", type=int, default=None,
                    help="real-time passes per sample (default: the road's)")
    ap.add_argument("--steps-per-stage", type=int, default=1,
                    help="RK4 steps per stage of the horizon problems")
    ap.add_argument("--lateral-ratio", type=float, default=1.0,
                    help="the planning tire's side force over the circle's "
                         "(FrictionEllipseTire.lateral_ratio; the plant's is 0.92 at 7 m/s, "
                         "experiments/lateral_peak.py)")
    ap.add_argument("--trace", action="store_true",
                    help="also write each sample's predicted time at the end gate "
                         "(predicted_finish) and its arc length (s)")
    ap.add_argument("--set", nargs="+", default=[], metavar="NAME=VALUE",
                    help="driver settings over the road's (a Python literal each: "
                         "traction_limit=None, peak_fraction=0.97)")
    args = ap.parse_args(argv)
    overrides = {}
    for item in args.set:
        name, _, value = item.partition("=")
        try:
            overrides[name] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            ap.error(f"--set {item}: VALUE must be a Python literal")
    if any(m < 0 for m in args.margins):
        ap.error(f"--margins must be >= 0 m, got {args.margins}")
    if not 0.0 < args.lateral_ratio <= 2.0:
        ap.error(f"--lateral-ratio must be in (0, 2], got {args.lateral_ratio}")
    if args.iterations is not None and args.iterations < 1:
        ap.error(f"--iterations must be >= 1, got {args.iterations}")
    for road in args.roads:
        base = scenario(road, "shipped")
        prim, _, exact = vs.offline_bound(base)
        free = float(prim.t_f)
        print(json.dumps(dict(road=road, variant="free bound", time=free, exact=exact)),
              flush=True)
        for condition in args.conditions:
            sc, bound = scenario(road, condition), free
            if "tire" in CONDITIONS[condition]:  # its own bound: the planner at its one peak
                bound = float(vs.nominal_primitive(sc, BENCHMARK_PEAK).t_f)
                print(json.dumps(dict(road=road, variant="free bound, " + condition, time=bound)),
                      flush=True)
            for label, settings in variants(
                    road, condition, args.margins, car=args.planning_car, mode=args.mode,
                    iterations=args.iterations, steps=args.steps_per_stage,
                    lateral_ratio=args.lateral_ratio):
                driver, _ = vs.scenario_driver(sc, "oracle", **(settings | overrides))
                t0 = time.perf_counter()
                run = _drive(sc.plant, Traced(driver) if args.trace else driver, sc.state0,
                             jax.random.key(args.seed), sc.num_samples)
                jax.block_until_ready(run)
                wall = time.perf_counter() - t0
                out = vs.drive_outcome(sc.road, *vs.drive_path(run, sc.state0)).record()
                if args.trace:
                    finish = predicted_finish(run.controller_info, float(sc.road.length))
                    out |= dict(predicted_finish=[round(f, 4) for f in finish],
                                s=[round(float(a), 3) for a in
                                   run.controller_info["s"][:len(finish)]])
                above = None if out["time"] is None else out["time"] / bound - 1.0
                print(json.dumps(dict(road=road, condition=condition, variant=label,
                                      planning_car=args.planning_car, mode=args.mode,
                                      iterations=args.iterations,
                                      steps_per_stage=args.steps_per_stage,
                                      lateral_ratio=args.lateral_ratio,
                                      overrides=args.set, seed=args.seed,
                                      **out, above_free=above, wall_s=wall)), flush=True)


if __name__ == "__main__":
    main()
