"""`vehsim tire show | plot | fit-lugre FILE.tir`: a tyre property file's Magic Formula
summarised, drawn, and matched by the distributed 2D LuGre model (docs/tir.md)."""

from __future__ import annotations

import math
import sys
from pathlib import Path


def register(subparsers) -> None:
    from ._options import integer, number

    p = subparsers.add_parser(
        "tire", help="a tyre property file (.tir): summary, curves, LuGre fit",
        description="Read a Magic Formula 5.2 / 6.1 / 6.2 tyre property file and summarise "
        "it (show), draw its curves (plot), or fit the distributed 2D LuGre model and its "
        "normal-load shape to its F_x, F_y and M_z (fit-lugre, report Fig. 15).")
    sub = p.add_subparsers(dest="tire_command", required=True)

    s = sub.add_parser("show", help="version, nominal load, peak friction, stiffnesses, ranges",
                       description="Summary of a .tir file at its nominal load (zero camber, "
                       "its inflation pressure): peak mu_x and mu_y with the slips where they "
                       "occur, the cornering and slip stiffnesses at zero slip, the valid "
                       "ranges. Values in the file's axes (ISO-W).")
    s.add_argument("file", help="tyre property file (.tir)")
    s.add_argument("--load", type=number(0.0, lower_open=True, unit="N"), default=None,
                   help="load [N] of the summary (default the nominal load LFZO * FNOMIN)")
    s.add_argument("--json", action="store_true", help="print JSON instead of text")
    s.set_defaults(func=_show)

    pl = sub.add_parser("plot", help="F_x, F_y, M_z curves at several loads and cambers, "
                        "combined slip", description="Draw F_x vs slip ratio, F_y and M_z "
                        "vs slip angle at 0.5, 1 and 1.5 times the nominal load and at three "
                        "cambers, and the combined-slip curves with the friction ellipse.")
    pl.add_argument("file", help="tyre property file (.tir)")
    pl.add_argument("--out", default=None, help="figure (default: FILE's name with _curves.png)")
    pl.set_defaults(func=_plot, out_kind="file")

    f = sub.add_parser("fit-lugre", help="fit the 2D LuGre model to the file's Magic Formula",
                       description="Fit the steady distributed 2D LuGre model (eqs. 31-33), its "
                       "normal-load shape and patch-length law to the file's pure-slip F_x, "
                       "F_y, M_z at three loads (report Fig. 15; vehsim.fit_to_magic_formula), "
                       "the Stribeck velocity and exponent held (3 m/s, 0.7: curves at one "
                       "speed do not determine them); print the error table, write the JSON "
                       "(parameters with units, errors in N and relative to each curve's "
                       "peak, status) and a figure (Figs. 15, 13, 14: LuGre solid, Magic "
                       "Formula dashed) beside it. Exit status 1 unless the fit converged "
                       "or its optimum is stationary by MINPACK's tests.")
    f.add_argument("file", help="tyre property file (.tir)")
    f.add_argument("--out", default="fit_lugre.json",
                   help="JSON file (default fit_lugre.json); the figure is written beside it "
                        "with the suffix .png")
    f.add_argument("--loads", default=None, metavar="F1,F2,...",
                   help="loads [N] (default 0.5, 1, 1.5 times the nominal load, within the "
                        "file's load range)")
    f.add_argument("--speed", type=number(0.0, 100.0, lower_open=True, unit="m/s"),
                   default=20.0, help="speed [m/s], in (0, 100] (20)")
    f.add_argument("--max-steps", type=integer(1, 100_000), default=300,
                   help="Levenberg-Marquardt steps at most (300; the sample converges in "
                        "109; docs/tir.md)")
    f.set_defaults(func=_fit_lugre, out_kind="file")


def read_tire(path):
    """`(TirFile, MFParams)` of the file at `path`; a missing file, a folder, an unreadable
    file or one that is not a valid tyre property file raise `ValueError` naming it (and
    the line and key where the reader gives them)."""
    from ..tire.mf6 import MFParams
    from ..tire.tir import read_tir

    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: no such file")
    if not path.is_file():
        raise ValueError(f"{path}: not a file")
    try:
        tir = read_tir(path)
    except OSError as e:
        raise ValueError(f"{path}: cannot read it ({e.strerror or e})") from None
    try:
        params = MFParams.from_tir(tir)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    return tir, params


def _positive(name: str, value: float) -> float:
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive number, got {value}")
    return value


def _range(lo, hi, scale=1.0) -> list | None:
    lo, hi = float(lo) * scale, float(hi) * scale
    return [lo if math.isfinite(lo) else None, hi if math.isfinite(hi) else None]


def tire_summary(tir, params, load=None) -> dict:
    """What `vehsim tire show` prints: `vehsim.tire.mf6.mf_summary` at `load` (default the
    scaled nominal load), in named fields with units, with the file's valid ranges."""
    from ..tire.mf6 import mf_summary

    P = params
    s = mf_summary(P, load)
    return {
        "file": tir.source, "version": f"{float(P.version):.1f}",
        "nominal_load_N": float(P.FNOMIN), "LFZO": float(P.LFZO),
        "load_N": s["Fz"], "unloaded_radius_m": float(P.UNLOADED_RADIUS),
        "inflation_pressure_Pa": float(P.INFLPRES), "nominal_pressure_Pa": float(P.NOMPRES),
        "peak_mu_x_driving": s["mu_x_drive"], "kappa_at_peak_mu_x_driving": s["kappa_at_mu_x_drive"],
        "peak_mu_x_braking": s["mu_x_brake"], "kappa_at_peak_mu_x_braking": s["kappa_at_mu_x_brake"],
        "peak_mu_y": s["mu_y"], "alpha_at_peak_mu_y_deg": s["alpha_deg_at_mu_y"],
        "cornering_stiffness_N_per_rad": s["dFy_dalpha_0"],
        "longitudinal_slip_stiffness_N": s["dFx_dkappa_0"],
        "K_ya_N_per_rad": s["Kya"], "K_xk_N": s["Kxk"],
        "valid_ranges": {
            "load_N": _range(P.FZMIN, P.FZMAX), "slip_ratio": _range(P.KPUMIN, P.KPUMAX),
            "slip_angle_deg": _range(P.ALPMIN, P.ALPMAX, 180.0 / math.pi),
            "camber_deg": _range(P.CAMMIN, P.CAMMAX, 180.0 / math.pi),
            "pressure_Pa": _range(P.PRESMIN, P.PRESMAX)},
        "unknown_keys": list(tir.unknown_keys),
        "axes": "ISO-W (the file's): alpha > 0 with the slip velocity to the left, F_y and "
                "the cornering stiffness then usually negative",
        "peaks_found_on": "2001 slip ratios in [-1, 1] and 2001 slip angles in [-30, 30] deg, "
                          "zero camber, the file's ranges not applied",
        "peaks_at_search_edge": [  # the largest value on the grid, not a peak inside it
            name for name, slip, edge in (
                ("peak_mu_x_driving", s["kappa_at_mu_x_drive"], 1.0),
                ("peak_mu_x_braking", s["kappa_at_mu_x_brake"], 1.0),
                ("peak_mu_y", s["alpha_deg_at_mu_y"], 30.0)) if abs(slip) >= edge * (1 - 1e-9)],
    }


def _fmt_range(r, unit="") -> str:
    lo, hi = ("unbounded" if v is None else f"{v:g}" for v in r)
    return f"{lo} to {hi}{unit}"


def summary_text(s: dict) -> str:
    """The text `vehsim tire show` prints for a `tire_summary`."""
    r = s["valid_ranges"]
    load = s["load_N"]
    lines = [
        f"{s['file']}: Magic Formula {s['version']}",
        f"  nominal load          {s['nominal_load_N']:g} N (FNOMIN; LFZO {s['LFZO']:g})",
        f"  unloaded radius       {s['unloaded_radius_m']:g} m",
        f"  pressure              {s['inflation_pressure_Pa']:g} Pa "
        f"(nominal {s['nominal_pressure_Pa']:g} Pa)",
        f"at F_z = {load:g} N, zero camber (file's axes, ISO-W):",
        f"  peak mu_x             {s['peak_mu_x_driving']:.4f} driving at kappa = "
        f"{s['kappa_at_peak_mu_x_driving']:.3f}; {s['peak_mu_x_braking']:.4f} braking at "
        f"kappa = {s['kappa_at_peak_mu_x_braking']:.3f}",
        f"  peak mu_y             {s['peak_mu_y']:.4f} at alpha = "
        f"{s['alpha_at_peak_mu_y_deg']:.2f} deg",
        f"  cornering stiffness   {s['cornering_stiffness_N_per_rad']:.1f} N/rad "
        f"(dF_y/dalpha at alpha = 0; K_ya = {s['K_ya_N_per_rad']:.1f})",
        f"  slip stiffness        {s['longitudinal_slip_stiffness_N']:.1f} N "
        f"(dF_x/dkappa at kappa = 0; K_xk = {s['K_xk_N']:.1f})",
        "valid ranges:",
        f"  load                  {_fmt_range(r['load_N'], ' N')}",
        f"  slip ratio            {_fmt_range(r['slip_ratio'])}",
        f"  slip angle            {_fmt_range(r['slip_angle_deg'], ' deg')}",
        f"  camber                {_fmt_range(r['camber_deg'], ' deg')}",
        f"  pressure              {_fmt_range(r['pressure_Pa'], ' Pa')}",
    ]
    if s["peaks_at_search_edge"]:
        lines.append(f"no peak inside the search ({s['peaks_found_on']}) for "
                     f"{', '.join(s['peaks_at_search_edge'])}: the value is the largest, at "
                     "its edge")
    if s["unknown_keys"]:
        lines.append(f"keys vehsim does not use: {', '.join(s['unknown_keys'])}")
    return "\n".join(lines)


def _show(args) -> int:
    import json

    from .._io import _jsonable

    tir, params = read_tire(args.file)
    if args.load is not None:
        _check_loads("--load", [args.load], params, lowest="zero")
    s = tire_summary(tir, params, args.load)
    _check_finite(tir, s)
    print(json.dumps(_jsonable(s), indent=2) if args.json else summary_text(s))
    if args.load is not None and args.load < float(params.FZMIN):
        print(f"note: --load {args.load:g} N is below the file's FZMIN ({float(params.FZMIN):g} "
              "N): the formula is evaluated there, outside the loads it was fitted on",
              file=sys.stderr)
    return 0


_SUMMARY_NUMBERS = ("peak_mu_x_driving", "peak_mu_x_braking", "peak_mu_y",
                    "cornering_stiffness_N_per_rad", "longitudinal_slip_stiffness_N",
                    "K_ya_N_per_rad", "K_xk_N")
"""The summary's numbers that the Magic Formula computes."""


def _check_finite(tir, summary: dict) -> None:
    """A file whose formulas overflow (a coefficient of 1e308) is refused naming the numbers
    that are not finite and the file's largest coefficient, rather than shown, drawn or
    fitted as NaN (`summary` a `tire_summary`)."""
    bad = [k for k in _SUMMARY_NUMBERS if not math.isfinite(float(summary[k]))]
    if not bad:
        return
    coefficients = [(abs(e.value), e) for name, e in tir.entries()
                    if name.upper().endswith("_COEFFICIENTS") and isinstance(e.value, int | float)]
    _, e = max(coefficients, key=lambda c: c[0], default=(0.0, None))
    largest = "" if e is None else f"; its largest coefficient: {e.key} = {e.value:g} (line {e.line})"
    raise ValueError(f"{tir.source}: the Magic Formula is not finite at {summary['load_N']:g} N "
                     f"({', '.join(bad)}): a coefficient too large to evaluate{largest}")


def tire_curves(params) -> dict:
    """The curves of `vehsim.plot.tire_curves_figure` for `params` (`MFParams`), in the
    file's axes with its ranges applied: loads 0.5, 1, 1.5 times $F'_{z0}$ (within
    [FZMIN, FZMAX]), cambers -4, 0, 4 deg (within [CAMMIN, CAMMAX]), slip ratios in
    [-0.5, 0.5] and slip angles in [-20, 20] deg (within the file's ranges); combined slip
    at $F'_{z0}$: slip ratio swept at slip angles 1, 2, 4, 8, 15 deg of both signs."""
    import jax.numpy as jnp
    import numpy as np

    from ..tire.characteristic import MFCharacteristic
    from ..tire.mf6 import mf_forces, mf_summary

    P = params
    char = MFCharacteristic(P)
    loads = char.fit_loads()
    Fz0 = char.nominal_load()
    kappa = np.linspace(max(-0.5, float(P.KPUMIN)), min(0.5, float(P.KPUMAX)), 201)
    lo, hi = max(-20.0, math.degrees(P.ALPMIN)), min(20.0, math.degrees(P.ALPMAX))
    deg = np.linspace(lo, hi, 201)
    alpha = np.deg2rad(deg)
    cam_lo, cam_hi = math.degrees(P.CAMMIN), math.degrees(P.CAMMAX)
    cambers = sorted({float(np.clip(g, cam_lo, cam_hi)) for g in (-4.0, 0.0, 4.0)})

    def F(k, a, fz, g=0.0):
        return np.asarray(mf_forces(P, jnp.asarray(k), jnp.asarray(a), fz, math.radians(g)))

    fz = np.asarray(loads)[:, None]
    fx, lat = F(kappa[None, :], 0.0, fz), F(0.0, alpha[None, :], fz)
    lat_g = np.stack([F(0.0, alpha, Fz0, g) for g in cambers])
    k_comb = np.linspace(max(-1.0, float(P.KPUMIN)), min(1.0, float(P.KPUMAX)), 201)
    combined = {}
    gap = np.full((1, 3), np.nan)
    for a in (1.0, 2.0, 4.0, 8.0, 15.0):  # both signs in one line, broken by a NaN
        f = np.concatenate([F(k_comb, math.radians(a), Fz0), gap,
                            F(k_comb, -math.radians(a), Fz0)])
        combined[f"alpha = +/-{a:g} deg"] = (f[:, 0], f[:, 1])
    s = mf_summary(P, Fz0)
    ellipse = (Fz0 * 0.5 * (s["mu_x_drive"] + s["mu_x_brake"]), Fz0 * s["mu_y"])
    return {"kappa": kappa, "alpha_deg": deg, "loads": list(loads), "Fx": fx[..., 0],
            "Fy": lat[..., 1], "Mz": lat[..., 2], "cambers_deg": cambers,
            "Fy_camber": lat_g[..., 1], "Mz_camber": lat_g[..., 2], "nominal_load": Fz0,
            "combined": combined, "ellipse": ellipse}


def _plot(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import save_figure
    from ..plot import tire_curves_figure
    from ._options import output_file, writable_output

    out = Path(args.out) if args.out else Path(f"{Path(args.file).stem}_curves.png")
    output_file("--out", str(out), {".png": "png", ".pdf": "pdf", ".svg": "svg"})
    writable_output("--out" if args.out else "--out (its default, FILE's name with "
                    "_curves.png in the current folder)", out, "file")
    tir, params = read_tire(args.file)
    _check_finite(tir, tire_summary(tir, params, None))
    curves = tire_curves(params)
    fig = tire_curves_figure(curves, title=f"{Path(args.file).name}: Magic Formula "
                             f"{float(params.version):.1f} (ISO-W axes, the file's ranges "
                             "applied)")
    save_figure(fig, out)
    plt.close(fig)
    print(f"wrote {out}", file=sys.stderr)
    return 0


def _parse_loads(text):
    from .._io import parse_number

    if text is None:
        return None
    try:
        loads = [parse_number(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"--loads expects F1,F2,... in N, got {text!r}") from None
    for v in loads:
        _positive("--loads", v)
    repeated = sorted({v for v in loads if loads.count(v) > 1})
    if repeated:
        raise ValueError(f"--loads: {', '.join(f'{v:g}' for v in repeated)} N given more than "
                         "once; the loads fitted together must differ (one load fits at that "
                         "load alone)")
    return loads


def _check_loads(option: str, loads, params, lowest: str = "FZMIN") -> None:
    """Each load within the file's valid range: [FZMIN, FZMAX] (`lowest` 'FZMIN'), or (0,
    FZMAX] ('zero')."""
    lo, hi = float(params.FZMIN) if lowest == "FZMIN" else 0.0, float(params.FZMAX)
    for v in loads:
        if not (lo <= v <= hi) or v <= 0:
            span = (f"[{lo:g}, {hi:g}] N (FZMIN, FZMAX)" if lowest == "FZMIN" else
                    f"(0, {hi:g}] N (up to FZMAX)")
            raise ValueError(f"{option}: {v:g} N is outside the file's load range {span}")


def _fit_lugre(args) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .._io import write_json_and_figure
    from .._result_files import with_units
    from ..reproduce.combined import fit_lugre_to, fit_table, lugre_fit_curves, lugre_fit_figure
    from ._options import output_file
    from ._status import as_options, exit_status

    loads = _parse_loads(args.loads)
    output_file("--out", args.out, {".json": "json"})
    out = Path(args.out)
    figure = out.with_suffix(".png")
    tir, params = read_tire(args.file)
    if loads is not None:
        _check_loads("--loads", loads, params)
    _check_finite(tir, tire_summary(tir, params, None))
    print(f"vehsim tire fit-lugre: {args.file}, Magic Formula {float(params.version):.1f}, "
          f"at most {args.max_steps} Levenberg-Marquardt steps", file=sys.stderr, flush=True)
    fit, record = fit_lugre_to(params, args.speed, loads, args.max_steps)
    record = {"file": str(args.file), "version": tir.version, **record}
    fig = lugre_fit_figure(lugre_fit_curves(params, fit, args.speed),
                           title=f"{Path(args.file).name}: distributed 2D LuGre (solid) fitted "
                                 "to its Magic Formula (dashed)")
    write_json_and_figure(out, with_units(record, strict=False), figure, fig)
    plt.close(fig)
    said = {"`max_steps`": "--max-steps"}  # the solver's setting, as this command's option
    print(f"fit: {record['status']}: {as_options(record['message'], said)}")
    print("errors (RMS and worst, in % of each curve's peak in brackets):")
    print("\n".join(fit_table(record)))
    print("at the start (uniform load):")
    print("\n".join(fit_table(record, "initial_errors")))
    print(f"wrote {out} and {figure}", file=sys.stderr)
    return exit_status("tire fit-lugre", fit.result, fit.message, options=said)
