r"""Driving a tire model through prescribed inputs: the transient friction forces.

`simulate_tire` drives any tire by $v_x(t)$, $\omega(t)$ and, for a combined-slip
`AbstractTire`, $v_y(t)$ and $F_z(t)$: for a longitudinal tire the "friction-state ODE
driven by measured speeds" of report section 2.2 (used to compare models, and by
`vehsim.identify` to fit parameters against braking data), for a combined-slip one the
transients of report sections 2.3-2.4.
"""

from __future__ import annotations

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PyTree

from .._checks import (
    check_finite_signals,
    check_nonnegative,
    check_positive,
    check_shaped_like,
    check_times,
)
from .._integrate import (
    DEFLECTION_ATOL,
    EQUILIBRIUM_DTMAX,
    MAX_STEPS,
    RTOL,
    check_solver_settings,
    integrate,
    solve_stats,
)
from .._results import RESULTS, as_result
from .._signals import as_signal
from .._solution import AbstractSolution
from .base import AbstractTire
from .lugre import AbstractLongitudinalTire


INPUT_NAMES = ("vx", "vy", "omega", "Fz")
"""The inputs of a tire, in the order of `AbstractTire.dynamics`."""

MAX_JUMP_SAMPLES = 20_000
"""Sampled inputs of at most this many samples land steps on every sample (the kinks of
their linear interpolation); longer records are stepped through freely."""


class TireSolution(AbstractSolution):
    r"""Result of `simulate_tire` and of the moment solves: the friction state and the forces
    at the save times.

    `forces[..., k]` = $F_x, F_y, M_z$ [N, N, N m] on the tire (a longitudinal tire's
    $F_x = \mu F_z$, $F_y = M_z = 0$); `inputs` the inputs ``vx``, ``vy``, ``omega``,
    ``Fz`` at `ts`. `signals` holds both (``sol["Fx"]``, ``sol["omega"]``), `mu` is
    $F_x/F_z$.
    """

    ts: Float[Array, " T"]
    state: PyTree
    forces: Float[Array, "T 3"]
    inputs: dict
    result: RESULTS = eqx.field(converter=as_result)
    stats: dict

    @property
    def signals(self) -> dict:
        forces = {n: self.forces[..., k] for k, n in enumerate(("Fx", "Fy", "Mz"))}
        return self.inputs | forces

    @property
    def mu(self) -> Array:
        r"""$F_x/F_z$ at `ts` (a longitudinal tire's friction coefficient)."""
        return self.forces[..., 0] / self.inputs["Fz"]


def input_signals(ts, vx, vy, omega, Fz) -> tuple:
    """The inputs as functions of time (constants, samples on `ts` or callables)."""
    return tuple(as_signal(ts, x, name=n) for x, n in zip((vx, vy, omega, Fz), INPUT_NAMES))


def inputs_at(ts, signals) -> dict:
    """The input `signals` (`input_signals`) evaluated at `ts`, by name."""
    return {n: jnp.broadcast_to(jax.vmap(f)(ts), ts.shape) for n, f in zip(INPUT_NAMES, signals)}


def _sampled_jumps(ts, *xs):
    """`ts` where an input is given as samples (the kinks of its interpolation), else None."""
    sampled = any(not callable(x) and jnp.ndim(x) > 0 for x in xs)
    return ts if sampled and ts.shape[0] <= MAX_JUMP_SAMPLES else None


def simulate_tire(
    model: AbstractTire | AbstractLongitudinalTire,
    ts: Float[Array, " T"],
    vx,
    omega,
    r,
    state0=None,
    *,
    vy=None,
    Fz=1.0,
    solver: dfx.AbstractSolver | None = None,
    rtol: float = RTOL,
    atol: float = DEFLECTION_ATOL,
    max_steps: int = MAX_STEPS,
    dtmax: float | None = EQUILIBRIUM_DTMAX,
    adjoint: dfx.AbstractAdjoint | None = None,
    throw: bool = True,
) -> TireSolution:
    r"""Integrate the friction state of `model` driven by $v_x(t)$, $\omega(t)$ (and
    $v_y(t)$, $F_z(t)$).

    **Arguments:**

    - `model`: an `AbstractLongitudinalTire` (point, lumped, distributed LuGre, relaxed
      Magic Formula) or a combined-slip `AbstractTire`.
    - `ts`: increasing save times [s]; the solve runs from `ts[0]` to `ts[-1]`.
    - `vx`, `omega`: wheel-centre speed along the wheel [m/s] and wheel angular speed
      [rad/s]; like `vy` and `Fz` a constant, samples on `ts` (linearly interpolated; steps
      land on the samples) or a callable of `t`.
    - `r`: rolling radius [m].
    - `state0`: initial friction state (default undeflected).
    - `vy`: lateral speed [m/s] (combined-slip tires only; default 0).
    - `Fz`: normal load [N] (default 1: forces per unit load, $F_x = \mu$).
    - `solver`: diffrax solver (default `Kvaerno5`, implicit: the bristle dynamics are stiff
      at large slip, rates up to $\theta\sigma_0|v_r|/g \sim 10^4$ 1/s).
    - `rtol`, `atol` (default `DEFLECTION_ATOL`: the states are deflections),
      `max_steps`, `adjoint`: as in every vehsim solve (`vehsim._integrate`).
    - `dtmax`: the largest step [s] (default `EQUILIBRIUM_DTMAX`, 10 ms: at zero slip or at
      standstill the motion's error alone would lengthen the steps past what a derivative
      needs; None: unbounded).
    - `throw`: raise if the solve fails; with `throw=False` check `result`.

    **Returns:** a `TireSolution`: `forces` $(F_x, F_y, M_z)$ and `mu` $= F_x/F_z$ at `ts`.
    """
    check_times("simulate_tire", ts)
    check_solver_settings("simulate_tire", rtol=rtol, atol=atol, max_steps=max_steps,
                          dtmax=dtmax, solver=solver, adjoint=adjoint)
    check_finite_signals("simulate_tire", vx=vx, omega=omega, r=r, vy=vy, Fz=Fz)
    if not callable(r):
        check_positive("simulate_tire", "r", r)
    if not callable(Fz):
        check_nonnegative("simulate_tire", "Fz", Fz)
    ts = jnp.asarray(ts, dtype=float)
    longitudinal = isinstance(model, AbstractLongitudinalTire)
    if not (longitudinal or isinstance(model, AbstractTire)):
        raise TypeError(f"simulate_tire needs a tire model, got {type(model).__name__}")
    if longitudinal and vy is not None:
        raise ValueError(f"simulate_tire: vy must be None for the longitudinal tire "
                         f"{type(model).__name__}")
    vy = 0.0 if vy is None else vy
    signals = input_signals(ts, vx, vy, omega, Fz)
    vx_s, vy_s, om_s, fz_s = signals
    y0 = model.init_state()
    if state0 is not None:
        check_shaped_like("simulate_tire", "state0", state0, y0,
                          f"{type(model).__name__}.init_state()")
        y0 = state0

    if longitudinal:
        def vector_field(t, y, args):
            return model.dynamics(y, vx_s(t), om_s(t), r)

        def force_at(t, y):
            mu = model.mu(y, vx_s(t), om_s(t), r)
            return jnp.stack([mu * fz_s(t), jnp.zeros_like(mu), jnp.zeros_like(mu)])
    else:
        def vector_field(t, y, args):
            return model.dynamics(y, vx_s(t), vy_s(t), om_s(t), r, fz_s(t))

        def force_at(t, y):
            return model.forces(y, vx_s(t), vy_s(t), om_s(t), r, fz_s(t))

    sol = integrate(
        vector_field, ts, y0,
        solver=dfx.Kvaerno5() if solver is None else solver,  # stiff: see the docstring
        rtol=rtol, atol=atol, jump_ts=_sampled_jumps(ts, vx, vy, omega, Fz),
        max_steps=max_steps, dtmax=dtmax, adjoint=adjoint, throw=throw,
    )
    forces = jax.vmap(force_at)(ts, sol.ys)
    return TireSolution(ts=ts, state=sol.ys, forces=forces, inputs=inputs_at(ts, signals),
                        result=sol.result, stats=solve_stats(sol))
