r"""Baseline drivers of a scenario: the nominal minimum-time drive replayed open loop, and
tracked; and the offline bound, the minimum-time drive on the true grip.

**The reference** (`primitive_reference`). A `RoadPrimitive` (the reduced half-car of eqs.
61-63 on the road, in arc length) gives at its nodes $s_k$ the time $t_k$, the pose, the body
velocities and the inputs $(\kappa_F, \kappa_R, \delta)$, piecewise linear in $s$ with the
rates $u_k = d(\kappa_F, \kappa_R, \delta)/ds$ of stage $k$. In time the rates are
$u_k\dot s$, so the axle torques that realise the slips are, as in
`vehsim.optimal.replay`, $T_i = I_i\dot\omega_i + rF_{ix}$ with
$\omega_i = (1 + \kappa_i)V_{ix}/r$ (`ReducedHalfCar.recover_torques`, eqs. 52-53). Between
the nodes every signal is linear in time (`PrimitiveReference.at`).

**Open loop** (`open_loop_schedule`): the command of sample $k$ is the reference's
$(T_F, T_R, \delta)$ at the middle of the sample it will act in, led by each channel's
known delay (whole samples) and lag time constant (a first-order lag trails a ramp by
$\tau$): $u_k = u_{ref}(t_k + d_jT + T/2 + \tau_j)$, a `CommandSchedule`.

**Tracking** (`PrimitiveTracker`): the sampled-data version of `replay_tracking`'s law
(`TrackingGains`) on the measurements: the same led feedforward plus the Stanley-type
steering correction on the lateral and heading errors $e_y$, $e_\psi$ to the time-indexed
reference, $\delta = \delta_{ff} - k_\psi e_\psi - \arctan(k_ye_y/(V + V_0))$; the axle
torques' correction on the speed and along-track errors,
$\Delta T_i = \tfrac12 m(k_v(V_{ref} - V) - k_se_s)r$; and slip tracking on the measured
wheel speeds, $\Delta T_i = k_\omega I_i(\omega^{ref}_i - \omega_i)$,
$\omega^{ref}_i = (1 + \kappa_i)V_{ix}/r$ from the measured velocities and steering.

**Offline bound** (`offline_bound`): the minimum-time drive of the receding-horizon
driver's planning model (the reduced half car, `rally_gravel_car`) on the scenario's
road from the drive's start, every stage with the true road's peak at the speed the drive
passes it, as the driver plans (the arc-length problem with a per-stage friction,
`horizon_problem` over the whole road; a fixed point in the speeds, solved from the drive
with the smallest peak at 20 m/s, feasible and slower: the fallback where a solve fails).
It ends with the horizon problem's terminal bounds ($|v_y| \le 0.1v_x$, $|\xi| \le 0.15$
rad) instead of the gate's $\xi = r = \dot n = 0$. The nominal primitive the replays follow
(`nominal_primitive`) is the same car's with one peak, 0.52.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._fields import array_field
from .._math import wrap_angle
from ..optimal.curvilinear import RoadPrimitive, resample_drive, road_primitive
from ..optimal.ip import IPOptions, interior_point
from ..optimal.primitives import rally_gravel_car
from ..optimal.replay import TrackingGains
from ..optimal.shooting import DELTA_MAX
from ..vehicle.params import HalfCarParams, rally_gravel
from ..vehicle.planar import axle_velocities
from ..vehicle.reduced import ReducedHalfCar
from .actuators import DriveActuators
from .horizon import PLAN_BACKWARD_ERROR, PLAN_REFINEMENT_STEPS, horizon_problem, stage_speeds
from .scenarios import BENCHMARK_PEAK, DriveScenario
from .sensors import DriveMeasurement
from .simulate import AbstractDriveController, CommandSchedule


_NAMES = ("x", "y", "psi", "vx", "vy", "yaw_rate", "kappa_F", "kappa_R", "delta",
          "torque_F", "torque_R")


class PrimitiveReference(eqx.Module):
    r"""A minimum-time drive as functions of time: `table` (P, 11) at the times `time` (P,)
    with the columns $x, y, \psi, v_x, v_y, r, \kappa_F, \kappa_R, \delta, T_F, T_R$ (SI
    units; module docstring); held at the ends. Rows past the drive's end repeat its last
    (padding to a common length for batches)."""

    time: Float[Array, " P"] = array_field()
    table: Float[Array, "P 11"] = array_field()

    def at(self, t) -> dict:
        """The reference's signals at time `t` [s] (linear between rows), by name."""
        row = jax.vmap(lambda col: jnp.interp(t, self.time, col), in_axes=1)(self.table)
        return dict(zip(_NAMES, row))

    @property
    def duration(self):
        """The drive's final time [s]."""
        return self.time[-1]

    def padded(self, rows: int) -> PrimitiveReference:
        """The reference with `rows` rows (the last repeated, 1 ms apart in time)."""
        P = self.time.shape[0]
        if rows < P:
            raise ValueError(f"PrimitiveReference.padded: rows must be >= {P}, got {rows}")
        extra = jnp.arange(1, rows - P + 1) * 1e-3
        return PrimitiveReference(
            time=jnp.concatenate([self.time, self.time[-1] + extra]),
            table=jnp.concatenate([self.table, jnp.tile(self.table[-1:], (rows - P, 1))]))


@eqx.filter_jit
def _torques(vehicle, states, inputs, rates_t):
    return jax.vmap(vehicle.recover_torques)(states, inputs, rates_t)


def primitive_reference(primitive: RoadPrimitive) -> PrimitiveReference:
    """The reference of a car `RoadPrimitive` (one RK4 step per stage; module docstring)."""
    prob = primitive.problem
    if prob.steps_per_stage != 1:
        raise ValueError("primitive_reference needs a primitive of one RK4 step per stage, got "
                         f"steps_per_stage={prob.steps_per_stage}")
    xs = np.asarray(primitive.solution.xs)[:, :9]
    us = np.asarray(primitive.solution.us)
    pose = primitive.cartesian()
    s = pose["s"]
    n, xi, vx, vy = xs[:, 0], xs[:, 1], xs[:, 2], xs[:, 3]
    kappa = np.asarray(primitive.road.curvature(s), float)
    sdot = (vx * np.cos(xi) - vy * np.sin(xi)) / (1.0 - n * kappa)
    rates_s = np.concatenate([us, us[-1:]], axis=0)
    rates_t = rates_s * sdot[:, None]
    states = np.stack([pose["x"], pose["y"], pose["psi"], vx, vy, xs[:, 4]], axis=1)
    _, _, TF, TR = (np.asarray(a) for a in _torques(prob.vehicle, jnp.asarray(states),
                                                    jnp.asarray(xs[:, 5:8]),
                                                    jnp.asarray(rates_t)))
    table = np.concatenate([states, xs[:, 5:8], TF[:, None], TR[:, None]], axis=1)
    return PrimitiveReference(time=jnp.asarray(xs[:, 8]), table=jnp.asarray(table))


def command_lead(actuators: DriveActuators):
    r"""Per channel, the time [s] a command is led by: the delay (whole samples) plus the
    lag's time constant where they are on, plus half a sample (module docstring)."""
    T = actuators.sample_time
    delay = actuators.delay_samples() * T
    lag = jnp.where(actuators.lag_on, actuators.time_constant, 0.0)
    return delay + lag + 0.5 * T


def _feedforward(reference: PrimitiveReference, t, lead):
    cols = (9, 10, 8)  # T_F, T_R, delta
    return jnp.stack([jnp.interp(t + lead[j], reference.time, reference.table[:, c])
                      for j, c in enumerate(cols)])


def open_loop_schedule(reference: PrimitiveReference, actuators: DriveActuators,
                       num_samples: int) -> CommandSchedule:
    """The open-loop replay of `reference` as `num_samples` commands (module docstring)."""
    lead = command_lead(actuators)
    ts = jnp.arange(num_samples) * actuators.sample_time
    commands = jax.vmap(lambda t: _feedforward(reference, t, lead))(ts)
    return CommandSchedule(commands=commands)


class PrimitiveTracker(AbstractDriveController):
    r"""Tracking of a `PrimitiveReference` from the measurements (module docstring).

    **Fields:** `reference`, `gains` (`TrackingGains`), `lead` (3,) [s] (`command_lead`),
    `params` (`HalfCarParams`, the nominal car: mass, wheel inertias and radius, axle
    positions)."""

    reference: PrimitiveReference
    lead: Float[Array, " 3"] = array_field()
    gains: TrackingGains = eqx.field(default_factory=TrackingGains)
    params: HalfCarParams = eqx.field(default_factory=rally_gravel)

    def init(self, measurement: DriveMeasurement):
        return jnp.zeros(())

    def command(self, state, m: DriveMeasurement, estimate):
        g, p = self.gains, self.params
        ref = self.reference.at(m.t)
        ff = _feedforward(self.reference, m.t, self.lead)
        kap_ff = jnp.stack([jnp.interp(m.t + self.lead[j], self.reference.time,
                                       self.reference.table[:, 6 + j]) for j in range(2)])
        cp, sp = jnp.cos(ref["psi"]), jnp.sin(ref["psi"])
        dx, dy = m.x - ref["x"], m.y - ref["y"]
        e_s, e_y = cp * dx + sp * dy, -sp * dx + cp * dy
        e_psi = wrap_angle(m.psi - ref["psi"])
        V, V_ref = m.speed, jnp.hypot(ref["vx"], ref["vy"])
        delta = ff[2] - g.k_psi * e_psi - jnp.arctan(g.k_y * e_y / (V + g.V0))
        delta = jnp.clip(delta, -DELTA_MAX, DELTA_MAX)
        dF = p.m * (g.k_v * (V_ref - V) - g.k_s * e_s)
        VFx, _, VRx, _ = axle_velocities(p, m.vx, m.vy, m.yaw_rate, m.delta)
        om_ref = (1.0 + kap_ff) * jnp.stack([VFx, VRx]) / p.r
        inertia = jnp.stack([p.Iw_F, p.Iw_R])
        torque = ff[:2] + 0.5 * dF * p.r + g.k_omega * inertia * (om_ref - m.omega)
        return state, jnp.concatenate([torque, delta[None]])


def nominal_primitive(scenario: DriveScenario, D: float = BENCHMARK_PEAK, **kwargs
                      ) -> RoadPrimitive:
    """The minimum-time drive of the reduced model (`rally_gravel_car(D)`, the
    receding-horizon driver's default planning car) with one peak $D$ on the scenario's road
    from the drive's start (`DriveScenario.primitive_road`); `kwargs` go to `road_primitive`
    (default ``num_stages`` 100, one per 2 m on the stage; ``options`` its default
    ``max_iter=500``, with the drive's `PLAN_BACKWARD_ERROR` and `PLAN_REFINEMENT_STEPS`)."""
    kwargs.setdefault("num_stages", max(100, int(round(scenario.road.length / 2.0))))
    kwargs.setdefault("options", IPOptions(max_iter=500,
                                           backward_error_singular=PLAN_BACKWARD_ERROR,
                                           max_refinement_steps=PLAN_REFINEMENT_STEPS))
    return road_primitive(scenario.primitive_road(), car=rally_gravel_car(D), throw=False,
                          **kwargs)


BOUND_ROUNDS = 6
"""Most solves of `offline_bound`'s fixed point in the stages' speeds."""


@eqx.filter_jit
def _stage_peaks(table, mid, xs):
    """The road's peak at the stages' midpoints ``mid`` and the plan ``xs``'s speeds there."""
    return table.peak_at(mid, stage_speeds(xs))


@eqx.filter_jit
def _bound_solve(table, car, length, rate_weight, xs0, us0, D_stage, limits):
    """One solve of `offline_bound`: the whole road's `horizon_problem` from ``xs0``, every
    number an array (one program per road shape and slip bound's presence, whatever the
    grip, the constraints or the scenario)."""
    prob = horizon_problem(table, car, 0.0, xs0[0, :8], limits["peak_fraction"] * D_stage,
                           horizon=length, rate_weight=rate_weight, margin=limits["margin"],
                           steer_rate=limits["steer_rate"], steer_limit=limits["steer_limit"],
                           slip_limit=limits["slip_limit"],
                           margin_grip_power=limits["margin_grip_power"],
                           stiffness_power=limits["stiffness_power"])
    return prob, interior_point(prob, xs0, us0, bound_options(), throw=False)


def bound_options() -> IPOptions:
    """The options of `offline_bound`'s solves: from a solution nearby, so a small first
    barrier (1e-3) that keeps its active set; the drive's `PLAN_BACKWARD_ERROR` and
    `PLAN_REFINEMENT_STEPS`, as the driver's plans."""
    return IPOptions(max_iter=500, mu0=1e-3, backward_error_singular=PLAN_BACKWARD_ERROR,
                     max_refinement_steps=PLAN_REFINEMENT_STEPS)


def offline_bound(scenario: DriveScenario, *, rounds: int = BOUND_ROUNDS, driver=None,
                  car: ReducedHalfCar | None = None,
                  **kwargs) -> tuple[RoadPrimitive, float, bool]:
    r"""The offline bound of the module docstring: ``(primitive, D, exact)``, $D$ the
    smallest stage peak. The minimum-time drive of the driver's default planning car
    (`rally_gravel_car`; its $D$ set per stage) over the whole road
    (`horizon_problem`, margin 0, the steering rate free) with each stage's peak the true
    road's at the speed the drive passes it, $D_k = \mu^*(\lambda(s_k), V_k)$
    (`peak_friction` of the plant's tire, $\lambda$ the table's scale at the stage's
    midpoint, $V_k$ the drive's speed there): a fixed point, solved from the drive with one
    peak, the smallest at 20 m/s (`nominal_primitive`; feasible, and slower), then again
    with the peaks at the last drive's speeds (or half or a quarter of the way to them
    where the whole step fails), until they change by less than 0.1 % (at most ``rounds``
    solves; on the scenarios 3-4). `exact` is False where no step converged or the peaks
    still moved: the last converged drive is returned (the one-peak drive if none).

    ``driver`` (a `RecedingHorizonDriver`; None: the bound above): the bound under that
    driver's own constraints, its corridor `margin` (and `margin_grip_power`), `slip_limit`,
    `steer_rate` and `steer_limit`, and `peak_fraction` of each stage's peak, with its
    planning tire's stiffness on each stage (`stiffness_power`), from the
    drive's start with the wheels rolling and the steering straight (as the driver's first
    plan): the fixed point continued from the unconstrained bound. It parts the driver's distance to the bound
    into what its safety constraints cost and what driving closed loop on an unknown road
    costs.

    ``car`` (None: `rally_gravel_car`) the reduced car the bound drives, its tire's $D$ set
    per stage as above: `planner_car` gives it a tire of the plant's shape (the LuGre
    steady state's, peaking at 5-6 % slip and falling off after it, where the gravel
    tire peaks near 21 %). On the scenarios the two bounds agree within 0.6 %: the bound
    is set by the peaks, not by the tire's shape."""
    peak = np.asarray(scenario.grip.peak)
    D = float(np.min(peak))
    floor = nominal_primitive(scenario, D, **kwargs)
    prob0 = floor.problem
    M = prob0.num_stages
    L = float(scenario.road.length)
    mid = jnp.asarray((np.arange(M) + 0.5) * L / M)
    car = rally_gravel_car(BENCHMARK_PEAK) if car is None else car
    length, rate_weight = jnp.asarray(L, float), jnp.asarray(prob0.rate_weight, float)

    def solve(xs0, us0, D_stage, limits):
        limits = {k: None if v is None else jnp.asarray(v, float) for k, v in limits.items()}
        return _bound_solve(scenario.table, car, length, rate_weight, xs0, us0, D_stage,
                            limits)

    def fixed_point(start, D_stage, limits, xs=None, us=None):
        """The fixed point from the drive `start` (solved again at least once; from `xs`,
        `us` where given)."""
        best, exact = start, True
        xs = start.solution.xs if xs is None else xs
        us = start.solution.us if us is None else us
        for _ in range(int(rounds)):
            target = _stage_peaks(scenario.table, mid, xs)
            if best is not start and float(jnp.max(jnp.abs(target / D_stage - 1.0))) < 1e-3:
                break
            for step in (1.0, 0.5, 0.25):  # the whole way to the new peaks, else part of it
                trial = D_stage + step * (target - D_stage)
                prob, sol = solve(xs, us, trial, limits)
                if bool(sol.converged):
                    break
            if not bool(sol.converged):
                exact = False
                break
            D_stage = trial
            best = RoadPrimitive(problem=prob, solution=sol, road=floor.road)
            xs, us = sol.xs, sol.us
        else:
            exact = False  # the peaks still moving after `rounds` solves
        return best, D_stage, exact and best is not start

    free = dict(margin=0.0, margin_grip_power=0.0, steer_rate=1e3, steer_limit=DELTA_MAX,
                slip_limit=None, peak_fraction=1.0, stiffness_power=None)
    # (the floor solve itself may not converge: not exact); the bound's stages are uniform,
    # the floor's have a knot on each curvature jump: its drive is moved onto them
    xs0, us0 = (None, None) if prob0.stage_lengths is None else resample_drive(
        prob0, floor.solution.xs, M)
    best, D_stage, exact = fixed_point(floor, jnp.full((M,), D), free, xs0, us0)
    if driver is not None:
        limits = {name: getattr(driver, name) for name in free}  # the same constraints
        # from the drive's start as the driver plans it: wheels rolling, steering straight
        # (the free bound's start inputs are its optimum's, past the slip bound)
        xs = best.solution.xs.at[0, 5:8].set(0.0)
        best, D_stage, exact_driver = fixed_point(best, D_stage, limits, xs)
        exact = exact and exact_driver
    return best, float(jnp.min(D_stage)), exact
