r"""Roads of the maneuver benchmark (docs/maneuvers.md, report Table 4).

A road is a union of rectangular legs (2 m wide corridors). The optimiser sees it as smooth
inequalities $c(x, y) \ge 0$ on the centre of gravity: the outer walls as linear bounds, and
each inner corner (a convex forbidden region $\{a_1 < 0, \dots, a_j < 0\}$) as
$\operatorname{smax}(a_1, \dots, a_j) \ge 0$ with a *conservative* smooth maximum
(`smooth_max` $\le \max$, equal to it away from the diagonal), so every feasible point of the
smooth problem is on the road.

Boundary conditions (Table 4): a start set and an end set, each fixing some of
$(x, y, \psi, \dot\psi)$, bounding others to an interval, and zeroing one inertial velocity
component ("$\dot y = 0$" means $v_x\sin\psi + v_y\cos\psi = 0$). `Road.validate` refuses
infeasible problems (a boundary set off the road, legs that do not connect start to end).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np


SMOOTHING = 0.1
"""Width [m] of the band around an inner corner's diagonal where `smooth_max` < max."""


def smooth_max(a, b, eps: float = SMOOTHING):
    r"""Conservative $C^2$ maximum: $\frac{a+b}{2} + \frac{\epsilon}{2}p(\frac{a-b}{\epsilon})$,
    $p(t) = |t|$ for $|t|\ge1$, else $\frac{15}{8}t^2 - \frac{5}{4}t^4 + \frac{3}{8}t^6$.

    $p \le |t|$, so the result is $\le \max(a, b)$ (by at most $0.0706\,\epsilon$), with equality
    for $|a - b| \ge \epsilon$.
    """
    return _smooth_max(a, b, eps, jnp)


def _smooth_max(a, b, eps, xp):
    """`smooth_max` with the array functions of ``xp`` (jax.numpy, or numpy for checks)."""
    t = (a - b) / eps
    inside = xp.abs(t) < 1.0
    ti = xp.where(inside, t, 0.0)
    t2 = ti * ti
    p = xp.where(inside, t2 * (15.0 / 8.0 - t2 * (5.0 / 4.0 - t2 * 3.0 / 8.0)), xp.abs(t))
    return 0.5 * (a + b) + 0.5 * eps * p


class Rect(eqx.Module):
    """An axis-aligned rectangle (a leg of the road), in metres."""

    xmin: float = eqx.field(static=True)
    xmax: float = eqx.field(static=True)
    ymin: float = eqx.field(static=True)
    ymax: float = eqx.field(static=True)

    def contains(self, x, y, tol: float = 1e-9) -> bool:
        return (self.xmin - tol <= x <= self.xmax + tol) and (
            self.ymin - tol <= y <= self.ymax + tol
        )

    def overlaps(self, other: Rect) -> bool:
        return (
            self.xmin <= other.xmax and other.xmin <= self.xmax
            and self.ymin <= other.ymax and other.ymin <= self.ymax
        )


class BoundarySet(eqx.Module):
    """Boundary conditions at one end: ``fixed`` {name: value}, ``box`` {name: (lo, hi)} for
    names in (x, y, psi, yaw_rate), and ``zero_velocity``: 'x' or 'y', the inertial velocity
    component that vanishes."""

    fixed: tuple = eqx.field(static=True)
    box: tuple = eqx.field(static=True)
    zero_velocity: str = eqx.field(static=True)

    def points(self) -> list[tuple[float, float]]:
        """The extreme (x, y) points of the set (both ends of the position interval)."""
        fixed, box = dict(self.fixed), dict(self.box)
        xs = [fixed["x"]] if "x" in fixed else list(box["x"])
        ys = [fixed["y"]] if "y" in fixed else list(box["y"])
        return [(x, y) for x in xs for y in ys]

    def centre(self) -> tuple[float, float]:
        pts = np.array(self.points())
        return float(pts[:, 0].mean()), float(pts[:, 1].mean())


_INDEX = {"x": 0, "y": 1, "psi": 2, "yaw_rate": 5}


class Road(eqx.Module):
    r"""A corridor (union of `legs`) with start and end sets.

    **Fields:** ``name``; ``legs`` (Rects, start leg first, consecutive legs overlapping);
    ``outer`` = (xmin, xmax, ymin, ymax) outer walls (``None``: an open end); ``corners``:
    forbidden convex regions, each a tuple of half-planes ``(nx, ny, b)`` meaning
    $a = n\cdot p - b$; ``start``, ``end`` (`BoundarySet`); ``centreline``: a polyline
    through the legs (for initial guesses).
    """

    name: str = eqx.field(static=True)
    legs: tuple = eqx.field(static=True)
    outer: tuple = eqx.field(static=True)
    corners: tuple = eqx.field(static=True)
    start: BoundarySet
    end: BoundarySet
    centreline: tuple = eqx.field(static=True)

    def __check_init__(self):
        self.validate()

    @property
    def num_corridor_constraints(self) -> int:
        return sum(w is not None for w in self.outer) + len(self.corners)

    def corridor(self, x, y):
        r"""Smooth corridor inequalities $c(x, y) \ge 0$ (outer walls, then inner corners).

        Walls given as ``None`` in ``outer`` are open ends (the start and end lines, which the
        boundary conditions fix; a wall there would duplicate them degenerately)."""
        return self._corridor(x, y, jnp)

    def _corridor(self, x, y, xp):
        xmin, xmax, ymin, ymax = self.outer
        cons = []
        for wall, val in ((xmin, x - (xmin or 0.0)), (xmax, (xmax or 0.0) - x),
                          (ymin, y - (ymin or 0.0)), (ymax, (ymax or 0.0) - y)):
            if wall is not None:
                cons.append(val)
        for planes in self.corners:
            vals = [nx_ * x + ny_ * y - b for nx_, ny_, b in planes]
            m = vals[0]
            for v in vals[1:]:
                m = _smooth_max(m, v, SMOOTHING, xp)
            cons.append(m)
        return xp.stack(cons)

    def on_road(self, x, y, tol: float = 1e-9) -> bool:
        """Exact membership of the union of legs (for validation and checks)."""
        return any(leg.contains(x, y, tol) for leg in self.legs)

    def distance_off_road(self, x, y) -> np.ndarray:
        """Exact distance [m] of points from the union of legs (0 on the road)."""
        x, y = np.asarray(x, float), np.asarray(y, float)
        d = np.full(x.shape, np.inf)
        for leg in self.legs:
            dx = np.maximum(np.maximum(leg.xmin - x, x - leg.xmax), 0.0)
            dy = np.maximum(np.maximum(leg.ymin - y, y - leg.ymax), 0.0)
            d = np.minimum(d, np.hypot(dx, dy))
        return d

    def validate(self) -> None:
        """Raise ``ValueError`` if the problem cannot be feasible: a boundary set off the road,
        start and end on legs that do not connect, or a degenerate leg."""
        for i, leg in enumerate(self.legs):
            if not (leg.xmax > leg.xmin and leg.ymax > leg.ymin):
                raise ValueError(f"Road {self.name!r}: leg {i} is empty ({leg})")
        for i in range(len(self.legs) - 1):
            if not self.legs[i].overlaps(self.legs[i + 1]):
                raise ValueError(
                    f"Road {self.name!r}: legs {i} and {i + 1} do not touch, so the end "
                    "cannot be reached from the start"
                )
        for label, bset, leg in (("start", self.start, self.legs[0]),
                                 ("end", self.end, self.legs[-1])):
            for name in dict(bset.fixed).keys() | dict(bset.box).keys():
                if name not in _INDEX:
                    raise ValueError(
                        f"Road {self.name!r}: {label} condition on {name!r}; allowed: "
                        f"{sorted(_INDEX)}"
                    )
            for lo_hi in dict(bset.box).values():
                if not lo_hi[0] <= lo_hi[1]:
                    raise ValueError(f"Road {self.name!r}: {label} interval {lo_hi} is empty")
            if bset.zero_velocity not in ("x", "y"):
                raise ValueError(f"Road {self.name!r}: {label}.zero_velocity must be 'x' or 'y'")
            for x, y in bset.points():
                if not leg.contains(x, y):
                    raise ValueError(
                        f"Road {self.name!r}: {label} point ({x}, {y}) is off its leg {leg} "
                        "(boundary set outside the corridor: infeasible)"
                    )
                c = self._corridor(float(x), float(y), np)
                if np.any(c < -1e-9):
                    raise ValueError(
                        f"Road {self.name!r}: {label} point ({x}, {y}) violates the corridor "
                        "constraints (infeasible)"
                    )

    # ---- boundary conditions as functions of the vehicle state (x, y, psi, vx, vy, r, ...)
    @staticmethod
    def _lateral_velocity(state, axis):
        psi, vx, vy = state[2], state[3], state[4]
        if axis == "y":
            return vx * jnp.sin(psi) + vy * jnp.cos(psi)
        return vx * jnp.cos(psi) - vy * jnp.sin(psi)

    def boundary_equality(self, bset: BoundarySet, state):
        """Equalities of a boundary set: fixed values and the zero inertial velocity."""
        vals = [state[_INDEX[n]] - v for n, v in bset.fixed]
        vals.append(self._lateral_velocity(state, bset.zero_velocity))
        return jnp.stack(vals)

    def boundary_inequality(self, bset: BoundarySet, state):
        """Inequalities (>= 0) of a boundary set: its intervals."""
        vals = []
        for n, (lo, hi) in bset.box:
            vals += [state[_INDEX[n]] - lo, hi - state[_INDEX[n]]]
        return jnp.stack(vals) if vals else jnp.zeros((0,))

    def path_length(self) -> float:
        pts = np.asarray(self.centreline, float)
        return float(np.sum(np.hypot(*np.diff(pts, axis=0).T)))


def _bset(fixed: dict, box: dict, zero_velocity: str) -> BoundarySet:
    return BoundarySet(
        fixed=tuple(sorted(fixed.items())),
        box=tuple(sorted((k, tuple(v)) for k, v in box.items())),
        zero_velocity=zero_velocity,
    )


def corner90() -> Road:
    """90 degree right corner (Table 4, first column)."""
    return Road(
        name="corner90",
        legs=(Rect(-5.0, 10.0, 8.0, 10.0), Rect(8.0, 10.0, -5.0, 10.0)),
        outer=(None, 10.0, None, 10.0),
        corners=(((1.0, 0.0, 8.0), (0.0, 1.0, 8.0)),),
        start=_bset({"x": -5.0, "psi": 0.0, "yaw_rate": 0.0}, {"y": (8.0, 10.0)}, "y"),
        end=_bset({"y": -5.0, "psi": -math.pi / 2, "yaw_rate": 0.0}, {"x": (8.0, 10.0)}, "x"),
        centreline=((-5.0, 9.0), (9.0, 9.0), (9.0, -5.0)),
    )


def uturn() -> Road:
    """U-turn (Table 4, second column): up the left leg, across the top, down the right."""
    return Road(
        name="uturn",
        legs=(Rect(-10.0, -8.0, -5.0, 10.0), Rect(-10.0, 10.0, 8.0, 10.0),
              Rect(8.0, 10.0, -5.0, 10.0)),
        outer=(-10.0, 10.0, None, 10.0),
        corners=(((1.0, 0.0, 8.0), (-1.0, 0.0, 8.0), (0.0, 1.0, 8.0)),),
        start=_bset({"y": -5.0, "psi": math.pi / 2, "yaw_rate": 0.0}, {"x": (-10.0, -8.0)}, "x"),
        end=_bset({"y": -5.0, "psi": -math.pi / 2, "yaw_rate": 0.0}, {"x": (8.0, 10.0)}, "x"),
        centreline=((-9.0, -5.0), (-9.0, 9.0), (9.0, 9.0), (9.0, -5.0)),
    )


def sturn() -> Road:
    """S-turn (Table 4, third column): lower leg, connector up, upper leg."""
    return Road(
        name="sturn",
        legs=(Rect(-14.0, 1.0, -10.0, -8.0), Rect(-1.0, 1.0, -10.0, 10.0),
              Rect(-1.0, 14.0, 8.0, 10.0)),
        outer=(None, None, -10.0, 10.0),
        corners=(((1.0, 0.0, -1.0), (0.0, -1.0, 8.0)), ((-1.0, 0.0, -1.0), (0.0, 1.0, 8.0))),
        start=_bset({"x": -14.0, "psi": 0.0, "yaw_rate": 0.0}, {"y": (-10.0, -8.0)}, "y"),
        end=_bset({"x": 14.0, "psi": 0.0, "yaw_rate": 0.0}, {"y": (8.0, 10.0)}, "y"),
        centreline=((-14.0, -9.0), (0.0, -9.0), (0.0, 9.0), (14.0, 9.0)),
    )


ROADS = {"corner90": corner90, "uturn": uturn, "sturn": sturn}


def road(name: str) -> Road:
    """The road called ``name`` (corner90, uturn, sturn)."""
    try:
        return ROADS[name]()
    except KeyError:
        raise ValueError(f"unknown road {name!r}; known: {sorted(ROADS)}") from None


def make_road(name: str, legs: Sequence[Rect], outer, corners, start: BoundarySet,
              end: BoundarySet, centreline) -> Road:
    """Build (and validate) a custom road."""
    return Road(name=name, legs=tuple(legs), outer=tuple(outer), corners=tuple(corners),
                start=start, end=end, centreline=tuple(map(tuple, centreline)))


boundary_set = _bset
