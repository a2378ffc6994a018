r"""Minimum-time driving on a road given by its centre line: the maneuver problem in the
road's curvilinear (Frenet) frame, with the arc length $s$ of the centre line as the
independent variable (the standard formulation of lap-time optimisation).

A point at arc length $s$ and lateral offset $n$ (left positive) has the Cartesian position
of `road.to_cartesian(s, n)`; the car's heading relative to the road's tangent is $\xi$. With
the body velocities $(v_x, v_y)$ and yaw rate $r$ of the reduced half-car (eqs. 61-63) and the
road's curvature $\kappa(s)$ (left positive),
$$\dot s = \frac{v_x\cos\xi - v_y\sin\xi}{1 - n\kappa(s)},\qquad
  \dot n = v_x\sin\xi + v_y\cos\xi,\qquad \dot\xi = r - \kappa(s)\dot s,$$
$(\dot v_x, \dot v_y, \dot r)$ as eqs. 61-63 (`ReducedHalfCar.f`, the body-rate rows), and
every rate is divided by $\dot s$ to give $dX/ds$; the time is a state with $dt/ds = 1/\dot s$
(`spatial_rhs`).

The grid is uniform, $s_k = kL/M$, except on a road whose curvature jumps (the junctions of
straights and arcs in `CentrelineRoad.from_segments`): there the stages are uniform within
each piece between jumps, with a node on every jump (`stage_edges`), since an RK4 step across
a jump is only first-order accurate (a stage across the 90-degree corner's two junctions was
off by mm where the others are off by um, enough to leave the road in an open-loop replay).
Each stage is integrated by ``steps_per_stage`` classical RK4 steps, with the curvature
sampled from the road at the RK4 points (a step's end from the left of a jump) when the
problem is built (the problem is a module of arrays, batchable, with no spline inside JAX).
The inputs $(\kappa_F, \kappa_R, \delta)$ are states with piecewise-constant rates
$d(\cdot)/ds$ (the NLP controls), as in `ManeuverOCP`. The corridor
$-w_r(s) + m \le n \le w_l(s) - m$ holds at every integration node and at every step's
midpoint, on the cubic Hermite interpolant of $n$ through the two nodes with their slopes
$dn/ds = (1 - n\kappa)\dot n/((1 - n\kappa)\dot s)$:
$n(s_{1/2}) = (n_0 + n_1)/2 + h(n_0' - n_1')/8$.

Boundary conditions from the road's gates: at each end $\xi = 0$, $r = 0$, $\dot n = 0$, $n$
in the gate's interval and the speed fixed where the gate fixes it; $t_0 = 0$. A closed road
(a lap) has periodic conditions instead: the states at $s = L$ equal those at $s = 0$ (except
$t$). The knots then carry a copy of the initial state (constant in $s$; the first knot's
equality sets it, the last knot's equality compares with it), which keeps the Newton system
block banded, as the free final time of `ManeuverOCP`.
"""

from __future__ import annotations

import abc
import dataclasses
import math
import warnings
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._checks import (
    check_count,
    check_integer,
    check_nonnegative,
    check_positive,
    check_range,
    require_float64,
)
from .._constants import GRAVITY
from .._fields import array_field
from .._math import safe_hypot
from .._results import result_name, result_record
from ..vehicle.reduced import ReducedHalfCar
from .ip import AbstractStagewiseNLP, IPOptions, IPSolution, interior_point
from .primitive import AbstractSolvedDrive, run_program
from .shooting import DELTA_MAX, KAPPA_MAX, KAPPA_MIN, SPEED_FLOOR


_RK4_A = (0.0, 0.5, 0.5, 1.0)
_RK4_B = (1.0 / 6.0, 1.0 / 3.0, 1.0 / 3.0, 1.0 / 6.0)
SUBSTEPS = 20
"""RK4 substeps per integration step of the re-integration between the nodes."""
SPEED_CAP = 80.0
"""Largest speed [m/s] of `speed_profile_guess` (on straights the friction allows any)."""


def spatial_rhs(vehicle: ReducedHalfCar, X: Array, rates: Array, kappa: Array) -> Array:
    r"""$dX/ds$ of the car in the road's frame (the equations of the module docstring).

    **Arguments:** ``vehicle`` (`ReducedHalfCar`), the state
    $X = (n, \xi, v_x, v_y, r, \kappa_F, \kappa_R, \delta, t)$ (9), the input rates
    $d(\kappa_F, \kappa_R, \delta)/ds$ (3) and the road's curvature $\kappa(s)$ [1/m].

    $$\dot s = \frac{v_x\cos\xi - v_y\sin\xi}{1 - n\kappa},\quad
      \frac{dn}{ds} = \frac{v_x\sin\xi + v_y\cos\xi}{\dot s},\quad
      \frac{d\xi}{ds} = \frac{r}{\dot s} - \kappa,\quad
      \frac{d(v_x, v_y, r)}{ds} = \frac{f_{3:6}(X)}{\dot s},\quad
      \frac{d(\kappa_F,\kappa_R,\delta)}{ds} = \text{rates},\quad \frac{dt}{ds} = \frac1{\dot s}$$
    with $f$ = `ReducedHalfCar.f` (eqs. 61-63; its rows 3-5 are the body rates, which do not
    depend on the pose). The road's length is the independent variable, so the equations
    are singular where the car makes no progress along it ($\dot s = 0$: standstill, or a
    heading across the road), and give inf/NaN there; the problems built on them keep
    each axle's $v_x$ at least `SPEED_FLOOR` (1 m/s) by a constraint.
    """
    n, xi, vx, vy, r = X[0], X[1], X[2], X[3], X[4]
    inputs = X[5:8]
    body = vehicle.f(jnp.stack([0.0 * n, 0.0 * n, xi, vx, vy, r]), inputs)[3:6]
    sdot = (vx * jnp.cos(xi) - vy * jnp.sin(xi)) / (1.0 - n * kappa)
    ndot = vx * jnp.sin(xi) + vy * jnp.cos(xi)
    inv = 1.0 / sdot
    return jnp.concatenate([jnp.stack([ndot * inv, r * inv - kappa]), body * inv, rates,
                            jnp.reshape(inv, (1,))])


def point_mass_rhs(X: Array, a: Array, kappa: Array) -> Array:
    r"""$dX/ds$ of a point mass in the road's frame: state $X = (n, \xi, V, t)$ ($\xi$ the
    velocity's angle to the tangent), control $a = (a_t, a_n)$ (along and across the
    velocity):
    $\dot s = V\cos\xi/(1 - n\kappa)$, $\dot n = V\sin\xi$, $\dot\xi = a_n/V - \kappa\dot s$,
    $\dot V = a_t$, each divided by $\dot s$."""
    n, xi, V = X[0], X[1], X[2]
    sdot = V * jnp.cos(xi) / (1.0 - n * kappa)
    inv = 1.0 / sdot
    return jnp.stack([V * jnp.sin(xi) * inv, a[1] / V * inv - kappa, a[0] * inv, inv])


def _rk4_steps(rhs: Callable, x, u, h, kappas):
    """RK4 steps of size ``h`` with the curvature at each step's (start, middle, end) in the
    rows of ``kappas`` (S, 3); returns the end state and the S step starts. The four stages
    of a step are a `lax.scan` loop, so the right-hand side is traced (and its second
    derivatives compiled) once (as `vehsim.optimal.shooting`)."""
    a = jnp.asarray(_RK4_A)
    b = jnp.asarray(_RK4_B)

    def step(x, kap):
        kap_stage = jnp.stack([kap[0], kap[1], kap[1], kap[2]])

        def stage(carry, abk):
            k_prev, acc = carry
            ai, bi, ki = abk
            k = rhs(x + (ai * h) * k_prev, u, ki)
            return (k, acc + bi * k), None

        (_, acc), _ = jax.lax.scan(stage, (jnp.zeros_like(x), jnp.zeros_like(x)),
                                   (a, b, kap_stage))
        return x + h * acc, x

    if kappas.shape[0] == 1:
        end, start = step(x, kappas[0])
        return end, start[None]
    return jax.lax.scan(step, x, kappas)


def stage_edges(road, num_stages: int) -> np.ndarray | None:
    """The stage boundaries $s_0 = 0 < \\dots < s_M = L$ with a node on every curvature jump
    (the road's `curvature_jumps`, where it has that method): each piece between jumps
    gets a whole number of equal stages, at least one, in proportion to its length (largest
    remainders). None (the uniform grid) for a road without jumps, or with more pieces than
    stages (then with a warning: the steps across a jump are first-order accurate)."""
    L = float(road.length)
    jumps = np.asarray(road.curvature_jumps() if hasattr(road, "curvature_jumps") else [],
                       float)
    if jumps.size == 0:
        return None
    bounds = np.concatenate([[0.0], jumps, [L]])
    pieces = np.diff(bounds)
    if pieces.size > num_stages:
        warnings.warn(f"road {getattr(road, 'name', '')!r}: its curvature jumps at "
                      f"{jumps.size} knots, more than num_stages={num_stages} stages can "
                      "put a node on; the grid stays uniform, and steps across a jump are "
                      "first-order accurate", stacklevel=3)
        return None
    share = pieces / L * num_stages
    n = np.maximum(1, np.floor(share)).astype(int)
    while n.sum() > num_stages:  # the pieces made one stage long: take from the largest
        n[np.argmax(np.where(n > 1, n - share, -np.inf))] -= 1
    while n.sum() < num_stages:
        n[np.argmax(share - n)] += 1
    edges = [b + p * np.arange(k) / k for b, p, k in zip(bounds[:-1], pieces, n)]
    return np.concatenate([*edges, [L]])


def _step_grid(edges: np.ndarray, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """``(starts, h)``: each of the ``steps`` equal steps of every stage between `edges`
    (M+1,): its start (M, steps) and its size (M,)."""
    h = np.diff(edges) / steps
    return edges[:-1, None] + h[:, None] * np.arange(steps), h


def _rk4_curvature(road, starts: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The road's curvature at the RK4 points of steps ``starts`` (M, S) of sizes ``h``
    (M,) or a scalar: (M, S, 3), a step's end taken from its left."""
    L = float(road.length)
    h = np.broadcast_to(np.asarray(h, float).reshape(-1, 1), starts.shape)
    ends = np.nextafter(starts + h, -np.inf)
    pts = np.clip(np.stack([starts, starts + 0.5 * h, ends], -1), 0.0, L)
    return np.asarray(road.curvature(pts.reshape(-1)), float).reshape(*starts.shape, 3)


def _gate(gate) -> tuple[float, float, float | None]:
    """(lower, upper) lateral bound [m] and the fixed speed (or None) of a road's gate."""
    lo, hi = gate.lateral
    speed = getattr(gate, "speed", None)
    return float(lo), float(hi), None if speed is None else float(speed)


def _road_arrays(road, num_stages: int, steps_per_stage: int, margin: float,
                 edges: np.ndarray | None = None):
    """Curvature at the RK4 points (M, S, 3), corridor bounds at the nodes (M+1, 2) and at the
    steps' midpoints (M, S, 2) as (lower, upper) on n; ``edges``: the stage boundaries
    (`stage_edges`; None: uniform)."""
    M, S = num_stages, steps_per_stage
    L = float(road.length)
    if edges is None:
        h = L / (M * S)
        starts = (np.arange(M * S) * h).reshape(M, S)
        pts = starts[..., None] + np.array([0.0, 0.5, 1.0]) * h
        kap = np.asarray(road.curvature(np.clip(pts, 0.0, L).reshape(-1)), float).reshape(
            M, S, 3)
        node_s = np.linspace(0.0, L, M + 1)
    else:
        starts, h = _step_grid(edges, S)
        kap = _rk4_curvature(road, starts, h)
        h, node_s = h[:, None], edges

    def bounds(s):
        s = np.clip(s, 0.0, L)
        return np.stack([np.asarray(road.width_right(s), float) * -1.0 + margin,
                         np.asarray(road.width_left(s), float) - margin], -1)

    nodes = bounds(node_s)
    mids = bounds((starts + 0.5 * h).reshape(-1)).reshape(M, S, 2)
    if np.any(nodes[:, 0] >= nodes[:, 1]) or np.any(mids[..., 0] >= mids[..., 1]):
        half = 0.5 * min(np.min(nodes[:, 1] - nodes[:, 0]), np.min(mids[..., 1] - mids[..., 0]))
        raise ValueError(f"margin={margin:g} m leaves no road: it must be below half the "
                         f"road's width, {math.floor(1e3 * (half + margin)) / 1e3:g} m where "
                         "it is narrowest")
    return kap, nodes, mids


class AbstractCurvilinearOCP(AbstractStagewiseNLP):
    """Shared machinery of the problems in the road's frame: RK4 stages in $s$ with the
    road's curvature, the corridor at the nodes and between them, the gates or the periodic
    conditions. Subclasses define the physical state (its first two entries are $n$ and
    $\\xi$, its last the time $t$)."""

    # subclasses define the fields: length, curvature, corridor, corridor_mid,
    # corridor_steps, start_lateral, end_lateral, start_speed, end_speed (arrays),
    # start_speed_fixed, end_speed_fixed, num_stages, steps_per_stage, closed, objective
    # (static), tf_max, rate_weight, stage_lengths (None: the uniform grid)

    @property
    @abc.abstractmethod
    def physical_size(self) -> int:
        """Size of the physical state (with $t$, without the periodic copy)."""

    @abc.abstractmethod
    def _rhs(self, X: Array, u: Array, kappa: Array) -> Array:
        """dX/ds of the physical state."""

    @abc.abstractmethod
    def _node_constraints(self, X: Array) -> Array:
        """Inequalities (>= 0) at every node besides the corridor."""

    @abc.abstractmethod
    def speed(self, x):
        """Speed [m/s] at the knot state(s) ``x`` (last axis: the state)."""

    @abc.abstractmethod
    def _gate_equality(self, x: Array, fixed_speed: bool, speed: Array) -> Array:
        """Equalities of a gate (heading, yaw rate, lateral velocity, speed)."""

    @property
    def periodic_size(self) -> int:
        """States compared by the periodic conditions (all but $t$; 0 for an open road)."""
        return self.physical_size - 1 if self.closed else 0

    def linear_variables(self) -> tuple[int, ...]:
        """The time $t$ (it only accumulates $1/\\dot s$ and enters the objective or a bound
        linearly) and a closed road's periodic copy (constant, compared linearly)."""
        p, q = self.physical_size, self.periodic_size
        return (p - 1, *range(p, p + q))

    @property
    def step(self):
        """RK4 step in s [m] of the uniform grid."""
        return self.length / (self.num_stages * self.steps_per_stage)

    def stage_length(self, k):
        """Length [m] of stage ``k`` (its ``steps_per_stage`` RK4 steps together)."""
        if self.stage_lengths is None:
            return self.length / self.num_stages
        return self.stage_lengths[k]

    def stage_step(self, k):
        """RK4 step in s [m] of stage ``k``."""
        if self.stage_lengths is None:
            return self.step
        return self.stage_lengths[k] / self.steps_per_stage

    def stage_edges(self) -> np.ndarray:
        """Arc lengths [m] of the knots (M+1), the stages' boundaries."""
        if self.stage_lengths is None:
            return np.linspace(0.0, float(self.length), self.num_stages + 1)
        return np.concatenate([[0.0], np.cumsum(np.asarray(self.stage_lengths, float))])

    def final_time(self, x):
        """Time [s] at the knot state(s) ``x``."""
        return x[..., self.physical_size - 1]

    def lateral_slope(self, X, kappa):
        r"""$dn/ds$ at the state $X$ where the curvature is $\kappa$."""
        return self._rhs(X, jnp.zeros((self.control_size,)), kappa)[0]

    def _full_rhs(self, X, u, kappa):
        p = self.physical_size
        return jnp.concatenate([self._rhs(X[:p], u, kappa), jnp.zeros((X.shape[0] - p,))])

    def _segment(self, x, u, k):
        return _rk4_steps(self._full_rhs, x, u, self.stage_step(k), self.curvature[k])

    def transition(self, x, u, k):
        return self._segment(x, u, k)[0]

    def transition_and_path(self, x, u, k):
        end, starts = self._segment(x, u, k)
        return end, self._path(x, u, k, starts, end)

    def path_inequality(self, x, u, k):
        end, starts = self._segment(x, u, k)
        return self._path(x, u, k, starts, end)

    def _path(self, x, u, k, starts, end):
        kap = self.curvature[k]  # (S, 3)
        nodes = jnp.concatenate([starts, end[None]], 0)  # (S+1, nx)
        kap_nodes = jnp.concatenate([kap[:, 0], kap[-1:, 2]])
        slope = jax.vmap(self.lateral_slope)(nodes, kap_nodes)
        n = nodes[:, 0]
        h = self.stage_step(k)
        n_mid = 0.5 * (n[:-1] + n[1:]) + h * (slope[:-1] - slope[1:]) / 8.0
        lo_hi = self.corridor_mid[k]  # (S, 2)
        node_lo_hi = jnp.concatenate([self.corridor[k][None], _interior_nodes(self, k)], 0)
        c = jnp.concatenate([
            n[:-1] - node_lo_hi[:, 0], node_lo_hi[:, 1] - n[:-1],
            n_mid - lo_hi[:, 0], lo_hi[:, 1] - n_mid,
        ])
        other = jax.vmap(self._node_constraints)(starts).reshape(-1)
        return jnp.concatenate([c, other, self._control_constraints(x, u)])

    def _control_constraints(self, x, u):
        return jnp.zeros((0,))

    def _terminal_node(self, x):
        lo, hi = self.corridor[-1, 0], self.corridor[-1, 1]
        return jnp.concatenate([jnp.stack([x[0] - lo, hi - x[0]]), self._node_constraints(x)])

    def initial_equality(self, x):
        p, q = self.physical_size, self.periodic_size
        t0 = jnp.reshape(x[p - 1], (1,))
        if self.closed:
            return jnp.concatenate([t0, x[p:p + q] - x[:q]])
        return jnp.concatenate([t0, self._gate_equality(x, self.start_speed_fixed,
                                                        self.start_speed)])

    def initial_inequality(self, x):
        if self.closed:
            return jnp.zeros((0,))
        return jnp.stack([x[0] - self.start_lateral[0], self.start_lateral[1] - x[0]])

    def terminal_equality(self, x):
        p, q = self.physical_size, self.periodic_size
        if self.closed:
            return x[:q] - x[p:p + q]
        return self._gate_equality(x, self.end_speed_fixed, self.end_speed)

    def terminal_inequality(self, x):
        parts = [self._terminal_node(x)]
        if not self.closed:
            parts.append(jnp.stack([x[0] - self.end_lateral[0], self.end_lateral[1] - x[0]]))
        if self.objective == "max-exit":
            parts.append(jnp.reshape(self.tf_max - self.final_time(x), (1,)))
        return jnp.concatenate(parts)

    def terminal_cost(self, x):
        if self.objective == "min-time":
            return self.final_time(x)
        return -self.speed(x)

    def nodes(self, xs, us):
        """Knot states at every integration node (M S + 1, nx), at `node_positions`."""
        _, starts = jax.vmap(self._segment)(xs[:-1], us, jnp.arange(self.num_stages))
        return jnp.concatenate([starts.reshape(-1, xs.shape[1]), xs[-1:]], 0)

    def fine_nodes(self, xs, us, fine_curvature):
        """Every stage re-integrated from its knot with the finer steps whose curvature is
        ``fine_curvature`` (M, S', 3) (`fine_curvature` of the road): (M S' + 1, nx) states,
        equal within each stage; the last state of each stage differs from the next knot by
        the discretisation error of the coarse steps."""
        Sf = fine_curvature.shape[1]
        if self.stage_lengths is None:
            h = self.length / (self.num_stages * Sf)
            _, fine = jax.vmap(lambda x, u, kap: _rk4_steps(self._full_rhs, x, u, h, kap))(
                xs[:-1], us, fine_curvature)
        else:
            _, fine = jax.vmap(lambda x, u, kap, h: _rk4_steps(self._full_rhs, x, u, h, kap))(
                xs[:-1], us, fine_curvature, self.stage_lengths / Sf)
        return jnp.concatenate([fine.reshape(-1, xs.shape[1]), xs[-1:]], 0)

    def node_positions(self, steps: int | None = None) -> np.ndarray:
        """Arc lengths [m] of the integration nodes (M S + 1), or of ``steps`` equal steps
        per stage."""
        S = self.steps_per_stage if steps is None else steps
        if self.stage_lengths is None:
            return np.linspace(0.0, float(self.length), self.num_stages * S + 1)
        edges = self.stage_edges()
        starts, _ = _step_grid(edges, S)
        return np.concatenate([starts.reshape(-1), edges[-1:]])


def _interior_nodes(prob, k):
    """Corridor bounds at the step starts after the first of stage ``k`` (S-1, 2; none for
    one step per stage)."""
    S = prob.steps_per_stage
    if S == 1:
        return jnp.zeros((0, 2))
    return prob.corridor_steps[k]


def fine_curvature(road, num_stages: int, substeps: int,
                   edges: np.ndarray | None = None) -> np.ndarray:
    """The road's curvature at the RK4 points of ``substeps`` equal steps per stage
    (M, substeps, 3); ``edges``: the stage boundaries (None: uniform)."""
    if edges is not None:
        return _rk4_curvature(road, *_step_grid(edges, substeps))
    L = float(road.length)
    h = L / (num_stages * substeps)
    starts = (np.arange(num_stages * substeps) * h).reshape(num_stages, substeps)
    pts = np.clip(starts[..., None] + np.array([0.0, 0.5, 1.0]) * h, 0.0, L)
    return np.asarray(road.curvature(pts.reshape(-1)), float).reshape(num_stages, substeps, 3)


def _require_centreline(owner: str, road,
                        needs=("length", "curvature", "width_left", "width_right")) -> None:
    """Refuse a road that is not a centre-line road, without what `owner` `needs` (a `Road`
    of rectangular legs has no arc length or curvature)."""
    missing = [a for a in needs if not hasattr(road, a)]
    if missing:
        raise TypeError(f"{owner} needs a centre-line road (a CentrelineRoad: "
                        f"{', '.join(missing)}), got {type(road).__name__}")


def _check_problem_settings(owner: str, num_stages, steps_per_stage, margin, tf_max,
                            rate_weight) -> None:
    """The settings of `from_road`: whole stage counts, a finite margin >= 0, a time budget
    > 0 and a rate weight >= 0."""
    check_count(owner, "num_stages", num_stages, lower=2)
    check_count(owner, "steps_per_stage", steps_per_stage)
    check_nonnegative(owner, "margin", margin)
    check_positive(owner, "tf_max", tf_max)
    check_nonnegative(owner, "rate_weight", rate_weight)


def _check_road(road) -> None:
    """What the road-frame problem can pose: float64, an open road's gates at its ends, a
    closed road's full width and free speed, and a fixed gate speed above the floor."""
    _require_centreline("the road-frame problem", road)
    require_float64("the road-frame problem",
                    "In float32 its solves stall (the residual stays near 0.4)")
    name = getattr(road, "name", "")
    L = float(road.length)
    closed = bool(getattr(road, "closed", False))
    for which, gate, at in (("start", road.start, 0.0), ("end", road.end, L)):
        s_gate = getattr(gate, "s", at)
        if not closed and abs(float(s_gate) - at) > 1e-9 * max(1.0, L):
            raise ValueError(
                f"road {name!r}: the {which} gate is at s = {float(s_gate):g} m; the "
                f"road-frame problem runs from s = 0 to s = L = {L:g} m, so its {which} "
                f"gate must be at s = {at:g} m (build the road from its points between the "
                "gates instead)")
        speed = getattr(gate, "speed", None)
        if closed and (speed is not None or tuple(map(float, gate.lateral)) != (
                -float(road.width_right(at)), float(road.width_left(at)))):
            raise ValueError(
                f"road {name!r}: a closed road's lap is periodic, so its {which} gate must be "
                "the full width with the speed free (got lateral "
                f"{tuple(map(float, gate.lateral))} m, speed {speed})")
        if speed is not None and float(speed) < SPEED_FLOOR:
            raise ValueError(
                f"road {name!r}: the {which} gate's speed must be at least {SPEED_FLOOR:g} m/s "
                f"(the speed floor of the road-frame problem, whose time is the integral of "
                f"ds/s-dot: a standing start cannot be posed), got {float(speed):g}")


def _common_fields(road, num_stages, steps_per_stage, margin):
    """The road's arrays as problem fields."""
    if num_stages < 2 or steps_per_stage < 1:
        raise ValueError("num_stages must be >= 2 and steps_per_stage >= 1, got "
                         f"{num_stages} and {steps_per_stage}")
    _check_road(road)
    edges = stage_edges(road, num_stages)
    kap, nodes, mids = _road_arrays(road, num_stages, steps_per_stage, margin, edges)
    S = steps_per_stage
    L = float(road.length)
    if edges is None:
        h = L / (num_stages * S)
        s_steps = (np.arange(num_stages * S) * h).reshape(num_stages, S)[:, 1:]
    else:
        s_steps = _step_grid(edges, S)[0][:, 1:]
    steps = np.stack([np.asarray(road.width_right(s_steps.reshape(-1)), float) * -1.0 + margin,
                      np.asarray(road.width_left(s_steps.reshape(-1)), float) - margin],
                     -1).reshape(num_stages, S - 1, 2)
    closed = bool(getattr(road, "closed", False))
    fields = dict(length=jnp.asarray(L), curvature=jnp.asarray(kap), corridor=jnp.asarray(nodes),
                  corridor_mid=jnp.asarray(mids), corridor_steps=jnp.asarray(steps),
                  num_stages=num_stages, steps_per_stage=steps_per_stage, closed=closed,
                  stage_lengths=None if edges is None else jnp.asarray(np.diff(edges)))
    if closed:
        fields.update(start_lateral=jnp.zeros(2), end_lateral=jnp.zeros(2),
                      start_speed=jnp.asarray(0.0), end_speed=jnp.asarray(0.0),
                      start_speed_fixed=False, end_speed_fixed=False)
    else:
        lo0, hi0, v0 = _gate(road.start)
        lo1, hi1, v1 = _gate(road.end)
        fields.update(start_lateral=jnp.asarray([lo0, hi0]), end_lateral=jnp.asarray([lo1, hi1]),
                      start_speed=jnp.asarray(0.0 if v0 is None else v0),
                      end_speed=jnp.asarray(0.0 if v1 is None else v1),
                      start_speed_fixed=v0 is not None, end_speed_fixed=v1 is not None)
    return fields


def _rate_penalty(prob, u, k):
    """$w\\,\\Delta s_k|u|^2$, the stage's share of the rate penalty (on the uniform grid in
    the arithmetic of $wL/M$)."""
    if prob.stage_lengths is None:
        return prob.rate_weight * prob.length / prob.num_stages * jnp.sum(u * u)
    return prob.rate_weight * prob.stage_lengths[k] * jnp.sum(u * u)


def _check_objective(objective: str) -> None:
    if objective not in ("min-time", "max-exit"):
        raise ValueError(f"objective must be 'min-time' or 'max-exit', got {objective!r}")


class CurvilinearManeuverOCP(AbstractCurvilinearOCP):
    r"""Minimum-time or maximum-exit-speed drive of the reduced half-car (eqs. 61-63) along a
    road given by its centre line, with the arc length as the independent variable (module
    docstring, `spatial_rhs`).

    Knot state $X = (n, \xi, v_x, v_y, r, \kappa_F, \kappa_R, \delta, t)$ (9; a closed road
    adds the copy of the first 8 at $s = 0$), control $d(\kappa_F, \kappa_R, \delta)/ds$ (3).
    Build it with `CurvilinearManeuverOCP.from_road`. **Fields:** ``vehicle``, ``length``
    $L$ [m], ``curvature`` at the RK4 points (M, S, 3), ``corridor`` (lower, upper) bounds on
    $n$ at the knots (M+1, 2), ``corridor_mid`` at the steps' midpoints (M, S, 2),
    ``corridor_steps`` at the steps' starts inside a stage (M, S-1, 2), the gates'
    ``start_lateral``/``end_lateral`` intervals and speeds (``start_speed``, used where
    ``start_speed_fixed``), ``objective``, ``tf_max`` [s] (the time budget of max-exit),
    ``rate_weight`` $w$ of the penalty $w\int |du/ds|^2 ds$ [s m] that picks one input history
    where the time is flat, ``num_stages`` $M$, ``steps_per_stage`` $S$, ``closed``,
    ``stage_lengths`` (M,) [m] (None: the uniform grid; module docstring).
    """

    vehicle: ReducedHalfCar
    length: Array
    curvature: Array
    corridor: Array
    corridor_mid: Array
    corridor_steps: Array
    start_lateral: Array
    end_lateral: Array
    start_speed: Array
    end_speed: Array
    start_speed_fixed: bool = eqx.field(static=True)
    end_speed_fixed: bool = eqx.field(static=True)
    num_stages: int = eqx.field(static=True)
    steps_per_stage: int = eqx.field(static=True)
    closed: bool = eqx.field(static=True)
    objective: str = eqx.field(static=True, default="min-time")
    tf_max: Array = array_field(default=60.0)
    rate_weight: Array = array_field(default=1e-4)
    control_size: int = eqx.field(static=True, default=3)
    stage_lengths: Array | None = None

    def __check_init__(self):
        _check_objective(self.objective)

    @classmethod
    def from_road(cls, road, vehicle: ReducedHalfCar, *, objective: str = "min-time",
                  num_stages: int = 100, steps_per_stage: int = 1, margin: float = 0.0,
                  tf_max: float = 60.0, rate_weight: float = 1e-4) -> CurvilinearManeuverOCP:
        """The problem on ``road`` (a centre-line road: `curvature`, `width_left`,
        `width_right`, `length`, `closed`, gates `start`/`end`, and where its curvature
        jumps, `curvature_jumps`: the knots then include each jump, `stage_edges`), its
        arrays sampled with NumPy; ``margin`` [m] narrows the corridor on each side."""
        _check_objective(objective)
        _check_problem_settings(cls.__name__, num_stages, steps_per_stage, margin, tf_max,
                                rate_weight)
        return cls(vehicle=vehicle, objective=objective, tf_max=tf_max,
                   rate_weight=rate_weight,
                   **_common_fields(road, num_stages, steps_per_stage, margin))

    @property
    def physical_size(self) -> int:
        return 9

    @property
    def state_size(self) -> int:
        return 17 if self.closed else 9

    def _rhs(self, X, u, kappa):
        return spatial_rhs(self.vehicle, X, u, kappa)

    def lateral_slope(self, X, kappa):
        n, xi, vx, vy = X[0], X[1], X[2], X[3]
        return (1.0 - n * kappa) * (vx * jnp.sin(xi) + vy * jnp.cos(xi)) / (
            vx * jnp.cos(xi) - vy * jnp.sin(xi))

    def _node_constraints(self, X):
        kF, kR, d = X[5], X[6], X[7]
        VFx, _, VRx, _ = self.vehicle.axle_velocities(jnp.concatenate([X[:1] * 0, X[:1] * 0,
                                                                       X[1:5]]), d)
        return jnp.stack([VFx - SPEED_FLOOR, VRx - SPEED_FLOOR,
                          kF - KAPPA_MIN, KAPPA_MAX - kF, kR - KAPPA_MIN, KAPPA_MAX - kR,
                          DELTA_MAX - d, d + DELTA_MAX])

    def _gate_equality(self, x, fixed_speed, speed):
        xi, vx, vy = x[1], x[2], x[3]
        parts = [xi, x[4], vx * jnp.sin(xi) + vy * jnp.cos(xi)]
        if fixed_speed:
            parts.append(vx - speed)
        return jnp.stack(parts)

    def stage_cost(self, x, u, k):
        return _rate_penalty(self, u, k)

    def speed(self, x):
        return safe_hypot(x[..., 2], x[..., 3])


class CurvilinearPointMassOCP(AbstractCurvilinearOCP):
    r"""The physical bound in the road's frame: a point mass with $|a| \le Dg$ along the same
    corridor and gates (`point_mass_rhs`). State $(n, \xi, V, t)$ (a closed road adds the
    copy of $(n, \xi, V)$ at $s = 0$), control $(a_t, a_n)$ (piecewise constant); the gates'
    heading condition is $\xi = 0$ (velocity along the road), the speed floor $V \ge 1$ m/s.
    Build it with `CurvilinearPointMassOCP.from_road`; fields as `CurvilinearManeuverOCP`,
    with ``friction`` $D$ and ``g`` instead of the vehicle."""

    length: Array
    curvature: Array
    corridor: Array
    corridor_mid: Array
    corridor_steps: Array
    start_lateral: Array
    end_lateral: Array
    start_speed: Array
    end_speed: Array
    start_speed_fixed: bool = eqx.field(static=True)
    end_speed_fixed: bool = eqx.field(static=True)
    num_stages: int = eqx.field(static=True)
    steps_per_stage: int = eqx.field(static=True)
    closed: bool = eqx.field(static=True)
    friction: Array = array_field(default=0.52)
    g: Array = array_field(default=GRAVITY)
    objective: str = eqx.field(static=True, default="min-time")
    tf_max: Array = array_field(default=60.0)
    rate_weight: Array = array_field(default=1e-6)
    control_size: int = eqx.field(static=True, default=2)
    stage_lengths: Array | None = None

    def __check_init__(self):
        _check_objective(self.objective)
        check_positive(type(self).__name__, "friction", self.friction)

    @classmethod
    def from_road(cls, road, *, friction: float = 0.52, objective: str = "min-time",
                  num_stages: int = 100, steps_per_stage: int = 1, margin: float = 0.0,
                  tf_max: float = 60.0, rate_weight: float = 1e-6) -> CurvilinearPointMassOCP:
        """The point-mass problem on ``road`` (as `CurvilinearManeuverOCP.from_road`)."""
        _check_objective(objective)
        _check_problem_settings(cls.__name__, num_stages, steps_per_stage, margin, tf_max,
                                rate_weight)
        return cls(friction=friction, objective=objective, tf_max=tf_max,
                   rate_weight=rate_weight,
                   **_common_fields(road, num_stages, steps_per_stage, margin))

    @property
    def physical_size(self) -> int:
        return 4

    @property
    def state_size(self) -> int:
        return 7 if self.closed else 4

    def _rhs(self, X, u, kappa):
        return point_mass_rhs(X, u, kappa)

    def lateral_slope(self, X, kappa):
        return (1.0 - X[0] * kappa) * jnp.tan(X[1])

    def _node_constraints(self, X):
        return jnp.reshape(X[2] - SPEED_FLOOR, (1,))

    def _control_constraints(self, x, u):
        amax = self.friction * self.g
        return jnp.reshape(amax**2 - u @ u, (1,))

    def _gate_equality(self, x, fixed_speed, speed):
        parts = [x[1]]
        if fixed_speed:
            parts.append(x[2] - speed)
        return jnp.stack(parts)

    def stage_cost(self, x, u, k):
        return _rate_penalty(self, u, k)

    def speed(self, x):
        return x[..., 2]


# --------------------------------------------------------------------------------------
# starting guess


def _friction(car_or_D) -> tuple[float, float]:
    """(peak friction D, gravity g) of a car or of a friction coefficient."""
    if isinstance(car_or_D, ReducedHalfCar):
        return float(car_or_D.tire.D), float(car_or_D.params.g)
    return float(car_or_D), GRAVITY


def speed_profile(road, D: float, fraction: float = 0.8, *, g: float = GRAVITY,
                  points: int = 2000, start_speed: float | None = None):
    r"""The quasi-steady friction-limited speed of a point mass on the centre line at
    ``points`` + 1 uniform arc lengths: $v \le \sqrt{fDg/|\kappa|}$ (at most `SPEED_CAP`),
    then a forward pass accelerating and a backward pass braking with the friction left,
    $dv^2/ds = \pm 2\sqrt{(fDg)^2 - (v^2\kappa)^2}$. The start speed is the gate's if it
    fixes one (``start_speed`` overrides); a closed road is periodic (three laps, the middle
    one kept). **Returns:** (s, v)."""
    _require_centreline("speed_profile", road, ("length", "curvature"))
    check_positive("speed_profile", "g", g)
    L = float(road.length)
    closed = bool(getattr(road, "closed", False))
    laps = 3 if closed else 1
    check_positive("speed_profile", "D", D)
    check_range("speed_profile", "fraction", fraction, lower=0.0, upper=1.0, lower_open=True)
    check_integer("speed_profile", "points", points, lower=1)
    if start_speed is not None:
        check_nonnegative("speed_profile", "start_speed", start_speed)
    s = np.linspace(0.0, L, points + 1)
    ds = L / points
    s_all = (s[:-1][None] + L * np.arange(laps)[:, None]).reshape(-1) if closed else s
    kap = np.asarray(road.curvature(np.mod(s_all, L) if closed else s_all), float)
    a = fraction * D * g
    vlim = np.minimum(np.sqrt(a / np.maximum(np.abs(kap), 1e-9)), SPEED_CAP)
    if not closed:
        if start_speed is None:
            start_speed = _gate(road.start)[2]
        if start_speed is not None:
            vlim[0] = min(vlim[0], start_speed)
        end_speed = _gate(road.end)[2]
        if end_speed is not None:
            vlim[-1] = min(vlim[-1], end_speed)
    v = vlim.copy()
    for i in range(len(v) - 1):
        room = np.sqrt(max(a**2 - (v[i] ** 2 * kap[i]) ** 2, 0.0))
        v[i + 1] = min(v[i + 1], math.sqrt(v[i] ** 2 + 2.0 * room * ds))
    for i in range(len(v) - 1, 0, -1):
        room = np.sqrt(max(a**2 - (v[i] ** 2 * kap[i]) ** 2, 0.0))
        v[i - 1] = min(v[i - 1], math.sqrt(v[i] ** 2 + 2.0 * room * ds))
    if closed:
        v = v[points:2 * points + 1]
    return s, v


def speed_profile_guess(road, car: ReducedHalfCar, num_stages: int, fraction: float = 0.8,
                        steps_per_stage: int = 1, edges: np.ndarray | None = None):
    r"""Knots (M+1, 9 or 17) and input rates (M, 3) of `CurvilinearManeuverOCP` on the centre
    line ($n = 0$, $\xi = 0$, $v_y = 0$) at the speed of `speed_profile` with ``fraction`` of
    the tire's peak friction: yaw rate $r = v\kappa$, kinematic steering
    $\delta = \arctan((\ell_F + \ell_R)\kappa)$, equal slips giving the tangential
    acceleration on the tire's curve (within 80 % of the peak), time by integration of
    $1/v$. A closed road's knots carry the first knot's copy. ``edges``: the knots' arc
    lengths (default those of the problem on ``road``, `stage_edges`: uniform unless the
    road's curvature jumps)."""
    check_count("speed_profile_guess", "num_stages", num_stages, sep=": ")
    D, g = _friction(car)
    s_fine, v_fine = speed_profile(road, D, fraction, g=g)
    L = float(road.length)
    edges = stage_edges(road, num_stages) if edges is None else edges
    s = np.linspace(0.0, L, num_stages + 1) if edges is None else np.asarray(edges, float)
    v = np.interp(s, s_fine, v_fine)
    kap = np.asarray(road.curvature(s), float)
    dv2 = np.gradient(v_fine**2, s_fine)
    a_t = 0.5 * np.interp(s, s_fine, dv2)
    t_fine = np.concatenate([[0.0], np.cumsum(np.diff(s_fine) * 0.5 * (
        1.0 / v_fine[1:] + 1.0 / v_fine[:-1]))])
    t = np.interp(s, s_fine, t_fine)
    p = car.params
    wheelbase = float(p.lF + p.lR)
    delta = np.clip(np.arctan(wheelbase * kap), -0.9 * DELTA_MAX, 0.9 * DELTA_MAX)
    tire = car.tire
    mux = np.clip(a_t / g, -0.8 * D, 0.8 * D)
    sl = np.tan(np.arcsin(np.abs(mux) / D) / float(tire.C)) / float(tire.B)
    sx = -np.sign(mux) * sl
    slip = -sx / (1.0 + sx)
    xs = np.stack([0 * s, 0 * s, v, 0 * s, v * kap, slip, slip, delta, t], 1)
    us = np.diff(xs[:, 5:8], axis=0) / (L / num_stages if edges is None else np.diff(s)[:, None])
    if bool(getattr(road, "closed", False)):
        xs = np.concatenate([xs, np.broadcast_to(xs[:1, :8], (num_stages + 1, 8))], 1)
    return jax.device_put(xs), jax.device_put(us)


def point_mass_guess(road, D: float, num_stages: int, fraction: float = 0.8,
                     edges: np.ndarray | None = None):
    """Knots (n = 0, xi = 0, V, t) and accelerations (a_t, a_n) of
    `CurvilinearPointMassOCP` from `speed_profile` (a closed road's knots carry the copy);
    ``edges`` as `speed_profile_guess`."""
    s_fine, v_fine = speed_profile(road, D, fraction)
    L = float(road.length)
    edges = stage_edges(road, num_stages) if edges is None else edges
    s = np.linspace(0.0, L, num_stages + 1) if edges is None else np.asarray(edges, float)
    v = np.interp(s, s_fine, v_fine)
    t_fine = np.concatenate([[0.0], np.cumsum(np.diff(s_fine) * 0.5 * (
        1.0 / v_fine[1:] + 1.0 / v_fine[:-1]))])
    xs = np.stack([0 * s, 0 * s, v, np.interp(s, s_fine, t_fine)], 1)
    sm = 0.5 * (s[1:] + s[:-1])
    vm = np.interp(sm, s_fine, v_fine)
    a_t = 0.5 * np.diff(v**2) / np.diff(s)
    a_n = vm**2 * np.asarray(road.curvature(sm), float)
    us = np.stack([a_t, a_n], 1)
    amax = 0.99 * D * GRAVITY
    scale = np.maximum(np.hypot(us[:, 0], us[:, 1]) / amax, 1.0)
    us = us / scale[:, None]
    if bool(getattr(road, "closed", False)):
        xs = np.concatenate([xs, np.broadcast_to(xs[:1, :3], (num_stages + 1, 3))], 1)
    return jax.device_put(xs), jax.device_put(us)


def _edges_of(prob) -> np.ndarray | None:
    """The stage boundaries of a problem on a non-uniform grid; None on the uniform one."""
    return None if prob.stage_lengths is None else prob.stage_edges()


# --------------------------------------------------------------------------------------
# the solved drive


@eqx.filter_jit
def _nodes(prob, xs, us):
    return prob.nodes(xs, us)


@eqx.filter_jit
def _fine(prob, xs, us, kap):
    return prob.fine_nodes(xs, us, kap)


@eqx.filter_jit
def _defects(prob, xs, us):
    d = xs[1:] - jax.vmap(prob.transition)(xs[:-1], us, jnp.arange(prob.num_stages))
    e = jnp.concatenate([jnp.abs(prob.initial_equality(xs[0])),
                         jnp.abs(prob.terminal_equality(xs[-1])), jnp.zeros(1)])
    return jnp.max(jnp.abs(d)), jnp.max(e)


@eqx.filter_jit
def _car_signals(vehicle, states, inputs) -> dict:
    return jax.vmap(vehicle.signals)(states, inputs)


class RoadPrimitive(AbstractSolvedDrive):
    """A drive solved on a centre-line road: ``problem`` (`CurvilinearManeuverOCP` or
    `CurvilinearPointMassOCP`), its interior-point ``solution`` and the ``road``. The same
    reading as `Primitive`: ``t_f`` [s], ``exit_speed`` [m/s], ``result``, `nodes`, `time`,
    `signals` (with the Cartesian pose), `violations`, and `solution_record`. ``coarse``: the
    solution of `road_primitive`'s coarse solve where it made one (its best iterate where it
    stopped short), and ``started_from_coarse`` whether the fine solve started from it
    (`coarse_start`; None without one) rather than from the speed profile."""

    problem: Any
    solution: IPSolution
    road: Any
    runner: Callable = eqx.field(static=True, default=run_program)
    starts: IPSolution | None = None
    coarse: IPSolution | None = None
    started_from_coarse: bool | None = eqx.field(static=True, default=None)

    def nodes(self):
        """States at every integration node (M S + 1, nx), uniform in s."""
        return self.runner("curvilinear_nodes", _nodes,
                           (self.problem, self.solution.xs, self.solution.us))

    def arc_length(self) -> np.ndarray:
        """s [m] at every node."""
        return self.problem.node_positions()

    def time(self):
        """t [s] at every node (the time state)."""
        return np.asarray(self.problem.final_time(self.nodes()))

    def cartesian(self) -> dict:
        """The path at every node in the road's Cartesian frame: ``x``, ``y`` [m] of the
        centre of gravity (`road.to_cartesian`) and the heading ``psi`` = the road's heading
        + $\\xi$ [rad]."""
        n = np.asarray(self.nodes())
        s = self.arc_length()
        x, y = self.road.to_cartesian(s, n[:, 0])
        psi = np.unwrap(np.asarray(self.road.heading(s), float)) + n[:, 1]
        return dict(s=s, x=np.asarray(x, float), y=np.asarray(y, float), psi=psi)

    def signals(self) -> dict:
        """Named signals at every node (car problems): the Cartesian pose (`cartesian`), the
        car's speeds, sideslip, slips and forces (`ReducedHalfCar.signals`), ``s``, ``n``,
        ``xi`` and ``t``."""
        n = np.asarray(self.nodes())
        pose = self.cartesian()
        states = np.stack([pose["x"], pose["y"], pose["psi"], n[:, 2], n[:, 3], n[:, 4]], 1)
        sig = self.runner("car_signals", _car_signals,
                          (self.problem.vehicle, states, n[:, 5:8]))
        sig = {k: np.asarray(v) for k, v in sig.items()}
        sig.update(s=pose["s"], n=n[:, 0], xi=n[:, 1], t=n[:, 8])
        return sig

    def violations(self, substeps: int = SUBSTEPS) -> dict:
        """Constraint violations measured exactly: ``corridor``, the distance off the road
        (`road.distance_off_road` of the Cartesian positions) at the nodes [m];
        ``corridor_between_nodes``, the same between the nodes after re-integrating every
        stage with ``substeps`` RK4 steps per step from its knot; ``boundary`` (the largest
        gate or periodic equality residual), ``defects`` (shooting), and for the car
        ``inputs`` (bounds) and ``axle_speed_floor`` [m/s]; ``time_budget`` for max-exit."""
        prob, rd = self.problem, self.road
        xs, us = self.solution.xs, self.solution.us
        n = np.asarray(self.nodes())
        s = self.arc_length()
        off = np.asarray(rd.distance_off_road(*rd.to_cartesian(s, n[:, 0])), float)
        steps = prob.steps_per_stage * substeps
        kap = fine_curvature(rd, prob.num_stages, steps, _edges_of(prob))
        fine = np.asarray(self.runner("curvilinear_fine", _fine, (prob, xs, us, kap)))
        s_fine = prob.node_positions(steps)
        between = np.asarray(rd.distance_off_road(*rd.to_cartesian(s_fine, fine[:, 0])), float)
        defects, bc = (float(a) for a in self.runner("curvilinear_defects", _defects,
                                                     (prob, xs, us)))
        out = dict(corridor=float(np.max(off)), corridor_between_nodes=float(np.max(between)),
                   boundary=bc, defects=defects)
        if isinstance(prob, CurvilinearManeuverOCP):
            kF, kR, d = n[:, 5], n[:, 6], n[:, 7]
            inp = np.concatenate([KAPPA_MIN - kF, kF - KAPPA_MAX, KAPPA_MIN - kR,
                                  kR - KAPPA_MAX, np.abs(d) - DELTA_MAX])
            out["inputs"] = float(max(np.max(inp), 0.0))
            sig = self.signals()
            out["axle_speed_floor"] = float(max(0.0, SPEED_FLOOR - min(sig["Vx_F"].min(),
                                                                       sig["Vx_R"].min())))
        else:
            out["speed_floor"] = float(max(0.0, SPEED_FLOOR - n[:, 2].min()))
        if prob.objective == "max-exit":
            out["time_budget"] = max(0.0, float(self.t_f) - float(prob.tf_max))
        return out

    def record(self, bound: RoadPrimitive | None = None) -> dict:
        """JSON-ready record, the fields of `solution_record` (t_f, exit_speed, status,
        message, iterations, residuals, violations, max_corridor_violation,
        max_corridor_violation_between_nodes, the bound), with the signals at every node
        (``s``, ``n``, ``xi`` besides the Cartesian states)."""
        sol = self.solution
        sig = self.signals()
        rec = dict(road=getattr(self.road, "name", None), objective=self.problem.objective,
                   closed=bool(self.problem.closed), length=float(self.problem.length),
                   t_f=float(self.t_f), exit_speed=float(self.exit_speed),
                   **result_record(sol.result), iterations=int(sol.iterations),
                   residuals=dict(inf_pr=float(sol.inf_pr), inf_du=float(sol.inf_du),
                                  compl=float(sol.compl)),
                   segments=self.problem.num_stages,
                   steps_per_stage=self.problem.steps_per_stage, nodes=len(sig["x"]))
        if self.coarse is not None:
            rec["coarse"] = dict(segments=int(self.coarse.xs.shape[0] - 1),
                                 **result_record(self.coarse.result),
                                 iterations=int(self.coarse.iterations),
                                 inf_pr=float(self.coarse.inf_pr),
                                 started_from=bool(self.started_from_coarse))
        v = self.violations()
        rec["violations"] = v
        rec["max_corridor_violation"] = v["corridor"]
        rec["max_corridor_violation_between_nodes"] = v["corridor_between_nodes"]
        if bound is not None:
            rec["point_mass_t_f"] = float(bound.t_f)
            rec["point_mass_exit_speed"] = float(bound.exit_speed)
            rec["point_mass_status"] = result_name(bound.result)
            rec["t_f_over_bound"] = rec["t_f"] / rec["point_mass_t_f"]
            rec["exit_speed_over_bound"] = rec["exit_speed"] / rec["point_mass_exit_speed"]
        rec["t"] = sig["t"]
        rec["s"] = sig["s"]
        rec["states"] = {k: sig[k] for k in ("x", "y", "psi", "vx", "vy", "yaw_rate", "n", "xi")}
        rec["inputs"] = {k: sig[k] for k in ("kappa_F", "kappa_R", "delta")}
        rec["signals"] = {k: sig[k] for k in ("speed", "sideslip", "Fz_F", "Fz_R", "Fx_F",
                                              "Fx_R", "Fy_F", "Fy_R", "Vx_F", "Vx_R")}
        return rec


def resample_drive(prob: CurvilinearManeuverOCP, xs, num_stages,
                   edges: np.ndarray | None = None):
    """A car drive's knots ``xs`` of ``prob`` on another grid by linear interpolation in s
    (the inputs stay piecewise linear, their rates the differences): a guess for a finer
    problem from a coarse solution. ``num_stages``: the new problem itself (its knots,
    `stage_edges`), or a number of stages with their knots' arc lengths ``edges`` (None:
    uniform)."""
    if isinstance(num_stages, AbstractCurvilinearOCP):
        num_stages, edges = num_stages.num_stages, _edges_of(num_stages)
    check_count("resample_drive", "num_stages", num_stages, sep=": ")
    xs = np.asarray(xs, float)
    L = float(prob.length)
    s_old = prob.stage_edges()
    s_new = np.linspace(0.0, L, num_stages + 1) if edges is None else np.asarray(edges, float)
    new = np.stack([np.interp(s_new, s_old, xs[:, j]) for j in range(xs.shape[1])], 1)
    us = np.diff(new[:, 5:8], axis=0) / (
        L / num_stages if edges is None else np.diff(s_new)[:, None])
    return jax.device_put(new), jax.device_put(us)


def road_point_mass_bound(road, objective: str = "min-time", *, D: float = 0.52,
                          num_stages: int = 100, steps_per_stage: int = 1,
                          tf_max: float = 60.0, fraction: float = 0.8,
                          options: IPOptions | None = None, throw: bool = True,
                          solver: Callable = interior_point) -> RoadPrimitive:
    """The physical bound on a centre-line road: `CurvilinearPointMassOCP` ($|a| \\le Dg$)
    solved from `point_mass_guess` (``fraction`` of the friction); ``options`` default
    ``IPOptions(max_iter=500)``; ``solver``: the interior-point solve."""
    options = IPOptions(max_iter=500) if options is None else options
    prob = CurvilinearPointMassOCP.from_road(road, friction=D, objective=objective,
                                             num_stages=num_stages,
                                             steps_per_stage=steps_per_stage, tf_max=tf_max)
    xs0, us0 = point_mass_guess(road, D, num_stages, fraction)
    if objective == "max-exit":
        xs0 = xs0.at[:, 3].multiply(jnp.minimum(1.0, 0.98 * tf_max / xs0[-1, 3]))
    sol = solver(prob, xs0, us0, options, throw=throw)
    return RoadPrimitive(problem=prob, solution=sol, road=road)


COARSE_START_VIOLATION = 1e-2
"""The largest constraint violation (the interior point's ``inf_pr``) of the best iterate of
`road_primitive`'s coarse solve, where that solve stopped short of its tolerance, from which
the fine solve still starts (further off: from the speed profile). Resampling a drive onto
the fine grid leaves larger violations itself: the converged first solve of the Oschersleben
lap (821 stages) resampled onto its 1478 has defects of 0.20 and corridor violations of
0.012."""


def road_primitive(road, objective: str = "min-time", *, car: ReducedHalfCar | None = None,
                   num_stages: int = 100, steps_per_stage: int = 1, margin: float = 0.0,
                   tf_max: float = 60.0, rate_weight: float = 1e-4, fraction: float = 0.8,
                   guess=None, coarse_stages: int | None = None, warm_mu0: float = 1e-3,
                   coarse_violation: float = COARSE_START_VIOLATION,
                   options: IPOptions | None = None, throw: bool = True,
                   solver: Callable = interior_point) -> RoadPrimitive:
    """Minimum-time (or maximum-exit-speed within ``tf_max`` [s]) drive of the reduced
    half-car along a centre-line road (`CurvilinearManeuverOCP`): open roads from the start
    gate to the end gate, closed roads as a periodic lap.

    **Arguments:** ``road`` (a centre-line road, e.g. `CentrelineRoad`), ``objective``,
    ``car`` (default the benchmark's `rally_gravel_car`), the grid ``num_stages`` x
    ``steps_per_stage`` RK4 steps, the corridor ``margin`` [m], ``rate_weight``, the
    starting ``guess`` (xs, us; default `speed_profile_guess` with ``fraction`` of the
    friction), ``coarse_stages``: first solve on that many stages from the guess, then start
    the fine problem from its solution (`resample_drive`) with the barrier ``warm_mu0``
    (long roads: the fine problem from the speed profile may stall); where that solve stops
    short of its tolerance, from its best iterate (`IPOptions.best_iterate`) if that
    violates no constraint by more than ``coarse_violation``, else from the speed profile
    (a first solve on a long lap can wander near the optimum until its iteration cap: its
    best iterate is then a far better start than the profile), ``options`` (default
    ``IPOptions(max_iter=500)``), ``throw``, ``solver``
    (`interior_point` or a function with its signature).

    **Returns:** a `RoadPrimitive`.
    """
    if car is None:
        from .primitives import rally_gravel_car

        car = rally_gravel_car()
    check_range("road_primitive", "coarse_violation", coarse_violation, lower=0.0)
    options = IPOptions(max_iter=500) if options is None else options
    prob = CurvilinearManeuverOCP.from_road(road, car, objective=objective,
                                            num_stages=num_stages,
                                            steps_per_stage=steps_per_stage, margin=margin,
                                            tf_max=tf_max, rate_weight=rate_weight)
    coarse, started = None, None
    if guess is None and coarse_stages is not None and coarse_stages < num_stages:
        coarse = road_primitive(road, objective, car=car, num_stages=coarse_stages,
                                steps_per_stage=steps_per_stage, margin=margin, tf_max=tf_max,
                                rate_weight=rate_weight, fraction=fraction,
                                options=dataclasses.replace(options, best_iterate=True),
                                throw=False, solver=solver)
        started = coarse_start(coarse.solution, coarse_violation)
        if started:
            guess = resample_drive(coarse.problem, coarse.solution.xs, prob)
            options = eqx.tree_at(lambda o: o.mu0, options, jnp.asarray(warm_mu0, float))
    if guess is None:
        guess = speed_profile_guess(road, car, num_stages, fraction)
        if objective == "max-exit":
            xs0, us0 = guess
            xs0 = xs0.at[:, 8].multiply(jnp.minimum(1.0, 0.98 * tf_max / xs0[-1, 8]))
            guess = (xs0, us0)
    sol = solver(prob, *guess, options, throw=throw)
    return RoadPrimitive(problem=prob, solution=sol, road=road,
                         coarse=None if coarse is None else coarse.solution,
                         started_from_coarse=started)


def coarse_start(sol: IPSolution, violation: float = COARSE_START_VIOLATION) -> bool:
    """Whether `road_primitive` starts its fine solve from the coarse solution ``sol``: it
    converged, or (stopped short) its iterate is finite and violates no constraint by more
    than ``violation`` (``inf_pr``). `coarse_refusal` says why not."""
    return coarse_refusal(sol, violation) is None


def coarse_refusal(sol: IPSolution, violation: float = COARSE_START_VIOLATION) -> str | None:
    """Why `road_primitive` does not start its fine solve from the coarse solution ``sol``, in
    words ("its best iterate is not finite", or its primal infeasibility above
    ``violation``); None where it does (`coarse_start`)."""
    if bool(sol.converged):
        return None
    inf_pr = float(sol.inf_pr)
    finite = (bool(jnp.all(jnp.isfinite(sol.xs))) and bool(jnp.all(jnp.isfinite(sol.us)))
              and math.isfinite(inf_pr))
    if not finite:
        return "its best iterate is not finite"
    if inf_pr > violation:
        return (f"its best iterate's primal infeasibility {inf_pr:.1e}, "
                f"above {violation:.0e}")
    return None
