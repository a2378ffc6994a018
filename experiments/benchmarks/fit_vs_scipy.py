"""Benchmark: identification through vehsim (optimistix LM, forward-mode Jacobians through the
diffrax solve) vs scipy.optimize.least_squares (MINPACK LM) with finite differences on a
NumPy simulation of the same model, same data, same start, same objective.

Model: lumped LuGre (eqs. 22-23) driven by the measured v, omega of the shipped brakings 1-2
(exponential midpoint rule, 2 substeps per sample, identical in both; the NumPy side
vectorises the coefficients and loops only over the scalar recurrence), parameters in logs
(mu_s - mu_c in logs), the same weak prior. Prints a JSON line; the headline is
``ratio`` = scipy wall time / vehsim wall time (after compilation; compile time separate),
each the best of `REPEATS` alternating runs (the development machine is shared; its load
average is printed with the result, and ``cpu_ratio``, the same ratio in process CPU time,
which load distorts less). Results and what made the difference: docs/performance.md,
"Braking identification".

Run:  PYTHONPATH=. python experiments/benchmarks/fit_vs_scipy.py
"""

from __future__ import annotations

import json
import math
import os
import sys
import time

import jax


jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402
from scipy.optimize import least_squares  # noqa: E402

from vehsim import result_name  # noqa: E402
from vehsim.identify.braking import load_braking, shipped_brakings  # noqa: E402
from vehsim.identify.fit import fit_loss, fit_open_loop  # noqa: E402
from vehsim.identify.parameters import (  # noqa: E402
    DEFAULT_FREE,
    default_initial_guess,
    parameter_values,
)


SUBSTEPS = 2
PRIOR = 1e-3
REPEATS = 7


def numpy_forces(theta: dict, d: dict) -> np.ndarray:
    """The lumped LuGre force history, same scheme as vehsim.identify.friction_state, in NumPy.

    The coefficients of every substep are vectorised NumPy; only the scalar recurrence
    z <- e^{-x} z + h phi(x) v_r (sequential by nature) is a Python loop over floats, the
    fastest way to run it without a compiler.
    """
    s0, s1, s2 = theta["sigma0"], theta["sigma1"], theta["sigma2"]
    mc, ms, vs, al, th = theta["mu_c"], theta["mu_s"], theta["v_s"], theta["alpha"], theta["theta"]
    kappa = theta["kappa0"] / theta["L"]
    r, t, v, om = d["r"], d["t"], d["v"], d["omega"]

    def rate(vv, oo):
        vr = r * oo - vv
        avr = np.abs(vr)
        g = mc + (ms - mc) * np.exp(-((avr / vs) ** al))
        return vr, th * s0 * avr / g + kappa * np.abs(oo * r)

    frac = (np.arange(SUBSTEPS) + 0.5) / SUBSTEPS
    v_mid = (v[:-1, None] + frac * np.diff(v)[:, None]).ravel()
    om_mid = (om[:-1, None] + frac * np.diff(om)[:, None]).ravel()
    h = np.repeat(np.diff(t) / SUBSTEPS, SUBSTEPS)
    vr_m, a_m = rate(v_mid, om_mid)
    x = a_m * h
    small = x <= 1e-12
    phi = np.where(small, 1.0, -np.expm1(-x) / np.where(small, 1.0, x))
    decay, forcing = np.exp(-x).tolist(), (h * phi * vr_m).tolist()
    vr, a = rate(v, om)
    z = vr[0] / a[0] if a[0] != 0 else 0.0
    zs = [z]
    for k in range(len(decay)):
        z = decay[k] * z + forcing[k]
        if k % SUBSTEPS == SUBSTEPS - 1:
            zs.append(z)
    z = np.asarray(zs)
    return (s0 * z + s1 * (vr - a * z) + s2 * vr) * d["F_n"]


class ScipyProblem:
    """The same least-squares problem for scipy: free parameters in logs (mu_s - mu_c in
    logs), force residuals scaled by the peak force, the same weak prior; counts its calls."""

    def __init__(self, train, init):
        self.base = {k: float(v) for k, v in parameter_values(init).items()}
        self.base["L"] = float(init.params.L)
        self.data = [{k: np.asarray(getattr(d, k)) for k in ("t", "v", "omega", "F_n", "F_x")}
                     | {"r": float(d.r)} for d in train]
        self.F_scale = max(float(np.max(np.abs(d["F_x"]))) for d in self.data)
        self.names = list(DEFAULT_FREE)
        self.u0 = np.array([math.log(self.base[n] - self.base["mu_c"]) if n == "mu_s"
                            else math.log(self.base[n]) for n in self.names])
        self.calls = 0

    def theta_of(self, u):
        th = dict(self.base)
        for n, x in zip(self.names, u):
            if n != "mu_s":
                th[n] = math.exp(x)
        th["mu_s"] = th["mu_c"] + math.exp(u[self.names.index("mu_s")])
        return th

    def residuals(self, u):
        self.calls += 1
        th = self.theta_of(u)
        r = [(numpy_forces(th, d) - d["F_x"]) / self.F_scale for d in self.data]
        return np.concatenate(r + [PRIOR * (u - self.u0)])

    def data_loss(self, th):
        return 0.5 * sum(float(np.sum(((numpy_forces(th, d) - d["F_x"]) / self.F_scale) ** 2))
                         for d in self.data)


def timed_runs(train, init, problem: ScipyProblem):
    """vehsim: the first call compiles, the next ones are timed (the whole fit: LM solve,
    Jacobian and standard errors at the optimum, per-braking errors). scipy: MINPACK
    Levenberg-Marquardt, 2-point finite differences. The runs alternate (the machine's
    speed drifts) and each side keeps its best."""
    t0 = time.perf_counter()
    fit_open_loop(train, init, n_starts=1, prior_weight=PRIOR, throw=False)
    first = time.perf_counter() - t0
    best = dict(vehsim_wall_s=math.inf, vehsim_cpu_s=math.inf, scipy_wall_s=math.inf,
                scipy_cpu_s=math.inf)
    for _ in range(REPEATS):
        t1, c1 = time.perf_counter(), time.process_time()
        res = fit_open_loop(train, init, n_starts=1, prior_weight=PRIOR, throw=False)
        best["vehsim_wall_s"] = min(best["vehsim_wall_s"], time.perf_counter() - t1)
        best["vehsim_cpu_s"] = min(best["vehsim_cpu_s"], time.process_time() - c1)
        problem.calls = 0
        t3, c3 = time.perf_counter(), time.process_time()
        sp = least_squares(problem.residuals, problem.u0, jac="2-point", method="lm",
                           xtol=1e-9, ftol=1e-9, gtol=1e-9, max_nfev=4000)
        best["scipy_wall_s"] = min(best["scipy_wall_s"], time.perf_counter() - t3)
        best["scipy_cpu_s"] = min(best["scipy_cpu_s"], time.process_time() - c3)
    best["vehsim_compile_s"] = first - best["vehsim_wall_s"]
    return res, sp, best


def main() -> int:
    files = shipped_brakings()
    train = [load_braking(files["braking_1"]), load_braking(files["braking_2"])]
    init = default_initial_guess()
    problem = ScipyProblem(train, init)
    res, sp, t = timed_runs(train, init, problem)
    print(f"vehsim: {result_name(res.result)} in {t['vehsim_wall_s']:.3f}s ({res.num_steps} "
          "LM steps)", file=sys.stderr, flush=True)
    # MINPACK's nfev leaves out the finite-difference evaluations: count every call
    print(f"scipy: status {sp.status} in {t['scipy_wall_s']:.2f}s ({sp.nfev} iterations' "
          f"evaluations, {problem.calls} residual evaluations in all)", file=sys.stderr,
          flush=True)
    th_v = {k: float(v) for k, v in res.values.items()} | {"L": problem.base["L"]}
    th_s = problem.theta_of(sp.x)
    names = problem.names
    row = {
        "benchmark": "fit_vs_scipy",
        "ratio": t["scipy_wall_s"] / t["vehsim_wall_s"],
        "cpu_ratio": t["scipy_cpu_s"] / t["vehsim_cpu_s"],
        **{k: t[k] for k in ("vehsim_wall_s", "vehsim_cpu_s", "vehsim_compile_s")},
        "vehsim_status": result_name(res.result),
        "vehsim_lm_steps": res.num_steps,
        "vehsim_loss": problem.data_loss(th_v),
        # cross-check: both implementations agree on the loss at vehsim's optimum
        "vehsim_loss_jax": float(fit_loss(res.model, train)),
        **{k: t[k] for k in ("scipy_wall_s", "scipy_cpu_s")},
        "scipy_status": int(sp.status),
        "scipy_nfev": int(sp.nfev),
        "scipy_residual_evaluations": problem.calls,
        "scipy_loss": problem.data_loss(th_s),
        "n_samples": int(sum(len(d["t"]) for d in problem.data)),
        "n_parameters": len(names),
        "vehsim_parameters": {n: th_v[n] for n in names},
        "scipy_parameters": {n: th_s[n] for n in names},
        "device": str(jax.devices()[0]),
        "load_average_1min": os.getloadavg()[0],
    }
    print(json.dumps(row))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
