"""Benchmark: vmapped steady-state braking force (eq. 19) on a 10^6-point grid vs NumPy.

Grid: slip (100) x vehicle speed (100) x road condition theta (100). The baseline is the same
formula vectorised in NumPy (whole-array operations, no Python loops): a competent use of it.
Run: python experiments/benchmarks/steady_state_curves.py
"""

import jax
import jax.numpy as jnp
import numpy as np
from _common import best_time, compile_time, emit

import vehsim as vs


jax.config.update("jax_enable_x64", True)


def numpy_braking_mu(p, s, v, theta):
    v_r = v * s
    g = p["mu_c"] + (p["mu_s"] - p["mu_c"]) * np.exp(-np.abs(v_r / p["v_s"]) ** p["alpha"])
    one_s = np.abs(1.0 + s)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = theta * p["sigma0"] * p["L"] * np.abs(s) / (g * one_s)
        psi = np.where(x < 1e-3, 0.5 - x / 6 + x * x / 24, (x + np.expm1(-x)) / (x * x))
        rolling = p["sigma0"] * p["L"] * s / one_s * psi
    return np.where(one_s == 0, np.sign(s) * g / theta, rolling) + p["sigma2"] * v_r


def main():
    p = vs.params.table3()
    n = 100
    s = np.linspace(-1.0, 0.0, n)
    v = np.linspace(1.0, 40.0, n)
    th = np.linspace(1.0, 2.5, n)
    S, V, TH = (a.reshape(-1) for a in np.meshgrid(s, v, th, indexing="ij"))

    @jax.jit
    def vehsim_curves(S, V, TH):
        def one(s, v, theta):
            q = vs.LuGreParams(sigma0=p.sigma0, sigma1=p.sigma1, sigma2=p.sigma2, mu_c=p.mu_c,
                               mu_s=p.mu_s, v_s=p.v_s, alpha=p.alpha, theta=theta, L=p.L)
            return vs.braking_mu_uniform(q, s, v)

        return jax.vmap(one)(S, V, TH)

    Sj, Vj, THj = jnp.asarray(S), jnp.asarray(V), jnp.asarray(TH)
    t_compile = compile_time(vehsim_curves, Sj, Vj, THj)
    t_vehsim = best_time(vehsim_curves, Sj, Vj, THj)
    pn = {k: float(getattr(p, k)) for k in ["sigma0", "sigma2", "mu_c", "mu_s", "v_s", "alpha", "L"]}
    t_numpy = best_time(numpy_braking_mu, pn, S, V, TH)
    a = np.asarray(vehsim_curves(Sj, Vj, THj))
    b = numpy_braking_mu(pn, S, V, TH)
    emit(benchmark="steady_state_curves", points=int(S.size), device=jax.devices()[0].platform,
         vehsim_s=t_vehsim, numpy_s=t_numpy, compile_s=t_compile,
         vehsim_evals_per_s=S.size / t_vehsim, numpy_evals_per_s=S.size / t_numpy,
         ratio=t_numpy / t_vehsim, max_abs_difference=float(np.max(np.abs(a - b))))


if __name__ == "__main__":
    main()
