"""A corridor margin from the position filter's uncertainty (a probe).

With exact sensing the oracle keeps corner90's road at a corridor margin of 0.1-0.2 m; with
the scenarios' noisy sensors the same margins leave it by 8-20 cm (docs/driver.md, "Plans
corrected by what the plant does"). The position the driver knows is the GNSS fixes (0.3 m)
averaged by its Kalman filter (`RecedingHorizonDriver.filter_position`), whose standard
deviation $\\sigma_p$ falls from 0.3 m at the first fix to a few centimetres. This probe
plans each sample with the margin $m_0 + z\\sigma_p$ (`RecedingHorizonDriver.position_margin`
$z$, `planning_margin`; narrowed with the planned grip as the road's margin is,
`margin_grip_power`) in place of the road's fixed margin, on the drive
scenarios of `drive_scenarios.py` (corner90 by default, every grip, noise seeds
``--seeds``), the oracle and the estimate with pace notes; one JSON line per drive, then a
summary per variant.

Usage: PYTHONPATH=. python experiments/position_margin.py [--roads corner90]
       [--seeds 8] [--variants 0.1:2 0.15:2] [--drivers rh-oracle rh-estimate-map]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np


jax.config.update("jax_enable_x64", True)

import vehsim as vs  # noqa: E402
from vehsim.drive.scenarios import GRIP_NAMES, ROAD_NAMES  # noqa: E402


sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from drive_scenarios import _drive, common_sizes, make_driver, scenario  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--roads", nargs="+", default=["corner90"], choices=ROAD_NAMES[:3])
    ap.add_argument("--grips", nargs="+", default=list(GRIP_NAMES), choices=GRIP_NAMES)
    ap.add_argument("--drivers", nargs="+", default=["rh-oracle", "rh-estimate-map"],
                    choices=["rh-oracle", "rh-estimate", "rh-estimate-map", "rh-nominal"])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--variants", nargs="+", default=["0.1:2", "0.15:2"],
                    metavar="M0:Z", help="base margin [m] and number of standard deviations")
    args = ap.parse_args(argv)
    variants = []
    for v in args.variants:
        m0, _, z = v.partition(":")
        variants.append((float(m0), float(z)))
    budget, points = common_sizes(["corner90", "uturn", "sturn"])
    summary: dict = {}
    for road in args.roads:
        for grip in args.grips:
            sc = scenario(road, grip, budget, points)
            for kind in args.drivers:
                driver, estimator = make_driver(kind, sc, None)
                runs = [("road", driver)] + [
                    (f"{m0:g}+{z:g}sigma", eqx.tree_at(
                        lambda d: (d.margin, d.position_margin), driver,
                        (jnp.asarray(m0, float), jnp.asarray(z, float)),
                        is_leaf=lambda x: x is None))
                    for m0, z in variants]
                for label, ctl in runs:
                    for seed in range(args.first_seed, args.first_seed + args.seeds):
                        t0 = time.perf_counter()
                        run = _drive(sc.plant, ctl, sc.state0, jax.random.key(seed),
                                     estimator, sc.num_samples)
                        jax.block_until_ready(run)
                        out = vs.drive_outcome(sc.road, *vs.drive_path(run, sc.state0)).record()
                        rec = dict(road=road, grip=grip, driver=kind, margin=label, seed=seed,
                                   **out, wall_s=time.perf_counter() - t0)
                        print(json.dumps(rec), flush=True)
                        summary.setdefault((road, grip, kind, label), []).append(rec)
    for (road, grip, kind, label), recs in summary.items():
        times = [r["time"] for r in recs if r["completed"]]
        print(json.dumps(dict(summary=True, road=road, grip=grip, driver=kind, margin=label,
                              completed=len(times), drives=len(recs),
                              median_time=float(np.median(times)) if times else None)),
              flush=True)


if __name__ == "__main__":
    main()
