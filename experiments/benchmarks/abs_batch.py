"""Benchmark: 4096 closed-loop brakings in one jitted call against a NumPy/SciPy loop.

Grid: 8 surfaces (the Burckhardt family and three of the CDC 1999 set) x 4 initial speeds
(15-30 m/s) x 5 controllers (locked wheel, rule-based ABS, fixed-slip and estimate-based
slip tracking, peak seeking) x 32 noise seeds = 5120 brakings of 3 s at the controller's 200 Hz, with the
realistic hardware (actuator delay, rate limit and lag, tone-wheel edge timing, speed noise)
and the adaptive-theta observer running in every braking. vehsim:
`vehsim.control.loop.simulate_braking_grid`, one jitted call (8 fixed ROS34PW2 steps per
sample for the plant and for each of the observer's two model copies).

Baseline: the same model written for NumPy/SciPy, one braking at a time (the closed loop
is sequential in time): per sample the plant, the observer's copy and its displaced copy
integrated by `scipy.integrate.solve_ivp` (LSODA, the fastest of LSODA, Radau and BDF on
this problem) at rtol 1e-8, atol 1e-10, with scalar `math` vector fields (faster than NumPy
for six states); the peak search's 64-point grid vectorised in NumPy. Its speed noise is the
same samples as vehsim's, drawn beforehand from the same keys (not timed). It is timed on a
subset of brakings spread over the grid and extrapolated per braking to the full grid (a
full run would take hours); the subset draws from the four controllers it implements
(`BASELINE_CONTROLLERS`; the peak-seeking law costs what fixed-slip tracking does beside
the three integrations per sample, and its runs are counted at the subset's mean cost).
Accuracy: on that subset, the largest differences of the final speed and distance between
the two, and of the stopping distance where both stopped.

The shape-free estimator: the controllers that read an estimator's belief
(`PEAK_CONTROLLERS`: estimate-based slip tracking and peak seeking) on the same runs with the
`PeakEstimator` instead of the observer, one more jitted call (its wall time, median of
`--repeats`, and its runs beside the headline's; not in `ratio`, whose baseline implements
the observer only).

The mismatch rows: every controller on the tires of other shapes (`OTHER_TIRES`, or
`--tires`) from 30 m/s to the stop (`mismatch_table`, one grid per tire structure and
horizon) with the observer built for dry asphalt, and the `PEAK_CONTROLLERS` with the
`PeakEstimator`; each its wall time including compilation, and each cell's distance over
the limit on the hardware.

Prints one JSON line; headline `ratio` = baseline wall time / vehsim wall time (median of
`--repeats` timed calls after the compiling one).
Usage: PYTHONPATH=. python experiments/benchmarks/abs_batch.py [--seeds 32] [--subset 16]
[--repeats 3] [--tires mf_sharp ...]  (smallest check: --seeds 1 --subset 1 --repeats 1
--tires mf_sharp)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import jax


jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from scipy.integrate import solve_ivp  # noqa: E402

from vehsim.control.estimation.peak_estimator import PeakEstimator  # noqa: E402
from vehsim.control.experiments.mismatch import mismatch_table  # noqa: E402
from vehsim.control.experiments.scenarios import (  # noqa: E402
    CONTROLLERS,
    braking_scenario,
    controller,
)
from vehsim.control.experiments.tires import OTHER_TIRES, other_tire  # noqa: E402
from vehsim.control.loop import simulate_braking_grid, stack  # noqa: E402
from vehsim.control.plant.hardware import realistic_hardware  # noqa: E402


SURFACES = ("dry_asphalt", "wet_asphalt", "cobblestone", "snow", "ice", "cdc1999_1",
            "cdc1999_0.6", "cdc1999_0.4")
SPEEDS = (15.0, 20.0, 25.0, 30.0)
DURATION = 3.0
BASELINE_CONTROLLERS = ("locked", "rule", "fixed", "estimate")
"""The controllers the NumPy/SciPy baseline implements."""
RTOL, ATOL = 1e-8, 1e-10
PEAK_CONTROLLERS = ("estimate", "seek")
"""The controllers run with the `PeakEstimator` as well (those that read the belief's peak)."""


def members(seeds: int):
    """The grid's runs per controller: (surface, speed, seed index), surface fastest."""
    return [(s, v, k) for k in range(seeds) for v in SPEEDS for s in SURFACES]


# ------------------------------------------------------------------ the NumPy/SciPy model
def tire_values(p):
    return {k: float(getattr(p, k)) for k in ("sigma0", "sigma1", "sigma2", "mu_c", "mu_s",
                                              "v_s", "alpha", "theta", "L")}


def stribeck(p, vr):
    return p["mu_c"] + (p["mu_s"] - p["mu_c"]) * math.exp(-abs(vr / p["v_s"]) ** p["alpha"])


def psi(x):
    if x < 1e-3:
        return 0.5 - x / 6.0 + x * x / 24.0 - x ** 3 / 120.0
    return (x + math.expm1(-x)) / (x * x)


def decay(p, v, omega, r):
    vr, c = r * omega - v, abs(omega * r)
    sliding = p["theta"] * p["sigma0"] * abs(vr) / stribeck(p, vr)
    if c > 0:
        return c / (p["L"] * psi(sliding * p["L"] / c))
    return sliding


def car_rates(p, car, v, omega, z, torque):
    """(dv, domega, dz) of the quarter car with the lumped tire (eq. 22-23)."""
    r = car["r"]
    vr = r * omega - v
    zdot = vr - decay(p, v, omega, r) * z
    mu = p["sigma0"] * z + p["sigma1"] * zdot + p["sigma2"] * vr
    F = mu * car["Fn"]
    return F / car["m"], (-r * F - torque * math.tanh(omega / car["eps"])) / car["J"], zdot


def braking_mu(p, s, v):
    """Eq. 19 (the braking steady state), NumPy arrays or scalars."""
    s = np.asarray(s, dtype=float)
    vr = v * s
    g = p["mu_c"] + (p["mu_s"] - p["mu_c"]) * np.exp(-np.abs(vr / p["v_s"]) ** p["alpha"])
    one_s = np.abs(1.0 + s)
    safe = np.where(one_s == 0, 1.0, one_s)
    x = p["theta"] * p["sigma0"] * p["L"] * np.abs(s) / (g * safe)
    small = x < 1e-3
    xs = np.where(small, 1.0, x)
    ps = np.where(small, 0.5 - x / 6 + x * x / 24 - x ** 3 / 120, (xs + np.expm1(-xs)) / (xs * xs))
    rolling = p["sigma0"] * p["L"] * s / safe * ps
    return np.where(one_s == 0, np.sign(s) * g / p["theta"], rolling) + p["sigma2"] * vr


def peak_braking(p, v):
    """Slip and |mu| of the peak of eq. 19 (grid of 64, golden section, as vehsim)."""
    u = np.linspace(0.0, 1.0, 64)
    grid = u * u
    i = int(np.argmax(-braking_mu(p, -grid, v)))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, 63)]
    q = 0.5 * (5.0 ** 0.5 - 1.0)
    for _ in range(40):
        c, d = b - q * (b - a), a + q * (b - a)
        if -float(braking_mu(p, -c, v)) >= -float(braking_mu(p, -d, v)):
            b = d
        else:
            a = c
    lam = 0.5 * (a + b)
    return -lam, -float(braking_mu(p, -lam, v))


def hermite(tau, T, p0, p1, d0, d1):
    t2, t3 = tau * tau, tau ** 3
    return ((2 * t3 - 3 * t2 + 1) * p0 + (t3 - 2 * t2 + tau) * T * d0
            + (3 * t2 - 2 * t3) * p1 + (t3 - t2) * T * d1)


def hermite_rate(tau, T, p0, p1, d0, d1):
    t2 = tau * tau
    return ((6 * t2 - 6 * tau) * p0 + (3 * t2 - 4 * tau + 1) * T * d0
            + (6 * tau - 6 * t2) * p1 + (3 * t2 - 2 * tau) * T * d1) / T


def brake(hw, torque0, target, t):
    return target + (torque0 - target) * math.exp(-t / hw["tau"])


def integrate(rates, y0, t0, T):
    sol = solve_ivp(rates, (t0, t0 + T), y0, method="LSODA", rtol=RTOL, atol=ATOL)
    return sol.y[:, -1]


class NumpyBraking:
    """One closed-loop braking of the vehsim model, sample by sample (see the module
    docstring); `run()` returns (final speed, final distance, stopping distance)."""

    def __init__(self, scenario, observer, ctrl, ctrl_name, hw, noise):
        self.p = tire_values(scenario.car.tire.params)
        model = observer.model  # a RoadCondition of the LuGre tire, or its LuGreParams
        self.pm = tire_values(getattr(getattr(model, "tire", None), "params", model))
        c = scenario.car
        self.car = dict(m=float(c.mass), J=float(c.inertia), r=float(c.radius),
                        Fn=float(c.Fn_static), eps=float(c.omega_eps))
        self.hw = dict(T=float(hw.sample_time), tau=float(hw.time_constant),
                       rate=float(hw.torque_rate), Tmax=float(hw.max_torque),
                       d=int(round(float(hw.actuator_delay) / float(hw.sample_time))),
                       delta=2 * math.pi / float(hw.encoder_pulses),
                       sigma=float(hw.speed_noise_std))
        self.ob = {k: float(getattr(observer, k)) for k in (
            "theta_min", "theta_max", "forgetting", "max_covariance", "noise_variance",
            "max_step", "injection", "speed_injection", "change_drift", "change_threshold")}
        self.ob["P0"] = float(observer.initial_covariance)
        self.ctrl, self.name, self.noise = ctrl, ctrl_name, noise
        self.v0 = float(scenario.speed)

    def plant_rates(self, t0, torque0, target):
        p, car, hw = self.p, self.car, self.hw

        def f(t, y):
            dv, dw, dz = car_rates(p, car, y[1], y[2], y[3], brake(hw, torque0, target, t - t0))
            return [y[1], dv, dw, dz, y[2]]
        return f

    def copy_predict(self, x, t0, torque0, target, stamp):
        pm = dict(self.pm, theta=math.exp(x[3]))
        car, hw = self.car, self.hw

        def f(t, y):
            return list(car_rates(pm, car, y[0], y[1], y[2], brake(hw, torque0, target, t - t0)))

        y0 = [x[2], x[0], x[1]]
        y1 = integrate(f, y0, t0, hw["T"])
        r0, r1 = f(t0, y0), f(t0 + hw["T"], y1)
        tau = min(max((stamp - t0) / hw["T"], 0.0), 1.0)
        return np.array([hermite(tau, hw["T"], y0[1], y1[1], r0[1], r1[1]), y1[1], y1[2], y1[0]])

    def observe(self, o, v_m, omega_m, stamp, fresh, t0, torque0, target):
        ob = self.ob
        x = np.array([o["omega"], o["z"], o["v"], o["log_theta"]])
        d = np.append(o["s"], 1.0)
        mid = self.copy_predict(x, t0, torque0, target, stamp)
        der = (self.copy_predict(x + 1e-6 * d, t0, torque0, target, stamp) - mid) / 1e-6
        e = omega_m - mid[0] if fresh else 0.0
        P, phi = o["P"], der[0]
        nis = e * e / (ob["noise_variance"] + phi * phi * P)
        g = max(o["g"] + (nis - ob["change_drift"] if fresh else 0.0), 0.0)
        if g > ob["change_threshold"]:  # a change of road: covariance reset
            P, g = max(P, ob["P0"]), 0.0
        K = P * phi / (ob["noise_variance"] + phi * phi * P) if fresh else 0.0
        full = K * e
        step = min(max(full, -ob["max_step"]), ob["max_step"])
        taken = 1.0 if full == 0 else step / full
        lt = min(max(o["log_theta"] + step, math.log(ob["theta_min"])), math.log(ob["theta_max"]))
        P = min((1.0 - taken * K * phi) * P / ob["forgetting"], ob["max_covariance"])
        L = ob["injection"] if fresh else 0.0
        omega = mid[1] + L * e if fresh else min(mid[1], omega_m)
        v = mid[3] + ob["speed_injection"] * (v_m - mid[3])
        s = np.array([(1 - L) * der[1], der[2], (1 - ob["speed_injection"]) * der[3]])
        return dict(z=mid[2], omega=omega, v=v, log_theta=lt, P=P, s=s, g=g)

    def rule(self, st, slip, accel):
        c, T = self.ctrl, self.hw["T"]
        phase, torque, a, ref = st
        a = a + (accel - a) * (1.0 - math.exp(-T / float(c.filter_time)))
        lam, dec = -slip, float(c.decel_threshold)
        if phase == 0:
            new = 1 if a < -dec else 0
        elif phase == 1:
            new = 2 if lam > float(c.slip_threshold) else (
                5 if (a > -dec and a < float(c.accel_threshold)) else 1)
        elif phase == 2:
            new = 3 if a > -dec else 2
        elif phase == 3:
            new = 4 if (a < float(c.accel_threshold) or lam < 0.5 * float(c.slip_threshold)) \
                else 3
        elif phase == 4:
            new = 5 if torque >= float(c.rebuild_fraction) * ref else 4
        else:
            new = 2 if a < -dec else 5
        if lam > float(c.lock_slip):
            new = 2
        if new == 2 and phase != 2:
            ref = torque
        rate = {0: float(c.build_rate), 4: float(c.build_rate), 5: float(c.slow_rate),
                2: -float(c.dump_rate)}.get(new, 0.0)
        torque = min(max(torque + rate * T, 0.0), self.hw["Tmax"])
        return (new, torque, a, ref), torque

    def tracking(self, integral, omega_m, v_hat, theta):
        c, car, hw = self.ctrl, self.car, self.hw
        pm = dict(self.pm, theta=theta)
        v = max(v_hat, 0.5)
        if self.name == "estimate":
            s = min(max(float(c.slip_scale) * peak_braking(pm, v)[0], -1.0), -1e-3)
        else:
            s = float(c.slip)
        mu = -float(braking_mu(pm, s, v))
        r = car["r"]
        ff = mu * car["Fn"] * (r + car["J"] * (1.0 + s) / (car["m"] * r))
        eps = r * omega_m - (1.0 + s) * v_hat
        e = math.tanh(eps) if eps > 0 else eps
        integral = min(max(integral + float(c.ki) * e * hw["T"], -ff), hw["Tmax"] - ff)
        return integral, min(max(ff + integral + float(c.kp) * e, 0.0), hw["Tmax"])

    def command(self, st, omega_m, omega_prev, v_hat, theta):
        r, T = self.car["r"], self.hw["T"]
        slip = min(max((r * omega_m / v_hat if v_hat != 0 else 1.0) - 1.0, -1.0), 1.0)
        if self.name == "locked":
            return st, self.hw["Tmax"]
        if self.name == "rule":
            return self.rule(st, slip, r * (omega_m - omega_prev) / T)
        return self.tracking(st, omega_m, v_hat, theta)

    def edges(self, enc, t0, y0, y1):
        delta, T = self.hw["delta"], self.hw["T"]
        phi0, phi1, w0, w1 = y0[4], y1[4], y0[2], y1[2]
        n1 = math.floor(phi1 / delta)

        def time_of(n):
            target = n * delta
            tau = min(max((target - phi0) / (phi1 - phi0), 0.0), 1.0) if phi1 != phi0 else 0.0
            for _ in range(3):
                rate = T * hermite_rate(tau, T, phi0, phi1, w0, w1)
                res = hermite(tau, T, phi0, phi1, w0, w1) - target
                tau = min(max(tau - (res / rate if rate != 0 else 0.0), 0.0), 1.0)
            return t0 + tau * T

        if n1 > enc["count"]:
            enc["before"] = time_of(n1 - 1.0) if n1 - enc["count"] >= 2 else enc["edge"]
            enc["edge"], enc["count"] = time_of(n1), n1
        return enc

    def wheel_speed(self, enc, t):
        delta = self.hw["delta"]
        fresh = enc["count"] > enc["count_sample"]
        if fresh:
            omega = delta / (enc["edge"] - enc["before"])
            stamp = 0.5 * (enc["edge"] + enc["before"])
        else:
            omega = min(enc["omega"], delta / (t - enc["edge"])) if t > enc["edge"] \
                else enc["omega"]
            stamp = t
        enc["count_sample"], enc["omega"] = enc["count"], omega
        return omega, stamp, fresh

    def run(self):
        hw, car = self.hw, self.car
        T, n = hw["T"], int(round(DURATION / hw["T"]))
        y = np.array([0.0, self.v0, self.v0 / car["r"], 0.0, 0.0])
        enc = dict(count=0.0, count_sample=0.0, edge=0.0, before=-hw["delta"] / y[2],
                   omega=y[2])
        o = dict(z=0.0, omega=y[2], v=y[1], log_theta=math.log(self.pm["theta"]),
                 P=self.ob["P0"], s=np.zeros(3), g=0.0)
        st = (0, 0.0, 0.0, hw["Tmax"]) if self.name == "rule" else 0.0
        buffer, target, torque = [0.0] * 9, 0.0, 0.0
        prev = (y[2], 0.0, 0.0)
        stop = math.inf
        for k in range(n):
            t = k * T
            omega_m, stamp, fresh = self.wheel_speed(enc, t)
            v_m = y[1] + hw["sigma"] * self.noise[k]
            if k > 0:
                o = self.observe(o, v_m, omega_m, stamp, fresh, t - T, prev[1], prev[2])
            st, cmd = self.command(st, omega_m, prev[0], o["v"], math.exp(o["log_theta"]))
            cmd = hw["Tmax"] if o["v"] < 3.0 else cmd
            buffer[k % 9] = min(max(cmd, -hw["Tmax"]), hw["Tmax"])
            delayed = buffer[(k - hw["d"]) % 9]
            target = min(max(delayed, target - hw["rate"] * T), target + hw["rate"] * T)
            prev = (omega_m, torque, target)
            y1 = y
            if y[1] > 0.05:
                y1 = integrate(self.plant_rates(t, torque, target), y, t, T)
                enc = self.edges(enc, t, y, y1)
            torque = brake(hw, torque, target, T)
            if math.isinf(stop) and y[1] >= 1.0 > y1[1]:
                stop = y[0] + (y[1] - 1.0) / (y[1] - y1[1]) * (y1[0] - y[0])
            y = y1
        return y[1], y[0], stop


# ------------------------------------------------------------------ the benchmark
def vehsim_inputs(seeds: int):
    runs = members(seeds)
    pairs = [braking_scenario(s, v) for s, v, _ in runs]
    keys = jax.random.split(jax.random.PRNGKey(0), seeds)
    keys = jnp.stack([keys[k] for _, _, k in runs])
    return stack([p[0] for p in pairs]), stack([p[1] for p in pairs]), keys


def time_vehsim(scenarios, observers, keys, hw, repeats):
    ctrls = [controller(c) for c in CONTROLLERS]

    return _timed(scenarios, ctrls, observers, keys, hw, repeats)


def _timed(scenarios, ctrls, observers, keys, hw, repeats):
    """The grid run once (compile and first call), then `repeats` times: ``(runs, first
    call [s], walls [s], CPU times [s])``."""

    def call():
        out = simulate_braking_grid(scenarios, ctrls, observers, keys, hw, duration=DURATION)
        return jax.block_until_ready(out)

    t0 = time.perf_counter()
    out = call()
    first = time.perf_counter() - t0
    walls, cpus = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        call()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return out, first, walls, cpus


def time_peak_estimator(scenarios, keys, hw, repeats):
    """The `PEAK_CONTROLLERS` on the same runs with the `PeakEstimator`: ``(runs, first
    call [s], median wall [s])``."""
    observers = stack([PeakEstimator()] * keys.shape[0])
    ctrls = [controller(c) for c in PEAK_CONTROLLERS]
    out, first, walls, _ = _timed(scenarios, ctrls, observers, keys, hw, repeats)
    return out, first, float(np.median(walls))


def time_baseline(out, scenarios, observers, keys, hw, subset, seeds):
    runs = members(seeds)
    M, n = len(runs), int(round(DURATION / float(hw.sample_time)))
    rng = np.random.default_rng(0)
    names = list(CONTROLLERS)
    picks = [(names.index(BASELINE_CONTROLLERS[i % len(BASELINE_CONTROLLERS)]),
              int(rng.integers(M))) for i in range(subset)]
    diffs, wall, cpu = [], 0.0, 0.0
    for ci, m in picks:
        name = list(CONTROLLERS)[ci]
        sc, ob = (jax.tree_util.tree_map(lambda a: a[m], x) for x in (scenarios, observers))
        noise = np.asarray(jax.vmap(lambda k: jax.random.normal(
            jax.random.fold_in(keys[m], k), (), jnp.float64))(jnp.arange(n)))
        braking = NumpyBraking(sc, ob, controller(name), name, hw, noise)
        t0, c0 = time.perf_counter(), time.process_time()
        v, x, stop = braking.run()
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
        ref = (float(out.final_speed[ci, m]), float(out.final_distance[ci, m]),
               float(out.stopping_distance[ci, m]))
        d = [abs(v - ref[0]), abs(x - ref[1]),
             abs(stop - ref[2]) if math.isfinite(stop) and math.isfinite(ref[2]) else 0.0]
        diffs.append(d)
        print(f"  baseline {name:8s} {runs[m][0]:12s} {runs[m][1]:4.0f} m/s: |dv| {d[0]:.1e} "
              f"m/s, |dx| {d[1]:.1e} m, |d stop| {d[2]:.1e} m", file=sys.stderr, flush=True)
    return np.array(diffs), wall / subset, cpu / subset, picks


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=32)
    ap.add_argument("--subset", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tires", nargs="+", default=list(OTHER_TIRES), choices=OTHER_TIRES)
    args = ap.parse_args(argv)
    hw = realistic_hardware()
    scenarios, observers, keys = vehsim_inputs(args.seeds)
    n_runs = len(CONTROLLERS) * keys.shape[0]
    load = os.getloadavg()[0]
    out, first, walls, cpus = time_vehsim(scenarios, observers, keys, hw, args.repeats)
    vehsim_wall = float(np.median(walls))
    diffs, per_run, per_run_cpu, picks = time_baseline(out, scenarios, observers, keys, hw,
                                                       args.subset, args.seeds)
    stopped = float(np.mean(np.isfinite(np.asarray(out.stopping_distance))))
    peak_out, peak_first, peak_wall = time_peak_estimator(scenarios, keys, hw, args.repeats)
    peak_over = peak_out.stopping_distance / out.stopping_distance[
        np.array([list(CONTROLLERS).index(c) for c in PEAK_CONTROLLERS])]
    rows = {t: ("dry_asphalt", other_tire(t), None, math.inf) for t in args.tires}
    t0 = time.perf_counter()
    tab = mismatch_table(rows, {c: controller(c) for c in CONTROLLERS}, hw)
    mismatch_wall = time.perf_counter() - t0
    t0 = time.perf_counter()
    peak_tab = mismatch_table(rows, {c: controller(c) for c in PEAK_CONTROLLERS}, hw,
                              estimator=PeakEstimator())
    peak_mismatch_wall = time.perf_counter() - t0
    print(json.dumps({
        "benchmark": "abs_batch",
        "grid": {"surfaces": len(SURFACES), "speeds": len(SPEEDS),
                 "controllers": len(CONTROLLERS), "seeds": args.seeds, "runs": n_runs,
                 "duration_s": DURATION, "rate_hz": 1 / float(hw.sample_time)},
        "vehsim_wall_s": round(vehsim_wall, 3),
        "vehsim_wall_s_all_timed_calls": [round(w, 3) for w in walls],
        "vehsim_cpu_s": round(float(np.median(cpus)), 3),
        "vehsim_compile_and_first_call_s": round(first, 2),
        "baseline": "NumPy/SciPy loop, one braking at a time, solve_ivp (LSODA, rtol 1e-8, "
                    "atol 1e-10) per sample for the plant and the observer's two copies; "
                    "timed on a subset and extrapolated per braking",
        "baseline_subset_runs": len(picks),
        "baseline_wall_s_per_run": round(per_run, 3),
        "baseline_wall_s_extrapolated": round(per_run * n_runs, 1),
        "ratio": round(per_run * n_runs / vehsim_wall, 1),
        "ratio_cpu_time": round(per_run_cpu * n_runs / float(np.median(cpus)), 1),
        "accuracy_max_final_speed_diff_m_s": float(diffs[:, 0].max()),
        "accuracy_max_final_distance_diff_m": float(diffs[:, 1].max()),
        "accuracy_max_stopping_distance_diff_m": float(diffs[:, 2].max()),
        "accuracy_median_final_distance_diff_m": float(np.median(diffs[:, 1])),
        "fraction_stopped_within_3_s": round(stopped, 3),
        "peak_estimator": {
            "controllers": list(PEAK_CONTROLLERS), "runs": len(PEAK_CONTROLLERS) * keys.shape[0],
            "wall_s": round(peak_wall, 3), "compile_and_first_call_s": round(peak_first, 2),
            "stopping_distance_over_observer_median": [
                round(float(np.nanmedian(np.where(np.isfinite(r), r, np.nan))), 4)
                for r in np.asarray(peak_over)]},
        "mismatch": {"tires": tab["rows"], "controllers": tab["controllers"],
                     "distance_over_actuated_bound": np.round(tab["over_actuated"], 4).tolist(),
                     "wall_s_with_compilation": round(mismatch_wall, 1)},
        "mismatch_peak_estimator": {
            "tires": peak_tab["rows"], "controllers": peak_tab["controllers"],
            "distance_over_actuated_bound": np.round(peak_tab["over_actuated"], 4).tolist(),
            "wall_s_with_compilation": round(peak_mismatch_wall, 1)},
        "load_average_1min_before_after": [round(load, 2), round(os.getloadavg()[0], 2)],
        "cpu_count": os.cpu_count(),
        "device": str(jax.devices()[0]),
        "dtype": "float64",
    }))


if __name__ == "__main__":
    main()
