r"""Measurements of a drive on a centre-line road: when it crossed the end gate, how far it
left the road, whether it completed.

All three read the centre of gravity's path at the plant's integration resolution: the
poses $(x, y)$ at every integrator step (`simulate_drive(..., substep_poses=True)`, the
`DriveRun.poses`), with the start pose first (`drive_path`).

- **Drive time** (`gate_crossing`, `drive_time`): the end gate is the line through $c(L)$
  along the road's normal $N(L)$; with $g(p) = (p - c(L))\cdot T(L)$, the path crosses it
  between poses $i$ and $i + 1$ where $g_i < 0 \le g_{i+1}$ and the crossing point's
  lateral offset $(p - c(L))\cdot N(L)$ is within the gate's interval widened by
  `tolerance` (a path off the road elsewhere on the gate's line does not count); the time is
  linear between the two poses, $t_i + (t_{i+1} - t_i)\,g_i/(g_i - g_{i+1})$. The first
  such crossing counts. A path that never crosses has no time (`drive_time` None; in JAX,
  `crossed` False and the time of the last pose, so that nothing is inf or NaN).
- **Departure** (`max_distance_off_road`): the largest exact distance off the road
  (`CentrelineRoad.distance_off_road`) of the poses up to the crossing (past the end gate
  every point is off the open road's end). Poses that the Frenet frame already places on
  the road (Newton's stationary point $p = c(s) + nN(s)$ with $0 < s < L$ and
  $|n| \le w(s)$ proves it, whichever centre-line point it found) skip the exact test.
- **Departure in JAX** (`path_departure`, for batches of drives): each pose projected onto
  a `RoadTable` (`RoadTable.to_frenet`: the nearest sample within its search distance,
  then Newton), starting from the nearest of every `search_points`-th sample of the road
  and its ends (every 4 m at the default spacing, so that the local searches tile it; not
  the table's extensions past an open road's ends), then
  $\max(n - w_l(s), -w_r(s) - n, 0)$, or past an open road's start or end line the
  distance from that line. On a road of constant widths this is the exact distance off the
  road region wherever the car is, up to the table's interpolation error ($10^{-4}$ m).
  One exception, metres off the road: a pose nearly as far from another part of the road
  as from the nearest one (between two legs of a hairpin) may read more, by less than the
  distance from the nearest point to its coarse sample (2 m).
- **Completed** (`drive_outcome`): crossed within the run, never more than
  `DEPARTURE_LIMIT` (5 cm) off the road.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._math import safe_hypot
from ..optimal.centreline import CentrelineRoad


DEPARTURE_LIMIT = 0.05
"""Largest distance [m] off the road of a completed drive."""

GATE_TOLERANCE = 1.0
"""Lateral slack [m] either side of the end gate's interval for a crossing to count."""


class EndGate(eqx.Module):
    r"""The end gate as arrays (JAX-usable): its centre-line `point` $c(L)$, unit `tangent`
    $T(L)$ and `normal` $N(L)$ (each (2,)), and the lateral interval `lateral` (2,) widened
    by the tolerance."""

    point: Float[Array, " 2"]
    tangent: Float[Array, " 2"]
    normal: Float[Array, " 2"]
    lateral: Float[Array, " 2"]

    @classmethod
    def of(cls, road: CentrelineRoad, tolerance: float = GATE_TOLERANCE) -> EndGate:
        """The end gate of `road`, its interval widened by `tolerance` [m] either side."""
        s = float(road.end.s)
        x, y = road.position(s)
        th = float(road.heading(s))
        t = np.array([np.cos(th), np.sin(th)])
        return cls(point=jnp.asarray([float(x), float(y)]), tangent=jnp.asarray(t),
                   normal=jnp.asarray([-t[1], t[0]]),
                   lateral=jnp.asarray([road.end.n_min - tolerance,
                                        road.end.n_max + tolerance]))

    def crossing(self, t, x, y):
        """``(crossed, time, index)`` of the path through poses `(x, y)` at times `t` (each
        (P,); module docstring): `index` $i$ of the pose before the crossing (the last pose
        if none), `time` the interpolated crossing time (the last pose's if none)."""
        dx, dy = x - self.point[0], y - self.point[1]
        g = dx * self.tangent[0] + dy * self.tangent[1]
        lat = dx * self.normal[0] + dy * self.normal[1]
        g0, g1 = g[:-1], g[1:]
        den = jnp.where(g0 < g1, g0 - g1, -1.0)
        frac = jnp.clip(g0 / den, 0.0, 1.0)
        lat_x = lat[:-1] + frac * (lat[1:] - lat[:-1])
        hit = (g0 < 0.0) & (g1 >= 0.0) & (lat_x >= self.lateral[0]) & (lat_x <= self.lateral[1])
        crossed = jnp.any(hit)
        i = jnp.where(crossed, jnp.argmax(hit), g.shape[0] - 1)
        j = jnp.minimum(i, g.shape[0] - 2)
        time = jnp.where(crossed, t[j] + (t[j + 1] - t[j]) * frac[j], t[-1])
        return crossed, time, i


def drive_path(run, state0=None):
    """The centre of gravity's path of a `DriveRun` at the integration resolution: ``(t, x,
    y)`` NumPy arrays, the start pose (from `state0`, a `DriveState`) first if given, then
    every integrator step's (`run.poses`, recorded with ``substep_poses=True``; without them,
    the sample poses). Leading batch axes are kept."""
    T = np.asarray(run.states.t)  # (..., N): times at the end of each sample
    if getattr(run, "poses", None) is not None:
        poses = np.asarray(run.poses)  # (..., N, S, 2)
        S = poses.shape[-2]
        # the sample period; a run of one sample: from the start (state0's time, else 0)
        start = 0.0 if state0 is None else np.asarray(state0.t, float)[..., None]
        dt = np.diff(T, axis=-1)[..., :1] if T.shape[-1] > 1 else T[..., :1] - start
        h = dt / S
        frac = np.arange(1, S + 1) - S  # substep j ends at t_k+1 - (S - j) h
        t = (T[..., :, None] + frac * h[..., None]).reshape(*T.shape[:-1], -1)
        xy = poses.reshape(*poses.shape[:-3], -1, 2)
    else:
        car = np.asarray(run.states.car)
        t, xy = T, car[..., :2]
    x, y = xy[..., 0], xy[..., 1]
    if state0 is not None:
        c0 = np.asarray(state0.car)
        t0 = np.broadcast_to(np.asarray(state0.t, float), t.shape[:-1] + (1,))
        t = np.concatenate([t0, t], axis=-1)
        x = np.concatenate([np.broadcast_to(c0[..., 0], x.shape[:-1])[..., None], x], axis=-1)
        y = np.concatenate([np.broadcast_to(c0[..., 1], y.shape[:-1])[..., None], y], axis=-1)
    return t, x, y


def drive_time(road: CentrelineRoad, t, x, y, tolerance: float = GATE_TOLERANCE):
    """The time [s] the path `(t, x, y)` crosses the end gate of `road` (module docstring),
    or None if it never does."""
    crossed, time, _ = EndGate.of(road, tolerance).crossing(
        jnp.asarray(t, float), jnp.asarray(x, float), jnp.asarray(y, float))
    return float(time) if bool(crossed) else None


def max_distance_off_road(road: CentrelineRoad, x, y) -> float:
    """The largest exact distance [m] off `road` of the points `(x, y)` (module docstring;
    NumPy). Non-finite points count as infinitely far."""
    x, y = np.asarray(x, float).ravel(), np.asarray(y, float).ravel()
    if x.size == 0:
        return 0.0
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        return float("inf")
    s, n = road.to_frenet(x, y)
    cx, cy = road.to_cartesian(s, n)
    residual = np.hypot(cx - x, cy - y)
    wl, wr = road.width_left(s), road.width_right(s)
    inside = (s > 0.0) & (s < road.length) & (n <= wl) & (n >= -wr) & (residual < 1e-9)
    if np.all(inside):
        return 0.0
    return float(np.max(road.distance_off_road(x[~inside], y[~inside])))


class DriveOutcome(eqx.Module):
    """What a drive achieved: `time` [s] at the end gate (None if it never crossed),
    `max_off_road` [m] (up to the crossing), `completed` (crossed, and never more than
    `DEPARTURE_LIMIT` off the road)."""

    time: float | None = eqx.field(static=True)
    max_off_road: float = eqx.field(static=True)
    completed: bool = eqx.field(static=True)

    def record(self) -> dict:
        """JSON-ready: time (None if not crossed), max_off_road, completed."""
        return dict(time=self.time, max_off_road=self.max_off_road, completed=self.completed)


def drive_outcome(road: CentrelineRoad, t, x, y, tolerance: float = GATE_TOLERANCE,
                  limit: float = DEPARTURE_LIMIT) -> DriveOutcome:
    """Time, departure and completion of one path `(t, x, y)` (1-D NumPy arrays; module
    docstring)."""
    t, x, y = (np.asarray(a, float) for a in (t, x, y))
    crossed, time, i = EndGate.of(road, tolerance).crossing(jnp.asarray(t), jnp.asarray(x),
                                                            jnp.asarray(y))
    crossed = bool(crossed)
    if crossed:
        i = int(i)
        g0 = time  # the crossing point, interpolated between poses i and i + 1
        frac = (float(g0) - t[i]) / (t[i + 1] - t[i]) if t[i + 1] > t[i] else 0.0
        xs = np.append(x[:i + 1], x[i] + frac * (x[i + 1] - x[i]))
        ys = np.append(y[:i + 1], y[i] + frac * (y[i + 1] - y[i]))
    else:
        xs, ys = x, y
    off = max_distance_off_road(road, xs, ys)
    return DriveOutcome(time=float(time) if crossed else None, max_off_road=off,
                        completed=bool(crossed and off <= limit))


def _coarse_samples(table):
    """The arc lengths the projections start from (every `search_points`-th sample, and an
    open road's ends), their points, and whether each is on the road."""
    coarse_s = table.s[::table.search_points]
    if not table.closed:  # the road's ends, where the table's extensions (not road) begin
        coarse_s = jnp.concatenate([coarse_s, jnp.stack([0.0 * table.length, table.length])])
    coarse_x, coarse_y = table.position(coarse_s)
    on_road = (jnp.ones(coarse_s.shape, bool) if table.closed
               else (coarse_s >= 0.0) & (coarse_s <= table.length))
    return coarse_s, coarse_x, coarse_y, on_road


def _departures(table, coarse, xs, ys):
    coarse_s, coarse_x, coarse_y, on_road = coarse
    d2 = (xs[:, None] - coarse_x[None]) ** 2 + (ys[:, None] - coarse_y[None]) ** 2
    guess = coarse_s[jnp.argmin(jnp.where(on_road[None], d2, jnp.inf), axis=1)]
    ss, _, _ = jax.vmap(table.to_frenet)(xs, ys, 0.0 * xs, guess)
    beyond = jnp.zeros(ss.shape, bool)
    if not table.closed:  # past an end: the distance from its line (a segment)
        beyond = (ss < 0.0) | (ss > table.length)
        ss = jnp.clip(ss, 0.0, table.length)
    (px, py), heading = table.position(ss), table.heading_at(ss)
    rx, ry = xs - px, ys - py
    along = rx * jnp.cos(heading) + ry * jnp.sin(heading)
    n = ry * jnp.cos(heading) - rx * jnp.sin(heading)
    lo_hi = table.corridor_at(ss)
    lateral = jnp.maximum(jnp.maximum(n - lo_hi[:, 1], lo_hi[:, 0] - n), 0.0)
    return jnp.where(beyond, safe_hypot(along, lateral), lateral)


def pose_departures(table, x, y):
    r"""The distance off the road (module docstring, JAX) of each pose `x`, `y` (shape
    (P,)), projected onto `table` (a `RoadTable`) from the nearest of every
    `search_points`-th sample of the road and its ends: shape (P,), 0 on the road.
    Differentiable in the poses (the search only picks where each projection starts)."""
    return _departures(table, _coarse_samples(table), x, y)


def path_departure(table, x, y, upto):
    r"""The largest distance off the road (module docstring, JAX) of the poses `x`, `y`
    (shape (N, S): N samples of S poses each, in order) whose flat index is at most `upto`
    (the pose before the end-gate crossing; `EndGate.crossing`'s index minus one, as the
    path there starts with the start pose), projected onto `table` (a `RoadTable`) as in
    `pose_departures`, a sample's poses at a time."""
    N, S = x.shape
    coarse = _coarse_samples(table)

    def sample(_, xy):
        xs, ys, idx = xy
        off = _departures(table, coarse, xs, ys)
        return None, jnp.max(jnp.where(idx <= upto, off, 0.0))

    idx = jnp.arange(N * S).reshape(N, S)
    _, offs = jax.lax.scan(sample, None, (x, y, idx))
    return jnp.max(offs)
