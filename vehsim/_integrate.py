r"""`integrate`: the one diffrax solve behind every simulation in vehsim.

`simulate`, `simulate_tire`, `simulate_quarter_car`, the exact moment closures and the
friction state of the braking fits all integrate $\dot y = f(t, y)$ through `integrate`,
with one set of defaults:

- **solver** `Tsit5` (explicit Runge-Kutta of order 5(4), adaptive);
- **step-size control** ``PIDController(rtol=RTOL, atol=ATOL)``, `RTOL` = `ATOL` = 1e-8,
  clipped to land steps on `jump_ts` (kinks and jumps of the inputs) and `step_ts`, with a
  floor of `DTMIN_FRACTION` of the time span: a step size rejected down to it ends the solve
  as `RESULTS.step_size_collapsed` (a vector field that is not finite past some time);
- **step budget** `MAX_STEPS` = 100 000: finite, so that reverse-mode differentiation is
  available (`RecursiveCheckpointAdjoint` keeps $O(\sqrt{\text{max\_steps}})$
  checkpoints); only dense or per-step saving allocates buffers of that length;
- **adjoint** `RecursiveCheckpointAdjoint` (reverse mode; `diffrax.ForwardMode()` for
  forward mode, `jax.jvp` and `jax.jacfwd`, as least squares wants them: differentiating
  the default in forward mode raises `FORWARD_MODE_MESSAGE`);
- **saving** at the time grid `ts`, the solve running from ``ts[0]`` to ``ts[-1]``;
- **failure**: the solution's `result` is a `vehsim.RESULTS` item; ``throw=True`` raises
  with its message (``result.error_if``, also under `jit`), ``throw=False`` leaves it for
  the caller (what batched runs do).

A caller that needs another solver or tolerance passes it at its call site and says why:
an implicit solver where the friction state is stiff, `DEFLECTION_ATOL` where the states
are bristle deflections, fixed unit steps of an exact step map.
"""

from __future__ import annotations

from collections.abc import Callable

import diffrax as dfx
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PyTree

from ._checks import check_count, check_finite, check_positive
from ._results import RESULTS, as_result


RTOL = 1e-8
"""Default relative tolerance of every adaptive solve."""

ATOL = 1e-8
"""Default absolute tolerance of every adaptive solve."""

DEFLECTION_ATOL = 1e-10
r"""Absolute tolerance of solves whose states are bristle deflections (of order
$10^{-5}$-$10^{-3}$ m) or their moments: it keeps their error near `RTOL` relative, where
`ATOL` would dominate it."""

MAX_STEPS = 100_000
"""Default step budget of every solve."""

DTMIN_FRACTION = 1e-12
r"""The floor of the default step-size control's steps, as a fraction of the time span
$|t_1 - t_0|$. An accepted step never shrinks the next one, so only rejected steps reach it,
and a finite vector field rejects steps only to meet the tolerances, far above it. Where
the vector field is NaN or inf just past the time reached (a control function that turns
NaN, a state outside the model's domain), each step is rejected and shrunk until the time no
longer advances: without the floor the solve then spends its whole step budget and reports
`max_steps_reached`; with it, it stops within a few dozen steps as
`RESULTS.step_size_collapsed`."""

EQUILIBRIUM_DTMAX = 0.01
r"""The largest step [s] of the quarter car's and a tire's adaptive solves
(`simulate_quarter_car`, `simulate_tire`). The step-size control sees the motion's error,
not its derivative's. From an exact equilibrium (a wheel at standstill, free rolling at
zero slip) the motion's error is zero and the steps would lengthen without bound, while a
derivative excites the tire's and the wheel's dynamics there: through steps of a third of
a second the derivative of a braked quarter car at standstill was off the central
differences by 2 to 3 times its largest entry, and a tire's at zero slip by 15 %. Steps of
at most 10 ms resolve those dynamics (to 1e-4 and 1e-6) and cost a few steps where the
solve would take fewer. `simulate` sets its own (`vehsim._simulate.stiffness_ceiling`)."""


def integrate(
    vector_field: Callable | dfx.AbstractTerm,
    ts: Float[Array, " T"] | None,
    y0: PyTree,
    *,
    args=None,
    solver: dfx.AbstractSolver | None = None,
    t0=None,
    t1=None,
    dt0=None,
    rtol: float = RTOL,
    atol: float = ATOL,
    jump_ts=None,
    step_ts=None,
    stepsize_controller: dfx.AbstractStepSizeController | None = None,
    max_steps: int = MAX_STEPS,
    dtmax: float | None = None,
    adjoint: dfx.AbstractAdjoint | None = None,
    saveat: dfx.SaveAt | None = None,
    throw: bool = True,
    progress_meter: dfx.AbstractProgressMeter | None = None,
) -> dfx.Solution:
    r"""Integrate $\dot y = f(t, y, \text{args})$ with the module's defaults.

    **Arguments:**

    - `vector_field`: ``f(t, y, args)``, or a diffrax term (e.g. a step map).
    - `ts`: increasing save times; the solve runs from ``ts[0]`` to ``ts[-1]`` and saves
      there. May be `None` when `t0`, `t1` and `saveat` are given.
    - `y0`: initial state (any PyTree).
    - `args`: passed to `vector_field`.
    - `solver`: a diffrax solver (default `Tsit5`).
    - `t0`, `t1`: override the interval (e.g. a solve in another clock than `ts`).
    - `dt0`: initial step (adaptive control) or the step (``ConstantStepSize``).
    - `rtol`, `atol`, `jump_ts`, `step_ts`: the default step-size controller,
      ``PIDController(rtol, atol)`` clipped to `jump_ts` (discontinuities: the solver
      restarts there) and `step_ts` (steps land there).
    - `stepsize_controller`: replaces the `PIDController` (`rtol` and `atol` then unused);
      an adaptive one is clipped to `jump_ts` and `step_ts` all the same (a
      `ConstantStepSize` is not: its steps land where they fall).
    - `max_steps`: the step budget.
    - `dtmax`: the largest step of the default `PIDController` (default: none).
    - `adjoint`: a diffrax adjoint (default `RecursiveCheckpointAdjoint`).
    - `saveat`: replaces ``SaveAt(ts=ts)`` (dense output, every step, a save function).
    - `throw`: raise if the solve fails; with ``throw=False`` check ``.result``.
    - `progress_meter`: a diffrax progress meter (default none).

    **Returns:** the diffrax `Solution`, its `result` a `vehsim.RESULTS` item.
    """
    check_solver_settings("integrate", rtol=rtol, atol=atol, max_steps=max_steps, dt0=dt0,
                          jump_ts=jump_ts, step_ts=step_ts, dtmax=dtmax, solver=solver,
                          stepsize_controller=stepsize_controller, adjoint=adjoint,
                          progress_meter=progress_meter)
    default_control = stepsize_controller is None
    if default_control:
        span = jax.lax.stop_gradient(
            jnp.abs((ts[-1] if t1 is None else t1) - (ts[0] if t0 is None else t0)))
        stepsize_controller = _StepFloor(dfx.PIDController(rtol=rtol, atol=atol, dtmax=dtmax),
                                         DTMIN_FRACTION * span)
    if (jump_ts is not None or step_ts is not None) and isinstance(
            stepsize_controller, dfx.AbstractAdaptiveStepSizeController):
        stepsize_controller = dfx.ClipStepSizeController(
            stepsize_controller, step_ts=step_ts, jump_ts=jump_ts)
    try:
        sol = _diffeqsolve(vector_field, solver, ts, t0, t1, dt0, y0, args, saveat,
                           stepsize_controller, max_steps, adjoint, progress_meter)
    except TypeError as e:  # JAX's words for a jvp of the checkpointed loop's custom_vjp
        if "custom_vjp" in str(e) and (adjoint is None or isinstance(
                adjoint, dfx.RecursiveCheckpointAdjoint)):
            raise TypeError(FORWARD_MODE_MESSAGE) from e
        raise
    result = as_result(sol.result)
    if default_control:  # the floor is this module's: its own case, saying what reaches it
        result = RESULTS.where(result == RESULTS.dt_min_reached, RESULTS.step_size_collapsed,
                               result)
    sol = eqx.tree_at(lambda s: s.result, sol, result)
    if throw:
        sol = result.error_if(sol, result != RESULTS.successful)
    return sol


def check_solver_settings(owner: str, *, rtol=None, atol=None, max_steps=None,
                          dt0=None, jump_ts=None, step_ts=None, dtmax=None, solver=None,
                          stepsize_controller=None, adjoint=None, progress_meter=None) -> None:
    """Refuse settings no solve can use (concrete values only; None: not given): `rtol`,
    `atol`, `dt0` and `dtmax` > 0, `max_steps` an integer >= 1, `jump_ts` and `step_ts`
    finite; `solver`, `stepsize_controller`, `adjoint` and `progress_meter` diffrax's
    objects of their kinds (``diffrax.Tsit5()``, not the name ``"Tsit5"``)."""
    for name, value, kind in (("solver", solver, dfx.AbstractSolver),
                              ("stepsize_controller", stepsize_controller,
                               dfx.AbstractStepSizeController),
                              ("adjoint", adjoint, dfx.AbstractAdjoint),
                              ("progress_meter", progress_meter, dfx.AbstractProgressMeter)):
        if value is not None and not isinstance(value, kind):
            raise TypeError(f"{owner}.{name} must be a diffrax.{kind.__name__} (e.g. "
                            f"diffrax.{_EXAMPLES[name]}), got {value!r}")
    for name, value in (("rtol", rtol), ("atol", atol), ("dt0", dt0), ("dtmax", dtmax)):
        if value is not None:
            check_positive(owner, name, value)
    if max_steps is not None:
        check_count(owner, "max_steps", max_steps)
    for name, value in (("jump_ts", jump_ts), ("step_ts", step_ts)):
        if value is not None:
            check_finite(owner, name, value)


_EXAMPLES = {"solver": "Tsit5()", "stepsize_controller": "PIDController(rtol=1e-8, atol=1e-8)",
             "adjoint": "ForwardMode()", "progress_meter": "TqdmProgressMeter()"}


FORWARD_MODE_MESSAGE = (
    "forward-mode differentiation (jax.jvp, jax.jacfwd) of an integration with the default "
    "adjoint (diffrax.RecursiveCheckpointAdjoint, reverse mode only): pass "
    "adjoint=diffrax.ForwardMode(), or differentiate in reverse mode (jax.grad, jax.jacrev)")
"""The error of a forward-mode derivative through `integrate` with its default adjoint."""


class _StepFloor(dfx.AbstractAdaptiveStepSizeController):
    """An adaptive controller whose rejected step proposing a next step shorter than `dtmin`
    ends the solve (`dt_min_reached`). The wrapped controller's steps are left exactly as
    they are (diffrax's own ``dtmin`` clips them, and the compiled program's rounding with
    them): the floor only reads them."""

    controller: dfx.AbstractAdaptiveStepSizeController
    dtmin: Float[Array, ""]

    @property
    def rtol(self):
        return self.controller.rtol

    @property
    def atol(self):
        return self.controller.atol

    @property
    def norm(self):  # pyright: ignore[reportIncompatibleMethodOverride]
        return self.controller.norm

    def wrap(self, direction):
        return _StepFloor(self.controller.wrap(direction), self.dtmin)

    def init(self, *args, **kwargs):
        return self.controller.init(*args, **kwargs)

    def adapt_step_size(self, *args, **kwargs):
        keep, t0, t1, jump, state, result = self.controller.adapt_step_size(*args, **kwargs)
        result = dfx.RESULTS.where(~keep & (t1 - t0 < self.dtmin), dfx.RESULTS.dt_min_reached,
                                   result)
        return keep, t0, t1, jump, state, result


def _diffeqsolve(vector_field, solver, ts, t0, t1, dt0, y0, args, saveat, stepsize_controller,
                 max_steps, adjoint, progress_meter):
    return dfx.diffeqsolve(
        vector_field if isinstance(vector_field, dfx.AbstractTerm) else dfx.ODETerm(vector_field),
        dfx.Tsit5() if solver is None else solver,
        t0=ts[0] if t0 is None else t0,
        t1=ts[-1] if t1 is None else t1,
        dt0=dt0,
        y0=y0,
        args=args,
        saveat=dfx.SaveAt(ts=ts) if saveat is None else saveat,
        stepsize_controller=stepsize_controller,
        max_steps=max_steps,
        adjoint=dfx.RecursiveCheckpointAdjoint() if adjoint is None else adjoint,
        throw=False,
        progress_meter=dfx.NoProgressMeter() if progress_meter is None else progress_meter,
    )


def solve_stats(sol: dfx.Solution) -> dict[str, Array]:
    """The step counts of a diffrax solve: ``num_steps``, ``num_accepted_steps`` and
    ``num_rejected_steps`` (arrays, so that they batch under `jax.vmap`)."""
    return {k: jnp.asarray(sol.stats[k])
            for k in ("num_steps", "num_accepted_steps", "num_rejected_steps")}
