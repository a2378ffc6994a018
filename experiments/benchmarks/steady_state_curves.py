"""Benchmark: vmapped steady-state braking force (eq. 19) at 10^6 operating points vs NumPy.

Points: slip uniform in [-1, 0] (1 % of them a locked wheel, slip exactly -1, the formula's
other branch), vehicle speed in [1, 40] m/s and road condition theta in [1, 2.5], drawn at
random, so that neither side can reuse work across a grid's axes (on a slip x speed x theta
grid the Stribeck term depends on slip and speed only, and a broadcast NumPy evaluation of it
on the 10^4 slip-speed pairs halves the baseline's time). The baseline is the same formula
vectorised in NumPy over the points (whole-array operations, no Python loops, the constant
factors multiplied once): a competent use of it. Each side is timed by its best of 5 calls
after a warm-up (vehsim's compilation apart), the two alternated over `--rounds` rounds; the
headline ratio is the median over the rounds. XLA may run one large fused loop on several
cores, so the CPU time of each side (`ratio_cpu_time`) is reported beside it, with the
machine's load.

Run: PYTHONPATH=. python experiments/benchmarks/steady_state_curves.py [--out FILE]
"""

import argparse
import datetime
import json
import os

import jax
import jax.numpy as jnp
import numpy as np
from _common import best_time, compile_time, cpu_time, emit

import vehsim as vs


jax.config.update("jax_enable_x64", True)


def numpy_braking_mu(p, s, v, theta):
    v_r = v * s
    g = p["mu_c"] + (p["mu_s"] - p["mu_c"]) * np.exp(-np.abs(v_r / p["v_s"]) ** p["alpha"])
    one_s = np.abs(1.0 + s)
    k = p["sigma0"] * p["L"]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (k * theta) * np.abs(s) / (g * one_s)
        psi = np.where(x < 1e-3, 0.5 - x / 6 + x * x / 24, (x + np.expm1(-x)) / (x * x))
        rolling = k * s / one_s * psi
    return np.where(one_s == 0, np.sign(s) * g / theta, rolling) + p["sigma2"] * v_r


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10**6)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", default=None, help="append the JSON line to this file")
    args = ap.parse_args(argv)
    load_before = os.getloadavg()
    p = vs.params.table3()
    rng = np.random.default_rng(0)
    S = rng.uniform(-1.0, 0.0, args.points)
    S[rng.random(args.points) < 0.01] = -1.0
    V = rng.uniform(1.0, 40.0, args.points)
    TH = rng.uniform(1.0, 2.5, args.points)

    @jax.jit
    def vehsim_curves(S, V, TH):
        def one(s, v, theta):
            q = vs.LuGreParams(sigma0=p.sigma0, sigma1=p.sigma1, sigma2=p.sigma2, mu_c=p.mu_c,
                               mu_s=p.mu_s, v_s=p.v_s, alpha=p.alpha, theta=theta, L=p.L)
            return vs.braking_mu_uniform(q, s, v)

        return jax.vmap(one)(S, V, TH)

    Sj, Vj, THj = jnp.asarray(S), jnp.asarray(V), jnp.asarray(TH)
    t_compile = compile_time(vehsim_curves, Sj, Vj, THj)
    pn = {k: float(getattr(p, k)) for k in ["sigma0", "sigma2", "mu_c", "mu_s", "v_s", "alpha", "L"]}
    rounds = [(best_time(vehsim_curves, Sj, Vj, THj), best_time(numpy_braking_mu, pn, S, V, TH))
              for _ in range(args.rounds)]
    t_vehsim, t_numpy = (float(np.median(col)) for col in zip(*rounds))
    cpu_vehsim, cpu_numpy = (cpu_time(fn, *a) for fn, a in (
        (vehsim_curves, (Sj, Vj, THj)), (numpy_braking_mu, (pn, S, V, TH))))
    a = np.asarray(vehsim_curves(Sj, Vj, THj))
    b = numpy_braking_mu(pn, S, V, TH)
    row = dict(benchmark="steady_state_curves", points=int(S.size),
               device=jax.devices()[0].platform, vehsim_s=t_vehsim, numpy_s=t_numpy,
               compile_s=t_compile, vehsim_evals_per_s=S.size / t_vehsim,
               numpy_evals_per_s=S.size / t_numpy,
               ratio=float(np.median([n / v for v, n in rounds])),
               ratio_cpu_time=cpu_numpy / cpu_vehsim,
               vehsim_cpu_s=cpu_vehsim, numpy_cpu_s=cpu_numpy,
               ratio_per_round=[round(n / v, 3) for v, n in rounds],
               max_abs_difference=float(np.max(np.abs(a - b))),
               load_average_before_after=[round(load_before[0], 2),
                                          round(os.getloadavg()[0], 2)],
               cpu_count=os.cpu_count(),
               date=datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"))
    emit(**row)
    if args.out:
        with open(args.out, "a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
