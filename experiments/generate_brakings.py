"""Regenerate the synthetic "instrumented car" brakings shipped in vehsim/data/brakings/.

The report (section 2.2, Figs. 8-11) identified the lumped LuGre model on three brakings of
the BASIL test car; those measurements are not public, so vehsim ships its own, made by a
truth model that is *not* the fitted model:

- plant: `QuarterCar` (400 kg mass share, J = 1.2 kg m^2, r = 0.30 m) with load transfer
  relaxing with a lag (`LoadRelaxation`, gain 0.15, tau 80 ms);
- tire: the distributed LuGre PDE (eq. 14, `DistributedLuGre`, n = 24) with the quartic
  load density (`QuarticLoad`) and the report's Table 3 parameters, for brakings 1-3;
  a longitudinal Magic Formula with relaxation length (`RelaxedMagicFormula`) for the
  fourth, so that fits are also judged against another model family;
- inputs: ABS-less emergency stops from 20-24 m/s (brake torque ramps, two two-stage),
  logged until the vehicle speed falls below 1.5 m/s;
- sensor model (seeded): first-order lags (force and load 2 ms, wheel speed 1 ms, vehicle
  speed 5 ms), white noise, wheel and vehicle speed sample-and-hold at 250 Hz, wheel speed
  quantised to 0.1 rad/s, everything logged at 500 Hz.

Run from the repository root:  ``PYTHONPATH=. python experiments/generate_brakings.py``
(``--check`` compares the CSV and JSON files byte for byte with the shipped ones instead of
writing; exit status 1 if any differs). The output is a pure
function of this script (fixed seeds, float64 on CPU): regenerating gives identical files
on the same platform and library versions.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax


jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from vehsim.identify.braking import BrakingData, save_braking  # noqa: E402
from vehsim.params import table3  # noqa: E402
from vehsim.tire.distributed import DistributedLuGre  # noqa: E402
from vehsim.tire.load import QuarticLoad  # noqa: E402
from vehsim.tire.relaxed_magic_formula import (  # noqa: E402
    MagicFormulaParams,
    RelaxedMagicFormula,
)
from vehsim.vehicle.normal_load import LoadRelaxation  # noqa: E402
from vehsim.vehicle.quarter_car import QuarterCar, simulate_quarter_car  # noqa: E402


OUT = Path(__file__).resolve().parent.parent / "vehsim" / "data" / "brakings"
LOG_RATE = 500.0  # Hz
V_END = 1.5  # m/s: the log stops when the (true) vehicle speed falls below this
SIM_DT = 1e-4  # s, the truth is saved every 0.1 ms before the sensor model
MASS, INERTIA, RADIUS = 400.0, 1.2, 0.30
LOAD = dict(gain=0.15, tau=0.08)
MF = dict(B=10.0, C=1.9, D=1.0, E=0.97, relaxation_length=0.25)


def torque(ramps, t, xp=np):
    """Brake torque [N m]: a sum of ramps (t0, t1, amplitude), each 0 before t0, full after t1."""
    return sum(a * xp.clip((t - t0) / (t1 - t0), 0.0, 1.0) for t0, t1, a in ramps)


# name: (tire, v0 [m/s], simulated duration [s], brake torque ramps, seed)
BRAKINGS = {
    "braking_1": ("distributed", 22.0, 1.95, ((0.10, 0.35, 2500.0),), 1),
    "braking_2": ("distributed", 24.0, 2.2, ((0.10, 0.40, 1300.0), (1.0, 1.2, 1300.0)), 2),
    "braking_3": ("distributed", 20.0, 1.9, ((0.10, 0.70, 1900.0),), 3),
    "braking_mf": ("magic_formula", 23.0, 2.2, ((0.10, 0.40, 1400.0), (0.9, 1.1, 1200.0)), 4),
}

SENSORS = {  # signal: (lag [s], noise std, hold rate [Hz] or None, quantum or None)
    "v": (5e-3, 0.02, 250.0, None),
    "omega": (1e-3, 0.02, 250.0, 0.1),
    "F_x": (2e-3, 25.0, None, None),
    "F_n": (2e-3, 25.0, None, None),
}


def truth_tire(kind):
    if kind == "distributed":
        return DistributedLuGre(table3(), QuarticLoad(), n=24)
    return RelaxedMagicFormula(MagicFormulaParams(**MF))


def lag(x, tau, dt):
    """Exact discretisation of tau y' + y = x for x held over each step."""
    a = np.exp(-dt / tau)
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, x.size):
        y[k] = a * y[k - 1] + (1.0 - a) * x[k - 1]
    return y


def sensor(rng, t_fine, x, t_log, lag_s, noise, hold, quantum):
    y = lag(x, lag_s, t_fine[1] - t_fine[0]) if lag_s else x
    if hold:  # sample-and-hold: the value sampled at the last hold instant
        t_s = np.floor(t_log * hold + 1e-9) / hold
    else:
        t_s = t_log
    idx = np.rint(t_s / (t_fine[1] - t_fine[0])).astype(int)
    y = y[idx] + noise * rng.standard_normal(t_log.size)
    if hold:  # noise is drawn per sample-and-hold value, not per log sample
        first = np.unique(idx, return_index=True)[1]
        held = np.searchsorted(first, np.arange(t_log.size), side="right") - 1
        y = y[first][held]
    if quantum:
        y = quantum * np.rint(y / quantum)
    return y


def generate(name):
    kind, v0, duration, ramps, seed = BRAKINGS[name]
    car = QuarterCar(truth_tire(kind), mass=MASS, inertia=INERTIA, radius=RADIUS,
                     load=LoadRelaxation(**LOAD))
    n_fine = int(round(duration / SIM_DT)) + 1
    t_fine = np.arange(n_fine) * SIM_DT
    sol = simulate_quarter_car(car, jnp.asarray(t_fine), lambda t: torque(ramps, t, jnp), v0,
                               rtol=1e-7, atol=1e-9, max_steps=500_000)
    truth = {"v": sol.v, "omega": sol.omega, "F_x": sol.Fx, "F_n": sol.Fn}
    rng = np.random.default_rng(seed)
    below = np.nonzero(np.asarray(sol.v) < V_END)[0]
    t_stop = t_fine[below[0]] if below.size else duration
    n_log = int(np.floor(t_stop * LOG_RATE + 1e-9)) + 1
    t_log = np.arange(n_log) / LOG_RATE
    meas = {k: sensor(rng, t_fine, np.asarray(truth[k]), t_log, *SENSORS[k]) for k in SENSORS}
    T_b = torque(ramps, t_log) * (1.0 + 0.005 * rng.standard_normal(n_log))
    data = BrakingData(t=jnp.asarray(t_log), T_b=jnp.asarray(T_b), r=jnp.asarray(RADIUS),
                       m=jnp.asarray(MASS), J=jnp.asarray(INERTIA), name=name,
                       **{k: jnp.asarray(v) for k, v in meas.items()})
    meta = {
        "description": f"synthetic braking '{name}' (vehsim experiments/generate_brakings.py)",
        "truth_tire": ("distributed LuGre PDE (eq. 14), quartic load, Table 3 parameters, "
                       "n = 24" if kind == "distributed"
                       else f"longitudinal Magic Formula with relaxation length, {MF}"),
        "truth_parameters": ({k: float(getattr(table3(), k)) for k in
                              ("sigma0", "sigma1", "sigma2", "mu_c", "mu_s", "v_s", "alpha",
                               "theta", "L")} if kind == "distributed" else MF),
        "load_relaxation": LOAD,
        "v0": v0,
        "sensors": {k: dict(zip(("lag_s", "noise_std", "hold_Hz", "quantum"), v))
                    for k, v in SENSORS.items()},
        "T_b_noise_rel": 0.005,
        "log_rate_Hz": LOG_RATE,
        "seed": seed,
        "final_speed_truth": float(np.interp(t_log[-1], t_fine, np.asarray(sol.v))),
    }
    Tf = np.asarray(sol.Fx)
    print(f"{name}: v {v0} -> {meta['final_speed_truth']:.2f} m/s, peak |F_x| "
          f"{np.max(np.abs(Tf)):.0f} N, {n_log} samples", file=sys.stderr)
    return data, meta


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(OUT))
    parser.add_argument("--check", action="store_true",
                        help="compare with the files in --out instead of writing")
    parser.add_argument("--only", nargs="*", default=None)
    args = parser.parse_args(argv)
    out = Path(args.out)
    ok = True
    for name in BRAKINGS:
        if args.only and name not in args.only:
            continue
        data, meta = generate(name)
        if args.check:
            import tempfile

            with tempfile.TemporaryDirectory() as tmp:
                path = save_braking(data, Path(tmp) / f"{name}.csv", meta, digits=7)
                same = {suffix: path.with_suffix(suffix).read_bytes()
                        == (out / f"{name}{suffix}").read_bytes() for suffix in (".csv", ".json")}
            print(f"{name}: " + ", ".join(f"{s} {'identical' if v else 'DIFFERS'}"
                                          for s, v in same.items()), file=sys.stderr)
            ok &= all(same.values())
        else:
            save_braking(data, out / f"{name}.csv", meta, digits=7)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
