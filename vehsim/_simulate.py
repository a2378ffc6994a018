r"""`simulate`: vehicle + tire + inputs + initial state + time grid -> named trajectory.

Pure and composable: `jax.jit`, `jax.vmap` (over parameters, inputs and initial states)
and `jax.grad` apply to `simulate` end to end.
"""

from __future__ import annotations

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


def _check_finite_start(vehicle: AbstractVehicle, state0, inputs) -> None:
    """A NaN or inf in a concrete initial state or input array is refused by name: the
    solver would otherwise spend its step budget and report `max_steps_reached`. A state
    of another length than the vehicle's is refused too."""
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
      steps; the cheaper choice at loose and moderate accuracy). Differentiating from an
      exact equilibrium (free rolling at zero slip), either solver's derivative can be
      wrong while its result is successful, unless `dtmax` bounds the steps.
    - `rtol`, `atol`, `dt0`, `max_steps`: step-size control (PID) and step budget; a
      finite `max_steps` keeps reverse-mode differentiation available (defaults: those
      of every vehsim solve, `vehsim._integrate`).
    - `jump_ts`: times where the inputs have kinks (the controller steps onto them);
      sampled inputs add `ts` themselves.
    - `stepsize_controller`: replaces the default ``PIDController(rtol, atol)`` (an
      adaptive one is still clipped to `jump_ts` and the sample times).
    - `dtmax`: the largest step [s] of the default controller (default: none). Give one
      to differentiate from an exact equilibrium (free rolling, standstill): the steps
      follow the motion's error alone, which is zero there, and steps longer than the
      tires' time constants make the derivative wrong while the result is successful.
      `Tsit5` needs about its own step off the equilibrium (1 ms for the lumped LuGre half
      car at 15 m/s), `ROS34PW2` 10 ms (docs/differentiating.md).
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
                          jump_ts=jump_ts, dtmax=dtmax)
    if dtmax is not None and stepsize_controller is not None:
        raise ValueError("simulate: dtmax bounds the default PIDController's steps; with a "
                         "stepsize_controller of your own, give the bound there "
                         "(diffrax.PIDController(rtol, atol, dtmax=...))")
    ts = jnp.asarray(ts, dtype=float)
    state0 = jnp.asarray(state0, dtype=float)
    _check_finite_start(vehicle, state0, inputs)
    u_fn, sampled = as_controls(ts, inputs, len(vehicle.control_names))

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
