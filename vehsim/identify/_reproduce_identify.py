"""Reproduce section: identification on the shipped brakings (report 2.2, Figs. 10-11)."""

from __future__ import annotations

from .braking import load_braking, shipped_brakings
from .fit import evaluate, fit_open_loop
from .report import figure_force_histories, identify


TITLE = "Braking identification through the simulator (section 2.2, Figs. 10-11)"


def reproduce(ctx) -> None:
    files = shipped_brakings()
    b = {name: load_braking(path) for name, path in files.items()}
    train, held = [b["braking_1"], b["braking_2"]], [b["braking_3"]]
    n_starts = 1 if ctx.quick else 8
    ctx.log(f"fitting on braking_1, braking_2; braking_3 held out ({n_starts} start(s))")
    out = identify(train, held, n_starts=n_starts, verbose=True)
    brakings = train + held
    for fig_no, labels in (("fig10", ["kappa0=1", "kappa0=2"]), ("fig11", ["kappa0 fitted"])):
        fig = figure_force_histories(brakings, out["predictions"], labels, held_out=["braking_3"])
        ctx.figure(fig, f"identify_{fig_no}",
                   f"Measured (synthetic: distributed LuGre PDE, quartic load, sensor model) and "
                   f"predicted friction force, lumped LuGre fitted on brakings 1-2, braking 3 held "
                   f"out; {', '.join(labels)} (report Fig. {fig_no[3:]}).")
    rows = ["| fit | status | kappa0 | sigma0 [1/m] | mu_c | mu_s | v_s [m/s] | "
            "held-out RMS [N] | % of peak |", "|---|---|---|---|---|---|---|---|---|"]
    for label, res in out["fits"].items():
        v, se = res.values, res.std_errors
        err = out["summary"]["fits"][label]["validation_errors"]["braking_3"]
        fmt = lambda n: f"{v[n]:.4g}" + (f" ± {se[n]:.2g}" if n in se else "")  # noqa: E731
        rows.append(f"| {label} | {res.status} | {fmt('kappa0')} | {fmt('sigma0')} | "
                    f"{fmt('mu_c')} | {fmt('mu_s')} | {fmt('v_s')} | {err['rms_error_N']:.1f} | "
                    f"{100 * err['rms_error_rel_peak']:.2f} |")
        ctx.record(f"identify.{label}.held_out_rms_rel_peak", err["rms_error_rel_peak"])
        ctx.record(f"identify.{label}.parameters", v)
        ctx.record(f"identify.{label}.std_errors", se)
    ctx.text("Lumped LuGre (eqs. 22-25) fitted by Levenberg-Marquardt through the simulator; "
             "± are Gauss-Newton standard errors (white-noise assumption: lower bounds). "
             "Truth: Table 3 parameters (sigma0 = 181.54, mu_c = 0.8, mu_s = 1.55, v_s = 6.57).",
             "", *rows)
    # another model family: the Magic Formula braking
    mf = b["braking_mf"]
    res = fit_open_loop([mf], n_starts=n_starts, throw=False)
    F, err = evaluate(res.model, mf)
    fig = figure_force_histories([mf], {"lumped LuGre fit": {mf.name: F}}, ["lumped LuGre fit"])
    ctx.figure(fig, "identify_magic_formula",
               "Lumped LuGre fitted to a braking made by a Magic Formula tire with relaxation "
               "length (another model family).")
    ctx.text(f"Magic Formula braking: lumped LuGre fit {res.status}, RMS error "
             f"{err['rms_error_N']:.1f} N = {100 * err['rms_error_rel_peak']:.2f}% of peak.")
    ctx.record("identify.magic_formula.rms_rel_peak", err["rms_error_rel_peak"])
