"""Reproduce report sections 2.3-2.4: combined-slip LuGre, Magic Formula, method of moments.

Figures 13, 14 (steady-state forces for several slip angles / slip ratios), 15 (LuGre vs the
1987 Magic Formula at 2, 4 and 6 kN, F_x, F_y and M_z, with the fit's error table) and 17
(transient F_x, F_y, M_z for the uniform, trapezoidal and quartic loads at alpha = 4 and
15 deg: the slip reached through a wheel in a few milliseconds, by the distributed PDE, and
the pure slip step by the method of moments; the full mode overlays the PDE on the step and
records the moments-vs-PDE error), with the steady state of each load.
"""

from __future__ import annotations

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..params import bakker1987, lugre2d_bakker1987, lugre2d_bakker1987_mz
from ..tire.characteristic import tire_characteristic
from ..tire.distributed2d import DistributedLuGre2D, lever_moment, steady_state_forces
from ..tire.load import QuarticLoad, TrapezoidalLoad, UniformLoad
from ..tire.lugre2d_fit import QUANTITIES, default_slip_grid, match_errors
from ..tire.magic_formula import combined_forces, lateral_coefficients
from ..tire.moments import MomentLuGre2D, moments_step_response
from ..tire.transient import simulate_tire


TITLE = "Combined longitudinal/lateral LuGre, Magic Formula and exact aggregate dynamics (2.3-2.4)"

V, FZ, R = 20.0, 4000.0, 0.3
FIT_LOADS = (2000.0, 4000.0, 6000.0)
"""The loads [N] of the Magic Formula fit (Fig. 15)."""


@eqx.filter_jit
def _steady_grid_jit(params, load, kappa, alpha, Fz):
    return jax.vmap(jax.vmap(lambda k, a: steady_state_forces(params, load, V, k, a, Fz),
                             in_axes=(0, None)), in_axes=(None, 0))(kappa, alpha)


def _steady_grid(params, load, kappa, alpha, Fz=FZ):
    return np.asarray(_steady_grid_jit(params, load, kappa, alpha, jnp.asarray(Fz)))


def reproduce(ctx) -> None:
    p, mf = lugre2d_bakker1987(), bakker1987()
    n = 11 if ctx.tiny else 41 if ctx.quick else 101
    kappa = jnp.linspace(-0.5, 0.5, n)
    alpha = jnp.deg2rad(jnp.linspace(-15.0, 15.0, n))
    ctx.log("Fig. 13-14: steady-state 2D LuGre (uniform load, v = 20 m/s, Fz = 4 kN)")
    _fig13(ctx, p, kappa)
    _fig14(ctx, p, alpha)
    ctx.log("Fig. 15: LuGre vs Magic Formula 1987 at 2, 4, 6 kN")
    _fig15(ctx, mf, kappa, alpha)
    _fit_table(ctx, mf)
    ctx.log("Fig. 17: transients through the wheel (PDE) and after a pure step (moments)")
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


def _fig15(ctx, mf, kappa, alpha) -> None:
    """Fig. 15: the LuGre preset fitted to F_x, F_y and M_z at three loads vs the Magic
    Formula (pure slip), and the F_x, F_y-only preset at 4 kN for comparison."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
    zeros = jnp.zeros(kappa.shape[0])
    deg = np.rad2deg(alpha)
    for i, Fz in enumerate(FIT_LOADS):
        params, load = lugre2d_bakker1987_mz(Fz)
        lug_k = _steady_grid(params, load, kappa, jnp.zeros(1), Fz)[0]
        lug_a = _steady_grid(params, load, jnp.zeros(1), alpha, Fz)[:, 0]
        mf_k = np.asarray(combined_forces(mf, kappa, zeros, Fz))
        mf_a = np.asarray(combined_forces(mf, zeros, alpha, Fz))
        color = f"C{i}"
        ax[0].plot(kappa, lug_k[:, 0], color=color, label=f"LuGre, Fz = {Fz / 1e3:g} kN")
        ax[0].plot(kappa, mf_k[:, 0], "--", color=color, label=f"Magic Formula, {Fz / 1e3:g} kN")
        for j in (1, 2):
            ax[j].plot(deg, lug_a[:, j], color=color)
            ax[j].plot(deg, mf_a[:, j], "--", color=color)
    old = _steady_grid(lugre2d_bakker1987(), UniformLoad(), jnp.zeros(1), alpha)[:, 0]
    ax[2].plot(deg, old[:, 2], ":", color="gray", label="lugre2d_bakker1987 (4 kN, M_z not fitted)")
    ax[0].set(xlabel="slip ratio kappa", ylabel="F_x [N]")
    ax[1].set(xlabel="slip angle [deg]", ylabel="F_y [N]")
    ax[2].set(xlabel="slip angle [deg]", ylabel="M_z [N m]")
    ax[0].legend(fontsize=7)
    ax[2].legend(fontsize=7)
    for a_ in ax:
        a_.grid(alpha=0.3)
    ctx.figure(fig, "fig15_lugre_vs_mf",
               "Fig. 15: steady distributed 2D LuGre (preset lugre2d_bakker1987_mz: F_x, F_y "
               "and M_z fitted together at 2, 4 and 6 kN, load shape and patch length fitted; "
               "solid) vs the Bakker-Nyborg-Pacejka 1987 Magic Formula (dashed), v = 20 m/s; "
               "dotted: the F_x, F_y-only preset at 4 kN")


def _fit_sets():
    """The parameter sets of the fit table: name -> function of the load."""
    return {
        "lugre2d_bakker1987_mz": lambda Fz: lugre2d_bakker1987_mz(Fz),
        "lugre2d_bakker1987_mz(symmetric=True)": lambda Fz: lugre2d_bakker1987_mz(
            Fz, symmetric=True),
        "lugre2d_bakker1987": lambda Fz: (lugre2d_bakker1987(), UniformLoad()),
    }


def _fit_table(ctx, mf) -> None:
    """RMS and worst error of each curve relative to its peak, per set and load."""
    kappa, alpha = default_slip_grid()
    errors_fn = eqx.filter_jit(match_errors)
    table, rows = {}, []
    for name, make in _fit_sets().items():
        table[name] = {}
        for Fz in FIT_LOADS:
            params, load = make(Fz)
            errs = [np.asarray(e) for e in errors_fn(params, load, mf, Fz, V, kappa, alpha)]
            cells = {q: {"rms": float(np.sqrt(np.mean(e**2))), "max": float(np.abs(e).max())}
                     for q, e in zip(QUANTITIES, errs)}
            table[name][f"{Fz:g}"] = cells
            rows.append(f"| {name} | {Fz / 1e3:g} | " + " | ".join(
                f"{100 * cells[q]['rms']:.1f} ({100 * cells[q]['max']:.1f})"
                for q in QUANTITIES) + " |")
    ctx.record("fig15.fit_errors_relative_to_peak", table)
    ctx.text(
        "**Fit of the steady 2D LuGre model to the Magic Formula** (`fit_to_magic_formula`): "
        "RMS (worst) error of each pure-slip curve in % of the Magic Formula's peak of that "
        "curve at that load; F_x on kappa in [-0.5, 0.5], F_y and M_z on alpha in "
        "[0.5, 20] deg, v = 20 m/s.", "",
        "| parameter set | Fz [kN] | F_x | F_y | M_z |", "|---|---|---|---|---|", *rows)
    _aligning_text(ctx, mf)


def _mf_load_dependence(mf) -> dict:
    """The Magic Formula's normalised cornering stiffness and friction at the fit loads, and
    where its M_z changes sign at 4 kN."""
    out = {}
    for Fz in FIT_LOADS:
        B, C, D, _ = lateral_coefficients(mf, Fz)
        out[f"{Fz:g}"] = {"cornering_stiffness_per_load_1_per_rad":
                          float(np.rad2deg(B * C * D) / Fz), "mu_y_peak": float(D / Fz)}
    a = jnp.deg2rad(jnp.linspace(0.5, 20.0, 391))
    mz = np.asarray(combined_forces(mf, jnp.zeros_like(a), a, FZ))[:, 2]
    out["Mz_sign_change_deg_4kN"] = float(np.rad2deg(a[np.argmax(mz > 0)]))
    return out


def _aligning_text(ctx, mf) -> None:
    """What the LuGre M_z can and cannot reproduce, with the numbers at 4 kN."""
    a = jnp.deg2rad(jnp.array([20.0]))
    mf_large = float(combined_forces(mf, 0.0, a[0], FZ)[2])
    large, levers = {}, {}
    for name, make in _fit_sets().items():
        params, load = make(FZ)
        large[name] = float(_steady_grid(params, load, jnp.zeros(1), a)[0, 0, 2])
        levers[name] = float(lever_moment(load))
    dep = _mf_load_dependence(mf)
    lo, hi = dep[f"{FIT_LOADS[0]:g}"], dep[f"{FIT_LOADS[-1]:g}"]
    ctx.record("fig15.Mz_at_20deg_4kN", {"magic_formula": mf_large, **large})
    ctx.record("fig15.magic_formula_load_dependence", dep)
    ctx.text(
        "**What the LuGre aligning torque can and cannot reproduce.** At steady state the "
        "bristles enter the patch undeflected and their lateral deflection grows "
        "monotonically towards the trailing edge, so with a load symmetric about the patch "
        "centre every pair of points xi, 1 - xi contributes a moment of the aligning sign: "
        "M_z is aligning at every slip angle and decays to zero as the patch saturates. It "
        "cannot change sign. The Magic Formula's M_z does (at 4 kN from "
        f"{dep['Mz_sign_change_deg_4kN']:.1f} deg; {mf_large:+.1f} N m at 20 deg): the LuGre "
        "model follows only when the load's centre of pressure lies ahead of the patch "
        "centre, for then M_z tends to F_y L int q (1/2 - xi) > 0 as the whole patch "
        "slides. At 20 deg and 4 kN: "
        + "; ".join(f"{n} {v:+.1f} N m (centre of pressure {levers[n]:.3f} L ahead)"
                    for n, v in large.items())
        + ". The skewed load pays for the sign change with the trail at small slip angles, "
        "which the same shape shortens, so the fit lengthens the patch. And no load shape "
        "gives the Magic Formula's change with load: the LuGre forces are per unit normal "
        "load (F = F_n(sigma0 z + ...)), so at a given patch length its cornering stiffness "
        "is proportional to F_z and its friction coefficient independent of it, while the "
        "Magic Formula's cornering stiffness per unit load falls from "
        f"{lo['cornering_stiffness_per_load_1_per_rad']:.1f} to "
        f"{hi['cornering_stiffness_per_load_1_per_rad']:.1f} 1/rad and its peak F_y/F_z "
        f"from {lo['mu_y_peak']:.3f} to {hi['mu_y_peak']:.3f} between "
        f"{FIT_LOADS[0] / 1e3:g} and {FIT_LOADS[-1] / 1e3:g} kN; the fitted patch-length "
        "law L ~ F_z^p is the model's only way to follow, and it cannot do both (the trail "
        "asks for a patch growing with load, the stiffness for one shrinking).")


T_PRE = 2.0
"""Milliseconds of the rest before the slip step drawn in Fig. 17."""

RISE_TIME = 0.002
"""Time constant [s] of the wheel's approach to the slip in Fig. 17 (a wheel of finite
inertia, and a steering of finite rate, reach the slip in a few milliseconds)."""

FIG17_LOADS = {"uniform": UniformLoad(), "trapezoidal": TrapezoidalLoad(0.25),
               "quartic": QuarticLoad()}
FIG17_KAPPA = 0.05


def _fig17(ctx, p) -> None:
    """Fig. 17 through the wheel (the default), the pure step, and the steady state of each
    load at both slip angles."""
    ts = jnp.linspace(0.0, 0.04, 161)
    alphas = (4.0, 15.0)
    wheel = _wheel_forces(p, ts, alphas, n=16 if ctx.quick else 48)
    _fig17_wheel_figure(ctx, ts, alphas, wheel, RISE_TIME)
    steps = _fig17_step(ctx, p, ts, alphas)
    _steady_table(ctx, p, alphas, wheel, steps)


def _pde_batch(p, n: int):
    """The distributed PDE for each load of `FIG17_LOADS`, stacked into one batch. The load
    enters a `DistributedLuGre2D` only through the quadrature weights computed when it is
    built, so a common placeholder in its `load` field lets the three share one compile."""
    models = [eqx.tree_at(lambda m: m.load, DistributedLuGre2D(p, ld, n=n), UniformLoad())
              for ld in FIG17_LOADS.values()]
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *models)


def wheel_inputs(alpha, kappa, rise_time):
    r"""$(v_x, v_y, \omega)(t)$ of a wheel at speed `V` whose slip angle and slip ratio rise
    to `alpha`, `kappa` as $1 - e^{-t/\tau}$ from rolling straight at $t = 0$ ($\tau$ =
    `rise_time` > 0)."""

    def ramp(t):
        return -jnp.expm1(-jnp.maximum(t, 0.0) / rise_time)

    def vx(t):
        return V * jnp.cos(alpha * ramp(t))

    def vy(t):
        return -V * jnp.sin(alpha * ramp(t))

    def omega(t):
        return vx(t) * (1.0 + kappa * ramp(t)) / R

    return vx, vy, omega


@eqx.filter_jit
def _wheel_solve(models, ts, alphas, rise_time):
    def one(model, a):
        vx, vy, om = wheel_inputs(a, FIG17_KAPPA, rise_time)
        return simulate_tire(model, ts, vx, om, R, vy=vy, Fz=FZ, solver=dfx.Tsit5(), rtol=1e-7,
                             atol=1e-9).forces

    return jax.vmap(jax.vmap(one, in_axes=(0, None)), in_axes=(None, 0))(models, alphas)


def _wheel_forces(p, ts, alphas, n: int) -> np.ndarray:
    """(alpha, load, t, 3) forces of the slip reached through the wheel (distributed PDE)."""
    return np.asarray(_wheel_solve(_pde_batch(p, n), ts, jnp.deg2rad(jnp.asarray(alphas)),
                                   RISE_TIME))


def _fig17_wheel_figure(ctx, ts, alphas, F, rise_time) -> None:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(3, 2, figsize=(11, 9), sharex=True)
    t_ms = 1e3 * np.asarray(ts)
    for col, a_deg in enumerate(alphas):
        for k, name in enumerate(FIG17_LOADS):
            for j in range(3):
                ax[j, col].plot(t_ms, F[col, k, :, j], label=name)
        ax[0, col].set_title(f"alpha = {a_deg:g} deg, kappa = {FIG17_KAPPA:g}")
        ax[2, col].set_xlabel("t [ms]")
    _label_force_panels(ax)
    ctx.figure(fig, "fig17_transients",
               "Fig. 17: transient F_x, F_y, M_z for the uniform, trapezoidal and quartic "
               "loads at alpha = 4 and 15 deg (v = 20 m/s, preset lugre2d_bakker1987), the "
               "slip reached through the wheel: slip angle and slip ratio rise as "
               f"1 - exp(-t/tau), tau = {1e3 * rise_time:g} ms, from rolling straight "
               "(distributed PDE, Chebyshev collocation). The damping term "
               "F_n sigma1 dz/dt still overshoots while the bristles catch up with the "
               "slip, far less than after a pure step (next figure).")
    ctx.record("fig17.wheel.rise_time_s", rise_time)
    ctx.record("fig17.wheel.peak_abs_N", {
        f"alpha{a:g}.{name}": np.abs(F[c, k]).max(axis=0).tolist()
        for c, a in enumerate(alphas) for k, name in enumerate(FIG17_LOADS)})


def _label_force_panels(ax) -> None:
    """Axis labels, grids and the legend of Fig. 17's 3 x 2 panels (F_x, F_y, M_z rows)."""
    for j, lab in enumerate(["F_x [N]", "F_y [N]", "M_z [N m]"]):
        ax[j, 0].set_ylabel(lab)
        for c in range(2):
            ax[j, c].grid(alpha=0.3)
    ax[0, 0].legend(fontsize=8)


@eqx.filter_jit
def _pde_forces(model, ts, vx, vy, omega):
    return simulate_tire(model, ts, vx, omega, R, vy=vy, Fz=FZ, solver=dfx.Tsit5(),
                         rtol=1e-10, atol=1e-12).forces


@eqx.filter_jit
def _step_forces(model, ts, vx, vy, omega):  # the moment system solved exactly
    return moments_step_response(model, ts, vx, vy, omega, R, FZ).forces


def _fig17_step(ctx, p, ts, alphas) -> np.ndarray:
    """The pure slip step (the option kept beside the wheel); returns (alpha, load, t, 3)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(3, 2, figsize=(11, 9), sharex=True)
    errors, jumps, forces = {}, {}, []
    for col, a_deg in enumerate(alphas):
        F, jumps[f"alpha{a_deg:g}"] = _fig17_column(ctx, p, ts, ax[:, col], a_deg, errors)
        forces.append(F)
    ctx.record("fig17.jump_at_step_N", jumps)
    _label_force_panels(ax)
    ctx.figure(fig, "fig17_pure_step",
               "Fig. 17 with a pure slip step at t = 0 (dashed line) from an undeflected "
               "patch with zero force (v = 20 m/s), by the method of moments (the moment "
               "system of eqs. 41-42 solved exactly: `moments_step_response`)"
               + ("" if ctx.quick else "; dotted: distributed PDE, n = 64")
               + ". At t = 0+ every bristle moves at dz/dt = v_r, so F_x, F_y jump by "
               "F_n(sigma1 + sigma2)v_r (vertical segment; M_z does not jump for these "
               "symmetric loads) and the damping spike decays within about 1/C0 ~ 1 ms; the "
               "axes are scaled to the transients after it and its height is written where "
               "it leaves them. The height of the jump depends on sigma1, which for our "
               "preset (0.7 s/m, unverified) is large; fitting the steady state to the Magic "
               "Formula cannot tell sigma1 (it does not enter the steady state).")
    if errors:
        ctx.record("fig17.moments_vs_pde_rel_err", errors)
        worst = max(max(v) for v in errors.values())
        ctx.text(f"Method of moments vs distributed PDE (n = 64), pure step: worst relative "
                 f"error {worst:.2e} over F_x, F_y, M_z.")
    return np.stack(forces)


def _fig17_column(ctx, p, ts, axes, a_deg: float, errors: dict):
    """One slip angle of the pure-step figure; returns its forces (load, t, 3) and the jump
    of the forces at t = 0+.

    The slip is a step at t = 0 applied to an undeflected patch at rest in the road frame
    (z = 0, F = 0 before the step). At t = 0+ every bristle has dz/dt = v_r, so F jumps by
    F_n (sigma1 + sigma2) v_r (M_z by F_n L (sigma1y + sigma2y) v_ry int q (1/2 - xi) = 0
    for symmetric loads), and that damping spike decays in ~1/C0 (about a millisecond):
    drawn as the vertical segment at t = 0, with the axes scaled to the transients and the
    spike's height written where it leaves the axes."""
    t_plot = np.concatenate([[-T_PRE, 0.0], 1e3 * np.asarray(ts)])
    late = np.asarray(ts) >= 3e-3
    a = np.deg2rad(a_deg)
    vx, vy = V * np.cos(a), -V * np.sin(a)
    om = vx * (1.0 + FIG17_KAPPA) / R
    jump = FZ * np.asarray(p.sigma1 + p.sigma2) * np.array([om * R - vx, -vy])
    span = [[0.0, 0.0] for _ in range(3)]
    out = []
    for name, ld in FIG17_LOADS.items():
        Fm = np.asarray(_step_forces(MomentLuGre2D(p, ld), ts, vx, vy, om))
        out.append(Fm)
        for j in range(3):
            axes[j].plot(t_plot, np.concatenate([[0.0, 0.0], Fm[:, j]]),
                         label=f"{name} (moments)")
            span[j] = [min(span[j][0], Fm[late, j].min()), max(span[j][1], Fm[late, j].max())]
        ctx.record(f"fig17.alpha{a_deg:g}.{name}.at_0plus", Fm[0].tolist())
        if not ctx.quick:
            Fp = np.asarray(_pde_forces(DistributedLuGre2D(p, ld, n=64), ts, vx, vy, om))
            for j in range(3):
                axes[j].plot(1e3 * np.asarray(ts), Fp[:, j], ":", color="k", lw=1)
            err = np.max(np.abs(Fm - Fp), axis=0) / np.max(np.abs(Fp), axis=0)
            errors[f"alpha{a_deg:g}.{name}"] = err.tolist()
    _mark_jump(axes, span, jump)
    axes[0].set_title(f"alpha = {a_deg:g} deg, kappa = {FIG17_KAPPA:g}")
    axes[2].set_xlabel("t [ms] (slip step at t = 0)")
    return np.stack(out), jump.tolist()


def _mark_jump(axes, span, jump) -> None:
    """Axes scaled to the transients after the spike; the spike's height written."""
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


def _steady_table(ctx, p, alphas, wheel, steps) -> None:
    """Steady F_x, F_y, M_z of each load at both slip angles: the closed form, and where the
    transients end; the spread across loads checks the report's 'same steady-state'."""
    rows, record, spread = [], {}, {}
    for c, a_deg in enumerate(alphas):
        a = np.deg2rad(a_deg)
        closed = np.stack([np.asarray(steady_state_forces(p, ld, V, FIG17_KAPPA, a, FZ))
                           for ld in FIG17_LOADS.values()])
        for k, name in enumerate(FIG17_LOADS):
            end = max(np.abs(wheel[c, k, -1] - closed[k]).max(),
                      np.abs(steps[c, k, -1] - closed[k]).max())
            rows.append(f"| {a_deg:g} | {name} | {closed[k, 0]:.0f} | {closed[k, 1]:.0f} | "
                        f"{closed[k, 2]:.1f} | {end:.2g} |")
            record[f"alpha{a_deg:g}.{name}"] = {
                "F_x": float(closed[k, 0]), "F_y": float(closed[k, 1]),
                "M_z": float(closed[k, 2]), "transients_end_minus_steady": float(end)}
        rel = (closed.max(0) - closed.min(0)) / np.abs(closed).max(0)
        spread[f"alpha{a_deg:g}"] = dict(zip(QUANTITIES, rel.tolist()))
    ctx.record("fig17.steady_state", record)
    ctx.record("fig17.steady_spread_across_loads", spread)
    s4, s15 = spread[f"alpha{alphas[0]:g}"], spread[f"alpha{alphas[1]:g}"]
    ctx.text(
        f"**Steady state of Fig. 17** (kappa = {FIG17_KAPPA:g}, v = 20 m/s, Fz = 4 kN; "
        "closed form of eqs. 31-33; the last column: the largest difference from it of "
        "both transients at t = 40 ms, in N or N m).", "",
        "| alpha [deg] | load | F_x [N] | F_y [N] | M_z [N m] | transients' end |",
        "|---|---|---|---|---|---|", *rows)
    ctx.text(
        "The report: \"the three normal load models converge to the same steady-state, as "
        "expected\". Each transient does converge, after one transit of the patch, to its "
        "own load's steady state, but these are not the same: across the three loads F_x "
        f"and F_y differ by {100 * max(s4['F_x'], s4['F_y']):.0f} % at 4 deg and "
        f"{100 * max(s15['F_x'], s15['F_y']):.0f} % at 15 deg, and M_z by "
        f"{100 * s4['M_z']:.0f} % and {100 * s15['M_z']:.0f} % (relative to the largest). "
        "The claim holds roughly for the forces and not for the aligning torque: the "
        "steady deflection z_ss(xi) is the same for every load, but the forces weigh it by "
        "the load q(xi), and M_z by q(xi)(1/2 - xi), whose integral against a deflection "
        "growing from the leading edge depends strongly on how much load the patch's ends "
        "carry.")


# --- Figs. 13-15 and the fit table for a tire the user brings --------------------------------

TIR_ALPHAS_DEG = (0.0, 2.0, 4.0, 8.0, 15.0)
"""Slip angles [deg] of the curves of Fig. 13 for a fitted tire."""

TIR_KAPPAS = (0.0, 0.05, 0.1, 0.2, -0.1)
"""Slip ratios of the curves of Fig. 14 for a fitted tire."""


@eqx.filter_jit
def _lugre_grid(params, load, v, kappa, alpha, Fz):
    """Steady LuGre (F_x, F_y, M_z), shape (alpha, kappa, 3)."""
    return jax.vmap(jax.vmap(lambda k, a: steady_state_forces(params, load, v, k, a, Fz),
                             in_axes=(0, None)), in_axes=(None, 0))(kappa, alpha)


@eqx.filter_jit
def _characteristic_grid(char, kappa, alpha, Fz):
    """The characteristic's (F_x, F_y, M_z), shape (alpha, kappa, 3)."""
    return char.forces(kappa[None, :], alpha[:, None], Fz)


def lugre_fit_curves(mf, fit, v: float = V, kappa=None, alpha=None, n: int = 61) -> dict:
    """The curves of Figs. 13-15 for the fit `fit` (a `MatchResult`) of the LuGre model to
    `mf` (anything `tire_characteristic` takes): pure slip at each fitted load (Fig. 15)
    and combined slip at the reference load (Figs. 13, 14), LuGre and Magic Formula, on
    `n` points spanning the fit's grids `kappa`, `alpha` (default the characteristic's)."""
    char = tire_characteristic(mf)
    k_fit, a_fit = char.slip_grid()
    k_fit = k_fit if kappa is None else kappa
    a_fit = a_fit if alpha is None else alpha
    kappa = jnp.linspace(float(jnp.min(k_fit)), float(jnp.max(k_fit)), n)
    alpha = jnp.linspace(float(jnp.min(a_fit)), float(jnp.max(a_fit)), n)
    v = jnp.asarray(v, dtype=float)
    zero = jnp.zeros(1)
    out = {"kappa": np.asarray(kappa), "alpha_deg": np.rad2deg(np.asarray(alpha)),
           "loads": [float(f) for f in np.asarray(fit.loads)],
           "reference_load": float(fit.reference_load),
           "alphas13_deg": TIR_ALPHAS_DEG, "kappas14": TIR_KAPPAS}
    pure = {"lugre": [], "mf": []}
    for Fz in out["loads"]:
        p = fit.params_at(Fz)
        fz = jnp.asarray(Fz)
        lk = np.asarray(_lugre_grid(p, fit.load, v, kappa, zero, fz))[0, :, 0]
        la = np.asarray(_lugre_grid(p, fit.load, v, zero, alpha, fz))[:, 0]
        mk = np.asarray(_characteristic_grid(char, kappa, zero, fz))[0, :, 0]
        ma = np.asarray(_characteristic_grid(char, zero, alpha, fz))[:, 0]
        pure["lugre"].append(np.stack([lk, la[:, 1], la[:, 2]]))
        pure["mf"].append(np.stack([mk, ma[:, 1], ma[:, 2]]))
    out["pure"] = {k: np.stack(v_) for k, v_ in pure.items()}  # (load, 3, point)
    Fz0 = jnp.asarray(out["reference_load"])
    p0 = fit.params_at(Fz0)
    a13, k14 = jnp.deg2rad(jnp.asarray(TIR_ALPHAS_DEG)), jnp.asarray(TIR_KAPPAS)
    out["fig13"] = {"lugre": np.asarray(_lugre_grid(p0, fit.load, v, kappa, a13, Fz0)),
                    "mf": np.asarray(_characteristic_grid(char, kappa, a13, Fz0))}
    out["fig14"] = {  # (kappa, alpha, 3)
        "lugre": np.swapaxes(np.asarray(_lugre_grid(p0, fit.load, v, k14, alpha, Fz0)), 0, 1),
        "mf": np.swapaxes(np.asarray(_characteristic_grid(char, k14, alpha, Fz0)), 0, 1)}
    return out


_NAMES = ("F_x [N]", "F_y [N]", "M_z [N m]")


def _draw_fig15(ax, c) -> None:
    for i, Fz in enumerate(c["loads"]):
        color = f"C{i}"
        for j in range(3):
            x = c["kappa"] if j == 0 else c["alpha_deg"]
            ax[j].plot(x, c["pure"]["lugre"][i, j], color=color,
                       label=f"LuGre, {Fz:.0f} N")
            ax[j].plot(x, c["pure"]["mf"][i, j], "--", color=color,
                       label=f"Magic Formula, {Fz:.0f} N")
    ax[0].set(xlabel="slip ratio kappa", ylabel=_NAMES[0], title="Fig. 15: pure slip")
    ax[1].set(xlabel="slip angle [deg]", ylabel=_NAMES[1])
    ax[2].set(xlabel="slip angle [deg]", ylabel=_NAMES[2])
    ax[0].legend(fontsize=7)


def _draw_combined(ax, c, fig: str, x, xlabel: str, values, label) -> None:
    """Figs. 13-14: LuGre (solid) and Magic Formula (dashed) at each of `values`."""
    Fz = c["reference_load"]
    for i, value in enumerate(values):
        for j in range(3):
            ax[j].plot(x, c[fig]["lugre"][i, :, j], color=f"C{i}", label=label(value))
            ax[j].plot(x, c[fig]["mf"][i, :, j], "--", color=f"C{i}")
    for j in range(3):
        ax[j].set(xlabel=xlabel, ylabel=_NAMES[j])
    ax[0].set_title(f"Fig. {fig[3:]}: combined slip at {Fz:.0f} N (dashed: Magic Formula)")
    ax[0].legend(fontsize=7)


def _draw_fig13(ax, c) -> None:
    _draw_combined(ax, c, "fig13", c["kappa"], "slip ratio kappa", c["alphas13_deg"],
                   lambda a: f"alpha = {a:g} deg")


def _draw_fig14(ax, c) -> None:
    _draw_combined(ax, c, "fig14", c["alpha_deg"], "slip angle [deg]", c["kappas14"],
                   lambda k: f"kappa = {k:g}")


def _finish(fig, ax, title: str):
    for a_ in np.ravel(ax):
        a_.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def lugre_fit_figure(curves: dict, title: str = ""):
    """Figs. 15, 13 and 14 (rows) of `lugre_fit_curves` in one figure: the fitted LuGre model
    (solid) against the Magic Formula (dashed)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(3, 3, figsize=(15, 12))
    _draw_fig15(ax[0], curves)
    _draw_fig13(ax[1], curves)
    _draw_fig14(ax[2], curves)
    return _finish(fig, ax, title)


def _errors_by_load(loads, rms, worst, peak) -> list[dict]:
    units = {"F_x": "N", "F_y": "N", "M_z": "N_m"}
    rows = []
    for i, Fz in enumerate(loads):
        row = {"load_N": float(Fz)}
        for j, q in enumerate(QUANTITIES):
            u = units[q]
            row[q] = {f"peak_{u}": float(peak[i, j]), f"rms_{u}": float(rms[i, j] * peak[i, j]),
                      f"max_{u}": float(worst[i, j] * peak[i, j]),
                      "rms_relative_to_peak": float(rms[i, j]),
                      "max_relative_to_peak": float(worst[i, j])}
        rows.append(row)
    return rows


STRIBECK_SPEEDS = (0.2, 1.0, 3.0, 10.0)
"""Slip speeds [m/s] at which the record states the fitted friction $g(v)$ of eq. 29."""


def _lugre_record(params, load_weights, exponent, reference_load) -> dict:
    v = np.asarray(STRIBECK_SPEEDS)[:, None]
    mu_k, mu_s = np.asarray(params.mu_k), np.asarray(params.mu_s)
    g = mu_k + (mu_s - mu_k) * np.exp(-(v / float(params.v_s)) ** float(params.gamma))
    return {
        "sigma0_per_m": np.asarray(params.sigma0), "sigma1_s_per_m": np.asarray(params.sigma1),
        "sigma2_s_per_m": np.asarray(params.sigma2), "mu_k": np.asarray(params.mu_k),
        "mu_s": np.asarray(params.mu_s), "v_s_m_per_s": float(params.v_s),
        "gamma": float(params.gamma), "L0_m": float(params.L),
        "patch_length_law": "L = L0 (F_z / reference_load_N)^patch_exponent",
        "patch_exponent": float(exponent), "reference_load_N": float(reference_load),
        "load_weights": None if load_weights is None else np.asarray(load_weights),
        "friction_at_slip_speed": {  # what the steady state sees of mu_k, mu_s, v_s, gamma
            "slip_speed_m_per_s": np.asarray(STRIBECK_SPEEDS), "g_x": g[:, 0], "g_y": g[:, 1]},
        "load_shape": "q(xi) ~ sum_k w_k binom(4, k) xi^k (1 - xi)^(4 - k), xi = 0 at the "
                      "leading edge",
    }


def lugre_fit_record(mf, fit, init, v, kappa, alpha) -> dict:
    """What a fit of the LuGre model to `mf` found, as JSON-ready data with units: the
    parameters (fitted and the start `init`), the grids, the error table (RMS and worst
    error of F_x, F_y, M_z at each load, in N or N m and relative to the curve's peak) at
    the fit and at the start (uniform load), the Stribeck parameters `held`, and the outcome:
    `status` and `message` (`MatchResult.message`), Levenberg-Marquardt's own
    `solver_status`, and the numbers of MINPACK's tests."""
    from .._results import result_record
    from ..tire.lugre2d_fit import match_errors

    errors_fn = eqx.filter_jit(match_errors)
    loads = np.asarray(fit.loads)
    rms0, max0 = [], []
    for Fz in loads:
        e = [np.asarray(x) for x in errors_fn(init, UniformLoad(), mf, Fz, v, kappa, alpha)]
        rms0.append([np.sqrt(np.mean(x**2)) for x in e])
        max0.append([np.abs(x).max() for x in e])
    peak = np.asarray(fit.peak)
    return {
        "speed_m_per_s": float(v), "loads_N": loads,
        "slip_ratio_grid": np.asarray(kappa), "slip_angle_grid_deg": np.rad2deg(np.asarray(alpha)),
        "slip_angle_sign": "positive when the wheel slides to its right (report, "
                           "vehsim.AbstractTire); a tyre property file's alpha is its negative",
        "lugre": _lugre_record(fit.params, fit.load_weights, fit.patch_exponent,
                               fit.reference_load),
        "initial_guess": _lugre_record(init, None, 0.0, fit.reference_load),
        "errors": _errors_by_load(loads, np.asarray(fit.rms_error), np.asarray(fit.max_error),
                                  peak),
        "initial_errors": _errors_by_load(loads, np.asarray(rms0), np.asarray(max0), peak),
        "held": list(fit.held),
        **result_record(fit.result), "message": fit.message,
        "solver_status": result_record(fit.solver_result)["status"],
        "num_steps": int(fit.num_steps), "gradient_cosine": float(fit.gradient_cosine),
        "predicted_relative_reduction": float(fit.predicted_reduction),
    }


def fit_table(record: dict, key: str = "errors") -> list[str]:
    """The error table of `lugre_fit_record` as Markdown lines: RMS and worst error of each
    curve at each load, in N (N m) and in % of the curve's peak."""
    rows = ["| F_z [N] | F_x RMS [N] | F_x max [N] | F_y RMS [N] | F_y max [N] | "
            "M_z RMS [N m] | M_z max [N m] |", "|---|---|---|---|---|---|---|"]
    for row in record[key]:
        cells = []
        for q in QUANTITIES:
            u = "N_m" if q == "M_z" else "N"
            cells += [f"{row[q][f'{s}_{u}']:.1f} ({100 * row[q][f'{s}_relative_to_peak']:.1f} %)"
                      for s in ("rms", "max")]
        rows.append(f"| {row['load_N']:.0f} | " + " | ".join(cells) + " |")
    return rows


def fit_lugre_to(mf, v: float = V, loads=None, max_steps: int = 1024, init=None, **kwargs):
    """Fit the LuGre model to `mf` (anything `tire_characteristic` takes) on its default
    grids (`fit_to_magic_formula` with `throw=False`); return `(fit, record)` with the
    record of `lugre_fit_record`."""
    from ..tire.lugre2d_fit import fit_to_magic_formula, lugre_initial_guess

    char = tire_characteristic(mf)
    kappa, alpha = char.slip_grid()
    init = lugre_initial_guess(char) if init is None else init
    fit = fit_to_magic_formula(char, init, loads=loads, v=v, kappa=kappa, alpha=alpha,
                               max_steps=max_steps, throw=False, **kwargs)
    return fit, lugre_fit_record(char, fit, init, v, kappa, alpha)


def figures_for_tir(path, out, v: float = V, loads=None, max_steps: int = 1024, **kwargs):
    """Figs. 13-15 and the fit table for the tyre property file at `path`: fit the LuGre
    model to its Magic Formula (`fit_lugre_to`) and write, into the folder `out`,
    ``fig13_steady_vs_kappa.png``, ``fig14_steady_vs_alpha.png``,
    ``fig15_lugre_vs_mf.png`` (LuGre solid, the file's Magic Formula dashed) and
    ``lugre_fit.json`` (`lugre_fit_record`, with the file). Returns `(fit, record)`."""
    from pathlib import Path

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import save_figure, write_json
    from .._result_files import with_units
    from ..tire.mf6 import MFParams
    from ..tire.tir import read_tir

    tir = read_tir(path)
    params = MFParams.from_tir(tir)
    fit, record = fit_lugre_to(params, v, loads, max_steps, **kwargs)
    record = {"file": str(path), "version": tir.version, **record}
    curves = lugre_fit_curves(params, fit, v)
    out = Path(out)
    name = Path(path).name
    for stem, draw in (("fig13_steady_vs_kappa", _draw_fig13),
                       ("fig14_steady_vs_alpha", _draw_fig14),
                       ("fig15_lugre_vs_mf", _draw_fig15)):
        fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))
        draw(ax, curves)
        save_figure(_finish(fig, ax, f"{name}: distributed 2D LuGre fitted to its Magic "
                                     "Formula"), out / f"{stem}.png")
        plt.close(fig)
    write_json(out / "lugre_fit.json", with_units(record, strict=False))
    return fit, record
