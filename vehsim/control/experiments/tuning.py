r"""Tuning the smooth controllers' gains by gradient: the mean stopping distance over a batch.

For a slip-tracking controller (`SlipTracking`, `PeakSlipTracking`) with gains
$(K_p, K_i) = e^{g}$, the objective is
$$J(g) = \frac1M\sum_{m=1}^M \frac{d_m(g)}{b_m},$$
$d_m$ the stopping distance of member $m$ of a batch of surfaces, initial speeds and noise
seeds, $b_m$ its physical limit (so that each member weighs alike). Its gradient comes from
forward-mode differentiation through the whole closed loop (two tangents, one per gain),
handed to optimistix's BFGS through a custom JVP rule. Reverse mode gives the same gradient
(`jax.grad` of `mean_distance_ratio`; tests/test_control_gradients.py checks the two against
finite differences); with two parameters forward mode is the cheaper of the two, in memory
(nothing stored per sample) and in compile time (docs/differentiating.md). The stopping
distance is the interpolated crossing of `STOP_SPEED`, a smooth function of the trajectory;
the tuning runs with the controllers regulating down to the stop (no hand-back, whose switch
would make the distance jump with the gains) and without the tone wheel (whose edge counts
are piecewise constant in the trajectory), the speed noise kept. The tuned gains are then judged with the full hardware
on surfaces and speeds left out.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from ..controllers.braking import AbstractSlipTracking
from ..estimation.observer import FrictionObserver
from ..loop import closed_loop
from ..plant.hardware import BrakeHardware
from ..plant.quarter_car import BrakingScenario


TUNING_HANDBACK = 0.5
"""Hand-back speed [m/s] while tuning: below `STOP_SPEED`, so never before the stop."""


def with_gains(controller: AbstractSlipTracking, log_gains):
    """`controller` with $(K_p, K_i) = e^{g}$."""
    return eqx.tree_at(lambda c: (c.kp, c.ki), controller,
                       (jnp.exp(log_gains[0]), jnp.exp(log_gains[1])))


def mean_distance_ratio(log_gains, controller: AbstractSlipTracking,
                        scenarios: BrakingScenario, observers: FrictionObserver, keys, bounds,
                        hardware: BrakeHardware, n_steps: int):
    r"""$J(g)$ of the module docstring over the batch (`scenarios`, `observers`, `keys` and
    the limits `bounds` with a leading batch axis)."""
    c = with_gains(controller, log_gains)

    def one(sc, ob, key):
        return closed_loop(sc, c, ob, hardware, key, n_steps, save=False,
                           handback_speed=TUNING_HANDBACK).stopping_distance

    return jnp.mean(jax.vmap(one)(scenarios, observers, keys) / bounds)


def objective(controller, scenarios, observers, keys, bounds, hardware, n_steps):
    """$g \\mapsto J(g)$ with a forward-mode gradient (custom JVP), for optimistix."""

    def value(g):
        return mean_distance_ratio(g, controller, scenarios, observers, keys, bounds, hardware,
                                   n_steps)

    @jax.custom_jvp
    def J(g):
        return value(g)

    @J.defjvp
    def _(primals, tangents):
        (g,), (dg,) = primals, tangents
        f, grad = value_and_forward_grad(value, g)
        return f, grad @ dg

    return J


def value_and_forward_grad(fn, g):
    """``(fn(g), grad fn(g))`` by one forward-mode pass per coordinate (vmapped): the value
    and gradient ``jax.value_and_grad(fn)(g)`` gives in one reverse-mode pass."""
    basis = jnp.eye(g.shape[0], dtype=g.dtype)
    values, grads = jax.vmap(lambda e: jax.jvp(fn, (g,), (e,)))(basis)
    return values[0], grads


_distance_ratio = eqx.filter_jit(mean_distance_ratio)


@eqx.filter_jit
def _bfgs(controller, scenarios, observers, keys, bounds, hardware, n_steps, max_steps):
    J = objective(controller, scenarios, observers, keys, bounds, hardware, n_steps)
    g0 = jnp.log(jnp.stack([controller.kp, controller.ki]))
    sol = optx.minimise(lambda g, _: J(g), optx.BFGS(rtol=1e-4, atol=1e-4), g0,
                        max_steps=max_steps, throw=False)
    return sol.value, sol.stats["num_steps"], sol.result


def tune_gains(controller: AbstractSlipTracking, scenarios, observers, keys, bounds,
               hardware: BrakeHardware, n_steps: int, max_steps: int = 12):
    r"""Minimise $J$ over $\log(K_p, K_i)$ from the controller's gains by BFGS.

    The search and the two evaluations of $J$ are separate compiled programs (one copy of
    the closed loop each; the evaluations share one), which keeps compilation small.

    **Returns:** ``(tuned controller, J at the start, J at the end, number of steps,
    result)``.
    """
    g, steps, result = _bfgs(controller, scenarios, observers, keys, bounds, hardware, n_steps,
                             max_steps)
    g0 = jnp.log(jnp.stack([controller.kp, controller.ki]))
    j0, j1 = (_distance_ratio(x, controller, scenarios, observers, keys, bounds, hardware, n_steps)
              for x in (g0, g))
    return with_gains(controller, g), j0, j1, steps, result
