r"""Direct multiple shooting of the maneuver problems (docs/maneuvers.md).

Time is the independent variable, scaled by the free final time, $t = \tau t_f$,
$\tau \in [0, 1]$. The horizon is cut into $M$ segments; segment $k$ is integrated by $S$
classical RK4 steps from its knot state. The inputs $(\kappa_F, \kappa_R, \delta)$ are
continuous and piecewise linear in $\tau$: they are carried as states with piecewise-constant
rates $v_k = du/d\tau$ (the NLP controls), which keeps every function local to one segment.
$t_f$ is carried as a state with $dt_f/d\tau = 0$ (so the KKT system stays block banded).

Knot state $X = (x, y, \psi, v_x, v_y, r, \kappa_F, \kappa_R, \delta, t_f)$ (10),
control $v$ (3). The corridor and the axle-speed floor $V_{Fx}, V_{Rx} \ge 1$ m/s hold at
every RK4 node ($M S + 1$ nodes, uniform in $\tau$), the input bounds at the knots (the inputs
are linear in between).

Between the nodes the path is not constrained, and a chord between two nodes on either side of
an inner corner (a sharp convex obstacle) cuts it by up to half its length. Two remedies, each
local to a segment:

- *corner clearance* (``corner_clearance``): every inner-corner constraint at both ends of a
  chord $d$ between consecutive nodes (or interior points, below) holds with a margin,
  $\max_i a_i(p) \ge m(d)$, $m(d) = \max_{i,j} \frac{|d\cdot n_i|\,|d\cdot n_j|}
  {|d\cdot n_i| + |d\cdot n_j|}$ over the pairs of half-planes of the corner (unit normals,
  anti-parallel pairs left out: a chord joining them would cross the whole forbidden region).
  If the ends satisfy the same half-plane the chord stays in it; if one end has $a_i \ge m$
  and the other $a_j \ge m$, at a fraction $s$ of the chord $a_i \ge m - s|d\cdot n_i|$ and
  $a_j \ge m - (1-s)|d\cdot n_j|$, so no point of the chord is in the forbidden region
  $\{a_k < 0\ \forall k\}$ (its distance from the road is $\min_k(-a_k)$). The path leaves
  its chord by the sagitta $\kappa |d|^2/8$ only. For a 90 degree corner crossed at 45
  degrees $m = |d|/(2\sqrt2)$, the depth by which such a chord between nodes on the road
  cuts it;
- *interior points* (``interior_points`` $P$): the corridor also at $\theta = j/(P+1)$ of
  every RK4 step, on RK4's continuous extension
  $x(\theta) = x + h\sum_i b_i(\theta) k_i$ (third order, from the four stages already
  computed): $b_1 = \theta - \frac32\theta^2 + \frac23\theta^3$,
  $b_2 = b_3 = \theta^2 - \frac23\theta^3$, $b_4 = -\frac12\theta^2 + \frac23\theta^3$.
"""

from __future__ import annotations

import abc
import math

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._checks import check_nonnegative, check_positive
from .._constants import GRAVITY
from .._fields import array_field
from .._math import safe_hypot
from ..vehicle.reduced import ReducedHalfCar
from .ip import AbstractStagewiseNLP
from .roads import Road


NX = 10
NU = 3
IDX_TF = 9
DELTA_MAX = math.radians(35.0)
KAPPA_MIN, KAPPA_MAX = -0.99, 1.0
SPEED_FLOOR = 1.0
TF_MIN = 0.3


def _check_between(owner: str, corner_clearance, interior_points) -> None:
    if not isinstance(corner_clearance, bool):
        raise TypeError(f"{owner}.corner_clearance must be True or False, got "
                        f"{corner_clearance!r}")
    if not isinstance(interior_points, int) or not 0 <= interior_points <= 8:
        raise ValueError(f"{owner}.interior_points must be an int in [0, 8], got "
                         f"{interior_points!r}")


class AbstractManeuverOCP(AbstractStagewiseNLP):
    """Shared machinery: RK4 segments with nodes, corridor, boundary conditions."""

    # subclasses define: road, num_stages, steps_per_stage (static ints)

    @abc.abstractmethod
    def _rhs(self, X: Array, u: Array) -> Array:
        """dX/dtau of the knot state under control ``u``."""

    @abc.abstractmethod
    def final_time(self, x):
        """t_f [s] carried by the knot state(s) ``x`` (last axis: the state; a NumPy array
        stays one)."""

    @abc.abstractmethod
    def speed(self, x):
        """Speed [m/s] at the knot state(s) ``x`` (last axis: the state)."""

    def transition_and_path(self, x, u, k):
        """One integration gives both the next knot and the node constraints."""
        x_next, nodes, dense = self._segment_points(x, u)
        return x_next, self._path(x, u, nodes, x_next, dense)

    def transition(self, x, u, k):
        return self._segment(x, u, k)[0]

    def path_inequality(self, x, u, k):
        x_next, nodes, dense = self._segment_points(x, u)
        return self._path(x, u, nodes, x_next, dense)

    def _segment_points(self, x, u):
        """The end knot, the S nodes and the (S, P) interior points of one segment."""
        S = self.steps_per_stage
        h = 1.0 / (self.num_stages * S)
        P = self.interior_points
        if P == 0:
            x_next, nodes = _rk4_segment(self._rhs, x, u, h, S)
            return x_next, nodes, None
        thetas = tuple((j + 1) / (P + 1) for j in range(P))
        return _rk4_segment(self._rhs, x, u, h, S, thetas)

    def _corridor_between(self, nodes, x_next, dense, margin=0.0):
        """Corridor constraints that bound the path between the nodes: the corridor at the
        interior points ``dense`` (S, P, nx), and the corner clearance at both ends of every
        chord between consecutive constrained points (nodes and interior points in order, the
        last chord ending at ``x_next``); ``margin`` [m] shrinks both."""
        parts = []
        road = self.road
        n_corners = len(road.corners)
        if self.corner_clearance and n_corners:
            seq = nodes[:, None] if dense is None else jnp.concatenate([nodes[:, None], dense], 1)
            pts = jnp.concatenate([seq[..., :2].reshape(-1, 2), x_next[None, :2]], 0)
            m = _clearance(road.corners, pts[1:] - pts[:-1])
            corner = jax.vmap(lambda p: road.corridor(p[0], p[1])[-n_corners:])
            parts += [corner(pts[:-1]) - m - margin, corner(pts[1:]) - m - margin]
        if dense is not None:
            flat = dense.reshape(-1, dense.shape[-1])
            parts.append(jax.vmap(lambda X: road.corridor(X[0], X[1]))(flat) - margin)
        return jnp.concatenate([p.reshape(-1) for p in parts]) if parts else jnp.zeros((0,))

    def _segment(self, x, u, k):
        """RK4 over one segment; returns the end knot and the states at the S nodes."""
        S = self.steps_per_stage
        h = 1.0 / (self.num_stages * S)
        return _rk4_segment(self._rhs, x, u, h, S)

    def fine_nodes(self, xs, us, substeps: int = 20):
        """The states between the nodes: each segment re-integrated from its knot with
        `substeps` RK4 steps per integration step (M S substeps + 1 states, uniform in
        tau), where the constraints are not imposed. The last state of each segment
        differs from the next knot by the discretisation error of the coarse steps."""
        S = self.steps_per_stage * substeps
        h = 1.0 / (self.num_stages * S)
        _, fine = jax.vmap(lambda x, u: _rk4_segment(self._rhs, x, u, h, S))(xs[:-1], us)
        return jnp.concatenate([fine.reshape(-1, xs.shape[1]), xs[-1:]], 0)


CLEARANCE_SOFTENING = 1e-3
r"""[m]: $|t|$ in the corner clearance is $\sqrt{t^2 + \epsilon^2}$ (smooth, and larger)."""


def _clearance(corners, d):
    """Corner clearance margins (chords, corners) [m] of chords ``d`` (n, 2) (module
    docstring)."""
    out = []
    for planes in corners:
        normals = [(nx_ / math.hypot(nx_, ny_), ny_ / math.hypot(nx_, ny_))
                   for nx_, ny_, _ in planes]
        m = jnp.zeros(d.shape[:1], d.dtype)
        for i, ni in enumerate(normals):
            for nj in normals[i + 1:]:
                if ni[0] * nj[0] + ni[1] * nj[1] < -1.0 + 1e-9:
                    continue
                a, b = (jnp.sqrt((d[:, 0] * n[0] + d[:, 1] * n[1]) ** 2
                                 + CLEARANCE_SOFTENING**2) for n in (ni, nj))
                m = jnp.maximum(m, a * b / (a + b))
        out.append(m)
    return jnp.stack(out, 1)


_RK4_A = (0.0, 0.5, 0.5, 1.0)
_RK4_B = (1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0)


def _rk4_segment(rhs, x, u, h, S, thetas=()):
    """``S`` classical RK4 steps of size ``h``; returns the end state and the S step starts,
    and with interior fractions ``thetas`` (P of them) also the (S, P) states of RK4's
    continuous extension at them (`_dense_weights`).

    Both the steps and the four stages of a step are `lax.scan` loops, so the right-hand
    side is traced (and its second derivatives compiled) once, not 4 S times: compile time
    is dominated by the Hessian of this function. One step (``S = 1``) is taken without the
    outer loop: a loop of one iteration still costs its tracing (each derivative of a scan
    is traced to a fixed point), its compilation and its run time."""
    a = jnp.asarray(_RK4_A)
    if thetas:
        return _rk4_segment_dense(rhs, x, u, h, S, thetas)
    b = jnp.asarray(_RK4_B)

    def step(x, _):
        def stage(carry, ab):
            k_prev, acc = carry
            ai, bi = ab
            k = rhs(x + (ai * h) * k_prev, u)
            return (k, acc + bi * k), None

        (_, acc), _ = jax.lax.scan(stage, (jnp.zeros_like(x), jnp.zeros_like(x)), (a, b))
        return x + h * acc, x

    if S == 1:
        end, start = step(x, None)
        return end, start[None]
    return jax.lax.scan(step, x, None, length=S)


def _dense_weights(theta: float) -> tuple:
    """Weights $b_i(\theta)$ of RK4's third-order continuous extension (module docstring);
    $b_i(1)$ are RK4's weights."""
    t2, t3 = theta * theta, theta**3
    mid = t2 - 2.0 * t3 / 3.0
    return (theta - 1.5 * t2 + 2.0 * t3 / 3.0, mid, mid, -0.5 * t2 + 2.0 * t3 / 3.0)


def _rk4_segment_dense(rhs, x, u, h, S, thetas):
    """`_rk4_segment` with the continuous extension at ``thetas``: one accumulator per
    fraction beside RK4's own, from the same four stages."""
    a = jnp.asarray(_RK4_A)
    w = jnp.asarray([_RK4_B] + [_dense_weights(t) for t in thetas]).T  # (4, 1 + P)

    def step(x, _):
        def stage(carry, aw):
            k_prev, acc = carry
            ai, wi = aw
            k = rhs(x + (ai * h) * k_prev, u)
            return (k, acc + wi[:, None] * k[None, :]), None

        acc0 = jnp.zeros((w.shape[1],) + x.shape, x.dtype)
        (_, acc), _ = jax.lax.scan(stage, (jnp.zeros_like(x), acc0), (a, w))
        return x + h * acc[0], (x, x[None, :] + h * acc[1:])

    end, (starts, dense) = jax.lax.scan(step, x, None, length=S)
    return end, starts, dense


class ManeuverOCP(AbstractManeuverOCP):
    r"""Minimum-time or maximum-exit-speed maneuver of the reduced half-car (eqs. 61-63).

    **Fields:** ``vehicle`` (`ReducedHalfCar`), ``road`` (`Road`), ``objective``
    ('min-time' or 'max-exit'), ``tf_max`` [s] (time budget of max-exit), ``num_stages``
    $M$, ``steps_per_stage`` $S$ (nodes $= MS$), ``rate_weight`` (a small penalty
    $w\int |du/d\tau|^2 d\tau$ on input rates that picks one input history where the cost is
    flat; it moves $t_f$ by far less than the discretisation error); between the nodes
    (module docstring): ``corner_clearance`` (default True) and ``interior_points`` $P$
    (default 0); both off is the corridor at the nodes only.
    """

    vehicle: ReducedHalfCar
    road: Road
    objective: str = eqx.field(static=True, default="min-time")
    tf_max: Array = array_field(default=4.0)
    num_stages: int = eqx.field(static=True, default=50)
    steps_per_stage: int = eqx.field(static=True, default=3)
    rate_weight: Array = array_field(default=1e-5)
    corner_clearance: bool = eqx.field(static=True, default=True)
    interior_points: int = eqx.field(static=True, default=0)
    state_size: int = eqx.field(static=True, default=NX)
    control_size: int = eqx.field(static=True, default=NU)

    def __check_init__(self):
        if self.objective not in ("min-time", "max-exit"):
            raise ValueError(
                f"ManeuverOCP.objective must be 'min-time' or 'max-exit', got {self.objective!r}"
            )
        if self.num_stages < 2 or self.steps_per_stage < 1:
            raise ValueError("ManeuverOCP.num_stages must be >= 2 and steps_per_stage >= 1")
        check_positive("ManeuverOCP", "tf_max", self.tf_max)
        check_nonnegative("ManeuverOCP", "rate_weight", self.rate_weight)
        _check_between(type(self).__name__, self.corner_clearance, self.interior_points)

    def _rhs(self, X, v):
        tf = X[IDX_TF]
        dyn = self.vehicle.f(X[:6], X[6:9])
        return jnp.concatenate([tf * dyn, v, jnp.zeros((1,))])

    def _node_constraints(self, X):
        c = self.road.corridor(X[0], X[1])
        VFx, _, VRx, _ = self.vehicle.axle_velocities(X[:6], X[8])
        return jnp.concatenate([c, jnp.stack([VFx - SPEED_FLOOR, VRx - SPEED_FLOOR])])

    def _input_bounds(self, X):
        kF, kR, d = X[6], X[7], X[8]
        return jnp.stack([
            kF - KAPPA_MIN, KAPPA_MAX - kF, kR - KAPPA_MIN, KAPPA_MAX - kR,
            DELTA_MAX - d, d + DELTA_MAX, X[IDX_TF] - TF_MIN,
        ])

    def _path(self, x, u, nodes, x_next, dense):
        node_c = jax.vmap(self._node_constraints)(nodes).reshape(-1)
        between = self._corridor_between(nodes, x_next, dense)
        return jnp.concatenate([node_c, between, self._input_bounds(x)])

    def stage_cost(self, x, u, k):
        return self.rate_weight * jnp.sum(u * u) / self.num_stages

    def terminal_cost(self, x):
        if self.objective == "min-time":
            return x[IDX_TF]
        return -safe_hypot(x[3], x[4])

    def final_time(self, x):
        return x[..., IDX_TF]

    def speed(self, x):
        return (x[..., 3] ** 2 + x[..., 4] ** 2) ** 0.5

    def initial_equality(self, x):
        return self.road.boundary_equality(self.road.start, x)

    def initial_inequality(self, x):
        return self.road.boundary_inequality(self.road.start, x)

    def terminal_equality(self, x):
        return self.road.boundary_equality(self.road.end, x)

    def terminal_inequality(self, x):
        parts = [self.road.boundary_inequality(self.road.end, x), self._node_constraints(x),
                 self._input_bounds(x)]
        if self.objective == "max-exit":
            parts.append(jnp.reshape(self.tf_max - x[IDX_TF], (1,)))
        return jnp.concatenate(parts)

    def nodes(self, xs, us):
        """All integration nodes (M S + 1, 10) of a knot/control trajectory."""
        _, nodes = jax.vmap(self._segment)(xs[:-1], us, jnp.arange(self.num_stages))
        return jnp.concatenate([nodes.reshape(-1, NX), xs[-1:]], 0)


class PointMassOCP(AbstractManeuverOCP):
    r"""The benchmark's physical lower bound (docs/maneuvers.md): a point mass with
    $|a| \le D g$ through the same corridor and boundary conditions (position and the zero
    inertial velocity component; the heading conditions become "velocity along the heading"). State
    $(x, y, v_x, v_y, t_f)$ (inertial velocity), control $a$ (piecewise constant).
    ``margin`` [m] shrinks the corridor (0 for the bound; > 0 for comfortable initial
    guesses of the car problem); ``corner_clearance``, ``interior_points``: as
    `ManeuverOCP`'s (the margin shrinks them too)."""

    def __check_init__(self):
        if self.objective not in ("min-time", "max-exit"):
            raise ValueError(f"PointMassOCP.objective must be 'min-time' or 'max-exit', got "
                             f"{self.objective!r}")
        check_positive("PointMassOCP", "friction", self.friction)
        check_positive("PointMassOCP", "tf_max", self.tf_max)
        check_nonnegative("PointMassOCP", "margin", self.margin)
        check_nonnegative("PointMassOCP", "rate_weight", self.rate_weight)
        if self.num_stages < 2 or self.steps_per_stage < 1:
            raise ValueError("PointMassOCP.num_stages must be >= 2 and steps_per_stage >= 1")
        _check_between(type(self).__name__, self.corner_clearance, self.interior_points)

    road: Road
    friction: Array = array_field(default=0.52)
    g: Array = array_field(default=GRAVITY)
    objective: str = eqx.field(static=True, default="min-time")
    tf_max: Array = array_field(default=4.0)
    num_stages: int = eqx.field(static=True, default=50)
    steps_per_stage: int = eqx.field(static=True, default=3)
    rate_weight: Array = array_field(default=1e-6)
    margin: Array = array_field(default=0.0)
    corner_clearance: bool = eqx.field(static=True, default=True)
    interior_points: int = eqx.field(static=True, default=0)
    state_size: int = eqx.field(static=True, default=5)
    control_size: int = eqx.field(static=True, default=2)

    def _rhs(self, X, a):
        tf = X[4]
        return jnp.concatenate([tf * X[2:4], tf * a, jnp.zeros((1,))])

    def _path(self, x, u, nodes, x_next, dense):
        c = jax.vmap(lambda X: self.road.corridor(X[0], X[1]) - self.margin)(nodes).reshape(-1)
        between = self._corridor_between(nodes, x_next, dense, self.margin)
        amax = self.friction * self.g
        return jnp.concatenate([c, between, jnp.stack([amax**2 - u @ u, x[4] - 0.1])])

    def stage_cost(self, x, u, k):
        return self.rate_weight * jnp.sum(u * u) / self.num_stages

    def terminal_cost(self, x):
        if self.objective == "min-time":
            return x[4]
        return -safe_hypot(x[2], x[3])

    def final_time(self, x):
        return x[..., 4]

    def speed(self, x):
        return (x[..., 2] ** 2 + x[..., 3] ** 2) ** 0.5

    def _bc(self, bset, x):
        fixed = dict(bset.fixed)
        vals = []
        for n, v in bset.fixed:
            if n in ("x", "y"):
                vals.append(x[{"x": 0, "y": 1}[n]] - v)
        # the inertial velocity component that vanishes: 'x' -> xdot = x[2], 'y' -> ydot = x[3]
        vals.append(x[2] if bset.zero_velocity == "x" else x[3])
        psi = fixed["psi"]
        return jnp.stack(vals), psi

    def _bc_ineq(self, bset, x):
        vals = []
        for n, (lo, hi) in bset.box:
            i = {"x": 0, "y": 1}[n]
            vals += [x[i] - lo, hi - x[i]]
        psi = dict(bset.fixed)["psi"]
        # velocity points along the heading
        vals.append(x[2] * math.cos(psi) + x[3] * math.sin(psi))
        return jnp.stack(vals)

    def initial_equality(self, x):
        return self._bc(self.road.start, x)[0]

    def initial_inequality(self, x):
        return self._bc_ineq(self.road.start, x)

    def terminal_equality(self, x):
        return self._bc(self.road.end, x)[0]

    def terminal_inequality(self, x):
        parts = [self._bc_ineq(self.road.end, x), self.road.corridor(x[0], x[1]) - self.margin]
        if self.objective == "max-exit":
            parts.append(jnp.reshape(self.tf_max - x[4], (1,)))
        return jnp.concatenate(parts)

    def nodes(self, xs, us):
        _, nodes = jax.vmap(self._segment)(xs[:-1], us, jnp.arange(self.num_stages))
        return jnp.concatenate([nodes.reshape(-1, xs.shape[1]), xs[-1:]], 0)
