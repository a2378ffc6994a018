"""Reproduce section: identification on the shipped brakings (report 2.2, Figs. 10-11).

`identify` runs the fit-and-validate variants of the report (constant kappa0 = 1, 2 and
fitted kappa0); `vehsim fit` uses it too.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from .._results import result_name
from ..identify.braking import BrakingData, load_braking, shipped_brakings
from ..identify.fit import FitResult, evaluate, fit_closed_loop, fit_open_loop
from ..plot import force_histories_figure


TITLE = "Braking identification through the simulator (section 2.2, Figs. 10-11)"

VARIANTS = {"kappa0=1": {"kappa0": 1.0}, "kappa0=2": {"kappa0": 2.0}, "kappa0 fitted": {}}


def identify(train: Sequence[BrakingData], validate: Sequence[BrakingData] = (), *,
             mode: str = "open_loop", variants: dict[str, dict] | None = None,
             n_starts: int = 4, throw: bool = False, verbose: bool = True,
             **fit_kwargs) -> dict[str, Any]:
    """Fit each variant (default: report Figs. 10-11) on `train`, evaluate on `validate`.

    **Returns:** ``{"fits": {variant: FitResult}, "predictions": {variant: {braking: F}},
    "summary": JSON-ready dict}``.
    """
    variants = VARIANTS if variants is None else variants
    fit = fit_open_loop if mode == "open_loop" else fit_closed_loop
    fits: dict[str, FitResult] = {}
    preds: dict[str, dict[str, np.ndarray]] = {}
    summary: dict[str, Any] = {"mode": mode, "train": [d.name for d in train],
                               "validate": [d.name for d in validate], "fits": {}}
    held = {d.name for d in validate}
    for i, (label, fixed) in enumerate(variants.items(), 1):
        if verbose:
            print(f"[{i}/{len(variants)}] fitting {label} ({mode})", file=sys.stderr, flush=True)
        res = fit(list(train), fixed=fixed, n_starts=n_starts, throw=throw, verbose=verbose,
                  **fit_kwargs)
        fits[label] = res
        preds[label] = {}
        entry = res.to_dict()
        entry["validation_errors"] = {}
        for d in list(train) + list(validate):
            F, err = evaluate(res.model, d, mode)
            preds[label][d.name] = F
            if d.name in held:
                entry["validation_errors"][d.name] = err
        summary["fits"][label] = entry
        if verbose:
            val = "; ".join(f"{k}: RMS {v['rms_error_N']:.0f} N "
                            f"({100 * v['rms_error_rel_peak']:.2f}% of peak)"
                            for k, v in entry["validation_errors"].items())
            print(f"  {label}: {result_name(res.result)}, kappa0 = {res.values['kappa0']:.3g}"
                  + (f"; held out {val}" if val else ""), file=sys.stderr, flush=True)
    return {"fits": fits, "predictions": preds, "summary": summary}


def reproduce(ctx) -> None:
    files = shipped_brakings()
    b = {name: load_braking(path) for name, path in files.items()}
    train, held = [b["braking_1"], b["braking_2"]], [b["braking_3"]]
    n_starts = 1 if ctx.quick else 8
    ctx.log(f"fitting on braking_1, braking_2; braking_3 held out ({n_starts} start(s))")
    out = identify(train, held, n_starts=n_starts, verbose=True)
    brakings = train + held
    for fig_no, labels in (("fig10", ["kappa0=1", "kappa0=2"]), ("fig11", ["kappa0 fitted"])):
        fig = force_histories_figure(brakings, out["predictions"], labels, held_out=["braking_3"])
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
        rows.append(f"| {label} | {result_name(res.result)} | {fmt('kappa0')} | {fmt('sigma0')} | "
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
    fig = force_histories_figure([mf], {"lumped LuGre fit": {mf.name: F}}, ["lumped LuGre fit"])
    ctx.figure(fig, "identify_magic_formula",
               "Lumped LuGre fitted to a braking made by a Magic Formula tire with relaxation "
               "length (another model family).")
    ctx.text(f"Magic Formula braking: lumped LuGre fit {result_name(res.result)}, RMS error "
             f"{err['rms_error_N']:.1f} N = {100 * err['rms_error_rel_peak']:.2f}% of peak.")
    ctx.record("identify.magic_formula.rms_rel_peak", err["rms_error_rel_peak"])
