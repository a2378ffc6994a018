"""Benchmark: the Table 2 Monte-Carlo grid in one vmapped, jitted call vs NumPy vectorised over runs.

Grid: 8 controllers x 2 systems x 4 missions x N seeds (default 100: 6400 runs), 40 s at
50 Hz with 4 motor sub-steps per sample on the realistic Khepera plant (odometry with wheel
mismatch and link delays, plus white pose noise).

Baseline: the same closed loop in NumPy, vectorised over runs (`numpy_grid`). The runs are
independent, so every quantity of the loop is an array with one element per run and a sample
is a few hundred array operations over all runs, not a Python loop per run. The state arrays
are (system, controller, initial pose): the plant (motor lags, true wheels and wheel base,
encoders, odometry, command and reading delays) steps all runs at once, the chained form and
the velocities are computed one system at a time, and each law over its controller's runs of
both systems, its branches (the sliding and cone sets, zero norms, the polar law of
controller 4, the six Newton steps of controller 8's homogeneous norm) as `np.where` over
those runs. The operations follow the scalar loop below in order, so the final poses are
bit for bit those of the scalar loop. It runs the whole grid (no extrapolation) with the
same plant, controllers, initial poses and noise samples as vehsim: the noise is drawn
beforehand for all runs at once from the same JAX keys (not timed), where vehsim draws its
noise inside the timed call. The headline baseline splits the grid by initial poses over
one process per core, as vehsim's grid is sharded over one host device per core: a pool of
fresh ('spawn') processes that import NumPy and this module but not JAX, started, given the
poses and noise and warmed up before the clock. The same function in this one process is
reported too (`ratio_single_process`).

Side figure, kept comparable with earlier rows: the plain Python loop over one run at a time
(`python_run`, scalar `math` arithmetic), timed on a subset of runs spread over controllers,
systems and missions and extrapolated per run to the full grid (`ratio_scalar_loop`). Before
the baselines are timed, the objects left by JAX's tracing and compiling (about 220 000) are
taken out of the garbage collector's view (`gc.freeze`): the scalar loop allocates many small
objects, and the full collections they trigger would otherwise scan those too, making the
loop 1.4-2.2x slower depending on when one falls (docs/performance.md).

Accuracy: the largest difference of the final poses between the NumPy baseline and vehsim
over all runs, between the pooled and the one-process NumPy results, and of the scalar loop
against both on its subset.

Prints one JSON line; headline key `ratio` = pooled NumPy wall time / vehsim wall time (each
the median of `--repeats` timed calls, vehsim's after the compiling one). On a shared machine
wall times depend on the load, so `ratio_cpu_time` (CPU time: vehsim's process against the
sum over the baseline's workers) and the load average are reported too. The grid runs twice:
on the default device, and sharded over one forced host device per core
(`simulate_robot_grid(..., devices=jax.devices())`); the faster is the headline, both are reported.
Usage: PYTHONPATH=. python experiments/benchmarks/robot_montecarlo.py [--seeds 100] [--subset 24]
    [--repeats 3] [--workers <cores>]
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import multiprocessing as mp
import os
import sys
import time

import numpy as np


# One shard per core: force as many host devices as cores (set before JAX starts), so the
# grid can run sharded with `devices=jax.devices()` beside the single-device call. JAX itself
# is imported in `main`: the NumPy baseline's worker processes import this module without it.
os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={os.cpu_count() or 1}")


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
    from vehsim.robot.khepera import MAX_DELAY

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


# ---------------------------------------------------------------- vectorised NumPy baseline
# The same closed loop over arrays of runs: one array element per run, `np.where` for the
# branches of the laws (both sides evaluated, the one the run takes kept), the operations in
# the scalar loop's order so that the final poses match it to the last bit or so.
def _np_wrap(a):
    return -np.mod(-a + math.pi, 2 * math.pi) + math.pi


def _np_chained(si, x, y, g):
    x, y = x / L, y / L
    if si == 0:
        g = _np_wrap(g)
        c, s = np.cos(g), np.sin(g)
        return x * c + y * s, g, x * s - y * c
    t = np.tan(g)
    return x, t, x * t - y


def _np_to_velocity(si, g, x3, u1, u2):
    if si == 0:
        return L * (u1 + x3 * u2), u2
    c = np.cos(g)
    return L * u1 / c, u2 * c * c


def _np_law(ci, t, x1, x2, x3):
    s = x3 - 0.5 * x1 * x2
    nu2 = x1 * x1 + x2 * x2
    if ci == 0:
        k, mu, eta_bar, ks = 1.0, 3.0, 2.0, 2.0
        sliding = (s * s >= eta_bar**2 * nu2) & (s != 0)
        a = mu * s / nu2
        return (np.where(sliding, ks * np.sign(s), -k * x1 + a * x2),
                np.where(sliding, 0.0, -k * x2 - a * x1))
    if ci == 1:
        k_in, k_out, mu = 1.0, -0.5, 3.0
        zero = nu2 == 0
        nu = np.sqrt(nu2)
        eta = s / nu
        se = np.minimum(1.0, np.maximum(-1.0, eta))
        sign = np.sign(s)
        sat1 = np.where(zero, sign, se * x1 / nu)
        sat2 = np.where(zero, sign, se * x2 / nu)
        outside = zero | (np.abs(eta) >= 1)
        k = np.where(outside & (s != 0), k_out, k_in)
        den = np.sqrt(nu2 + 1)
        return -k * x1 / den + mu * sat2, -k * x2 / den - mu * sat1
    if ci == 2:
        k, k1, c = 1.0, 2.0, 1.0
        z = 2 * s
        cone = nu2 < c * np.abs(z)
        zero = nu2 == 0
        speed = k1 * np.sqrt(np.abs(z))
        r = np.sqrt(nu2)
        alpha = np.where(zero, 0.0, 2 * k * z / nu2)
        return (np.where(cone, np.where(zero, speed, speed * x1 / r), -k * x1 + alpha * x2),
                np.where(cone, np.where(zero, 0.0, speed * x2 / r), -k * x2 - alpha * x1))
    if ci == 4:
        return -x1 + x3 * math.cos(t), -x2 - x3 * x3 * math.sin(t)
    if ci in (5, 7):
        if ci == 5:
            k, a, w = 1.0, 1.0, 1.0
            rho = np.sqrt(np.sqrt(x1**4 + x2**4 + x3**2))
        else:
            k, a, w = 2.0, 2.0, 2.0
            aa, b = nu2, x3 * x3
            r0 = np.sqrt(aa) + np.sqrt(np.sqrt(b))
            r = r0
            for _ in range(6):
                r = r - (r**4 - aa * r * r - b) / (4 * r**3 - 2 * aa * r)
            rho = np.where(r0 != 0, r, 0.0)
        zero = rho == 0
        return (np.where(zero, -k * x1, -k * x1 + a * x3 / rho * math.cos(w * t)),
                np.where(zero, -k * x2, -k * x2 - a * x3 * x3 / rho**3 * math.sin(w * t)))
    if ci == 6:
        c, sn = math.cos(t), math.sin(t)
        p = x1 + x3 * c
        b = p * x1 * c + x2 + x1 * x3
        return -p + x3 * sn, -b
    raise ValueError(ci)


def _np_polar(x, y, g):
    lam, k, h = 1.0, 3.0, 1.5
    e2 = x * x + y * y
    zero = e2 == 0
    e = np.where(zero, 0.0, np.sqrt(e2))
    theta = np.where(zero, 0.0, np.arctan2(-y, -x))
    alpha = _np_wrap(theta - g)
    sinc = np.where(np.abs(alpha) < 1e-6, 1 - alpha**2 / 6, np.sin(alpha) / alpha)
    ca = np.cos(alpha)
    return lam * e * ca, k * alpha + lam * ca * sinc * (alpha + h * theta)


def numpy_grid(controllers, pose0, noise, n_steps, substeps=4):
    """The closed loops of `controllers` (indices 0..7) x both systems x all initial poses,
    vectorised over runs: `pose0` (P, 3), `noise` (n_steps, 3, P) the pose noise of each
    initial pose (the same for every controller and system, as in vehsim). Returns the final
    true poses, (len(controllers), 2, P, 3). State arrays are (system, controller, pose):
    the plant steps all runs at once, the chained form and the velocities one system at a
    time, each law its controller's runs of both systems (so every branch is one `np.where`
    over the runs of one law)."""
    T, b, ppm, unit, vmax = 0.02, 0.053, 12000.0, 1 / 120, 127 / 120
    tau = (0.06, 0.09)
    scale, base = (0.9985, 1.0015), 0.053 * 1.02      # true wheels and wheel base
    h = T / substeps
    lag_l, lag_r = -math.expm1(-h / tau[0]), -math.expm1(-h / tau[1])
    # the polar law (3) last: it reads the measured pose, not the chained form
    order = sorted(range(len(controllers)), key=lambda j: controllers[j] == 3)
    ctrl = [controllers[j] for j in order]
    n_chain = sum(c != 3 for c in ctrl)
    shape = (2, len(ctrl), pose0.shape[0])
    px, py, pg = (np.broadcast_to(pose0[:, i], shape).copy() for i in range(3))
    ox, oy, og = px.copy(), py.copy(), pg.copy()     # odometry
    sx, sy, sg = px.copy(), py.copy(), pg.copy()     # the reading seen (read delay 1)
    wl, wr, tl, tr, al, ar = (np.zeros(shape) for _ in range(6))  # wheels, travel, applied
    x1, x2, x3, u1, u2, v, w = (np.empty(shape) for _ in range(7))
    with np.errstate(all="ignore"):   # the branches not taken may divide by zero
        for k in range(n_steps):
            t = k * T
            nk = noise[k]
            mx, my, mg = sx + nk[0], sy + nk[1], sg + nk[2]
            for si in (0, 1):
                x1[si, :n_chain], x2[si, :n_chain], x3[si, :n_chain] = _np_chained(
                    si, mx[si, :n_chain], my[si, :n_chain], mg[si, :n_chain])
            for j, ci in enumerate(ctrl[:n_chain]):
                u1[:, j], u2[:, j] = _np_law(ci, t, x1[:, j], x2[:, j], x3[:, j])
            for si in (0, 1):
                v[si, :n_chain], w[si, :n_chain] = _np_to_velocity(
                    si, mg[si, :n_chain], x3[si, :n_chain], u1[si, :n_chain], u2[si, :n_chain])
            for j in range(n_chain, len(ctrl)):
                v[:, j], w[:, j] = _np_polar(mx[:, j], my[:, j], mg[:, j])
            cl = np.minimum(vmax, np.maximum(-vmax, np.round((v - 0.5 * w * b) / unit) * unit))
            cr = np.minimum(vmax, np.maximum(-vmax, np.round((v + 0.5 * w * b) / unit) * unit))
            before_l, before_r = np.floor(tl * ppm), np.floor(tr * ppm)
            for _ in range(substeps):   # the command of the previous sample (delay 1)
                wl = wl + lag_l * (al - wl)
                wr = wr + lag_r * (ar - wr)
                gl, gr = wl * scale[0], wr * scale[1]
                vv, ww = 0.5 * (gl + gr), (gr - gl) / base
                half = 0.5 * ww * h
                chord = vv * h * np.where(half != 0, np.sin(half) / half, 1.0)
                mid = pg + half
                px = px + chord * np.cos(mid)
                py = py + chord * np.sin(mid)
                pg = pg + 2 * half
                tl = tl + wl * h
                tr = tr + wr * h
            al, ar = cl, cr
            dl = (np.floor(tl * ppm) - before_l) / ppm
            dr = (np.floor(tr * ppm) - before_r) / ppm
            ds, dg = 0.5 * (dl + dr), (dr - dl) / b
            mid = og + 0.5 * dg
            sx, sy, sg = ox, oy, og
            ox = ox + ds * np.cos(mid)
            oy = oy + ds * np.sin(mid)
            og = og + dg
    final = np.stack([px, py, pg], axis=-1).transpose(1, 0, 2, 3)   # (controller, ...)
    out = np.empty_like(final)
    out[order] = final
    return out


# ---------------------------------------------------------------- one process per core
_WORKER = {}


def _pool_init(pose0, noise, barrier):
    """A worker's start: the initial poses and noise of all runs (sent once, before timing)."""
    _WORKER.update(pose0=pose0, noise=noise, barrier=barrier)


def _pool_warm(n_steps):
    """A few samples of every law (NumPy's first calls), then wait for the other workers, so
    that each worker takes one warm-up."""
    numpy_grid(list(range(8)), _WORKER["pose0"][:2], _WORKER["noise"][:, :, :2], n_steps)
    _WORKER["barrier"].wait()
    return os.getpid()


def _pool_chunk(job):
    """A worker's share: all controllers and systems from the initial poses `chunk` (a slice);
    the final poses and the worker's CPU time."""
    chunk, n_steps = job
    c0 = time.process_time()
    final = numpy_grid(list(range(8)), _WORKER["pose0"][chunk], _WORKER["noise"][:, :, chunk],
                       n_steps)
    return final, time.process_time() - c0


def pooled_numpy(pose0, noise, n_steps, workers, repeats):
    """`numpy_grid` over the whole grid split over `workers` processes by initial poses (as
    vehsim's grid is sharded over one device per core): wall times of `repeats` calls, the
    summed CPU times of the workers, and the final poses. The pool is started ('spawn': a
    fresh interpreter that imports NumPy and this module, not JAX), given the poses and
    noise and warmed up before the clock."""
    bounds = np.linspace(0, pose0.shape[0], workers + 1).astype(int)
    jobs = [(slice(a, z), n_steps) for a, z in zip(bounds[:-1], bounds[1:]) if z > a]
    ctx = mp.get_context("spawn")
    with ctx.Pool(workers, initializer=_pool_init,
                  initargs=(pose0, noise, ctx.Barrier(workers))) as pool:
        assert len(set(pool.map(_pool_warm, [3] * workers, chunksize=1))) == workers
        walls, cpus = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            parts = pool.map(_pool_chunk, jobs, chunksize=1)
            walls.append(time.perf_counter() - t0)
            cpus.append(sum(c for _, c in parts))
    final = np.concatenate([f for f, _ in parts], axis=2)
    return walls, cpus, final


# ---------------------------------------------------------------- benchmark
def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--subset", type=int, default=24, help="runs of the scalar loop")
    ap.add_argument("--repeats", type=int, default=3,
                    help="timed calls of vehsim and of the NumPy baseline (median)")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                    help="processes of the pooled NumPy baseline")
    args = ap.parse_args(argv)

    import jax

    jax.config.update("jax_enable_x64", True)

    import jax.numpy as jnp

    from vehsim.reproduce.robot import run_grid
    from vehsim.robot.khepera import realistic_plant
    from vehsim.robot.missions import ROBOT_MISSIONS

    # the realistic plant with white pose noise on its odometry, so the timed call draws noise
    plant = realistic_plant(noise=True)
    n_steps = 2000
    n_m = len(ROBOT_MISSIONS)
    runs = 8 * 2 * n_m * args.seeds

    load_before = os.getloadavg()

    def timed(devices):
        t0 = time.perf_counter()
        run = run_grid(args.seeds, plant=plant, devices=devices)
        jax.block_until_ready(run.final_pose)
        first = time.perf_counter() - t0
        walls, cpus = [], []
        for _ in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            run = run_grid(args.seeds, plant=plant, devices=devices)
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
    ref = np.asarray(run.final_pose)        # (controller, system, pose, 3)

    # Same poses and noise as run_grid (key 0): the noise of initial pose i at sample k is
    # the first three of five normals from fold_in(keys[i], k), times the plant's sigmas.
    # Drawn for all runs at once, beforehand (not timed).
    k_pose, k_noise = jax.random.split(jax.random.PRNGKey(0))
    poses = np.asarray(jnp.concatenate([m.initial_poses(jax.random.fold_in(k_pose, i),
                                                        args.seeds)
                                        for i, m in enumerate(ROBOT_MISSIONS)]))
    keys = jax.random.split(k_noise, poses.shape[0])
    sigma = jnp.stack([plant.noise_position, plant.noise_position, plant.noise_heading])
    draw = jax.jit(jax.vmap(jax.vmap(lambda key, k: jax.random.normal(
        jax.random.fold_in(key, k), (5,), jnp.float64)[:3] * sigma, (None, 0)), (0, None)))
    noise = np.ascontiguousarray(
        np.asarray(draw(keys, jnp.arange(n_steps))).transpose(1, 2, 0))  # (sample, 3, pose)

    gc.collect()
    gc.freeze()  # the baselines' collections scan their own objects only

    # vectorised NumPy, one process
    np_walls, np_cpus = [], []
    for _ in range(args.repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        np_final = numpy_grid(list(range(8)), poses, noise, n_steps)
        np_walls.append(time.perf_counter() - t0)
        np_cpus.append(time.process_time() - c0)
    print(f"NumPy, one process: {np_walls} s (CPU {np_cpus} s)", file=sys.stderr)
    np_err = np.abs(np_final - ref).max()

    # vectorised NumPy, one process per core (the headline baseline)
    pool_walls, pool_cpus, pool_final = pooled_numpy(poses, noise, n_steps, args.workers,
                                                     args.repeats)
    print(f"NumPy, {args.workers} processes: {pool_walls} s (CPU {pool_cpus} s)",
          file=sys.stderr)
    pool_vs_single = np.abs(pool_final - np_final).max()

    # the scalar loop, on a subset of runs spread over controllers, systems and missions
    rng = np.random.default_rng(0)
    subset = [(i % 8, (i // 8) % 2, int(rng.integers(poses.shape[0])))
              for i in range(args.subset)]
    errors, errors_np, t_py, cpu_py = [], [], 0.0, 0.0
    for j, (ci, si, pi) in enumerate(subset):
        run_noise = noise[:, :, pi].tolist()
        t0, c0 = time.perf_counter(), time.process_time()
        final = python_run(ci, si, [float(p) for p in poses[pi]], run_noise, n_steps)
        t_py += time.perf_counter() - t0
        cpu_py += time.process_time() - c0
        errors.append(np.max(np.abs(final - ref[ci, si, pi])))
        errors_np.append(np.max(np.abs(final - np_final[ci, si, pi])))
        print(f"  python run {j + 1}/{len(subset)} ctrl {ci + 1} sys {si + 1}: max |final "
              f"pose diff| {errors[-1]:.2e} to vehsim, {errors_np[-1]:.2e} to NumPy",
              file=sys.stderr)
    per_run = t_py / len(subset)
    scalar = per_run * runs
    scalar_cpu = cpu_py / len(subset) * runs
    errors = np.array(errors)

    np_time, np_cpu = float(np.median(np_walls)), float(np.median(np_cpus))
    baseline, baseline_cpu = float(np.median(pool_walls)), float(np.median(pool_cpus))
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
        "baseline": "NumPy vectorised over runs (np.where for the laws' branches), all runs, "
                    f"split by initial poses over {args.workers} processes (a spawned pool, "
                    "started, given the poses and noise and warmed before the clock); its "
                    "noise is drawn beforehand (not timed), vehsim draws its noise inside the "
                    "timed call; median of the timed calls",
        "baseline_workers": args.workers,
        "baseline_wall_s": round(baseline, 3),
        "baseline_wall_s_all_timed_calls": [round(w, 3) for w in pool_walls],
        "baseline_cpu_s": round(baseline_cpu, 3),
        "baseline_runs_per_s": round(runs / baseline, 1),
        "baseline_wall_s_single_process": round(np_time, 3),
        "baseline_wall_s_single_process_all_timed_calls": [round(w, 3) for w in np_walls],
        "baseline_cpu_s_single_process": round(np_cpu, 3),
        "scalar_loop": "plain Python loop (math scalars), one run at a time in one process, "
                       "timed on a subset and extrapolated per run to the full grid; the "
                       "objects of JAX's tracing frozen out of the garbage collector's view "
                       "before it is timed",
        "scalar_loop_subset_runs": len(subset),
        "scalar_loop_wall_s_per_run": round(per_run, 4),
        "scalar_loop_wall_s_extrapolated": round(scalar, 1),
        "scalar_loop_cpu_s_extrapolated": round(scalar_cpu, 1),
        "ratio": round(baseline / vehsim_time, 2),
        "ratio_single_device": round(baseline / single_time, 2),
        "ratio_single_process": round(np_time / vehsim_time, 2),
        "ratio_single_process_vs_single_device": round(np_time / single_time, 2),
        "ratio_scalar_loop": round(scalar / vehsim_time, 1),
        "ratio_scalar_loop_single_device": round(scalar / single_time, 1),
        "ratio_cpu_time": round(baseline_cpu / vehsim_cpu, 2),
        "ratio_cpu_time_scalar_loop": round(scalar_cpu / vehsim_cpu, 1),
        "load_average_1min_before_after": [round(load_before[0], 2),
                                           round(os.getloadavg()[0], 2)],
        "cpu_count": os.cpu_count(),
        "accuracy_max_final_pose_diff": float(np_err),
        "accuracy_max_final_pose_diff_pooled_vs_single_process": float(pool_vs_single),
        "accuracy_max_final_pose_diff_scalar_loop_subset": float(errors.max()),
        "accuracy_median_final_pose_diff_scalar_loop_subset": float(np.median(errors)),
        "accuracy_max_final_pose_diff_scalar_loop_vs_numpy_subset": float(max(errors_np)),
        "device": str(jax.devices()[0]),
        "dtype": "float64",
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
