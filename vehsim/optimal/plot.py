"""Figures of optimal maneuvers in the style of report Fig. 20."""

from __future__ import annotations

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
