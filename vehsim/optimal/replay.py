r"""Replay of an optimal primitive on the full half-car (report section 2.5).

A primitive is computed on the reduced model (eqs. 61-63: slips $\kappa_F, \kappa_R$ and
steering $\delta$ as inputs, quasi-static loads, static tire). The full half-car
(eqs. 49-60: wheel spin, suspension, optionally a dynamic tire) is driven by torques, so:

1. **Reference.** The primitive's inputs are continuous and piecewise linear in time
   (knots at $t_k = k t_f / M$), so $\dot\kappa_i, \dot\delta$ are piecewise constant. The
   reduced model is integrated under them (diffrax, tight tolerances, steps onto the knots):
   the continuous-time trajectory the primitive stands for (it differs from the
   primitive's RK4 nodes by their discretisation error, which `replay_open_loop` reports).
2. **Torques.** Along the reference, $T_i = I_i\dot\omega_i + f_{ix}r$ with
   $\omega_i = (1+\kappa_i)V_{ix}/r$ (`ReducedHalfCar.recover_torques`, eqs. 52-53).
3. **Initial state.** Pose and velocities of the primitive's start, wheel speeds from the
   initial slips, heave and pitch at the equilibrium of eqs. 54-55 for the initial forces
   (loads of eqs. 59-60 equal to the quasi-static ones), tire friction states at their steady
   state: all by Newton on $\dot z_{\rm susp} = \dot\zeta = 0$ of `HalfCar.f` itself.
4. **Open loop**: torques and steering as functions of time only. **Tracking**
   (`replay_tracking`): the same feedforward plus a Stanley-type steering correction on the
   lateral and heading errors to the time-indexed reference, a proportional correction of
   the axle torques on the speed and along-track errors, and a slip-tracking term on the
   wheel speeds (the primitive prescribes slips; $\omega_i^{\rm ref} = (1+\kappa_i)V_{ix}/r$
   with the *measured* $V_{ix}$, as an ABS/traction controller would).

Drift is measured with the road's exact `Road.distance_off_road` (union of legs).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._fields import array_field
from .._math import wrap_angle
from .._simulate import Trajectory, simulate
from ..tire.base import AbstractTire
from ..tire.isotropic_lumped import IsotropicLumpedLuGre
from ..tire.lugre import LuGreParams
from ..vehicle.half_car import HalfCar
from ..vehicle.planar import axle_velocities
from ..vehicle.reduced import ReducedHalfCar
from .shooting import DELTA_MAX, IDX_TF


def matched_lugre_tire() -> IsotropicLumpedLuGre:
    r"""An isotropic lumped LuGre tire whose steady state roughly matches the benchmark's
    friction-ellipse tire (docs/maneuvers.md) ($B = 7$, $C = 1.6$, $D = 0.52$).

    In steady state ($\dot z = 0$, $\sigma_2 = 0$) the force per load is
    $|\mu| = \sigma_0|v_r| / (\theta\sigma_0|v_r|/g(|v_r|) + \kappa_0\omega r/L)$, a
    function of the combined slip $s = |v_r|/(\omega r)$ (the friction ellipse's $s$) and,
    through the Stribeck curve $g$, of the slip speed. With $\theta = 1$, $\alpha = 1/2$,
    $L = 0.25$ m, $\kappa_0 = 1$ held, $(\sigma_0, \mu_s, \mu_c, v_s)$ were fitted (scipy
    least squares) to $D\sin(C\arctan(Bs))$ on $s \in [0.005, 1]$ at rolling speeds 6, 8
    and 10 m/s (the speeds of the corner90 primitive): $\sigma_0 = 33.19$ 1/m,
    $\mu_s = 1.916$, $\mu_c = 0.3736$, $v_s = 0.6656$ m/s; max misfit 0.055 (RMS 0.027) in
    $\mu$. Peak $\mu$ = 0.559 / 0.494 / 0.453 at 5 / 8 / 11 m/s (friction ellipse 0.52) at
    $s \approx 0.21$-$0.26$ (0.214); full sliding ($s = 1$) 0.45 / 0.40 / 0.38 (0.39).
    Cornering stiffness per load $\sigma_0 L/\kappa_0 = 8.3$ (friction ellipse $BCD = 5.8$).
    $\sigma_1 = 1$ s/m (damping of the bristles, transients only; not fitted), $\sigma_2 = 0$.
    """
    params = LuGreParams(sigma0=33.19, sigma1=1.0, sigma2=0.0, mu_c=0.3736, mu_s=1.916,
                         v_s=0.6656, alpha=0.5, theta=1.0, L=0.25)
    return IsotropicLumpedLuGre(params, kappa0=1.0)


class TrackingGains(eqx.Module):
    r"""Gains of the path-tracking feedback of `replay_tracking`.

    $\delta = \delta_{\rm ff} - k_\psi e_\psi - \arctan(k_y e_y / (V + V_0))$ (Stanley, on
    the time-indexed reference: $e_y$ lateral [m] and $e_\psi$ heading [rad] errors),
    $\Delta F = m(k_v (V_{\rm ref} - V) - k_s e_s)$ split over the axles as torques
    $\Delta T_i = \tfrac12 \Delta F r$ ($e_s$ along-track error [m]), and
    $\Delta T_i = k_\omega I_i (\omega^{\rm ref}_i - \omega_i)$ (slip tracking).
    """

    k_y: Float[Array, ""] = array_field(default=2.0)
    k_psi: Float[Array, ""] = array_field(default=1.0)
    V0: Float[Array, ""] = array_field(default=1.0)
    k_v: Float[Array, ""] = array_field(default=2.0)
    k_s: Float[Array, ""] = array_field(default=1.0)
    k_omega: Float[Array, ""] = array_field(default=50.0)

    @classmethod
    def open_loop(cls) -> TrackingGains:
        """All gains 0: the feedforward alone (open loop; shares the compiled solve)."""
        return cls(k_y=0.0, k_psi=0.0, V0=1.0, k_v=0.0, k_s=0.0, k_omega=0.0)


class _Schedule(eqx.Module):
    """The primitive's piecewise-linear inputs in time: knot values and rates [1/s]."""

    knots: Array  # (M+1, 3)
    rates: Array  # (M, 3) d/dt
    t_f: Array

    def index(self, t):
        M = self.rates.shape[0]
        return jnp.clip(jnp.floor(t / self.t_f * M).astype(int), 0, M - 1)

    def __call__(self, t):
        M = self.rates.shape[0]
        k = self.index(t)
        t_k = k * self.t_f / M
        return self.knots[k] + self.rates[k] * (t - t_k), self.rates[k]

    def jump_ts(self):
        M = self.rates.shape[0]
        return jnp.linspace(0.0, self.t_f, M + 1)


def _schedule(primitive) -> _Schedule:
    xs, us = primitive.solution.xs, primitive.solution.us
    t_f = xs[-1, IDX_TF]
    return _Schedule(knots=xs[:, 6:9], rates=us / t_f, t_f=t_f)


def default_vehicle(primitive, tire: AbstractTire | None = None, suspension: bool = True):
    """The full `HalfCar` with the primitive's parameters and ``tire`` (default: the
    primitive's own static tire)."""
    red: ReducedHalfCar = primitive.problem.vehicle
    if tire is None:
        return HalfCar(red.params, red.tire, red.tire_R, suspension=suspension)
    return HalfCar(red.params, tire, suspension=suspension)


def initial_state(vehicle: HalfCar, state6, controls, newton_steps: int = 10):
    r"""Full half-car state consistent with a reduced state and slip inputs.

    Wheel speeds $\omega_i = (1+\kappa_i)V_{ix}/r$; heave, pitch (zero rates) and tire friction
    states solve $\ddot z = \ddot\theta = 0$, $\dot\zeta = 0$ of `HalfCar.f` (Newton), so the
    suspension starts at its static equilibrium for the initial tire forces."""
    p = vehicle.params
    delta = controls[2]
    VFx, _, VRx, _ = axle_velocities(p, state6[3], state6[4], state6[5], delta)
    omF, omR = (1.0 + controls[0]) * VFx / p.r, (1.0 + controls[1]) * VRx / p.r
    y = vehicle.init_state(vx=state6[3], vy=state6[4], yaw_rate=state6[5], x=state6[0],
                           y=state6[1], psi=state6[2], delta=delta)
    y = y.at[6].set(omF).at[7].set(omR)
    n = len(vehicle.state_names)
    idx_unknown = list(range(n, vehicle.state_size))  # tire friction states
    idx_residual = list(range(n, vehicle.state_size))
    if vehicle.suspension:
        idx_unknown = [8, 10] + idx_unknown  # z, theta
        idx_residual = [9, 11] + idx_residual  # z_dd, theta_dd
    if not idx_unknown:
        return y
    iu, ir = jnp.array(idx_unknown), jnp.array(idx_residual)
    u = jnp.array([0.0, 0.0, delta])  # torques do not enter these residuals

    def residual(w):
        return vehicle.f(y.at[iu].set(w), u)[ir]

    def newton(_, w):
        return w - jnp.linalg.solve(jax.jacfwd(residual)(w), residual(w))

    return y.at[iu].set(jax.lax.fori_loop(0, newton_steps, newton, y[iu]))


def _reference_solution(reduced, sched: _Schedule, state6_0, ts):
    """The reduced model under the primitive's inputs (dense, steps onto the knots)."""
    return simulate(reduced, ts, lambda t, y: sched(t)[0], state6_0, rtol=1e-10, atol=1e-10,
                    jump_ts=sched.jump_ts(), dense=True, max_steps=100_000)


@eqx.filter_jit
def _run(vehicle: HalfCar, reduced: ReducedHalfCar, sched: _Schedule, state6_0, ts,
         gains: TrackingGains):
    ref = _reference_solution(reduced, sched, state6_0, ts)
    p = vehicle.params

    def reference(t):
        y6 = ref.evaluate(t)
        u, u_dot = sched(t)
        omF, omR, TF, TR = reduced.recover_torques(y6, u, u_dot)
        return y6, u, omF, omR, TF, TR

    def tracking(t, y):
        y6, u, _, _, TF, TR = reference(t)
        cp, sp = jnp.cos(y6[2]), jnp.sin(y6[2])
        dx, dy = y[0] - y6[0], y[1] - y6[1]
        e_s, e_y = cp * dx + sp * dy, -sp * dx + cp * dy
        e_psi = wrap_angle(y[2] - y6[2])
        V, V_ref = jnp.hypot(y[3], y[4]), jnp.hypot(y6[3], y6[4])
        delta = u[2] - gains.k_psi * e_psi - jnp.arctan(gains.k_y * e_y / (V + gains.V0))
        delta = jnp.clip(delta, -DELTA_MAX, DELTA_MAX)
        dF = p.m * (gains.k_v * (V_ref - V) - gains.k_s * e_s)
        VFx, _, VRx, _ = axle_velocities(p, y[3], y[4], y[5], delta)
        omF_ref, omR_ref = (1.0 + u[0]) * VFx / p.r, (1.0 + u[1]) * VRx / p.r
        TF = TF + 0.5 * dF * p.r + gains.k_omega * p.Iw_F * (omF_ref - y[6])
        TR = TR + 0.5 * dF * p.r + gains.k_omega * p.Iw_R * (omR_ref - y[7])
        return jnp.stack([TF, TR, delta])

    y0 = initial_state(vehicle, state6_0, sched(0.0)[0])
    traj = simulate(vehicle, ts, tracking, y0, rtol=1e-8,
                    atol=1e-8, jump_ts=sched.jump_ts(), max_steps=200_000, throw=False)
    ref_traj = Trajectory(ts=ref.ts, states=ref.states, controls=ref.controls,
                          signals=ref.signals, result=ref.result, stats=ref.stats)
    return traj, ref_traj


class Replay(eqx.Module):
    """Result of `replay_open_loop` / `replay_tracking`: the full-model ``trajectory``, the
    continuous-time ``reference`` (reduced model under the primitive's inputs), and ``drift``
    (a dict of floats, see `drift_metrics`)."""

    trajectory: Trajectory
    reference: Trajectory
    drift: dict = eqx.field(static=True)


def drift_metrics(primitive, traj: Trajectory, ref: Trajectory) -> dict:
    r"""How far a replay drifts.

    - ``max_corridor_violation`` [m]: max exact distance off the road (union of legs) of the
      CG over the save times (those reached, if the solve failed);
    - ``final_position_error`` [m], ``final_heading_error`` [rad]: at $t_f$ against the
      primitive's final knot (None if the solve failed);
    - ``max_deviation_from_reference`` [m]: max CG distance to the time-indexed reference;
    - ``max_speed_error`` [m/s] against the reference;
    - ``reference_corridor_violation`` [m]: the same for the reference (a coarse primitive
      keeps the corridor at its nodes only and may cut an inner corner between them);
    - ``reference_vs_primitive`` [m]: max CG distance of the reference from the primitive's
      own nodes (their RK4 discretisation error);
    - ``completed``: the solve reached $t_f$.
    """
    road = primitive.problem.road
    x, y = np.asarray(traj["x"]), np.asarray(traj["y"])
    ok = bool(traj.ok) and bool(np.all(np.isfinite(x)))
    xr, yr = np.asarray(ref["x"]), np.asarray(ref["y"])
    fin = np.isfinite(x) & np.isfinite(y)
    xT = np.asarray(primitive.solution.xs[-1])
    off = road.distance_off_road(x[fin], y[fin])
    nodes = np.asarray(primitive.nodes())
    t_nodes = np.asarray(primitive.time())
    ref_at_nodes = np.stack([np.interp(t_nodes, np.asarray(ref.ts), xr),
                             np.interp(t_nodes, np.asarray(ref.ts), yr)], 1)
    dpsi = float(np.asarray(traj["psi"])[-1] - xT[2])
    return dict(
        completed=ok,
        max_corridor_violation=float(off.max()),
        final_position_error=float(np.hypot(x[-1] - xT[0], y[-1] - xT[1])) if ok else None,
        final_heading_error=float(math.atan2(math.sin(dpsi), math.cos(dpsi))) if ok else None,
        max_deviation_from_reference=float(np.max(np.hypot(x[fin] - xr[fin], y[fin] - yr[fin]))),
        max_speed_error=float(np.max(np.abs(np.asarray(traj["speed"])[fin]
                                            - np.asarray(ref["speed"])[fin]))),
        reference_corridor_violation=float(road.distance_off_road(xr, yr).max()),
        reference_vs_primitive=float(np.max(np.hypot(*(ref_at_nodes - nodes[:, :2]).T))),
    )


def _replay(primitive, vehicle, tire, suspension, gains, num_saves):
    if vehicle is None:
        vehicle = default_vehicle(primitive, tire, suspension)
    reduced = primitive.problem.vehicle
    sched = _schedule(primitive)
    ts = jnp.linspace(0.0, sched.t_f, num_saves)
    traj, ref = _run(vehicle, reduced, sched, primitive.solution.xs[0, :6], ts, gains)
    return Replay(trajectory=traj, reference=ref, drift=drift_metrics(primitive, traj, ref))


def replay_open_loop(primitive, vehicle: HalfCar | None = None,
                     tire: AbstractTire | None = None, *, suspension: bool = True,
                     num_saves: int = 401) -> Replay:
    r"""Drive the full half-car open loop with the torques recovered from ``primitive``.

    **Arguments:** a car `Primitive` (``min_time_primitive``/``max_exit_primitive``);
    ``vehicle``: the `HalfCar` to drive (default: the primitive's parameters with ``tire``,
    itself defaulting to the primitive's static tire, and ``suspension``); ``num_saves``
    save times on $[0, t_f]$ (the drift is measured there).

    **Returns:** a `Replay` (trajectory, reference, drift metrics).
    """
    return _replay(primitive, vehicle, tire, suspension, TrackingGains.open_loop(), num_saves)


def replay_tracking(primitive, vehicle: HalfCar | None = None,
                    tire: AbstractTire | None = None, *, gains: TrackingGains | None = None,
                    suspension: bool = True, num_saves: int = 401) -> Replay:
    r"""As `replay_open_loop`, with the path-tracking feedback of `TrackingGains` (default
    ``TrackingGains()``) around the primitive's feedforward (torques and steering)."""
    gains = TrackingGains() if gains is None else gains
    return _replay(primitive, vehicle, tire, suspension, gains, num_saves)
