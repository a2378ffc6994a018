r"""`simulate`: vehicle + tire + inputs + initial state + time grid -> named trajectory.

Pure and composable: `jax.jit`, `jax.vmap` (over parameters, inputs and initial states)
and `jax.grad` apply to `simulate` end to end.
"""

from __future__ import annotations

import functools

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._checks import check_times, is_concrete
from ._integrate import ATOL, MAX_STEPS, RTOL, check_solver_settings, integrate, solve_stats
from ._results import RESULTS, as_result
from ._signals import as_controls
from ._solution import AbstractSolution
from .vehicle.base import AbstractVehicle


class Trajectory(AbstractSolution):
    """Result of `simulate`: states, controls and named signals at the save times.

    `signals` maps names (``x``, ``y``, ``psi``, ``vx``, ``vy``, ``yaw_rate``, ``speed``,
    ``sideslip``, ``ax``, ``ay``, ``kappa_F``, ``alpha_F``, ``Fx_F``, ``Fy_F``, ``Fz_F``, ...,
    see the vehicle's ``signals``) to arrays over `ts`; ``traj["Fz_F"]`` is a shortcut.
    `result` is a `vehsim.RESULTS` (``throw=False`` leaves failures for the caller), `stats`
    the solver's step counts; `solution` holds the dense interpolant when
    `simulate(..., dense=True)`.
    """

    ts: Float[Array, " T"]
    states: Float[Array, "T n"]
    controls: Float[Array, "T m"]
    signals: dict
    result: RESULTS = eqx.field(converter=as_result)
    stats: dict
    solution: dfx.Solution | None = None

    def evaluate(self, t):
        """State at time ``t`` from the dense interpolant (needs ``dense=True``)."""
        if self.solution is None:
            raise ValueError("Trajectory.evaluate needs simulate(..., dense=True)")
        return self.solution.evaluate(t)


STABILITY_FRACTION = 0.8
r"""The fraction of an explicit solver's stability limit on the stiff wheel-tire blocks that
`simulate` keeps its steps below by default (`stiffness_ceiling`)."""

CEILING_FLOOR = 1e-4
r"""The shortest default step ceiling [s]: where the blocks would ask for less (a static
tire near standstill, whose slip stiffness grows as $1/v$: 1.3 µs at rest), `simulate`
sets none, since $10^4$ steps a second and more would cost more than an explicit solve
should; differentiate such starts with `ROS34PW2` or a `dtmax` of one's own."""


def stability_boundary(solver: dfx.AbstractERK) -> float:
    r"""The real-axis stability boundary $x^*$ of an explicit Runge-Kutta `solver` (its
    Butcher tableau): the largest $x$ with $|R(-y)| \le 1$ for all $0 \le y \le x$,
    $R$ its stability function (`Tsit5` 3.51, `Dopri5` 3.31, `Heun` 2.00)."""
    return _tableau_boundary(type(solver))


@functools.cache
def _tableau_boundary(solver_type) -> float:
    tableau = solver_type.tableau
    z = -np.linspace(0.0, 20.0, 200_001)[1:]
    ks = []
    for row in ((), *tableau.a_lower):  # k_i = z (1 + sum_j a_ij k_j), stage by stage
        ks.append(z * (1.0 + sum((a * k for a, k in zip(row, ks)), np.zeros_like(z))))
    R = 1.0 + sum(b * k for b, k in zip(tableau.b_sol, ks))
    unstable = np.abs(R) > 1.0 + 1e-12
    return float(-z[np.argmax(unstable) - 1]) if unstable.any() else float(-z[-1])


def _spectral_radius_bound(J: Float[Array, "b m m"], squarings: int = 8) -> Float[Array, ""]:
    r"""$\max_b \|J_b^N\|^{1/N}$, $N = 2^{\text{squarings}}$, by repeated squaring with
    rescaling: at least the spectral radius, and within $(m\,\kappa)^{1/N}$ of it
    ($\kappa$ the eigenvectors' condition number; a wheel-tire block's is about $10^6$,
    5 % at $N = 256$). Matrix products only, on any backend."""
    log_c = jnp.zeros(J.shape[0], J.dtype)
    A = J
    for _ in range(squarings):
        s = jnp.max(jnp.abs(A), axis=(-2, -1))
        s = jnp.where(s > 0, s, 1.0)
        A = A / s[:, None, None]
        log_c = 2.0 * (log_c + jnp.log(s))
        A = A @ A
    n = 2.0**squarings
    top = jnp.max(jnp.abs(A), axis=(-2, -1))
    return jnp.max(jnp.where(top > 0, jnp.exp((log_c + jnp.log(jnp.where(top > 0, top, 1.0)))
                                               / n), 0.0))


def stiffness_ceiling(vehicle: AbstractVehicle, solver, u_fn, t0, state0):
    r"""The default largest step of `simulate`: for an explicit Runge-Kutta `solver` and a
    vehicle with stiff wheel-tire blocks (``vehicle.stiff_blocks``), `STABILITY_FRACTION`
    of the solver's stability limit on those blocks at the start,
    $0.8\,x^*/\rho(J_b(y_0))$ (`stability_boundary`), none (infinite) where that is below
    `CEILING_FLOOR`; None for other solvers and vehicles.

    The steps follow the motion's error alone. From an exact or near equilibrium (free
    rolling, zero slip) that error is zero or tiny and the steps lengthen past the blocks'
    stability, where the derivative, which excites the blocks, grows without bound while
    the motion stays right: $\partial v_x(1\,\mathrm{s})/\partial T_b$ from free rolling
    at 15 m/s was $-76$ with the lumped LuGre tires and $-2\times10^8$ with the static
    ones, against $-0.0022$. Off the equilibrium the blocks' stability bounds the steps
    anyway, so the ceiling costs few steps there. It is set by the stiffness at the start:
    a static tire's grows as the car slows, so a motion that settles into a slower
    equilibrium later is not covered, and one that speeds up from a slow start pays for
    steps shorter than it needs. Its gradient is stopped."""
    blocks = getattr(vehicle, "stiff_blocks", None)
    solver = dfx.Tsit5() if solver is None else solver
    if not blocks or not isinstance(solver, dfx.AbstractERK):
        return None
    idx = np.asarray(blocks)
    y0 = jax.lax.stop_gradient(state0)
    J = jax.jacfwd(lambda y: vehicle.f(y, u_fn(t0, y)))(y0)
    rho = _spectral_radius_bound(J[idx[:, :, None], idx[:, None, :]])
    ceiling = STABILITY_FRACTION * stability_boundary(solver) / rho
    return jax.lax.stop_gradient(jnp.where((rho > 0) & (ceiling >= CEILING_FLOOR), ceiling,
                                           jnp.inf))


def _check_finite_start(vehicle: AbstractVehicle, state0, inputs) -> None:
    """A NaN or inf in a concrete initial state or input array is refused by name: the
    solver would otherwise reject its first step down to the floor and report
    `step_size_collapsed`, naming nothing. A state of another length than the vehicle's is
    refused too."""
    if jnp.shape(state0) != (vehicle.state_size,):
        raise ValueError(f"simulate: state0 must have shape ({vehicle.state_size},), the state "
                         f"of {type(vehicle).__name__}, got {jnp.shape(state0)}")
    for what, x, names in (("state0", state0, vehicle.state_names),
                           ("inputs", None if callable(inputs) else inputs,
                            vehicle.control_names)):
        if x is None or not is_concrete(x):
            continue
        v = np.asarray(x, dtype=float)
        if np.all(np.isfinite(v)):
            continue
        # a state or input vector, or input samples (T, m): the names are the last axis's
        columns = np.flatnonzero(~np.all(np.isfinite(v.reshape(-1, v.shape[-1])), axis=0))
        named = ", ".join(names[c] if c < len(names) else str(c) for c in columns)
        raise ValueError(f"simulate: {what} must be finite; non-finite values in {named}")


def _check_finite_controls(vehicle: AbstractVehicle, u0) -> None:
    """A control function whose value at the start is not finite is refused by name, as a
    constant input is (`_check_finite_start`), rather than failing at its first step."""
    if not is_concrete(u0):
        return
    v = np.asarray(u0, dtype=float).reshape(-1)
    if not np.all(np.isfinite(v)):
        named = ", ".join(vehicle.control_names[c] if c < len(vehicle.control_names) else str(c)
                          for c in np.flatnonzero(~np.isfinite(v)))
        raise ValueError(f"simulate: inputs(t0, state0) must be finite; non-finite values in "
                         f"{named}")


def simulate(
    vehicle: AbstractVehicle,
    ts: Float[Array, " T"],
    inputs,
    state0: Float[Array, " n"],
    *,
    solver: dfx.AbstractSolver | None = None,
    rtol: float = RTOL,
    atol: float = ATOL,
    dt0: float | None = None,
    jump_ts=None,
    stepsize_controller: dfx.AbstractStepSizeController | None = None,
    max_steps: int = MAX_STEPS,
    dtmax: float | None = None,
    adjoint: dfx.AbstractAdjoint | None = None,
    dense: bool = False,
    throw: bool = True,
    progress_meter: dfx.AbstractProgressMeter | None = None,
) -> Trajectory:
    r"""Integrate $\dot y = f(y, u(t, y))$ of `vehicle` and evaluate its named signals.

    **Arguments:**

    - `vehicle`: an `AbstractVehicle` (`HalfCar`, `ReducedHalfCar`), tire included.
    - `ts`: increasing save times [s]; the solve runs from ``ts[0]`` to ``ts[-1]``.
    - `inputs`: the controls (`vehicle.control_names`): a constant vector, samples on
      `ts` of shape ``(T, m)`` (linearly interpolated; the step-size controller stops at
      the sample times), or a callable ``u(t, state)`` (time function or feedback).
    - `state0`: initial state (e.g. ``HalfCar.init_state(vx=...)``).
    - `solver`: diffrax solver, default `Tsit5` (explicit, adaptive). With dynamic tires
      the wheel-tire blocks are stiff (explicit steps of about a millisecond);
      ``ROS34PW2(vehicle.stiff_blocks)`` treats them linearly implicitly (order 3, larger
      steps; the cheaper choice at loose and moderate accuracy). A car braked to a stop
      on static tires (`FrictionEllipseTire`) is stiff without bound as it stops (the
      slips divide by $|\omega r|$, floored at 1 mm/s): 6 s of `brake_in_turn` from
      5 m/s exhausts `Tsit5`'s steps, ``ROS34PW2`` needs about 63,000; the dynamic
      tires (lumped LuGre) stop in about 1,000 `Tsit5` steps.
    - `rtol`, `atol`, `dt0`, `max_steps`: step-size control (PID) and step budget; a
      finite `max_steps` keeps reverse-mode differentiation available (defaults: those
      of every vehsim solve, `vehsim._integrate`).
    - `jump_ts`: times where the inputs have kinks (the controller steps onto them);
      sampled inputs add `ts` themselves.
    - `stepsize_controller`: replaces the default ``PIDController(rtol, atol)`` (an
      adaptive one is still clipped to `jump_ts` and the sample times).
    - `dtmax`: the largest step [s] of the default controller. The steps follow the
      motion's error alone, which from an equilibrium (free rolling at zero slip) is zero,
      and steps past the wheel-tire blocks' time constants then make the derivative wrong
      while the result is successful. By default (None) an explicit solver on a vehicle
      with ``stiff_blocks`` keeps 0.8 of its stability limit on those blocks at the start
      (`stiffness_ceiling`; about 1.5 ms with the lumped LuGre tires, 20 ms with the
      static ones at 15 m/s), which costs few steps off the equilibrium; other solvers
      have none: give ``ROS34PW2`` 10 ms to differentiate from an equilibrium
      (docs/differentiating.md).
    - `adjoint`: diffrax adjoint (default `RecursiveCheckpointAdjoint`).
    - `dense`: also keep the dense interpolant (`Trajectory.evaluate`).
    - `throw`: raise on solver failure; with ``throw=False`` check `Trajectory.result`
      (what batched sweeps do).
    - `progress_meter`: a diffrax progress meter (``diffrax.TqdmProgressMeter()``,
      ``TextProgressMeter()``); under `jax.vmap` it follows the slowest member.

    **Returns:** a `Trajectory`.
    """
    check_times("simulate", ts)
    check_solver_settings("simulate", rtol=rtol, atol=atol, max_steps=max_steps, dt0=dt0,
                          jump_ts=jump_ts, dtmax=dtmax, solver=solver,
                          stepsize_controller=stepsize_controller, adjoint=adjoint,
                          progress_meter=progress_meter)
    if dtmax is not None and stepsize_controller is not None:
        raise ValueError("simulate: dtmax bounds the default PIDController's steps; with a "
                         "stepsize_controller of your own, give the bound there "
                         "(diffrax.PIDController(rtol, atol, dtmax=...))")
    ts = jnp.asarray(ts, dtype=float)
    state0 = jnp.asarray(state0, dtype=float)
    _check_finite_start(vehicle, state0, inputs)
    u_fn, sampled = as_controls(ts, inputs, len(vehicle.control_names))
    if callable(inputs) and is_concrete(state0) and is_concrete(ts):
        _check_finite_controls(vehicle, u_fn(ts[0], state0))
    if dtmax is None and stepsize_controller is None:
        dtmax = stiffness_ceiling(vehicle, solver, u_fn, ts[0], state0)
        if dtmax is not None and is_concrete(dtmax) and not np.isfinite(dtmax):
            dtmax = None  # no ceiling (a static tire near standstill): not a setting to refuse

    def vector_field(t, y, args):
        return vehicle.f(y, u_fn(t, y))

    jumps = [jnp.atleast_1d(jnp.asarray(j, dtype=float)) for j in (jump_ts,) if j is not None]
    if sampled:
        jumps.append(ts)
    sol = integrate(
        vector_field, ts, state0, solver=solver, dt0=dt0, rtol=rtol, atol=atol,
        jump_ts=jnp.sort(jnp.concatenate(jumps)) if jumps else None,
        stepsize_controller=stepsize_controller, max_steps=max_steps, dtmax=dtmax,
        adjoint=adjoint,
        saveat=dfx.SaveAt(ts=ts, dense=dense), throw=throw, progress_meter=progress_meter,
    )
    controls = jax.vmap(u_fn)(ts, sol.ys)
    signals = jax.vmap(vehicle.signals)(sol.ys, controls)
    return Trajectory(
        ts=ts, states=sol.ys, controls=controls, signals=signals, result=sol.result,
        stats=solve_stats(sol), solution=sol if dense else None,
    )
