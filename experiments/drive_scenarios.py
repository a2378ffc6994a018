"""The drive scenarios: roads x grips x drivers, and a Monte Carlo of noisy drives.

For each road (corner90, uturn, sturn, stage) and grip (nominal, minus20, icy, rising) of
`vehsim.drive_scenario`, each driver drives the plant (default actuators with delay, rate
limit and lag; noisy sensors, seed ``--seed``) and is measured at the integrator's
resolution (`vehsim.drive_outcome`): the time at the end gate, the largest distance off the
road, completed (crossed, never more than 5 cm off). Drivers:

- ``open-loop``: the nominal minimum-time drive (`nominal_primitive`, D = 0.52) replayed
  as a command schedule (`open_loop_schedule`);
- ``tracking``: the same reference tracked (`PrimitiveTracker`);
- ``rh-nominal``, ``rh-oracle``, ``rh-estimate``: `RecedingHorizonDriver` planning on the
  nominal road (peak 0.52 at 20 m/s), the true road along the horizon (the table's scale
  column), or the `AxleGripEstimator`'s (prior: the nominal scale), each stage with that
  road's peak at the stage's planned speed; a driver with an estimator also records the
  estimate and the planner's D at the main corner's apex (``apex``);
- ``rh-estimate-map``: ``rh-estimate`` with a map of the road's relative grip
  (`DriveScenario.surface_map`: pace notes, which say how the surfaces compare and nothing
  of their level) for the estimator (`AxleGripEstimator.surface`) and the planner
  (`RecedingHorizonDriver.surface_map`, the map along the whole horizon);
- ``bound``: the offline bound (`offline_bound`; time of the reduced model's minimum-time
  drive on the true grip; departure: its path between the nodes);
- ``bound-driver``: the same bound under the receding-horizon driver's own constraints
  (its corridor margin, slip bound, steering rate and peak fraction on that road:
  `offline_bound` with ``driver``), what those constraints cost before any estimation.

One JSON line per row goes to ``--out`` (default experiments/drive_scenarios_results.jsonl,
appended), then a markdown table is printed. The benchmark corners share one number of
samples (the longest budget) and one road-table size, so that each driver compiles once for
them; the stage (four times their budget) has its own.

``--monte-carlo SEEDS``: roads x grips x SEEDS noise seeds of one driver (``--mc-driver``,
default tracking) in ONE jitted call (plants, controllers, initial states and keys
batched, the drives vectorised or one after another: ``--mc-map``; the end-gate time and
the departure computed in the same call, on the road tables, `path_departure`); prints
the compile and run wall times and the completion rate, and checks the JAX departure
against the exact NumPy one on a few drives (equal to the table's interpolation error).
``--previews M ...`` (with ``--mc-driver rh-oracle``): the oracle that knows the grip only
M metres ahead of the car (`RecedingHorizonDriver.preview`; 0: the grip under the car, at
once), each preview more members of the same batch: how far ahead a driver must know the
grip to keep the road.
``--mc-map map`` (the default on a CPU): the same call with the drives one after another
(`jax.lax.map`) instead of vectorised (``--mc-map vmap``, the default on an accelerator); on
a CPU about 1.7 times as fast, since a vectorised drive computes both sides of every branch
of its driver and runs each loop to the slowest drive's count.
``--mc-replay-failures``: every drive the batch failed is driven again alone (the same key;
one unbatched program), and both outcomes are recorded (``failures_alone``): a drive at the
limit of the grip can fail in one program and not in the other, which round differently.

Usage: PYTHONPATH=. python experiments/drive_scenarios.py [--roads corner90 ...]
       [--grips nominal ...] [--drivers open-loop tracking ...] [--quick] [--seed 0]
       [--out PATH] [--monte-carlo 16 [--mc-driver tracking] [--mc-only]
       [--previews 0 5 inf] [--mc-first-seed 0] [--mc-map map] [--mc-replay-failures]]
       [--driver-settings JSON] [--plant-tire mf]

``--driver-settings '{"iterations": 8}'``: receding-horizon settings over
`driver_settings`'s, on every road (recorded with each row).
``--plant-tire mf``: the plant on a tire of another family than the drivers assume, a Magic
Formula with the scenario's peak on every surface (`mf_plant_tire`; rows marked
``plant_tire``).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import itertools
import json
import math
import time
from pathlib import Path

import jax


jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vehsim as vs  # noqa: E402
from vehsim.drive.horizon import BACK_EXTENSION, EXTENSION  # noqa: E402
from vehsim.drive.scenarios import (  # noqa: E402
    BENCHMARK_PEAK,
    GRIP_NAMES,
    ROAD_NAMES,
    TIME_BUDGETS,
    main_corner,
)


DRIVERS = ("open-loop", "tracking", "rh-nominal", "rh-oracle", "rh-estimate",
           "rh-estimate-map", "bound", "bound-driver")
OUT = Path(__file__).with_name("drive_scenarios_results.jsonl")
SPACING = 0.1
SETTINGS: dict = {}
"""`RecedingHorizonDriver` settings over `driver_settings`'s on every road
(``--driver-settings``)."""


def settings_for(road: str, kind: str) -> dict:
    """The settings of the receding-horizon driver ``kind`` (its planner's friction after
    ``rh-``) on ``road``: `driver_settings`, then `SETTINGS`."""
    return vs.driver_settings(road, kind.split("-")[1]) | SETTINGS


def size_group(road: str, roads) -> list[str]:
    """The roads that share `road`'s number of samples and table size: the benchmark
    corners together, the stage alone (its budget is four times theirs)."""
    return [r for r in roads if (r == "stage") == (road == "stage")]


def common_sizes(roads) -> tuple[float, int]:
    """The longest time budget [s] and the road-table size that fits every road."""
    budget = max(TIME_BUDGETS[r] for r in roads)
    points = max(int(math.ceil((vs.scenario_road(r).length + BACK_EXTENSION + EXTENSION)
                               / SPACING)) + 1 for r in roads)
    return budget, points


ESTIMATOR: list = ["axle-grip"]
"""The estimating drivers' estimator (``--estimator``, `driver_estimator`'s kinds)."""

PLANT_TIRE: list = ["lugre"]
"""The plant's tire (``--plant-tire``): 'lugre' (the scenarios' lumped 2D LuGre) or 'mf'
(`mf_plant_tire`)."""


@functools.cache
def mf_plant_tire() -> vs.RelaxedMFTire:
    r"""A tire of another family for the plant (``--plant-tire mf``): the shipped .tir
    file's Magic Formula 6.1 with its relaxation lengths (`vs.mf_plant_tire`), its pure-slip
    peaks at the rally car's static front axle load the nominal road's 0.52; on the other
    surfaces the scenario's peaks (`vs.peak_surface_factor`, which `drive_scenario` gives
    the plant). The curves' shapes (peak slip, fall-off, combined slip, load and speed
    dependence) are the Magic Formula's, which neither the estimator nor the planner
    assumes."""
    from vehsim.tire.tir import shipped_tires

    return vs.mf_plant_tire(shipped_tires()["sample_185_80R14_mf61"], BENCHMARK_PEAK)


def scenario(road, grip, budget, points):
    return vs.drive_scenario(road, grip, time_budget=budget, table_points=points,
                             table_spacing=SPACING,
                             tire=mf_plant_tire() if PLANT_TIRE[0] == "mf" else None)


def make_driver(kind: str, sc, reference):
    """``(controller, estimator)`` of driver `kind` on scenario `sc`."""
    act = sc.plant.actuators
    if kind == "open-loop":
        return vs.open_loop_schedule(reference, act, sc.num_samples), None
    if kind == "tracking":
        return vs.PrimitiveTracker(reference=reference, lead=vs.command_lead(act)), None
    return vs.scenario_driver(sc, kind.split("-")[1], pace_notes=kind == "rh-estimate-map",
                              estimator=ESTIMATOR[0], **settings_for(sc.road.name, kind))


@eqx.filter_jit
def _drive(plant, controller, state0, key, estimator, num_samples):
    return vs.simulate_drive(plant, controller, state0, key, num_samples, estimator,
                             substep_poses=True)


def run_one(kind, sc, reference, seed):
    controller, estimator = make_driver(kind, sc, reference)
    t0 = time.perf_counter()
    run = _drive(sc.plant, controller, sc.state0, jax.random.key(seed), estimator,
                 sc.num_samples)
    jax.block_until_ready(run)
    wall = time.perf_counter() - t0
    t, x, y = vs.drive_path(run, sc.state0)
    out = vs.drive_outcome(sc.road, t, x, y)
    rec = dict(out.record(), wall_s=wall)
    info = run.controller_info
    if isinstance(info, dict) and "iterations" in info:
        n = rec["time"] and int(min(len(t) - 1, math.ceil(rec["time"] / sc.sample_time)))
        n = n or sc.num_samples
        rec["planner"] = dict(
            mean_iterations=float(np.mean(np.asarray(info["iterations"])[:n])),
            converged_fraction=float(np.mean(np.asarray(info["converged"])[:n])),
            max_kkt=float(np.max(np.asarray(info["kkt"])[:n])))
    if run.estimates is not None:
        rec["final_peak_estimate"] = np.asarray(run.estimates.peak[-1]).tolist()
        if isinstance(info, dict) and "s" in info:  # at the main corner's apex
            s0, s1 = main_corner(sc.road_name)
            i = int(np.argmax(np.asarray(info["s"]) >= 0.5 * (s0 + s1)))
            rec["apex"] = dict(t=float(np.asarray(run.measurements.t)[i]),
                               peak_estimate=np.asarray(run.estimates.peak[i]).tolist(),
                               scale_estimate=np.asarray(run.estimates.scale[i]).tolist(),
                               planner_D_first=float(np.asarray(info["D"])[i, 0]),
                               planner_D_min=float(np.min(np.asarray(info["D"])[i])))
    return rec


def bound_row(sc, driver=None):
    prim, D, exact = vs.offline_bound(sc, driver=driver)
    v = prim.violations()
    return dict(time=float(prim.t_f) if bool(prim.solution.converged) else None,
                max_off_road=v["corridor_between_nodes"],
                completed=bool(prim.solution.converged), bound_D=D, bound_exact=exact)


def table(rows) -> str:
    lines = ["| road | grip | driver | time [s] | max off road [m] | completed |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        tm = "-" if r["time"] is None else f"{r['time']:.3f}"
        extra = "" if r.get("bound_exact", True) else " (min grip)"
        lines.append(f"| {r['road']} | {r['grip']} | {r['driver']} | {tm}{extra} | "
                     f"{r['max_off_road']:.3f} | {'yes' if r['completed'] else 'no'} |")
    return "\n".join(lines)


def scenario_table(args):
    rows = []
    with open(args.out, "a") as f:
        for road in args.roads:
            budget, points = common_sizes(size_group(road, args.roads))
            reference = None
            if {"open-loop", "tracking"} & set(args.drivers):
                nominal = scenario(road, "nominal", budget, points)
                t0 = time.perf_counter()
                prim = vs.nominal_primitive(nominal)
                print(f"# {road}: nominal primitive t_f = {float(prim.t_f):.3f} s "
                      f"(converged {bool(prim.solution.converged)}, "
                      f"{time.perf_counter() - t0:.1f} s)", flush=True)
                reference = vs.primitive_reference(prim).padded(args.reference_rows)
            for grip in args.grips:
                sc = scenario(road, grip, budget, points)
                for kind in args.drivers:
                    t0 = time.perf_counter()
                    if kind == "bound":
                        rec = bound_row(sc)
                    elif kind == "bound-driver":
                        rec = bound_row(sc, make_driver("rh-oracle", sc, None)[0])
                    else:
                        rec = run_one(kind, sc, reference, args.seed)
                    rec = dict(road=road, grip=grip, driver=kind, seed=args.seed,
                               num_samples=sc.num_samples, **rec)
                    if PLANT_TIRE[0] != "lugre":
                        rec["plant_tire"] = PLANT_TIRE[0]
                    if ESTIMATOR[0] != "axle-grip" and "estimate" in kind:
                        rec["estimator"] = ESTIMATOR[0]
                    if kind.startswith("rh-") or kind == "bound-driver":
                        rec["driver_settings"] = settings_for(
                            road, "rh-oracle" if kind == "bound-driver" else kind)
                    rec.setdefault("wall_s", time.perf_counter() - t0)
                    rows.append(rec)
                    f.write(json.dumps(rec) + "\n")
                    f.flush()
                    print(json.dumps(rec), flush=True)
    print(table(rows))
    return rows


def stack(trees):
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *trees)


def noise_key(args, seed: int) -> int:
    """The `jax.random.key` of the Monte Carlo's noise seed `seed` (counted from
    ``--mc-first-seed``), so that one drive can be driven again alone."""
    return 1000 + args.mc_first_seed + seed


def monte_carlo(args):
    budget, points = common_sizes(args.roads)
    previews = args.previews or [None]
    plants, ctrls, states, keys, tables, gates, meta, ests = [], [], [], [], [], [], [], []
    for road in args.roads:
        nominal = scenario(road, "nominal", budget, points)
        reference = vs.primitive_reference(vs.nominal_primitive(nominal)).padded(
            args.reference_rows)
        for grip in args.grips:
            sc = scenario(road, grip, budget, points)
            ctrl, estimator = make_driver(args.mc_driver, sc, reference)
            for preview in previews:
                if preview is not None:
                    ctrl = eqx.tree_at(lambda c: c.preview, ctrl, jnp.asarray(preview))
                for seed in range(args.monte_carlo):
                    plants.append(sc.plant)
                    ctrls.append(ctrl)
                    states.append(sc.state0)
                    keys.append(jax.random.key_data(jax.random.key(noise_key(args, seed))))
                    tables.append(sc.table)
                    gates.append(vs.EndGate.of(sc.road))
                    ests.append(estimator)
                    meta.append((road, grip, seed, sc, preview))
    B = len(meta)
    num_samples = meta[0][3].num_samples
    # the estimators differ between roads only by their surface maps: batched where they
    # have one, else the one estimator is a constant of the program
    mapped = ests[0] is not None and ests[0].surface is not None
    batch = (stack(plants), stack(ctrls), stack(states), jnp.stack(keys), stack(tables),
             stack(gates), stack(ests) if mapped else None)

    def one(plant, ctrl, state0, key, tbl, gate, est):
        estimator = est if mapped else ests[0]
        run = vs.simulate_drive(plant, ctrl, state0, jax.random.wrap_key_data(key),
                                num_samples, estimator, substep_poses=True)
        poses = run.poses
        N, S = poses.shape[:2]
        h = plant.actuators.sample_time / S
        t = jnp.concatenate([state0.t[None], state0.t + h * jnp.arange(1, N * S + 1)])
        x = jnp.concatenate([state0.car[:1], poses[..., 0].reshape(-1)])
        y = jnp.concatenate([state0.car[1:2], poses[..., 1].reshape(-1)])
        crossed, tc, i = gate.crossing(t, x, y)
        off = vs.path_departure(tbl, poses[..., 0], poses[..., 1], i - 1)
        return crossed, tc, off, poses

    if args.mc_map == "vmap":
        fn = eqx.filter_jit(jax.vmap(one))
    else:  # one drive after another inside the one program: each drive's branches its own
        fn = eqx.filter_jit(lambda *b: jax.lax.map(lambda a: one(*a), b))
    t0 = time.perf_counter()
    compiled = fn.lower(*batch).compile()
    t_compile = time.perf_counter() - t0
    t0 = time.perf_counter()
    crossed, tc, off, poses = jax.block_until_ready(compiled(*batch))
    t_run = time.perf_counter() - t0
    crossed, tc, off = np.asarray(crossed), np.asarray(tc), np.asarray(off)
    done = crossed & (off <= 0.05)
    print(f"# Monte Carlo: {B} drives ({len(args.roads)} roads x {len(args.grips)} grips x "
          f"{args.monte_carlo} seeds) of {num_samples} samples, driver {args.mc_driver}, one "
          f"jitted call ({args.mc_map}): compile {t_compile:.1f} s, run {t_run:.1f} s")
    # the JAX departure against the exact NumPy one, on a few drives
    check = []
    for b in np.linspace(0, B - 1, min(B, 6)).astype(int):
        sc = meta[b][3]
        p = np.asarray(poses[b])
        t = np.concatenate([[0.0], sc.sample_time / p.shape[1] * np.arange(1, p.size // 2 + 1)])
        x = np.concatenate([[float(sc.state0.car[0])], p[..., 0].ravel()])
        y = np.concatenate([[float(sc.state0.car[1])], p[..., 1].ravel()])
        ref = vs.drive_outcome(sc.road, t, x, y)
        near = ref.max_off_road < 1.0  # tracked: the exact value; far off: a lower bound
        check.append(dict(error=abs(ref.max_off_road - float(off[b])) if near else None,
                          completed_agrees=bool(done[b]) == ref.completed))
        print(f"#   check {meta[b][:3]}: JAX off {float(off[b]):.5f} m, NumPy "
              f"{ref.max_off_road:.5f} m; time {float(tc[b]):.4f} / {ref.time}")
    summary = dict(kind="monte-carlo", driver=args.mc_driver, drives=B, batching=args.mc_map,
                   num_samples=num_samples, compile_s=t_compile, run_s=t_run,
                   departure_checks=check, per_scenario={},
                   seeds=[args.mc_first_seed, args.mc_first_seed + args.monte_carlo - 1])
    if PLANT_TIRE[0] != "lugre":
        summary["plant_tire"] = PLANT_TIRE[0]
    if ESTIMATOR[0] != "axle-grip" and "estimate" in args.mc_driver:
        summary["estimator"] = ESTIMATOR[0]
    if args.mc_driver.startswith("rh-"):
        summary["driver_settings"] = {r: settings_for(r, args.mc_driver) for r in args.roads}
    if args.previews:
        summary["previews_m"] = [p if math.isfinite(p) else "inf" for p in args.previews]
    for road in args.roads:
        for grip, preview in itertools.product(args.grips, previews):
            m = np.array([(r == road) and (g == grip) and (p == preview)
                          for r, g, _, _, p in meta])
            name = f"{road}/{grip}" + ("" if preview is None else f"/preview {preview:g} m")
            summary["per_scenario"][name] = dict(
                completed=float(np.mean(done[m])),
                time_p50=float(np.median(tc[m & crossed])) if np.any(m & crossed) else None,
                max_off_p50=float(np.median(off[m])), max_off_max=float(np.max(off[m])),
                # the noise keys (jax.random.key) of the drives that failed, to drive again alone
                failed_keys=[noise_key(args, meta[b][2]) for b in np.flatnonzero(m & ~done)])
    if args.mc_replay_failures:
        summary["failures_alone"] = replay_failures(args, meta, ctrls, ests, done, off, tc,
                                                    crossed, mapped)
    print(json.dumps(summary))
    with open(args.out, "a") as f:
        f.write(json.dumps(summary) + "\n")
    print("| road/grip | completed | time p50 [s] | max off p50 [m] | max off max [m] |")
    print("|---|---|---|---|---|")
    for k, v in summary["per_scenario"].items():
        tm = "-" if v["time_p50"] is None else f"{v['time_p50']:.3f}"
        print(f"| {k} | {v['completed']:.2f} | {tm} | {v['max_off_p50']:.3f} | "
              f"{v['max_off_max']:.3f} |")


def replay_failures(args, meta, ctrls, ests, done, off, tc, crossed, mapped):
    """Each drive the batch failed, driven again alone (one unbatched program, the same
    plant, driver, estimator and noise key): at the limit of the grip a drive can fail in
    one and not in the other, since the batched and the single program round differently.
    One record per failed drive: its key and both outcomes."""
    records = []
    for b in np.flatnonzero(~done):
        road, grip, seed, sc, _ = meta[b]
        key = noise_key(args, seed)
        run = _drive(sc.plant, ctrls[b], sc.state0, jax.random.key(key),
                     ests[b] if mapped else ests[0], sc.num_samples)
        alone = vs.drive_outcome(sc.road, *vs.drive_path(run, sc.state0))
        rec = dict(road=road, grip=grip, key=key,
                   batched=dict(time=float(tc[b]) if crossed[b] else None,
                                max_off_road=float(off[b]), completed=False),
                   alone=alone.record())
        print(f"#   failed {road}/{grip} key {key}: batched {float(off[b]):.3f} m off; alone "
              f"{alone.max_off_road:.3f} m off, completed {alone.completed}")
        records.append(rec)
    return records


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--roads", nargs="+", default=list(ROAD_NAMES), choices=ROAD_NAMES)
    ap.add_argument("--grips", nargs="+", default=list(GRIP_NAMES), choices=GRIP_NAMES)
    ap.add_argument("--drivers", nargs="+", default=list(DRIVERS), choices=DRIVERS)
    ap.add_argument("--quick", action="store_true",
                    help="corner90 only, grips nominal and minus20")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--reference-rows", type=int, default=160,
                    help="rows of every reference table (padding; >= the primitives' nodes)")
    ap.add_argument("--monte-carlo", type=int, default=0, metavar="SEEDS")
    ap.add_argument("--mc-driver", default="tracking", choices=DRIVERS[:-2])
    ap.add_argument("--mc-only", action="store_true")
    ap.add_argument("--mc-first-seed", type=int, default=0, metavar="K",
                    help="the Monte Carlo's seeds are K, K+1, ... (another sample of seeds)")
    ap.add_argument("--mc-map", choices=("vmap", "map"), default=None,
                    help="the drives of the one jitted call vectorised (vmap, the default on "
                         "an accelerator) or one after another (lax.map, the default on a "
                         "CPU, where it is faster: a vectorised drive computes both sides of "
                         "every branch, and each loop runs to its slowest drive)")
    ap.add_argument("--mc-replay-failures", action="store_true",
                    help="drive each failed drive again alone and record both outcomes")
    ap.add_argument("--previews", nargs="+", type=float, metavar="M",
                    help="Monte Carlo of rh-oracle only: also over these previews [m] "
                         "(`RecedingHorizonDriver.preview`; inf: the whole horizon)")
    ap.add_argument("--plant-tire", choices=("lugre", "mf"), default="lugre",
                    help="the plant's tire: the scenarios' lumped LuGre, or a Magic Formula "
                         "of the same peak on the nominal road (mf_plant_tire)")
    ap.add_argument("--estimator", choices=vs.drive.scenarios.ESTIMATORS,
                    default="axle-grip",
                    help="the estimating drivers' estimator: axle-grip (the LuGre family "
                         "assumed), axle-peak (shape-free; the driver plans with its peak) or "
                         "cautious (both; the driver plans with the smaller peak)")
    ap.add_argument("--driver-settings", type=json.loads, default={}, metavar="JSON",
                    help="RecedingHorizonDriver settings over driver_settings' on every road, "
                         'e.g. \'{"iterations": 8, "hessian_update": "first"}\'')
    args = ap.parse_args(argv)
    fields = {f.name for f in dataclasses.fields(vs.RecedingHorizonDriver)} - {"table"}
    if not isinstance(args.driver_settings, dict) or not set(args.driver_settings) <= fields:
        ap.error("--driver-settings must be a JSON object of RecedingHorizonDriver fields ("
                 + ", ".join(sorted(fields)) + f"), got {args.driver_settings!r}")
    SETTINGS.update(args.driver_settings)
    PLANT_TIRE[0] = args.plant_tire
    ESTIMATOR[0] = args.estimator
    if args.mc_map is None:
        args.mc_map = "map" if jax.default_backend() == "cpu" else "vmap"
    if args.previews and args.mc_driver != "rh-oracle":
        ap.error("--previews needs --mc-driver rh-oracle (the oracle's preview of the grip)")
    if args.previews and any(not p >= 0 for p in args.previews):
        ap.error("--previews must be >= 0 m (inf allowed)")
    if args.quick:
        args.roads, args.grips = ["corner90"], ["nominal", "minus20"]
    if not args.mc_only:
        scenario_table(args)
    if args.monte_carlo:
        monte_carlo(args)


if __name__ == "__main__":
    main()
