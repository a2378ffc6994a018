"""Benchmark: 5120 closed-loop brakings in one jitted call against a NumPy/SciPy loop.

Grid: 8 surfaces (the Burckhardt family and three of the CDC 1999 set) x 4 initial speeds
(15-30 m/s) x 5 controllers (locked wheel, rule-based ABS, fixed-slip and estimate-based
slip tracking, peak seeking) x 32 noise seeds = 5120 brakings of 3 s at the controller's
200 Hz, with the realistic hardware (actuator delay, rate limit and lag, tone-wheel edge timing, speed noise)
and the adaptive-theta observer running in every braking. vehsim:
`vehsim.control.loop.simulate_braking_grid`, one jitted call (8 fixed ROS34PW2 steps per
sample for the plant and for each of the observer's two model copies).

Baseline (`NumpyBraking`): the same model and all five controllers written for NumPy/SciPy,
one braking at a time (the closed loop is sequential in time). Per sample, two LSODA solves
(the fastest of LSODA, Radau and BDF on this problem) through `scipy.integrate.odeint`,
whose whole step sequence runs in Fortran (`solve_ivp` steps the same LSODA from Python and
takes 1.4-2.3 times as long; the results agree within 3e-5 m): the plant, and the observer's copy
together with its copy displaced by 1e-6 along the sensitivity direction (the forward
difference that gives the adaptation's regressor) as one 6-state system, so that both
copies take the same steps (half the solver calls; the results move by at most 2e-6 m
against two separate solves). rtol 1e-8, atol 1e-10: at 1e-6 and 1e-8 the final distances
move by up to 1e-3 m, more than the baseline's typical difference from vehsim, for a
quarter less time. The vector fields, the controllers and eq. 19 (the belief's
steady-state curve: the feedforward, the peak searches) on Python floats with `math`
(a NumPy call on a scalar costs about 30 times as much); the peak search's 64-point grid in one
NumPy call and its golden section with one new point a step (vehsim evaluates both points
each step; the peak's slip agrees within 3e-7, the curve is flat to rounding there). Its
speed noise is the same samples as vehsim's, drawn beforehand from the same keys (not
timed).

Timing: the baseline runs `--subset` brakings per controller (the j-th on surface j mod 8
at a random speed and seed), each controller's mean time per braking scaled by its number
of runs (their costs differ by up to 3 times, `baseline_wall_s_per_run_by_controller`;
peak seeking, for one, runs two peak searches per sample, the estimate-based tracking one)
and summed (a full run would take about an hour in one process). The headline
figure pools them over `--processes` worker processes (default: one per core; vehsim's call
keeps about 1.5 of 2 cores busy), one braking a task, the pool started and its imports
done before the clock, each braking timed in its worker while the others run; the
extrapolation divides the summed time by the number of processes (a full grid keeps every
process busy). Side figures: the same brakings one after another in the main process
(`ratio_single_process_baseline`) and their CPU time against vehsim's (`ratio_cpu_time`).
The previous baseline (`PreviousNumpyBraking`: `solve_ivp` for each of three solves per
sample, eq. 19 on NumPy scalars, both golden-section points each step, the controller's
fields read as floats at each use, no peak-seeking law, its runs counted at the mean of the
others) on the same brakings of the other four controllers, extrapolated as it was then
(`ratio_previous_baseline`), so that the figures recorded before stay comparable.
Accuracy: on the subset, the largest differences of the final speed and distance between
the baseline and vehsim, and of the stopping distance where both stopped (also per
controller), the number of brakings that stopped in one and not in the other, and the
largest differences between the baseline and the previous one.

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

Prints one JSON line; headline `ratio` = the pooled baseline's extrapolated wall time /
vehsim wall time (median of `--repeats` timed calls after the compiling one).
Usage: PYTHONPATH=. python experiments/benchmarks/abs_batch.py [--seeds 32] [--subset 8]
[--processes N] [--repeats 3] [--tires mf_sharp ...]  (smallest check: --seeds 1
--subset 1 --repeats 1 --tires mf_sharp)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import multiprocessing as mp
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor

import jax


jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from scipy.integrate import odeint, solve_ivp  # noqa: E402

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
PREVIOUS_CONTROLLERS = ("locked", "rule", "fixed", "estimate")
"""The controllers the previous baseline implements (`PreviousNumpyBraking`)."""
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


def floats(module):
    """The fields of a controller or hardware module as Python floats."""
    return {f.name: float(getattr(module, f.name)) for f in dataclasses.fields(module)}


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
    """Eq. 19 (the braking steady state) at slip `s` and speed `v`, on Python floats."""
    vr = v * s
    g = stribeck(p, vr)
    one_s = abs(1.0 + s)
    if one_s == 0:
        return math.copysign(1.0, s) * g / p["theta"] + p["sigma2"] * vr
    x = p["theta"] * p["sigma0"] * p["L"] * abs(s) / (g * one_s)
    return p["sigma0"] * p["L"] * s / one_s * psi(x) + p["sigma2"] * vr


def braking_mu_array(p, s, v):
    """Eq. 19 on NumPy arrays of slips `s` (the peak search's grid in one call)."""
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


PEAK_GRID = np.linspace(0.0, 1.0, 64) ** 2
"""The peak search's braking slips (finer near zero slip, as vehsim's)."""
INVERSE_GOLDEN = 0.5 * (5.0 ** 0.5 - 1.0)


def peak_braking(p, v):
    """Slip and |mu| of the peak of eq. 19: the best of the 64-point grid (one NumPy call),
    then 40 golden-section steps in its neighbouring cells (one new point a step, on
    floats)."""
    def f(lam):
        return -braking_mu(p, -lam, v)

    i = int(np.argmax(-braking_mu_array(p, -PEAK_GRID, v)))
    a, b = float(PEAK_GRID[max(i - 1, 0)]), float(PEAK_GRID[min(i + 1, 63)])
    c, d = b - INVERSE_GOLDEN * (b - a), a + INVERSE_GOLDEN * (b - a)
    fc, fd = f(c), f(d)
    for step in range(40):
        if fc >= fd:
            b, d, fd = d, c, fc
            if step < 39:
                c = b - INVERSE_GOLDEN * (b - a)
                fc = f(c)
        else:
            a, c, fc = c, d, fd
            if step < 39:
                d = a + INVERSE_GOLDEN * (b - a)
                fd = f(d)
    lam = 0.5 * (a + b)
    return -lam, f(lam)


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
    """The state at t0 + T: LSODA through `odeint` (its whole step sequence in Fortran)."""
    return odeint(rates, y0, (t0, t0 + T), rtol=RTOL, atol=ATOL, tfirst=True, mxstep=5000)[-1]


FD_STEP = 1e-6
"""The displacement of the observer's second copy (a forward difference)."""


class NumpyBraking:
    """One closed-loop braking of the vehsim model, sample by sample (see the module
    docstring); plain Python data only (it is sent to worker processes); `run()` returns
    (final speed, final distance, stopping distance)."""

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
        a = self.hw["T"] / self.hw["tau"]
        self.hw["mean_fraction"] = -math.expm1(-a) / a  # mean of the lag over a sample
        self.ob = {k: float(getattr(observer, k)) for k in (
            "theta_min", "theta_max", "forgetting", "max_covariance", "noise_variance",
            "max_step", "injection", "speed_injection", "change_drift", "change_threshold")}
        self.ob["P0"] = float(observer.initial_covariance)
        self.c, self.name, self.noise = floats(ctrl), ctrl_name, np.asarray(noise).tolist()
        self.v0 = float(scenario.speed)

    def plant_rates(self, t0, torque0, target):
        p, car, hw = self.p, self.car, self.hw

        def f(t, y):
            dv, dw, dz = car_rates(p, car, y[1], y[2], y[3], brake(hw, torque0, target, t - t0))
            return [y[1], dv, dw, dz, y[2]]
        return f

    def predict(self, x, d, t0, torque0, target, stamp):
        """The observer's copy from x = (omega, z, v, log theta) over the last sample and the
        copy displaced by FD_STEP d, one 6-state solve: (values, forward differences), each
        (omega at the stamp, omega, z, v at the sample's end)."""
        car, hw, T = self.car, self.hw, self.hw["T"]
        pa = dict(self.pm, theta=math.exp(x[3]))
        pb = dict(self.pm, theta=math.exp(x[3] + FD_STEP * d[3]))

        def f(t, y):
            tb = brake(hw, torque0, target, t - t0)
            return [*car_rates(pa, car, y[0], y[1], y[2], tb),
                    *car_rates(pb, car, y[3], y[4], y[5], tb)]

        y0 = [x[2], x[0], x[1], x[2] + FD_STEP * d[2], x[0] + FD_STEP * d[0],
              x[1] + FD_STEP * d[1]]
        y1 = integrate(f, y0, t0, T)
        r0, r1 = f(t0, y0), f(t0 + T, y1)
        tau = min(max((stamp - t0) / T, 0.0), 1.0)
        a, b = ([hermite(tau, T, y0[i + 1], y1[i + 1], r0[i + 1], r1[i + 1]), y1[i + 1],
                 y1[i + 2], y1[i]] for i in (0, 3))
        return a, [(bj - aj) / FD_STEP for aj, bj in zip(a, b)]

    def observe(self, o, v_m, omega_m, stamp, fresh, t0, torque0, target):
        ob = self.ob
        x = (o["omega"], o["z"], o["v"], o["log_theta"])
        mid, der = self.predict(x, (*o["s"], 1.0), t0, torque0, target, stamp)
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
        s = ((1 - L) * der[1], der[2], (1 - ob["speed_injection"]) * der[3])
        return dict(z=mid[2], omega=omega, v=v, log_theta=lt, P=P, s=s, g=g)

    def rule(self, st, slip, accel):
        c, T = self.c, self.hw["T"]
        phase, torque, a, ref = st
        a = a + (accel - a) * (1.0 - math.exp(-T / c["filter_time"]))
        lam, dec = -slip, c["decel_threshold"]
        if phase == 0:
            new = 1 if a < -dec else 0
        elif phase == 1:
            new = 2 if lam > c["slip_threshold"] else (
                5 if (a > -dec and a < c["accel_threshold"]) else 1)
        elif phase == 2:
            new = 3 if a > -dec else 2
        elif phase == 3:
            new = 4 if (a < c["accel_threshold"] or lam < 0.5 * c["slip_threshold"]) else 3
        elif phase == 4:
            new = 5 if torque >= c["rebuild_fraction"] * ref else 4
        else:
            new = 2 if a < -dec else 5
        if lam > c["lock_slip"]:
            new = 2
        if new == 2 and phase != 2:
            ref = torque
        rate = {0: c["build_rate"], 4: c["build_rate"], 5: c["slow_rate"],
                2: -c["dump_rate"]}.get(new, 0.0)
        torque = min(max(torque + rate * T, 0.0), self.hw["Tmax"])
        return (new, torque, a, ref), torque

    def track(self, integral, omega_m, v_hat, s, mu):
        """The slip-tracking PI law at the target slip `s` with the feedforward of |mu|."""
        c, car, hw = self.c, self.car, self.hw
        r = car["r"]
        ff = mu * car["Fn"] * (r + car["J"] * (1.0 + s) / (car["m"] * r))
        eps = r * omega_m - (1.0 + s) * v_hat
        e = math.tanh(eps) if eps > 0 else eps
        integral = min(max(integral + c["ki"] * e * hw["T"], -ff), hw["Tmax"] - ff)
        return integral, min(max(ff + integral + c["kp"] * e, 0.0), hw["Tmax"])

    peak = staticmethod(peak_braking)
    """The peak of eq. 19 at a speed: ``(slip, mu)``."""
    mu = staticmethod(braking_mu)
    """Eq. 19 at one slip and speed, a float."""

    def tracking(self, integral, omega_m, v_hat, theta):
        pm = dict(self.pm, theta=theta)
        v = max(v_hat, 0.5)
        if self.name == "estimate":
            s = min(max(self.c["slip_scale"] * self.peak(pm, v)[0], -1.0), -1e-3)
        else:
            s = self.c["slip"]
        return self.track(integral, omega_m, v_hat, s, -self.mu(pm, s, v))

    def seek(self, st, omega_m, v_hat, slip, accel, brake_mean, theta):
        """The peak-seeking law (`PeakSeekingABS`): the belief's peak at the onset's speed
        and at the present one, the kernel-weighted slope of the measured friction, the
        dithered target held by the slip-tracking law."""
        c, car, T = self.c, self.car, self.hw["T"]
        r = car["r"]
        pm = dict(self.pm, theta=theta)
        v, lam = max(v_hat, 0.5), -slip
        mu = (brake_mean * math.tanh(omega_m / car["eps"]) + car["J"] * accel / r) / (
            r * car["Fn"])
        first = st["time"] == 0.0
        speed = v if first else st["speed"]
        lam_belief = min(max(-peak_braking(pm, speed)[0], c["min_slip"]), 1.0)
        new_road = first or abs(math.log(lam_belief / st["reference"])) > math.log(
            c["change_ratio"])
        reference = lam_belief if new_road else st["reference"]
        lam_now = min(max(-peak_braking(pm, v)[0], c["min_slip"]), 1.0)
        floor = lam_now if lam_belief < c["start_slip"] else max(c["min_slip"],
                                                                 c["start_slip"])
        start = 1.0 if lam_belief >= 1.0 - 1e-3 else max(c["start_scale"], floor / lam_belief)
        scale = start if new_road else st["scale"]
        center = scale * lam_belief if new_road else st["target"]
        # the kernel-weighted, forgotten moments of (mean slip, measured friction)
        pair = 0.5 * (lam + st["slip"])
        w = math.exp(-0.5 * ((pair - center) / c["kernel_width"]) ** 2)
        a = -math.expm1(-T / c["window"])
        weight = (1.0 - a) * st["weight"] + a * w
        g = a * w / max(weight, 1e-12)
        d_lam, d_mu = pair - st["mean_slip"], mu - st["mean_mu"]
        var = (1.0 - g) * (st["var_slip"] + g * d_lam * d_lam)
        var_mu = (1.0 - g) * (st["var_mu"] + g * d_mu * d_mu)
        cov = (1.0 - g) * (st["cov"] + g * d_lam * d_mu)
        fit = cov * cov / ((var + c["variance_floor"]) * (var_mu + c["mu_variance_floor"]))
        slope = cov / (var + c["variance_floor"])
        rate = c["rate"] if slope > 0 else c["descent_rate"]
        step = st["engaged"] * w * fit * rate * T * math.tanh(slope / c["slope_scale"])
        scale = min(max(scale + step / lam_belief, floor / lam_belief), 1.0 / lam_belief)
        target = scale * lam_belief
        engaged = max(st["engaged"], 1.0 if lam >= target else 0.0)
        dither = c["dither"] * math.sin(2.0 * math.pi * c["dither_frequency"] * st["time"])
        s = -min(max(target + dither, 1e-3), 1.0)
        integral, torque = self.track(st["integral"], omega_m, v_hat, s,
                                      -braking_mu(pm, s, v))
        if s <= -1.0:  # a target at the locked wheel
            torque = self.hw["Tmax"]
        return dict(integral=integral, target=target, scale=scale, speed=speed,
                    reference=reference, slip=lam, weight=weight,
                    mean_slip=st["mean_slip"] + g * d_lam, mean_mu=st["mean_mu"] + g * d_mu,
                    var_slip=var, var_mu=var_mu, cov=cov, engaged=engaged,
                    time=st["time"] + T), torque

    def command(self, st, omega_m, prev, v_hat, theta):
        r, T = self.car["r"], self.hw["T"]
        slip = min(max((r * omega_m / v_hat if v_hat != 0 else 1.0) - 1.0, -1.0), 1.0)
        if self.name == "locked":
            return st, self.hw["Tmax"]
        if self.name == "rule":
            return self.rule(st, slip, r * (omega_m - prev[0]) / T)
        if self.name == "seek":
            mean = prev[2] + (prev[1] - prev[2]) * self.hw["mean_fraction"]
            return self.seek(st, omega_m, v_hat, slip, r * (omega_m - prev[0]) / T, mean, theta)
        return self.tracking(st, omega_m, v_hat, theta)

    def initial_state(self):
        if self.name == "rule":
            return (0, 0.0, 0.0, self.hw["Tmax"])
        if self.name == "seek":
            return dict.fromkeys(("integral", "target", "scale", "speed", "reference", "slip",
                                  "weight", "mean_slip", "mean_mu", "var_slip", "var_mu",
                                  "cov", "engaged", "time"), 0.0)
        return 0.0

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

    def run(self, n=None):
        """The braking over DURATION (or its first `n` samples)."""
        hw, car = self.hw, self.car
        T = hw["T"]
        n = int(round(DURATION / T)) if n is None else n
        y = [0.0, self.v0, self.v0 / car["r"], 0.0, 0.0]
        enc = dict(count=0.0, count_sample=0.0, edge=0.0, before=-hw["delta"] / y[2],
                   omega=y[2])
        o = dict(z=0.0, omega=y[2], v=y[1], log_theta=math.log(self.pm["theta"]),
                 P=self.ob["P0"], s=(0.0, 0.0, 0.0), g=0.0)
        st = self.initial_state()
        buffer, target, torque = [0.0] * 9, 0.0, 0.0
        prev = (y[2], 0.0, 0.0)
        stop = math.inf
        for k in range(n):
            t = k * T
            omega_m, stamp, fresh = self.wheel_speed(enc, t)
            v_m = y[1] + hw["sigma"] * self.noise[k]
            if k > 0:
                o = self.observe(o, v_m, omega_m, stamp, fresh, t - T, prev[1], prev[2])
            st, cmd = self.command(st, omega_m, prev, o["v"], math.exp(o["log_theta"]))
            cmd = hw["Tmax"] if o["v"] < 3.0 else cmd
            buffer[k % 9] = min(max(cmd, -hw["Tmax"]), hw["Tmax"])
            delayed = buffer[(k - hw["d"]) % 9]
            target = min(max(delayed, target - hw["rate"] * T), target + hw["rate"] * T)
            prev = (omega_m, torque, target)
            y1 = y
            if y[1] > 0.05:
                y1 = self.advance(y, t, torque, target)
                enc = self.edges(enc, t, y, y1)
            torque = brake(hw, torque, target, T)
            if math.isinf(stop) and y[1] >= 1.0 > y1[1]:
                stop = y[0] + (y[1] - 1.0) / (y[1] - y1[1]) * (y1[0] - y[0])
            y = y1
        return float(y[1]), float(y[0]), float(stop)

    def advance(self, y, t, torque, target):
        return integrate(self.plant_rates(t, torque, target), y, t, self.hw["T"]).tolist()


# the previous baseline, kept to compare with the figures recorded before (see the module
# docstring): solve_ivp per solve, the observer's two copies solved apart, eq. 19 on NumPy
# scalars and its peak search evaluating both golden-section points each step
def integrate_solve_ivp(rates, y0, t0, T):
    sol = solve_ivp(rates, (t0, t0 + T), y0, method="LSODA", rtol=RTOL, atol=ATOL)
    return sol.y[:, -1]


def peak_braking_numpy(p, v):
    grid = PEAK_GRID
    i = int(np.argmax(-braking_mu_array(p, -grid, v)))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, 63)]
    for _ in range(40):
        c, d = b - INVERSE_GOLDEN * (b - a), a + INVERSE_GOLDEN * (b - a)
        if -float(braking_mu_array(p, -c, v)) >= -float(braking_mu_array(p, -d, v)):
            b = d
        else:
            a = c
    lam = 0.5 * (a + b)
    return -lam, -float(braking_mu_array(p, -lam, v))


class _FloatOnRead:
    """A controller's fields converted to floats at each read, as the previous baseline did."""

    def __init__(self, module):
        self.module = module

    def __getitem__(self, name):
        return float(getattr(self.module, name))


class PreviousNumpyBraking(NumpyBraking):
    """`NumpyBraking` as the baseline was written before (comment above); not for `seek`."""

    def __init__(self, scenario, observer, ctrl, ctrl_name, hw, noise):
        super().__init__(scenario, observer, ctrl, ctrl_name, hw, noise)
        self.c = _FloatOnRead(ctrl)

    peak = staticmethod(peak_braking_numpy)

    @staticmethod
    def mu(p, s, v):
        return float(braking_mu_array(p, s, v))

    def advance(self, y, t, torque, target):
        return integrate_solve_ivp(self.plant_rates(t, torque, target), y, t,
                                   self.hw["T"]).tolist()

    def copy_predict(self, x, t0, torque0, target, stamp):
        pm = dict(self.pm, theta=math.exp(x[3]))
        car, hw = self.car, self.hw

        def f(t, y):
            return list(car_rates(pm, car, y[0], y[1], y[2], brake(hw, torque0, target, t - t0)))

        y0 = [x[2], x[0], x[1]]
        y1 = integrate_solve_ivp(f, y0, t0, hw["T"])
        r0, r1 = f(t0, y0), f(t0 + hw["T"], y1)
        tau = min(max((stamp - t0) / hw["T"], 0.0), 1.0)
        return np.array([hermite(tau, hw["T"], y0[1], y1[1], r0[1], r1[1]), y1[1], y1[2], y1[0]])

    def predict(self, x, d, t0, torque0, target, stamp):
        x, d = np.asarray(x), np.asarray(d)
        mid = self.copy_predict(x, t0, torque0, target, stamp)
        der = (self.copy_predict(x + FD_STEP * d, t0, torque0, target, stamp) - mid) / FD_STEP
        return mid, der


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


def baseline_picks(seeds: int, subset: int):
    """`subset` brakings per controller, ``(controller index, run index)``: the j-th on
    surface j mod 8 at a random speed and seed (seeded)."""
    rng = np.random.default_rng(0)
    picks = []
    for j in range(subset):
        for ci in range(len(CONTROLLERS)):
            k, vi = int(rng.integers(seeds)), int(rng.integers(len(SPEEDS)))
            picks.append((ci, (k * len(SPEEDS) + vi) * len(SURFACES) + j % len(SURFACES)))
    return picks


_BARRIER = None


def _start_worker(barrier):
    global _BARRIER
    _BARRIER = barrier


def _all_started(_):
    """Returns once every worker holds one of these (all started and imported)."""
    _BARRIER.wait(timeout=600)


def _run_timed(braking):
    """A braking in a worker: ``(wall [s], CPU [s], result)``."""
    t0, c0 = time.perf_counter(), time.process_time()
    result = braking.run()
    return time.perf_counter() - t0, time.process_time() - c0, result


def pooled_baseline(brakings, workers):
    """The brakings over `workers` processes (one task each, taken in turn), the pool
    started and its imports done before the clock: ``(wall [s], per braking (wall [s], CPU
    [s], result))``, each braking's times taken in its worker while the others run."""
    ctx = mp.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_start_worker,
                             initargs=(ctx.Barrier(workers),)) as ex:
        list(ex.map(_all_started, range(workers)))
        t0 = time.perf_counter()
        timed = list(ex.map(_run_timed, brakings))
        wall = time.perf_counter() - t0
    return wall, timed


def by_controller(picks, values):
    """The mean of `values` (one per pick) per controller name."""
    names = list(CONTROLLERS)
    return {name: float(np.mean([x for (ci, _), x in zip(picks, values) if ci == c]))
            for c, name in enumerate(names)}


def time_baseline(out, scenarios, observers, keys, hw, subset, seeds, workers):
    """The baseline on `baseline_picks`, single-process (with the previous baseline on the
    same brakings) and pooled; each controller's mean time per braking scaled by its number
    of runs. Returns the JSON keys."""
    runs = members(seeds)
    M, n = len(runs), int(round(DURATION / float(hw.sample_time)))
    names = list(CONTROLLERS)
    picks = baseline_picks(seeds, subset)
    brakings, single, previous, diffs, vs_previous = [], [], [], [], []
    for ci, m in picks:
        name = names[ci]
        sc, ob = (jax.tree_util.tree_map(lambda a: a[m], x) for x in (scenarios, observers))
        noise = np.asarray(jax.vmap(lambda k: jax.random.normal(
            jax.random.fold_in(keys[m], k), (), jnp.float64))(jnp.arange(n)))
        braking = NumpyBraking(sc, ob, controller(name), name, hw, noise)
        brakings.append(braking)
        t0, c0 = time.perf_counter(), time.process_time()
        res = braking.run()
        single.append((time.perf_counter() - t0, time.process_time() - c0, res))
        ref = (float(out.final_speed[ci, m]), float(out.final_distance[ci, m]),
               float(out.stopping_distance[ci, m]))
        d = [abs(res[0] - ref[0]), abs(res[1] - ref[1]),
             abs(res[2] - ref[2]) if math.isfinite(res[2]) and math.isfinite(ref[2]) else 0.0,
             float(math.isfinite(res[2]) != math.isfinite(ref[2]))]
        diffs.append(d)
        line = (f"  baseline {name:8s} {runs[m][0]:12s} {runs[m][1]:4.0f} m/s: "
                f"{single[-1][0]:.3f} s, |dv| {d[0]:.1e} m/s, |dx| {d[1]:.1e} m, "
                f"|d stop| {d[2]:.1e} m")
        if name in PREVIOUS_CONTROLLERS:
            old = PreviousNumpyBraking(sc, ob, controller(name), name, hw, noise)
            t0 = time.perf_counter()
            res_old = old.run()
            previous.append(time.perf_counter() - t0)
            vs_previous.append([abs(a - b) if math.isfinite(a) or math.isfinite(b) else 0.0
                                for a, b in zip(res, res_old)])
            line += f"; previous {previous[-1]:.3f} s, |dx| {vs_previous[-1][1]:.1e} m"
        print(line, file=sys.stderr, flush=True)
    pool_wall, pooled = pooled_baseline(brakings, workers)
    same = all(p[2] == s[2] for p, s in zip(pooled, single))
    single_wall = by_controller(picks, [s[0] for s in single])
    single_cpu = by_controller(picks, [s[1] for s in single])
    pooled_wall = by_controller(picks, [p[0] for p in pooled])
    single_total = M * sum(single_wall.values())
    pooled_total = M * sum(pooled_wall.values()) / workers
    diffs, vs_previous = np.array(diffs), np.array(vs_previous)
    stop_by = {name: float(np.max([d[2] for (ci, _), d in zip(picks, diffs) if ci == c]))
               for c, name in enumerate(names)}
    return dict(
        baseline_subset_runs=len(picks), baseline_subset_runs_per_controller=subset,
        baseline_processes=workers,
        baseline_wall_s_per_run_by_controller={k: round(v, 4) for k, v in single_wall.items()},
        baseline_pooled_wall_s_per_run_by_controller={k: round(v, 4)
                                                      for k, v in pooled_wall.items()},
        baseline_wall_s_per_run=round(single_total / (M * len(names)), 4),
        baseline_wall_s_extrapolated=round(pooled_total, 1),
        baseline_single_process_wall_s_extrapolated=round(single_total, 1),
        baseline_cpu_s_extrapolated=round(M * sum(single_cpu.values()), 1),
        baseline_subset_pooled_wall_s=round(pool_wall, 2),
        baseline_subset_single_process_wall_s=round(sum(s[0] for s in single), 2),
        baseline_pooled_results_equal_single=bool(same),
        previous_baseline_wall_s_per_run=round(float(np.mean(previous)), 4),
        previous_baseline_subset_runs=len(previous),
        previous_baseline_wall_s_extrapolated=round(float(np.mean(previous)) * M * len(names),
                                                    1),
        baseline_vs_previous_max_final_speed_diff_m_s=float(vs_previous[:, 0].max()),
        baseline_vs_previous_max_final_distance_diff_m=float(vs_previous[:, 1].max()),
        baseline_vs_previous_max_stopping_distance_diff_m=float(vs_previous[:, 2].max()),
        accuracy_max_final_speed_diff_m_s=float(diffs[:, 0].max()),
        accuracy_max_final_distance_diff_m=float(diffs[:, 1].max()),
        accuracy_max_stopping_distance_diff_m=float(diffs[:, 2].max()),
        accuracy_max_stopping_distance_diff_m_by_controller=stop_by,
        accuracy_median_final_distance_diff_m=float(np.median(diffs[:, 1])),
        accuracy_stopped_disagreements=int(diffs[:, 3].sum()),
    ), single_cpu


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=32)
    ap.add_argument("--subset", type=int, default=8,
                    help="baseline brakings timed per controller")
    ap.add_argument("--processes", type=int, default=os.cpu_count(),
                    help="worker processes of the pooled baseline")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tires", nargs="+", default=list(OTHER_TIRES), choices=OTHER_TIRES)
    args = ap.parse_args(argv)
    hw = realistic_hardware()
    scenarios, observers, keys = vehsim_inputs(args.seeds)
    n_runs = len(CONTROLLERS) * keys.shape[0]
    load = os.getloadavg()[0]
    out, first, walls, cpus = time_vehsim(scenarios, observers, keys, hw, args.repeats)
    vehsim_wall, vehsim_cpu = float(np.median(walls)), float(np.median(cpus))
    base, _ = time_baseline(out, scenarios, observers, keys, hw, args.subset, args.seeds,
                            args.processes)
    load_baseline = os.getloadavg()[0]
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
        "vehsim_cpu_s": round(vehsim_cpu, 3),
        "vehsim_compile_and_first_call_s": round(first, 2),
        "baseline": f"NumPy/SciPy loop, one braking at a time per process over "
                    f"{args.processes} processes, odeint (LSODA, rtol 1e-8, atol 1e-10) per "
                    "sample for the plant and for the observer's copy with its displaced copy "
                    "(one 6-state solve), scalar math; timed on a subset per controller and "
                    "extrapolated per controller",
        **base,
        "ratio": round(base["baseline_wall_s_extrapolated"] / vehsim_wall, 1),
        "ratio_single_process_baseline": round(
            base["baseline_single_process_wall_s_extrapolated"] / vehsim_wall, 1),
        "ratio_cpu_time": round(base["baseline_cpu_s_extrapolated"] / vehsim_cpu, 1),
        "ratio_previous_baseline": round(
            base["previous_baseline_wall_s_extrapolated"] / vehsim_wall, 1),
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
        "load_average_1min_after_baseline": round(load_baseline, 2),
        "cpu_count": os.cpu_count(),
        "device": str(jax.devices()[0]),
        "dtype": "float64",
    }))


if __name__ == "__main__":
    main()
