r"""Roads defined by a centre line and two widths (racetrack data, or built in code).

The centre line $c(s)$ is a planar curve parametrised by its arc length $s \in [0, L]$, with
unit tangent $T(s) = (\cos\theta, \sin\theta)$, left normal $N(s) = (-\sin\theta,
\cos\theta)$ and signed curvature $\kappa = \theta'$ (left turns positive). A point is
written in the Frenet (curvilinear) frame as

$$p(s, n) = c(s) + n\,N(s),$$

$n$ the lateral offset, positive to the left. The road is the region
$\{c(s) + nN(s) : -w_r(s) \le n \le w_l(s)\}$; the map $(s, n) \mapsto p$ is one-to-one on
it only while $1 - n\kappa > 0$, so a width reaching the local radius of curvature (the
boundary folds over itself) is refused. A closed road (a circuit) is periodic in $s$ with
period $L$.

Stored form: the curve is sampled at knots $s_0 = 0 < \dots < s_K = L$ (at most
`SPACING` metres apart, and at every junction of segments or breakpoint of a spline), with
position, unit tangent and the second derivative $\kappa N$ on each side of a knot; between
knots the position is the quintic Hermite interpolant of these (so $C^2$, and exactly $C^2$
across knots of a spline centre line; a curvature jump of joined segments stays a jump at the
junction), the widths the cubic Hermite interpolant of their values and slopes. Every method
takes and returns numpy arrays and is vectorised over its arguments.

Gates (`Gate`): the start and end lines of a problem, each a line across the road at an arc
length, with the lateral interval it allows and optionally a fixed speed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import equinox as eqx
import numpy as np

from .._checks import check_finite, check_order, is_numeric


SPACING = 0.5
"""Target spacing [m] of the knots that store the centre line."""

_FOLD_MARGIN = 1.0
"""A width $w$ with $w\\,|\\kappa| \\ge$ this folds the boundary (it is refused)."""


# ---- gates --------------------------------------------------------------------------------


class Gate(eqx.Module):
    r"""A line across the road at arc length `s`: the positions $c(s) + nN(s)$ with
    $n \in [n_{\min}, n_{\max}]$ (default the full width, $[-w_r(s), w_l(s)]$), and a fixed
    `speed` [m/s] or ``None`` (free).

    Build one with `Gate.at` (an arc length) or `Gate.from_point` (a point projected onto
    the road); both refuse a gate off the road.
    """

    s: float = eqx.field(static=True)
    n_min: float = eqx.field(static=True)
    n_max: float = eqx.field(static=True)
    speed: float | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        for name in ("s", "n_min", "n_max"):
            check_finite("Gate", name, getattr(self, name))
        check_order("Gate", "n_min", self.n_min, "n_max", self.n_max)
        if self.speed is not None and not (math.isfinite(self.speed) and self.speed >= 0):
            raise ValueError(f"Gate.speed must be None (free) or a speed in [0, inf) m/s, got "
                             f"{self.speed!r}")

    @classmethod
    def at(cls, road: CentrelineRoad, s: float, *, n_min: float | None = None,
           n_max: float | None = None, speed: float | None = None) -> Gate:
        """The gate at arc length ``s`` of ``road``; ``n_min``/``n_max`` (default the road's
        edges there) bound the lateral offset [m], ``speed`` [m/s] fixes the speed."""
        s = float(s)
        if not (math.isfinite(s) and -1e-9 * road.length <= s <= road.length * (1 + 1e-12)):
            raise ValueError(f"road {road.name!r}: gate at s = {s:g} m is off the road "
                             f"(s must be in [0, {road.length:g}] m)")
        s = min(max(s, 0.0), road.length)
        wl, wr = float(road.width_left(s)), float(road.width_right(s))
        lo = -wr if n_min is None else float(n_min)
        hi = wl if n_max is None else float(n_max)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f"road {road.name!r}: gate at s = {s:g} m has an empty lateral "
                             f"interval [{lo:g}, {hi:g}] m")
        tol = 1e-9 * max(1.0, wl + wr)
        if lo < -wr - tol or hi > wl + tol:
            raise ValueError(
                f"road {road.name!r}: gate at s = {s:g} m is off the road: its lateral interval "
                f"[{lo:g}, {hi:g}] m leaves the road's [{-wr:g}, {wl:g}] m")
        if speed is not None:
            speed = float(speed)
            if not (math.isfinite(speed) and speed >= 0):
                raise ValueError(f"road {road.name!r}: gate speed must be finite and >= 0 m/s, "
                                 f"got {speed:g}")
        return cls(s=s, n_min=lo, n_max=hi, speed=speed)

    @classmethod
    def from_point(cls, road: CentrelineRoad, x: float, y: float, *,
                   speed: float | None = None) -> Gate:
        """The full-width gate through the point ``(x, y)`` [m], projected onto the centre
        line (`CentrelineRoad.to_frenet`); refused if the point is off the road."""
        s, n = road.to_frenet(float(x), float(y))
        s, n = float(s), float(n)
        wl, wr = float(road.width_left(s)), float(road.width_right(s))
        if not (-wr - 1e-9 <= n <= wl + 1e-9) or road.distance_off_road(x, y) > 1e-6:
            raise ValueError(
                f"road {road.name!r}: gate point ({float(x):g}, {float(y):g}) is off the road: "
                f"{abs(n):g} m from the centre line at s = {s:g} m, where the road reaches "
                f"{wl if n > 0 else wr:g} m to the {'left' if n > 0 else 'right'}")
        return cls.at(road, s, speed=speed)

    @property
    def lateral(self) -> tuple[float, float]:
        """The lateral interval ``(n_min, n_max)`` [m] the gate allows."""
        return self.n_min, self.n_max

    def endpoints(self, road: CentrelineRoad) -> np.ndarray:
        """The gate's two ends as a (2, 2) array: right end (``n_min``), left end (``n_max``)."""
        x, y = road.to_cartesian(np.array([self.s, self.s]),
                                 np.array([self.n_min, self.n_max]))
        return np.stack([x, y], axis=-1)


# ---- the road -----------------------------------------------------------------------------


def _hermite5(t, h, p0, m0, a0, a1, m1, p1):
    """Quintic Hermite on t in [0, 1] with end values p, slopes m and second derivatives a
    (per unit s; h the interval length): value, first and second derivatives in s."""
    m0, m1, a0, a1 = m0 * h, m1 * h, a0 * h * h, a1 * h * h
    c3 = -10 * p0 - 6 * m0 - 1.5 * a0 + 0.5 * a1 - 4 * m1 + 10 * p1
    c4 = 15 * p0 + 8 * m0 + 1.5 * a0 - a1 + 7 * m1 - 15 * p1
    c5 = -6 * p0 - 3 * m0 - 0.5 * a0 + 0.5 * a1 - 3 * m1 + 6 * p1
    c2 = 0.5 * a0
    p = p0 + t * (m0 + t * (c2 + t * (c3 + t * (c4 + t * c5))))
    d1 = m0 + t * (2 * c2 + t * (3 * c3 + t * (4 * c4 + t * 5 * c5)))
    d2 = 2 * c2 + t * (6 * c3 + t * (12 * c4 + t * 20 * c5))
    return p, d1 / h, d2 / (h * h)


def _hermite3(t, h, p0, m0, m1, p1):
    """Cubic Hermite on t in [0, 1] (interval length h): value and first two s-derivatives
    (NumPy or JAX arrays alike)."""
    t2, t3 = t * t, t * t * t
    v = ((2 * t3 - 3 * t2 + 1) * p0 + (t3 - 2 * t2 + t) * h * m0 + (-2 * t3 + 3 * t2) * p1
         + (t3 - t2) * h * m1)
    d = ((6 * t2 - 6 * t) * p0 + (3 * t2 - 4 * t + 1) * h * m0 + (-6 * t2 + 6 * t) * p1
         + (3 * t2 - 2 * t) * h * m1) / h
    dd = ((12 * t - 6) * p0 + (6 * t - 4) * h * m0 + (-12 * t + 6) * p1
          + (6 * t - 2) * h * m1) / (h * h)
    return v, d, dd


def _check_length(name, length: float, where: str = "") -> None:
    """Refuse a centre line outside `LENGTH_RANGE`, naming its length."""
    if not LENGTH_RANGE[0] <= length <= LENGTH_RANGE[1]:
        raise ValueError(f"road {name!r}: the centre line is {length:.6g} m long{where}; a "
                         f"road must be {LENGTH_RANGE[0]:g} m to {LENGTH_RANGE[1]:g} m long")


class CentrelineRoad(eqx.Module):
    r"""A road given by its centre line $c(s)$, $s \in [0, L]$, and widths $w_l(s), w_r(s) > 0$
    to the left and right (module docstring: the Frenet frame, the stored form).

    Build with `CentrelineRoad.from_points` (racetrack data: a smoothing spline through
    points), `CentrelineRoad.from_segments` (straights, arcs and clothoids) or read a CSV
    file with `read_road`. Methods take arc lengths `s` [m] (closed roads: any real,
    wrapped with period `length`; open roads: clipped to $[0, L]$) or points, as numpy
    arrays of any shape.

    **Fields:** `name`; `closed`; `length` $L$ [m]; the knots (`knots`, `points`,
    `tangents`, `accel_start`, `accel_end`, `headings`, `widths`, `width_slopes`: the
    stored form); `start` and `end` (`Gate`, default the full width at $s = 0$ and
    $s = L$: a closed road's lap).
    """

    name: str = eqx.field(static=True)
    closed: bool = eqx.field(static=True)
    length: float = eqx.field(static=True)
    knots: np.ndarray  # (K+1,) arc lengths, 0 ... L
    points: np.ndarray  # (K+1, 2) c(s_k)
    tangents: np.ndarray  # (K+1, 2) T(s_k)
    accel_start: np.ndarray  # (K, 2) c''(s_k+), the start of interval k
    accel_end: np.ndarray  # (K, 2) c''(s_{k+1}-), the end of interval k
    headings: np.ndarray  # (K+1,) unwrapped theta(s_k)
    widths: np.ndarray  # (K+1, 2) (w_right, w_left)
    width_slopes: np.ndarray  # (K+1, 2) their s-derivatives
    start: Gate
    end: Gate

    # ---- evaluation ---------------------------------------------------------------------

    def _wrap(self, s):
        s = np.asarray(s, float)
        if self.closed:
            return np.mod(s, self.length)
        return np.clip(s, 0.0, self.length)

    def _locate(self, s):
        s = self._wrap(s)
        k = np.clip(np.searchsorted(self.knots, s, side="right") - 1, 0, len(self.knots) - 2)
        h = self.knots[k + 1] - self.knots[k]
        return k, (s - self.knots[k]) / h, h

    def _curve(self, s):
        """c(s), c'(s), c''(s), each (..., 2); and the interval index."""
        k, t, h = self._locate(s)
        t, h = t[..., None], h[..., None]
        p, d1, d2 = _hermite5(t, h, self.points[k], self.tangents[k], self.accel_start[k],
                              self.accel_end[k], self.tangents[k + 1], self.points[k + 1])
        return p, d1, d2, k

    def position(self, s) -> tuple[np.ndarray, np.ndarray]:
        """The centre line $c(s) = (x, y)$ [m]."""
        p = self._curve(s)[0]
        return p[..., 0], p[..., 1]

    def curvature_jumps(self, tol: float = 1e-8) -> np.ndarray:
        """Arc lengths in $(0, L)$ of the knots where the curvature jumps by more than
        ``tol`` [1/m]: the junctions of straights and arcs of `from_segments` (none on a
        smoothing spline's road). The road's frame in `road_primitive` puts a node on each."""
        if len(self.knots) < 3:
            return np.zeros(0)
        T = self.tangents[1:-1]
        norm3 = np.hypot(T[:, 0], T[:, 1]) ** 3
        cross = lambda a: T[:, 0] * a[:, 1] - T[:, 1] * a[:, 0]
        left = cross(self.accel_end[:-1]) / norm3  # at s_k-
        right = cross(self.accel_start[1:]) / norm3  # at s_k+
        return np.asarray(self.knots[1:-1], float)[np.abs(right - left) > tol]

    def heading(self, s) -> np.ndarray:
        r"""The tangent's angle $\theta(s)$ [rad], unwrapped: continuous in $s$, and for a
        closed road continued over the laps, $\theta(s + L) = \theta(s) + \Theta$ with
        $\Theta = \theta(L) - \theta(0)$ the lap's total turn ($\pm 2\pi$ for a circuit)."""
        _, d1, _, k = self._curve(s)
        th = self.headings[k]
        c, sn = np.cos(th), np.sin(th)
        out = th + np.arctan2(c * d1[..., 1] - sn * d1[..., 0], c * d1[..., 0] + sn * d1[..., 1])
        if self.closed:
            laps = np.floor(np.asarray(s, float) / self.length)
            out = out + laps * (self.headings[-1] - self.headings[0])
        return out

    def curvature(self, s) -> np.ndarray:
        r"""Signed curvature $\kappa(s) = \theta'(s)$ [1/m], left turns positive."""
        _, d1, d2, _ = self._curve(s)
        v = np.hypot(d1[..., 0], d1[..., 1])
        return (d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0]) / v**3

    def _widths(self, s):
        k, t, h = self._locate(s)
        t, h = t[..., None], h[..., None]
        return _hermite3(t, h, self.widths[k], self.width_slopes[k], self.width_slopes[k + 1],
                         self.widths[k + 1])[:2]

    def width_left(self, s) -> np.ndarray:
        """Width $w_l(s) > 0$ [m] from the centre line to the left edge."""
        return self._widths(s)[0][..., 1]

    def width_right(self, s) -> np.ndarray:
        """Width $w_r(s) > 0$ [m] from the centre line to the right edge."""
        return self._widths(s)[0][..., 0]

    def _frame(self, s):
        p, d1, _, _ = self._curve(s)
        t = d1 / np.hypot(d1[..., 0], d1[..., 1])[..., None]
        return p, t, np.stack([-t[..., 1], t[..., 0]], axis=-1)

    def to_cartesian(self, s, n) -> tuple[np.ndarray, np.ndarray]:
        """The point $c(s) + nN(s)$ [m] ($n$ positive to the left)."""
        s, n = np.broadcast_arrays(np.asarray(s, float), np.asarray(n, float))
        p, _, nrm = self._frame(s)
        q = p + n[..., None] * nrm
        return q[..., 0], q[..., 1]

    def to_frenet(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        r"""The Frenet coordinates $(s, n)$ of points: $s$ of the nearest centre-line point
        (nearest knot, then Newton's method on $(p - c(s))\cdot T(s) = 0$), $n = (p -
        c(s))\cdot N(s)$. Open roads: $s$ is clipped to $[0, L]$, and beyond the ends $n$ is
        the offset along the end's normal."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        shape = x.shape
        q = np.stack([x.ravel(), y.ravel()], axis=-1)
        s = self.knots[_nearest(self.points, q)]
        h = float(np.max(np.diff(self.knots)))
        for _ in range(12):
            p, d1, d2, _ = self._curve(s)
            r = q - p
            f = np.sum(r * d1, axis=-1)
            fp = np.sum(d1 * d1, axis=-1) - np.sum(r * d2, axis=-1)
            step = np.clip(f / np.where(fp > 0.1, fp, 0.1), -h, h)
            s = self._wrap(s + step) if self.closed else np.clip(s + step, 0.0, self.length)
            if np.all(np.abs(step) < 1e-12 * max(1.0, self.length)):
                break
        p, _, nrm = self._frame(s)
        n = np.sum((q - p) * nrm, axis=-1)
        return s.reshape(shape), n.reshape(shape)

    # ---- the road region ----------------------------------------------------------------

    def boundaries(self, num: int = 1000) -> tuple[np.ndarray, np.ndarray]:
        """The left and right edges, each a (num, 2) polyline at ``num`` equally spaced arc
        lengths (closed roads: the first point repeated at the end)."""
        s = np.linspace(0.0, self.length, int(num))
        wl, wr = self.width_left(s), self.width_right(s)
        left = np.stack(self.to_cartesian(s, wl), axis=-1)
        right = np.stack(self.to_cartesian(s, -wr), axis=-1)
        return left, right

    @property
    def centreline(self) -> tuple[tuple[float, float], ...]:
        """A coarse polyline of the centre line, ((x, y), ...), about every 5 m (for plots
        and initial guesses; as `Road.centreline`)."""
        num = max(8, min(2000, int(math.ceil(self.length / 5.0)) + 1))
        x, y = self.position(np.linspace(0.0, self.length, num))
        return tuple(zip(x.tolist(), y.tolist()))

    def path_length(self) -> float:
        """Arc length $L$ [m] of the centre line (as `Road.path_length`)."""
        return self.length

    def _edge_samples(self):
        """The edges sampled at the knots and the knot midpoints: arc lengths and the left and
        right boundary points."""
        s = np.sort(np.concatenate([self.knots, 0.5 * (self.knots[1:] + self.knots[:-1])]))
        left = np.stack(self.to_cartesian(s, self.width_left(s)), axis=-1)
        right = np.stack(self.to_cartesian(s, -self.width_right(s)), axis=-1)
        return s, left, right

    def distance_off_road(self, x, y) -> np.ndarray:
        r"""Exact distance [m] of points from the road region $\{c(s) + nN(s) : -w_r(s) \le n
        \le w_l(s)\}$ (0 on the road), as `Road.distance_off_road`.

        The boundary polygon through edge samples (open roads: left edge, end line, right
        edge reversed, start line; closed: the ring between the two closed edges) gives, by
        the even-odd rule, inside or outside and the nearest side. Outside, and within a side's
        length of an edge, the nearest point of the exact edge curve is found by a
        golden-section search over the neighbouring arc lengths: its distance, and the side of
        the edge the point is on, decide. A point with a NaN coordinate is at NaN, one with
        an infinite (and no NaN) coordinate at inf."""
        x, y = np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float))
        q = np.stack([x.ravel(), y.ravel()], axis=-1)
        finite = np.all(np.isfinite(q), axis=-1)
        out = np.where(np.any(np.isnan(q), axis=-1), np.nan, np.inf)
        if np.any(finite):
            out[finite] = self._finite_distance_off_road(q[finite])
        return out.reshape(x.shape)

    def _finite_distance_off_road(self, q):
        """`distance_off_road` of finite points ``q`` (P, 2)."""
        s, left, right = self._edge_samples()
        m = len(s)
        # sides: left edge (s increasing), right edge (s increasing); caps for open roads
        a = np.concatenate([left[:-1], right[:-1]])
        b = np.concatenate([left[1:], right[1:]])
        side = np.concatenate([np.ones(m - 1), -np.ones(m - 1)])
        lo = np.concatenate([s[:-1], s[:-1]])
        hi = np.concatenate([s[1:], s[1:]])
        if not self.closed:
            a = np.concatenate([a, [right[0], right[-1]]])
            b = np.concatenate([b, [left[0], left[-1]]])
            side = np.concatenate([side, [0.0, 0.0]])
            lo = np.concatenate([lo, [0.0, 0.0]])
            hi = np.concatenate([hi, [0.0, 0.0]])
        inside, out, near = _polygon_query(q, a, b)
        out[inside] = 0.0
        # outside, or near an edge curve (where the polygon's sides, chords of the curve, may
        # put a point on the wrong side): the nearest point of the exact edge curve, and on
        # which side of it the point is
        delta = float(np.max(np.hypot(*(b - a).T)))
        curve = (side[near] != 0.0) & (~inside | (out < delta))
        if np.any(curve):
            j = near[curve]
            d, s_near, outward = self._edge_distance(q[curve], side[j], lo[j], hi[j])
            at_end = ~self.closed & ((s_near <= 0.0) | (s_near >= self.length))
            off = np.where(at_end, ~inside[curve], outward)  # at a corner: the polygon's word
            out[curve] = np.where(off, d, 0.0)
        return out

    def _edge_distance(self, q, side, lo, hi):
        """Distance from points q to the edge curve (side +1 left, -1 right) near arc lengths
        [lo, hi] (golden-section search over [lo - (hi - lo), hi + (hi - lo)]), the arc length
        of the nearest point, and whether q lies beyond the edge (off the road)."""
        span = hi - lo
        a, b = lo - span, hi + span
        if not self.closed:
            a, b = np.clip(a, 0.0, self.length), np.clip(b, 0.0, self.length)

        def dist2(s):
            n = np.where(side > 0, self.width_left(s), -self.width_right(s))
            px, py = self.to_cartesian(s, n)
            return (q[:, 0] - px) ** 2 + (q[:, 1] - py) ** 2

        g = (math.sqrt(5.0) - 1.0) / 2.0
        for _ in range(48):
            c, d = b - g * (b - a), a + g * (b - a)
            first = dist2(c) < dist2(d)
            a, b = np.where(first, a, c), np.where(first, d, b)
        s = 0.5 * (a + b)
        d2 = dist2(s)
        # whether q is beyond the edge: (q - b(s)) . the edge's outward normal, which is the
        # edge's tangent b'(s) turned left (left edge) or right (right edge) by 90 degrees
        eps = 1e-6 * max(1.0, float(np.max(hi - lo)))
        n = np.where(side > 0, self.width_left(s), -self.width_right(s))
        px, py = self.to_cartesian(s, n)
        s_a, s_b = s - eps, s + eps
        if not self.closed:
            s_a, s_b = np.clip(s_a, 0.0, self.length), np.clip(s_b, 0.0, self.length)
        ax_, ay_ = self.to_cartesian(s_a, np.where(side > 0, self.width_left(s_a),
                                                   -self.width_right(s_a)))
        bx_, by_ = self.to_cartesian(s_b, np.where(side > 0, self.width_left(s_b),
                                                   -self.width_right(s_b)))
        tx, ty = bx_ - ax_, by_ - ay_
        beyond = side * ((q[:, 1] - py) * tx - (q[:, 0] - px) * ty) > 0
        return np.sqrt(d2), s, beyond

    def on_road(self, x, y, tol: float = 1e-9) -> np.ndarray:
        """Whether points are on the road (`distance_off_road` <= ``tol``)."""
        return self.distance_off_road(x, y) <= tol

    # ---- building -----------------------------------------------------------------------

    @classmethod
    def from_points(cls, x, y, width_right, width_left, *, closed: bool = False,
                    smoothing: float = 0.0, name: str = "road", start=None,
                    end=None) -> CentrelineRoad:
        r"""The road through centre-line points $(x_i, y_i)$ [m] with widths [m] to the right
        and left (the columns of a racetrack CSV file).

        The centre line is a cubic smoothing spline (`scipy.interpolate.splprep`, periodic
        for a closed road) in the chord length of the points, re-parametrised by its true arc
        length; ``smoothing`` [m] is the root-mean-square distance allowed between the points
        and the curve (0: through the points). Closed roads: the first point is $s = 0$ and
        is not repeated at the end. The widths are cubic splines (periodic if closed) in the
        same parameter.

        ``start``/``end``: a `Gate`, an arc length [m], a point ``(x, y)`` projected onto the
        road, or ``None`` (full width at $s = 0$ and $s = L$).

        **Raises:** `ValueError` (naming the row, column or arc length) for fewer than 4
        points, a non-finite value, a width $\le 0$, duplicate consecutive points, a
        self-intersecting centre line, a width reaching the local radius of curvature, a
        centre line outside `LENGTH_RANGE`, or a gate off the road.
        """
        from scipy.interpolate import CubicSpline, splev, splprep

        cols = {"x": x, "y": y, "width_right": width_right, "width_left": width_left}
        arrs = {}
        for key, v in cols.items():
            v = np.asarray(v, float)
            if v.ndim != 1:
                raise ValueError(f"road {name!r}: {key} must be a 1-D array, got shape {v.shape}")
            arrs[key] = v
        npts = len(arrs["x"])
        for key, v in arrs.items():
            if len(v) != npts:
                raise ValueError(f"road {name!r}: {key} has {len(v)} values, x has {npts}")
        if npts < 4:
            raise ValueError(f"road {name!r}: needs at least 4 centre-line points, got {npts}")
        for key, v in arrs.items():
            bad = np.flatnonzero(~np.isfinite(v))
            if bad.size:
                raise ValueError(f"road {name!r}: row {bad[0]}, {key} is not finite "
                                 f"({v[bad[0]]})")
        for key in ("width_right", "width_left"):
            bad = np.flatnonzero(arrs[key] <= 0)
            if bad.size:
                raise ValueError(f"road {name!r}: row {bad[0]}, {key} must be > 0 m, got "
                                 f"{arrs[key][bad[0]]:g}")
        for key, limit in (("x", COORDINATE_LIMIT), ("y", COORDINATE_LIMIT),
                           ("width_right", WIDTH_LIMIT), ("width_left", WIDTH_LIMIT)):
            bad = np.flatnonzero(np.abs(arrs[key]) > limit)
            if bad.size:
                raise ValueError(f"road {name!r}: row {bad[0]}, {key} must lie within "
                                 f"{limit:g} m (a local frame in metres), got "
                                 f"{arrs[key][bad[0]]:g}")
        pts = np.stack([arrs["x"], arrs["y"]], axis=-1)
        if closed:
            pts_c = np.concatenate([pts, pts[:1]])
        else:
            pts_c = pts
        chord = np.hypot(*np.diff(pts_c, axis=0).T)
        scale = max(1.0, float(np.max(np.abs(pts))))
        dup = np.flatnonzero(chord <= 1e-9 * scale)
        if dup.size:
            i = int(dup[0])
            j = (i + 1) % npts
            hint = " (a closed road's first point is not repeated at the end)" if (
                closed and j == 0) else ""
            raise ValueError(f"road {name!r}: rows {i} and {j} are the same point "
                             f"({pts[i, 0]:g}, {pts[i, 1]:g}){hint}")
        if closed:
            typical = float(np.median(chord[:-1]))
            if chord[-1] > CLOSING_GAP * typical:
                raise ValueError(
                    f"road {name!r}: a closed road, but its last point (row {npts - 1}) is "
                    f"{chord[-1]:.4g} m from its first, {chord[-1] / typical:.0f} times the "
                    f"points' median spacing ({typical:.4g} m): is it an open road?")
        u = np.concatenate([[0.0], np.cumsum(chord)])
        # an RMS distance beyond the points' path length would flatten any road (and
        # overflow the spline's sum of squares)
        if not (is_numeric(smoothing) and np.ndim(smoothing) == 0
                and 0 <= float(smoothing) <= u[-1]):
            raise ValueError(f"road {name!r}: smoothing must lie in [0, {u[-1]:.6g}] m (the "
                             f"points' path length), got {smoothing!r}")
        smoothing = float(smoothing)
        tck, _ = splprep([pts_c[:, 0], pts_c[:, 1]], u=u, k=3, s=len(u) * smoothing**2,
                         per=1 if closed else 0, quiet=1)
        U = u[-1]

        def speed(uu):
            d = np.asarray(splev(uu, tck, der=1))
            return np.hypot(d[0], d[1])

        # arc length at the points: 8-point Gauss-Legendre per chord (and per spline piece
        # inside it, the knots being a subset of u when smoothing)
        brk = np.unique(np.concatenate([u, np.clip(tck[0], 0.0, U)]))
        gx, gw = np.polynomial.legendre.leggauss(8)
        mid, half = 0.5 * (brk[1:] + brk[:-1]), 0.5 * np.diff(brk)
        seg = (speed(mid[:, None] + half[:, None] * gx[None]) @ gw) * half
        sb = np.concatenate([[0.0], np.cumsum(seg)])
        length = float(sb[-1])
        _check_length(name, length)
        # knots: every breakpoint of the spline (where its third derivative jumps), and
        # equal steps of at most SPACING between them
        pieces = np.maximum(1, np.ceil(np.diff(sb) / SPACING)).astype(int)
        frac = np.concatenate([np.arange(m) / m for m in pieces])
        j_of = np.repeat(np.arange(len(pieces)), pieces)
        s_k = np.concatenate([sb[j_of] + frac * np.diff(sb)[j_of], [length]])
        u_lin = np.concatenate([brk[j_of] + frac * np.diff(brk)[j_of], [U]])

        def arc(uu):
            j = np.clip(np.searchsorted(brk, uu, side="right") - 1, 0, len(brk) - 2)
            m, hh = 0.5 * (uu + brk[j]), 0.5 * (uu - brk[j])
            return sb[j] + (speed(m[:, None] + hh[:, None] * gx[None]) @ gw) * hh

        u_k = u_lin
        exact = np.concatenate([frac == 0, [True]])  # the breakpoints themselves
        for _ in range(5):
            u_k = np.where(exact, u_k, np.clip(u_k - (arc(u_k) - s_k) / speed(u_k), 0.0, U))
        p = np.asarray(splev(u_k, tck)).T
        d1 = np.asarray(splev(u_k, tck, der=1)).T
        d2 = np.asarray(splev(u_k, tck, der=2)).T
        v = np.hypot(d1[:, 0], d1[:, 1])
        tan = d1 / v[:, None]
        kappa = (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / v**3
        acc = kappa[:, None] * np.stack([-tan[:, 1], tan[:, 0]], axis=-1)
        w = np.stack([arrs["width_right"], arrs["width_left"]], axis=-1)
        if closed:
            w = np.concatenate([w, w[:1]])
            wspl = CubicSpline(u, w, bc_type="periodic")
        else:
            wspl = CubicSpline(u, w)
        widths = wspl(u_k)
        slopes = wspl(u_k, 1) / v[:, None]
        if closed:  # exactly periodic
            p[-1], tan[-1], acc[-1] = p[0], tan[0], acc[0]
            widths[-1], slopes[-1] = widths[0], slopes[0]
        road = _assemble(name, closed, s_k, p, tan, acc[:-1], acc[1:], widths, slopes)
        return road.with_gates(start, end)

    @classmethod
    def from_segments(cls, segments: Sequence[tuple], width, *, start_heading: float = 0.0,
                      start=(0.0, 0.0), name: str = "road",
                      closed: bool = False) -> CentrelineRoad:
        r"""A road built from pieces, in order from ``start`` [m] heading ``start_heading``
        [rad]:

        - ``("straight", length)``: $\kappa = 0$;
        - ``("arc", radius, angle_deg)``: $\kappa = \pm 1/R$ over $R|\alpha|$, the angle in
          degrees, positive turning left;
        - ``("clothoid", length, end_curvature)``: $\kappa$ linear in $s$ from the curvature
          where the previous piece ended (0 for the first) to ``end_curvature`` [1/m].

        ``width``: the full width [m] (the centre line in the middle), or a pair
        ``(width_right, width_left)``. Positions are the exact integrals of the piecewise
        curvature (closed form on straights and arcs, Gauss-Legendre on clothoids). A closed
        road must end where it starts, with the same heading (mod $2\pi$). The gates are the
        default ones (`with_gates` sets others).
        """
        if not (is_numeric(width) and np.shape(width) in ((), (2,))):
            raise ValueError(f"road {name!r}: width must be a number or a pair (width_right, "
                             f"width_left) [m], got {width!r}")
        if np.ndim(width) == 0:
            wr = wl = 0.5 * float(width)
        else:
            wr, wl = (float(v) for v in width)
        for key, v in (("width_right", wr), ("width_left", wl)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"road {name!r}: {key} must be > 0 m, got {v:g}")
        if len(segments) == 0:
            raise ValueError(f"road {name!r}: no segments")
        gx, gw = np.polynomial.legendre.leggauss(10)
        th0 = float(start_heading)
        p0 = np.asarray(start, float)
        if not (math.isfinite(th0) and p0.shape == (2,) and np.all(np.isfinite(p0))):
            raise ValueError(f"road {name!r}: start must be a finite point (x, y) [m] and "
                             f"start_heading a finite angle [rad], got {start!r}, "
                             f"{start_heading!r}")
        k_prev = 0.0
        s_all, p_all, th_all, kl_all, kr_all = [0.0], [p0], [th0], [], []
        s0 = 0.0
        forms = {"straight": "('straight', length)", "arc": "('arc', radius, angle_deg)",
                 "clothoid": "('clothoid', length, end_curvature)"}
        for idx, seg in enumerate(segments):
            kind = seg[0] if isinstance(seg, tuple | list) and len(seg) else seg
            if kind in forms and len(seg) != forms[kind].count(",") + 1:
                raise ValueError(f"road {name!r}: segment {idx} must be {forms[kind]}, got "
                                 f"{tuple(seg)!r}")
            if kind in forms and not all(is_numeric(v) and np.ndim(v) == 0 for v in seg[1:]):
                raise ValueError(f"road {name!r}: segment {idx} must be {forms[kind]} with "
                                 f"numbers, got {tuple(seg)!r}")
            if kind == "straight":
                (length,) = seg[1:]
                k_a = k_b = 0.0
            elif kind == "arc":
                radius, angle = (float(v) for v in seg[1:])
                if not (radius > 0 and math.isfinite(radius)):
                    raise ValueError(f"road {name!r}: segment {idx} ({kind}): radius must be "
                                     f"> 0 m, got {radius:g}")
                length = radius * abs(math.radians(angle))
                k_a = k_b = math.copysign(1.0 / radius, angle)
            elif kind == "clothoid":
                length, k_b = (float(v) for v in seg[1:])
                if not math.isfinite(k_b):
                    raise ValueError(f"road {name!r}: segment {idx} ({kind}): end_curvature "
                                     f"must be finite [1/m], got {k_b:g}")
                k_a = k_prev
            else:
                raise ValueError(f"road {name!r}: segment {idx}: unknown kind {kind!r}; "
                                 "known: 'straight', 'arc', 'clothoid'")
            length = float(length)
            if not (math.isfinite(length) and length > 0):
                raise ValueError(f"road {name!r}: segment {idx} ({kind}) has length "
                                 f"{length:g} m; must be > 0")
            if s0 + length > LENGTH_RANGE[1]:  # before its points are laid out
                _check_length(name, s0 + length, f" at segment {idx}")
            n = max(1, int(math.ceil(length / SPACING)))
            tt = np.linspace(0.0, length, n + 1)
            dk = (k_b - k_a) / length
            th = th0 + k_a * tt + 0.5 * dk * tt**2
            if kind == "clothoid":
                mids, halves = 0.5 * (tt[1:] + tt[:-1]), 0.5 * np.diff(tt)
                sg = mids[:, None] + halves[:, None] * gx[None]
                ang = th0 + k_a * sg + 0.5 * dk * sg**2
                inc = np.stack([np.cos(ang) @ gw, np.sin(ang) @ gw], axis=-1) * halves[:, None]
                pts = p0 + np.concatenate([np.zeros((1, 2)), np.cumsum(inc, axis=0)])
            elif k_a == 0.0:
                pts = p0 + tt[:, None] * np.array([math.cos(th0), math.sin(th0)])
            else:
                pts = p0 + np.stack([np.sin(th) - math.sin(th0),
                                     -(np.cos(th) - math.cos(th0))], axis=-1) / k_a
            kap = k_a + dk * tt
            s_all += list(s0 + tt[1:])
            p_all += list(pts[1:])
            th_all += list(th[1:])
            kl_all += list(kap[:-1])  # curvature at each interval's start
            kr_all += list(kap[1:])  # and end
            s0 += length
            p0, th0, k_prev = pts[-1], float(th[-1]), k_b
        _check_length(name, s0)
        s_k = np.asarray(s_all)
        p = np.asarray(p_all)
        th = np.asarray(th_all)
        tan = np.stack([np.cos(th), np.sin(th)], axis=-1)
        nrm = np.stack([-tan[:, 1], tan[:, 0]], axis=-1)
        acc_s = np.asarray(kl_all)[:, None] * nrm[:-1]
        acc_e = np.asarray(kr_all)[:, None] * nrm[1:]
        if closed:
            gap = float(np.hypot(*(p[-1] - p[0])))
            turn = (th[-1] - th[0]) / (2 * math.pi)
            if gap > 1e-6 * max(1.0, s0) or abs(turn - round(turn)) > 1e-9:
                raise ValueError(
                    f"road {name!r}: a closed road must end where it starts with the same "
                    f"heading; it ends {gap:g} m away, turned {math.degrees(th[-1] - th[0]):g} "
                    "deg")
            p[-1] = p[0]
        widths = np.tile([wr, wl], (len(s_k), 1))
        road = _assemble(name, closed, s_k, p, tan, acc_s, acc_e, widths, np.zeros_like(widths))
        return road.with_gates(None, None)

    def with_gates(self, start=None, end=None) -> CentrelineRoad:
        """This road with other gates: each a `Gate`, an arc length [m], a point ``(x, y)``,
        or ``None`` (full width at $s = 0$, resp. $s = L$)."""
        gates = []
        for g, s_default in ((start, 0.0), (end, self.length)):
            if g is None:
                g = Gate.at(self, s_default)
            elif isinstance(g, Gate):
                g = Gate.at(self, g.s, n_min=g.n_min, n_max=g.n_max, speed=g.speed)
            elif np.ndim(g) == 0:
                g = Gate.at(self, float(g))
            else:
                g = Gate.from_point(self, *g)
            gates.append(g)
        return eqx.tree_at(lambda r: (r.start, r.end), self, tuple(gates))


def _nearest(points, q):
    """Index of the nearest of `points` (M, 2) to each query (Q, 2), in chunks."""
    out = np.empty(len(q), int)
    for i0 in range(0, len(q), 256):
        d = ((q[i0:i0 + 256, None, :] - points[None]) ** 2).sum(-1)
        out[i0:i0 + 256] = np.argmin(d, axis=1)
    return out


_BLOCK = 32
"""Polygon sides per bounding box in `_polygon_query`."""


def _polygon_query(q, a, b):
    """For points q (Q, 2) and the polygon of sides a -> b (E, 2): inside by the even-odd
    rule, the distance to the nearest side and its index. Sides are grouped in blocks of
    `_BLOCK` consecutive ones with bounding boxes; only the blocks that can hold the nearest
    side (box distance <= an upper bound) or that a ray from the point to +x can cross are
    looked at."""
    e = len(a)
    nb = -(-e // _BLOCK)
    pad = nb * _BLOCK - e  # degenerate sides at the last vertex: never crossed, never nearer
    a = np.concatenate([a, np.repeat(b[-1:], pad, axis=0)])
    b = np.concatenate([b, np.repeat(b[-1:], pad, axis=0)])
    ab, bb = a.reshape(nb, _BLOCK, 2), b.reshape(nb, _BLOCK, 2)
    lo = np.minimum(ab, bb).min(axis=1)
    hi = np.maximum(ab, bb).max(axis=1)
    nq = len(q)
    inside = np.zeros(nq, bool)
    dist = np.full(nq, np.inf)
    near = np.zeros(nq, int)
    for i0 in range(0, nq, 512):
        qq = q[i0:i0 + 512]
        below, above = lo[None] - qq[:, None], qq[:, None] - hi[None]  # (Q, nb, 2)
        gap = np.maximum(np.maximum(below, above), 0.0)
        lb = np.hypot(gap[..., 0], gap[..., 1])
        first = np.argmin(lb, axis=1)
        upper, _ = _block_nearest(qq, ab[first], bb[first])
        qi, bi = np.nonzero(lb <= upper[:, None])
        d, j = _block_nearest(qq[qi], ab[bi], bb[bi])
        order = np.lexsort((d, qi))
        keep = order[np.r_[True, qi[order][1:] != qi[order][:-1]]]
        dist[i0 + qi[keep]] = d[keep]
        near[i0 + qi[keep]] = bi[keep] * _BLOCK + j[keep]
        # even-odd: the blocks spanning the point's y and reaching right of it
        qi, bi = np.nonzero((below[..., 1] <= 0) & (above[..., 1] <= 0) & (above[..., 0] <= 0))
        crossings = _block_crossings(qq[qi], ab[bi], bb[bi])
        inside[i0:i0 + 512] = np.bincount(qi, weights=crossings, minlength=len(qq)) % 2 == 1
    return inside, dist, near


def _block_crossings(q, a, b):
    """Number of sides a -> b (P, n, 2) that the ray from each q (P, 2) to +x crosses."""
    ya, yb, py = a[..., 1], b[..., 1], q[:, None, 1]
    crosses = (ya > py) != (yb > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xi = a[..., 0] + (py - ya) * (b[..., 0] - a[..., 0]) / (yb - ya)
    return np.sum(crosses & (q[:, None, 0] < xi), axis=1)


def _block_nearest(q, a, b):
    """Distance from each q (P, 2) to the nearest of its sides a -> b (P, n, 2), and which."""
    ab = b - a
    ll = np.maximum(np.sum(ab * ab, axis=-1), 1e-300)
    t = np.clip(((q[:, None, :] - a) * ab).sum(-1) / ll, 0.0, 1.0)
    c = a + t[..., None] * ab
    d = np.hypot(q[:, None, 0] - c[..., 0], q[:, None, 1] - c[..., 1])
    j = np.argmin(d, axis=1)
    return d[np.arange(len(q)), j], j


COORDINATE_LIMIT = 1e7
"""Largest centre-line coordinate [m] of a road (10,000 km: a local frame in metres)."""
WIDTH_LIMIT = 1e3
"""Largest width [m] of a road's side."""
CLOSING_GAP = 10.0
"""Largest gap between a closed road's last and first points, in median spacings of its
points: a longer one would be closed by a straight that is in no file."""
LENGTH_RANGE = (5.0, 1e5)
"""Shortest and longest centre line [m] of a road from points: longer than a car, and at
most 100 km (the knots, every `SPACING`, number 200,000 there; the longest rally stages
and circuits are a few tens of kilometres)."""


def _segments_cross(p1, p2, q1, q2):
    """Whether segments p1-p2 and q1-q2 intersect (and where, as fractions along each), a
    crossing at or a rounding error beyond an end included (a centre line that passes again
    through one of its knots). The arguments broadcast: (2,) or (N, 2) each."""
    r = p2 - p1
    sv = q2 - q1
    den = r[..., 0] * sv[..., 1] - r[..., 1] * sv[..., 0]
    qp = q1 - p1
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t = (qp[..., 0] * sv[..., 1] - qp[..., 1] * sv[..., 0]) / den
        u = (qp[..., 0] * r[..., 1] - qp[..., 1] * r[..., 0]) / den
    tol = 1e-9
    hit = ((np.abs(den) > 1e-15) & (t >= -tol) & (t <= 1 + tol) & (u >= -tol)
           & (u <= 1 + tol))
    # parallel segments on one line that overlap (a centre line doubling back on itself)
    rr = np.sum(r * r, axis=-1)
    off_line = (np.abs(qp[..., 0] * r[..., 1] - qp[..., 1] * r[..., 0])
                / np.maximum(np.sqrt(rr), 1e-300))
    a0, a1 = np.sum(qp * r, axis=-1) / rr, np.sum((q2 - p1) * r, axis=-1) / rr
    overlap = np.minimum(np.maximum(a0, a1), 1.0) - np.maximum(np.minimum(a0, a1), 0.0)
    along = (np.abs(den) <= 1e-15) & (off_line <= tol * (1.0 + np.sqrt(rr))) & (overlap > tol)
    t = np.where(along, np.clip(np.maximum(np.minimum(a0, a1), 0.0), 0.0, 1.0), t)
    u = np.where(along, 0.0, u)
    return hit | along, np.clip(t, 0.0, 1.0), np.clip(u, 0.0, 1.0)


def _crossing(points: np.ndarray, closed: bool) -> tuple[int, int, float, float] | None:
    """The first crossing (in the order of the first segment, then the second) of two
    segments of the polyline through ``points`` that are not neighbours, as the segments'
    indices and the fractions along each, or None. Every segment is tested against those
    that share a cell of a grid as fine as the longest segment (a crossing lies in a cell
    both segments' bounding boxes touch), so a long road is checked at its knots' resolution
    in time about linear in their number."""
    a, b = points[:-1], points[1:]
    n = len(a)
    h = float(np.max(np.linalg.norm(b - a, axis=1)))
    lo = np.minimum(a, b) - 1e-6 * h
    hi = np.maximum(a, b) + 1e-6 * h
    origin = lo.min(axis=0)
    c0 = np.floor((lo - origin) / h).astype(np.int64)
    c1 = np.floor((hi - origin) / h).astype(np.int64)  # at most 2 cells apart on each axis
    ny = int(c1[:, 1].max()) + 1
    seg, key = [], []
    for dx in range(3):
        for dy in range(3):
            cx, cy = c0[:, 0] + dx, c0[:, 1] + dy
            ok = (cx <= c1[:, 0]) & (cy <= c1[:, 1])
            seg.append(np.nonzero(ok)[0])
            key.append(cx[ok] * ny + cy[ok])
    seg, key = np.concatenate(seg), np.concatenate(key)
    order = np.lexsort((seg, key))
    seg, key = seg[order], key[order]
    pairs = []
    for d in range(1, len(seg)):  # the entries d apart within a cell, sorted by segment
        same = key[d:] == key[:-d]
        if not same.any():
            break
        pairs.append(np.stack([seg[:-d][same], seg[d:][same]], axis=1))
    if not pairs:
        return None
    i, j = np.unique(np.concatenate(pairs), axis=0).T  # i < j
    keep = (j >= i + 2) & ~(closed & (i == 0) & (j == n - 1))  # neighbours share a knot
    i, j = i[keep], j[keep]
    hit, t, u = _segments_cross(a[i], b[i], a[j], b[j])
    if not hit.any():
        return None
    k = int(np.argmax(hit))  # np.unique sorted the pairs by i, then j
    return int(i[k]), int(j[k]), float(t[k]), float(u[k])


def _assemble(name, closed, s_k, p, tan, acc_s, acc_e, widths, slopes) -> CentrelineRoad:
    """The road from its knots, validated (folds, self-intersection), default gates."""
    th = np.unwrap(np.arctan2(tan[:, 1], tan[:, 0]))
    length = float(s_k[-1])
    gate0 = Gate(s=0.0, n_min=-float(widths[0, 0]), n_max=float(widths[0, 1]))
    gate1 = Gate(s=length, n_min=-float(widths[-1, 0]), n_max=float(widths[-1, 1]))
    road = CentrelineRoad(name=name, closed=bool(closed), length=length, knots=s_k, points=p,
                          tangents=tan, accel_start=acc_s, accel_end=acc_e, headings=th,
                          widths=widths, width_slopes=slopes, start=gate0, end=gate1)
    _validate(road)
    return road


def _validate(road: CentrelineRoad) -> None:
    name = road.name
    # widths on a fine grid (the Hermite interpolant may dip between knots)
    s = np.sort(np.concatenate([road.knots, 0.5 * (road.knots[1:] + road.knots[:-1])]))
    wr, wl = road.width_right(s), road.width_left(s)
    for key, w in (("width_right", wr), ("width_left", wl)):
        if np.any(w <= 0):
            i = int(np.argmax(w <= 0))
            raise ValueError(f"road {name!r}: {key} is {w[i]:g} m at s = {s[i]:.6g} m; must "
                             "be > 0 (the widths between the points are a cubic spline "
                             "through theirs, which overshoots where they change abruptly: "
                             "smooth the widths there, or give more points)")
    # the boundary folds where a width reaches the radius of curvature: n kappa >= 1
    kappa = road.curvature(s)
    for key, w, sign, side in (("width_left", wl, 1.0, "left"),
                               ("width_right", wr, -1.0, "right")):
        fold = sign * w * kappa
        if np.any(fold >= _FOLD_MARGIN):
            i = int(np.argmax(fold))
            raise ValueError(
                f"road {name!r}: {key} {w[i]:g} m reaches the radius of curvature "
                f"{1 / abs(kappa[i]):g} m at s = {s[i]:.6g} m (the {side} edge folds over "
                f"itself: n kappa = {fold[i]:.3g} >= 1)")
    # self-intersection of the centre line (the polyline through its knots)
    crossing = _crossing(road.points, road.closed)
    if crossing is not None:
        i, j, t, u = crossing
        sk = road.knots
        s_a = sk[i] + t * (sk[i + 1] - sk[i])
        s_b = sk[j] + u * (sk[j + 1] - sk[j])
        raise ValueError(
            f"road {name!r}: the centre line crosses itself: between s = {sk[i]:.6g} and "
            f"{sk[i + 1]:.6g} m and between s = {sk[j]:.6g} and {sk[j + 1]:.6g} m "
            f"(at s = {round(s_a, 6):.6g} m and s = {round(s_b, 6):.6g} m)")
