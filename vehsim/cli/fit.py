"""`vehsim fit DATA.csv [more.csv] [--validate X.csv] [--out DIR]`: identify the lumped LuGre
parameters from brakings (report section 2.2)."""

from __future__ import annotations

import sys
from pathlib import Path


def register(subparsers) -> None:
    from ._options import integer, number

    p = subparsers.add_parser(
        "fit",
        help="fit lumped LuGre parameters to braking data (CSV, see vehsim.identify.braking)",
        description="Fit the lumped LuGre model (eqs. 22-25) to brakings by Levenberg-Marquardt "
        "through the simulator, for constant kappa0 = 1, 2 and fitted kappa0 (report Figs. "
        "10-11); write fit.json (parameters, standard errors, errors, status) and fit.png.",
    )
    p.add_argument("data", nargs="+", help="training braking CSV file(s)")
    p.add_argument("--validate", nargs="*", default=[], help="held-out braking CSV file(s)")
    p.add_argument("--out", default="fit_results", help="output folder (default: fit_results/)")
    p.add_argument("--closed-loop", action="store_true",
                   help="fit the quarter car driven by the brake torque T_b (needs T_b, m, J)")
    p.add_argument("--starts", type=integer(1, 1024), default=4,
                   help="multi-start: initial guesses solved in one vmapped call (default 4)")
    p.add_argument("--radius", type=number(0.0, 5.0, lower_open=True, unit="m"), default=None,
                   help="wheel radius [m], in place of the side file's r (default: the side file's)")
    p.add_argument("--only-fitted-kappa0", action="store_true",
                   help="skip the constant kappa0 = 1, 2 fits")
    p.set_defaults(func=_fit)


KAPPA0_RANGE = (0.5, 3.0)
"""The kappa0 the lumped model's derivation gives (eq. 25: the exact constant runs from 2 at
small slip to 1 at a locked wheel for a uniform load, a little wider for others)."""


def kappa0_note(fit) -> str | None:
    """A sentence pointing out a fitted kappa0 far outside `KAPPA0_RANGE`, with the
    diagnostics that explain it; None when kappa0 is fixed or inside."""
    if "kappa0" not in fit.free:
        return None
    k, se = fit.values["kappa0"], fit.std_errors["kappa0"]
    lo, hi = KAPPA0_RANGE
    if lo <= k <= hi:
        return None
    return (f"kappa0 = {k:.3g} +/- {se:.2g} lies far from the {lo:g}-{hi:g} of the lumped "
            f"model's derivation (eq. 25; the exact constant runs from 2 at small slip to 1 at "
            f"a locked wheel). Jacobian condition number {fit.condition_number:.3g}: "
            + ("the data determine kappa0 poorly (little slip excitation?); "
               if se > 0.5 * abs(k) or fit.condition_number > 1e6 else "")
            + "a tire that is not a lumped LuGre, or a wrong wheel radius, also moves it")


def _fit(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import write_json_and_figure
    from .._result_files import with_units
    from ..identify.braking import load_braking, slip_sign_note
    from ..identify.parameters import UNITS as PARAMETER_UNITS
    from ..plot import force_histories_figure
    from ..reproduce.identify import VARIANTS, identify
    from ._options import outputs_spare_inputs

    outputs_spare_inputs(args.out, ("fit.json", "fit.png"), args.data + args.validate)
    train = [load_braking(f, r=args.radius) for f in args.data]
    validate = [load_braking(f, r=args.radius) for f in args.validate]
    if args.closed_loop:  # before anything is compiled
        for f, d in zip(args.data + args.validate, train + validate):
            missing = ([] if d.T_b is not None else ["the column 'T_b'"]) + [
                f"the side file's {k!r}" for k in ("m", "J") if getattr(d, k) is None]
            if missing:
                raise ValueError(f"{f}: --closed-loop needs {' and '.join(missing)} (the brake "
                                 "torque drives the quarter car; m [kg] and J [kg m^2] in "
                                 "the side file NAME.json)")
    names = [d.name for d in train + validate]
    if len(set(names)) != len(names):
        raise ValueError(f"braking names (file stems) must be distinct, got {names}")
    print(f"vehsim fit: {len(train)} training and {len(validate)} held-out braking(s)",
          file=sys.stderr, flush=True)
    for d in train + validate:
        note = slip_sign_note(d)
        if note:
            print(f"  note: {note}", file=sys.stderr, flush=True)
    variants = {"kappa0 fitted": {}} if args.only_fitted_kappa0 else VARIANTS
    out = identify(train, validate, mode="closed_loop" if args.closed_loop else "open_loop",
                   variants=variants, n_starts=args.starts, throw=False, verbose=True)
    folder = Path(args.out)
    summary = out["summary"]
    summary["files"] = {"train": [str(f) for f in args.data],
                        "validate": [str(f) for f in args.validate]}
    fig = force_histories_figure(train + validate, out["predictions"], list(variants),
                                 title="measured vs predicted friction force (lumped LuGre)",
                                 held_out=[d.name for d in validate])
    write_json_and_figure(folder / "fit.json",
                          with_units(summary, PARAMETER_UNITS, strict=False),
                          folder / "fit.png", fig)
    plt.close(fig)
    best = out["fits"]["kappa0 fitted"]
    print(f"wrote {folder / 'fit.json'} and {folder / 'fit.png'}", file=sys.stderr)
    for n in best.free:
        print(f"  {n:7s} = {best.values[n]:.6g} +/- {best.std_errors[n]:.2g}", file=sys.stderr)
    note = kappa0_note(best)
    if note:
        print(f"  note: {note}", file=sys.stderr)
    from ._status import exit_status

    return max(exit_status(f"fit: {label}", f.result, f.message)
               for label, f in out["fits"].items())
