"""The receding-horizon driver on the shipped circuit (Oschersleben, a road from a file).

Drives `vehsim.track("Oschersleben")` on the nominal gravel grip (0.52), from rest at the
start line's 8 m/s, with the driver of `vehsim drive --road-file ... --closed` (the
estimate; `driver_settings(None)`, `FILE_ROAD_DRIVER`) or with the settings given, for
``--duration`` seconds (200: a lap and a bit), one drive per noise seed, and writes one JSON
line per drive: the lap time (the first crossing of the start line, with how far off the
road the car was until then), where it first went more than 5 cm off the road (time, arc
length, speed), and the plans: the samples whose KKT residual passed 1 and 100, the
re-plans from the cold start (`replan_kkt`) and how many of those did not converge, and the
wheels' largest and smallest true slip (front, rear) up to the lap.

The measured lines are in experiments/drive_circuit_results.jsonl (docs/driver.md, "A road
from a file").

Usage: PYTHONPATH=. python experiments/drive_circuit.py [--settings '{"margin": 0.5}'
       | --defaults] [--mode rti|converged] [--seeds 0 1] [--duration 200] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import time

import jax


jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import vehsim as vs  # noqa: E402
from vehsim.cli import _drive_setup as setup, drive as drive_command  # noqa: E402
from vehsim.drive.metrics import drive_path  # noqa: E402
from vehsim.plot import drive_trace  # noqa: E402


def _drive_arguments(argv: list[str]) -> argparse.Namespace:
    """`vehsim drive`'s arguments for ``argv``, every other option at its default (parsed by
    the command's own parser, so an option it gains later has its default here too)."""
    parser = argparse.ArgumentParser()
    drive_command.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["drive", *argv])
    drive_command._check(args)  # the command's checks, and the defaults it fills in
    return args


def drive(settings: dict, seed: int, duration: float) -> dict:
    path = vs.shipped_tracks()["Oschersleben"]
    args = _drive_arguments(["--road-file", str(path), "--closed", "--duration", str(duration),
                             "--seed", str(seed)])
    road = setup.road(args)
    sc = setup.scenario(args, road)
    settings = dict(settings)
    mode = settings.pop("mode", "rti")
    driver, estimator = vs.scenario_driver(sc, "estimate", mode=mode, **settings)
    t0 = time.perf_counter()
    run = jax.block_until_ready(setup.simulate(sc, driver, estimator, seed))
    wall = time.perf_counter() - t0
    t, x, y = (np.asarray(a) for a in drive_path(run, sc.state0))
    off = np.asarray(road.distance_off_road(x, y))
    info = {k: np.asarray(v) for k, v in run.controller_info.items()}
    # progress from the start line: the first fix may project just behind it, at s near L
    L = float(road.length)
    s_car = np.unwrap(info["s"], period=L)
    s_car = s_car - (s_car[0] - ((s_car[0] + 0.5 * L) % L - 0.5 * L))
    lap = np.flatnonzero(s_car >= L)
    k_lap = int(lap[0]) if lap.size else None
    i_off = np.flatnonzero(off > 0.05)
    first = None
    if i_off.size:
        i = int(i_off[0])
        k = min(int(t[i] / sc.sample_time), len(s_car) - 1)
        car = np.asarray(run.states.car)
        v = np.hypot(car[k, 3], car[k, 4])
        first = {"t": float(t[i]), "s": float(s_car[k]), "speed": float(v)}
    # the wheels' true slip (front, rear) up to the lap: spinning or locked wheels
    slip = drive_trace(road, run, sc.plant)["slip_true"]
    kkt, its = info["kkt"], info["iterations"]
    cold = its > driver.iterations
    lap_t = None if k_lap is None else float(np.asarray(run.states.t)[k_lap])
    upto = len(t) if k_lap is None else int(np.searchsorted(t, lap_t))
    return {"road": "Oschersleben", "seed": seed, "settings": settings | {"mode": mode},
            "duration": duration, "lap_time": lap_t,
            "lap_max_off_road": float(off[:max(upto, 1)].max()),
            "max_off_road": float(off.max()), "first_departure": first,
            "samples": int(kkt.size), "kkt_over_1": int(np.sum(kkt > 1)),
            "kkt_over_100": int(np.sum(kkt > 100)), "replans": int(np.sum(cold[1:])),
            "replans_not_converged": int(np.sum(cold[1:] & ~info["converged"][1:])),
            "slip_max": np.max(slip[:max(k_lap or len(slip), 1)], axis=0).tolist(),
            "slip_min": np.min(slip[:max(k_lap or len(slip), 1)], axis=0).tolist(),
            "wall_s": wall}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--settings", type=json.loads, default=None,
                    help="RecedingHorizonDriver settings (JSON); default FILE_ROAD_DRIVER")
    ap.add_argument("--defaults", action="store_true", help="the driver's own defaults")
    ap.add_argument("--mode", choices=("rti", "converged"), default=None,
                    help="the file road's settings in this mode (`driver_settings(None, "
                         "mode=...)`: 'converged' takes a fresh Hessian every pass, as "
                         "`vehsim drive --mode converged` does); --settings are laid over them")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--duration", type=float, default=200.0)
    ap.add_argument("--out", default=None, help="also append the lines to this file")
    a = ap.parse_args()
    if a.mode is not None and a.defaults:
        ap.error("--mode takes the file road's settings and --defaults the driver's own: "
                 "give one of them")
    if a.mode is not None:
        settings = vs.driver_settings(None, mode=a.mode) | (a.settings or {})
    else:
        settings = {} if a.defaults else (vs.driver_settings(None) if a.settings is None
                                          else a.settings)
    for seed in a.seeds:
        line = json.dumps(drive(settings, seed, a.duration))
        print(line, flush=True)
        if a.out:
            with open(a.out, "a") as f:
                f.write(line + "\n")


if __name__ == "__main__":
    main()
