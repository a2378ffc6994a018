"""The drive plant's tire grips less sideways than it brakes: its side-force peak against its
braking peak over speed, and what that does to the offline bound.

The plant's 2D LuGre tire (`lugre2d_bakker1987`, fitted to Bakker's Magic Formula, whose
side force peaks below its braking force) is anisotropic. The planner's friction-ellipse
tire and `offline_bound` take one peak $D$ in every direction, the braking peak
(`peak_friction`). This script writes, as JSON lines:

- for speeds 5-20 m/s on the nominal road: the braking peak (`peak_friction`), the peak in
  pure side slip (`side_peak_friction`, the wheel rolling freely) and their ratio;
- for each benchmark corner on the nominal road: the free bound (`offline_bound`), and the
  same bound with the planning tire's side force times the ratio at ``--speed`` m/s
  (`FrictionEllipseTire.lateral_ratio`): a bound nearer what the plant can do in a corner.

Usage: PYTHONPATH=. python experiments/lateral_peak.py [--roads corner90 uturn sturn]
       [--speed 7]
"""

from __future__ import annotations

import argparse
import json

import equinox as eqx
import jax
import jax.numpy as jnp


jax.config.update("jax_enable_x64", True)

import vehsim as vs  # noqa: E402
from vehsim.drive.scenarios import ROAD_NAMES  # noqa: E402
from vehsim.optimal.primitives import rally_gravel_car  # noqa: E402


TIRE = vs.DrivePlant().tire


def ratio(speed: float) -> tuple[float, float, float]:
    """(braking peak, side peak, side over braking) on the nominal road at ``speed``."""
    lam = vs.nominal_scale()
    braking = float(vs.peak_friction(TIRE, lam, speed))
    side = float(vs.side_peak_friction(TIRE, lam, speed))
    return braking, side, side / braking


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--roads", nargs="+", default=["corner90", "uturn", "sturn"],
                    choices=ROAD_NAMES)
    ap.add_argument("--speed", type=float, default=7.0,
                    help="the speed [m/s] whose ratio the corners' bound takes")
    args = ap.parse_args(argv)
    if not args.speed > 0:
        ap.error(f"--speed must be > 0 m/s, got {args.speed}")
    for V in (5.0, 7.0, 10.0, 15.0, 20.0):
        braking, side, r = ratio(V)
        print(json.dumps(dict(speed=V, braking_peak=braking, side_peak=side, ratio=r)),
              flush=True)
    r = ratio(args.speed)[2]
    car = eqx.tree_at(lambda c: c.tire.lateral_ratio, rally_gravel_car(), jnp.asarray(r, float))
    for road in args.roads:
        sc = vs.drive_scenario(road, "nominal")
        free, _, exact = vs.offline_bound(sc)
        side, _, exact_side = vs.offline_bound(sc, car=car)
        print(json.dumps(dict(road=road, free_bound=float(free.t_f), exact=exact,
                              lateral_ratio=r, bound_with_ratio=float(side.t_f),
                              exact_with_ratio=exact_side,
                              above_free=float(side.t_f) / float(free.t_f) - 1.0)),
              flush=True)


if __name__ == "__main__":
    main()
