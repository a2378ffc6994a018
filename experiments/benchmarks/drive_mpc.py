"""Benchmark: vehsim's receding-horizon driver against the same MPC in do-mpc.

Both controllers solve the same horizon problem per sample (`vehsim.HorizonOCP`: the
reduced half-car in arc length over H m in M stages, one RK4 step per stage, the corridor
with its margin at the knots and the stages' midpoints, the node constraints, the steering
rate, the terminal speed, sideslip and heading bounds, the bound on the axles' combined
slip, each stage's peak friction at the speed the previous plan drives it at (and, with
a driver's `stiffness_power`, each stage's tire $B$ below the car's grip), objective
t(H) + w sum |u|^2 h; ``--no-slip-limit``: the driver's bound off in both) and
drive the same plant on the same road at 20 Hz: `vehsim.drive_scenario(road, "nominal")`
(the `DrivePlant` with the lumped 2D LuGre tires on the gravel whose peak friction is the
planner's D = 0.52, the actuators' delay, rate limit and lag, the sensors' noise of the same
seed, the scenario's start speed and time budget).

- vehsim: `RecedingHorizonDriver` with the scenario's `driver_settings` (on the stage
  more passes per sample in 'rti' mode and 90 % of the peak, which do-mpc's problem gets
  too through the stages' grip) (its jitted ``command``: projection, prediction over the
  actuator delay, the shifted warm start, `interior_point`, the torques), timed per sample
  with ``block_until_ready`` in a Python loop; in 'converged' mode, in 'rti' mode, and in
  'rti' mode with the first pass's Hessian kept for the sample's later passes
  (``hessian_update='first'``, reported as 'vehsim-rti-frozen'); with ``--modes
  rti-kept`` also with its Jacobians kept (``jacobian_update='first'``).
- do-mpc (`_dompc_driver`): the problem as do-mpc's discrete model with the arc length as
  the independent variable (``t_step`` = H/M; the same RK4 stage map, so the same
  transcription), the road's data along the horizon as time-varying parameters set from the
  current station each sample, IPOPT (MUMPS; HSL's MA27 is not in this CasADi build) to the
  same tolerance and iteration cap, warm-started by do-mpc from its previous solution and
  multipliers (``--shift``: from the previous plan shifted by the distance travelled, as
  vehsim's driver does), CasADi's common-subexpression elimination on,
  ``store_full_solution`` off, no printing. Per sample, in Python: the
  driver's own jitted projection and prediction and the problem's arrays (the same
  functions as vehsim's, so both see identical data), ``mpc.make_step``, and the driver's
  conversion of the plan's inputs to the command (`RecedingHorizonDriver.plan_command`,
  with the same traction control).

``--sample-solves`` (with the converged mode): each sample's problem of vehsim's converged
drive solved again on its own (`sample_solves`), by vehsim from the drive's warm start
(`RecedingHorizonDriver.recorded_solve`), by vehsim from the same plan without the
multipliers, and by IPOPT through the do-mpc transcription from the same plan (IPOPT's own
multiplier estimate): the same problems and starts for both solvers, so their robustness
(solves converged, iterations) and their time per solve compare directly; ``ratio`` = IPOPT's
p50 time per solve / vehsim's without the multipliers.

Per-sample compute of each controller alone (the plant's step is not timed; each drive
stops once the car is past the road's end): p50, p99, mean and max of the samples after the
first (vehsim's first command solves the first plan from the cold start, do-mpc's setup
does; ``first_sample_ms`` apart); ``ratio`` = do-mpc
p50 / vehsim p50 (and the p99 ratio); the closed-loop results
(`vehsim.drive_outcome` on the CG's path at every integration step: drive time to the
end gate, largest distance off the road, completed); the open-loop agreement of the first
horizon solve (same state, same starting guess): objectives and the largest differences of
the plans. Run on one core:

    taskset -c 0 env OMP_NUM_THREADS=1 \\
      XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1" \\
      PYTHONPATH=. python experiments/benchmarks/drive_mpc.py --out \\
      experiments/benchmarks/drive_mpc_results.jsonl
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np


jax.config.update("jax_enable_x64", True)

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))  # also when loaded by path
import _dompc_driver  # noqa: E402

import vehsim  # noqa: E402
from vehsim.drive.horizon import profile_guess, shift_plan  # noqa: E402
from vehsim.drive.metrics import drive_outcome  # noqa: E402
from vehsim.drive.plant import drive_step, measure_drive  # noqa: E402
from vehsim.drive.scenarios import drive_scenario  # noqa: E402
from vehsim.optimal.ip import interior_point  # noqa: E402
from vehsim.optimal.shooting import KAPPA_MAX, KAPPA_MIN, SPEED_FLOOR  # noqa: E402


SAMPLE_TIME = 0.05


def percentiles(times):
    """Per-sample compute [ms] after the first sample (vehsim's first command solves the
    first plan from the cold start; do-mpc's solves it in its own setup), which is reported
    apart as ``first_sample_ms``."""
    t = np.asarray(times)[1:] * 1e3
    return {"p50_ms": round(float(np.percentile(t, 50)), 3),
            "p99_ms": round(float(np.percentile(t, 99)), 3),
            "mean_ms": round(float(np.mean(t)), 3), "max_ms": round(float(np.max(t)), 3),
            "samples": int(t.size), "first_sample_ms": round(float(times[0]) * 1e3, 3)}


def arrays(prob):
    """The arrays of the `HorizonOCP` ``prob`` that do-mpc's tvp table is made of
    (`_dompc_driver.tvp_table`)."""
    return (prob.curvature[:, 0], prob.grip, prob.corridor, prob.corridor_mid[:, 0],
            prob.terminal_speed, prob.slip_limit)


def tvp_rows(tvp_arrays):
    """do-mpc's tvp table of a sample from `arrays` (NumPy; no slip bound stays None)."""
    return _dompc_driver.tvp_table(*(None if a is None else np.asarray(a)
                                     for a in tvp_arrays))


# ---- the do-mpc controller ----------------------------------------------------------------


def dompc_mpc(driver, warm_start: bool = True):
    """do-mpc's MPC of the vehsim ``driver``'s horizon problem (`_dompc_driver.horizon_mpc`:
    its sizes, limits, weights, tolerance, iteration cap and first barrier) and its
    ``set_horizon``; ``warm_start``: IPOPT's warm start from do-mpc's previous solution."""
    tire, par = driver.vehicle.tire, driver.vehicle.params
    if (float(tire.B), float(tire.C), float(par.m), float(par.Iz), float(par.lF),
            float(par.lR), float(par.h)) != (7.0, 1.6, 1450.0, 2740.0, 1.3, 1.4, 0.4):
        raise SystemExit("the do-mpc model (_casadi_maneuver.body_model) is the rally "
                         "gravel car with B = 7, C = 1.6: the driver plans with another")
    d = driver
    limits = dict(SPEED_FLOOR=SPEED_FLOOR, KAPPA_MIN=KAPPA_MIN, KAPPA_MAX=KAPPA_MAX,
                  DELTA_MAX=float(d.steer_limit))
    ocp = d.problem(0.0, jnp.zeros(8), jnp.full((d.num_stages,), float(d.nominal_peak)))
    return _dompc_driver.horizon_mpc(
        float(d.horizon), d.num_stages, limits, D=float(d.vehicle.tire.D),
        rate_weight=float(d.rate_weight), steer_rate=float(d.steer_rate),
        terminal_sideslip=float(ocp.terminal_sideslip),
        terminal_heading=float(ocp.terminal_heading), tol=d.tol,
        max_iter=d.max_iterations, mu_init=float(d.barrier), warm_start=warm_start,
        stiffness_power=None if d.stiffness_power is None else float(d.stiffness_power))


class DompcDriver:
    """The do-mpc MPC as a drive controller (module docstring), with the vehsim driver
    ``driver``'s projection, prediction, problem data and command conversion."""

    def __init__(self, driver, shift: bool = False):
        self.driver = driver
        self.shift = shift
        d = driver
        self.mpc, self.set_horizon = dompc_mpc(driver)

        def prepare(s_prev, t_prev, position, position_var, velocity, inputs, m, xs, us,
                    s_plan):
            position, position_var, velocity = d.filter_position(
                SimpleNamespace(t=t_prev, position=position, position_var=position_var,
                                velocity=velocity), m)
            s, X5 = d._measured_state(m, position, s_prev)
            y = d.predict(s, X5, inputs, d.delay_samples * d.sample_time) \
                if d.delay_samples > 0 else jnp.concatenate([s[None], X5])
            state8 = jnp.concatenate([y[1:], inputs])
            xs0, us0 = shift_plan(xs, us, y[0] - s_plan, d.horizon)
            D = d.planner_friction(y[0], None, d.stage_speeds(xs0))
            return (s, position, position_var, velocity, y[0], state8, D,
                    arrays(d.problem(y[0], state8, D)), (xs0, us0))

        def finish(xs, us, D0, inputs_prev, m, s_pred):
            scales = None if d.traction_limit is None else d.believed_scales(s_pred, None)
            inputs, torques = d.plan_command(xs, us, D0, scales)
            torques = torques + d.slip_gain * (inputs_prev[:2] - d.measured_slip(m))
            return inputs, jnp.concatenate([torques, inputs[2:]])

        self._prepare = jax.jit(prepare)
        self._finish = jax.jit(finish)
        self.make_step_times = []
        self.iterations = []
        self.success = []

    def _solve(self, state8, tvp_arrays):
        self.set_horizon(tvp_rows(tvp_arrays))
        x0 = np.concatenate([np.asarray(state8), [0.0]])
        t0 = time.perf_counter()
        self.mpc.make_step(x0)
        self.make_step_times.append(time.perf_counter() - t0)
        stats = self.mpc.solver_stats
        self.iterations.append(int(stats["iter_count"]))
        self.success.append(bool(stats["success"]))
        return _dompc_driver.plan(self.mpc)

    def first_problem(self, m):
        """The first sample's station, inputs, problem and starting guess (as
        `RecedingHorizonDriver.init`)."""
        d = self.driver
        d2 = (d.table.x - m.x) ** 2 + (d.table.y - m.y) ** 2
        s_guess = d.table.s[jnp.argmin(d2)]
        inputs = jnp.stack([0.0 * m.delta, 0.0 * m.delta, m.delta])
        s, X5 = d._measured_state(m, jnp.stack([m.x, m.y]), s_guess)
        state8 = jnp.concatenate([X5, inputs])
        D = d.planner_friction(s, None, jnp.hypot(X5[2], X5[3]))
        prob = d.problem(s, state8, D)
        guess = profile_guess(d.table, d.vehicle, s, state8, D, horizon=d.horizon)
        return s, inputs, state8, prob, guess

    def init(self, m):
        """The first plan, from `profile_guess`, re-solved until IPOPT converges (at most 5
        calls of ``max_iter`` iterations; untimed, as vehsim's `init`)."""
        s, inputs, state8, prob, (xs0, us0) = self.first_problem(m)
        _dompc_driver.set_guess(self.mpc, xs0, us0)
        for _ in range(5):
            xs, us = self._solve(state8, arrays(prob))
            if self.success[-1]:
                break
        self.make_step_times.clear()
        self.iterations.clear()
        self.success.clear()
        # compile the jitted pieces now (vehsim's command is compiled before its loop too)
        position, velocity = jnp.stack([m.x, m.y]), self.driver._world_velocity(m)
        position_var = self.driver.position_std ** 2
        jax.block_until_ready(self._prepare(s, m.t, position, position_var, velocity, inputs, m,
                                            jnp.asarray(xs), jnp.asarray(us), s))
        jax.block_until_ready(self._finish(jnp.asarray(xs), jnp.asarray(us), prob.grip[0],
                                           inputs, m, s))
        return {"s": s, "t": m.t, "position": position, "position_var": position_var,
                "velocity": velocity, "s_plan": s, "inputs": inputs, "xs": xs, "us": us}

    def command(self, cs, m):
        s, position, position_var, velocity, s_pred, state8, D, data, (xs0, us0) = \
            self._prepare(cs["s"], cs["t"], cs["position"], cs["position_var"],
                          cs["velocity"], cs["inputs"], m, jnp.asarray(cs["xs"]),
                          jnp.asarray(cs["us"]), cs["s_plan"])
        if self.shift:
            _dompc_driver.set_guess(self.mpc, np.asarray(xs0), np.asarray(us0))
        xs, us = self._solve(state8, data)
        inputs, command = self._finish(jnp.asarray(xs), jnp.asarray(us), D[0], cs["inputs"], m,
                                       s_pred)
        return {"s": s, "t": m.t, "position": position, "position_var": position_var,
                "velocity": velocity, "s_plan": s_pred, "inputs": inputs, "xs": xs,
                "us": us}, command


# ---- the closed loop ----------------------------------------------------------------------


def sample_solves(driver, states):
    """Each sample's solve of vehsim's drive (``states``: its `HorizonState` per command)
    solved again on its own: by vehsim from the drive's warm start
    (`RecedingHorizonDriver.recorded_solve`), by vehsim from the same plan without the
    multipliers, and by IPOPT through do-mpc's transcription from the same plan (IPOPT's own
    multiplier estimate, its first barrier the driver's, no do-mpc warm start). The first
    sample (the cold first plan) is left out. Returns per solver the converged count, the
    iterations and the wall time per solve (vehsim's compiled beforehand)."""
    info = jax.tree.map(lambda *a: np.stack([np.asarray(x) for x in a]),
                        *[driver.info(s) for s in states])
    mpc, set_horizon = dompc_mpc(driver, warm_start=False)
    solve = jax.jit(lambda p, x, u, o, d: interior_point(p, x, u, o, throw=False,
                                                         multipliers=d))
    out = {"vehsim": [], "vehsim_without_multipliers": [], "ipopt": []}
    for k in range(1, len(states)):
        prob, xs0, us0, options, duals = driver.recorded_solve(info, k)
        cold = (duals[0], duals[1], jnp.zeros_like(duals[2]))
        if k == 1:  # compile
            jax.block_until_ready(solve(prob, xs0, us0, options, duals))
        for name, d in (("vehsim", duals), ("vehsim_without_multipliers", cold)):
            t0 = time.perf_counter()
            sol = jax.block_until_ready(solve(prob, xs0, us0, options, d))
            out[name].append((bool(sol.converged), int(sol.iterations),
                              time.perf_counter() - t0))
        set_horizon(tvp_rows(arrays(prob)))
        _dompc_driver.set_guess(mpc, np.asarray(xs0), np.asarray(us0))
        t0 = time.perf_counter()
        mpc.make_step(np.concatenate([np.asarray(info["start"][k]), [0.0]]))
        dt = time.perf_counter() - t0
        stats = mpc.solver_stats
        out["ipopt"].append((bool(stats["success"]), int(stats["iter_count"]), dt))
    summary = {}
    for name, rows in out.items():
        conv, its, dt = (np.array(c) for c in zip(*rows))
        summary[name] = {
            "converged": int(conv.sum()), "solves": int(conv.size),
            "failed_samples": [k + 1 for k in np.flatnonzero(~conv).tolist()],
            "iterations_p50": float(np.median(its)), "iterations_mean": round(float(its.mean()), 2),
            "solve_ms_p50": round(float(np.median(dt)) * 1e3, 3)}
    return summary


def closed_loop(command, cs, plant, state0, m0, key, num_samples, step, table):
    """Drive at most ``num_samples`` samples in a Python loop, until the CG is past the road's
    end (arc length L on ``table``); the controller's ``command(cs, m)`` alone is timed (its
    outputs blocked on). Returns the per-sample times and the CG's path ``(t, x, y)`` at
    every integration step, the start first (as `vehsim.drive_path`)."""
    state, m = state0, m0
    S = plant.substeps
    times, t, xy = [], [0.0], [np.asarray(state0.car[:2])[None]]
    station = jax.jit(lambda car, sg: table.to_frenet(car[0], car[1], car[2], sg)[0])
    s = 0.0
    for k in range(num_samples):
        t0 = time.perf_counter()
        cs, cmd = command(cs, m)
        cmd = jax.block_until_ready(cmd)
        times.append(time.perf_counter() - t0)
        state, m, poses = step(plant, state, cmd, jax.random.fold_in(key, k + 1))
        t.extend(SAMPLE_TIME * (k + np.arange(1, S + 1) / S))
        xy.append(np.asarray(poses))
        s = float(station(state.car, s))
        if not np.all(np.isfinite(xy[-1])) or s > float(table.length):
            break
    xy = np.concatenate(xy)
    return times, (np.array(t), xy[:, 0], xy[:, 1])


def drive_result(road, path):
    """Drive time to the end gate, the CG's largest distance off the road (every integration
    step), completed (`vehsim.drive_outcome`)."""
    out = drive_outcome(road, *path)
    return {"drive_time_s": out.time, "max_off_road_m": out.max_off_road,
            "completed": out.completed}


def objective(xs, us, H, w):
    M = us.shape[0]
    return float(xs[-1, 8] + w * H / M * np.sum(np.asarray(us) ** 2))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--road", default="corner90")
    ap.add_argument("--speed", type=float, default=None,
                    help="initial speed [m/s] (default: the scenario's)")
    ap.add_argument("--samples", type=int, default=None,
                    help="samples to drive (default: the scenario's time budget)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--horizon", type=float, default=None,
                    help="horizon H [m] (default: the driver's)")
    ap.add_argument("--stages", type=int, default=None,
                    help="stages M (default: the driver's)")
    ap.add_argument("--modes", default="converged,rti,rti-frozen",
                    help="vehsim modes to run: converged, rti, rti-frozen (rti with the "
                         "first pass's Hessian kept: hessian_update='first'), rti-kept "
                         "(its Jacobians kept too: jacobian_update='first')")
    ap.add_argument("--shift", action="store_true",
                    help="warm-start do-mpc from its plan shifted by the distance travelled "
                         "(vehsim's shift) instead of do-mpc's own unshifted previous solution")
    ap.add_argument("--no-slip-limit", action="store_true",
                    help="plan without the bound on the axles' combined slip (both drivers)")
    ap.add_argument("--driver-settings", default=None, metavar="JSON",
                    help="settings laid over the road's driver settings, for both drivers "
                         "(e.g. '{\"tol\": 1e-4}')")
    ap.add_argument("--sample-solves", action="store_true",
                    help="after vehsim's converged drive, solve each of its samples' "
                         "problems again on its own, by vehsim and by IPOPT from the same "
                         "plan (`sample_solves`)")
    ap.add_argument("--out", default=None, help="append the JSON lines to this file")
    args = ap.parse_args(argv)
    if args.sample_solves and "converged" not in args.modes.split(","):
        raise SystemExit("--sample-solves: needs vehsim's converged drive, 'converged' in "
                         f"--modes (got {args.modes!r})")
    overrides = json.loads(args.driver_settings) if args.driver_settings else {}
    if not isinstance(overrides, dict):
        raise SystemExit("--driver-settings: expected a JSON object, got "
                         f"{args.driver_settings!r}")
    warnings.filterwarnings("ignore")
    load_before = os.getloadavg()

    sc = drive_scenario(args.road, "nominal", start_speed=args.speed)
    road, plant, table, state0 = sc.road, sc.plant, sc.table, sc.state0
    num_samples = sc.num_samples if args.samples is None else args.samples
    key = jax.random.PRNGKey(args.seed)
    m0 = measure_drive(plant, state0, jax.random.fold_in(key, 0))
    step = jax.jit(lambda p, st, c, k: drive_step(p, st, c, k, substep_poses=True))
    rows = []

    def emit(**row):
        rows.append(row)
        print(json.dumps(row), flush=True)

    sizes = {k: v for k, v in (("horizon", args.horizon), ("num_stages", args.stages))
             if v is not None}
    bound = {"slip_limit": None} if args.no_slip_limit else {}
    probe = vehsim.RecedingHorizonDriver(table=table, **sizes)
    H, M = float(probe.horizon), probe.num_stages
    common = dict(road=args.road, horizon_m=H, stages=M,
                  sample_time_s=SAMPLE_TIME, initial_speed=float(sc.start_speed),
                  grip="nominal", seed=args.seed, samples_budget=num_samples,
                  slip_limit=None if args.no_slip_limit else float(probe.slip_limit),
                  driver_settings=vehsim.driver_settings(args.road) | overrides)

    def planning_driver(mode, **extra):
        """The driver of vehsim's `mode` ('converged' or 'rti') with the benchmark's sizes,
        slip bound and the road's settings: every reading, and do-mpc's, from this one. The
        mode sets the Hessian update (a fresh Hessian every pass unless ``extra`` keeps the
        first), whatever the road's settings say."""
        settings = (vehsim.driver_settings(args.road) | overrides | {"hessian_update": "every"}
                    | extra)
        return vehsim.RecedingHorizonDriver(table=table, mode=mode, **sizes, **bound,
                                            **settings)

    results = {}
    for mode in args.modes.split(","):
        kept = {"rti-frozen": "every", "rti-kept": "first"}
        if mode not in ("converged", "rti", *kept):
            raise SystemExit(f"--modes: {mode!r} is not one of converged, rti, "
                             + ", ".join(kept))
        frozen = ({"hessian_update": "first", "jacobian_update": kept[mode]} if mode in kept
                  else {})
        driver = planning_driver(mode.split("-")[0], **frozen)
        init = jax.jit(lambda m, d=driver: d.init(m))
        command = jax.jit(lambda cs, m, d=driver: d.command(cs, m, None))
        t0 = time.perf_counter()
        cs = jax.block_until_ready(init(m0))
        t_init = time.perf_counter() - t0
        t0 = time.perf_counter()
        jax.block_until_ready(command(cs, m0))
        t_compile = time.perf_counter() - t0
        infos = []

        def timed(cs, m, command=command):
            cs, cmd = command(cs, m)
            infos.append(cs)
            return cs, cmd

        times, path = closed_loop(timed, cs, plant, state0, m0, key, num_samples, step,
                                  table)
        its = np.array([int(c.iterations) for c in infos])
        conv = np.array([bool(c.converged) for c in infos])
        res = drive_result(road, path)
        pct = percentiles(times)
        results[mode] = (driver, cs, pct)
        if mode == "converged":
            converged_drive = (driver, infos)
        period_ms = SAMPLE_TIME * 1e3
        emit(controller=f"vehsim-{mode}", **common, **pct,
             # compute / period, as `vehsim drive`'s real_time_factor (< 1: real time); rows
             # before these fields carried real_time_factor_p99, period / p99
             real_time_factor=round(pct["p50_ms"] / period_ms, 3),
             p99_over_period=round(pct["p99_ms"] / period_ms, 3),
             iterations_mean=round(float(its.mean()), 2), iterations_max=int(its.max()),
             converged_fraction=round(float(conv.mean()), 3),
             init_and_compile_s=round(t_init, 2), command_compile_s=round(t_compile, 2), **res)

    # do-mpc, with the converged-mode driver's settings (its tolerance, iteration cap and
    # first barrier: IPOPT's mu_init), whichever vehsim modes were run
    driver = planning_driver("converged")
    t0 = time.perf_counter()
    dm = DompcDriver(driver, shift=args.shift)
    t_setup = time.perf_counter() - t0
    cs = dm.init(m0)
    # open-loop agreement of the first horizon solve: same state, same guess
    xs_d, us_d = np.asarray(cs["xs"]), np.asarray(cs["us"])
    _, _, _, prob, guess = dm.first_problem(m0)
    sol = interior_point(prob, *guess, driver.options(first=True), throw=False)
    w = float(driver.rate_weight)
    emit(comparison="open_loop_first_solve", **common,
         vehsim_objective=objective(np.asarray(sol.xs), np.asarray(sol.us), H, w),
         vehsim_objective_reported=float(sol.objective),
         vehsim_converged=bool(sol.converged), vehsim_iterations=int(sol.iterations),
         dompc_objective=objective(xs_d, us_d, H, w),
         max_abs_diff_knots=float(np.max(np.abs(np.asarray(sol.xs) - xs_d))),
         max_abs_diff_knots_per_state=np.max(np.abs(np.asarray(sol.xs) - xs_d), 0).tolist(),
         max_abs_diff_rates=float(np.max(np.abs(np.asarray(sol.us) - us_d))))
    # the same problem: vehsim's interior point started from do-mpc's optimum stays there
    sol2 = interior_point(prob, jnp.asarray(xs_d), jnp.asarray(us_d),
                          driver.options(first=True), throw=False)
    emit(comparison="open_loop_vehsim_from_dompc_solution", **common,
         vehsim_objective=objective(np.asarray(sol2.xs), np.asarray(sol2.us), H, w),
         vehsim_converged=bool(sol2.converged), vehsim_iterations=int(sol2.iterations),
         dompc_objective=objective(xs_d, us_d, H, w),
         max_abs_diff_knots=float(np.max(np.abs(np.asarray(sol2.xs) - xs_d))),
         max_abs_diff_rates=float(np.max(np.abs(np.asarray(sol2.us) - us_d))))

    def dm_command(cs, m):
        return dm.command(cs, m)

    times, path = closed_loop(dm_command, cs, plant, state0, m0, key, num_samples, step,
                              table)
    res = drive_result(road, path)
    p_d = percentiles(times)
    emit(controller="do-mpc", **common, **p_d,
         make_step=percentiles(dm.make_step_times),
         iterations_mean=round(float(np.mean(dm.iterations)), 2),
         iterations_max=int(np.max(dm.iterations)),
         converged_fraction=round(float(np.mean(dm.success)), 3),
         setup_s=round(t_setup, 2), warm_start="shifted" if args.shift else "do-mpc",
         linear_solver="mumps", do_mpc=__import__("do_mpc").__version__,
         casadi=__import__("casadi").__version__, **res)
    for mode, (_, _, p) in results.items():
        emit(ratio_against=f"vehsim-{mode}", **common,
             ratio=round(p_d["p50_ms"] / p["p50_ms"], 2),
             ratio_p99=round(p_d["p99_ms"] / p["p99_ms"], 2))
    if args.sample_solves:
        summary = sample_solves(*converged_drive)
        emit(comparison="sample_solves", **common, **summary,
             ratio=round(summary["ipopt"]["solve_ms_p50"]
                         / summary["vehsim_without_multipliers"]["solve_ms_p50"], 2))
    emit(note="machine", load_average_before=[round(v, 2) for v in load_before],
         load_average_after=[round(v, 2) for v in os.getloadavg()],
         cpu_affinity=sorted(os.sched_getaffinity(0)), cpu_count=os.cpu_count(),
         xla_flags=os.environ.get("XLA_FLAGS", ""), date=time.strftime("%Y-%m-%d %H:%M UTC",
                                                                       time.gmtime()))
    if args.out:
        with open(args.out, "a") as f:
            for row in rows:
                f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main()
