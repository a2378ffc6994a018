r"""Driving a tire model through prescribed inputs: the transient friction forces.

`simulate_tire` drives a longitudinal tire by $v(t)$, $\omega(t)$: the "friction-state ODE
driven by measured speeds" of report section 2.2 (used to compare models, and by
`vehsim.identify` to fit parameters against braking data). `simulate_tire_2d` drives a
combined-slip `AbstractTire` by $v_x(t)$, $v_y(t)$, $\omega(t)$ and $F_z(t)$ (report
sections 2.3-2.4).
"""

from __future__ import annotations

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PyTree

from .._results import RESULTS, as_result
from .._signals import as_signal
from .base import AbstractTire
from .lugre import AbstractLongitudinalTire


class TireSolution(eqx.Module):
    """Result of `simulate_tire`: states and normalised force at the save times."""

    ts: Float[Array, " T"]
    state: PyTree
    mu: Float[Array, " T"]
    v: Float[Array, " T"]
    omega: Float[Array, " T"]
    result: RESULTS = eqx.field(converter=as_result)
    num_steps: Array


def simulate_tire(
    model: AbstractLongitudinalTire,
    ts: Float[Array, " T"],
    v,
    omega,
    r,
    state0=None,
    *,
    solver: dfx.AbstractSolver | None = None,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 100_000,
    adjoint: dfx.AbstractAdjoint | None = None,
    throw: bool = True,
) -> TireSolution:
    r"""Integrate the friction state of `model` driven by $v(t)$, $\omega(t)$.

    **Arguments:**

    - `model`: any `AbstractLongitudinalTire` (point, lumped, distributed).
    - `ts`: increasing save times [s]; the solve runs from `ts[0]` to `ts[-1]`.
    - `v`, `omega`: wheel-centre speed [m/s] and wheel angular speed [rad/s], each a
      constant, samples on `ts` (linearly interpolated), or a callable of `t`.
    - `r`: rolling radius [m].
    - `state0`: initial friction state (default undeflected).
    - `solver`: diffrax solver (default `Kvaerno5`, implicit: the bristle dynamics are stiff
      at large slip, rates up to $\theta\sigma_0|v_r|/g \sim 10^4$ 1/s).
    - `throw`: raise if the solve fails; with `throw=False` check `result`.

    **Returns:** a `TireSolution` with `mu` $=F/F_n$ at `ts`.
    """
    ts = jnp.asarray(ts, dtype=float)
    v_fn, omega_fn = as_signal(ts, v), as_signal(ts, omega)
    y0 = model.init_state() if state0 is None else state0
    sampled = not (callable(v) and callable(omega))

    def vector_field(t, y, args):
        return model.dynamics(y, v_fn(t), omega_fn(t), r)

    controller = dfx.PIDController(
        rtol=rtol, atol=atol, jump_ts=ts if sampled and ts.shape[0] <= 20_000 else None
    )
    sol = dfx.diffeqsolve(
        dfx.ODETerm(vector_field),
        dfx.Kvaerno5() if solver is None else solver,
        t0=ts[0],
        t1=ts[-1],
        dt0=None,
        y0=y0,
        saveat=dfx.SaveAt(ts=ts),
        stepsize_controller=controller,
        max_steps=max_steps,
        adjoint=dfx.RecursiveCheckpointAdjoint() if adjoint is None else adjoint,
        throw=throw,
    )
    vs, oms = jax.vmap(v_fn)(ts), jax.vmap(omega_fn)(ts)
    mu = jax.vmap(lambda y, a, b: model.mu(y, a, b, r))(sol.ys, vs, oms)
    return TireSolution(
        ts=ts, state=sol.ys, mu=mu, v=vs, omega=oms, result=sol.result,
        num_steps=sol.stats["num_steps"],
    )


class Tire2DSolution(eqx.Module):
    """Result of `simulate_tire_2d`: states and ``(F_x, F_y, M_z)`` at the save times."""

    ts: Float[Array, " T"]
    state: PyTree
    forces: Float[Array, "T 3"]
    result: RESULTS = eqx.field(converter=as_result)
    num_steps: Array


def simulate_tire_2d(
    model: AbstractTire,
    ts,
    vx,
    vy,
    omega,
    r,
    Fz,
    state0=None,
    *,
    solver=None,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    max_steps: int = 100_000,
    throw: bool = True,
) -> Tire2DSolution:
    r"""Integrate a combined-slip tire driven by $v_x(t), v_y(t), \omega(t)$ (diffrax).

    **Arguments:** `model` (any `AbstractTire`), save times `ts` [s]; `vx`, `vy` [m/s],
    `omega` [rad/s], `Fz` [N]: constants, samples on `ts` or callables of `t`; `r` [m];
    `solver` (default `Kvaerno5`: the bristle dynamics are stiff); `throw` as in diffrax.

    **Returns:** a `Tire2DSolution` with `forces[:, k]` = $F_x, F_y, M_z$.
    """
    ts = jnp.asarray(ts, dtype=float)
    sig = [as_signal(ts, x) for x in (vx, vy, omega, Fz)]
    y0 = model.init_state() if state0 is None else state0

    def inputs(t):
        return tuple(f(t) for f in sig)

    def vector_field(t, y, args):
        vx_, vy_, om_, fz_ = inputs(t)
        return model.dynamics(y, vx_, vy_, om_, r, fz_)

    sol = dfx.diffeqsolve(
        dfx.ODETerm(vector_field),
        dfx.Kvaerno5() if solver is None else solver,
        t0=ts[0], t1=ts[-1], dt0=None, y0=y0,
        saveat=dfx.SaveAt(ts=ts),
        stepsize_controller=dfx.PIDController(rtol=rtol, atol=atol),
        max_steps=max_steps, throw=throw,
    )

    def force_at(t, y):
        vx_, vy_, om_, fz_ = inputs(t)
        return model.forces(y, vx_, vy_, om_, r, fz_)

    forces = jax.vmap(force_at)(ts, sol.ys)
    return Tire2DSolution(ts=ts, state=sol.ys, forces=forces, result=sol.result,
                          num_steps=sol.stats["num_steps"])
