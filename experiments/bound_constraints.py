"""What each of the receding-horizon driver's constraints costs against the offline bound.

For each road (nominal grip), `vehsim.offline_bound` solves the free bound (no corridor
margin, no slip bound, the steering rate free) and then the same bound under a
`RecedingHorizonDriver` of the scenarios (`driver_settings`) with only some of its
constraints kept, the others switched off:

- ``all``: the driver's margin, slip bound and steering rate and limit;
- ``margin``: only the corridor margin; ``slip``: only the slip bound; ``steer``: only the
  steering rate and limit;
- ``all, margin M``: all of them, with the margin ``--margin`` M instead;
- ``free, plant's tire shape``: the free bound of `planner_car` (a tire of the plant's
  LuGre shape) instead of the gravel tire, with the slips of both free bounds (the
  largest and the 90th percentile per axle).

One JSON line per bound (time [s], whether the fixed point converged, and the fraction
above the free bound) goes to stdout; the measured lines are in
experiments/bound_constraints_results.jsonl (docs/drive.md, "Baselines").

Usage: PYTHONPATH=. python experiments/bound_constraints.py [--roads corner90 uturn sturn]
       [--grips nominal] [--margin 0.1] [--shape-only]
"""

from __future__ import annotations

import argparse
import json

import jax
import numpy as np


jax.config.update("jax_enable_x64", True)

import vehsim as vs  # noqa: E402
from vehsim.drive.scenarios import GRIP_NAMES, ROAD_NAMES  # noqa: E402
from vehsim.optimal.shooting import DELTA_MAX  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--roads", nargs="+", default=["corner90", "uturn", "sturn"],
                    choices=ROAD_NAMES)
    ap.add_argument("--grips", nargs="+", default=["nominal"], choices=GRIP_NAMES)
    ap.add_argument("--margin", type=float, default=0.1,
                    help="the margin [m] of the last variant, with the other constraints")
    ap.add_argument("--shape-only", action="store_true",
                    help="only the free bounds of the two tires, not the driver's constraints")
    args = ap.parse_args()
    off = dict(margin=0.0, slip_limit=None, steer_rate=1e3, steer_limit=DELTA_MAX)
    variants = {
        "all": {},
        "margin": {k: v for k, v in off.items() if k != "margin"},
        "slip": {k: v for k, v in off.items() if k != "slip_limit"},
        "steer": {k: v for k, v in off.items() if k not in ("steer_rate", "steer_limit")},
        f"all, margin {args.margin:g}": dict(margin=args.margin),
    }
    for road in args.roads:
        for grip in args.grips:
            sc = vs.drive_scenario(road, grip)
            prim, _, exact = vs.offline_bound(sc)
            free = float(prim.t_f)
            print(json.dumps(dict(road=road, grip=grip, variant="free", time=free, exact=exact,
                                  **slips(prim))), flush=True)
            shaped, _, exact = vs.offline_bound(sc, car=vs.planner_car(0.52))
            t = float(shaped.t_f)
            print(json.dumps(dict(road=road, grip=grip, variant="free, plant's tire shape",
                                  time=t, exact=exact, above_free=t / free - 1.0,
                                  B=float(shaped.problem.vehicle.tire.B),
                                  C=float(shaped.problem.vehicle.tire.C), **slips(shaped))),
                  flush=True)
            if args.shape_only:
                continue
            for name, over in variants.items():
                # (`offline_bound` reads only the driver's constraints)
                driver = vs.RecedingHorizonDriver(table=sc.table,
                                                  **(vs.driver_settings(road) | over))
                prim, _, exact = vs.offline_bound(sc, driver=driver)
                t = float(prim.t_f)
                print(json.dumps(dict(road=road, grip=grip, variant=name, time=t, exact=exact,
                                      above_free=t / free - 1.0,
                                      margin=float(driver.margin),
                                      slip_limit=None if driver.slip_limit is None
                                      else float(driver.slip_limit))), flush=True)


def slips(prim) -> dict:
    """The largest and the 90th-percentile combined slip of each axle over the bound's knots
    (front, rear)."""
    s = np.asarray(jax.vmap(lambda X: vs.axle_slips(prim.problem.vehicle, X))(
        prim.solution.xs))
    return dict(slip_max=s.max(0).round(4).tolist(),
                slip_p90=np.percentile(s, 90, axis=0).round(4).tolist())


if __name__ == "__main__":
    main()
