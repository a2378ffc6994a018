"""Benchmark: distributed LuGre PDE (eq. 14) vs lumped model (eqs. 22-25) on a 2 s braking.

The PDE's accuracy is measured against a fine reference (n = 96); the smallest collocation
degree whose force error stays below 1e-3 of the peak is then timed against the lumped model
(kappa0 = 1 and 2, whose error against the same reference is reported too).
`ratio` = PDE wall time / lumped wall time (how much the lumped model saves).
Run: python experiments/benchmarks/distributed_vs_lumped.py
"""

import argparse

import jax
import jax.numpy as jnp
import numpy as np
from _common import best_time, compile_time, emit, log

import vehsim as vs


jax.config.update("jax_enable_x64", True)
R = 0.3


def v_fn(t):
    return 25.0 - 8.0 * t


def om_fn(t):
    slip = -0.4 * jnp.clip(t / 0.4, 0.0, 1.0) * (1.0 - jnp.clip((t - 1.4) / 0.3, 0.0, 1.0))
    return v_fn(t) * (1.0 + slip) / R


def main():
    p = vs.params.table3()
    load = vs.QuarticLoad()
    ts = jnp.linspace(0.0, 2.0, 401)

    def run(model):
        return vs.simulate_tire(model, ts, v_fn, om_fn, R, rtol=1e-8, atol=1e-10).mu

    run = jax.jit(run)
    ref = np.asarray(run(vs.DistributedLuGre(p, load, n=96)))
    peak = float(np.max(np.abs(ref)))
    chosen = None
    for n in [4, 6, 8, 10, 12, 16, 24, 32]:
        err = float(np.max(np.abs(np.asarray(run(vs.DistributedLuGre(p, load, n=n))) - ref)) / peak)
        log(f"n = {n}: error/peak = {err:.2e}")
        emit(benchmark="distributed_vs_lumped", stage="pde_grid", n=n, error_over_peak=err)
        if err < 1e-3 and chosen is None:
            chosen = n
            break
    pde = vs.DistributedLuGre(p, load, n=chosen)
    fresh = jax.jit(lambda m: vs.simulate_tire(m, ts, v_fn, om_fn, R, rtol=1e-8, atol=1e-10).mu)
    t_pde_compile = compile_time(fresh, pde)
    t_pde = best_time(run, pde)
    err_pde = float(np.max(np.abs(np.asarray(run(pde)) - ref)) / peak)
    for kappa0 in [1.0, 2.0]:
        lumped = vs.LumpedLuGre(p, kappa0)
        t_l = best_time(run, lumped)
        err_l = float(np.max(np.abs(np.asarray(run(lumped)) - ref)) / peak)
        emit(benchmark="distributed_vs_lumped", load="quartic", pde_n=chosen,
             pde_error_over_peak=err_pde, pde_s=t_pde, pde_compile_s=t_pde_compile,
             lumped_kappa0=kappa0, lumped_s=t_l, lumped_error_over_peak=err_l,
             ratio=t_pde / t_l)


if __name__ == "__main__":
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    main()
