"""`vehsim estimate DATA.csv [--estimator observer|mhe] [--tire NAME] [--out DIR]`: the road
condition theta over a recorded braking (`vehsim.estimate_friction`).

**Format.** A CSV file with one header row and one row per sample, as the identification's
brakings (`vehsim.identify.braking`), and an optional side file of the same stem with suffix
``.json`` (``{"r": ..., "m": ..., "J": ...}``, the wheel's radius [m], mass share [kg] and
inertia [kg m^2]; the options override it):

| column  | unit  | meaning                                                                 |
|---------|-------|-------------------------------------------------------------------------|
| `t`     | s     | time, uniformly sampled (steps within 1 % of the mean, from 10 us to 1 s) |
| `v`     | m/s   | vehicle speed, forwards, >= 0                                           |
| `omega` | rad/s | wheel speed; an empty field or ``nan`` is a missing sample              |
| `T_b`   | N m   | brake torque as it acted, >= 0 and at most 100 r F_n                   |
| `F_x`   | N     | friction force (optional, not used by the estimators)                  |
| `F_n`   | N     | normal load (optional; its mean is the model's load unless --normal-load) |
| `theta` | -     | the true road condition (optional, e.g. a simulated record: drawn)      |

A malformed file is refused (exit status 2) with its name, row (1-based data row) and
column, before anything is computed or written.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path


ESTIMATORS = ("observer", "mhe", "peak")

REQUIRED = ("t", "v", "omega", "T_b")
OPTIONAL = ("F_x", "F_n", "theta")
UNITS = {"t_s": "s", "theta": "1", "theta_se": "1", "peak_slip": "1", "peak_mu": "1",
         "record_sample_time_s": "s",
         "estimator_sample_time_s": "s", "mass_kg": "kg", "radius_m": "m",
         "inertia_kg_m2": "kg m^2", "normal_load_n": "N"}


def register(subparsers) -> None:
    from .._constants import SAMPLE_STEP_RANGE
    from ._options import choice_of, integer, number

    p = subparsers.add_parser(
        "estimate", help="estimate the road condition theta over a recorded braking (CSV)",
        description="Run the friction observer or the moving-horizon estimator over a "
        "recorded braking (CSV columns t [s], v [m/s], omega [rad/s], T_b [N m]; optional F_x, "
        "F_n [N] and the true theta) and write estimate.json (theta over time, its standard "
        "error, each estimate's status, units, summary) and estimate.png (theta with a band "
        "of 2 standard errors, the measured slip); the peak estimator, which assumes no "
        "tire, estimates the peak of the force-slip curve instead. See docs/estimation.md.")
    p.add_argument("data", help="the recorded braking (CSV)")
    p.add_argument("--estimator", default="observer", type=choice_of(ESTIMATORS, "estimator"),
                   help=f"one of: {', '.join(ESTIMATORS)} (default: observer)")
    p.add_argument("--kappa0", type=number(0.0, 10.0, lower_open=True), default=None,
                   help="assume the lumped LuGre tire with this constant kappa0 (eq. 25) "
                        "instead of the uniform-load lumped tire (kappa0 from 2 to 1)")
    p.add_argument("--tire", default=None,
                   help="the tire the estimator assumes: a surface (e.g. dry_asphalt, snow, "
                        "cdc1999_1) or a LuGre parameter preset (table3, cdc1999) of "
                        "vehsim.params (default: dry_asphalt)")
    p.add_argument("--prior-theta", type=number(0.0, lower_open=True), default=None,
                   help="the estimator's starting theta (default: the surface's prior, or "
                        "the preset's theta)")
    p.add_argument("--theta-range", type=number(0.0, lower_open=True), nargs=2, default=None, metavar=("LO", "HI"),
                   help="the range theta is projected on (default: the surface's, or 0.3 40)")
    p.add_argument("--mass", type=number(0.0, lower_open=True, unit="kg"), default=None,
                   help="mass share of the wheel [kg] (default: side file, else 350)")
    p.add_argument("--radius", type=number(0.0, 5.0, lower_open=True, unit="m"), default=None,
                   help="rolling radius [m] (default: side file, else 0.3)")
    p.add_argument("--inertia", type=number(0.0, lower_open=True, unit="kg m^2"), default=None,
                   help="wheel inertia [kg m^2] (default: side file, else 1.0)")
    p.add_argument("--normal-load", type=number(0.0, lower_open=True, unit="N"), default=None,
                   help="normal load [N] (default: the mean of F_n if recorded, else m g)")
    p.add_argument("--sample-time", type=number(*SAMPLE_STEP_RANGE, unit="s"), default=None,
                   help="the estimator's step [s], a whole multiple of the record's "
                        "(default: the record's step)")
    p.add_argument("--window", type=integer(2, 100_000), default=None,
                   help="mhe: samples per window (20)")
    p.add_argument("--stride", type=integer(1, 100_000), default=None,
                   help="mhe: samples between window ends (default: half a window)")
    p.add_argument("--starts", type=integer(1, 1024), default=None,
                   help="mhe: starts per window (3)")
    p.add_argument("--out", default="estimate_results",
                   help="output folder (default: estimate_results/)")
    p.set_defaults(func=_estimate)


def read_recorded_braking(path) -> tuple:
    """``(MeasuredBraking, extras)`` of a CSV in the format of the module docstring;
    `extras` holds the side file's ``r``, ``m``, ``J`` and the optional ``theta`` column.
    Raises `ValueError` naming the file, row and column of the first problem."""
    import numpy as np

    from ..control.estimation.recorded import MeasuredBraking, nonuniform_step
    from ..identify.braking import (
        _fail,
        _read_columns,
        braking_path,
        check_magnitudes,
        check_sample_step,
        read_side_file,
    )

    path = braking_path(path)
    values = _read_columns(path, REQUIRED, OPTIONAL, may_be_missing=("omega",))
    n = len(values["t"])
    if n < 3:
        raise ValueError(f"{path}: need at least 3 data rows, got {n}")
    k = nonuniform_step(values["t"])
    if k is not None:
        dt = np.diff(values["t"])
        _fail(path, k + 1, "t", f"time must increase uniformly (steps within 1 % of the mean "
              f"{np.mean(dt):g} s), got {values['t'][k]:g} after {values['t'][k - 1]:g}; "
              "resample the record first")
    check_sample_step(path, values["t"])
    if math.isnan(values["omega"][0]):
        _fail(path, 1, "omega", "the first sample starts the estimators and must be present")
    check_magnitudes(path, values)
    if "theta" in values and np.any(values["theta"] <= 0):
        i = int(np.argmax(values["theta"] <= 0)) + 1
        _fail(path, i, "theta", f"must be > 0, got {values['theta'][i - 1]:g}")
    extras = read_side_file(path)
    extras["theta"] = values.get("theta")
    record = MeasuredBraking(values["t"], values["v"], values["omega"], values["T_b"],
                             values.get("F_x"), values.get("F_n"))
    return record, extras


def _positive(option: str, value) -> None:
    if value is not None and not (math.isfinite(value) and value > 0):
        raise ValueError(f"{option} must lie in (0, inf), got {value:g}")


def _assumed_tire(args):
    """``(the assumed tire at the prior, (theta_min, theta_max))`` of --tire, --kappa0 and
    the prior's options."""
    import equinox as eqx

    from ..params import PRESET_KINDS, preset
    from ..tire.lugre import LuGreParams, LumpedLuGre
    from ..tire.uniform_lumped import UniformLumpedLuGre

    kind = PRESET_KINDS.get(args.tire)
    if kind == "surface":
        srf = preset(args.tire)
        params, prior, rng = srf.params, srf.prior_theta, srf.theta_range
    elif kind == "tire_params" and isinstance(preset(args.tire), LuGreParams):
        params = preset(args.tire)
        prior, rng = float(params.theta), (0.3, 40.0)
    else:
        names = sorted(n for n, k in PRESET_KINDS.items() if k == "surface") + ["cdc1999",
                                                                                "table3"]
        raise ValueError(f"--tire must be a surface or a longitudinal LuGre preset, one of "
                         f"{', '.join(names)}; got {args.tire!r}")
    prior = prior if args.prior_theta is None else args.prior_theta
    rng = tuple(rng) if args.theta_range is None else tuple(args.theta_range)
    _positive("--prior-theta", prior)
    _positive("--theta-range LO", rng[0])
    _positive("--kappa0", args.kappa0)
    if rng[0] >= rng[1]:
        raise ValueError(f"--theta-range: LO must be below HI, got {rng[0]:g} {rng[1]:g}")
    if not (rng[0] <= prior <= rng[1]):
        raise ValueError(f"--prior-theta must lie in --theta-range [{rng[0]:g}, {rng[1]:g}], "
                         f"got {prior:g}")
    params = eqx.tree_at(lambda p: p.theta, params, prior)
    tire = UniformLumpedLuGre(params) if args.kappa0 is None else LumpedLuGre(params,
                                                                              args.kappa0)
    return tire, rng


MHE_ONLY = ("--window", "--stride", "--starts")
"""Options of the moving-horizon estimator alone."""
TIRE_OPTIONS = ("--tire", "--kappa0", "--prior-theta", "--theta-range")
"""Options of the estimators that assume a tire (not the peak estimator)."""


def _refuse_options_of_other_estimators(args) -> None:
    """Refuse, naming them, the options the chosen estimator does not use."""
    unused = [o for o in MHE_ONLY if args.estimator != "mhe"]
    unused += [o for o in TIRE_OPTIONS if args.estimator == "peak"]
    given = [o for o in unused if getattr(args, o[2:].replace("-", "_")) is not None]
    if given:
        why = (["the peak estimator assumes no tire"] if set(given) & set(TIRE_OPTIONS) else [])
        why += (["--window, --stride and --starts belong to --estimator mhe"]
                if set(given) & set(MHE_ONLY) else [])
        raise ValueError(f"{', '.join(given)} {'does' if len(given) == 1 else 'do'} not apply "
                         f"to --estimator {args.estimator}: {'; '.join(why)}")


TORQUE_LOAD_RATIO = 100.0
r"""Largest brake torque of a record, in units of its wheel radius times its normal load
$rF_n$: a tire brakes with $|F_x| \le \mu F_n$, $\mu$ about 1, so a hundredfold torque is
not a braking (most likely a column in the wrong unit)."""


def _check_torque(path, T_b, r: float, Fn: float, sources: dict[str, str]) -> None:
    """Refuse the first brake torque above `TORQUE_LOAD_RATIO` $rF_n$, naming its row and
    where r and F_n came from (`sources`: "r" and "F_n" to the option, side file or column
    that gave them); the hint names the options that were given as well as the column."""
    import numpy as np

    from ..identify.braking import _fail

    limit = TORQUE_LOAD_RATIO * r * Fn
    over = np.abs(T_b) > limit
    if np.any(over):
        i = int(np.argmax(over))
        given = [o for o in ("--normal-load", "--mass", "--radius")
                 if o in (sources["F_n"] + " " + sources["r"])]
        _fail(path, i + 1, "T_b", f"{T_b[i]:g} N m is more than {TORQUE_LOAD_RATIO:g} r F_n = "
              f"{limit:g} N m (r = {r:g} m from {sources['r']}, F_n = {Fn:g} N from "
              f"{sources['F_n']}): no tire brakes with that; is the column in N m"
              + "".join(f", or {g} too small" for g in given) + "?")


MIN_ESTIMATOR_SAMPLES = 10
"""Fewest estimator samples (the record's samples at the estimator's ``--sample-time``) that
`vehsim estimate` runs on: fewer give a standard error without meaning."""


def _check_estimator_samples(args, samples: int, h: float) -> None:
    """Enough estimator samples in the record: at least `MIN_ESTIMATOR_SAMPLES`, and for
    the moving horizon more than one ``--window`` (checked here, before anything compiles,
    naming the options)."""
    from ..control.estimation.recorded import estimator_sample_count

    T = h if args.sample_time is None else args.sample_time
    n = estimator_sample_count(samples, h, T)
    span = f"the record's {(samples - 1) * h:g} s"
    if n < MIN_ESTIMATOR_SAMPLES:
        raise ValueError(f"--sample-time {T:g} s leaves {n} estimator samples in {span}: at "
                         f"least {MIN_ESTIMATOR_SAMPLES} are needed; give a shorter "
                         "--sample-time")
    if args.estimator == "mhe" and n <= args.window:
        window = f"--window {args.window}" + ("" if args.window_given else " (the default)")
        raise ValueError(f"{window} needs more than {args.window} estimator samples, and "
                         f"{span} give {n} at a sample time of {T:g} s: give a shorter "
                         "--window or --sample-time")


MIN_WHEEL_SAMPLES = 10
"""Fewest measured wheel speeds a record must have for `vehsim estimate` (all of a shorter
record's; the rest may be missing, as from a slower sensor)."""


def _check_speeds(path, v, omega, r) -> None:
    """Refuse a record with nothing to estimate from: the car never moving faster than
    1 m/s, or fewer than `MIN_WHEEL_SAMPLES` wheel speeds measured. A slip beyond 1.5
    (omega in rpm, for example, gives slips near 9) gets a note on stderr, as `vehsim fit`
    gives."""
    import sys

    import numpy as np

    if not np.any(np.abs(v) > 1.0):
        raise ValueError(f"{path}: column 'v' never exceeds 1 m/s: no braking to estimate "
                         "from")
    measured = np.isfinite(omega)
    if measured.sum() < min(MIN_WHEEL_SAMPLES, omega.size):
        raise ValueError(f"{path}: column 'omega' has {int(measured.sum())} measured samples "
                         f"of {omega.size} (the rest nan); the estimators need at least "
                         f"{MIN_WHEEL_SAMPLES}")
    from ..identify.braking import slip_unit_reasons

    reasons = slip_unit_reasons(v, omega, r)
    if reasons:
        print(f"note: {path}: {' and '.join(reasons)}; check the units (omega in rad/s, v in "
              "m/s, r in m) and signs", file=sys.stderr)


def _estimate(args) -> int:
    # the options' types and ranges are checked while parsing (vehsim.cli._options)
    _refuse_options_of_other_estimators(args)
    if args.tire is not None and not args.tire.strip():
        raise ValueError("--tire: an empty name; give a surface or a LuGre preset")
    args.tire = args.tire or "dry_asphalt"
    args.window_given = args.window is not None
    args.window = args.window or 20
    args.starts = args.starts or 3
    tire, (lo, hi) = _assumed_tire(args)
    from ._options import outputs_spare_inputs

    outputs_spare_inputs(args.out, ("estimate.json", "estimate.png"), [args.data])
    record, extras = read_recorded_braking(args.data)

    import numpy as np

    from .._constants import GRAVITY
    from ..control.estimation.mhe import MovingHorizonEstimator
    from ..control.estimation.observer import FrictionObserver
    from ..control.estimation.peak_estimator import PeakEstimator
    from ..control.estimation.recorded import UNIFORM_TOLERANCE, estimate_friction
    from ..control.plant.hardware import ideal_hardware
    from ..vehicle.quarter_car import QuarterCar

    m = args.mass or extras.get("m", 350.0)
    r = args.radius or extras.get("r", 0.3)
    J = args.inertia or extras.get("J", 1.0)
    def source(option, given, key):  # where a value came from, for the torque check
        return option if given else "the side file" if key in extras else "the default"

    sources = {"r": source("--radius", args.radius, "r")}
    if args.normal_load is not None:
        Fn, sources["F_n"] = args.normal_load, "--normal-load"
    elif record.F_n is not None:
        Fn, sources["F_n"] = float(np.mean(np.asarray(record.F_n))), "the mean of column 'F_n'"
        _positive(f"{args.data}: the mean of column 'F_n'", Fn)
    else:
        Fn, sources["F_n"] = m * GRAVITY, (f"m g (m = {m:g} kg from "
                                             f"{source('--mass', args.mass, 'm')})")
    _check_torque(args.data, np.asarray(record.torque), r, Fn, sources)
    _check_speeds(args.data, np.asarray(record.v), np.asarray(record.omega), r)
    car = QuarterCar(tire, mass=m, inertia=J, radius=r, Fn_static=Fn, omega_eps=1.0)
    h = record.sample_time
    if args.sample_time is not None:
        n = round(args.sample_time / h)
        if n < 1 or abs(n * h - args.sample_time) > UNIFORM_TOLERANCE * h:
            raise ValueError(f"--sample-time ({args.sample_time:g} s) must be a whole multiple "
                             f"of the record's step ({h:g} s in {args.data})")
    hardware = ideal_hardware(sample_time=h if args.sample_time is None else args.sample_time)
    _check_estimator_samples(args, len(record), h)
    if args.estimator == "observer":
        estimator = FrictionObserver(tire, theta_min=lo, theta_max=hi)
    elif args.estimator == "mhe":
        estimator = MovingHorizonEstimator(tire, lo, hi, starts=args.starts, window=args.window)
    else:
        estimator = PeakEstimator()
    if not args.no_progress:
        print(f"vehsim estimate: {args.estimator} over {len(record)} samples of {h:g} s "
              f"({args.data}); compiling and running...", file=sys.stderr, flush=True)
    est = estimate_friction(record, estimator, car, hardware, stride=args.stride)
    _write(args, record, extras, est, car, hardware, h)
    import jax

    from ._status import exit_status

    # status 1 where any estimate failed: the summary's final estimate is the last successful
    # one, which a failure leaves stale. The leading estimates that are not identifiable (the
    # observer's before the data outweigh its prior, windows before the braking starts) are
    # the start, not a failure, where a successful estimate follows them
    start = _leading_unidentified(est.result)
    return exit_status("estimate", jax.tree.map(lambda a: a[start:], est.result))


def _leading_unidentified(result) -> int:
    """How many of the first estimates are `not_identifiable` before a successful one (0
    where none is successful after them)."""
    import numpy as np

    from .._results import is_successful, result_name

    names = np.asarray(result_name(result), dtype=object)
    k = int(np.argmax(names != "not_identifiable"))  # 0 where all are: not a success
    return k if bool(np.asarray(is_successful(result))[k]) else 0


def _write(args, record, extras, est, car, hardware, h) -> dict:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from .._io import write_json_and_figure
    from .._results import is_successful, result_name
    from ..plot import friction_estimate_figure

    peak = est.theta is None
    ts = np.asarray(est.ts, dtype=float)
    fields = ("peak_slip", "peak_mu") if peak else ("theta", "theta_se")
    values = {f: np.asarray(getattr(est, f), dtype=float) for f in fields}
    ok = np.asarray(is_successful(est.result))
    names = [str(n) for n in np.asarray(result_name(est.result), dtype=object).tolist()]
    last = np.nonzero(ok)[0]
    summary = {"samples": len(record), "record_sample_time_s": h,
               "estimator_sample_time_s": float(hardware.sample_time),
               "estimates": int(ts.size), "estimates_successful": int(ok.sum()),
               "t_final_s": float(ts[last[-1]]) if last.size else None}
    summary |= {f"{f}_final": float(a[last[-1]]) if last.size else None
                for f, a in values.items()}
    truth = extras.get("theta")
    if truth is not None and last.size and not peak:
        true_at = np.interp(ts, np.asarray(record.t), truth)
        summary["theta_true_final"] = float(true_at[last[-1]])
        summary["relative_error_median"] = float(np.median(np.abs(
            values["theta"][ok] / true_at[ok] - 1.0)))
    out = {"file": str(args.data), "estimator": args.estimator,
           "tire": None if peak else args.tire, "kappa0": None if peak else args.kappa0,
           "car": {"mass_kg": float(car.mass), "radius_m": float(car.radius),
                   "inertia_kg_m2": float(car.inertia),
                   "normal_load_n": float(car.Fn_static)},
           "summary": summary, "t_s": ts, **values, "status": names, "units": UNITS}
    t = np.asarray(record.t)
    slip = np.asarray(record.omega) * float(car.radius) / np.maximum(np.asarray(record.v),
                                                                      1e-9) - 1.0
    shown = ({"value": values["peak_mu"], "label": "peak friction mu* [-]"} if peak else
             {"value": values["theta"], "se": values["theta_se"],
              "label": "road condition theta [-]"})
    fig = friction_estimate_figure(
        {"ts": ts, "ok": ok, **shown},
        {"t": t, "slip": slip, "torque": np.asarray(record.torque),
         "truth": None if peak else truth,
         "peak_slip": values["peak_slip"] if peak else None},
        title=f"{args.estimator} on {Path(args.data).name}"
              + ("" if peak else f" (assumed tire: {args.tire}"
                 + ("" if args.kappa0 is None else f", kappa0 = {args.kappa0:g}") + ")"))
    folder = Path(args.out)
    write_json_and_figure(folder / "estimate.json", out, folder / "estimate.png", fig)
    plt.close(fig)
    print(f"wrote {folder / 'estimate.json'} and {folder / 'estimate.png'}", file=sys.stderr)
    if last.size:
        a, b = fields
        print(f"  at {summary['t_final_s']:.3g} s: {a} {summary[a + '_final']:.4g}, {b} "
              f"{summary[b + '_final']:.2g} ({summary['estimates_successful']} of "
              f"{summary['estimates']} estimates successful)", file=sys.stderr)
    return out
