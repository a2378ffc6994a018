"""The plant's own fastest drive: minimum time by shooting through the plant itself.

The free bound (`vehsim.offline_bound`) is the minimum time of the *planning* model, the
reduced half car on a friction-ellipse tire, on the true grip. The driver drives another car:
the full half car (eqs. 49-60) on dynamic LuGre tires with wheel spin and suspension. How
fast can that car go, with everything about the road known in advance?

This script searches for the answer directly on the plant. Its decision variables are the
commands $(T_F, T_R, \\delta)$ of every control sample (20 Hz, held over the sample, within
the actuators' limits); the plant has exact sensing and ideal actuators (no delay, rate
limit or lag), so the commands are what the car gets. The objective is the time at the end
gate (`EndGate.crossing`, linear between the integrator's poses) plus a penalty
$\\rho\\int d(t)^2\\,dt$ on the centre of gravity's distance off the road $d$
(`pose_departures`, at every integrator step before the gate), minimised by L-BFGS-B
(SciPy) on the reverse-mode gradient of the whole drive, for increasing $\\rho$. It starts
from the commands of the oracle's drive (the receding-horizon driver with the true grip, at
the road's settings) under the same conditions, or (``--start bound``) from the free
bound's open-loop replay. ``--margin M`` keeps the car M metres inside each edge, as the
driver's corridor margin does. The last line per road holds the commands
found, to replay with `CommandSchedule`.

A local search: what it finds is a drive the plant can make, so the plant's true minimum
time is at most that; it is not a lower bound. If it finds nothing faster than the oracle,
the oracle is near a local optimum of the plant; if it finds much faster drives, the driver
leaves that time on the road.

One JSON line per road and round to stdout (the time at the gate, the exact distance off the
road from `drive_outcome`, and the times of the free bound and of the oracle's drive), then
where the oracle's drive and the one found spend their time (`profile`); the
measured lines are in experiments/plant_bound_results.jsonl (docs/driver.md, "The plant's
own fastest drive").

Usage: PYTHONPATH=. python experiments/plant_bound.py [--roads corner90 uturn sturn]
       [--penalties 1e3 1e4] [--iterations 120] [--start oracle]
       [--margin 0]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize


jax.config.update("jax_enable_x64", True)

import vehsim as vs  # noqa: E402
from vehsim.drive.scenarios import ROAD_NAMES  # noqa: E402


def scenario(road: str) -> vs.DriveScenario:
    """The nominal scenario of ``road`` with exact sensing and ideal actuators."""
    return vs.drive_scenario(road, "nominal", sensors=vs.DriveSensors(noise_on=False),
                             actuators=vs.ideal_actuators())


@eqx.filter_jit
def _drive(plant, controller, state0, num_samples):
    return vs.simulate_drive(plant, controller, state0, jax.random.key(0), num_samples, None,
                             substep_poses=True)


def _path(run, state0, h):
    """``(t, x, y)`` of the poses at every integrator step, the start first (JAX)."""
    poses = run.poses.reshape(-1, 2)
    t = state0.t + h * jnp.arange(poses.shape[0] + 1)
    x = jnp.concatenate([state0.car[:1], poses[:, 0]])
    y = jnp.concatenate([state0.car[1:2], poses[:, 1]])
    return t, x, y


def objective(sc: vs.DriveScenario, gate: vs.EndGate, num_samples: int, margin: float = 0.0):
    """``f(z, rho)``: the time at the gate plus the departure penalty of the commands
    ``z`` (num_samples x 3, scaled by the actuators' limits to [-1, 1]), the road narrowed
    by ``margin`` [m] on each side."""
    limit = sc.plant.actuators.limit
    table = eqx.tree_at(lambda t: (t.width_left, t.width_right), sc.table,
                        (sc.table.width_left - margin, sc.table.width_right - margin))
    h = float(sc.plant.actuators.sample_time) / sc.plant.substeps

    def f(z, rho):
        U = z.reshape(num_samples, 3) * limit
        run = vs.simulate_drive(sc.plant, vs.CommandSchedule(U), sc.state0, jax.random.key(0),
                                num_samples, None, substep_poses=True)
        t, x, y = _path(run, sc.state0, h)
        crossed, t_gate, _ = gate.crossing(t, x, y)
        before = (x - gate.point[0]) * gate.tangent[0] + (y - gate.point[1]) * gate.tangent[1]
        d = vs.pose_departures(table, x, y)
        penalty = rho * h * jnp.sum(jnp.where(before < 0.0, d * d, 0.0))
        # not across the gate: the metres still to go, a slope towards it
        short = jnp.where(crossed, 0.0, -jnp.min(jnp.stack([before[-1], 0.0])))
        return t_gate + penalty + short, (t_gate, crossed, penalty)

    return jax.jit(jax.value_and_grad(f, has_aux=True))


def profile(sc: vs.DriveScenario, run, spacing: float = 5.0) -> dict:
    """Where a drive spends its time: its time and speed every ``spacing`` metres of the
    road, and its smallest clearance from the road's edges [m] (negative: off the road)."""
    t, x, y = vs.drive_path(run, sc.state0)
    s, n = sc.road.to_frenet(x, y)
    inside = (s > 0.0) & (s < float(sc.road.length))
    clearance = np.minimum(sc.road.width_left(s) - n, n + sc.road.width_right(s))[inside]
    speed = np.hypot(np.diff(x), np.diff(y)) / np.diff(t)
    at = np.arange(spacing, float(sc.road.length), spacing)
    return dict(time=vs.drive_outcome(sc.road, t, x, y).time,
                min_clearance=float(clearance.min()), arc_length=at.tolist(),
                times=np.round(np.interp(at, s[inside], t[inside]), 4).tolist(),
                speeds=np.round(np.interp(at, s[1:][inside[1:]], speed[inside[1:]]),
                                2).tolist())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--roads", nargs="+", default=["corner90"], choices=ROAD_NAMES)
    ap.add_argument("--penalties", nargs="+", type=float, default=[1e3, 1e4],
                    help="the departure penalty rho [1/m^2], one round each")
    ap.add_argument("--iterations", type=int, default=120,
                    help="L-BFGS-B iterations per round")
    ap.add_argument("--start", choices=("oracle", "bound"), default="oracle",
                    help="the first commands: the oracle's drive, or the free bound's "
                         "open-loop replay (open_loop_schedule)")
    ap.add_argument("--margin", type=float, default=0.0,
                    help="the road narrowed by this much [m] on each side, as the driver's "
                         "corridor margin narrows it")
    ap.add_argument("--extra-samples", type=int, default=6,
                    help="samples driven past the oracle's crossing")
    args = ap.parse_args(argv)
    if args.iterations < 1:
        ap.error(f"--iterations must be >= 1, got {args.iterations}")
    if not 0.0 <= args.margin <= 1.0:
        ap.error(f"--margin must be in [0, 1] m, got {args.margin}")
    if any(p <= 0 for p in args.penalties):
        ap.error(f"--penalties must be > 0, got {args.penalties}")
    for road in args.roads:
        sc = scenario(road)
        bound = vs.offline_bound(sc)[0]
        free = float(bound.t_f)
        driver, _ = vs.scenario_driver(sc, "oracle", **vs.driver_settings(road, "oracle"))
        run = _drive(sc.plant, driver, sc.state0, sc.num_samples)
        oracle = vs.drive_outcome(sc.road, *vs.drive_path(run, sc.state0))
        if oracle.time is None:
            raise SystemExit(f"{road}: the oracle's drive did not cross the end gate")
        T = float(sc.plant.actuators.sample_time)
        n = int(np.ceil(oracle.time / T)) + args.extra_samples
        limit = np.asarray(sc.plant.actuators.limit)
        start = run.commands[:n] if args.start == "oracle" else vs.open_loop_schedule(
            vs.primitive_reference(bound), sc.plant.actuators, n).commands
        z = np.clip(np.asarray(start) / limit, -1.0, 1.0).ravel()
        gate = vs.EndGate.of(sc.road)
        fg = objective(sc, gate, n, args.margin)
        print(json.dumps(dict(road=road, variant="start", start=args.start, free_bound=free,
                              oracle=oracle.record(), samples=n)), flush=True)
        for rho in args.penalties:
            t0 = time.perf_counter()
            calls = [0]

            def fun(zz, rho=rho):
                calls[0] += 1
                (v, (t_gate, _, penalty)), g = fg(jnp.asarray(zz), rho)
                if calls[0] % 20 == 0:  # progress, to stderr
                    print(f"{road} rho={rho:g}: call {calls[0]}, time at the gate "
                          f"{float(t_gate):.4f} s, penalty {float(penalty):.2e}",
                          file=sys.stderr, flush=True)
                return float(v), np.asarray(g, float)

            res = scipy.optimize.minimize(fun, z, jac=True, method="L-BFGS-B",
                                          bounds=[(-1.0, 1.0)] * z.size,
                                          options=dict(maxiter=args.iterations))
            z = res.x
            U = jnp.asarray(z.reshape(n, 3) * limit)
            shot = _drive(sc.plant, vs.CommandSchedule(U), sc.state0, n)
            out = vs.drive_outcome(sc.road, *vs.drive_path(shot, sc.state0))
            (_, (_, _, penalty)), _ = fg(jnp.asarray(z), rho)
            print(json.dumps(dict(
                road=road, variant="shot", start=args.start, margin=args.margin, rho=rho,
                **out.record(),
                objective=float(res.fun), penalty=float(penalty),
                above_free=None if out.time is None else out.time / free - 1.0,
                below_oracle=None if out.time is None else 1.0 - out.time / oracle.time,
                iterations=int(res.nit), calls=calls[0], message=str(res.message),
                wall_s=time.perf_counter() - t0)), flush=True)
        for name, r in (("oracle", run), ("shot", shot)):
            print(json.dumps(dict(road=road, variant="profile", drive=name,
                                  margin=args.margin, **profile(sc, r))), flush=True)
        print(json.dumps(dict(road=road, variant="commands", sample_time=T,
                              commands=np.round(z.reshape(n, 3) * limit, 6).tolist())),
              flush=True)


if __name__ == "__main__":
    main()
