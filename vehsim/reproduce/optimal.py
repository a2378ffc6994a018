"""Reproduce section: optimal driving primitives (report section 2.5, Table 4, Fig. 20)."""

from __future__ import annotations

import time

import numpy as np

from ..plot import primitive_figure, replay_figure


TITLE = "Optimal driving primitives: minimum time and maximum exit speed (section 2.5, Fig. 20)"

PROBLEMS = (
    ("corner90", "min-time", "a"),
    ("corner90", "max-exit", "b"),
    ("uturn", "min-time", "c"),
    ("sturn", "min-time", "d"),
)


def techniques(sig: dict, t: np.ndarray) -> dict:
    """Which race-driving techniques show in a solution, with the evidence.

    - trail braking: braking (a slip < -0.02) while steering more than 3 degrees;
    - rear-wheel locking / handbrake: rear slip below -0.5 while the front slip is above it;
    - left-foot braking: one axle drives (slip > 0.02) while the other brakes (< -0.02).
    """
    kF, kR, d = sig["kappa_F"], sig["kappa_R"], np.degrees(sig["delta"])
    dt = np.gradient(t)
    brake = (np.minimum(kF, kR) < -0.02) & (np.abs(d) > 3.0)
    lock = (kR < -0.5) & (kF > kR)
    lfb = ((kF > 0.02) & (kR < -0.02)) | ((kR > 0.02) & (kF < -0.02))
    return {
        "trail_braking_s": float(np.sum(dt[brake])),
        "rear_locking_s": float(np.sum(dt[lock])),
        "min_kappa_R": float(kR.min()),
        "left_foot_braking_s": float(np.sum(dt[lfb])),
        "max_sideslip_deg": float(np.degrees(np.max(np.abs(sig["sideslip"])))),
    }


def reproduce(ctx) -> None:
    segments = 30 if ctx.tiny else 50 if ctx.quick else 150  # tiny: the tests' grid
    problems = PROBLEMS[:1] if ctx.quick else PROBLEMS
    # several point-mass seeds (corridor margin, friction fraction): the problems have several
    # local optima and the best converged one is kept
    starts = ((0.5, 0.6),) if ctx.quick else ((0.5, 0.6), (0.3, 0.8), (0.8, 0.45))
    ctx.text(
        f"Direct multiple shooting ({segments} segments, one RK4 node each, t = tau t_f), "
        "solved by vehsim's structured interior-point method (block-tridiagonal KKT factored "
        "by a Riccati recursion, filter line search with second-order correction). Vehicle "
        "rally-gravel, friction-ellipse Magic Formula (D = 0.52), quasi-static load "
        "transfer; corridor and axle-speed floor enforced at every node. "
        + ("Quick mode: corner90 min-time only, coarse grid." if ctx.quick else "")
    )
    rows = ["| problem | status | t_f [s] | exit speed [m/s] | point-mass bound | ratio | "
            "corridor viol. [m] | BC viol. | iterations | solve [s] |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for road, objective, panel in problems:
        rows.append(_problem(ctx, road, objective, panel, segments, starts))
    ctx.text(*rows)


def _problem(ctx, road: str, objective: str, panel: str, segments: int, starts) -> str:
    """Solve one benchmark problem, draw its Fig. 20 panel, record it; returns its table row."""
    from .._compilation import primitive_and_bound
    from ..optimal.primitive import solution_record
    from ..optimal.primitives import primitive_options

    ctx.log(f"{road} {objective} ({segments} segments)")
    opts = primitive_options(objective, starts)
    t0 = time.perf_counter()
    prim, bound = primitive_and_bound(road, objective, num_stages=segments, steps_per_stage=1,
                                      options=opts, starts=starts, throw=False)
    wall = time.perf_counter() - t0
    rec = solution_record(prim, bound)
    tech = techniques(prim.signals(), np.asarray(prim.time()))
    key = f"{road}_{objective}"
    ctx.record(key, {k: rec[k] for k in ("t_f", "exit_speed", "status", "iterations",
                                         "violations", "point_mass_t_f",
                                         "point_mass_exit_speed", "t_f_over_bound")}
               | {"techniques": tech, "wall_time_s": wall})
    b = rec["point_mass_t_f"] if objective == "min-time" else rec["point_mass_exit_speed"]
    ratio = (rec["t_f"] / b) if objective == "min-time" else (rec["exit_speed"] / b)
    row = (
        f"| {road} {objective} | {rec['message']} | {rec['t_f']:.3f} | "
        f"{rec['exit_speed']:.2f} | {b:.3f} | {ratio:.3f} | "
        f"{rec['violations']['corridor']:.1e} | {rec['violations']['boundary']:.1e} | "
        f"{rec['iterations']} | {wall:.1f} |"
    )
    fig = primitive_figure(prim, title=f"({panel}) {road}, {objective}: t_f = {rec['t_f']:.3f} s")
    ctx.figure(fig, f"fig20{panel}_{key}",
               f"Fig. 20({panel}): {road}, {objective}; car outline every 0.3 s, "
               "speed, sideslip, slips, steering.")
    if (road, objective) == ("corner90", "min-time"):
        _replay_section(ctx, prim)
    ctx.text(
        f"{road} {objective}: trail braking {tech['trail_braking_s']:.2f} s, rear slip "
        f"below -0.5 for {tech['rear_locking_s']:.2f} s (min kappa_R "
        f"{tech['min_kappa_R']:.2f}), opposite-sign axle slips (left-foot braking) "
        f"{tech['left_foot_braking_s']:.2f} s, max sideslip {tech['max_sideslip_deg']:.1f} deg."
    )
    return row


def _replay_section(ctx, prim) -> None:
    """Replay: the primitive's recovered torques on the full half-car, open loop and tracked."""
    from ..optimal.replay import (
        matched_lugre_tire,
        replay_open_loop,
        replay_tracking,
    )

    ctx.log("replay of corner90 min-time on the full half-car")
    kR_min = float(np.min(prim.signals()["kappa_R"]))
    lugre = matched_lugre_tire()
    runs = {}
    if not ctx.quick:
        runs["open loop, static tire, no suspension"] = replay_open_loop(prim, suspension=False)
        runs["open loop, static tire, suspension"] = replay_open_loop(prim)
        runs["tracked, static tire, suspension"] = replay_tracking(prim)
    runs["open loop, LuGre tire, suspension"] = replay_open_loop(prim, tire=lugre)
    runs["tracked, LuGre tire, suspension"] = replay_tracking(prim, tire=lugre)
    ctx.record("corner90_min-time_replay", {k: v.drift for k, v in runs.items()})
    rows = ["| replay | off road (max) [m] | reference off road [m] | final position error [m] "
            "| final heading error [rad] | max deviation from reference [m] |",
            "|---|---|---|---|---|---|"]
    for k, v in runs.items():
        d = v.drift
        rows.append(f"| {k} | {d['max_corridor_violation']:.3f} | "
                    f"{d['reference_corridor_violation']:.3f} | "
                    f"{d['final_position_error']:.3f} | {d['final_heading_error']:.3f} | "
                    f"{d['max_deviation_from_reference']:.3f} |")
    ctx.text(
        "Replay. The torques that realise the optimal slips are recovered along the "
        "primitive (T_i = I_i domega_i/dt + f_ix r, eqs. 52-53, with the piecewise-linear "
        "slips' exact rates) and drive the full half-car (wheel spin, suspension of eqs. "
        "54-60) from the primitive's start (wheel speeds from the slips, suspension and tire "
        "states at equilibrium). Without suspension and with the same static tire the full "
        "model *is* the reduced one, and the replay follows the primitive to solver "
        "tolerance. With the suspension, or the dynamic lumped LuGre tire (fitted to the "
        "friction-ellipse steady state, `matched_lugre_tire`), open loop drifts off: the "
        f"optimum brakes the rear axle near the friction peak (min slip {kR_min:.2f}; the "
        "peak is at -0.18), an unstable equilibrium of the wheel, and any load or force mismatch locks it. A simple "
        "tracking feedback around the feedforward (Stanley steering on lateral and heading "
        "error, proportional speed and along-track torque correction, slip tracking on the "
        "wheel speeds; `TrackingGains`) keeps the full model on the road: its distance off "
        "the road is no larger than the reference's own (the coarse grid keeps the corridor "
        "at its nodes only and cuts the inner corner slightly between them).",
        *rows,
    )
    fig = replay_figure(prim, runs, title="corner90 min-time: replay on the full half-car")
    ctx.figure(fig, "replay_corner90_min_time",
               "Primitive (reduced model) and its replays on the full half-car, open loop "
               "and with path tracking; legend: max distance off the road.")
