"""Offset-free receding horizon (a probe): the planning model corrected by the plant's
measured disturbance.

Offset-free model-predictive control augments the model with a disturbance estimated from
what the plant does against what the model predicts. Here the disturbance is additive on the
body rates $(\\dot v_x, \\dot v_y, \\dot r)$ of the reduced half car (eqs. 61-63): at each
sample the driver compares the measured accelerations (the IMU's $a_x + rv_y$, $a_y - rv_x$,
and the yaw rate's difference over the sample) with the planning car's rates at the
measured velocities and the slips and steering it last commanded (the default) or the
measured ones (``--inputs measured``: the gravel tire at the plant's small slips reads a
large longitudinal disturbance), low-pass filters the difference with
gain ``beta`` per sample, and plans the whole horizon with ``gain`` times it added to the
planning car's rates (`DisturbedCar`). The drives are the oracle's on the nominal corners
(seed 0), as `closed_loop_gap.py`, at the road's settings and at the margins
``--margins``; one JSON line per drive.

Usage: PYTHONPATH=. python experiments/offset_free.py [--roads corner90] [--betas 0.2]
       [--gains 1.0] [--margins 0.2 0.1 0.0] [--conditions ...]
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


jax.config.update("jax_enable_x64", True)

import vehsim as vs  # noqa: E402
from vehsim.drive.scenarios import ROAD_NAMES  # noqa: E402
from vehsim.optimal.primitives import rally_gravel_car  # noqa: E402


sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from closed_loop_gap import CONDITIONS, _drive, scenario  # noqa: E402


class DisturbedCar(vs.ReducedHalfCar):
    """The reduced half car with `body_disturbance` added to its body rates."""

    body_disturbance: jax.Array = eqx.field(default_factory=lambda: jnp.zeros(3))

    def f(self, state, controls):
        return super().f(state, controls) + jnp.concatenate(
            [jnp.zeros(3), self.body_disturbance])


class OffsetFree(eqx.Module):
    """`driver` (a `RecedingHorizonDriver` on a `DisturbedCar`) with the disturbance
    estimate of the module docstring in its state."""

    driver: vs.RecedingHorizonDriver
    beta: jax.Array
    gain: jax.Array
    measured: jax.Array

    def init(self, m):
        return self.driver.init(m), jnp.zeros(3), m.yaw_rate, m.t

    def command(self, state, m, estimate):
        inner, d, r_prev, t_prev = state
        dt = m.t - t_prev
        car = eqx.tree_at(lambda c: (c.tire.D, c.body_disturbance), self.driver.vehicle,
                          (inner.D[0], jnp.zeros(3)))
        X6 = jnp.stack([0.0 * m.vx, 0.0 * m.vx, 0.0 * m.vx, m.vx, m.vy, m.yaw_rate])
        inputs = jnp.where(self.measured, jnp.concatenate(
            [self.driver.measured_slip(m), m.delta[None]]), inner.inputs)
        model = car.f(X6, inputs)[3:]
        rdot = jnp.where(dt > 0, (m.yaw_rate - r_prev) / jnp.where(dt > 0, dt, 1.0), model[2])
        meas = jnp.stack([m.ax + m.yaw_rate * m.vy, m.ay - m.yaw_rate * m.vx, rdot])
        update = inner.planned & (dt > 0)
        d = jnp.where(update, d + self.beta * (meas - model - d), d)
        driver = eqx.tree_at(lambda dr: dr.vehicle.body_disturbance, self.driver, self.gain * d)
        inner, command = driver.command(inner, m, estimate)
        return (inner, d, m.yaw_rate, m.t), command

    def info(self, state):
        return dict(disturbance=state[1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--roads", nargs="+", default=["corner90"], choices=ROAD_NAMES)
    ap.add_argument("--betas", nargs="+", type=float, default=[0.2])
    ap.add_argument("--gains", nargs="+", type=float, default=[1.0])
    ap.add_argument("--margins", nargs="+", type=float, default=[0.2, 0.1, 0.0])
    ap.add_argument("--conditions", nargs="+", choices=list(CONDITIONS),
                    default=["exact sensing, ideal actuators", "shipped"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--channels", nargs=3, type=float, default=[1.0, 1.0, 1.0],
                    metavar=("VX", "VY", "R"),
                    help="each body rate's share of the correction (1 1 1: all; 0 1 1: "
                         "the lateral and yaw rates only)")
    ap.add_argument("--inputs", choices=("commanded", "measured"), default="commanded",
                    help="the slips and steering of the model's rates: the last command's, "
                         "or the measured ones (wheel speeds, steering angle)")
    args = ap.parse_args(argv)
    base_car = rally_gravel_car()
    car = DisturbedCar(params=base_car.params, tire=base_car.tire)
    for road in args.roads:
        free = float(vs.offline_bound(scenario(road, "shipped"))[0].t_f)
        for condition in args.conditions:
            sc = scenario(road, condition)
            settings = vs.driver_settings(road, "oracle")
            variants = [("the road's settings", settings)] + [
                (f"margin {m:g}", settings | {"margin": m, "margin_grip_power": 0.0})
                for m in args.margins]
            for label, kw in variants:
                driver, _ = vs.scenario_driver(sc, "oracle", **(kw | {"vehicle": car}))
                runs = [(args.betas[0], 0.0)] + [(b, g) for b in args.betas for g in args.gains]
                for beta, gain in runs:
                    ctl = OffsetFree(driver, jnp.asarray(beta),
                                     jnp.asarray(gain) * jnp.asarray(args.channels),
                                     jnp.asarray(args.inputs == "measured"))
                    t0 = time.perf_counter()
                    run = _drive(sc.plant, ctl, sc.state0, jax.random.key(args.seed),
                                 sc.num_samples)
                    jax.block_until_ready(run)
                    out = vs.drive_outcome(sc.road, *vs.drive_path(run, sc.state0)).record()
                    d = run.controller_info["disturbance"]
                    above = None if out["time"] is None else out["time"] / free - 1.0
                    print(json.dumps(dict(
                        road=road, condition=condition, variant=label, beta=beta,
                        gain=gain, channels=args.channels, inputs=args.inputs,
                        seed=args.seed, **out, above_free=above,
                        disturbance_mean=[float(v) for v in jnp.mean(d, 0)],
                        disturbance_absmax=[float(v) for v in jnp.max(jnp.abs(d), 0)],
                        wall_s=time.perf_counter() - t0)), flush=True)


if __name__ == "__main__":
    main()
