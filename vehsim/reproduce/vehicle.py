"""Reproduce section: half-car maneuvers (report section 2.5, eqs. 49-60).

A step steer and a braking-in-a-turn maneuver of the rally-gravel half-car with the
benchmark maneuvers' friction-ellipse tire, showing sideslip, forces and the dynamic load transfer of the
suspension model (eqs. 54-60) beside the quasi-static transfer of the reduced model.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._simulate import simulate
from ..tire.friction_ellipse import rally_gravel_tire
from ..vehicle.half_car import HalfCar
from ..vehicle.maneuvers import brake_in_turn, step_steer
from ..vehicle.params import rally_gravel


TITLE = "Half-car maneuvers: step steer and braking in a turn (section 2.5, eqs. 49-60)"


def _plot(tr, tr_qs, title, static):
    import matplotlib.pyplot as plt

    t = np.asarray(tr.ts)
    fig, ax = plt.subplots(2, 3, figsize=(13, 6.5))
    ax[0, 0].plot(tr["x"], tr["y"])
    ax[0, 0].set(xlabel="x [m]", ylabel="y [m]", title="path of the centre of gravity")
    ax[0, 0].set_aspect("equal", adjustable="datalim")
    ax[0, 1].plot(t, np.degrees(tr["sideslip"]), label="sideslip angle")
    ax[0, 1].plot(t, np.degrees(tr["yaw_rate"]), label="yaw rate [deg/s]")
    ax[0, 1].plot(t, np.degrees(tr["delta"]) * 10, "--", label="steering x10")
    ax[0, 1].set(xlabel="t [s]", ylabel="[deg]", title="sideslip and yaw rate")
    ax[0, 1].legend(fontsize=8)
    ax[0, 2].plot(t, tr["speed"], label="speed [m/s]")
    ax[0, 2].plot(t, tr["ay"], label="lateral acc. [m/s^2]")
    ax[0, 2].plot(t, tr["ax"], label="longitudinal acc. [m/s^2]")
    ax[0, 2].set(xlabel="t [s]", title="speed and accelerations")
    ax[0, 2].legend(fontsize=8)
    for k, c in (("F", "C0"), ("R", "C1")):
        ax[1, 0].plot(t, tr[f"Fz_{k}"], c, label=f"F_z{k}, suspension (eqs. 54-60)")
        ax[1, 0].plot(t, tr_qs[f"Fz_{k}"], c + ":", label=f"F_z{k}, quasi-static")
        ax[1, 1].plot(t, tr[f"Fx_{k}"], c, label=f"f_{k}x")
        ax[1, 1].plot(t, tr[f"Fy_{k}"], c + "--", label=f"f_{k}y")
    for s in static:
        ax[1, 0].axhline(float(s), color="0.6", lw=0.8)
    ax[1, 0].set(xlabel="t [s]", ylabel="[N]", title="normal loads (grey: eqs. 57-58)")
    ax[1, 0].legend(fontsize=7)
    ax[1, 1].set(xlabel="t [s]", ylabel="[N]", title="tire forces (wheel frame)")
    ax[1, 1].legend(fontsize=8)
    ax[1, 2].plot(t, np.degrees(tr["theta"]), label="pitch angle theta [deg] (+: nose down)")
    ax[1, 2].plot(t, 100 * np.asarray(tr["z"]), label="heave z [cm]")
    ax[1, 2].plot(t, tr["kappa_F"], label="slip kappa_F")
    ax[1, 2].plot(t, tr["kappa_R"], label="slip kappa_R")
    ax[1, 2].set(xlabel="t [s]", title="suspension and longitudinal slips")
    ax[1, 2].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def reproduce(ctx) -> None:
    params, tire = rally_gravel(), rally_gravel_tire()
    car = HalfCar(params, tire)
    car_qs = HalfCar(params, tire, suspension=False)
    v0 = 20.0
    static = params.static_loads()
    cases = [
        ("step_steer", step_steer(0.02, t_step=0.5),
         "Step steer, delta = 0.02 rad at 20 m/s (coasting), rally-gravel car"),
        ("brake_in_turn", brake_in_turn(0.03, 1200.0, t_brake=2.0),
         "Braking in a turn: delta = 0.03 rad, 1200 N m braking (60 % front) from t = 2 s"),
    ]
    duration = 4.0 if ctx.quick else 6.0
    ts = jnp.linspace(0.0, duration, 201 if ctx.quick else 601)
    for name, u, caption in cases:
        ctx.log(f"simulating {name}")
        tr = simulate(car, ts, u, car.init_state(vx=v0))
        tr_qs = simulate(car_qs, ts, u, car_qs.init_state(vx=v0))
        ctx.figure(_plot(tr, tr_qs, caption, static), f"vehicle_{name}", caption)
        rec = {
            "max_abs_sideslip_deg": float(np.degrees(np.max(np.abs(tr["sideslip"])))),
            "final_speed_m_s": float(tr["speed"][-1]),
            "max_Fz_F_N": float(np.max(tr["Fz_F"])),
            "min_Fz_R_N": float(np.min(tr["Fz_R"])),
            "max_Fz_F_quasi_static_N": float(np.max(tr_qs["Fz_F"])),
            "max_pitch_deg": float(np.degrees(np.max(tr["theta"]))),
            "solver_steps": int(tr.num_steps),
        }
        for k, v in rec.items():
            ctx.record(f"vehicle.{name}.{k}", v)
        ctx.text(
            f"**{name}**: peak |sideslip| {rec['max_abs_sideslip_deg']:.2f} deg, final speed "
            f"{rec['final_speed_m_s']:.2f} m/s, front load peak {rec['max_Fz_F_N']:.0f} N "
            f"(suspension) vs {rec['max_Fz_F_quasi_static_N']:.0f} N (quasi-static), static "
            f"{float(static[0]):.0f} N; peak pitch {rec['max_pitch_deg']:.2f} deg."
        )
    ctx.text(
        "The suspension model (eqs. 54-60) carries the load transfer as states: it lags and "
        "overshoots the quasi-static transfer of the reduced model (docs/maneuvers.md) when the "
        "brakes come on, then settles onto it (eq. 55 with no pitch acceleration)."
    )
