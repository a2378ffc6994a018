"""How far the driver's real-time plans are from converged ones.

In real-time iteration (`RecedingHorizonDriver` ``mode='rti'``, the drivers' default) each
sample runs a fixed number of interior-point passes from the previous plan, shifted, and
applies the first part of whatever plan those passes reach: the plan rarely ends a sample
converged. This script drives one scenario with the road's settings (`driver_settings`,
the planner's friction ``--friction``, with the scenario's pace notes for the estimate),
then rebuilds every sample's solve as the drive posed it
(`RecedingHorizonDriver.recorded_solve`: the problem at the recorded start and planner's
peaks, the shifted plan and multipliers) and solves it twice more, one program each:

- with the drive's own options: the rebuilt solve should give the drive's plan (these
  solves are sensitive to rounding, so a few samples may differ);
- to convergence: the options of the same driver in ``mode='converged'`` (a fresh Hessian
  every pass, the multipliers re-estimated, at most `max_iterations` passes) from the same
  guess and multipliers.

Per sample it compares the two plans at the command they give (the plan `lead` seconds
after its start, `plan_point`: the slips $\\kappa_F, \\kappa_R$ and the steering angle
$\\delta$), in the planned time to the horizon's end $t(H)$, and in their KKT residuals (the
largest of the primal, dual and complementarity residuals). The first plan (a cold start
solved to convergence whatever the mode) is left out.

Prints one JSON line of percentiles (appended to ``--out``), draws ``--figure`` and writes
each sample's comparison to ``--samples-out``.

Usage: PYTHONPATH=. python experiments/rti_suboptimality.py [--road corner90]
       [--grip minus20] [--friction estimate] [--seed 0] [--passes N] [--out PATH]
       [--figure PATH] [--samples-out PATH]
"""

from __future__ import annotations

import argparse
import datetime
import json
import time
from pathlib import Path

import jax


jax.config.update("jax_enable_x64", True)

import equinox as eqx  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import vehsim as vs  # noqa: E402


HERE = Path(__file__).resolve().parent
ROADS = ("corner90", "uturn", "sturn", "stage")
GRIPS = ("nominal", "minus20", "icy", "rising")
FRICTIONS = ("estimate", "oracle", "nominal")


def _args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--road", default="corner90", choices=ROADS)
    p.add_argument("--grip", default="minus20", choices=GRIPS)
    p.add_argument("--friction", default="estimate", choices=FRICTIONS,
                   help="the planner's friction (estimate: with the scenario's pace notes)")
    p.add_argument("--seed", type=int, default=0, help="the sensors' noise seed")
    p.add_argument("--passes", type=int, default=None,
                   help="interior-point passes per sample, [1, 100] (default: the road's)")
    p.add_argument("--out", default=str(HERE / "rti_suboptimality_results.jsonl"))
    p.add_argument("--figure", default=None, help="a figure of the samples (PNG)")
    p.add_argument("--samples-out", default=None,
                   help="write each sample's comparison here, one JSON line per sample")
    args = p.parse_args(argv)
    if args.passes is not None and not 1 <= args.passes <= 100:
        p.error(f"--passes must lie in [1, 100], got {args.passes}")
    return args


def _drivers(sc, args):
    notes = args.friction == "estimate"
    settings = vs.driver_settings(args.road, args.friction)
    if args.passes is not None:
        settings = settings | {"iterations": args.passes}
    rti, estimator = vs.scenario_driver(sc, args.friction, pace_notes=notes, **settings)
    conv_settings = vs.driver_settings(args.road, args.friction, mode="converged")
    conv, _ = vs.scenario_driver(sc, args.friction, pace_notes=notes, **conv_settings)
    return rti, conv, estimator


def _kkt(sol):
    return float(jnp.maximum(jnp.maximum(sol.inf_pr, sol.inf_du), sol.compl))


def _percentiles(a):
    a = np.asarray(a, float)
    return {f"p{q}": float(np.percentile(a, q)) for q in (50, 90, 99)} | {
        "max": float(np.max(a))}


def main(argv=None):
    args = _args(argv)
    sc = vs.drive_scenario(args.road, args.grip)
    rti, conv, estimator = _drivers(sc, args)
    t0 = time.perf_counter()
    run = jax.jit(lambda key: vs.simulate_drive(sc.plant, rti, sc.state0, key, sc.num_samples,
                                                estimator=estimator, substep_poses=True))(
        jax.random.key(args.seed))
    outcome = vs.drive_outcome(sc.road, *vs.drive_path(run, sc.state0))
    gate = "never crossed" if outcome.time is None else f"end gate {outcome.time:.3f} s"
    print(f"drive: {time.perf_counter() - t0:.1f} s (with its compilation); {gate}, "
          f"{outcome.max_off_road:.3f} m off the road", flush=True)
    info = jax.tree.map(np.asarray, run.controller_info)
    T = np.asarray(run.states.t)
    last = len(T) - 1 if outcome.time is None else int(np.searchsorted(T, outcome.time))
    samples = range(1, min(last + 1, len(T)))

    solve = eqx.filter_jit(lambda p, x, u, o, m: vs.interior_point(p, x, u, o, throw=False,
                                                                  multipliers=m))
    rows = []
    t0 = time.perf_counter()
    for k in samples:
        prob, xs0, us0, options, duals = rti.recorded_solve(info, k)
        again = solve(prob, xs0, us0, options, duals)
        full = solve(prob, xs0, us0, conv.options(False, False), duals)
        X_rti, _ = rti.plan_point(jnp.asarray(info["xs"][k]), jnp.asarray(info["us"][k]))
        X_conv, _ = rti.plan_point(full.xs, full.us)
        d = np.abs(np.asarray(X_rti[5:8] - X_conv[5:8]))
        rows.append(dict(
            k=k, s=float(info["s"][k]), kkt_rti=float(info["kkt"][k]),
            rebuilt=float(np.max(np.abs(np.asarray(again.xs) - info["xs"][k]))),
            kkt_conv=_kkt(full), converged=bool(full.result == vs.RESULTS.successful),
            iterations=int(full.iterations), d_kappa_F=float(d[0]), d_kappa_R=float(d[1]),
            d_delta_deg=float(np.degrees(d[2])),
            t_H=float(full.xs[-1, 8]), dt_H=float(info["xs"][k][-1, 8] - full.xs[-1, 8])))
    wall = time.perf_counter() - t0
    conv_rows = [r for r in rows if r["converged"]]
    rec = dict(
        script="rti_suboptimality", road=args.road, grip=args.grip, friction=args.friction,
        seed=args.seed, passes=int(rti.iterations), samples=len(rows),
        end_time=outcome.time, max_off_road=outcome.max_off_road,
        completed=bool(outcome.completed), resolves_wall_s=round(wall, 1),
        rebuilt_exactly=sum(r["rebuilt"] < 1e-9 for r in rows),
        rebuilt=_percentiles([r["rebuilt"] for r in rows]),
        rebuilt_off=sum(r["rebuilt"] > 1e-3 for r in rows),
        rti_converged=int(np.sum(np.asarray(info["converged"])[list(samples)])),
        converged=len(conv_rows),
        kkt_rti=_percentiles([r["kkt_rti"] for r in rows]),
        # the differences where the converged solve converged (a plan to compare against)
        d_delta_deg=_percentiles([r["d_delta_deg"] for r in conv_rows]),
        d_kappa=_percentiles([max(r["d_kappa_F"], r["d_kappa_R"]) for r in conv_rows]),
        dt_H_ms=_percentiles([1e3 * abs(r["dt_H"]) for r in conv_rows]),
        dt_H_mean_ms=float(np.mean([1e3 * r["dt_H"] for r in conv_rows])),
        t_H_s=_percentiles([r["t_H"] for r in conv_rows]),
        date=datetime.date.today().isoformat())
    line = json.dumps(rec)
    print(line)
    with open(args.out, "a") as f:
        f.write(line + "\n")
    if args.samples_out:
        tmp = Path(args.samples_out).with_suffix(".tmp")
        tmp.write_text("".join(json.dumps(r) + "\n" for r in rows))
        tmp.replace(args.samples_out)
    if args.figure:
        _figure(rows, rec, args.figure)
        print(f"figure: {args.figure}")


def _figure(rows, rec, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = np.array([r["s"] for r in rows])
    ok = np.array([r["converged"] for r in rows])
    fig, ax = plt.subplots(3, 1, figsize=(7.5, 7.5), sharex=True, constrained_layout=True)
    ax[0].semilogy(s, [r["kkt_rti"] for r in rows], ".-", label="real-time plan")
    ax[0].semilogy(s[ok], [r["kkt_conv"] for r, o in zip(rows, ok) if o], ".",
                   label="solved to convergence")
    ax[0].set_ylabel("KKT residual")
    ax[0].legend()
    ax[1].plot(s[ok], [r["d_delta_deg"] for r, o in zip(rows, ok) if o], ".-",
               label=r"$|\Delta\delta|$ [deg]")
    ax[1].plot(s[ok], [100 * max(r["d_kappa_F"], r["d_kappa_R"])
                       for r, o in zip(rows, ok) if o], ".-",
               label=r"$\max_i |\Delta\kappa_i|$ [%]")
    ax[1].set_ylabel("command difference")
    ax[1].legend()
    ax[2].plot(s[ok], [1e3 * r["dt_H"] for r, o in zip(rows, ok) if o], ".-")
    ax[2].axhline(0.0, color="0.6", lw=0.8)
    ax[2].set_ylabel(r"$t_{rti}(H) - t_{conv}(H)$ [ms]")
    ax[2].set_xlabel("arc length of the car at the sample [m]")
    ax[0].set_title(f"{rec['road']}, {rec['grip']}, {rec['friction']}: "
                    f"{rec['passes']} passes per sample against converged plans")
    tmp = Path(path).with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(path)


if __name__ == "__main__":
    main()
