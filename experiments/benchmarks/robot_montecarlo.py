"""Benchmark: the Table 2 Monte-Carlo grid in one vmapped, jitted call vs a plain Python loop.

Grid: 8 controllers x 2 systems x 4 missions x N seeds (default 100: 6400 runs), 40 s at
50 Hz with 4 motor sub-steps per sample on the realistic Khepera plant (odometry with wheel
mismatch and link delays, plus white pose noise).

Baseline: the same closed loop written as a plain Python loop over runs and samples
(scalar `math` arithmetic, which is faster than NumPy for 3-vectors), with the same
plant, controllers and the same noise samples (drawn beforehand from the same JAX keys, not
timed). It is timed on a subset of runs spread over controllers, systems and missions, and
extrapolated per run to the full grid (stated in the JSON). Accuracy: the largest
difference of the final poses between the two on that subset. Before the baseline is timed,
the objects left by JAX's tracing and compiling (about 220 000) are taken out of the
garbage collector's view (`gc.freeze`): the baseline allocates many small objects, and the
full collections they trigger would otherwise scan those too, making the loop 1.4-2.2x
slower depending on when one falls (docs/performance.md).

Prints JSON lines; headline key `ratio` = baseline wall time / vehsim wall time (median of
`--repeats` timed calls after the compiling one). On a shared machine wall times depend on
the load (XLA's thread pool suffers more from it than the single-threaded baseline), so
`ratio_cpu_time` (process CPU time, both sides) and the load average are reported too.
The grid runs twice: on the default device, and sharded over one forced host device per core
(`simulate_robot_grid(..., devices=jax.devices())`); the faster is the headline, both are reported.
Usage: PYTHONPATH=. python experiments/benchmarks/robot_montecarlo.py [--seeds 100] [--subset 24]
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import sys
import time


# One shard per core: force as many host devices as cores (set before JAX starts), so the
# grid can run sharded with `devices=jax.devices()` beside the single-device call.
os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={os.cpu_count() or 1}")

import jax  # noqa: E402


jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from vehsim.reproduce.robot import run_grid  # noqa: E402
from vehsim.robot.khepera import MAX_DELAY, realistic_plant  # noqa: E402
from vehsim.robot.missions import ROBOT_MISSIONS  # noqa: E402


#: The realistic plant with white pose noise on its odometry, so the timed call draws noise.
PLANT = realistic_plant(noise=True)

# ---------------------------------------------------------------- plain Python baseline
L = 0.1  # chained length scale of SystemI/SystemII defaults


def _wrap(a):
    return -((-a + math.pi) % (2 * math.pi)) + math.pi


def _sign(a):
    return float(a > 0) - float(a < 0)


def _chained(sys, x, y, g):
    x, y = x / L, y / L
    if sys == 0:
        g = _wrap(g)
        c, s = math.cos(g), math.sin(g)
        return x * c + y * s, g, x * s - y * c
    t = math.tan(g)
    return x, t, x * t - y


def _to_velocity(sys, pose, x, u1, u2):
    if sys == 0:
        return L * (u1 + x[2] * u2), u2
    c = math.cos(pose[2])
    return L * u1 / c, u2 * c * c


def _law(ci, t, x):
    x1, x2, x3 = x
    s = x3 - 0.5 * x1 * x2
    nu2 = x1 * x1 + x2 * x2
    if ci == 0:
        k, mu, eta_bar, ks = 1.0, 3.0, 2.0, 2.0
        if s * s >= eta_bar**2 * nu2 and s != 0:
            return ks * _sign(s), 0.0
        a = mu * s / nu2
        return -k * x1 + a * x2, -k * x2 - a * x1
    if ci == 1:
        k_in, k_out, mu = 1.0, -0.5, 3.0
        if nu2 == 0:
            sat1 = sat2 = _sign(s)
            outside = True
        else:
            nu = math.sqrt(nu2)
            eta = s / nu
            se = max(-1.0, min(1.0, eta))
            sat1, sat2 = se * x1 / nu, se * x2 / nu
            outside = abs(eta) >= 1
        k = k_out if (outside and s != 0) else k_in
        den = math.sqrt(nu2 + 1)
        return -k * x1 / den + mu * sat2, -k * x2 / den - mu * sat1
    if ci == 2:
        k, k1, c = 1.0, 2.0, 1.0
        z = 2 * s
        if nu2 < c * abs(z):
            speed = k1 * math.sqrt(abs(z))
            if nu2 == 0:
                return speed, 0.0
            r = math.sqrt(nu2)
            return speed * x1 / r, speed * x2 / r
        alpha = 2 * k * z / nu2 if nu2 != 0 else 0.0
        return -k * x1 + alpha * x2, -k * x2 - alpha * x1
    if ci == 4:
        return -x1 + x3 * math.cos(t), -x2 - x3 * x3 * math.sin(t)
    if ci in (5, 7):
        if ci == 5:
            k, a, w = 1.0, 1.0, 1.0
            rho = math.sqrt(math.sqrt(x1**4 + x2**4 + x3**2))
        else:
            k, a, w = 2.0, 2.0, 2.0
            aa, b = nu2, x3 * x3
            r = math.sqrt(aa) + math.sqrt(math.sqrt(b))
            rho = 0.0
            if r != 0:
                for _ in range(6):
                    r = r - (r**4 - aa * r * r - b) / (4 * r**3 - 2 * aa * r)
                rho = r
        if rho == 0:
            return -k * x1, -k * x2
        return (-k * x1 + a * x3 / rho * math.cos(w * t),
                -k * x2 - a * x3 * x3 / rho**3 * math.sin(w * t))
    if ci == 6:
        c, sn = math.cos(t), math.sin(t)
        p = x1 + x3 * c
        b = p * x1 * c + x2 + x1 * x3
        return -p + x3 * sn, -b
    raise ValueError(ci)


def _polar(x, y, g):
    lam, k, h = 1.0, 3.0, 1.5
    e2 = x * x + y * y
    if e2 == 0:
        e, theta = 0.0, 0.0
    else:
        e, theta = math.sqrt(e2), math.atan2(-y, -x)
    alpha = _wrap(theta - g)
    sinc = 1 - alpha**2 / 6 if abs(alpha) < 1e-6 else math.sin(alpha) / alpha
    return lam * e * math.cos(alpha), k * alpha + lam * math.cos(alpha) * sinc * (
        alpha + h * theta)


def python_run(ci, si, pose0, noise, n_steps, substeps=4):
    """One closed loop, plain Python: same model as vehsim.robot.khepera (its default
    effects, plus the pose noise given in `noise`)."""
    T, b, ppm, unit, vmax = 0.02, 0.053, 12000.0, 1 / 120, 127 / 120
    tau = (0.06, 0.09)
    delay, read_delay = 1, 1
    scale, base = (0.9985, 1.0015), 0.053 * 1.02      # true wheels and wheel base
    h = T / substeps
    lag = [-math.expm1(-h / tau[0]), -math.expm1(-h / tau[1])]
    pose = list(pose0)
    odo = list(pose0)
    readings = [list(pose0) for _ in range(read_delay + 1)]   # newest first
    wheels = [0.0, 0.0]
    travel = [0.0, 0.0]
    buffer = [[0.0, 0.0] for _ in range(MAX_DELAY + 1)]
    for k in range(n_steps):
        t = k * T
        nk, seen = noise[k], readings[read_delay]
        meas = [seen[0] + nk[0], seen[1] + nk[1], seen[2] + nk[2]]
        if ci == 3:
            v, w = _polar(*meas)
        else:
            x = _chained(si, *meas)
            u1, u2 = _law(ci, t, x)
            v, w = _to_velocity(si, meas, x, u1, u2)
        cmd = [v - 0.5 * w * b, v + 0.5 * w * b]
        cmd = [min(vmax, max(-vmax, round(c / unit) * unit)) for c in cmd]
        buffer = [cmd] + buffer[:-1]
        applied = buffer[delay]
        before = [math.floor(travel[0] * ppm), math.floor(travel[1] * ppm)]
        for _ in range(substeps):
            wheels = [wheels[i] + lag[i] * (applied[i] - wheels[i]) for i in range(2)]
            gl, gr = wheels[0] * scale[0], wheels[1] * scale[1]
            vv, ww = 0.5 * (gl + gr), (gr - gl) / base
            half = 0.5 * ww * h
            chord = vv * h * (math.sin(half) / half if half != 0 else 1.0)
            mid = pose[2] + half
            pose = [pose[0] + chord * math.cos(mid), pose[1] + chord * math.sin(mid),
                    pose[2] + 2 * half]
            travel = [travel[0] + wheels[0] * h, travel[1] + wheels[1] * h]
        d = [(math.floor(travel[i] * ppm) - before[i]) / ppm for i in range(2)]
        ds, dg = 0.5 * (d[0] + d[1]), (d[1] - d[0]) / b
        mid = odo[2] + 0.5 * dg
        odo = [odo[0] + ds * math.cos(mid), odo[1] + ds * math.sin(mid), odo[2] + dg]
        readings = [list(odo)] + readings[:-1]
    return np.array(pose)


# ---------------------------------------------------------------- benchmark
def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--subset", type=int, default=24)
    ap.add_argument("--repeats", type=int, default=3, help="timed vehsim calls (median)")
    args = ap.parse_args(argv)
    n_steps = 2000
    n_m = len(ROBOT_MISSIONS)
    runs = 8 * 2 * n_m * args.seeds

    load_before = os.getloadavg()

    def timed(devices):
        t0 = time.perf_counter()
        run = run_grid(args.seeds, plant=PLANT, devices=devices)
        jax.block_until_ready(run.final_pose)
        first = time.perf_counter() - t0
        walls, cpus = [], []
        for _ in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            run = run_grid(args.seeds, plant=PLANT, devices=devices)
            jax.block_until_ready(run.final_pose)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
        print(f"vehsim grid on {len(devices) if devices else 1} device(s): first call "
              f"{first:.1f} s, timed calls {walls} s (CPU {cpus} s)", file=sys.stderr)
        return run, first, walls, cpus

    single = timed(None)
    sharded = timed(jax.devices()) if jax.device_count() > 1 else single
    # headline: the faster way to run the grid on this machine
    run, first, walls, cpus = min((single, sharded), key=lambda r: np.median(r[2]))
    vehsim_time, vehsim_cpu = float(np.median(walls)), float(np.median(cpus))
    single_time = float(np.median(single[2]))
    sharded_diff = float(jnp.max(jnp.abs(sharded[0].final_pose - single[0].final_pose)))

    # Same poses and noise as run_grid (key 0).
    k_pose, k_noise = jax.random.split(jax.random.PRNGKey(0))
    poses = np.asarray(jnp.concatenate([m.initial_poses(jax.random.fold_in(k_pose, i),
                                                        args.seeds)
                                        for i, m in enumerate(ROBOT_MISSIONS)]))
    keys = jax.random.split(k_noise, poses.shape[0])
    sigma = jnp.stack([PLANT.noise_position, PLANT.noise_position, PLANT.noise_heading])

    gc.collect()
    gc.freeze()  # the baseline's collections scan its own objects only
    rng = np.random.default_rng(0)
    subset = [(i % 8, (i // 8) % 2, int(rng.integers(poses.shape[0])))
              for i in range(args.subset)]
    errors, t_py, cpu_py = [], 0.0, 0.0
    for j, (ci, si, pi) in enumerate(subset):
        noise = np.asarray(jax.vmap(lambda k: jax.random.normal(
            jax.random.fold_in(keys[pi], k), (5,), jnp.float64)[:3] * sigma)(
                jnp.arange(n_steps)))
        t0, c0 = time.perf_counter(), time.process_time()
        final = python_run(ci, si, [float(p) for p in poses[pi]], noise.tolist(), n_steps)
        t_py += time.perf_counter() - t0
        cpu_py += time.process_time() - c0
        ref = np.asarray(run.final_pose[ci, si, pi])
        err = np.max(np.abs(final - ref))
        errors.append(err)
        print(f"  python run {j + 1}/{len(subset)} ctrl {ci + 1} sys {si + 1}: "
              f"max |final pose diff| {err:.2e}", file=sys.stderr)
    per_run = t_py / len(subset)
    baseline = per_run * runs
    baseline_cpu = cpu_py / len(subset) * runs
    errors = np.array(errors)
    result = {
        "benchmark": "robot_montecarlo",
        "grid": {"controllers": 8, "systems": 2, "missions": n_m, "seeds": args.seeds,
                 "runs": runs, "t_final_s": 40.0, "rate_hz": 50, "substeps": 4},
        "vehsim_wall_s": round(vehsim_time, 3),
        "vehsim_wall_s_all_timed_calls": [round(w, 3) for w in walls],
        "vehsim_cpu_s": round(vehsim_cpu, 3),
        "vehsim_compile_and_first_call_s": round(first, 2),
        "vehsim_runs_per_s": round(runs / vehsim_time, 1),
        "vehsim_devices": len(jax.devices()) if run is sharded[0] and sharded is not single else 1,
        "vehsim_wall_s_single_device": round(single_time, 3),
        "sharded_vs_single_max_final_pose_diff": sharded_diff,
        "baseline": "plain Python loop (math scalars), timed on a subset and extrapolated "
                    "per run to the full grid; its noise is drawn beforehand (not timed), "
                    "vehsim draws its noise inside the timed call; the objects of JAX's "
                    "tracing frozen out of the garbage collector's view before it is timed",
        "baseline_subset_runs": len(subset),
        "baseline_wall_s_per_run": round(per_run, 4),
        "baseline_wall_s_extrapolated": round(baseline, 1),
        "baseline_cpu_s_extrapolated": round(baseline_cpu, 1),
        "baseline_runs_per_s": round(1 / per_run, 2),
        "ratio": round(baseline / vehsim_time, 1),
        "ratio_single_device": round(baseline / single_time, 1),
        "ratio_cpu_time": round(baseline_cpu / vehsim_cpu, 1),
        "load_average_1min_before_after": [round(load_before[0], 2),
                                           round(os.getloadavg()[0], 2)],
        "cpu_count": os.cpu_count(),
        "accuracy_max_final_pose_diff_subset": float(errors.max()),
        "accuracy_median_final_pose_diff_subset": float(np.median(errors)),
        "device": str(jax.devices()[0]),
        "dtype": "float64",
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
