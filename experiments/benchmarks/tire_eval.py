"""Benchmark: the MF 6.1 tire of a tyre property file at 10^6 operating points vs NumPy.

Combined-slip F_x, F_y, M_z of the shipped sample (vehsim/data/tires/, MF 6.1) at 10^6
random operating points (slip ratio, slip angle, camber, load, pressure), with the file's
limits. vehsim: `vs.mf_forces`, jitted and vmapped. Baseline: the same equations written
here again for NumPy (whole-array operations, no Python loop over points, each
intermediate computed once): a competent vectorised evaluation. Each side is timed by its
best of 3 calls after a warm-up (vehsim's compilation apart), the two alternated over
`--rounds` rounds; `ratio` = NumPy wall time / vehsim wall time, the median over the rounds.
XLA may spread the fused loops over the cores where NumPy runs on one, so each side's CPU
time (`ratio_cpu_time`) is reported beside it, with the machine's load and the largest
difference of the results. NumPy's transcendental functions are vectorised (SIMD) on CPUs
that have the instructions, so the ratio depends on the processor.

Run: PYTHONPATH=. python experiments/benchmarks/tire_eval.py [--points N] [--out FILE]
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


def _mf(B, C, D, E, x):
    bx = B * x
    return D * np.sin(C * np.arctan(bx - E * (bx - np.arctan(bx))))


def _w(B, C, E, x):
    bx = B * x
    return np.cos(C * np.arctan(bx - E * (bx - np.arctan(bx))))


def numpy_mf61(c, kappa, alpha, gamma, Fz, p):
    """(F_x, F_y, M_z) of MF 6.1 (Pacejka 2012, 4.E1-4.E78 with the choices of
    vehsim.tire.mf6), NumPy, with the file's limits and E <= 1."""
    kappa = np.clip(kappa, c["KPUMIN"], c["KPUMAX"])
    alpha = np.clip(alpha, c["ALPMIN"], c["ALPMAX"])
    gamma = np.clip(gamma, c["CAMMIN"], c["CAMMAX"])
    p = np.clip(p, c["PRESMIN"], c["PRESMAX"])
    Fz = np.minimum(np.maximum(Fz, 0.0), c["FZMAX"])
    fz0p = c["LFZO"] * c["FNOMIN"]
    dfz = (Fz - fz0p) / fz0p
    dpi = (p - c["NOMPRES"]) / c["NOMPRES"]
    a = np.tan(alpha)
    g = np.sin(gamma)
    g2 = g * g
    R0 = c["UNLOADED_RADIUS"]
    # longitudinal
    Cx = c["PCX1"] * c["LCX"]
    mux = ((c["PDX1"] + c["PDX2"] * dfz) * (1 + c["PPX3"] * dpi + c["PPX4"] * dpi**2)
           * (1 - c["PDX3"] * g2) * c["LMUX"])
    kxn = ((c["PKX1"] + c["PKX2"] * dfz) * np.exp(c["PKX3"] * dfz)
           * (1 + c["PPX1"] * dpi + c["PPX2"] * dpi**2) * c["LKX"])
    Bx = kxn / (Cx * mux)
    kx = kappa + (c["PHX1"] + c["PHX2"] * dfz) * c["LHX"]
    Ex = np.minimum((c["PEX1"] + c["PEX2"] * dfz + c["PEX3"] * dfz**2)
                    * (1 - c["PEX4"] * np.sign(kx)) * c["LEX"], 1.0)
    Fx0 = _mf(Bx, Cx, mux * Fz, Ex, kx) + Fz * (c["PVX1"] + c["PVX2"] * dfz) * c["LVX"] * c["LMUX"]
    # lateral, at gamma and at gamma = 0 (for the aligning moment)
    Cy = c["PCY1"] * c["LCY"]

    def fy0(g, g2):
        cc = (c["PKY2"] + c["PKY5"] * g2) * (1 + c["PPY2"] * dpi)
        u = Fz / (fz0p * cc)
        kyn = (c["PKY1"] * (1 + c["PPY1"] * dpi) * (1 - c["PKY3"] * np.abs(g))
               * np.sin(c["PKY4"] * np.arctan(u)) / (u * cc) * c["LKY"])
        svyg = (c["PVY3"] + c["PVY4"] * dfz) * g * c["LKYC"] * c["LMUY"]
        kyg0 = (c["PKY6"] + c["PKY7"] * dfz) * (1 + c["PPY5"] * dpi) * c["LKYC"]
        shy = (c["PHY1"] + c["PHY2"] * dfz) * c["LHY"] + (kyg0 * g - svyg) / kyn
        svy = (c["PVY1"] + c["PVY2"] * dfz) * c["LVY"] * c["LMUY"] + svyg
        ay = a + shy
        muy = ((c["PDY1"] + c["PDY2"] * dfz) * (1 + c["PPY3"] * dpi + c["PPY4"] * dpi**2)
               * (1 - c["PDY3"] * g2) * c["LMUY"])
        Ey = np.minimum((c["PEY1"] + c["PEY2"] * dfz)
                        * (1 + c["PEY5"] * g2 - (c["PEY3"] + c["PEY4"] * g)
                           * np.where(ay < 0, -1.0, 1.0)) * c["LEY"], 1.0)
        By = kyn / (Cy * muy)
        return _mf(By, Cy, muy * Fz, Ey, ay) + svy * Fz, muy, kyn, By, shy, svy

    Fy0, muy, kyn, By, shy, svy = fy0(g, g2)
    zero = np.zeros_like(g)
    Fy0_0 = fy0(zero, zero)[0]
    # combined
    Bxa = (c["RBX1"] + c["RBX3"] * g2) * np.cos(np.arctan(c["RBX2"] * kappa)) * c["LXAL"]
    Exa = np.minimum(c["REX1"] + c["REX2"] * dfz, 1.0)
    Fx = _w(Bxa, c["RCX1"], Exa, a + c["RHX1"]) / _w(Bxa, c["RCX1"], Exa, c["RHX1"]) * Fx0
    Eyk = np.minimum(c["REY1"] + c["REY2"] * dfz, 1.0)
    shyk = c["RHY1"] + c["RHY2"] * dfz
    cos_b = np.cos(np.arctan(c["RBY2"] * (a - c["RBY3"]))) * c["LYKA"]

    def gyk(byk):
        return _w(byk, c["RCY1"], Eyk, kappa + shyk) / _w(byk, c["RCY1"], Eyk, shyk)

    svyk = (muy * Fz * (c["RVY1"] + c["RVY2"] * dfz + c["RVY3"] * g)
            * np.cos(np.arctan(c["RVY4"] * a)) * np.sin(c["RVY5"] * np.arctan(c["RVY6"] * kappa))
            * c["LVYKA"])
    Fy = gyk((c["RBY1"] + c["RBY4"] * g2) * cos_b) * Fy0 + svyk
    # aligning moment
    at = a + c["QHZ1"] + c["QHZ2"] * dfz + (c["QHZ3"] + c["QHZ4"] * dfz) * g
    ar = a + shy + svy / kyn
    Dt = ((c["QDZ1"] + c["QDZ2"] * dfz) * (1 - c["PPZ1"] * dpi) * (1 + c["QDZ3"] * g + c["QDZ4"] * g2)
          * Fz * (R0 / fz0p) * c["LTR"])
    Bt = ((c["QBZ1"] + c["QBZ2"] * dfz + c["QBZ3"] * dfz**2) * (1 + c["QBZ4"] * g + c["QBZ5"] * np.abs(g))
          * c["LKY"] / c["LMUY"])
    Ct = c["QCZ1"]
    Et = np.minimum((c["QEZ1"] + c["QEZ2"] * dfz + c["QEZ3"] * dfz**2)
                    * (1 + (c["QEZ4"] + c["QEZ5"] * g) * (2 / np.pi) * np.arctan(Bt * Ct * at)), 1.0)
    Dr = (Fz * R0 * ((c["QDZ6"] + c["QDZ7"] * dfz) * c["LRES"]
                     + ((c["QDZ8"] + c["QDZ9"] * dfz) * (1 + c["PPZ2"] * dpi)
                        + (c["QDZ10"] + c["QDZ11"] * dfz) * np.abs(g)) * g * c["LKZC"]) * c["LMUY"])
    Br = c["QBZ9"] * c["LKY"] / c["LMUY"] + c["QBZ10"] * By * Cy
    kk = (kxn / kyn) ** 2 * kappa**2
    cos_a = np.cos(alpha)
    t = Dt * _w(Bt, Ct, Et, np.sqrt(at**2 + kk)) * cos_a
    mzr = Dr * np.cos(np.arctan(Br * np.sqrt(ar**2 + kk))) * cos_a
    s = R0 * (c["SSZ1"] + c["SSZ2"] * Fy / fz0p + (c["SSZ3"] + c["SSZ4"] * dfz) * g) * c["LS"]
    Mz = -t * gyk(c["RBY1"] * cos_b) * Fy0_0 + mzr + s * Fx
    return np.stack([Fx, Fy, Mz], axis=-1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", default=None, help="append the JSON line to this file")
    args_ = ap.parse_args(argv)
    n = args_.points
    load_before = os.getloadavg()
    tir = vs.read_tir(vs.shipped_tires()["sample_185_80R14_mf61"])
    # pressure terms of a typical MF 6.1 car tire, so that the pressure path does work
    tir = tir.replace(PPX1=-0.35, PPX2=0.38, PPX3=-0.1, PPX4=0.06, PPY1=-0.65, PPY2=-0.8,
                      PPY3=-0.2, PPY4=0.2, PPY5=-0.1, PPZ1=-0.2, PPZ2=0.3)
    P = vs.MFParams.from_tir(tir)
    rng = np.random.default_rng(0)
    kappa = rng.uniform(-0.5, 0.5, n)
    alpha = rng.uniform(-0.3, 0.3, n)
    gamma = rng.uniform(-0.05, 0.05, n)
    Fz = rng.uniform(1000.0, 7000.0, n)
    p = rng.uniform(1.6e5, 2.2e5, n)

    @jax.jit
    def vehsim_eval(P, kappa, alpha, gamma, Fz, p):
        return jax.vmap(lambda k, a, g, f, q: vs.mf_forces(P, k, a, f, g, q))(
            kappa, alpha, gamma, Fz, p)

    args = (P,) + tuple(jnp.asarray(x) for x in (kappa, alpha, gamma, Fz, p))
    t_compile = compile_time(vehsim_eval, *args)
    c = {k: float(getattr(P, k)) for k in vs.tire.mf6.FIELD_NAMES}
    np_args = (c, kappa, alpha, gamma, Fz, p)
    rounds = [(best_time(vehsim_eval, *args, repeats=3),
               best_time(numpy_mf61, *np_args, repeats=3)) for _ in range(args_.rounds)]
    t_vehsim, t_numpy = (float(np.median(col)) for col in zip(*rounds))
    cpu_vehsim = cpu_time(vehsim_eval, *args, repeats=3)
    cpu_numpy = cpu_time(numpy_mf61, *np_args, repeats=3)
    a = np.asarray(vehsim_eval(*args))
    b = numpy_mf61(c, kappa, alpha, gamma, Fz, p)
    scale = np.max(np.abs(b), axis=0)
    row = dict(benchmark="tire_eval", tire="sample_185_80R14_mf61 (MF 6.1) + pressure terms",
               points=n, outputs="Fx, Fy, Mz combined", device=jax.devices()[0].platform,
               dtype="float64", cpu_count=os.cpu_count(),
               load_average_before_after=[round(load_before[0], 2),
                                          round(os.getloadavg()[0], 2)],
               vehsim_s=t_vehsim, numpy_s=t_numpy, compile_s=t_compile,
               vehsim_points_per_s=n / t_vehsim, numpy_points_per_s=n / t_numpy,
               ratio=float(np.median([b_ / a_ for a_, b_ in rounds])),
               ratio_per_round=[round(b_ / a_, 3) for a_, b_ in rounds],
               vehsim_cpu_s=cpu_vehsim, numpy_cpu_s=cpu_numpy,
               ratio_cpu_time=cpu_numpy / cpu_vehsim,
               max_abs_difference=[float(x) for x in np.max(np.abs(a - b), axis=0)],
               max_rel_difference=[float(x) for x in np.max(np.abs(a - b), axis=0) / scale],
               date=datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"))
    emit(**row)
    if args_.out:
        with open(args_.out, "a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
