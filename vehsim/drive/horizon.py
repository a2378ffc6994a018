r"""The receding-horizon driver: the reduced half-car (eqs. 61-63) planned over a moving
window of the road in arc length, re-solved every control sample, driving the full
half-car plant (eqs. 49-60).

**The road as arrays.** `RoadTable` samples a centre-line road at a fixed spacing $\Delta$:
arc length $s_j$, centre point $c(s_j)$, heading $\theta(s_j)$, curvature $\kappa(s_j)$,
widths $w_l, w_r$, the friction-limited speed $v_1(s)$ of unit peak friction
(`speed_profile` with $D = 1$) and the road's friction scale $\lambda(s)$ (the grip field on
the centre line; its peak friction at a speed $V$ is $\mu^*(\lambda(s), V)$,
`peak_friction`). Between samples
the centre line is the cubic Hermite interpolant of the points and unit tangents
($C^1$, error $O(\Delta^4\kappa^3)$), the other columns are linear. An open road is extended
by straights of its end widths before its start and past its end (a horizon may reach
beyond the end gate); a closed one is periodic. The projection of a pose
(`RoadTable.to_frenet`) is a search over the samples near a guess followed by Newton's
method on $(p - c(s))\cdot c'(s) = 0$: a few fixed steps, so it is `jit`/`vmap`-able and
differentiable.

**The horizon problem** (`HorizonOCP`, built by `horizon_problem` from arrays only): the
arc-length problem of `CurvilinearManeuverOCP` (knots $X = (n, \xi, v_x, v_y, r, \kappa_F,
\kappa_R, \delta, t)$, controls $u = d(\kappa_F, \kappa_R, \delta)/ds$, $S$ RK4 steps per
stage, one by default) on $[s_0, s_0 + H]$ with $M$ stages,

$$\min\ t(H) + w\sum_k |u_k|^2 h\quad\text{s.t.}\quad X_0[0{:}8] = \hat X,\ t_0 = 0,\quad
  -w_r + m \le n \le w_l - m,\quad |u_\delta\,\dot s| \le \dot\delta_{max},\quad
  |v(H)| \le \beta\sqrt{D}\,v_1(s_0 + H),\ |v_y(H)| \le \sigma v_x(H),\
  |\xi(H)| \le \xi_{max},$$

$\hat X$ the current (predicted) state, the corridor at the knots and the stages'
midpoints, the speed floor and slip and steering bounds at the knots, and the terminal
bound: the friction-limited speed profile scales exactly with $\sqrt D$, so a plan that
ends below it can always brake for what lies beyond the horizon. Stage $k$'s tire has the
peak $D_k$ = `grip`$_k\cdot D$ (the per-stage friction of the planner: the peak of the
road it believes in at the speed it plans that stage at, `RecedingHorizonDriver`).

**The controller** (`RecedingHorizonDriver`) per sample: project the measured pose, predict
it over the actuator delay with the reduced model and the inputs already on their way,
shift the previous plan by the distance travelled (interpolated in $s$), solve by
`interior_point` from it, and apply the plan's first inputs: the steering angle directly,
the axle torques from the planned slips through the wheel equations 52-53,
$T_i = I_i\dot\omega_i + r f_{ix}$ (`ReducedHalfCar.recover_torques`), each axle's force
at most a fraction of what the plant's tire can give (the traction control,
`RecedingHorizonDriver.traction_limit`), plus a feedback on the slip error measured from
the wheel speeds and the ground velocity.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._checks import (
    check_count,
    check_integer,
    check_nonnegative,
    check_positive,
    check_range,
    is_concrete,
    require_float64,
)
from .._fields import array_field, float_array, int_array, int_field
from .._math import safe_hypot, wrap_angle
from ..optimal.centreline import _hermite3
from ..optimal.curvilinear import (
    SPEED_CAP,
    CurvilinearManeuverOCP,
    _rk4_steps,
    spatial_rhs,
    speed_profile,
)
from ..optimal.ip import IPOptions, IPSolution, interior_point
from ..optimal.ip.implicit import implicit_solve
from ..optimal.ip.kkt import BACKWARD_ERROR_TOL
from ..optimal.ip.problem import stage_layout
from ..optimal.shooting import KAPPA_MAX, KAPPA_MIN, SPEED_FLOOR
from ..tire.lumped2d import LumpedLuGre2D
from ..tire.params import lugre2d_bakker1987
from ..vehicle.reduced import ReducedHalfCar
from .estimator import REFERENCE_SPEED, longitudinal_capacity, peak_friction, scale_of_peak
from .sensors import DriveMeasurement
from .simulate import AbstractDriveController


EXTENSION = 60.0
"""Length [m] of the straight that extends an open road past its end in a `RoadTable`."""
BACK_EXTENSION = 5.0
"""Length [m] of the straight before an open road's start in a `RoadTable`."""
MAX_SPACING = 1.0
"""The largest spacing [m] of a `RoadTable`: its samples must resolve the road's corners
and the position search around the guess (`SEARCH_DISTANCE` each side)."""
SEARCH_DISTANCE = 4.0
"""Distance [m] on each side of the guess over which `RoadTable.to_frenet` compares
samples."""
NEWTON_STEPS = 4
"""Newton steps of `RoadTable.to_frenet` after the search."""
PLAN_BACKWARD_ERROR = BACKWARD_ERROR_TOL
"""`IPOptions.backward_error_singular` of every drive solve (the driver's plans, the nominal
reference and the offline bounds): a Newton solve is accepted only where it reaches the
refinement's own tolerance, 1e-10, where the offline primitives accept IPOPT's 1e-5. The
closed-loop figures of docs/driver.md were measured with it; the looser acceptance, which
regularises less where the factorisation loses accuracy, is not measured on the closed
loop."""
PLAN_REFINEMENT_STEPS = 1
"""`IPOptions.max_refinement_steps` of every drive solve: one step of iterative refinement,
as the closed-loop figures of docs/driver.md were measured (the offline primitives refine
up to IPOPT's 10 steps)."""


# ---- the road as arrays -----------------------------------------------------------------


def _plant_tire() -> LumpedLuGre2D:
    return LumpedLuGre2D(lugre2d_bakker1987())


class RoadTable(eqx.Module):
    r"""A centre-line road sampled at a fixed spacing (module docstring), as arrays.

    **Fields** (each sample column shape (N,)): `start` $s$ of the first sample [m] (open
    roads: $-$`BACK_EXTENSION`), `spacing` $\Delta$ [m], `length` $L$ [m] (an array, so
    tables of different roads of the same `num_points` batch in one `vmap`), the columns `s`,
    `x`, `y`, `heading` (unwrapped), `curvature`, `width_left`, `width_right`,
    `speed_limit` ($v_1$: `speed_profile` with $D = 1$ and all the friction), `scale` (the
    friction scale $\lambda(s)$ of the road along the centre line: the true grip for the
    planner's oracle, see `with_grip` and `peak_at`); `closed` and `search_points`
    (static).

    The interpolated centre line is within $10^{-4}$ m of the road's at the default spacing
    of 0.1 m where the curvature jumps (joined segments; $O(\Delta^2\,|[\kappa]|)$), far
    closer elsewhere.

    Build it with `RoadTable.from_road`. Arc lengths given to the methods are wrapped
    (`wrap`): modulo $L$ on a closed road, clipped to the table on an open one.
    """

    start: Float[Array, ""]
    spacing: Float[Array, ""]
    length: Float[Array, ""]
    s: Float[Array, " N"]
    x: Float[Array, " N"]
    y: Float[Array, " N"]
    heading: Float[Array, " N"]
    curvature: Float[Array, " N"]
    width_left: Float[Array, " N"]
    width_right: Float[Array, " N"]
    speed_limit: Float[Array, " N"]
    scale: Float[Array, " N"]
    closed: bool = eqx.field(static=True, default=False)
    search_points: int = eqx.field(static=True, default=16)

    @classmethod
    def from_road(cls, road, spacing: float = 0.1, num_points: int | None = None, *,
                  scale: float = 1.0, extension: float = EXTENSION) -> RoadTable:
        """The table of ``road`` (a `CentrelineRoad`) at ``spacing`` [m] (at most
        `MAX_SPACING`; a closed road: the nearest spacing that divides its length).
        ``num_points``: the number of samples (default: just enough); more pad the table
        (an open road's end straight grows, a closed road repeats its last sample), fewer
        are refused. ``scale``: the constant friction scale column (`with_grip` sets a
        varying one); ``extension`` [m]: the straight past an open road's end (at least
        the horizon)."""
        spacing = float(spacing)
        if not (math.isfinite(spacing) and 0 < spacing <= MAX_SPACING):
            raise ValueError(f"RoadTable.from_road: spacing must lie in (0, {MAX_SPACING:g}] m "
                             f"(the table resolves the road's corners), got {spacing:g}")
        L = float(road.length)
        closed = bool(getattr(road, "closed", False))
        if closed:
            K = max(2, int(math.ceil(L / spacing)))
            spacing = L / K
            need = K + 1
            start = 0.0
        else:
            start = -BACK_EXTENSION
            need = int(math.ceil((L + BACK_EXTENSION + float(extension)) / spacing)) + 1
        N = need if num_points is None else int(num_points)
        if N < need:
            raise ValueError(f"RoadTable.from_road: num_points={num_points} is too few for "
                             f"road {getattr(road, 'name', '')!r}: it needs {need} at spacing "
                             f"{spacing:g} m")
        s = start + spacing * np.arange(N)
        _, v1 = speed_profile(road, 1.0, 1.0, start_speed=SPEED_CAP, points=4000)
        s_prof = np.linspace(0.0, L, len(v1))
        if closed:
            sc = np.minimum(s, L)
            sc[need:] = L
            x, y = road.position(sc)
            th = np.asarray(road.heading(sc), float)
            kap = np.asarray(road.curvature(sc), float)
            wl, wr = road.width_left(sc), road.width_right(sc)
            v = np.interp(sc, s_prof, v1)
        else:
            sc = np.clip(s, 0.0, L)
            x, y = road.position(sc)
            th = np.asarray(road.heading(sc), float)
            tx, ty = np.cos(th), np.sin(th)
            beyond = s - sc  # < 0 before the start, > 0 past the end
            x, y = x + beyond * tx, y + beyond * ty
            kap = np.where(beyond == 0.0, np.asarray(road.curvature(sc), float), 0.0)
            wl, wr = road.width_left(sc), road.width_right(sc)
            v = np.where(beyond > 0, SPEED_CAP, np.interp(sc, s_prof, v1))
        col = lambda a: jnp.asarray(np.asarray(a, float))
        return cls(start=col(start), spacing=col(spacing), length=col(L), s=col(s), x=col(x),
                   y=col(y), heading=col(th), curvature=col(kap), width_left=col(wl),
                   width_right=col(wr), speed_limit=col(v), scale=col(np.full(N, scale)),
                   closed=closed, search_points=int(math.ceil(SEARCH_DISTANCE / spacing)))

    def with_grip(self, grip) -> RoadTable:
        r"""The table with `scale` $= \lambda(c(s))$: the grip field `grip`
        (`AbstractGripField`) read on the centre line. The peak friction follows from it at
        a speed (`peak_at`): it is neither proportional to $\lambda$ nor independent of the
        speed."""
        lam = jax.vmap(grip.scale_at)(self.x, self.y)
        return eqx.tree_at(lambda t: t.scale, self, lam)

    @property
    def num_points(self) -> int:
        """Samples in the table."""
        return self.s.shape[-1]

    def wrap(self, s):
        """Arc length on the table: modulo $L$ (closed road) or clipped to the table."""
        if self.closed:
            return jnp.remainder(s, self.length)
        return jnp.clip(s, self.s[0], self.s[-1])

    def _locate(self, s):
        s = self.wrap(s)
        i = jnp.clip(jnp.floor((s - self.start) / self.spacing).astype(int), 0,
                     self.num_points - 2)
        t = (s - self.s[i]) / self.spacing
        return i, t

    def _linear(self, column, s):
        i, t = self._locate(s)
        return column[i] + t * (column[i + 1] - column[i])

    def _curve(self, s):
        """$c(s)$, $c'(s)$, $c''(s)$ of the Hermite centre line, each a pair (x, y)."""
        i, t = self._locate(s)
        h = self.spacing
        th0, th1 = self.heading[i], self.heading[i + 1]
        px = _hermite3(t, h, self.x[i], jnp.cos(th0), jnp.cos(th1), self.x[i + 1])
        py = _hermite3(t, h, self.y[i], jnp.sin(th0), jnp.sin(th1), self.y[i + 1])
        return (px[0], py[0]), (px[1], py[1]), (px[2], py[2]), th0

    def position(self, s):
        """The centre line $c(s)$ [m] as (x, y)."""
        return self._curve(s)[0]

    def heading_at(self, s):
        r"""The tangent's angle $\theta(s)$ [rad] of the interpolated centre line."""
        _, (dx, dy), _, th0 = self._curve(s)
        c, sn = jnp.cos(th0), jnp.sin(th0)
        return th0 + jnp.arctan2(c * dy - sn * dx, c * dx + sn * dy)

    def curvature_at(self, s):
        r"""$\kappa(s)$ [1/m] (linear between samples)."""
        return self._linear(self.curvature, s)

    def speed_limit_at(self, s):
        """$v_1(s)$ [m/s]: the friction-limited speed at unit peak friction."""
        return self._linear(self.speed_limit, s)

    def scale_at(self, s):
        r"""The road's friction scale $\lambda(s)$ (linear between samples)."""
        return self._linear(self.scale, s)

    def peak_at(self, s, speed, tire=None):
        r"""The road's peak friction $\mu^*(\lambda(s), V)$ at arc length(s) `s` [m] and the
        ground speed(s) $V$ = `speed` [m/s] (`peak_friction` of `tire`, default the drive
        plant's `LumpedLuGre2D` with `lugre2d_bakker1987`)."""
        tire = _plant_tire() if tire is None else tire
        lam = self.scale_at(s)
        lam, V = jnp.broadcast_arrays(lam, jnp.asarray(speed, float))
        peaks = jax.vmap(lambda la, v: peak_friction(tire, la, v))(lam.ravel(), V.ravel())
        return peaks.reshape(lam.shape)

    def corridor_at(self, s, margin=0.0):
        """Bounds (lower, upper) on $n$ [m]: $(-w_r + m, w_l - m)$, stacked on the last axis."""
        return jnp.stack([-self._linear(self.width_right, s) + margin,
                          self._linear(self.width_left, s) - margin], -1)

    def to_cartesian(self, s, n):
        """The point $c(s) + nN(s)$ [m] as (x, y)."""
        (px, py), (dx, dy), _, _ = self._curve(s)
        v = jnp.sqrt(dx * dx + dy * dy)
        return px - n * dy / v, py + n * dx / v

    def to_frenet(self, x, y, psi, s_guess):
        r"""$(s, n, \xi)$ of the pose $(x, y, \psi)$: the nearest of the samples within
        `SEARCH_DISTANCE` of ``s_guess`` (`search_points` on each side), then `NEWTON_STEPS`
        Newton steps on $f(s) = (p - c(s))\cdot c'(s) = 0$ ($f' = |c'|^2 - (p - c)\cdot
        c''$, floored at 0.1, steps within $\pm\Delta$); $n = (p - c(s))\cdot N(s)$, $\xi =
        \psi - \theta(s)$ in $(-\pi, \pi]$. On a closed road $s$ is not wrapped: it stays
        continuous with ``s_guess`` (counting laps). Differentiable in the pose (the search
        only picks the starting sample)."""
        h = self.spacing
        offsets = jnp.arange(-self.search_points, self.search_points + 1)
        base = jnp.round((s_guess - self.start) / h)
        cand = self.start + (base + offsets) * h  # continuous arc lengths near the guess
        if not self.closed:
            cand = jnp.clip(cand, self.s[0], self.s[-1])
        (cx, cy) = self.position(cand)
        d2 = (cx - x) ** 2 + (cy - y) ** 2
        s = jax.lax.stop_gradient(cand[jnp.argmin(d2)])

        def newton(s, _):
            (px, py), (dx, dy), (ddx, ddy), _ = self._curve(s)
            rx, ry = x - px, y - py
            f = rx * dx + ry * dy
            fp = dx * dx + dy * dy - (rx * ddx + ry * ddy)
            step = jnp.clip(f / jnp.maximum(fp, 0.1), -h, h)
            s = s + step
            if not self.closed:
                s = jnp.clip(s, self.s[0], self.s[-1])
            return s, None

        s, _ = jax.lax.scan(newton, s, None, length=NEWTON_STEPS)
        (px, py), (dx, dy), _, _ = self._curve(s)
        v = jnp.sqrt(dx * dx + dy * dy)
        n = ((y - py) * dx - (x - px) * dy) / v
        xi = wrap_angle(psi - self.heading_at(s))
        return s, n, xi


# ---- the horizon problem ------------------------------------------------------------------


def _slip_parts(vehicle: ReducedHalfCar, X):
    r"""$(\kappa_i, V_{ix}, k_y V_{iy})$ of both axles: the side velocity in the tire's
    combined slip (`FrictionEllipseTire.lateral_stiffness` $k_y$; 1 where it is None or
    the tire has none)."""
    VFx, VFy, VRx, VRy = vehicle.axle_velocities(
        jnp.concatenate([X[:1] * 0, X[:1] * 0, X[1:5]]), X[7])
    Vy = jnp.stack([VFy, VRy])
    ky = getattr(vehicle.tire, "lateral_stiffness", None)
    return X[5:7], jnp.stack([VFx, VRx]), Vy if ky is None else ky * Vy


def axle_slips(vehicle: ReducedHalfCar, X) -> Float[Array, " 2"]:
    r"""The combined slip $s_i = \sqrt{\kappa_i^2 + k_y^2\tan^2\alpha_i}/(1 + \kappa_i)$
    of each axle of the knot ``X`` $(n, \xi, v_x, v_y, r, \kappa_F, \kappa_R, \delta, ...)$
    (the friction-ellipse tire's, `FrictionEllipseTire`, $k_y$ its `lateral_stiffness`;
    $\tan\alpha_i = V_{iy}/V_{ix}$ in the wheel frame)."""
    k, Vx, Vy = _slip_parts(vehicle, X)
    return safe_hypot(k, Vy / Vx) / (1.0 + k)  # a zero gradient, not NaN, rolling straight


def scaled_planning_car(vehicle: ReducedHalfCar, grip, stiffness_power=None
                        ) -> ReducedHalfCar:
    r"""The planning car ``vehicle`` on a surface of relative grip $g$ = ``grip``: its
    friction-ellipse tire's peak $D g$ and, with ``stiffness_power`` $q$ (None: $B$ kept),
    $B \min(g, 1)^{-q}$, so that on a surface of less grip than the car's its slip
    stiffness $BCD$ scales as $g^{1-q}$ (above, as $g$: $B$ kept).

    With $B$ kept ($q$ = 0) a surface of less grip is also a softer tire: the planner
    believes it needs larger slip angles for the same force. The plant's LuGre tire is not:
    its slope at zero slip is set by its bristles' stiffness $\sigma_0$, whatever the
    road, and fitted over the scenarios' peaks (`fit_planner_tire`, 0.23-0.68) its
    $BCD$ scales as about $D^{0.4}$. The Magic Formula states its stiffness apart from its
    peak for the same reason ($B = K/(CD)$): $q$ = 1 keeps the slip stiffness of
    ``vehicle`` on every surface of less grip, $q$ = 0.6 follows the plant's. Where the
    grip is above the car's (the LuGre peak rises as the speed falls: $g$ up to 1.25 on
    the nominal road at 4-8 m/s) $B$ stays: a softer tire there made the horizon problems
    harder to converge (docs/driver.md)."""
    tire = vehicle.tire
    D = tire.D * grip
    if stiffness_power is None:
        return eqx.tree_at(lambda v: v.tire.D, vehicle, D)
    B = tire.B * jnp.minimum(grip, 1.0) ** (-jnp.asarray(stiffness_power, float))
    return eqx.tree_at(lambda v: (v.tire.B, v.tire.D), vehicle, (B, D))


class HorizonOCP(CurvilinearManeuverOCP):
    r"""The horizon problem of the module docstring: `CurvilinearManeuverOCP` on a window of
    length `length` $H$ with the initial state fixed, the steering-rate bound, the
    terminal speed bound and a per-stage peak friction. Build it with `horizon_problem`.

    **Fields** (besides `CurvilinearManeuverOCP`'s; the gates' are unused):
    `initial_state` $\hat X$ (8,) $(n, \xi, v_x, v_y, r, \kappa_F, \kappa_R, \delta)$,
    `grip` (M,) the factor on the tire's $D$ in each stage, `terminal_speed` [m/s] (the
    bound on the speed $|v|$ at $H$), `terminal_sideslip` $\sigma$ (the bound on
    $|v_y|/v_x$ at $H$) and `terminal_heading` $\xi_{max}$ [rad] (on $|\xi(H)|$): without
    them the last stages of a minimum-time plan throw the car sideways or point it off the
    road, nothing after the horizon paying for it; `steer_rate` $\dot\delta_{max}$ [rad/s],
    `steer_limit` [rad]; `slip_limit` (M,) or None: the bound on each axle's combined slip
    (`axle_slips`) at stage $k$'s first knot (the planner's tire trusted only where it
    agrees with the plant's), and at the end knot `end_slip_limit`; `corridor_penalty`
    $\rho$ [s/m] or None (hard corridor): a soft corridor, below; `soft_stages` (None:
    all) the stages whose corridor is soft, the first ones (the later stages' slacks are
    unused: zero at a converged plan, though a few passes without multipliers can leave
    them negative, docs/drive.md).

    **The soft corridor.** With $\rho$ the controls gain a slack $\sigma_k \ge 0$
    ($u = (d(\kappa_F, \kappa_R, \delta)/ds, \sigma)$, `control_size` 4), the corridor at
    stage $k$'s first knot and midpoint becomes $-w_r + m - \sigma_k \le n \le w_l - m +
    \sigma_k$ and the objective gains $\rho\sum_k\sigma_k$ (the end knot's corridor stays
    hard). The penalty is exact: where the hard problem has a solution whose corridor
    multipliers are below $\rho$, it is the soft problem's, with $\sigma = 0$; where it has
    none (a start a few tenths of a metre wide of its plan at the friction limit), the soft
    problem still has one, the plan that leaves the corridor by the least total distance,
    instead of an interior point with nothing to converge to. With `soft_stages` $R$ only
    the stages $k < R$ are soft: a start that no control keeps inside the corridor (at its
    edge, drifting out) still has a plan, and the rest of the horizon keeps the hard
    corridor, which a plan cannot trade for time at any $\rho$.
    """

    initial_state: Float[Array, " 8"] = array_field(default=(0.0,) * 8)
    grip: Float[Array, " M"] | None = None
    terminal_speed: Float[Array, ""] = array_field(default=SPEED_CAP)
    steer_rate: Float[Array, ""] = array_field(default=1.0)
    steer_limit: Float[Array, ""] = array_field(default=0.6)
    terminal_sideslip: Float[Array, ""] = array_field(default=0.1)
    terminal_heading: Float[Array, ""] = array_field(default=0.15)
    slip_limit: Float[Array, " M"] | None = None
    corridor_penalty: Float[Array, ""] | None = None
    soft_stages: Int[Array, ""] | None = None
    stiffness_power: Float[Array, ""] | None = None

    def __check_init__(self):
        if self.control_size != (3 if self.corridor_penalty is None else 4):
            raise ValueError("HorizonOCP.control_size must be 3 with a hard corridor and 4 "
                             "(the slack) with corridor_penalty; build it with "
                             "horizon_problem")
        if self.soft_stages is not None and self.corridor_penalty is None:
            raise ValueError("HorizonOCP.soft_stages needs corridor_penalty (the soft "
                             "corridor's cost, > 0), got None")

    def linear_variables(self) -> tuple[int, ...]:
        """The time, and with a soft corridor its slack (additive in the corridor rows and
        the objective)."""
        slack = () if self.corridor_penalty is None else (self.state_size + 3,)
        return (*super().linear_variables(), *slack)

    def _slip_constraints(self, X, limit):
        r"""`axle_slips` $\le$ ``limit`` for both axles, as the polynomial
        $\ell^2(1 + \kappa_i)^2V_{ix}^2 - \kappa_i^2V_{ix}^2 - V_{iy}^2 \ge 0$."""
        k, Vx, Vy = _slip_parts(self.vehicle, X)
        return (limit * (1.0 + k)) ** 2 * Vx * Vx - k * k * Vx * Vx - Vy * Vy

    def _slip_rows(self, X, stage, limit=None):
        """The slip bound's rows at knot ``X`` with stage ``stage``'s limit, or ``limit``
        where given (none without `slip_limit`)."""
        if self.slip_limit is None:
            return jnp.zeros((0,))
        return self._slip_constraints(X, self.slip_limit[stage] if limit is None else limit)

    def stage_vehicle(self, k) -> ReducedHalfCar:
        r"""The planning car of stage ``k``: its tire's $D$ times `grip`[k] (and with
        `stiffness_power` $q$ its $B$ times $\min$(`grip`[k], 1)$^{-q}$,
        `scaled_planning_car`)."""
        if self.grip is None:
            return self.vehicle
        return scaled_planning_car(self.vehicle, self.grip[k], self.stiffness_power)

    def _segment(self, x, u, k):
        veh = self.stage_vehicle(k)
        return _rk4_steps(lambda X, uu, kap: spatial_rhs(veh, X, uu, kap), x, u[:3],
                          self.step, self.curvature[k])

    def _rhs(self, X, u, kappa):  # the rates only: a soft corridor's slack is the last control
        return super()._rhs(X, u[:3], kappa)

    def stage_cost(self, x, u, k):
        cost = super().stage_cost(x, u[:3], k)
        if self.corridor_penalty is None:
            return cost
        return cost + self.corridor_penalty * u[3]

    def _node_constraints(self, X):
        kF, kR, d = X[5], X[6], X[7]
        VFx, _, VRx, _ = self.vehicle.axle_velocities(
            jnp.concatenate([X[:1] * 0, X[:1] * 0, X[1:5]]), d)
        return jnp.stack([VFx - SPEED_FLOOR, VRx - SPEED_FLOOR,
                          kF - KAPPA_MIN, KAPPA_MAX - kF, kR - KAPPA_MIN, KAPPA_MAX - kR,
                          self.steer_limit - d, d + self.steer_limit])

    def _path(self, x, u, k, starts, end):
        base = super()._path(x, u, k, starts, end)
        if self.corridor_penalty is not None:  # the corridor's rows: 2 per node, 2 per mid
            slack = u[3] if self.soft_stages is None else jnp.where(k < self.soft_stages,
                                                                    u[3], 0.0)
            base = jnp.concatenate([base[:4 * self.steps_per_stage] + slack,
                                    base[4 * self.steps_per_stage:], u[3:4]])
        n, xi, vx, vy = x[0], x[1], x[2], x[3]
        kap = self.curvature[k][0, 0]
        sdot = (vx * jnp.cos(xi) - vy * jnp.sin(xi)) / (1.0 - n * kap)
        rate = u[2] * sdot
        return jnp.concatenate([base, jnp.stack([self.steer_rate - rate,
                                                 self.steer_rate + rate]),
                                self._slip_rows(x, k)])

    def initial_equality(self, x):
        return jnp.concatenate([x[8:9], x[:8] - self.initial_state])

    def initial_inequality(self, x):
        return jnp.zeros((0,))

    def terminal_equality(self, x):
        return jnp.zeros((0,))

    def terminal_inequality(self, x):
        vx, vy = x[2], x[3]
        b = self.terminal_sideslip * vx
        xi_max = self.terminal_heading
        return jnp.concatenate([self._terminal_node(x), jnp.stack([
            self.terminal_speed**2 - vx * vx - vy * vy, b - vy, b + vy, xi_max - x[1],
            xi_max + x[1]]), self._slip_rows(x, -1, self.end_slip_limit())])

    def end_slip_limit(self):
        r"""The bound on the axles' combined slip at the end knot: the last stage's
        `slip_limit` or, where larger, the peak slip $s^*$ of the last stage's tire
        (`FrictionEllipseTire.peak_slip`); None without `slip_limit`. Without a bound there
        the last stage of a minimum-time plan can brake on a locked wheel that no stage
        after it pays for; with the path's own bound there, the end knot cannot take up the
        terminal speed bound's fall as the horizon's end moves into a braking zone, and the
        few real-time passes of a sample must spread that braking over the whole plan
        (docs/driver.md, "The slip bound at the horizon's end")."""
        if self.slip_limit is None:
            return None
        peak = getattr(self.stage_vehicle(self.num_stages - 1).tire, "peak_slip", 0.0)
        return jnp.maximum(self.slip_limit[-1], peak)


RELAX_STAGES = 3
"""Stages over which the corridor is widened to hold a start outside it (`horizon_problem`)."""

FALLBACK_SLIP = 10.0
"""The slip bound of the first step of a first plan solved again in two steps
(`RecedingHorizonDriver`): none in effect."""


def horizon_problem(table: RoadTable, vehicle: ReducedHalfCar, s0, state8, D_per_stage, *,
                    horizon=60.0, margin=0.2, rate_weight=1e-4, steer_rate=1.0,
                    steer_limit=0.6, terminal_backoff=1.0, slip_limit=None,
                    margin_grip_power=0.0, corridor_penalty=None,
                    soft_stages=None, stiffness_power=None,
                    steps_per_stage: int = 1) -> HorizonOCP:
    r"""The `HorizonOCP` at arc length ``s0`` [m] from the state ``state8`` $\hat X$ with
    the stages' peak friction ``D_per_stage`` (M,): arrays only, so it runs under `jit`
    and `vmap`, and every sample shares one program (the stage count is the length of
    ``D_per_stage``).

    Curvature at each stage's RK4 points, corridor $(-w_r + m_k, w_l - m_k)$ at the knots
    and midpoints (widened over the first `RELAX_STAGES` stages, linearly to nothing, by as
    much as the start lies outside it plus 5 cm, so that a start off the corridor stays
    feasible), $m_k = m \min(1, g_k)^p$ with $m$ = ``margin``, $p$ = ``margin_grip_power``
    (0: the same margin everywhere) and $g_k$ the stage's `grip` below (the last stage's at
    the end knot). How far the car strays from its plan within a sample grows with the
    lateral force the planning model gets wrong, a fraction of the grip it plans with, and
    with the speed, which scales as $\sqrt{g}$: $p$ = 1 or 1/2 narrows the margin on a
    slippery surface, where the road's width is what lets the car through; terminal bound
    $|v(H)| \le \beta\sqrt{D_{M-1}}\,v_1(s_0 + H)$ with $\beta$ = ``terminal_backoff``,
    `grip` = ``D_per_stage`` / the vehicle's $D$;
    ``slip_limit`` (None: no bound) the bound on the axles' combined slip, widened over the
    first `RELAX_STAGES` stages as the corridor by as much as the start exceeds it (plus
    0.02 at the fixed first knot only: with the slack on the later knots too, each sample's
    start, read from the last plan between its first two knots, crept up to the bound
    plus twice the slack); ``corridor_penalty`` $\rho$ [s/m] (None: a hard corridor) the
    soft corridor of `HorizonOCP`, whose controls then end in the slack $\sigma_k$, on the
    first ``soft_stages`` stages (None: all); ``stiffness_power`` $q$ (None: the tire's
    $B$ on every stage) each stage's $B$ times $\min(g_k, 1)^{-q}$ (`scaled_planning_car`);
    ``steps_per_stage`` $S$ (static) the RK4 steps of each stage, the curvature at each
    step's points and the corridor at each step's start and midpoint. The car's lateral
    modes decay in arc length at a rate of about $BCD\,g/v_x^2$ [1/m] (the axles' cornering
    stiffness over $m v_x$, per metre travelled), and one step stays stable only while that
    rate times the step is within RK4's interval (2.8): the benchmark's gravel tire ($BCD$
    = 5.8) at 8 m/s is 0.9 per m, a step of 2 m; the tire of the plant's shape
    (`planner_car`, $BCD$ about 26) 4 per m, which needs steps of 0.5 m."""
    D_per_stage = jnp.asarray(D_per_stage, float)
    M = D_per_stage.shape[0]
    S = steps_per_stage
    h = jnp.asarray(horizon, float) / M
    s_nodes = s0 + h * jnp.arange(M + 1)
    s_steps = s_nodes[:-1, None] + (h / S) * jnp.arange(S)[None, :]  # (M, S): steps' starts
    kap = jnp.stack([table.curvature_at(s_steps), table.curvature_at(s_steps + 0.5 * h / S),
                     table.curvature_at(s_steps + h / S)], -1)
    state8 = jnp.asarray(state8, float)
    grip = D_per_stage / vehicle.tire.D
    power = jnp.asarray(margin_grip_power, float)
    scaled = jnp.asarray(margin, float) * jnp.minimum(grip, 1.0) ** power
    nodes = table.corridor_at(s_nodes, jnp.concatenate([scaled, scaled[-1:]]))
    mids = table.corridor_at(s_steps + 0.5 * h / S, scaled[:, None])  # (M, S, 2)
    inner = table.corridor_at(s_steps[:, 1:], scaled[:, None])  # (M, S-1, 2)
    n0 = state8[0]
    excess = jnp.maximum(jnp.maximum(nodes[0, 0] - n0, n0 - nodes[0, 1]), 0.0)
    excess = jnp.where(excess > 0, excess + 0.05, 0.0)
    fade = lambda s: jnp.clip(1.0 - (s - s0) / (RELAX_STAGES * h), 0.0, 1.0)
    widen = lambda b, s: b + jnp.stack([-excess * fade(s), excess * fade(s)], -1)
    nodes = widen(nodes, s_nodes)
    mids, inner = widen(mids, s_steps + 0.5 * h / S), widen(inner, s_steps[:, 1:])
    v_end = terminal_backoff * jnp.sqrt(D_per_stage[-1]) * table.speed_limit_at(s0 + horizon)
    slips = None
    if slip_limit is not None:
        limit = jnp.asarray(slip_limit, float)
        over = jnp.maximum(jnp.max(axle_slips(vehicle, state8)) - limit, 0.0)
        slips = (limit + over * fade(s_nodes[:-1])).at[0].add(jnp.where(over > 0, 0.02, 0.0))
    return HorizonOCP(
        vehicle=vehicle, length=jnp.asarray(horizon, float), curvature=kap, corridor=nodes,
        corridor_mid=mids, corridor_steps=inner,
        start_lateral=jnp.zeros(2), end_lateral=jnp.zeros(2), start_speed=jnp.zeros(()),
        end_speed=jnp.zeros(()), start_speed_fixed=False, end_speed_fixed=False,
        num_stages=M, steps_per_stage=S, closed=False, objective="min-time",
        rate_weight=rate_weight, initial_state=state8, grip=grip,
        terminal_speed=v_end, steer_rate=steer_rate, steer_limit=steer_limit,
        slip_limit=slips, corridor_penalty=None if corridor_penalty is None else
        jnp.asarray(corridor_penalty, float), control_size=3 if corridor_penalty is None else 4,
        soft_stages=None if soft_stages is None else jnp.asarray(soft_stages, int),
        stiffness_power=None if stiffness_power is None else
        jnp.asarray(stiffness_power, float))


def profile_guess(table: RoadTable, vehicle: ReducedHalfCar, s0, state8, D_per_stage, *,
                  horizon=60.0, fraction=0.8):
    r"""A starting guess of `horizon_problem` (JAX, as `speed_profile_guess`): the centre
    line's speed limit $\sqrt{fD}\,v_1(s)$ capped by accelerating from the current speed
    with $fDg$, $n$ decaying from the current offset to 0, $\xi = v_y = 0$, $r = v\kappa$,
    kinematic steering $\arctan((\ell_F + \ell_R)\kappa)$, free-rolling slips, time by the
    trapezoidal rule in $1/v$; the first knot is the current state."""
    M = D_per_stage.shape[0]
    h = horizon / M
    s = s0 + h * jnp.arange(M + 1)
    D = jnp.concatenate([D_per_stage, D_per_stage[-1:]])
    g = vehicle.params.g
    v_lim = jnp.sqrt(fraction * D) * table.speed_limit_at(s)
    v_acc = jnp.sqrt(state8[2] ** 2 + 2.0 * fraction * D * g * (s - s0))
    v = jnp.maximum(jnp.minimum(v_lim, v_acc), 2.0 * SPEED_FLOOR)
    v = v.at[0].set(state8[2])
    kap = table.curvature_at(s)
    wb = vehicle.params.lF + vehicle.params.lR
    delta = jnp.clip(jnp.arctan(wb * kap), -0.5, 0.5)
    decay = jnp.exp(-(s - s0) / 5.0)
    t = jnp.concatenate([jnp.zeros(1), jnp.cumsum(0.5 * h * (1 / v[1:] + 1 / v[:-1]))])
    z = jnp.zeros_like(s)
    xs = jnp.stack([state8[0] * decay, state8[1] * decay, v, z, v * kap, z, z, delta, t], 1)
    xs = xs.at[0, :8].set(state8)
    us = jnp.diff(xs[:, 5:8], axis=0) / h
    return xs, us


def stage_speeds(xs) -> Float[Array, " M"]:
    """The speed $|v|$ [m/s] at the stages' midpoints of the plan ``xs`` (M+1, 9): the mean
    of its knots', at least 1 m/s."""
    v = jnp.hypot(xs[:, 2], xs[:, 3])
    return jnp.maximum(0.5 * (v[:-1] + v[1:]), SPEED_FLOOR)


def shift_plan(xs, us, distance, horizon):
    r"""The plan (knots (M+1, 9), controls (M, $n_u$)) on a grid moved forward by ``distance``
    [m] (interpolated in $s$; past its end the last knot held, its time advanced at the
    last speed), times restarted at 0."""
    M = us.shape[0]
    h = horizon / M
    grid = h * jnp.arange(M + 1)
    q = grid + distance
    cols = jax.vmap(lambda c: jnp.interp(q, grid, c), in_axes=1, out_axes=1)(xs)
    past = jnp.maximum(q - grid[-1], 0.0)
    t = cols[:, 8] + past / jnp.maximum(xs[-1, 2], SPEED_FLOOR)
    cols = cols.at[:, 8].set(t - t[0])
    qm = q[:-1] + 0.5 * h
    mid = grid[:-1] + 0.5 * h
    us_new = jax.vmap(lambda c: jnp.interp(qm, mid, c, right=0.0), in_axes=1, out_axes=1)(us)
    return cols, us_new


def shift_multipliers(lam, nu, z, distance, horizon):
    r"""The multipliers of a plan (`IPSolution`'s ``lam`` (M+1, nx), ``nu``, ``z`` (M+1,
    ng)) on the grid of `shift_plan`: the stages' rows ($k < M$: defects, path
    inequalities) interpolated at the moved stage midpoints (past the end the last stage's
    held), the last knot's row (terminal inequalities) and ``nu`` (the initial state's
    equalities) kept."""
    lam, z = jnp.asarray(lam), jnp.asarray(z)
    M = lam.shape[0] - 1
    h = horizon / M
    mid = h * (jnp.arange(M) + 0.5)
    q = mid + distance
    move = lambda a: a.at[:M].set(jax.vmap(lambda c: jnp.interp(q, mid, c), in_axes=1,
                                           out_axes=1)(a[:M]))
    return move(lam), nu, move(z)


def fit_planner_tire(D=None, scale=1.0, *, tire=None, speed=12.0, max_slip=0.5,
                     anisotropic=False):
    r"""A `FrictionEllipseTire` of the plant tire's steady state: $B, C$ of
    $\sin(C\arctan(Bs))$ least-squares fitted to $\mu_{ss}(s)/\max\mu_{ss}$ of ``tire``
    (default the drive plant's `LumpedLuGre2D` with `lugre2d_bakker1987`) on a road of
    friction scale ``scale`` at ``speed`` [m/s] (`scaled_steady_state_mu`), in pure braking
    ($s = \kappa/(1 - \kappa)$ for the braking slip $\kappa$ up to ``max_slip``) and pure
    side slip ($s = \tan\alpha$, $\alpha$ up to ``max_slip`` rad) together; the peak
    ``D`` as given, or (None) the largest $\mu_{ss}$ of these curves.

    With ``anisotropic`` the two curves are fitted as $\sin(C\arctan(Bs))$ and
    $\rho_y\sin(C\arctan(Bk_ys))$ over the braking peak, with the tire's `lateral_ratio`
    $\rho_y$ and `lateral_stiffness` $k_y$ among the unknowns: the plant's bristles are
    about half as stiff sideways ($\sigma_{0y}/\sigma_{0x}$ = 0.47), its side curve's
    slope at zero slip 0.51 of the braking one and its peak 0.92 of it at 7 m/s. One
    $B$ for both curves (the isotropic fit) takes the side stiffness for the braking one.

    The LuGre curve peaks at a few per cent of slip and falls off after it; the benchmark's
    gravel tire (B = 7, C = 1.6) peaks near 20 %, so a planner with it asks for slips,
    and expects lateral forces, that the plant does not have. The LuGre friction also
    rises as the sliding speed falls (the Stribeck curve, eq. 21): on the nominal road
    (`nominal_scale`, 0.400) its peak is 0.52 at 20 m/s
    (`AxleGripEstimator.reference_speed`) but 0.56 at 12 m/s."""
    from scipy.optimize import least_squares

    from ..tire.friction_ellipse import FrictionEllipseTire
    from ..tire.lumped2d import LumpedLuGre2D
    from ..tire.params import lugre2d_bakker1987
    from .estimator import scaled_steady_state_mu

    tire = LumpedLuGre2D(lugre2d_bakker1987()) if tire is None else tire
    V = float(speed)
    k = np.linspace(0.002, float(max_slip), 80)
    vr = np.concatenate([np.stack([-k * V, 0 * k], 1), np.stack([0 * k, -V * np.tan(k)], 1)])
    c = np.concatenate([(1 - k) * V, np.full_like(k, V)])
    mu = jax.vmap(lambda v, cc: jnp.linalg.norm(scaled_steady_state_mu(tire, scale, v, cc)))(
        jnp.asarray(vr), jnp.asarray(c))
    peak = float(np.max(mu))
    mu = np.asarray(mu) / peak
    sl = np.concatenate([k / (1 - k), np.tan(k)])
    if anisotropic:
        n = len(k)

        def residual(p):
            B, C, ky, ratio = p
            return np.concatenate([np.sin(C * np.arctan(B * sl[:n])) - mu[:n],
                                   ratio * np.sin(C * np.arctan(B * ky * sl[n:])) - mu[n:]])

        fit = least_squares(residual, [20.0, 1.5, 0.5, 0.9],
                            bounds=([0.5, 1.0, 0.05, 0.3], [200.0, 1.99, 2.0, 1.5]))
        B, C, ky, ratio = (float(v) for v in fit.x)
        return FrictionEllipseTire(B=B, C=C, D=peak if D is None else D, lateral_ratio=ratio,
                                   lateral_stiffness=ky)
    fit = least_squares(lambda p: np.sin(p[1] * np.arctan(p[0] * sl)) - mu, [10.0, 1.5],
                        bounds=([0.5, 1.0], [200.0, 1.99]))
    B, C = (float(v) for v in fit.x)
    return FrictionEllipseTire(B=B, C=C, D=peak if D is None else D)


# ---- the controller ---------------------------------------------------------------------


RTI_DERIVATIVE_MESSAGE = (
    "RecedingHorizonDriver(mode='rti'): derivatives of a drive (jax.jvp, jax.grad) are not "
    "available in real-time-iteration mode: its plans are a few interior-point iterations, "
    "not solutions, so neither differentiating the iterations nor the implicit function "
    "theorem gives the derivative of the drive; use mode='converged', whose plans are "
    "differentiated by the implicit function theorem")


@jax.custom_jvp
def no_derivative(x):
    """The identity; differentiating it (either mode) raises `RTI_DERIVATIVE_MESSAGE`."""
    return x


@no_derivative.defjvp
def _no_derivative_jvp(primals, tangents):
    raise TypeError(RTI_DERIVATIVE_MESSAGE)


def _solve_in_steps(prob, xs0, us0, options, multipliers, retry) -> IPSolution:
    r"""`interior_point` of ``prob`` from the guess; where ``retry`` and that solve did not
    converge, solved again in two steps: without the slip bound (`FALLBACK_SLIP`) from the
    same guess, then with it from that plan. The second step's plan is returned where it
    converged, the first solve's otherwise, with the iterations of all three. The
    slip-bounded problem from a cold guess can stall under a growing regularisation where
    the same problem from the unbounded plan converges in some 30 iterations (docs/driver.md,
    "When the first plan does not converge"). One solve in a loop of one pass (three where
    it retries): the program holds the interior point once."""

    def solve(step, xs, us):
        limit = jnp.where(step == 1, FALLBACK_SLIP, prob.slip_limit)
        p = eqx.tree_at(lambda q: q.slip_limit, prob, limit)
        return interior_point(p, xs, us, options, throw=False, multipliers=multipliers)

    blank = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype),
                         eqx.filter_eval_shape(solve, 0, xs0, us0))

    def more(carry):  # step 0: the solve; steps 1 and 2 where it retries
        step, once, _, _ = carry
        return (step == 0) | (retry & ~once.converged & (step < 3))

    def attempt(carry):
        step, once, last, iterations = carry
        sol = solve(step, jnp.where(step == 2, last.xs, xs0), jnp.where(step == 2, last.us, us0))
        once = jax.tree.map(lambda a, b: jnp.where(step == 0, a, b), sol, once)
        return step + 1, once, sol, iterations + sol.iterations

    step, once, last, iterations = jax.lax.while_loop(
        more, attempt, (jnp.zeros((), int), blank, blank, jnp.zeros((), int)))
    sol = jax.tree.map(lambda a, b: jnp.where((step == 3) & last.converged, a, b), last, once)
    return eqx.tree_at(lambda q: q.iterations, sol, iterations)


PLANNER_FIT_SPEED = 12.0
"""Speed [m/s] at which `planner_car` fits its tire's shape to the plant's steady state (the
speeds of the scenarios' corners and their approaches)."""


@functools.cache
def _planner_shape(peak: float, speed: float, anisotropic: bool) -> dict[str, float]:
    lam = float(scale_of_peak(_plant_tire(), peak, REFERENCE_SPEED))
    tire = fit_planner_tire(peak, lam, speed=speed, anisotropic=anisotropic)
    return {k: float(getattr(tire, k)) for k in ("B", "C", "lateral_ratio", "lateral_stiffness")
            if getattr(tire, k) is not None}


def planner_car(D=0.52, *, nominal_peak: float = 0.52, speed: float = PLANNER_FIT_SPEED,
                anisotropic: bool = False) -> ReducedHalfCar:
    r"""The receding-horizon driver's planning car: the benchmark's rally-gravel reduced
    half car (`rally_gravel`) with a `FrictionEllipseTire` of the drive plant's shape,
    $B, C$ of `fit_planner_tire` on the road whose peak at `REFERENCE_SPEED` is
    ``nominal_peak`` (its scale by `scale_of_peak`), at ``speed`` [m/s], and peak ``D``
    (the driver sets each stage's $D_k$ itself); with ``anisotropic``, also the side
    curve's own peak and stiffness (`fit_planner_tire`). The fit is done once per
    (``nominal_peak``, ``speed``, ``anisotropic``).

    The benchmark's gravel tire ($B = 7$, $C = 1.6$, `rally_gravel_car`) peaks near 20 %
    slip; the plant's LuGre tire at 5-6 % and falls off after it. Planned with the former,
    the driver's plans drift at slip angles where the plant has lost much of its lateral
    force. This car's stiff tire ($B$ about 33) needs several RK4 steps per stage of 2 m
    (`RecedingHorizonDriver.steps_per_stage`, `horizon_problem`): with one, the drives of
    the uturn and sturn left the road by metres. With four it completes about half of the
    benchmark corners' drives, none of them faster than the gravel tire's (docs/driver.md).
    It is therefore not the default."""
    from ..tire.friction_ellipse import FrictionEllipseTire
    from ..vehicle.params import rally_gravel

    shape = _planner_shape(float(nominal_peak), float(speed), bool(anisotropic))
    return ReducedHalfCar(params=rally_gravel(), tire=FrictionEllipseTire(D=D, **shape))


def _default_car() -> ReducedHalfCar:
    from ..optimal.primitives import rally_gravel_car

    return rally_gravel_car()


class HorizonState(eqx.Module):
    """The driver between samples: the time `t` of the last measurement, arc length `s` of
    its projection, the filtered `position` $(x, y)$, its error variance `position_var`
    [m^2] (per axis) and the measured ground `velocity` in the inertial frame, the plan
    (`xs`, `us`, starting at `s_plan`; its multipliers `lam`, `nu`, `z`), the `inputs`
    $(\\kappa_F, \\kappa_R, \\delta)$ of the last command, and its diagnostics:
    `iterations`, `converged`, `kkt` (the largest of the residuals), `D` (M,) the planner's
    peak friction, `projection` $(s, n, \\xi)$; `planned`: whether a plan has been solved
    (False after `RecedingHorizonDriver.init`, whose first plan the first command solves);
    `probing`: whether the last command was a test brake (`RecedingHorizonDriver`'s
    `probe_distance`)."""

    t: Float[Array, ""]
    s: Float[Array, ""]
    position: Float[Array, " 2"]
    position_var: Float[Array, ""]
    velocity: Float[Array, " 2"]
    s_plan: Float[Array, ""]
    xs: Float[Array, "M+1 9"]
    us: Float[Array, "M nu"]
    lam: Float[Array, "M+1 9"]
    nu: Array
    z: Array
    inputs: Float[Array, " 3"]
    iterations: Array
    converged: Array
    kkt: Float[Array, ""]
    D: Float[Array, " M"]
    projection: Float[Array, " 3"]
    planned: Bool[Array, ""]
    probing: Bool[Array, ""]


PROBE_DIRECTIONS = ("brake", "plan", "balanced")
"""`RecedingHorizonDriver.probe_direction`: the test brakes the front axle; or brakes or
drives it as the plan slows or speeds the car there; or brakes it while the rear axle
drives."""


class RecedingHorizonDriver(AbstractDriveController):
    r"""The receding-horizon driver of the module docstring.

    **Fields:** `table` (`RoadTable`), `vehicle` (the planning `ReducedHalfCar` with a
    `FrictionEllipseTire`; default `rally_gravel_car()`; `planner_car()` has a tire of the
    plant's shape),
    `horizon` $H$ [m] (60), `num_stages` $M$ (30, static), `steps_per_stage` (1, static;
    the RK4 steps of each stage, several for a stiff planning tire, `horizon_problem`),
    `margin`
    [m] (0.2) and `margin_grip_power` $p$ (0: the margin the same on every surface; else
    the margin times $\min(1, D_k/D)^p$, narrower where the planned grip is low,
    `horizon_problem`), `position_margin` $z$ (None: off) the number of the position
    filter's standard deviations added to `margin` at each sample, $m + z\sqrt{P_k}$
    (`planning_margin`), `stiffness_power` $q$ (None: the tire's $B$ on every surface;
    else $B \min(1, D_k/D)^{-q}$, its slip stiffness scaling as $(D_k/D)^{1-q}$ below
    the car's grip, `scaled_planning_car`), `rate_weight` $w$ (1e-4),
    `terminal_backoff` $\beta$ (1);
    `mode` (static): 'rti' (real-time iteration: `iterations` interior-point passes per
    sample from the shifted plan, barrier `mu0`, whether or not they converge; the last
    pass only evaluates, so `iterations` - 1 steps) or 'converged' (to `tol`, at most
    `max_iterations`); `friction` (static): 'nominal' (the nominal
    road, whose peak at `reference_speed` is `nominal_peak`, 0.52), 'oracle' (the
    `table`'s friction scale at the stages' midpoints: the true grip, known ahead as far as
    `preview` [m], default inf) or
    'estimate' (the estimator's belief, less `estimate_backoff` standard deviations
    (default 0: the estimate itself; planning below the plant's grip also misleads the
    torque recovery, and measured drives left the road more often, docs/driver.md);
    needs an estimator in `simulate_drive`; the first plan uses its prior),
    each at the stages' speeds (below); `slip_gain` [N m] (torque per unit slip error, 0:
    feedforward only), `lead` [s] (the plan is read this far past the predicted state: the
    actuators' lag), `position_std` [m] and `velocity_std` [m/s] (the standard deviations
    the position filter assumes for a GNSS fix and for each axis of the measured velocity
    over ground, `filter_position`; 0.3 and 0.1), `steer_rate` [rad/s] and
    `steer_limit` [rad] (the steering actuator's), `sample_time` [s] and `delay_samples`
    (static; the actuators' delay), `init_iterations` (cap of the first plan's solve, and
    of each of its two steps where it is solved again: `_solve_in_steps`),
    `warm_start` (static): 'primal' (the shifted plan; the multipliers start afresh, the
    least-squares estimate) or 'primal-dual' (also the previous plan's multipliers, shifted
    by `shift_multipliers`, where that plan converged: `interior_point`'s
    ``multipliers``); default None: 'primal-dual' in 'converged' mode, 'primal' in 'rti'
    mode; `mu0` the first barrier of a sample's solve (default None: `barrier`);
    `plant_tire` (the `LumpedLuGre2D` whose peak `peak_friction` turns a friction scale into
    $D$; default the drive plant's), `reference_speed` [m/s] (the speed `nominal_peak` is
    stated at; `REFERENCE_SPEED`, 20), `peak_speed` (static; None: each stage's planned
    speed, below; a number [m/s]: that speed for every stage, a planner whose $D$ does not
    depend on its speed), `slip_limit` (0.15; None: no bound) the bound on each axle's
    combined slip in the plans (`horizon_problem`), `peak_fraction` (in (0, 1]; 1) the
    fraction of the believed peak the plans use (a margin for what the planning model gets
    wrong: the plant's force at the planned slips, the loads' dynamics), `hessian_update`
    (static; 'every') the sample solves' `IPOptions.hessian_update` ('first': each
    sample's first step's Hessian kept for its later passes, which then cost about a third;
    `fresh_hessian_steps` (1) the steps of a sample's solve that take a fresh one before it
    is kept),
    `jacobian_update` (static; 'every') their `IPOptions.jacobian_update` ('first', with
    `hessian_update` 'first': the first step's Jacobians kept too, the later passes
    evaluating the stages' values and the Lagrangian's gradient only; docs/performance.md
    for what it did to the stage's drives), `preview` [m] (inf) how far ahead of the car
    the 'oracle' knows the grip (or, with
    `surface_map`, the estimate the surface); `surface_map` (static; False) with
    'estimate': the `table`'s `scale` column is a map of the road's *relative* grip (pace
    notes, a camera's surface classification; below); `replan_kkt` (inf: never) the KKT
    residual of a sample's plan past which the next sample plans again from the cold start
    (`profile_guess`, every stage at the predicted speed, the first plan's options), not
    from the shifted plan: a real-time iteration that lost its plan (infeasible at the
    friction limit, its residual climbing) otherwise keeps following it;
    `replan_iterations` (300) the cap of such a re-plan's passes (a re-plan stopped there
    is used as it stands, as a real-time iteration's plan is); `corridor_penalty` $\rho$
    [s/m] (None: a hard corridor) the plans' soft corridor (`HorizonOCP`): a plan may leave
    the corridor at a cost of $\rho$ seconds per metre at each knot, so that a state from
    which no plan keeps inside it still has a plan, the one that leaves it least;
    `soft_stages` (None: every stage) the number of first stages whose corridor is soft,
    the rest hard: with 1 and $\rho$ = 100 s/m in 'converged' mode every solve of a corner
    drive converged, but in 'rti' mode it lost drives the hard corridor kept on the road
    (docs/drive.md, "A soft first stage").
    `probe_distance` [m] (None: never) with 'estimate': a test brake on the front axle over
    the road's first `probe_distance` metres (on a circuit the first lap's: the projected
    arc length runs on) while the grip is not known (below), asking
    `probe_utilisation` (0.95) of the believed peak, until the front axle's belief is
    narrower than `probe_std` (0.25); `probe_direction` (static; 'brake') 'balanced' for a
    test whose front brake is balanced by the rear axle driving, or 'plan' for one that
    drives the front axle instead where the plan speeds the car up; `traction_limit`
    $\rho$ (in (0, 1]; 0.9; None: off) the traction control (below); `peak_model`
    (static): 'plant' (the stages' peak of `plant_tire` at their speeds, below) or
    'estimated' (with 'estimate' only: every stage plans with the estimate's
    `GripEstimate.peak` itself, the smaller axle's less
    `estimate_backoff` times its `peak_std`, times the map's ratio with `surface_map` (as a
    ratio of `plant_tire`'s peaks at the estimate's scale);
    no tire shape, no speed dependence: for a shape-free estimator such as
    `AxlePeakEstimator` on a plant whose tire is not `plant_tire`'s family) or 'cautious'
    (each stage the smaller of the two: the 'plant' peak of the estimate's `scale` and the
    'estimated' one of its `peak`; for `CautiousGripEstimator`, whose `scale` is a
    model-based estimator's and whose `peak` a shape-free one's).

    **The test brake.** The estimator learns only where an axle uses most of the grip it
    believes in (`driver_estimator`), and a driver that trusts its prior first does so
    where it brakes for the first corner: on a road worse than believed it has then
    already arrived too fast. A rally driver brakes once on the first straight to feel the
    surface; with `probe_distance` this driver does the same. While the arc length is below
    `probe_distance` and the front axle's $\sigma_F$ = `scale_std`/`scale` (the standard
    deviation of its $\log\lambda$; the prior's 0.3) is at least `probe_std`, the command
    brakes the front axle at least at the planner's slip $-\kappa_p$ (`probe_slip`: the
    slip at which the planning tire gives `probe_utilisation` of the believed peak, more
    than the estimator's gate of 70 %), held, and takes the rear axle and the steering
    from the plan. A road with that much grip gives informative samples at once; a worse
    one makes the front wheels slide, which counts too (`sliding_slip`). One axle, the
    front, so that the car slows by half as much and stays straight; the planner takes the
    smaller axle's peak, so a front axle that finds less grip than believed slows every
    plan at once. The plans go on from the braking car, so the test costs only the speed
    it takes off; it ends with the first informative sample (the actuators' delay and lag:
    three commands at 20 Hz) or at `probe_distance`. The condition is evaluated at every
    sample, not latched: a belief that widens again within the distance (the estimator's
    change detector resets it to its prior's width) brakes again. A car that starts below
    the speed its plan wants pays for a brake twice, the speed it takes off and the
    acceleration it postpones. With `probe_direction` 'balanced' the rear axle drives
    meanwhile at the same combined slip (at least; traction control caps its torque), so
    that the two axles' forces nearly cancel: the front axle is tested as before and the
    car keeps its speed. With 'plan' the test follows the plan's sign instead, driving the
    front axle where the plan's slips sum positive, and the car gains speed it must brake
    off later (docs/driver.md has what each measured).

    **Traction control.** The torques realise the planned slips through the wheel
    equations with the planner's tire force, $T_i = I_i\dot\omega_i + r f_{ix}$. Where
    that force is more than the plant's tire can give at the wheel's lateral slip, the
    wheel has no steady slip: past the LuGre peak (5-6 % slip) the force falls as the slip
    grows, and a driven wheel spins up (a braked one locks) until the torque falls. On the
    benchmark corners without it the rear wheels spun to slips of 1.6-3.4 on every
    corner's exit, a front wheel to 29 on one drive, and the car, its tires sliding, ran
    wide.
    With `traction_limit` $\rho$ each axle's $f_{ix}$ in the torque is clipped to $\rho
    F_{iz}$ times the plant tire's `longitudinal_capacity` at the axle's planned
    velocity, on the road the driver believes to be under that axle (`believed_scales`):
    the wheel then finds a steady slip below the peak, where the plant's force is what
    the torque asks. A sample-rate slip feedback (`slip_gain`) cannot do this: the
    wheel's instability past the peak is faster (tens of 1/s) than a 20 Hz loop behind a
    delay; measured, it roughly halved the spin and left it. docs/drive.md has the
    measurements.

    **The slip bound.** The planner's friction-ellipse tire ($B = 7$, $C = 1.6$) keeps
    most of its force far past its peak, so an unbounded minimum-time plan drifts (rear
    slips of 0.6, side slip near 50 degrees on corner90), where the plant's LuGre tire,
    peaking at 5-6 % slip, has lost much of its force: the car ran wide by 0.2-0.4 m. At
    0.15 the planner's tire still has 96 % of its peak and the plans stay where the two
    tires agree (docs/driver.md has the measurements).

    **The stages' peak friction.** All three modes believe in a road, a friction scale
    $\lambda$ (the nominal one, the true one ahead, the estimated one), and plan stage $k$
    with that road's peak at the speed they drive it at, $D_k = \mu^*(\lambda, V_k)$
    (`peak_friction` of `plant_tire`): the LuGre peak rises as the speed falls (eq. 21;
    0.52 at 20 m/s, 0.65 at 4 m/s on the nominal road), and the corners are driven far
    below the speed the grips are stated at. $V_k$ is the speed $|v|$ at the stage's
    midpoint of the previous plan shifted to the new start (`stage_speeds`; the first plan:
    the measured speed), at least 1 m/s. 'nominal': $\lambda$ the road whose peak at
    `reference_speed` is `nominal_peak`; 'oracle': the `table`'s `scale` at the stage's
    midpoint $s_k$, or at $s_0$ + `preview` where that is nearer (the road beyond the
    preview believed to go on as last seen: `preview` = 0 is an estimator that knows the
    grip under the car at once and nothing ahead); 'estimate': per axle
    $\mu^*(\lambda_a, V_k) - \beta\,|\partial\mu^*/\partial\vartheta|\,\sigma_a$ with the
    estimate's $\lambda_a$ (`GripEstimate.scale`) and $\sigma_a$ = `scale_std`/`scale` the
    standard deviation of $\vartheta = \log \lambda_a$, $\beta$ = `estimate_backoff`, the
    smaller axle's, clipped to [0.05, 2] (at $V_k$ = `reference_speed`: `GripEstimate.peak`
    less $\beta$ `peak_std`). With `surface_map`, stage $k$ believes
    $\lambda_a\,r(\bar s_k)/r(s_a)$ instead: the estimate, which holds for the surface under
    axle $a$, carried to the stage's surface by the ratio of the map $r$ (the table's
    `scale` column at the stage's midpoint $\bar s_k$, or at $s_0$ + `preview` where that is
    nearer, as the oracle) to the map under that axle when it was measured, $s_a = s_m +
    \ell_F$ or $s_m - \ell_R$ with $s_m$ the measured arc length (not the plan's start
    predicted over the delay). Referred to the centre of gravity instead, a road whose grip
    changes along the wheelbase is counted twice: on a rising road the rear axle, still on
    the worse surface, believed every stage worse by its ratio over $\ell_R$, and the planner
    took the smaller axle's. The map states how the surfaces compare, the estimate how much
    grip there is: give the estimator the same map (`AxleGripEstimator.surface`), so that
    its $\lambda_a$ is that of the surface under the axle as soon as the axle reaches it.

    **Derivatives.** In 'converged' mode every plan is differentiated by the implicit
    function theorem at the solution returned (`interior_point` with ``implicit``): a
    drive's derivatives in forward and reverse mode are those of its converged plans (and
    only as good as their convergence); a plan that did not converge has none, and the
    drive's derivative raises `UNCONVERGED_DERIVATIVE_MESSAGE` when it runs. In 'rti' mode
    a plan is a few iterations, not a solution: derivatives raise `RTI_DERIVATIVE_MESSAGE`.

    **Assumptions.** Float64 (`jax_enable_x64`; the driver refuses to be built without
    it: in float32 its plans do not converge). The prediction over the delay assumes the
    plant's actuators: the command issued now acts from the next sample, and meanwhile the
    last command's slips and steering hold. The planning model is the reduced car (quasi-static loads, slips as
    inputs, no wheel or suspension dynamics) with a friction-ellipse tire; the torques
    realise the planned slips only as far as the plant's tire agrees with the planner's.
    The horizon must hold the braking before a corner and the corner itself (60 m at
    12-15 m/s before a 15 m radius: with 30 m the plans cut inside early and braked to the
    centre line's speed at their end).
    """

    table: RoadTable
    vehicle: ReducedHalfCar = eqx.field(default_factory=_default_car)
    horizon: Float[Array, ""] = array_field(default=60.0)
    num_stages: int = eqx.field(static=True, default=30)
    steps_per_stage: int = eqx.field(static=True, default=1)
    margin: Float[Array, ""] = array_field(default=0.2)
    margin_grip_power: Float[Array, ""] = array_field(default=0.0)
    position_margin: Float[Array, ""] | None = eqx.field(
        default=None, converter=lambda x: None if x is None else float_array(x))
    rate_weight: Float[Array, ""] = array_field(default=1e-4)
    terminal_backoff: Float[Array, ""] = array_field(default=1.0)
    mode: str = eqx.field(static=True, default="rti")
    iterations: int = eqx.field(static=True, default=4)
    max_iterations: int = eqx.field(static=True, default=100)
    init_iterations: int = eqx.field(static=True, default=300)
    tol: float = eqx.field(static=True, default=1e-6)
    mu0: Float[Array, ""] | None = eqx.field(
        default=None, converter=lambda x: None if x is None else float_array(x))
    friction: str = eqx.field(static=True, default="nominal")
    nominal_peak: Float[Array, ""] = array_field(default=0.52)
    estimate_backoff: Float[Array, ""] = array_field(default=0.0)
    slip_gain: Float[Array, ""] = array_field(default=0.0)
    lead: Float[Array, ""] = array_field(default=0.05)
    position_std: Float[Array, ""] = array_field(default=0.3)
    velocity_std: Float[Array, ""] = array_field(default=0.1)
    steer_rate: Float[Array, ""] = array_field(default=1.0)
    steer_limit: Float[Array, ""] = array_field(default=0.6)
    sample_time: Float[Array, ""] = array_field(default=0.05)
    delay_samples: int = eqx.field(static=True, default=1)
    warm_start: str | None = eqx.field(static=True, default=None)
    plant_tire: LumpedLuGre2D = eqx.field(default_factory=_plant_tire)
    reference_speed: Float[Array, ""] = array_field(default=REFERENCE_SPEED)
    peak_speed: float | None = eqx.field(static=True, default=None)
    slip_limit: Float[Array, ""] | None = eqx.field(
        default=0.15, converter=lambda x: None if x is None else float_array(x))
    peak_fraction: Float[Array, ""] = array_field(default=1.0)
    hessian_update: str = eqx.field(static=True, default="every")
    jacobian_update: str = eqx.field(static=True, default="every")
    fresh_hessian_steps: Int[Array, ""] = int_field(default=1)
    preview: Float[Array, ""] = array_field(default=math.inf)
    surface_map: bool = eqx.field(static=True, default=False)
    replan_kkt: Float[Array, ""] = array_field(default=math.inf)
    replan_iterations: Int[Array, ""] = int_field(default=300)
    corridor_penalty: Float[Array, ""] | None = eqx.field(
        default=None, converter=lambda x: None if x is None else float_array(x))
    soft_stages: Int[Array, ""] | None = eqx.field(
        default=None, converter=lambda x: None if x is None else int_array(x))
    stiffness_power: Float[Array, ""] | None = eqx.field(
        default=None, converter=lambda x: None if x is None else float_array(x))
    probe_distance: Float[Array, ""] | None = eqx.field(
        default=None, converter=lambda x: None if x is None else float_array(x))
    probe_utilisation: Float[Array, ""] = array_field(default=0.95)
    probe_std: Float[Array, ""] = array_field(default=0.25)
    probe_direction: str = eqx.field(static=True, default="brake")
    traction_limit: Float[Array, ""] | None = eqx.field(
        default=0.9, converter=lambda x: None if x is None else float_array(x))
    peak_model: str = eqx.field(static=True, default="plant")

    def __check_init__(self):
        require_float64("RecedingHorizonDriver",
                        "In float32 its horizon problems do not converge (the first plan's "
                        "residual stays near 1) and the car drives on without a plan")
        if self.mode not in ("rti", "converged"):
            raise ValueError(f"RecedingHorizonDriver.mode must be 'rti' or 'converged', got "
                             f"{self.mode!r}")
        if self.warm_start not in (None, "primal", "primal-dual"):
            raise ValueError("RecedingHorizonDriver.warm_start must be 'primal' or "
                             f"'primal-dual', got {self.warm_start!r}")
        if self.hessian_update not in ("every", "first"):
            raise ValueError("RecedingHorizonDriver.hessian_update must be 'every' or 'first', "
                             f"got {self.hessian_update!r}")
        if self.jacobian_update not in ("every", "first"):
            raise ValueError("RecedingHorizonDriver.jacobian_update must be 'every' or "
                             f"'first', got {self.jacobian_update!r}")
        if self.jacobian_update == "first" and self.hessian_update != "first":
            raise ValueError("RecedingHorizonDriver.jacobian_update='first' needs "
                             f"hessian_update='first', got {self.hessian_update!r}")
        if self.peak_model not in ("plant", "estimated", "cautious"):
            raise ValueError("RecedingHorizonDriver.peak_model must be 'plant', 'estimated' or "
                             f"'cautious', got {self.peak_model!r}")
        if self.peak_model != "plant" and self.friction != "estimate":
            raise ValueError(f"RecedingHorizonDriver.peak_model={self.peak_model!r} plans with "
                             "the estimate's peak: it needs friction='estimate', got "
                             f"{self.friction!r}")
        if self.friction not in ("nominal", "oracle", "estimate"):
            raise ValueError("RecedingHorizonDriver.friction must be 'nominal', 'oracle' or "
                             f"'estimate', got {self.friction!r}")
        if not isinstance(self.num_stages, int) or self.num_stages < 2:
            raise ValueError(f"RecedingHorizonDriver.num_stages must be an integer >= 2, got "
                             f"{self.num_stages}")
        if not isinstance(self.iterations, int) or self.iterations < 2:
            raise ValueError("RecedingHorizonDriver.iterations must be an integer >= 2 (the "
                             f"last pass only evaluates), got {self.iterations}")
        for name in ("horizon", "sample_time", "steer_rate", "steer_limit", "nominal_peak",
                     "terminal_backoff", "mu0", "reference_speed", "slip_limit",
                     "position_std", "corridor_penalty", "probe_distance", "probe_std",
                     "soft_stages"):
            if getattr(self, name) is not None:
                check_positive("RecedingHorizonDriver", name, getattr(self, name))
        if self.soft_stages is not None and self.corridor_penalty is None:
            raise ValueError("RecedingHorizonDriver.soft_stages needs corridor_penalty (the "
                             "soft corridor's cost, > 0), got None")
        for name in ("velocity_std", "margin", "margin_grip_power", "position_margin",
                     "rate_weight", "estimate_backoff", "slip_gain", "lead"):
            if getattr(self, name) is not None:
                check_nonnegative("RecedingHorizonDriver", name, getattr(self, name))
        if self.stiffness_power is not None:
            check_range("RecedingHorizonDriver", "stiffness_power", self.stiffness_power,
                        lower=0.0, upper=1.0)
        if not (isinstance(self.tol, int | float) and math.isfinite(self.tol)
                and self.tol > 0):
            raise ValueError("RecedingHorizonDriver.tol must be a number in (0, inf), got "
                             f"{self.tol!r}")
        check_count("RecedingHorizonDriver", "steps_per_stage", self.steps_per_stage)
        check_count("RecedingHorizonDriver", "max_iterations", self.max_iterations)
        check_count("RecedingHorizonDriver", "init_iterations", self.init_iterations)
        check_count("RecedingHorizonDriver", "delay_samples", self.delay_samples, lower=0)
        check_range("RecedingHorizonDriver", "preview", self.preview, lower=0.0,
                    allow_inf=True)  # inf: the whole horizon
        check_range("RecedingHorizonDriver", "replan_kkt", self.replan_kkt, lower=0.0,
                    lower_open=True, allow_inf=True)  # inf: never
        if not jnp.issubdtype(jnp.result_type(self.replan_iterations), jnp.integer):
            raise ValueError("RecedingHorizonDriver.replan_iterations must be an integer >= 1, "
                             f"got {self.replan_iterations}")
        check_range("RecedingHorizonDriver", "replan_iterations", self.replan_iterations,
                    lower=1.0)
        check_integer("RecedingHorizonDriver", "fresh_hessian_steps", self.fresh_hessian_steps,
                      lower=1)
        if self.probe_distance is not None and self.friction != "estimate":
            raise ValueError("RecedingHorizonDriver.probe_distance is a test brake that "
                             "excites the grip estimator: it needs friction='estimate', got "
                             f"{self.friction!r}")
        if self.surface_map and self.friction != "estimate":
            raise ValueError("RecedingHorizonDriver.surface_map carries the estimate along a "
                             "map of the relative grip: it needs friction='estimate', got "
                             f"{self.friction!r}")
        if (is_concrete(self.preview) and np.any(np.isfinite(self.preview))
                and self.friction != "oracle" and not self.surface_map):
            raise ValueError("RecedingHorizonDriver.preview limits what the 'oracle' (or the "
                             "estimate with surface_map=True) knows ahead; "
                             f"friction={self.friction!r} has no preview (leave it inf)")
        check_range("RecedingHorizonDriver", "peak_fraction", self.peak_fraction, lower=0.0,
                    upper=1.0, lower_open=True)
        check_range("RecedingHorizonDriver", "probe_utilisation", self.probe_utilisation,
                    lower=0.0, upper=1.0, lower_open=True)
        if self.probe_direction not in PROBE_DIRECTIONS:
            raise ValueError("RecedingHorizonDriver.probe_direction must be one of "
                             f"{', '.join(map(repr, PROBE_DIRECTIONS))}, got "
                             f"{self.probe_direction!r}")
        if self.traction_limit is not None:
            check_range("RecedingHorizonDriver", "traction_limit", self.traction_limit,
                        lower=0.0, upper=1.0, lower_open=True)
        if not isinstance(self.plant_tire, LumpedLuGre2D):
            raise TypeError("RecedingHorizonDriver.plant_tire must be a LumpedLuGre2D, got "
                            f"{type(self.plant_tire).__name__}")
        if self.peak_speed is not None and not (math.isfinite(self.peak_speed)
                                                and self.peak_speed > 0):
            raise ValueError("RecedingHorizonDriver.peak_speed must be None or a speed > 0 "
                             f"m/s, got {self.peak_speed}")

    @property
    def warm_duals(self) -> bool:
        """Whether the solves start from the previous plan's multipliers (`warm_start`;
        default: in 'converged' mode)."""
        if self.warm_start is None:
            return self.mode == "converged"
        return self.warm_start == "primal-dual"

    @property
    def barrier(self):
        """The first barrier of a sample's solve: `mu0`, by default $10^{-3}$ in 'rti'
        mode and $10^{-4}$ in 'converged' mode (with the multipliers warm-started a larger
        barrier pushes the active inequalities' slacks off the previous solution)."""
        if self.mu0 is not None:
            return self.mu0
        return jnp.asarray(1e-4 if self.warm_duals else 1e-3)

    # ---- pieces -----------------------------------------------------------------------

    def options(self, first=False, replan=False) -> IPOptions:
        """The interior-point options of a sample; ``first`` (a boolean, or a boolean
        array: one program for both): the first plan's, a cold start solved to convergence
        (at most `init_iterations`, IPOPT's first barrier 0.1, the multipliers'
        re-estimate on) by Newton's method (a fresh Hessian every step, whatever
        `hessian_update`); ``replan``: a lost plan's re-plan, the same at most
        `replan_iterations`."""
        cap = self.iterations if self.mode == "rti" else self.max_iterations
        cold_cap = jnp.where(replan, self.replan_iterations, self.init_iterations)
        first = first | replan
        # a real-time iteration does a fixed work per sample: no uncounted re-estimates
        return IPOptions(max_iter=jnp.where(first, cold_cap, cap), tol=self.tol,
                         constr_tol=self.tol,
                         mu0=jnp.where(first, IPOptions().mu0, self.barrier),
                         log_size=8, hessian_update=self.hessian_update,
                         jacobian_update=self.jacobian_update,
                         fresh_hessian_steps=jnp.where(first, self.init_iterations,
                                                       self.fresh_hessian_steps),
                         reestimate_multipliers=first | (self.mode == "converged"),
                         backward_error_singular=PLAN_BACKWARD_ERROR,
                         max_refinement_steps=PLAN_REFINEMENT_STEPS)

    def stage_speeds(self, xs) -> Float[Array, " M"]:
        """`stage_speeds` of the plan ``xs``."""
        return stage_speeds(xs)

    def _peaks(self, scale, speeds):
        r"""$\mu^*$ of `plant_tire` at the scale(s) and speeds (M,)."""
        scale, speeds = jnp.broadcast_arrays(scale, speeds)
        return jax.vmap(lambda lam, v: peak_friction(self.plant_tire, lam, v))(scale, speeds)

    def _peak_ratios(self, scale, log_ratio):
        r"""The map's scale ratios $e^{\rho_k}$ from the car's surface (friction scale
        `scale`) as ratios of `plant_tire`'s peaks at `reference_speed`:
        $\mu^*(\lambda e^{\rho_k})/\mu^*(\lambda)$ (1 without a map). The LuGre peak is not
        proportional to its scale (the icy patch's scale ratio 0.44 is a peak ratio of 0.50)."""
        if not self.surface_map:
            return jnp.ones_like(log_ratio)
        lam = scale * jnp.exp(jnp.concatenate([log_ratio, jnp.zeros(1)]))
        peaks = self._peaks(lam, self.reference_speed)
        return peaks[:-1] / peaks[-1]

    def _stage_speed(self, speeds):
        M = self.num_stages
        if self.peak_speed is None:
            return jnp.maximum(jnp.broadcast_to(jnp.asarray(speeds, float), (M,)), SPEED_FLOOR)
        return jnp.full((M,), float(self.peak_speed))

    def nominal_friction(self, speeds) -> Float[Array, " M"]:
        r"""$D_k$ of the nominal road (whose peak at `reference_speed` $V_0$ is
        `nominal_peak` $D_0$) at the stages' ``speeds`` [m/s] (`peak_speed` overrides
        them): $D_0\,\mu^*(\lambda_0, V_k)/\mu^*(\lambda_0, V_0)$, $\lambda_0$ =
        `scale_of_peak` of $D_0$ (so $D_0$ exactly at $V_0$)."""
        lam = scale_of_peak(self.plant_tire, self.nominal_peak, self.reference_speed)
        V = self._stage_speed(speeds)
        # the reference in the same vectorised call as the stages: the same rounding, so
        # the ratio is exactly 1 at the reference speed however the drive is compiled
        peaks = self._peaks(lam, jnp.concatenate([V, jnp.reshape(self.reference_speed, (1,))]))
        return self.nominal_peak * peaks[:-1] / peaks[-1]

    def planner_friction(self, s0, estimate, speeds, s_measured=None) -> Float[Array, " M"]:
        """The stages' peak friction $D_k$ for the horizon starting at ``s0``, the stages
        driven at ``speeds`` [m/s] (M,) (class docstring; `peak_speed` overrides them):
        `peak_fraction` of the believed peak. ``s_measured`` (default ``s0``): the arc
        length of the centre of gravity where ``estimate`` was measured, whose axles'
        surfaces a `surface_map` refers the estimate to."""
        return self.peak_fraction * self._believed_peaks(s0, estimate, speeds, s_measured)

    def _believed_peaks(self, s0, estimate, speeds, s_measured=None):
        M = self.num_stages
        V = self._stage_speed(speeds)
        if self.friction == "nominal":
            return self.nominal_friction(V)
        h = self.horizon / M
        seen = jnp.minimum(s0 + h * (jnp.arange(M) + 0.5), s0 + self.preview)
        if self.friction == "oracle":
            return self._peaks(self.table.scale_at(seen), V)
        if estimate is None:
            raise ValueError("RecedingHorizonDriver(friction='estimate') needs a grip "
                             "estimator: pass estimator= to simulate_drive")
        theta = jnp.log(estimate.scale)
        sigma = estimate.scale_std / estimate.scale
        if self.surface_map:  # each axle's estimate carried along the map's ratios
            sm = s0 if s_measured is None else s_measured
            under = jnp.log(self.table.scale_at(self.axle_arc_lengths(sm)))
            ratio = jnp.log(self.table.scale_at(seen))[None, :] - under[:, None]
        else:
            ratio = jnp.zeros((2, M))

        if self.peak_model != "plant":  # the estimate's peak itself, at every speed
            lower = estimate.peak - self.estimate_backoff * estimate.peak_std
            measured = jnp.min(lower[:, None] * jax.vmap(self._peak_ratios)(estimate.scale,
                                                                             ratio), axis=0)
            if self.peak_model == "estimated":
                return jnp.clip(measured, 0.05, 2.0)

        def axle(th, sd, ratio):
            def stage(v, r):
                p, dp = jax.jvp(lambda t: peak_friction(self.plant_tire, jnp.exp(t), v),
                                (th + r,), (jnp.ones_like(th),))
                return p - self.estimate_backoff * jnp.abs(dp) * sd
            return jax.vmap(stage)(V, ratio)

        D = jnp.min(jax.vmap(axle)(theta, sigma, ratio), axis=0)
        if self.peak_model == "cautious":
            D = jnp.minimum(D, measured)
        return jnp.clip(D, 0.05, 2.0)

    def planning_margin(self, position_var) -> Float[Array, ""]:
        r"""The corridor margin of a sample whose position filter has the variance
        ``position_var`` $P_k$ [m^2] (`filter_position`): $m + z\sqrt{P_k}$, $m$ =
        `margin`, $z$ = `position_margin` (None: $m$ itself). The filter's standard deviation falls from
        `position_std` at the first fix to a few centimetres; with noisy fixes the car is
        that far from where the driver believes it is, which a fixed margin has to cover
        at its largest (docs/driver.md, "A margin from the position's uncertainty")."""
        if self.position_margin is None:
            return self.margin
        return self.margin + self.position_margin * jnp.sqrt(position_var)

    def problem(self, s0, state8, D, margin=None) -> HorizonOCP:
        """`horizon_problem` with this driver's settings (and ``margin`` in place of
        `margin` where given)."""
        margin = self.margin if margin is None else margin
        return horizon_problem(self.table, self.vehicle, s0, state8, D, horizon=self.horizon,
                               margin=margin, rate_weight=self.rate_weight,
                               steer_rate=self.steer_rate, steer_limit=self.steer_limit,
                               terminal_backoff=self.terminal_backoff,
                               slip_limit=self.slip_limit,
                               margin_grip_power=self.margin_grip_power,
                               corridor_penalty=self.corridor_penalty,
                               soft_stages=self.soft_stages,
                               stiffness_power=self.stiffness_power,
                               steps_per_stage=self.steps_per_stage)

    def cold_guess(self, s0, state8, D):
        """`profile_guess` with this driver's horizon (and a zero slack with
        `corridor_penalty`)."""
        xs, us = profile_guess(self.table, self.vehicle, s0, state8, D, horizon=self.horizon)
        if self.corridor_penalty is not None:
            us = jnp.concatenate([us, jnp.zeros_like(us[:, :1])], 1)
        return xs, us

    def _frenet_rates(self, X5, inputs, s):
        """Time derivative of $(s, n, \\xi, v_x, v_y, r)$ of the reduced car (eqs. 61-63)."""
        n, xi, vx, vy, r = X5[0], X5[1], X5[2], X5[3], X5[4]
        kap = self.table.curvature_at(s)
        sdot = (vx * jnp.cos(xi) - vy * jnp.sin(xi)) / (1.0 - n * kap)
        body = self.vehicle.f(jnp.stack([0.0 * n, 0.0 * n, xi, vx, vy, r]), inputs)[3:6]
        return jnp.concatenate([jnp.stack([sdot, vx * jnp.sin(xi) + vy * jnp.cos(xi),
                                           r - kap * sdot]), body])

    def predict(self, s, X5, inputs, duration, steps: int = 2):
        """$(s, n, \\xi, v_x, v_y, r)$ after ``duration`` [s] with constant ``inputs``
        (classical RK4, ``steps`` steps)."""
        y = jnp.concatenate([jnp.reshape(s, (1,)), X5])
        dt = duration / steps

        def f(y):
            return self._frenet_rates(y[1:], inputs, y[0])

        def step(y, _):
            k1 = f(y)
            k2 = f(y + 0.5 * dt * k1)
            k3 = f(y + 0.5 * dt * k2)
            k4 = f(y + dt * k3)
            return y + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4), None

        y, _ = jax.lax.scan(step, y, None, length=steps)
        return y

    def _solve(self, prob, xs0, us0, options, multipliers=None, retry=False) -> IPSolution:
        """The plan (the guess kept where the solve broke down). A converged-mode plan is
        differentiated by the implicit function theorem (`interior_point`'s ``implicit``);
        a real-time iteration's refuses derivatives (`RTI_DERIVATIVE_MESSAGE`). Where
        ``retry`` (the first plan) and the solve did not converge, it is solved again in two
        steps (`_solve_in_steps`)."""
        implicit = self.mode == "converged"
        if prob.slip_limit is None or retry is False:
            sol = interior_point(prob, xs0, us0, options, throw=False,
                                 multipliers=multipliers, implicit=implicit)
        elif implicit:
            sol = implicit_solve(prob, (xs0, us0, options, multipliers, retry),
                                 solve=_solve_in_steps)
        else:
            sol = _solve_in_steps(prob, xs0, us0, options, multipliers, retry)
        ok = jnp.all(jnp.isfinite(sol.xs)) & jnp.all(jnp.isfinite(sol.us))
        guard = (lambda a: a) if implicit else no_derivative
        xs = guard(jnp.where(ok, sol.xs, xs0))
        us = guard(jnp.where(ok, sol.us, us0))
        return eqx.tree_at(lambda s: (s.xs, s.us), sol, (xs, us))

    def _state(self, t, s, position, position_var, velocity, s_plan, sol, inputs, D,
               projection, probing):
        kkt = jnp.maximum(jnp.maximum(sol.inf_pr, sol.inf_du), sol.compl)
        return HorizonState(t=t, s=s, position=position, position_var=position_var,
                            velocity=velocity, s_plan=s_plan,
                            xs=sol.xs, us=sol.us, lam=sol.lam, nu=sol.nu, z=sol.z,
                            inputs=inputs,
                            iterations=sol.iterations, converged=sol.converged, kkt=kkt, D=D,
                            projection=projection, planned=jnp.asarray(True),
                            probing=probing)

    def _measured_state(self, m: DriveMeasurement, position, s_guess):
        s, n, xi = self.table.to_frenet(position[0], position[1], m.psi, s_guess)
        return s, jnp.stack([n, xi, m.vx, m.vy, m.yaw_rate])

    @staticmethod
    def _world_velocity(m: DriveMeasurement):
        c, sn = jnp.cos(m.psi), jnp.sin(m.psi)
        return jnp.stack([c * m.vx - sn * m.vy, sn * m.vx + c * m.vy])

    def filter_position(self, state: HorizonState, m: DriveMeasurement):
        r"""The position estimate: a Kalman filter per axis whose model is dead reckoning
        with the measured ground velocities (trapezoidal rule) and whose measurement is the
        GNSS fix. Over $\Delta t = t_k - t_{k-1}$,
        $\bar p = \hat p_{k-1} + \tfrac{\Delta t}2(v_{k-1} + v_k)$ with variance
        $\bar P = P_{k-1} + (\Delta t\,\sigma_v)^2$; the fix $p_k$ corrects it with the
        gain $K = \bar P/(\bar P + \sigma_p^2)$: $\hat p_k = \bar p + K(p_k - \bar p)$,
        $P_k = (1 - K)\bar P$ ($\sigma_p$ = `position_std`, $\sigma_v$ = `velocity_std`).
        The filter starts at the first fix with $P = \sigma_p^2$, and the first command,
        which sees `init`'s measurement again ($\Delta t = 0$), does not count it twice.
        The gain falls from 1/2 to about $\Delta t\,\sigma_v/\sigma_p$ (0.017 at 20 Hz
        with the defaults): the early fixes are averaged, the later ones mostly filtered.
        Returns the position, its variance and the velocity $v_k$ (inertial frame)."""
        v = self._world_velocity(m)
        dt = m.t - state.t
        pred = state.position + 0.5 * dt * (state.velocity + v)
        P = state.position_var + (dt * self.velocity_std) ** 2
        K = jnp.where(dt > 0, P / (P + self.position_std ** 2), 0.0)
        p = pred + K * (jnp.stack([m.x, m.y]) - pred)
        return p, (1.0 - K) * P, v

    # ---- the controller protocol --------------------------------------------------------

    def init(self, measurement: DriveMeasurement) -> HorizonState:
        """The state before the first sample, from the measured pose (projected near the
        table's start, or its nearest sample). The first plan is the first command's solve
        from that projection (not the state predicted over the delay), a cold start from
        `profile_guess` solved to convergence (at most `init_iterations`; `options` with
        ``first``), so that a drive holds one interior-point solve, not two."""
        m = measurement
        d2 = (self.table.x - m.x) ** 2 + (self.table.y - m.y) ** 2
        s_guess = self.table.s[jnp.argmin(d2)]
        position = jnp.stack([m.x, m.y])
        s, X5 = self._measured_state(m, position, s_guess)
        inputs = jnp.stack([0.0 * m.delta, 0.0 * m.delta, m.delta])
        state8 = jnp.concatenate([X5, inputs])
        V = jnp.hypot(X5[2], X5[3])  # no plan yet: the current speed for every stage
        if self.friction == "estimate":  # no data yet: the nominal road
            D = self.nominal_friction(V)
        else:
            D = self.planner_friction(s, None, V)
        xs0, us0 = self.cold_guess(s, state8, D)
        prob = self.problem(s, state8, D)
        projection = jnp.concatenate([s[None], X5[:2]])
        masks = stage_layout(prob).masks()
        # typed as `command`'s state (no weak types), so a jitted command that is given
        # `init`'s state and then its own compiles once
        inf = jnp.full((), jnp.inf, dtype=float)
        return HorizonState(t=m.t, s=s, position=position,
                            position_var=self.position_std ** 2 + 0.0 * m.x,
                            velocity=self._world_velocity(m),
                            s_plan=s, xs=xs0, us=us0, lam=jnp.zeros_like(xs0),
                            nu=jnp.zeros(masks.eq.shape), z=jnp.zeros(masks.g.shape),
                            inputs=inputs, iterations=jnp.zeros((), dtype=int),
                            converged=jnp.asarray(False), kkt=inf, D=D,
                            projection=projection, planned=jnp.asarray(False),
                            probing=jnp.asarray(False))

    def command(self, state: HorizonState, measurement: DriveMeasurement, estimate
                ) -> tuple[HorizonState, Float[Array, " 3"]]:
        m = measurement
        position, position_var, velocity = self.filter_position(state, m)
        s, X5 = self._measured_state(m, position, state.s)
        T = self.sample_time
        delay = self.delay_samples * T
        y = self.predict(s, X5, state.inputs, delay) if self.delay_samples > 0 else \
            jnp.concatenate([s[None], X5])
        # the first plan (no plan yet) starts where `init` projected the measurement, every
        # stage at the measured speed, from the cold start; a later one at the state
        # predicted over the delay
        first = ~state.planned
        # a plan lost (its residual past `replan_kkt`) is planned again from the cold start
        cold = first | (state.kkt > self.replan_kkt)
        measured8 = jnp.concatenate([state.projection[1:], jnp.stack([m.vx, m.vy, m.yaw_rate]),
                                     state.inputs])
        s_pred = jnp.where(first, state.s, y[0])
        state8 = jnp.where(first, measured8, jnp.concatenate([y[1:], state.inputs]))
        xs0, us0 = shift_plan(state.xs, state.us, s_pred - state.s_plan, self.horizon)
        xs0 = xs0.at[0, :8].set(state8)
        speeds = jnp.where(cold, jnp.hypot(state8[2], state8[3]), self.stage_speeds(xs0))
        D = self.planner_friction(s_pred, estimate, speeds, s)
        guess = self.cold_guess(s_pred, state8, D)
        xs0, us0 = (jnp.where(cold, g, w) for g, w in zip(guess, (xs0, us0)))
        prob = self.problem(s_pred, state8, D, self.planning_margin(position_var))
        duals = None
        if self.warm_duals:
            lam, nu, z = shift_multipliers(state.lam, state.nu, state.z,
                                           s_pred - state.s_plan, self.horizon)
            # a plan that did not converge has no multipliers to trust: the cold start
            duals = lam, nu, jnp.where(state.converged & ~cold, z, 0.0)
        sol = self._solve(prob, xs0, us0, self.options(first, cold & ~first), duals,
                          retry=first)
        X, u = self.plan_point(sol.xs, sol.us)
        probing = jnp.asarray(False)
        if self.probe_distance is not None:  # a test brake while the grip is not known
            probing = self.probing(s, estimate)
            X, u = self.probe_point(X, u, probing)
        scales = None
        if self.traction_limit is not None:
            scales = self.believed_scales(s_pred, estimate)
        inputs, torques = X[5:8], self.plan_torques(X, u, D[0], scales)
        # slip feedback: the slip commanded for now against the one measured
        slip_meas = self.measured_slip(m)
        torques = torques + self.slip_gain * (state.inputs[:2] - slip_meas)
        new = self._state(m.t, s, position, position_var, velocity, s_pred, sol, inputs, D,
                          jnp.concatenate([s[None], X5[:2]]), probing)
        return new, jnp.concatenate([torques, inputs[2:]])

    def measured_slip(self, m: DriveMeasurement):
        r"""$\kappa_i = \omega_i r/V_{ix} - 1$ of both axles from the measured wheel speeds
        and ground velocity ($V_{ix}$ floored at 1 m/s)."""
        X6 = jnp.stack([0.0 * m.vx, 0.0 * m.vx, 0.0 * m.vx, m.vx, m.vy, m.yaw_rate])
        VFx, _, VRx, _ = self.vehicle.axle_velocities(X6, m.delta)
        V = jnp.maximum(jnp.stack([VFx, VRx]), SPEED_FLOOR)
        return m.omega * self.vehicle.params.r / V - 1.0

    def plan_command(self, xs, us, D0, scales=None):
        r"""The inputs $(\kappa_F, \kappa_R, \delta)$ of the plan `lead` seconds after its
        start (interpolated in $s$) and the torques that realise them (eqs. 52-53:
        $T_i = I_i\dot\omega_i + r f_{ix}$ with $\dot{(\cdot)} = \dot s\,d(\cdot)/ds$) on
        the planning car with peak ``D0``; with ``scales`` (`believed_scales`) and
        `traction_limit`, the traction control's (`plan_torques`)."""
        X, u = self.plan_point(xs, us)
        return X[5:8], self.plan_torques(X, u, D0, scales)

    def plan_point(self, xs, us):
        """The plan's knot ``X`` (9,) `lead` seconds after its start (interpolated in $s$)
        and its stage's rates ``u`` (3,)."""
        M = us.shape[0]
        pos = jnp.interp(self.lead, xs[:, 8], jnp.arange(M + 1.0))
        k = jnp.clip(jnp.floor(pos).astype(int), 0, M - 1)
        w = pos - k
        return xs[k] + w * (xs[k + 1] - xs[k]), us[k, :3]  # a soft corridor's slack last

    def plan_torques(self, X, u, D0, scales=None):
        r"""The axle torques (2,) that realise the knot ``X``'s slips changing at the rates
        ``u`` (per metre) on the planning car with peak ``D0`` (`plan_command`).

        ``scales`` (2,): the believed friction scales of the axles (`believed_scales`),
        with `traction_limit` $\rho$: each axle's longitudinal force in $T_i = I_i\dot
        \omega_i + r f_{ix}$ is clipped to $\rho F_{iz}$ times the plant tire's
        `longitudinal_capacity` at the axle's planned velocity (the traction control
        of the class docstring)."""
        if self.stiffness_power is None:
            veh = eqx.tree_at(lambda v: v.tire.D, self.vehicle, D0)
        else:  # the stages' tire at the peak D0
            veh = scaled_planning_car(self.vehicle, D0 / self.vehicle.tire.D,
                                      self.stiffness_power)
        n, xi, vx, vy = X[0], X[1], X[2], X[3]
        sdot = vx * jnp.cos(xi) - vy * jnp.sin(xi)  # on the centre line's scale (n small)
        state6 = jnp.stack([0.0 * n, 0.0 * n, xi, vx, vy, X[4]])
        _, _, T_F, T_R = veh.recover_torques(state6, X[5:8], u * sdot)
        T = jnp.stack([T_F, T_R])
        if scales is None or self.traction_limit is None:
            return T
        fF, fR, FzF, FzR = veh._axle_forces(state6, X[5:8])
        VFx, VFy, VRx, VRy = veh.axle_velocities(state6, X[7])
        f = jnp.stack([fF[0], fR[0]])
        capacity = jax.vmap(functools.partial(longitudinal_capacity, self.plant_tire))
        drive, brake = capacity(scales, jnp.stack([VFx, VRx]), jnp.stack([VFy, VRy]))
        Fz = jnp.stack([FzF, FzR])
        rho = self.traction_limit
        clipped = jnp.clip(f, -rho * brake * Fz, rho * drive * Fz)
        return T - self.vehicle.params.r * (f - clipped)

    def axle_arc_lengths(self, s) -> Float[Array, " 2"]:
        r"""The arc lengths of the front and rear axles, $s + \ell_F$ and $s - \ell_R$, with
        the centre of gravity at ``s`` (along the road: the car's heading error ignored)."""
        p = self.vehicle.params
        return jnp.stack([s + p.lF, s - p.lR])

    def believed_scales(self, s, estimate) -> Float[Array, " 2"]:
        r"""The friction scales $\lambda$ the driver believes to be under its front and rear
        axle with the car's centre of gravity at arc length ``s``: the nominal road's, the
        true road's at $s + \ell_F$ and $s - \ell_R$ ('oracle'), or the estimate's
        (`GripEstimate.scale`: per axle, with a surface map that of the surface under the
        axle)."""
        if self.friction == "nominal":
            lam = scale_of_peak(self.plant_tire, self.nominal_peak, self.reference_speed)
            return jnp.full((2,), lam)
        if self.friction == "oracle":
            return self.table.scale_at(self.axle_arc_lengths(s))
        if estimate is None:
            raise ValueError("RecedingHorizonDriver(friction='estimate') needs a grip "
                             "estimator: pass estimator= to simulate_drive")
        return estimate.scale

    def probing(self, s, estimate) -> Bool[Array, ""]:
        r"""Whether the command at arc length ``s`` is a test brake: ``s`` <
        `probe_distance` and the front axle's belief still wide, $\sigma_F$ =
        `scale_std`/`scale` $\ge$ `probe_std` (class docstring)."""
        if estimate is None:
            raise ValueError("RecedingHorizonDriver.probe_distance needs a grip estimator: "
                             "pass estimator= to simulate_drive")
        wide = estimate.scale_std[0] / estimate.scale[0] >= self.probe_std
        return (s < self.probe_distance) & wide

    def _probe_combined_slip(self) -> Float[Array, ""]:
        tire = self.vehicle.tire
        share = jnp.minimum(self.probe_utilisation / self.peak_fraction, 0.99)
        return jnp.tan(jnp.arcsin(share) / tire.C) / tire.B

    def probe_slip(self) -> Float[Array, ""]:
        r"""$\kappa_p$: the planner's slip at which its tire (`FrictionEllipseTire`,
        $\mu = D\sin(C\arctan(Bs))$) with $D$ = `peak_fraction` times the believed peak
        gives `probe_utilisation` $u_p$ of the believed peak, $s = \tan(\arcsin(\min(u_p
        /f, 0.99))/C)/B$, $\kappa_p = s/(1 + s)$ (braking, $s = -\kappa/(1 + \kappa)$)."""
        slip = self._probe_combined_slip()
        return slip / (1.0 + slip)

    def probe_point(self, X, u, probing):
        r"""The plan's point ``X``, ``u`` with, where ``probing``, the front axle braking at
        least at the slip $-\kappa_p$ (`probe_slip`), held: $\kappa_F \leftarrow
        \min(\kappa_F, -\kappa_p)$, $d\kappa_F/ds \leftarrow 0$ where it changed; the rear
        axle and the steering are the plan's. With `probe_direction` 'balanced' the rear
        axle drives at least at the same combined slip $s$, $\kappa_R \leftarrow
        \max(\kappa_R, s/(1 - s))$, held; with 'plan', where the plan speeds the car up
        there ($\kappa_F + \kappa_R > 0$) the front axle drives instead, $\kappa_F
        \leftarrow \max(\kappa_F, s/(1 - s))$."""
        slip = self._probe_combined_slip()
        brake = jnp.minimum(X[5], -slip / (1.0 + slip))  # -`probe_slip`
        traction = slip / (1.0 - slip)  # the driven wheel's kappa at the same slip
        if self.probe_direction == "plan":
            drive = jnp.maximum(X[5], traction)
            kap = jnp.where(X[5] + X[6] > 0.0, drive, brake)
        else:
            kap = brake
        held = probing & (kap != X[5])
        X1 = X.at[5].set(jnp.where(probing, kap, X[5]))
        u1 = u.at[0].set(jnp.where(held, 0.0, u[0]))
        if self.probe_direction == "balanced":
            rear = jnp.maximum(X[6], traction)
            X1 = X1.at[6].set(jnp.where(probing, rear, X[6]))
            u1 = u1.at[1].set(jnp.where(probing & (rear != X[6]), 0.0, u[1]))
        return X1, u1

    def recorded_solve(self, info: dict, k: int):
        """The interior-point solve of sample ``k`` of a drive as `command` posed it,
        rebuilt from that drive's diagnostics ``info`` (`controller_info` of one drive, the
        samples first): ``(problem, xs0, us0, options, multipliers)``, so that
        ``interior_point(problem, xs0, us0, options, multipliers=multipliers)`` solves it
        again on its own, e.g. with ``verbose`` options to read how a plan that did not
        converge failed. The problem is the one at the recorded start, $D$ and margin; the
        guess and multipliers are the previous plan's shifted by the distance between the
        two plans' starts (the multipliers only where that plan converged), or the cold
        start for the first plan and for a re-plan (`replan_kkt`); a first plan that the
        drive solved again (`_solve_in_steps`) is rebuilt as its first solve. The same
        problem solved in another program may take more or fewer iterations than it did in
        the drive: these solves are sensitive to rounding (docs/performance.md)."""
        n = len(info["iterations"])
        if not 0 <= k < n:
            raise ValueError(f"recorded_solve: sample k must be in [0, {n - 1}], got {k}")
        first = k == 0
        cold = first or bool(info["kkt"][k - 1] > self.replan_kkt)
        s0, state8, D = info["plan_s"][k, 0], info["start"][k], info["D"][k]
        prob = self.problem(s0, state8, D, info["margin"][k])
        if cold:
            xs0, us0 = self.cold_guess(s0, state8, D)
        else:
            distance = s0 - info["plan_s"][k - 1, 0]
            xs0, us0 = shift_plan(info["xs"][k - 1], info["us"][k - 1], distance,
                                  self.horizon)
            xs0 = xs0.at[0, :8].set(state8)
        duals = None
        if self.warm_duals:
            j = max(k - 1, 0)
            lam, nu, z = shift_multipliers(info["lam"][j], info["nu"][j], info["z"][j],
                                           s0 - info["plan_s"][j, 0], self.horizon)
            trusted = (not cold) and bool(info["converged"][j])
            duals = lam, nu, z if trusted else jnp.zeros_like(z)
        return prob, xs0, us0, self.options(first, cold and not first), duals

    def info(self, state: HorizonState) -> dict:
        """Per-sample diagnostics: `iterations`, `converged`, `kkt`, the plan (`xs`, `us`)
        and its multipliers (`lam`, `nu`, `z`), the planned horizon
        as `plan_s`, `plan_n` (M+1,) and `plan_t`, its `start` (the predicted state the
        plan starts from, (8,)), the planner's `D` (M,), its corridor `margin`
        (`planning_margin`), the projection `s`, `n`, `xi`."""
        M = self.num_stages
        return dict(iterations=state.iterations, converged=state.converged, kkt=state.kkt,
                    xs=state.xs, us=state.us, lam=state.lam, nu=state.nu, z=state.z,
                    plan_s=state.s_plan + self.horizon / M * jnp.arange(M + 1),
                    plan_n=state.xs[:, 0], plan_t=state.xs[:, 8], start=state.xs[0, :8],
                    D=state.D, margin=self.planning_margin(state.position_var),
                    probing=state.probing,
                    s=state.projection[0], n=state.projection[1], xi=state.projection[2])
