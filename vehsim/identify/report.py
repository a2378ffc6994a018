"""Fit-and-validate runs as in report section 2.2 (constant kappa0 = 1, 2, and fitted kappa0),
their JSON summary and the force-history figures of Figs. 10-11. Used by `vehsim fit` and
`vehsim reproduce`."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

from .braking import BrakingData
from .fit import FitResult, evaluate, fit_closed_loop, fit_open_loop


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
            print(f"  {label}: {res.status}, kappa0 = {res.values['kappa0']:.3g}"
                  + (f"; held out {val}" if val else ""), file=sys.stderr, flush=True)
    return {"fits": fits, "predictions": preds, "summary": summary}


def figure_force_histories(brakings: Sequence[BrakingData], predictions: dict, labels,
                           title: str = "", held_out: Sequence[str] = ()):
    """Measured vs predicted $F_x(t)$, one panel per braking (report Figs. 10-11)."""
    import matplotlib.pyplot as plt

    n = len(brakings)
    fig, axes = plt.subplots(n, 1, figsize=(7.5, 2.3 * n + 0.6), sharex=False, squeeze=False)
    styles = ["--", "-.", "-"]
    for ax, d in zip(axes[:, 0], brakings):
        t = np.asarray(d.t)
        ax.plot(t, -np.asarray(d.F_x), color="0.6", lw=1.0, label="measured")
        for k, label in enumerate(labels):
            ax.plot(t, -predictions[label][d.name], styles[k % 3], lw=1.3, label=label)
        tag = " (held out)" if d.name in held_out else ""
        ax.set_title(f"{d.name}{tag}", fontsize=9)
        ax.set_ylabel("$-F_x$ [N]")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("t [s]")
    axes[0, 0].legend(fontsize=8, loc="lower right")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
