"""Reproduce report sections 2.3-2.4: combined-slip LuGre, Magic Formula, method of moments.

Figures 13, 14 (steady-state forces for several slip angles / slip ratios), 15 (LuGre vs the
1987 Magic Formula) and 17 (transient F_x, F_y, M_z for trapezoidal and quartic loads at
alpha = 4 and 15 deg, from the method-of-moments model; the full mode overlays the
distributed PDE and records the moments-vs-PDE error).
"""

from __future__ import annotations

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..params import bakker1987, lugre2d_bakker1987
from ..tire.distributed2d import DistributedLuGre2D, steady_state_forces
from ..tire.load import QuarticLoad, TrapezoidalLoad, UniformLoad
from ..tire.lugre2d_fit import default_slip_grid, match_residuals
from ..tire.magic_formula import combined_forces
from ..tire.moments import MomentLuGre2D, moments_step_response
from ..tire.transient import simulate_tire_2d


TITLE = "Combined longitudinal/lateral LuGre, Magic Formula and exact aggregate dynamics (2.3-2.4)"

V, FZ, R = 20.0, 4000.0, 0.3


def _steady_grid(params, load, kappa, alpha):
    f = jax.jit(jax.vmap(jax.vmap(lambda k, a: steady_state_forces(params, load, V, k, a, FZ),
                                  in_axes=(0, None)), in_axes=(None, 0)))
    return np.asarray(f(kappa, alpha))  # (n_alpha, n_kappa, 3)


def reproduce(ctx) -> None:
    p, mf = lugre2d_bakker1987(), bakker1987()
    n = 11 if ctx.tiny else 41 if ctx.quick else 101
    kappa = jnp.linspace(-0.5, 0.5, n)
    alpha = jnp.deg2rad(jnp.linspace(-15.0, 15.0, n))
    ctx.log("Fig. 13-14: steady-state 2D LuGre (uniform load, v = 20 m/s, Fz = 4 kN)")
    _fig13(ctx, p, kappa)
    _fig14(ctx, p, alpha)
    ctx.log("Fig. 15: LuGre vs Magic Formula 1987")
    _fig15(ctx, p, mf, kappa, alpha)
    ctx.log("Fig. 17: transients by the method of moments")
    _fig17(ctx, p)


def _fig13(ctx, p, kappa) -> None:
    """Fig. 13: forces vs slip ratio for several slip angles."""
    import matplotlib.pyplot as plt

    alphas_deg = np.array([0.0, 2.0, 4.0, 8.0, 15.0])
    F = _steady_grid(p, UniformLoad(), kappa, jnp.deg2rad(alphas_deg))
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for i, a in enumerate(alphas_deg):
        ax[0].plot(kappa, F[i, :, 0], label=f"alpha = {a:g} deg")
        ax[1].plot(kappa, F[i, :, 1], label=f"alpha = {a:g} deg")
    ax[0].set(xlabel="slip ratio kappa", ylabel="F_x [N]")
    ax[1].set(xlabel="slip ratio kappa", ylabel="F_y [N]")
    ax[0].legend(fontsize=8)
    for a_ in ax:
        a_.grid(alpha=0.3)
    ctx.figure(fig, "fig13_steady_vs_kappa",
               "Fig. 13: steady-state F_x, F_y of the distributed 2D LuGre model (preset "
               "lugre2d_bakker1987, uniform load) vs slip ratio for several slip angles")
    ctx.record("fig13.max_Fx_alpha0_N", float(F[0, :, 0].max()))
    ctx.record("fig13.Fx_at_kappa0.2_by_alpha_N",
               {f"{a:g}": float(np.interp(0.2, kappa, F[i, :, 0]))
                for i, a in enumerate(alphas_deg)})


def _fig14(ctx, p, alpha) -> None:
    """Fig. 14: forces vs slip angle for several slip ratios."""
    import matplotlib.pyplot as plt

    kappas = np.array([0.0, 0.05, 0.1, 0.2, -0.1])
    G = np.swapaxes(_steady_grid(p, UniformLoad(), jnp.asarray(kappas), alpha), 0, 1)
    fig, ax = plt.subplots(1, 3, figsize=(14, 4))
    for i, k in enumerate(kappas):
        for j in range(3):
            ax[j].plot(np.rad2deg(alpha), G[i, :, j], label=f"kappa = {k:g}")
    for j, lab in enumerate(["F_x [N]", "F_y [N]", "M_z [N m]"]):
        ax[j].set(xlabel="slip angle alpha [deg]", ylabel=lab)
        ax[j].grid(alpha=0.3)
    ax[1].legend(fontsize=8)
    ctx.figure(fig, "fig14_steady_vs_alpha",
               "Fig. 14: steady-state F_x, F_y, M_z of the distributed 2D LuGre model vs slip "
               "angle for several slip ratios")
    ctx.record("fig14.Fy_at_alpha4deg_by_kappa_N",
               {f"{k:g}": float(np.interp(4.0, np.rad2deg(alpha), G[i, :, 1]))
                for i, k in enumerate(kappas)})


def _fig15(ctx, p, mf, kappa, alpha) -> None:
    """Fig. 15: LuGre vs Magic Formula (pure slip), and the residual of the preset's fit."""
    import matplotlib.pyplot as plt

    load, zeros = UniformLoad(), jnp.zeros(kappa.shape[0])
    lug_k = _steady_grid(p, load, kappa, jnp.zeros(1))[0]
    lug_a = _steady_grid(p, load, jnp.zeros(1), alpha)[:, 0]
    mf_k = np.asarray(combined_forces(mf, kappa, zeros, FZ))
    mf_a = np.asarray(combined_forces(mf, zeros, alpha, FZ))
    fig, ax = plt.subplots(1, 3, figsize=(14, 4))
    ax[0].plot(kappa, lug_k[:, 0], label="LuGre (distributed, steady)")
    ax[0].plot(kappa, mf_k[:, 0], "--", label="Magic Formula 1987")
    ax[1].plot(np.rad2deg(alpha), lug_a[:, 1], np.rad2deg(alpha), mf_a[:, 1], "--")
    ax[2].plot(np.rad2deg(alpha), lug_a[:, 2], np.rad2deg(alpha), mf_a[:, 2], "--")
    ax[0].set(xlabel="slip ratio kappa", ylabel="F_x [N]")
    ax[1].set(xlabel="slip angle [deg]", ylabel="F_y [N]")
    ax[2].set(xlabel="slip angle [deg]", ylabel="M_z [N m]")
    ax[0].legend(fontsize=8)
    for a_ in ax:
        a_.grid(alpha=0.3)
    ctx.figure(fig, "fig15_lugre_vs_mf",
               "Fig. 15: steady 2D LuGre (fitted preset) vs the Bakker-Nyborg-Pacejka 1987 "
               "Magic Formula, Fz = 4 kN, v = 20 m/s (M_z was not fitted)")
    k0, a0 = default_slip_grid()
    res = np.asarray(match_residuals(p, mf, FZ, V, k0, a0))
    ctx.record("fig15.fit_rms_residual_over_Fz", float(np.sqrt(np.mean(res**2))))
    ctx.record("fig15.fit_max_residual_over_Fz", float(np.abs(res).max()))
    ctx.text(f"Fit of the 2D LuGre steady state to the Magic Formula (F_x, F_y pure slip): "
             f"RMS |F_LuGre - F_MF|/Fz = {np.sqrt(np.mean(res**2)):.4f}, "
             f"max = {np.abs(res).max():.4f}.")


T_PRE = 2.0
"""Milliseconds of the rest before the slip step drawn in Fig. 17."""


def _fig17(ctx, p) -> None:
    """Fig. 17: transients after a slip step, by the method of moments (and the PDE in the
    full mode), at alpha = 4 and 15 deg."""
    import matplotlib.pyplot as plt

    ts = jnp.linspace(0.0, 0.04, 161 if not ctx.quick else 81)
    fig, ax = plt.subplots(3, 2, figsize=(11, 9), sharex=True)
    errors, jumps = {}, {}
    for col, a_deg in enumerate((4.0, 15.0)):
        jumps[f"alpha{a_deg:g}"] = _fig17_column(ctx, p, ts, ax[:, col], a_deg, errors)
    ctx.record("fig17.jump_at_step_N", jumps)
    for j, lab in enumerate(["F_x [N]", "F_y [N]", "M_z [N m]"]):
        ax[j, 0].set_ylabel(lab)
        for c in range(2):
            ax[j, c].grid(alpha=0.3)
    ax[0, 0].legend(fontsize=8)
    ctx.figure(fig, "fig17_transients",
               "Fig. 17: transient F_x, F_y, M_z after a slip step at t = 0 (dashed line) from "
               "an undeflected patch with zero force (v = 20 m/s), trapezoidal and quartic "
               "loads, by the method of moments (the moment system of eqs. 41-42 solved "
               "exactly: `moments_step_response`)"
               + ("" if ctx.quick else "; dotted: distributed PDE, n = 64")
               + ". At t = 0+ every bristle moves at dz/dt = v_r, so F_x, F_y jump by "
               "F_n(sigma1 + sigma2)v_r (vertical segment; M_z does not jump for these "
               "symmetric loads) and the damping spike decays within about 1/C0 ~ 1 ms; the "
               "axes are scaled to the transients after it and its height is written where "
               "it leaves them. The report's curves (from [7], parameters not given) start "
               "from zero force too; the height of the jump depends on sigma1, which for our "
               "preset (0.7 s/m, unverified) is large.")
    if errors:
        ctx.record("fig17.moments_vs_pde_rel_err", errors)
        worst = max(max(v) for v in errors.values())
        ctx.text(f"Method of moments vs distributed PDE (n = 64): worst relative error "
                 f"{worst:.2e} over F_x, F_y, M_z.")


@eqx.filter_jit
def _pde_forces(model, ts, vx, vy, omega):
    return simulate_tire_2d(model, ts, vx, vy, omega, R, FZ, solver=dfx.Tsit5(),
                            rtol=1e-10, atol=1e-12).forces


@eqx.filter_jit
def _step_forces(model, ts, vx, vy, omega):  # the moment system solved exactly
    return moments_step_response(model, ts, vx, vy, omega, R, FZ).forces


def _fig17_column(ctx, p, ts, axes, a_deg: float, errors: dict) -> list:
    """One slip angle of Fig. 17; returns the jump of the forces at t = 0+.

    The slip is a step at t = 0 applied to an undeflected patch at rest in the road frame
    (z = 0, F = 0 before the step; the report's curves start from F = 0). At t = 0+ every
    bristle has dz/dt = v_r, so F jumps by F_n (sigma1 + sigma2) v_r (M_z by F_n L
    (sigma1y + sigma2y) v_ry int q (1/2 - xi) = 0 for symmetric loads), and that damping
    spike decays in ~1/C0 (about a millisecond): drawn as the vertical segment at t = 0,
    with the axes scaled to the transients and the spike's height written where it leaves
    the axes."""
    loads = {"trapezoidal": TrapezoidalLoad(0.25), "quartic": QuarticLoad()}
    t_plot = np.concatenate([[-T_PRE, 0.0], 1e3 * np.asarray(ts)])
    late = np.asarray(ts) >= 3e-3
    a = np.deg2rad(a_deg)
    vx, vy = V * np.cos(a), -V * np.sin(a)
    om = vx * 1.05 / R
    jump = FZ * np.asarray(p.sigma1 + p.sigma2) * np.array([om * R - vx, -vy])
    span = [[0.0, 0.0] for _ in range(3)]
    for name, ld in loads.items():
        Fm = np.asarray(_step_forces(MomentLuGre2D(p, ld), ts, vx, vy, om))
        for j in range(3):
            axes[j].plot(t_plot, np.concatenate([[0.0, 0.0], Fm[:, j]]),
                         label=f"{name} (moments)")
            span[j] = [min(span[j][0], Fm[late, j].min()), max(span[j][1], Fm[late, j].max())]
        ctx.record(f"fig17.alpha{a_deg:g}.{name}.final", Fm[-1].tolist())
        ctx.record(f"fig17.alpha{a_deg:g}.{name}.at_0plus", Fm[0].tolist())
        if not ctx.quick:
            Fp = np.asarray(_pde_forces(DistributedLuGre2D(p, ld, n=64), ts, vx, vy, om))
            for j in range(3):
                axes[j].plot(1e3 * np.asarray(ts), Fp[:, j], ":", color="k", lw=1)
            err = np.max(np.abs(Fm - Fp), axis=0) / np.max(np.abs(Fp), axis=0)
            errors[f"alpha{a_deg:g}.{name}"] = err.tolist()
    for j in range(3):
        lo, hi = span[j]
        pad = 0.15 * max(hi - lo, 1e-9)
        axes[j].set_ylim(lo - pad, hi + pad)
        axes[j].axvline(0.0, color="gray", lw=0.8, ls="--")
        if j < 2 and not lo - pad <= jump[j] <= hi + pad:
            y = hi + 0.5 * pad if jump[j] > 0 else lo - 0.5 * pad
            axes[j].annotate(
                f"t = 0+: jump of F_n(sigma1+sigma2)v_r = {jump[j]:.0f} N (off scale)",
                xy=(0.0, y), xytext=(4.0, y), fontsize=7, va="center",
                arrowprops=dict(arrowstyle="->", lw=0.6))
    axes[0].set_title(f"alpha = {a_deg:g} deg, kappa = 0.05")
    axes[2].set_xlabel("t [ms] (slip step at t = 0)")
    return jump.tolist()
