"""Benchmark: identification through vehsim (optimistix LM, forward-mode Jacobians through the
diffrax solve) vs scipy.optimize.least_squares (MINPACK LM) with finite differences on a
NumPy simulation of the same model, same data, same start, same objective.

Model: lumped LuGre (eqs. 22-23) driven by the measured v, omega of the shipped brakings 1-2
(exponential midpoint rule, 2 substeps per sample, identical in both), parameters in logs
(mu_s - mu_c in logs), the same weak prior.

The NumPy model (``ScipyProblem.forces``) is array code throughout:

* everything that does not depend on the parameters (substep midpoints, slips, step sizes)
  is computed once, with the brakings stacked into one zero-padded array (padding has step
  0, so it leaves the state unchanged and is dropped from the residuals);
* the friction-state recurrence z_{k+1} = e^{-x_k} z_k + f_k is linear, so with X_k the
  running sum of x it is z_k = e^{-X_k} (z_0 + sum_{j<k} e^{X_{j+1}} f_j): two cumsums and
  exponentials. X reaches a few thousand here, so the sum restarts in blocks over which X
  grows by at most ``SPAN`` (e^500 is far from overflow); that is a handful of blocks, the
  only Python loop (``linear_recurrence``);
* scipy differentiates it by its own 2-point finite differences (6 model evaluations per
  Jacobian). Evaluating the 6 perturbations as one batched call (parameters on a leading
  axis, through a callable ``jac``) measured slower on the development machine, so it is
  not used.

The same model with the recurrence as a Python loop over floats (``numpy_forces_loop``, the
form the earlier result rows used) is timed as a side figure, ``ratio_python_loop``; the row
also reports how far the two NumPy models differ (``model_max_rel_diff``). Prints a JSON
line; the headline is ``ratio`` = scipy wall time / vehsim wall time (after compilation;
compile time separate), each the best of `REPEATS` alternating runs (the development machine
is shared; its load average is printed with the result, and ``cpu_ratio``, the same ratio in
process CPU time, which load distorts less; XLA's worker threads spin for about 0.1 s after
each vehsim fit, so the scipy runs start after a pause of ``PAUSE_S``, and the CPU time spent
in that pause is reported as ``vehsim_trailing_cpu_s``, outside ``vehsim_cpu_s``). Results
and what made the difference: docs/performance.md, "Braking identification".

Run:  PYTHONPATH=. python experiments/benchmarks/fit_vs_scipy.py
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
PAUSE_S = 0.3  # idle time after each vehsim fit, before the scipy fits
SPAN = 500.0  # largest growth of the running decay exponent within one block (e^500 ~ 1e217)


def linear_recurrence(x: np.ndarray, f: np.ndarray, z0: np.ndarray) -> np.ndarray:
    """z_{k+1} = e^{-x_k} z_k + f_k along the last axis (x >= 0), for every leading index.

    Returns z_0..z_n (last axis n + 1). Closed form per block starting at k0:
    z_k = e^{-(X_k - X_k0)} (z_k0 + sum_{k0<=j<k} e^{X_{j+1} - X_k0} f_j), X the running sum
    of x; the blocks are cut where the largest X over the leading indices crosses a multiple
    of SPAN, so no exponential exceeds e^SPAN.
    """
    n = x.shape[-1]
    X = np.zeros(x.shape[:-1] + (n + 1,))
    np.cumsum(x, axis=-1, out=X[..., 1:])
    X_max = np.concatenate(([0.0], np.cumsum(x.reshape(-1, n).max(axis=0))))
    cuts = np.searchsorted(X_max, np.arange(0.0, X_max[-1], SPAN))
    bounds = np.append(np.union1d([0], cuts), n + 1)
    z = np.empty_like(X)
    zc = z0
    for k0, k1 in zip(bounds[:-1], bounds[1:]):
        w = np.exp(X[..., k0 + 1:k1] - X[..., k0:k0 + 1])
        z[..., k0] = zc
        z[..., k0 + 1:k1] = (zc[..., None] + np.cumsum(w * f[..., k0:k1 - 1], axis=-1)) / w
        if k1 <= n:
            zc = np.exp(-x[..., k1 - 1]) * z[..., k1 - 1] + f[..., k1 - 1]
    return z


def numpy_forces_loop(theta: dict, d: dict) -> np.ndarray:
    """The same force history with the recurrence as a Python loop over floats, one braking,
    everything recomputed per call (side figure, ``ratio_python_loop``)."""
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
    logs), force residuals scaled by the peak force, the same weak prior; counts its
    model evaluations."""

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
        self._stack()

    def _stack(self):
        """Parameter-independent arrays, brakings stacked on axis 0 and zero-padded: slip
        v_r, |v_r| and |omega r| at the substep midpoints then at the samples (one rate
        evaluation covers both), the substep lengths h (0 in the padding), F_n, F_x."""
        n_max = max(len(d["t"]) for d in self.data)
        n_sub = (n_max - 1) * SUBSTEPS
        frac = (np.arange(SUBSTEPS) + 0.5) / SUBSTEPS
        shape = (len(self.data), n_sub + n_max)
        self.vr, self.aomr = np.zeros(shape), np.zeros(shape)
        self.h, self.F_n = np.zeros((len(self.data), n_sub)), np.zeros((len(self.data), n_max))
        self.mask = np.zeros((len(self.data), n_max), bool)
        for i, d in enumerate(self.data):
            t, v, om, r, n = d["t"], d["v"], d["omega"], d["r"], len(d["t"])
            v_mid = (v[:-1, None] + frac * np.diff(v)[:, None]).ravel()
            om_mid = (om[:-1, None] + frac * np.diff(om)[:, None]).ravel()
            m = (n - 1) * SUBSTEPS
            self.vr[i, :m], self.aomr[i, :m] = r * om_mid - v_mid, np.abs(om_mid * r)
            self.vr[i, n_sub:n_sub + n], self.aomr[i, n_sub:n_sub + n] = r * om - v, np.abs(om * r)
            self.h[i, :m] = np.repeat(np.diff(t) / SUBSTEPS, SUBSTEPS)
            self.F_n[i, :n], self.mask[i, :n] = d["F_n"], True
        self.avr = np.abs(self.vr)
        self.n_sub = n_sub
        self.F_x = np.concatenate([d["F_x"] for d in self.data])

    def theta_of(self, u):
        th = dict(self.base)
        for n, x in zip(self.names, u):
            if n != "mu_s":
                th[n] = math.exp(x)
        th["mu_s"] = th["mu_c"] + math.exp(u[self.names.index("mu_s")])
        return th

    def forces(self, u) -> np.ndarray:
        """Model forces at the samples of all brakings (concatenated) for parameters u."""
        self.calls += 1
        th = self.theta_of(u)
        s0, s1, s2 = th["sigma0"], th["sigma1"], th["sigma2"]
        mc, ms, vs = th["mu_c"], th["mu_s"], th["v_s"]
        kappa = th["kappa0"] / th["L"]
        g = mc + (ms - mc) * np.exp(-((self.avr / vs) ** th["alpha"]))
        a = th["theta"] * s0 * self.avr / g + kappa * self.aomr
        a_m, a_s = a[:, :self.n_sub], a[:, self.n_sub:]
        vr_m, vr_s = self.vr[:, :self.n_sub], self.vr[:, self.n_sub:]
        x = a_m * self.h
        small = x <= 1e-12
        phi = np.where(small, 1.0, -np.expm1(-x) / np.where(small, 1.0, x))
        a0 = a_s[:, 0]
        z0 = np.where(a0 != 0, vr_s[:, 0] / np.where(a0 != 0, a0, 1.0), 0.0)
        z = linear_recurrence(x, self.h * phi * vr_m, z0)[:, ::SUBSTEPS]
        return ((s0 * z + s1 * (vr_s - a_s * z) + s2 * vr_s) * self.F_n)[self.mask]

    def residuals(self, u):
        return np.concatenate([(self.forces(u) - self.F_x) / self.F_scale,
                               PRIOR * (u - self.u0)])

    def residuals_loop(self, u):
        self.calls += 1
        th = self.theta_of(u)
        r = [(numpy_forces_loop(th, d) - d["F_x"]) / self.F_scale for d in self.data]
        return np.concatenate(r + [PRIOR * (u - self.u0)])

    def data_loss(self, th):
        """The data part of the objective, through the loop model (the reference)."""
        return 0.5 * sum(float(np.sum(((numpy_forces_loop(th, d) - d["F_x"]) / self.F_scale)
                                      ** 2)) for d in self.data)

    def model_difference(self, u):
        """max |vectorised - loop| / max |loop| over the brakings' forces at u."""
        vec = self.forces(u)
        loop = np.concatenate([numpy_forces_loop(self.theta_of(u), d) for d in self.data])
        return float(np.max(np.abs(vec - loop)) / np.max(np.abs(loop)))


def scipy_fit(problem: ScipyProblem, loop: bool = False):
    """MINPACK Levenberg-Marquardt with 2-point finite differences, on the vectorised model
    or (loop) the loop model."""
    problem.calls = 0
    return least_squares(problem.residuals_loop if loop else problem.residuals, problem.u0,
                         jac="2-point", method="lm", xtol=1e-9, ftol=1e-9, gtol=1e-9,
                         max_nfev=4000)


def timed_runs(train, init, problem: ScipyProblem):
    """vehsim: the first call compiles, the next ones are timed (the whole fit: LM solve,
    Jacobian and standard errors at the optimum, per-braking errors). scipy: the vectorised
    model, then the loop model, after a pause. The runs alternate (the machine's speed
    drifts) and each keeps its best."""
    t0 = time.perf_counter()
    fit_open_loop(train, init, n_starts=1, prior_weight=PRIOR, throw=False)
    first = time.perf_counter() - t0
    best = {f"{s}_{k}_s": math.inf for s in ("vehsim", "scipy", "scipy_loop")
            for k in ("wall", "cpu")} | {"vehsim_trailing_cpu_s": math.inf}
    for _ in range(REPEATS):
        t1, c1 = time.perf_counter(), time.process_time()
        res = fit_open_loop(train, init, n_starts=1, prior_weight=PRIOR, throw=False)
        best["vehsim_wall_s"] = min(best["vehsim_wall_s"], time.perf_counter() - t1)
        best["vehsim_cpu_s"] = min(best["vehsim_cpu_s"], time.process_time() - c1)
        # XLA's worker threads keep spinning for about 0.1 s after a call returns; the pause
        # keeps that CPU time (and core) away from the scipy runs, and measures it
        c2 = time.process_time()
        time.sleep(PAUSE_S)
        best["vehsim_trailing_cpu_s"] = min(best["vehsim_trailing_cpu_s"],
                                            time.process_time() - c2)
        for side, loop in (("scipy", False), ("scipy_loop", True)):
            t3, c3 = time.perf_counter(), time.process_time()
            sp = scipy_fit(problem, loop)
            best[f"{side}_wall_s"] = min(best[f"{side}_wall_s"], time.perf_counter() - t3)
            best[f"{side}_cpu_s"] = min(best[f"{side}_cpu_s"], time.process_time() - c3)
            if loop:
                sp_loop, calls_loop = sp, problem.calls
            else:
                sp_vec, calls_vec = sp, problem.calls
    best["vehsim_compile_s"] = first - best["vehsim_wall_s"]
    return res, (sp_vec, calls_vec), (sp_loop, calls_loop), best


def main() -> int:
    files = shipped_brakings()
    train = [load_braking(files["braking_1"]), load_braking(files["braking_2"])]
    init = default_initial_guess()
    problem = ScipyProblem(train, init)
    res, (sp, calls), (sp_loop, calls_loop), t = timed_runs(train, init, problem)
    print(f"vehsim: {result_name(res.result)} in {t['vehsim_wall_s']:.3f}s ({res.num_steps} "
          "LM steps)", file=sys.stderr, flush=True)
    # MINPACK's nfev leaves out the finite-difference evaluations: count every call
    print(f"scipy: status {sp.status} in {t['scipy_wall_s']:.3f}s ({sp.nfev} iterations' "
          f"evaluations, {calls} residual evaluations in all); "
          f"loop model: status {sp_loop.status} in {t['scipy_loop_wall_s']:.3f}s "
          f"({calls_loop} evaluations)", file=sys.stderr, flush=True)
    th_v = {k: float(v) for k, v in res.values.items()} | {"L": problem.base["L"]}
    th_s = problem.theta_of(sp.x)
    names = problem.names
    row = {
        "benchmark": "fit_vs_scipy",
        "variant": "vectorised NumPy baseline (closed-form blocked recurrence, hoisted "
                   "constants, stacked brakings); loop baseline as ratio_python_loop",
        "ratio": t["scipy_wall_s"] / t["vehsim_wall_s"],
        "cpu_ratio": t["scipy_cpu_s"] / t["vehsim_cpu_s"],
        "ratio_python_loop": t["scipy_loop_wall_s"] / t["vehsim_wall_s"],
        "cpu_ratio_python_loop": t["scipy_loop_cpu_s"] / t["vehsim_cpu_s"],
        **{k: t[k] for k in ("vehsim_wall_s", "vehsim_cpu_s", "vehsim_compile_s",
                             "vehsim_trailing_cpu_s")},
        "vehsim_status": result_name(res.result),
        "vehsim_lm_steps": res.num_steps,
        "vehsim_loss": problem.data_loss(th_v),
        # cross-check: both implementations agree on the loss at vehsim's optimum
        "vehsim_loss_jax": float(fit_loss(res.model, train)),
        **{k: t[k] for k in ("scipy_wall_s", "scipy_cpu_s")},
        "scipy_status": int(sp.status),
        "scipy_nfev": int(sp.nfev),
        "scipy_residual_evaluations": calls,
        "scipy_loss": problem.data_loss(th_s),
        **{k: t[k] for k in ("scipy_loop_wall_s", "scipy_loop_cpu_s")},
        "scipy_loop_status": int(sp_loop.status),
        "scipy_loop_residual_evaluations": calls_loop,
        "scipy_loop_loss": problem.data_loss(problem.theta_of(sp_loop.x)),
        # vectorised vs loop NumPy model, at the start and at scipy's optimum
        "model_max_rel_diff": max(problem.model_difference(problem.u0),
                                  problem.model_difference(sp.x)),
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
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    raise SystemExit(main())
