"""Figures drawn by `vehsim reproduce` and the command line, in the style of the report.

Model code never draws: these functions take results (arrays, `Primitive`, `Replay`,
`BrakingData`) and return matplotlib figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def _car_outline(x, y, psi, lF, lR, width=1.6):
    """Rectangle of the car body (wheelbase plus overhangs) at pose (x, y, psi)."""
    front, rear = lF + 0.6, lR + 0.6
    pts = np.array([[front, width / 2], [front, -width / 2], [-rear, -width / 2],
                    [-rear, width / 2], [front, width / 2]])
    c, s = np.cos(psi), np.sin(psi)
    return np.stack([x + c * pts[:, 0] - s * pts[:, 1], y + s * pts[:, 0] + c * pts[:, 1]], 1)


def draw_road(ax, road):
    from matplotlib.patches import Rectangle

    for leg in road.legs:
        ax.add_patch(Rectangle((leg.xmin, leg.ymin), leg.xmax - leg.xmin, leg.ymax - leg.ymin,
                               facecolor="0.88", edgecolor="none", zorder=0))
    ax.set_aspect("equal")


def maneuver_figure(road, t, signals: dict, lF: float, lR: float, title: str = "",
                    outline_every: float = 0.3):
    """Path in the corridor with the car outline every ``outline_every`` seconds, and
    histories of speed, sideslip, slips and steering (report Fig. 20)."""
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(11, 6.5))
    gs = fig.add_gridspec(4, 2, width_ratios=[1.25, 1.0])
    ax = fig.add_subplot(gs[:, 0])
    draw_road(ax, road)
    x, y, psi = signals["x"], signals["y"], signals["psi"]
    ax.plot(x, y, "k-", lw=1.2, label="centre of gravity")
    t_marks = np.arange(0.0, t[-1] + 1e-9, outline_every)
    for tm in t_marks:
        i = int(np.argmin(np.abs(t - tm)))
        o = _car_outline(x[i], y[i], psi[i], lF, lR)
        ax.plot(o[:, 0], o[:, 1], "-", color="tab:blue", lw=0.7)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    panels = [
        ("speed [m/s]", [("speed", "speed")]),
        ("sideslip [deg]", [("sideslip_deg", "beta")]),
        ("slip kappa", [("kappa_F", "front"), ("kappa_R", "rear")]),
        ("steering [deg]", [("delta_deg", "delta")]),
    ]
    sig = dict(signals)
    sig["sideslip_deg"] = np.degrees(signals["sideslip"])
    sig["delta_deg"] = np.degrees(signals["delta"])
    for j, (label, keys) in enumerate(panels):
        a = fig.add_subplot(gs[j, 1])
        for key, name in keys:
            a.plot(t, sig[key], label=name)
        a.set_ylabel(label)
        a.grid(alpha=0.3)
        if len(keys) > 1:
            a.legend(fontsize=7, loc="best")
        if j == len(panels) - 1:
            a.set_xlabel("t [s]")
    fig.tight_layout()
    return fig


def force_histories_figure(brakings: Sequence, predictions: dict, labels,
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


def replay_figure(primitive, replays: dict, title: str = ""):
    """Paths in the corridor: the primitive's nodes and each replay in ``replays``
    ({label: `Replay`}), with speed histories."""
    import matplotlib.pyplot as plt

    fig, (ax, av) = plt.subplots(1, 2, figsize=(11, 5), width_ratios=[1.2, 1.0])
    draw_road(ax, primitive.problem.road)
    nodes = np.asarray(primitive.nodes())
    ax.plot(nodes[:, 0], nodes[:, 1], "k.-", lw=1.0, ms=3, label="primitive (reduced model)")
    av.plot(np.asarray(primitive.time()), np.hypot(nodes[:, 3], nodes[:, 4]), "k.-", ms=3,
            label="primitive")
    for label, rp in replays.items():
        tr = rp.trajectory
        ok = np.isfinite(np.asarray(tr["x"]))
        v = rp.drift["max_corridor_violation"]
        ax.plot(np.asarray(tr["x"])[ok], np.asarray(tr["y"])[ok], "-", lw=1.2,
                label=f"{label} (off road {v:.2f} m)")
        av.plot(np.asarray(tr.ts)[ok], np.asarray(tr["speed"])[ok], "-", label=label)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(fontsize=7, loc="lower left")
    ax.set_title(title)
    av.set_xlabel("t [s]")
    av.set_ylabel("speed [m/s]")
    av.grid(alpha=0.3)
    av.legend(fontsize=7)
    fig.tight_layout()
    return fig


def primitive_figure(primitive, title: str = ""):
    """`maneuver_figure` of a car `Primitive` (report Fig. 20)."""
    p = primitive.problem.vehicle.params
    return maneuver_figure(primitive.problem.road, np.asarray(primitive.time()),
                           primitive.signals(), float(p.lF), float(p.lR), title=title)


def braking_figure(runs: dict, title: str = ""):
    """Closed-loop brakings (`vehsim.control`): speed, wheel slip with the peak slip, friction
    used against the friction available (the peak of the steady-state curve at the current
    speed), the estimated road condition against the truth, the brake command and torque,
    and the distance. `runs` maps a label to a dict of arrays: ``ts``, ``v``, ``slip``,
    ``mu``, ``theta_hat``, ``command``, ``torque``, ``x`` and, where known, ``peak_slip``,
    ``peak_mu``, ``theta_true``; each is drawn while the car moves (above 0.5 m/s). A surface
    change (a jump of ``theta_true``) is marked in every panel by a vertical line in the
    run's colour. The road condition is drawn on a linear scale clipped to 1.5 times the
    largest true value (a locked wheel's estimate, which has no tone-wheel edges to learn
    from, can spike far above it; the panel says when it is clipped)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(3, 2, figsize=(11, 8.5), sharex=True)
    theta_top, estimate_top = 0.0, 0.0
    for i, (label, s) in enumerate(runs.items()):
        c = f"C{i}"
        moving = np.asarray(s["v"]) > 0.5
        s = {k: np.asarray(v)[moving] for k, v in s.items()}
        t = s["ts"]
        ax[0, 0].plot(t, s["v"], c, label=label)
        ax[0, 1].plot(t, np.clip(s["slip"], -1.0, 0.2), c, lw=1.0)
        ax[1, 0].plot(t, np.abs(s["mu"]), c, lw=1.0)
        ax[1, 1].plot(t, s["theta_hat"], c, lw=1.2)
        ax[2, 0].plot(t, s["command"], c + ":", lw=0.8)
        ax[2, 0].plot(t, s["torque"], c, lw=1.0)
        ax[2, 1].plot(t, s["x"], c)
        if "peak_slip" in s:
            ax[0, 1].plot(t, s["peak_slip"], "k:", lw=0.8)
            ax[1, 0].plot(t, s["peak_mu"], "k:", lw=0.8)
        if "theta_true" in s and s["theta_true"].size:
            truth = s["theta_true"]
            ax[1, 1].plot(t, truth, "k--", lw=0.8)
            theta_top = max(theta_top, float(np.max(truth)))
            for k in np.nonzero(np.diff(truth) != 0)[0]:
                for a in ax.ravel():
                    a.axvline(t[k + 1], color=c, lw=0.8, ls="-.", alpha=0.6)
        if s["theta_hat"].size:
            estimate_top = max(estimate_top, float(np.max(s["theta_hat"])))
    theta_label = "road condition theta: estimate, truth (dashed)"
    if theta_top > 0:
        ax[1, 1].set_ylim(0.0, 1.5 * theta_top)
        if estimate_top > 1.5 * theta_top:
            theta_label += "; clipped at 1.5x the truth"
    labels = [("speed [m/s]", "wheel slip s (dotted: peak of eq. 19)"),
              ("|F_x|/F_n: used, available (dotted)", theta_label),
              ("brake torque [N m] (dotted: command)", "distance [m]")]
    for row, (left, right) in enumerate(labels):
        ax[row, 0].set_ylabel(left, fontsize=8)
        ax[row, 1].set_ylabel(right, fontsize=8)
        for a in ax[row]:
            a.grid(alpha=0.3)
    ax[2, 0].set_xlabel("t [s]")
    ax[2, 1].set_xlabel("t [s]")
    ax[0, 0].legend(fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def friction_estimate_figure(estimate: dict, record: dict, title: str = ""):
    r"""An estimate over a recorded braking (`vehsim.estimate_friction`): the estimate with
    its band of two standard errors and, where known, the truth; below, the measured wheel
    slip $r\omega/v - 1$ (and an estimated peak slip) and the brake torque. `estimate`
    holds arrays ``ts``, ``value``, ``ok`` (drawn where true), optionally ``se``, and the
    axis ``label``; `record` holds ``t``, ``slip``, ``torque`` and optionally ``truth``
    (over ``t``) and ``peak_slip`` (over the estimate's ``ts``)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    ok = np.asarray(estimate["ok"], dtype=bool) & np.isfinite(estimate["value"])
    t, value = np.asarray(estimate["ts"])[ok], np.asarray(estimate["value"])[ok]
    se = estimate.get("se")
    marker = "o-" if t.size < 200 else "-"
    if se is not None:
        se = np.asarray(se)[ok]
        ax[0].fill_between(t, value - 2.0 * se, value + 2.0 * se, color="C0", alpha=0.25,
                           lw=0, label="estimate +/- 2 standard errors")
    ax[0].plot(t, value, marker, color="C0", lw=1.2, ms=3, label="estimate")
    truth = record.get("truth")
    if truth is not None:
        ax[0].plot(record["t"], truth, "k--", lw=0.9, label="truth")
    if value.size:
        lo, hi = np.nanmin(value), np.nanmax(value)
        if truth is not None:
            lo, hi = min(lo, np.nanmin(truth)), max(hi, np.nanmax(truth))
        pad = 0.25 * (hi - lo) + 0.05 * abs(hi)
        ax[0].set_ylim(max(lo - pad, 0.0), hi + pad)
    ax[0].set_ylabel(estimate.get("label", "estimate"))
    ax[0].legend(fontsize=8)
    ax[1].plot(record["t"], np.clip(record["slip"], -1.0, 0.2), "C1", lw=0.8,
               label="measured slip")
    if record.get("peak_slip") is not None:
        ax[1].plot(np.asarray(estimate["ts"])[ok], np.asarray(record["peak_slip"])[ok], "C0:",
                   lw=1.0, label="estimated peak slip")
        ax[1].legend(fontsize=8)
    ax[1].set_ylabel("wheel slip r omega / v - 1", fontsize=8)
    twin = ax[1].twinx()
    twin.plot(record["t"], record["torque"], "0.5", lw=0.8)
    twin.set_ylabel("brake torque [N m] (grey)", fontsize=8)
    ax[1].set_xlabel("t [s]")
    for a in ax:
        a.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def turn_figure(runs: dict, title: str = ""):
    """The half car braking in a turn: paths, yaw rates and sideslip angles; `runs` maps a
    label to the signals of `vehsim.control.experiments.half_car_abs.simulate_turn`."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(13, 4.2))
    for label, s in runs.items():
        moving = np.asarray(s["speed"]) > 0.5
        ax[0].plot(np.asarray(s["x"])[moving], np.asarray(s["y"])[moving], label=label)
        ax[1].plot(s["ts"], s["yaw_rate"])
        ax[2].plot(s["ts"], np.degrees(s["sideslip"]))
    ax[0].set(xlabel="x [m]", ylabel="y [m]", title="path")
    ax[0].set_aspect("equal", adjustable="datalim")
    ax[1].set(xlabel="t [s]", ylabel="yaw rate [rad/s]")
    ax[2].set(xlabel="t [s]", ylabel="sideslip [deg]")
    ax[0].legend(fontsize=8)
    for a in ax:
        a.grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def tire_curves_figure(curves: dict, title: str = ""):
    r"""A tyre property file's Magic Formula at a glance (`vehsim tire plot`): $F_x(\kappa)$,
    $F_y(\alpha)$, $M_z(\alpha)$ at several loads (top row); $F_y(\alpha)$, $M_z(\alpha)$ at
    several cambers and the combined-slip curves $F_y(F_x)$ with the friction ellipse
    $(F_x/\mu_xF_z)^2 + (F_y/\mu_yF_z)^2 = 1$ of the pure-slip peaks, at the nominal load
    (bottom row). `curves`: ``kappa``, ``alpha_deg`` (grids), ``loads`` [N] with ``Fx``,
    ``Fy``, ``Mz`` (load, point); ``cambers_deg`` with ``Fy_camber``, ``Mz_camber``
    (camber, point); ``nominal_load``, ``combined`` (label -> (F_x, F_y) arrays) and
    ``ellipse`` ($(\mu_xF_z, \mu_yF_z)$)."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 3, figsize=(15, 8.5))
    kappa, deg = np.asarray(curves["kappa"]), np.asarray(curves["alpha_deg"])
    for i, Fz in enumerate(curves["loads"]):
        label = f"F_z = {Fz:.0f} N"
        ax[0, 0].plot(kappa, curves["Fx"][i], label=label)
        ax[0, 1].plot(deg, curves["Fy"][i], label=label)
        ax[0, 2].plot(deg, curves["Mz"][i], label=label)
    for i, g in enumerate(curves["cambers_deg"]):
        ax[1, 0].plot(deg, curves["Fy_camber"][i], label=f"camber {g:+g} deg")
        ax[1, 1].plot(deg, curves["Mz_camber"][i], label=f"camber {g:+g} deg")
    for label, (fx, fy) in curves["combined"].items():
        ax[1, 2].plot(fx, fy, label=label)
    a, b = curves["ellipse"]
    t = np.linspace(0.0, 2.0 * np.pi, 241)
    ax[1, 2].plot(a * np.cos(t), b * np.sin(t), "k--", lw=0.8, label="friction ellipse")
    ax[1, 2].set_aspect("equal", adjustable="datalim")
    nominal = f"F_z = {curves['nominal_load']:.0f} N"
    labels = [
        ("slip ratio kappa", "F_x [N]", "longitudinal force, zero slip angle"),
        ("slip angle alpha [deg]", "F_y [N]", "lateral force, zero slip ratio"),
        ("slip angle alpha [deg]", "M_z [N m]", "aligning moment, zero slip ratio"),
        ("slip angle alpha [deg]", "F_y [N]", f"lateral force, {nominal}"),
        ("slip angle alpha [deg]", "M_z [N m]", f"aligning moment, {nominal}"),
        ("F_x [N]", "F_y [N]", f"combined slip, {nominal}"),
    ]
    for a_, (xl, yl, tl) in zip(ax.ravel(), labels):
        a_.set(xlabel=xl, ylabel=yl, title=tl)
        a_.grid(alpha=0.3)
        a_.axhline(0.0, color="0.6", lw=0.6)
        a_.axvline(0.0, color="0.6", lw=0.6)
        a_.legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def draw_centreline_road(ax, road, num: int | None = None):
    """Draw a `CentrelineRoad` on ``ax``: the road surface between its edges, the edges,
    the dashed centre line and the start and end gates; ``num`` points per edge (default
    about one per metre, at most 4000)."""
    from matplotlib.patches import Polygon

    num = num or int(min(4000, max(200, road.length)))
    left, right = road.boundaries(num)
    ax.add_patch(Polygon(np.concatenate([left, right[::-1]]), closed=True, facecolor="0.88",
                         edgecolor="none", zorder=0))
    for edge in (left, right):
        ax.plot(edge[:, 0], edge[:, 1], "-", color="0.35", lw=0.8, zorder=1)
    centre = np.asarray(road.centreline)
    ax.plot(centre[:, 0], centre[:, 1], "--", color="0.6", lw=0.6, zorder=1)
    for gate, colour in ((road.start, "tab:green"), (road.end, "tab:red")):
        ends = gate.endpoints(road)
        ax.plot(ends[:, 0], ends[:, 1], "-", color=colour, lw=1.5, zorder=2)
    ax.set_aspect("equal")


def _draw_any_road(ax, road):
    if hasattr(road, "legs"):
        draw_road(ax, road)
    else:
        draw_centreline_road(ax, road)


def road_figure(road, path=None, *, title: str | None = None):
    """A figure of a road (a rectangle `Road`: its legs; a `CentrelineRoad`: surface, edges,
    centre line, start gate green, end gate red) and optionally a path ``(x, y)`` [m] on it."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6))
    _draw_any_road(ax, road)
    if path is not None:
        ax.plot(np.asarray(path[0]), np.asarray(path[1]), "k-", lw=1.0)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(road.name if title is None else title)
    ax.autoscale_view()
    fig.tight_layout()
    return fig


def path_on_road_figure(road, x, y, psi, speed, *, footprint=(4.2, 1.8), every: int | None = None,
                        title: str | None = None):
    """A path on a road (rectangle or centre-line) coloured by speed [m/s] (colour bar), with
    the car's footprint, a ``footprint = (length, width)`` [m] rectangle centred on the path
    and turned by the heading ``psi`` [rad], every ``every`` samples (default: about 25
    along the path, the first and last included)."""
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Polygon

    x, y, psi, speed = (np.asarray(v, float) for v in (x, y, psi, speed))
    n = len(x)
    every = max(1, (n - 1) // 24) if every is None else int(every)
    fig, ax = plt.subplots(figsize=(8, 6))
    _draw_any_road(ax, road)
    pts = np.stack([x, y], axis=-1)
    segs = np.stack([pts[:-1], pts[1:]], axis=1)
    lc = LineCollection(segs, cmap="viridis", linewidths=2.0, zorder=3)
    lc.set_array(0.5 * (speed[:-1] + speed[1:]))
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="speed [m/s]", shrink=0.8)
    marks = sorted(set(range(0, n, every)) | {n - 1})
    for i in marks:
        corners = _footprint(x[i], y[i], psi[i], footprint)
        ax.add_patch(Polygon(corners, closed=True, facecolor="none", edgecolor="tab:blue",
                             lw=0.8, zorder=4, gid="footprint"))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(road.name if title is None else title)
    ax.autoscale_view()
    fig.tight_layout()
    return fig


# ---- a drive on a centre-line road (`vehsim drive`) ------------------------------------------

DRIVE_FOOTPRINT = (4.2, 1.8)
"""Length and width [m] of the car's footprint drawn by `drive_figure` and `drive_animation`
(the `rally_gravel` car: wheelbase 2.7 m plus overhangs)."""


def drive_trace(road, run, plant, upto: int | None = None) -> dict:
    r"""The arrays a drive's figure and animation draw, as numpy (leading axis: samples
    $1..N$ of `run`, a `vehsim.DriveRun` of `plant` on `road`):

    ``t``, ``x``, ``y``, ``psi``, ``speed`` (true), ``s``, ``n`` (Frenet coordinates of the
    centre of gravity on `road`), ``command`` and ``applied`` $(T_F, T_R, \delta)$ (N, 3),
    ``scale_true`` $\lambda$ under the (front, rear) axle (N, 2) and ``peak_true``
    $\mu^*(\lambda)$ there (the plant tire's peak on that road at 20 m/s,
    `vehsim.drive.plant_tires.plant_peaks`; N, 2), ``slip_true`` the wheels' longitudinal slip
    $\kappa_i = \omega_i r/V_{ix} - 1$ (front, rear; N, 2: a spinning wheel above 1, a
    locked one at -1); with an estimator ``scale_est``, ``peak_est``,
    ``peak_std`` (N, 2); with a planner that reports them (``run.controller_info``, as
    `RecedingHorizonDriver.info`: ``plan_s``, ``plan_n`` (N, M + 1), ``D`` (N, M)),
    ``horizon_x``, ``horizon_y`` (N, M + 1), the planned path converted from its
    $(s, n)$ to the plane, and ``planner_D`` (N,), the planned peak friction (the mean over
    the horizon where it varies), ``probing`` (N,) whether the sample's command was a test
    brake (`RecedingHorizonDriver.probe_distance`). `upto`: only the first this many
    samples (e.g. up to the end of the road).
    """
    import jax
    import jax.numpy as jnp

    from .drive.plant_tires import plant_peaks

    def cut(tree):  # the first `upto` samples of a per-sample record
        return tree if upto is None else jax.tree.map(lambda a: a[:upto], tree)

    states, estimates = cut(run.states), cut(run.estimates)
    car = np.asarray(states.car)
    x, y, psi, vx, vy = (car[:, i] for i in range(5))
    s, n = road.to_frenet(x, y)
    lam_F, lam_R = jax.vmap(plant.grip_scales)(states.car)
    lam = np.stack([np.asarray(lam_F), np.asarray(lam_R)], -1)
    peak = np.asarray(plant_peaks(plant, lam))

    def slips(car, u):
        sig = plant.car_at(car).signals(car, plant.wheel_torques(car, u))
        return jnp.stack([sig["kappa_F"], sig["kappa_R"]])

    applied = states.actuators.applied
    out = {"t": np.asarray(states.t), "x": x, "y": y, "psi": psi,
           "speed": np.hypot(vx, vy), "s": s, "n": n, "command": np.asarray(cut(run.commands)),
           "applied": np.asarray(applied), "scale_true": lam,
           "peak_true": peak,
           "slip_true": np.asarray(jax.jit(jax.vmap(slips))(states.car, applied))}
    if estimates is not None:
        out["scale_est"] = np.asarray(estimates.scale)
        out["peak_est"] = np.asarray(estimates.peak)
        out["peak_std"] = np.asarray(estimates.peak_std)
    out.update(_planned(road, cut(getattr(run, "controller_info", None))))
    return out


def _planned(road, info) -> dict:
    """The planned horizon in the plane, the planner's D and the test brake from a
    controller's per-sample diagnostics (a mapping with ``plan_s``, ``plan_n`` (N, M + 1),
    ``D`` (N,) or (N, M) and ``probing`` (N,)); what it lacks is left out."""
    if info is None or not hasattr(info, "get"):
        return {}
    out = {}
    hs, hn = info.get("plan_s"), info.get("plan_n")
    if hs is not None and hn is not None:
        hx, hy = road.to_cartesian(np.asarray(hs), np.asarray(hn))
        out["horizon_x"], out["horizon_y"] = np.asarray(hx), np.asarray(hy)
    D = info.get("D")
    if D is not None:
        D = np.asarray(D, float)
        out["planner_D"] = D if D.ndim == 1 else D.reshape(D.shape[0], -1).mean(axis=1)
    if info.get("probing") is not None:
        out["probing"] = np.asarray(info["probing"], bool)
    return out


def _shade_test_brake(ax, t, probing):
    """Shade the samples whose command was a test brake (each from the command's sample
    time, a period before the state recorded after it, to that state's time)."""
    if probing is None or not np.any(probing) or len(t) < 2:
        return
    period = t[1] - t[0]
    edges = np.flatnonzero(np.diff(np.concatenate([[0], probing.astype(int), [0]])))
    for i, (start, stop) in enumerate(zip(edges[::2], edges[1::2])):
        ax.axvspan(t[start] - period, t[stop - 1], color="tab:purple", alpha=0.15, lw=0,
                   label="test brake" if i == 0 else None, gid="test-brake")


def _footprint(x, y, psi, footprint):
    """Corners (4, 2) of a ``(length, width)`` rectangle centred at (x, y), turned by psi."""
    length, width = footprint
    half = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * [length / 2, width / 2]
    c, s = np.cos(psi), np.sin(psi)
    return np.stack([x + c * half[:, 0] - s * half[:, 1], y + s * half[:, 0] + c * half[:, 1]],
                    axis=-1)


def draw_grip_field(ax, road, grip, *, resolution: float | None = None,
                    vmax: float | None = None):
    r"""Shade the friction scale $\lambda(x, y)$ of a grip field (`vehsim.AbstractGripField`)
    on the road surface of a `CentrelineRoad` (clipped to it): pale at ``vmax`` (default the
    largest scale on the grid) and above, a deeper blue the lower the scale; ``resolution``
    [m] of the grid (default about 200 cells across the road's extent). Returns the image
    (for a colour bar)."""
    from matplotlib.patches import Polygon

    left, right = road.boundaries(int(min(4000, max(200, road.length))))
    outline = np.concatenate([left, right[::-1]])
    lo, hi = outline.min(axis=0), outline.max(axis=0)
    step = resolution or float(max(hi - lo)) / 200.0
    gx = np.arange(lo[0], hi[0] + step, step)
    gy = np.arange(lo[1], hi[1] + step, step)
    X, Y = np.meshgrid(gx, gy)
    lam = np.asarray(grip.scale_at(X, Y), float)
    vmax = float(np.max(lam)) if vmax is None else vmax
    im = ax.imshow(lam, origin="lower", extent=(gx[0] - step / 2, gx[-1] + step / 2,
                                                gy[0] - step / 2, gy[-1] + step / 2),
                   cmap="Blues_r", vmin=0.0, vmax=vmax, interpolation="bilinear",
                   zorder=0.5, alpha=0.8)
    clip = Polygon(outline, closed=True, facecolor="none", edgecolor="none")
    ax.add_patch(clip)
    im.set_clip_path(clip)
    return im


def drive_figure(road, run, plant, *, title: str = "", footprint=DRIVE_FOOTPRINT,
                 every: int | None = None, grip_vmax: float | None = None,
                 upto: int | None = None):
    r"""A drive at a glance (`vehsim drive`): left, the road (`CentrelineRoad`) with its grip
    field shaded (`draw_grip_field`), the path of the centre of gravity coloured by speed and
    the car's footprint every `every` samples (default about 25 along the drive); right,
    the speed along the road's arc length $s$; the peak friction: each axle's estimate
    (with a band of two standard deviations), the truth under it and the planner's $D$ where
    the controller reports one; the steering angle and the axle torques (command dashed,
    applied solid) over time, the samples of a test brake (`drive_trace`'s ``probing``)
    shaded on the grip and torque panels. `run`: a `vehsim.DriveRun` of `plant`
    (`drive_trace`);
    `grip_vmax`: the grip scale shaded palest (`draw_grip_field`'s `vmax`,
    e.g. the nominal road's, so that a road of less grip everywhere shows blue); `upto`: draw
    the first this many samples only (`drive_trace`)."""
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Polygon

    tr = drive_trace(road, run, plant, upto)
    fig = plt.figure(figsize=(13, 7.5))
    gs = fig.add_gridspec(4, 2, width_ratios=[1.3, 1.0])
    ax = fig.add_subplot(gs[:, 0])
    draw_centreline_road(ax, road)
    im = draw_grip_field(ax, road, plant.grip, vmax=grip_vmax)
    fig.colorbar(im, ax=ax, label="grip scale lambda (friction x lambda)", shrink=0.6,
                 location="bottom", pad=0.08)
    pts = np.stack([tr["x"], tr["y"]], axis=-1)
    lc = LineCollection(np.stack([pts[:-1], pts[1:]], axis=1), cmap="viridis", linewidths=2.0,
                        zorder=3)
    lc.set_array(0.5 * (tr["speed"][:-1] + tr["speed"][1:]))
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, label="speed [m/s]", shrink=0.6)
    num = len(tr["t"])
    every = max(1, (num - 1) // 24) if every is None else int(every)
    for i in sorted(set(range(0, num, every)) | {num - 1}):
        ax.add_patch(Polygon(_footprint(tr["x"][i], tr["y"][i], tr["psi"][i], footprint),
                             closed=True, facecolor="none", edgecolor="tab:red", lw=0.7,
                             zorder=4, gid="footprint"))
    ax.set(xlabel="x [m]", ylabel="y [m]", title=title or road.name)
    ax.autoscale_view()

    a = fig.add_subplot(gs[0, 1])
    a.plot(tr["s"], tr["speed"], "C0")
    a.set(xlabel="s along the road [m]", ylabel="speed [m/s]")
    a = fig.add_subplot(gs[1, 1])
    t = tr["t"]
    for j, axle in enumerate(("front", "rear")):
        a.plot(t, tr["peak_true"][:, j], f"C{j}--", lw=0.9, label=f"truth {axle}")
        if "peak_est" in tr:
            m, sd = tr["peak_est"][:, j], tr["peak_std"][:, j]
            a.fill_between(t, m - 2 * sd, m + 2 * sd, color=f"C{j}", alpha=0.15, lw=0)
            a.plot(t, m, f"C{j}-", lw=1.2, label=f"estimate {axle}")
    if "planner_D" in tr:
        a.plot(t, tr["planner_D"], "k-", lw=1.0, label="planner D, horizon mean")
    _shade_test_brake(a, t, tr.get("probing"))
    a.set(ylabel="peak friction")
    a.legend(fontsize=7, ncol=2, loc="best")
    a = fig.add_subplot(gs[2, 1], sharex=a)
    a.plot(t, np.degrees(tr["command"][:, 2]), "C2--", lw=0.8, label="command")
    a.plot(t, np.degrees(tr["applied"][:, 2]), "C2-", lw=1.2, label="applied")
    a.set(ylabel="steering [deg]")
    a.legend(fontsize=7)
    a = fig.add_subplot(gs[3, 1], sharex=a)
    for j, axle in enumerate(("front", "rear")):
        a.plot(t, tr["command"][:, j], f"C{j}--", lw=0.8)
        a.plot(t, tr["applied"][:, j], f"C{j}-", lw=1.2, label=f"T_{axle[0].upper()}")
    _shade_test_brake(a, t, tr.get("probing"))
    a.set(xlabel="t [s]", ylabel="axle torque [N m]")
    a.legend(fontsize=7)
    for a in fig.axes[2:]:
        if a.get_label() != "<colorbar>":
            a.grid(alpha=0.3)
    fig.tight_layout()
    return fig


MAX_ANIMATION_FRAMES = 600
"""The most frames `frame_every_for` gives an animation (a 200 s drive at 20 Hz: every 7th
sample; drawing 2000 frames took about 6 minutes and wrote 23 MB)."""


def frame_every_for(num_samples: int, every: int = 2) -> int:
    """One frame per `every` samples, or per more where that would draw more than
    `MAX_ANIMATION_FRAMES` frames (`animation_frames` adds the last sample)."""
    return max(int(every), math.ceil((int(num_samples) - 1) / (MAX_ANIMATION_FRAMES - 1)))


def animation_frames(num_samples: int, every: int) -> list[int]:
    """The samples (0-based) `drive_animation` draws: every `every`-th from the first, and
    the last."""
    return sorted(set(range(0, num_samples, every)) | {num_samples - 1})


def drive_animation(road, run, path, plant, *, every: int = 2, dpi: int = 80,
                    footprint=DRIVE_FOOTPRINT,
                    title: str = "", fps: float | None = None, window: float | None = None,
                    grip_vmax: float | None = None, upto: int | None = None,
                    progress=None) -> int:
    r"""An animation of a drive, written to `path` (``.gif``: matplotlib's `PillowWriter`,
    no external program; ``.mp4``: `FFMpegWriter`, needs ffmpeg): the road with its grip field
    shaded, the path so far, the car's footprint (a `footprint` = (length, width) [m]
    rectangle at the pose, turned by the heading), the planned horizon where the controller
    reports one, and a panel of text (time, speed, each axle's estimated peak friction
    against the truth under it, the planner's $D$). One frame per `every` samples
    (`animation_frames`), played in real time unless `fps` says otherwise, at `dpi`.
    `window` [m]: the view follows the car, this far from it each way (default: the whole
    road); `grip_vmax` and `upto` as in `drive_figure`; `progress` (None, or a callable
    ``progress(done, total)`` called after each frame is drawn). Written atomically;
    returns the number of frames."""
    import tempfile
    from pathlib import Path

    import matplotlib.pyplot as plt
    from matplotlib import animation
    from matplotlib.patches import Polygon

    from ._io import write_atomic

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"drive_animation: the file name must end in .gif or .mp4, got "
                         f"{str(path)!r}")
    if suffix == ".mp4" and not animation.writers.is_available("ffmpeg"):
        raise ValueError("drive_animation: an .mp4 animation needs the ffmpeg program, which "
                         "was not found; write a .gif instead")
    tr = drive_trace(road, run, plant, upto)
    frames = animation_frames(len(tr["t"]), every)
    if fps is None:
        dt = float(np.median(np.diff(tr["t"]))) if len(tr["t"]) > 1 else 0.05
        fps = 1.0 / (every * dt)
    fig, ax = plt.subplots(figsize=(7, 6))
    draw_centreline_road(ax, road)
    draw_grip_field(ax, road, plant.grip, vmax=grip_vmax)
    ax.set(xlabel="x [m]", ylabel="y [m]", title=title or road.name)
    ax.autoscale_view()
    if window is not None:  # a square view to scale: the axes box, not the limits, adjusts
        ax.set_aspect("equal", adjustable="box")
    (trail,) = ax.plot([], [], "-", color="tab:blue", lw=1.2, zorder=3)
    (plan,) = ax.plot([], [], ".-", color="tab:orange", lw=1.0, ms=2, zorder=3,
                      label="planned horizon")
    car = Polygon(_footprint(tr["x"][0], tr["y"][0], tr["psi"][0], footprint), closed=True,
                  facecolor="tab:red", edgecolor="k", lw=0.8, alpha=0.85, zorder=5)
    ax.add_patch(car)
    if "horizon_x" in tr:
        ax.legend(loc="lower right", fontsize=7)
    text = ax.text(0.02, 0.98, "", transform=ax.transAxes, va="top", ha="left", fontsize=8,
                   family="monospace", zorder=6,
                   bbox=dict(boxstyle="round", facecolor="white", alpha=0.85))
    fig.tight_layout()

    def draw(i):
        trail.set_data(tr["x"][: i + 1], tr["y"][: i + 1])
        car.set_xy(_footprint(tr["x"][i], tr["y"][i], tr["psi"][i], footprint))
        if window is not None:
            ax.set_xlim(tr["x"][i] - window, tr["x"][i] + window)
            ax.set_ylim(tr["y"][i] - window, tr["y"][i] + window)
        if "horizon_x" in tr:
            plan.set_data(tr["horizon_x"][i], tr["horizon_y"][i])
        lines = [f"t {tr['t'][i]:5.2f} s   v {tr['speed'][i]:5.1f} m/s",
                 "peak mu  front  rear",
                 f"truth    {tr['peak_true'][i, 0]:5.2f}  {tr['peak_true'][i, 1]:5.2f}"]
        if "peak_est" in tr:
            lines.append(f"estimate {tr['peak_est'][i, 0]:5.2f}  {tr['peak_est'][i, 1]:5.2f}")
        if "planner_D" in tr:
            lines.append(f"planner D (horizon mean) {tr['planner_D'][i]:5.2f}")
        text.set_text("\n".join(lines))
        return trail, plan, car, text

    anim = animation.FuncAnimation(fig, draw, frames=frames, blit=False, repeat=False)
    writer = (animation.PillowWriter(fps=fps) if suffix == ".gif"
              else animation.FFMpegWriter(fps=fps))
    with tempfile.TemporaryDirectory() as work:
        tmp = Path(work) / f"animation{suffix}"
        report = None if progress is None else (lambda i, n: progress(i + 1, n))
        anim.save(tmp, writer=writer, dpi=dpi, progress_callback=report)
        write_atomic(path, tmp.read_bytes())
    plt.close(fig)
    return len(frames)
