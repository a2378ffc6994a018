r"""The interior-point loop: options, solution, state, and `interior_point`.

The start: slacks $s = \max(g, \min(10^{-2}, 10\mu_0))$, $z = \mu_0 / s$ (on the central
path), and the defect and equality multipliers $(\lambda, \nu)$ that minimise the first
Lagrangian gradient (IPOPT's least-squares estimate, from the KKT system with $W = I$:
values, Jacobians and one factorisation before the first iteration; ``multiplier_init``
and ``bound_multiplier_init`` of `IPOptions` select the alternatives, docs/performance.md
compares them).

One iteration at the iterate $(y, s, z, \lambda, \nu)$ and barrier $\mu$:

1. stage values and derivatives (`stage_derivatives`), the residuals and the scaled KKT
   errors (`kkt_residuals`); stop when $E_0 \le$ ``tol`` and the constraint violation is
   below ``constr_tol``;
2. the monotone (Fiacco-McCormick) barrier update: while $E_\mu \le 10\mu$,
   $\mu \leftarrow \max(\text{tol}/10, \min(0.2\mu, \mu^{1.5}))$ (several decreases in
   one iteration where the iterate allows);
3. the Newton step of the condensed, inertia-corrected KKT system (`newton_step`);
4. fraction to the boundary ($\tau = \max(0.99, 1 - \mu)$) for the slacks (primal step) and
   the multipliers $z$ (dual step), then the filter line search on the primal step (with a
   second-order correction of a full step that raised the constraint violation);
5. the step, with $z$ kept within a factor $\kappa_\Sigma$ of $\mu S^{-1}$.

A line search that accepts no trial takes the shortest one and forgets the filter (the
method has no restoration phase). Where the multipliers are re-estimated after it
(``reestimate_multipliers``) the next pass starts from new $(\lambda, \nu)$; where they are
not, the next pass starts from the same primal point, and a second failure in a row ends the
solve (`STALLED_PASSES`, `RESULTS.ip_line_search_failed`): further passes would repeat
the same step at the full cost of its trials (a fixed-work solve's slowest passes). A
pass whose inertia correction accepts no regularisation (`MAX_FACTORISATIONS` of them:
non-finite derivatives, or a precision the solve's backward-error test cannot meet) has no
Newton direction, and ends the solve with `RESULTS.ip_newton_system_failed` at its iterate
(IPOPT would enter its restoration phase).

The whole solve is one `lax.while_loop`: it compiles once, and `vmap` runs a batch of problems
together. A solve that reaches ``max_iter`` ends with a pass that takes no step: it tests
convergence at the iterate returned, from values and Jacobians only (no Hessian). Where the
constraint violation is then above ``constr_tol``, no pass of the last `INFEASIBLE_PASSES`
reduced it by 1 % and none of the log brought it below `VIOLATION_REACHED` of the starting
one, the result is `RESULTS.ip_locally_infeasible`
rather than `RESULTS.ip_max_iterations`: more iterations would probably not help (IPOPT's
"converged to a point of local infeasibility"; here a diagnosis of the passes made, not a
proof, since the method has no restoration phase). Only the result differs: the iterate,
its residuals and the log are those of the limit.
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ..._checks import check_integer, check_positive, check_range, is_concrete
from ..._derivative_modes import forward_mode_only
from ..._fields import array_field, bool_field, int_field
from ..._results import RESULTS, as_result, result_message
from ._carry import strong
from .derivatives import (
    StageDerivatives,
    stage_derivatives,
    stage_jacobians,
    stage_values,
    stage_values_and_lagrangian_gradient,
)
from .implicit import implicit_solve
from .kkt import (
    BACKWARD_ERROR_SINGULAR,
    MAX_REFINEMENT_STEPS,
    Iterate,
    NewtonStep,
    Residuals,
    barrier_error,
    capped_multipliers,
    kkt_residuals,
    newton_step,
    second_order_correction,
)
from .linesearch import (
    Filter,
    constraint_violation,
    filter_line_search,
    fraction_to_boundary,
)
from .problem import AbstractStagewiseNLP, StageLayout, stage_layout


KAPPA_SIGMA = 1e10
"""Bound on the deviation of $z$ from $\\mu S^{-1}$ (IPOPT's $\\kappa_\\Sigma$)."""
TAU_MIN = 0.99
"""Smallest fraction-to-boundary parameter $\\tau$."""
MU_DECREASE, MU_POWER, MU_TEST = 0.2, 1.5, 10.0
"""Barrier update: $\\mu \\leftarrow \\min(0.2\\mu, \\mu^{1.5})$ once $E_\\mu \\le 10\\mu$."""
DELTA_RESET = 1e8
"""A step that needed a larger primal regularisation (or a failed line search) re-estimates
the defect and equality multipliers by least squares on the next pass."""
STALLED_PASSES = 2
"""Consecutive passes whose line search accepted no trial that end a solve which does not
re-estimate its multipliers (the first is retried without its filter)."""
INITIAL_SLACK = 1e-2
"""Initial slacks are at least $\\min(10^{-2}, 10\\mu_0)$."""
INFEASIBLE_PASSES = 25
"""A solve that reaches ``max_iter`` with its constraint violation above ``constr_tol``, and
not reduced by `VIOLATION_PROGRESS` over its last 25 passes, ends with
`RESULTS.ip_locally_infeasible` rather than `RESULTS.ip_max_iterations`. Judged from the
iteration log (`passes_without_progress`): a solve of more passes than ``log_size`` is
not judged."""
VIOLATION_PROGRESS = 0.01
"""The relative reduction of the constraint violation that counts as progress."""
VIOLATION_REACHED = 1e-3
"""A solve that brought its constraint violation below this fraction of the starting one at
any pass is not judged infeasible however long it stalls: it has been near a feasible point
and is stuck on optimality (the dual infeasibility), and ends `RESULTS.ip_max_iterations`."""


class IPOptions(eqx.Module):
    """Interior-point settings. ``tol``: scaled KKT error for convergence; ``constr_tol``:
    largest constraint violation at convergence; ``max_iter``; ``log_size``: length of the
    iteration log; ``hessian``: 'forward-over-reverse' (the Hessian of the weighted stage
    Lagrangian only; the default) or 'forward-over-forward' (every per-output Hessian, then
    weighted); ``hessian_update``: 'every' (the Hessian of the Lagrangian at every
    iterate: Newton's method) or 'first' (the Hessian of the first step kept for the
    later passes, whose values and Jacobians are fresh: the limit is still a KKT point,
    reached linearly rather than quadratically, and such a pass costs about a third; for
    real-time iterations of a few passes from a close warm start; a kept Hessian that
    needed a regularisation starts the next pass's inertia correction from it, not from 0);
    ``jacobian_update``: 'every' (fresh Jacobians every pass) or 'first' (with
    ``hessian_update='first'``: the kept passes keep the Jacobians of the last fresh step
    too, and evaluate the values and the Lagrangian gradient, by one reverse pass, so that
    the residuals and the limit are exact, `_adjoint_derivatives`);
    ``fresh_hessian_steps``: with 'first', the steps that take a fresh Hessian before it
    is kept (1; an array, so that a solve by Newton's method, ``max_iter`` of them, and a
    frozen one are one program); ``mu0``: initial
    barrier (small for warm starts); ``reestimate_multipliers``: after a pass whose line
    search failed or whose regularisation exceeded `DELTA_RESET` (multipliers running
    away), the next pass re-estimates $(\\lambda, \\nu)$ by least squares (one more
    factorisation, not counted as an iteration; off for a fixed work per solve; an array,
    so one program serves both);
    ``multiplier_init``:
    'least-squares' (the defect and equality multipliers that minimise the first Lagrangian
    gradient, IPOPT's default) or 'zero'; ``bound_multiplier_init``: 'constant' ($z = 1$,
    IPOPT's default) or 'mu-based' ($z = \\mu_0 / s$, on the central path; the default);
    ``verbose``: print the iteration log to stderr when the solve returns
    (`print_iteration_log`; not part of the compiled program, so the quiet and the verbose
    solve are one program); ``live``: print each iteration's line while the solve runs (a
    host callback per iteration, so a program of its own; for one solve, not a `vmap`ped
    batch, whose members would interleave); ``best_iterate``: a solve that stops without
    converging returns the iterate of the smallest scaled KKT error it reached, with its
    residuals, objective and multipliers, instead of the last one (its ``result``,
    ``iterations`` and ``log`` unchanged): for a plan that is used whatever the outcome, such
    as a receding-horizon controller's, where the iterates of a solve that does not settle
    can wander far from the nearly converged ones it passed (off: the last iterate);
    ``backward_error_singular``: the largest componentwise backward error of a Newton solve
    after iterative refinement that is accepted (`BACKWARD_ERROR_SINGULAR`, 1e-5, IPOPT's
    ``residual_ratio_singular``); above it the factor counts as singular and the
    regularisation grows. A solve is refined only where its first backward error exceeds
    `BACKWARD_ERROR_TOL` (1e-10), by at most ``max_refinement_steps`` steps
    (`MAX_REFINEMENT_STEPS`, 10, IPOPT's ``max_refinement_steps``; refinement stops where the
    error stops falling). Setting ``backward_error_singular`` to 1e-10 as well accepts only
    solves that reach that, and ``max_refinement_steps=1`` refines once (the drive's
    solves, `vehsim.drive.horizon.PLAN_REFINEMENT_STEPS`): where the factorisation loses
    accuracy, more regularised and shorter steps, on a path that follows the compiled
    program's rounding."""

    tol: float = eqx.field(static=True, default=1e-8)
    constr_tol: float = eqx.field(static=True, default=1e-9)
    max_iter: Int[Array, ""] = int_field(default=300)
    log_size: int = eqx.field(static=True, default=1000)
    hessian: str = eqx.field(static=True, default="forward-over-reverse")
    hessian_update: str = eqx.field(static=True, default="every")
    jacobian_update: str = eqx.field(static=True, default="every")
    fresh_hessian_steps: Int[Array, ""] = int_field(default=1)
    reestimate_multipliers: Bool[Array, ""] = bool_field(default=True)
    mu0: Float[Array, ""] = array_field(default=0.1)
    multiplier_init: str = eqx.field(static=True, default="least-squares")
    bound_multiplier_init: str = eqx.field(static=True, default="mu-based")
    verbose: bool = eqx.field(static=True, default=False)
    live: bool = eqx.field(static=True, default=False)
    best_iterate: bool = eqx.field(static=True, default=False)
    backward_error_singular: float = eqx.field(static=True, default=BACKWARD_ERROR_SINGULAR)
    max_refinement_steps: int = eqx.field(static=True, default=MAX_REFINEMENT_STEPS)

    def __check_init__(self):
        for name, allowed in (("multiplier_init", ("least-squares", "zero")),
                              ("bound_multiplier_init", ("constant", "mu-based")),
                              ("hessian", ("forward-over-reverse", "forward-over-forward")),
                              ("hessian_update", ("every", "first")),
                              ("jacobian_update", ("every", "first"))):
            if getattr(self, name) not in allowed:
                raise ValueError(f"IPOptions.{name} must be one of {allowed}, "
                                 f"got {getattr(self, name)!r}")
        for name in ("verbose", "live", "best_iterate"):
            if not isinstance(getattr(self, name), bool | np.bool_):
                raise TypeError(f"IPOptions.{name} must be True or False, got "
                                f"{getattr(self, name)!r}")
        check_integer("IPOptions", "fresh_hessian_steps", self.fresh_hessian_steps, lower=1)
        check_integer("IPOptions", "max_iter", self.max_iter, lower=1)
        check_integer("IPOptions", "log_size", self.log_size, lower=1)
        for name in ("tol", "constr_tol", "mu0"):
            check_positive("IPOptions", name, getattr(self, name))
        check_range("IPOptions", "backward_error_singular", self.backward_error_singular,
                    lower=0.0, upper=1.0, lower_open=True, upper_open=True)
        check_integer("IPOptions", "max_refinement_steps", self.max_refinement_steps, lower=1)
        if self.jacobian_update == "first" and self.hessian_update != "first":
            raise ValueError("IPOptions.jacobian_update='first' keeps the Jacobians with the "
                             "Hessian: it needs hessian_update='first', got "
                             f"{self.hessian_update!r}")


class IPLog(eqx.Module):
    """Per-iteration history (arrays of length ``log_size``; entries past the last iteration
    are NaN, or 0 for the counts): ``objective``, ``inf_pr``, ``inf_du``, barrier ``mu``,
    step ``alpha``, the primal ``regularisation`` $\\delta$, the ``factorisations`` of the
    KKT matrix (inertia correction) and the line-search ``trials``."""

    objective: Float[Array, " L"]
    inf_pr: Float[Array, " L"]
    inf_du: Float[Array, " L"]
    mu: Float[Array, " L"]
    alpha: Float[Array, " L"]
    regularisation: Float[Array, " L"]
    factorisations: Int[Array, " L"]
    trials: Int[Array, " L"]

    @classmethod
    def empty(cls, size: int) -> IPLog:
        nan = jnp.full((size,), jnp.nan)
        zero = jnp.zeros((size,), int)
        return cls(objective=nan, inf_pr=nan, inf_du=nan, mu=nan, alpha=nan, regularisation=nan,
                   factorisations=zero, trials=zero)

    def record(self, i, **values) -> IPLog:
        """The log with entry ``i`` of each named history set."""
        return eqx.tree_at(lambda log: [getattr(log, k) for k in values], self,
                           [getattr(self, k).at[i].set(v) for k, v in values.items()])


class IPSolution(eqx.Module):
    """Result of `interior_point`: knots ``xs`` (M+1, nx), controls ``us`` (M, nu),
    multipliers (``lam`` of the defects, ``nu`` of the equalities, ``z`` of the
    inequalities), ``result`` (`vehsim.RESULTS`: ``successful``, ``ip_max_iterations``,
    ``ip_locally_infeasible``, ``ip_line_search_failed``, ``ip_newton_system_failed`` or
    ``nonfinite``),
    ``iterations``, the final ``objective`` and residuals (``inf_pr``: max constraint
    violation, ``inf_du``: max Lagrangian-gradient entry, ``compl``: max
    complementarity), the iteration ``log`` (`IPLog`) and the slacks ``s`` of the
    inequalities (shaped as ``z``)."""

    xs: Float[Array, "M+1 nx"]
    us: Float[Array, "M nu"]
    lam: Float[Array, "M+1 nx"]
    nu: Array
    z: Array
    result: RESULTS = eqx.field(converter=as_result)
    iterations: Int[Array, ""]
    objective: Float[Array, ""]
    inf_pr: Float[Array, ""]
    inf_du: Float[Array, ""]
    compl: Float[Array, ""]
    log: IPLog
    s: Array | None = None

    @property
    def converged(self):
        """Whether the solve converged (a boolean array for a batch)."""
        return self.result == RESULTS.successful

    @property
    def message(self) -> str | list:
        """The first line of the result's message (nested lists for a batch)."""
        return result_message(self.result)


class _Best(eqx.Module):
    """The iterate of the smallest scaled KKT error a solve has reached
    (``IPOptions.best_iterate``), with its ``residuals`` and ``objective``."""

    iterate: Iterate
    residuals: Residuals
    objective: Float[Array, ""]

    def update(self, it: Iterate, res: Residuals, objective) -> _Best:
        """This record, or ``it`` where its error is smaller (and finite)."""
        better = jnp.isfinite(objective) & (res.error < self.residuals.error)
        return jax.tree.map(lambda new, old: jnp.where(better, new, old),
                            _Best(iterate=it, residuals=res, objective=objective), self)


class IPState(eqx.Module):
    """The loop state: the ``iterate``, the stage Lagrangian ``hessian`` of the last pass
    that took it (kept by ``hessian_update='first'``), barrier ``mu``, the last nonzero
    regularisation ``delta_last`` and that of the last step, ``delta_step`` (0 where none
    was needed), the line-search ``filter``, the ``iteration`` count, ``done``, the
    ``result`` so far, whether the defect and equality multipliers are ``multipliers_ready``
    (false after runaway multipliers: the next pass re-estimates them), and the
    ``objective`` and ``residuals`` at the iterate (from the last pass), with the ``log``;
    ``failed_searches``: the passes in a row, up to the last, whose line search accepted no
    trial; ``best`` (with ``best_iterate``, else None): the iterate of the smallest scaled
    KKT error so far, its residuals and objective (`_Best`); ``jacobians`` (with
    ``jacobian_update='first'``, else None): the stage derivatives of the last pass, whose
    Jacobians the kept passes reuse."""

    iterate: Iterate
    hessian: Float[Array, "M+1 ny ny"]
    mu: Float[Array, ""]
    delta_last: Float[Array, ""]
    delta_step: Float[Array, ""]
    filter: Filter
    iteration: Int[Array, ""]
    done: Array
    result: RESULTS
    multipliers_ready: Array
    objective: Float[Array, ""]
    residuals: Residuals
    log: IPLog
    failed_searches: Int[Array, ""]
    best: _Best | None = None
    jacobians: StageDerivatives | None = None


def interior_point(
    prob: AbstractStagewiseNLP,
    xs0: Float[Array, "M+1 nx"],
    us0: Float[Array, "M nu"],
    options: IPOptions | None = None,
    *,
    throw: bool = True,
    multipliers: tuple[Array, Array, Array] | None = None,
    implicit: bool = False,
) -> IPSolution:
    """Solve ``prob`` from the guess (``xs0``, ``us0``) by the structured interior-point method.

    **Arguments:** ``prob`` (an `AbstractStagewiseNLP`), the initial knots (M+1, nx) and
    controls (M, nu), ``options`` (`IPOptions`; default ``IPOptions()``), ``throw``: raise
    unless the solve converged (``False`` for batches: check ``result``), ``multipliers``:
    a warm start of the multipliers ``(lam, nu, z)``, shaped as `IPSolution`'s (e.g. a
    previous solution's, shifted), used as they are instead of the least-squares estimate
    (`_initial_state`; default None: the cold start of the module docstring),
    ``implicit``: differentiate the solution in ``prob``'s arrays by the implicit function
    theorem at the iterate returned (`implicit_solve`; forward and reverse mode, none in the
    guess) instead of through the iterations (forward mode only, and the derivative of the
    iterations, not of the solution: reverse mode raises `REVERSE_MODE_MESSAGE`).

    **Returns:** an `IPSolution`.
    """
    if implicit:
        return implicit_solve(prob, (xs0, us0, options, multipliers),
                              solve=functools.partial(_solve_guess, throw=throw))
    return forward_mode_only(
        solver_of(_solve)(prob, xs0, us0, options, throw=throw, multipliers=multipliers),
        REVERSE_MODE_MESSAGE)


REVERSE_MODE_MESSAGE = (
    "reverse-mode differentiation (jax.grad, jax.vjp, jax.jacrev) of interior_point through "
    "its iterations (a while loop, forward mode only): pass implicit=True (the solution's "
    "derivative by the implicit function theorem, in both modes), or differentiate in "
    "forward mode (jax.jvp, jax.jacfwd)")
"""The error of a reverse-mode derivative of `interior_point` with ``implicit=False``."""


def _solve_guess(prob, xs0, us0, options, multipliers, *, throw):
    return solver_of(_solve)(prob, xs0, us0, options, throw=throw, multipliers=multipliers)


def compile_interior_point(
    prob: AbstractStagewiseNLP,
    xs0: Float[Array, "M+1 nx"],
    us0: Float[Array, "M nu"],
    options: IPOptions | None = None,
):
    """`interior_point` compiled ahead of time (``jax.jit(...).lower(...).compile()``) for
    problems, guesses and options shaped as these (their values do not matter).

    **Returns:** ``solve(prob, xs0, us0, options, *, throw=True)``, the same program as
    `interior_point`; it refuses arguments of another structure. XLA releases Python's lock
    while it compiles, so a caller may compile on a thread while it builds the starting
    guess.
    """
    options = IPOptions() if options is None else options
    return solver_of(_solve.lower(*solve_arguments(prob, xs0, us0, options)).compile(),
                     options)


def solver_of(program: Callable, default_options: IPOptions | None = None):
    """``solve(prob, xs0, us0, options=default_options, *, throw=True)`` around ``program``,
    a function with `_solve`'s arguments and result (`_solve` itself, its compiled form, or
    an equivalent loaded program): the arguments made canonical (`solve_arguments`), the
    iteration log printed if ``options.verbose``, and the error raised if ``throw``."""

    def solve(prob, xs0, us0, options=default_options, *, throw=True,
              multipliers=None) -> IPSolution:
        options = IPOptions() if options is None else options
        args = solve_arguments(prob, xs0, us0, options)
        if multipliers is None:
            sol = program(*args)
        else:
            sol = program(*args, tuple(_floats(m) for m in multipliers))
        _report(sol, options)
        return _raise_if_failed(sol) if throw else sol

    return solve


def solve_arguments(prob, xs0, us0, options: IPOptions) -> tuple:
    """The arguments of the compiled program `_solve`: the problem, the guess as arrays of
    the default float dtype and `canonical_options`."""
    return prob, _floats(xs0), _floats(us0), canonical_options(options)


def canonical_options(options: IPOptions) -> IPOptions:
    """The options as the compiled program takes them: arrays in the current default dtypes
    (an `IPOptions` built before float64 was switched on, a default argument at import, then
    compiles the same program as one built after) and ``verbose`` off (the log is printed
    on the host when the solve returns)."""
    return dataclasses.replace(options, max_iter=jnp.asarray(options.max_iter, dtype=int),
                               fresh_hessian_steps=jnp.asarray(options.fresh_hessian_steps,
                                                               dtype=int),
                               mu0=jnp.asarray(options.mu0, dtype=float),
                               reestimate_multipliers=jnp.asarray(
                                   options.reestimate_multipliers, dtype=bool), verbose=False)


def _floats(x) -> Array:
    """``x`` as an array of the default float dtype, without running a program where none
    is needed (``jnp.asarray`` compiles one to copy even a NumPy array): a JAX array of
    that dtype as it is, host data by `jax.device_put`."""
    dtype = jnp.result_type(float)
    if isinstance(x, jax.core.Tracer) or (isinstance(x, jax.Array) and x.dtype != dtype):
        return jnp.asarray(x, dtype)
    return x if isinstance(x, jax.Array) else jax.device_put(np.asarray(x, dtype))


@functools.cache
def solution_tree():
    """The tree structure of every `IPSolution` (its leaves are arrays whatever the sizes):
    the output structure of `_solve` for a caller that flattens it."""
    a = np.zeros(1)
    log = IPLog(objective=a, inf_pr=a, inf_du=a, mu=a, alpha=a, regularisation=a,
                factorisations=a, trials=a)
    return jax.tree.structure(IPSolution(
        xs=a, us=a, lam=a, nu=a, z=a, result=RESULTS.successful, iterations=a, objective=a,
        inf_pr=a, inf_du=a, compl=a, log=log, s=a))


def print_iteration_log(sol: IPSolution, file=None) -> None:
    """One line per iteration of a finished solve, from its log: objective, ``inf_pr``,
    ``inf_du``, barrier ``mu``, step ``alpha``, regularisation ``reg`` and line-search
    trials ``ls`` (the last line is the iterate returned, unless ``best_iterate`` returned an
    earlier one: the line whose residuals are the solution's). ``file``: default stderr."""
    log = jax.tree.map(np.asarray, sol.log)
    n = min(int(sol.iterations) + 1, log.mu.shape[0])
    for i in range(n):
        if np.isnan(log.mu[i]):
            break
        _print_row(i, log.objective[i], log.inf_pr[i], log.inf_du[i], log.mu[i], log.alpha[i],
                   log.regularisation[i], log.trials[i], file=file)


def _print_row(i, objective, inf_pr, inf_du, mu, alpha, regularisation, trials, file=None):
    """One line of the iteration log (`print_iteration_log`, and ``IPOptions.live``)."""
    print(f"  ip {int(i):4d}  obj {float(objective): .8e}  inf_pr {float(inf_pr):.2e}  "
          f"inf_du {float(inf_du):.2e}  mu {float(mu):.1e}  alpha {float(alpha):.2e}  "
          f"reg {float(regularisation):.1e}  ls {int(trials)}",
          file=sys.stderr if file is None else file, flush=True)


def _report(sol: IPSolution, options: IPOptions) -> None:
    """`print_iteration_log` if ``options.verbose``: at once for a concrete solution, through
    a host callback when traced (inside the caller's `jit` or `vmap`)."""
    if not options.verbose:
        return
    if is_concrete(sol.iterations):
        print_iteration_log(sol)
    else:
        jax.debug.callback(print_iteration_log, sol)


def _raise_if_failed(sol: IPSolution) -> IPSolution:
    """Raise with the residuals (concrete result), or thread a runtime error (traced)."""
    failed = sol.result != RESULTS.successful
    if not is_concrete(failed):
        return eqx.tree_at(lambda s: s.xs, sol, sol.result.error_if(sol.xs, failed))
    if bool(failed):
        raise RuntimeError(
            f"interior point did not converge: {sol.message} after "
            f"{int(sol.iterations)} iterations; residuals inf_pr={float(sol.inf_pr):.3e}, "
            f"inf_du={float(sol.inf_du):.3e}, compl={float(sol.compl):.3e} "
            "(use throw=False to get the partial solution)"
        )
    return sol


@eqx.filter_jit
def _solve(prob: AbstractStagewiseNLP, xs0, us0, options: IPOptions,
           multipliers=None) -> IPSolution:
    lay = stage_layout(prob)
    state = _initial_state(prob, lay, xs0, us0, options, multipliers)
    # every pass but the last takes a step (or re-estimates the multipliers); the last only
    # evaluates the residuals at the iterate returned, which needs no Hessian
    stepping = lambda st: (~st.done) & ((st.iteration < options.max_iter - 1)
                                        | ~st.multipliers_ready)
    if options.hessian_update == "first":
        # the passes until `fresh_hessian_steps` steps are taken take the Hessian, the
        # later ones keep it
        state = jax.lax.while_loop(lambda st: stepping(st)
                                   & (st.iteration < options.fresh_hessian_steps),
                                   lambda st: _iteration(prob, lay, options, st), state)
    state = jax.lax.while_loop(
        stepping,
        lambda st: _iteration(prob, lay, options, st,
                              frozen=options.hessian_update == "first"),
        state,
    )
    state = jax.lax.cond(state.done, lambda st: st,
                         lambda st: _final_evaluation(prob, lay, options, st), state)
    it, res, objective = state.iterate, state.residuals, state.objective
    if state.best is not None:  # a solve that did not converge: its best iterate
        keep = state.result == RESULTS.successful
        it, res, objective = jax.tree.map(
            lambda last, best: jnp.where(keep, last, best), (it, res, objective),
            (state.best.iterate, state.best.residuals, state.best.objective))
    return IPSolution(
        xs=it.ys[:, : lay.nx], us=it.ys[:-1, lay.nx :], lam=it.lam, nu=it.nu, z=it.z,
        result=state.result, iterations=state.iteration, objective=objective,
        inf_pr=res.inf_pr, inf_du=res.inf_du, compl=res.compl, log=state.log, s=it.s,
    )


def _initial_state(prob, lay: StageLayout, xs0, us0, options: IPOptions,
                   multipliers=None) -> IPState:
    """Slacks $s = \\max(g, \\min(10^{-2}, 10\\mu_0))$ on the inequalities in use, $z = 1$
    or $\\mu_0 / s$ (``bound_multiplier_init``), and the defect and equality multipliers of
    ``multiplier_init``: zero, or their least-squares estimate at that $z$
    (`_least_squares_multipliers`).

    With ``multipliers`` $(\\lambda, \\nu, \\bar z)$ (a warm start): those $\\lambda$,
    $\\nu$ (no least-squares pass), $s = \\max(g, \\min(10^{-2}, \\mu_0/\\bar z))$ and
    $z = \\max(\\bar z, \\mu_0/s)$, so $s z \\ge \\mu_0$: an active inequality keeps a
    small slack and its multiplier, an inactive one its slack $g$ and $z \\approx \\mu_0/g$;
    the cold start where $\\bar z$ is not positive on every inequality (e.g. zeros: no warm
    start for this problem of a batch) or a multiplier is not finite."""
    mk = lay.masks()
    mg = mk.g
    ys = lay.join(xs0, us0)
    _, c0, e0, g0 = stage_values(prob, lay, ys)
    mu0 = options.mu0
    s = jnp.where(mg > 0, jnp.maximum(g0, jnp.minimum(INITIAL_SLACK, 10.0 * mu0)), 1.0)
    z = jnp.where(mg > 0, 1.0 if options.bound_multiplier_init == "constant" else mu0 / s, 0.0)
    lam, nu = jnp.zeros((lay.M + 1, lay.nx)), jnp.zeros((lay.M + 1, lay.ne))
    warm = jnp.asarray(False)
    if multipliers is not None:
        lam_w, nu_w, z_w = multipliers
        warm = (jnp.all((z_w > 0) | (mg == 0)) & jnp.all(jnp.isfinite(z_w))
                & jnp.all(jnp.isfinite(lam_w)) & jnp.all(jnp.isfinite(nu_w)))
        z_w = jnp.where(mg > 0, jnp.maximum(z_w, 1e-300), 1.0)
        s_w = jnp.where(mg > 0, jnp.maximum(g0, jnp.minimum(INITIAL_SLACK, mu0 / z_w)), 1.0)
        z_w = jnp.where(mg > 0, jnp.maximum(z_w, mu0 / s_w), 0.0)
    if options.multiplier_init == "least-squares":
        cold = Iterate(ys=ys, s=s, z=z, lam=lam, nu=nu)
        least_squares = lambda: _least_squares_multipliers(prob, lay, cold, mu0)
        lam, nu = (least_squares() if multipliers is None
                   else jax.lax.cond(warm, lambda: (lam, nu), least_squares))
    if multipliers is not None:
        s, z, lam, nu = (jnp.where(warm, w, c) for w, c in (
            (s_w, s), (z_w, z), (lam_w * mk.lam, lam), (nu_w * mk.eq, nu)))
    iterate = Iterate(ys=ys, s=s, z=z, lam=lam, nu=nu)
    inf = jnp.asarray(jnp.inf)
    state = IPState(
        iterate=iterate, hessian=jnp.zeros((lay.M + 1, lay.ny, lay.ny)), mu=jnp.asarray(mu0),
        delta_last=jnp.asarray(0.0), delta_step=jnp.asarray(0.0),
        filter=Filter.initial(constraint_violation(c0, e0, g0, s, mg)),
        iteration=jnp.asarray(0), done=jnp.asarray(False), result=RESULTS.ip_max_iterations,
        multipliers_ready=jnp.asarray(True),
        objective=jnp.asarray(jnp.nan),
        residuals=Residuals(inf_pr=inf, inf_du=inf, compl=inf, error=inf,
                            optimality=inf, s_c=jnp.asarray(1.0)),
        log=IPLog.empty(options.log_size), failed_searches=jnp.asarray(0),
    )
    if options.best_iterate:
        state = eqx.tree_at(lambda st: st.best, state,
                            _Best(iterate, state.residuals, state.objective),
                            is_leaf=lambda x: x is None)
    if options.jacobian_update == "first":
        zeros = lambda *shape: jnp.zeros((lay.M + 1,) + shape)
        state = eqx.tree_at(lambda st: st.jacobians, state, StageDerivatives(
            objective=jnp.asarray(0.0), c=zeros(lay.nx), e=zeros(lay.ne), g=zeros(lay.ng),
            grad_f=zeros(lay.ny), A=zeros(lay.nx, lay.ny), Je=zeros(lay.ne, lay.ny),
            Jg=zeros(lay.ng, lay.ny), H=zeros(lay.ny, lay.ny)), is_leaf=lambda x: x is None)
    return strong(state)


def _least_squares_multipliers(prob, lay: StageLayout, it: Iterate, mu):
    """IPOPT's least-squares estimate of $(\\lambda, \\nu)$ at ``it`` (`newton_step` with
    ``least_squares``: the KKT system with $W = I$, so values and Jacobians only), capped."""
    d = stage_jacobians(prob, lay, it.ys)
    step = newton_step(lay, it, d, mu, jnp.asarray(0.0), least_squares=True)
    return capped_multipliers(step.dlam, step.dnu)


def _adjoint_derivatives(prob, lay: StageLayout, it: Iterate, kept: StageDerivatives,
                         H) -> StageDerivatives:
    """The stage derivatives of a kept-Jacobian pass (``jacobian_update='first'``):
    the values and the Lagrangian gradient at ``it`` (one reverse pass per stage), the
    Jacobians ``kept``, the Hessian ``H``, and the cost gradient that makes the Lagrangian
    gradient assembled from the kept Jacobians the exact one (whatever they are). The line
    search's directional derivative takes that gradient too: the cost gradient plus the
    multipliers times the Jacobians' change since they were kept."""
    mk = lay.masks()
    objective, c, e, g, grad_l = stage_values_and_lagrangian_gradient(
        prob, lay, it.ys, it.lam, it.nu, it.z)
    grad_f = (grad_l - jnp.einsum("kij,ki->kj", kept.Je, it.nu * mk.eq)
              + jnp.einsum("kij,ki->kj", kept.A, it.lam * mk.lam)
              + jnp.einsum("kij,ki->kj", kept.Jg, it.z * mk.g))
    return eqx.tree_at(lambda d: (d.objective, d.c, d.e, d.g, d.grad_f, d.H), kept,
                       (objective, c, e, g, grad_f, H))


def _iteration(prob, lay: StageLayout, options: IPOptions, st: IPState,
               frozen: bool = False) -> IPState:
    """One pass: test convergence at the iterate, update the barrier, step. A pass after
    runaway multipliers (not ``multipliers_ready``) only re-estimates them by least squares
    (the same derivatives and KKT factorisation, no step, not counted). ``frozen``: the
    Hessian of the state, only the values and Jacobians evaluated; with
    ``jacobian_update='first'`` the Jacobians of the state too: the values and the
    Lagrangian gradient $\\nabla_y \\mathcal{L}$ are evaluated
    (`stage_values_and_lagrangian_gradient`), and the kept cost gradient replaced by
    $\\nabla_y \\mathcal{L} - J_e^T\\nu + A^T\\lambda + J_g^T z$ with the kept Jacobians
    (`_adjoint_derivatives`), so that the residuals, and the right-hand side on the central
    path, are exact: the limit is a KKT point. (With the values alone, a zero-order step,
    the limit is feasible but stationary only for the kept Jacobians.)"""
    it = st.iterate
    setup = ~st.multipliers_ready
    if frozen and options.jacobian_update == "first":
        d = _adjoint_derivatives(prob, lay, it, st.jacobians, st.hessian)
    elif frozen:
        d = eqx.tree_at(lambda d: d.H, stage_jacobians(prob, lay, it.ys), st.hessian)
    else:
        d = stage_derivatives(prob, lay, it.ys, it.lam, it.nu, it.z, options.hessian)
    res = kkt_residuals(lay, it, d)
    converged = _converged(res, options) & ~setup
    mu, mu_changed = _barrier_update(lambda m: barrier_error(lay, it, res, m), st.mu,
                                     options.tol)
    mu, mu_changed = jnp.where(setup, st.mu, mu), mu_changed & ~setup
    # a kept Hessian whose last step needed a regularisation almost surely needs one again
    # (only the barrier's curvature changed): the correction starts from it, not from 0
    try_zero = ~(frozen & (st.delta_step > 0) & (st.delta_last > 0))
    step = newton_step(lay, it, d, mu, st.delta_last, least_squares=setup, try_zero=try_zero,
                       singular=options.backward_error_singular,
                       refinement_steps=options.max_refinement_steps)
    tau = jnp.maximum(TAU_MIN, 1.0 - mu)
    mg = lay.masks().g
    alpha_max = fraction_to_boundary(it.s, step.ds, mg, tau)
    alpha_dual = fraction_to_boundary(jnp.where(mg > 0, it.z, 1.0), step.dz, mg, tau)
    alpha, n_trials, accepted, filt, direction = filter_line_search(
        prob, lay, it, step, (d.objective, d.c, d.e, d.g), d.grad_f, mu,
        st.filter.cleared_where(mu_changed), alpha_max,
        lambda c, e, gs: second_order_correction(lay, it, d, mu, step, c, e, gs), tau
    )
    dy, ds, dlam, dnu = direction
    taken = eqx.tree_at(lambda n: (n.dy, n.ds, n.dlam, n.dnu), step, (dy, ds, dlam, dnu))
    trial = _take_step(lay, it, taken, alpha, alpha_dual, mu)
    lam0, nu0 = capped_multipliers(step.dlam, step.dnu)
    trial = jax.tree.map(lambda a, b: jnp.where(setup, a, b),
                         eqx.tree_at(lambda i: (i.lam, i.nu), it, (lam0, nu0)), trial)
    log = st.log.record(st.iteration, objective=d.objective, inf_pr=res.inf_pr,
                        inf_du=res.inf_du, mu=mu, alpha=alpha, regularisation=step.delta,
                        factorisations=step.factorisations, trials=n_trials)
    if options.live:  # the line of this pass, on the host as it happens (not a setup pass)
        jax.lax.cond(setup, lambda: None, lambda: jax.debug.callback(
            _print_row, st.iteration, d.objective, res.inf_pr, res.inf_du, mu, alpha,
            step.delta, n_trials))
    finite = jnp.all(jnp.isfinite(trial.ys)) & jnp.all(jnp.isfinite(trial.lam))
    # runaway multipliers: the line search failed, or the inertia correction needed a
    # regularisation that leaves no Newton step; estimate (lambda, nu) afresh next pass
    failed = ~setup & ~accepted
    reset = (failed | (~setup & (step.delta > DELTA_RESET))) & options.reestimate_multipliers
    # without a re-estimate, a failure after a failure (the filter already forgotten) stalls:
    # the next pass would start from the same point and take the same step
    failed_searches = jnp.where(setup, st.failed_searches,
                                jnp.where(failed, st.failed_searches + 1, 0))
    stalled = ((failed_searches >= STALLED_PASSES) & ~options.reestimate_multipliers
               & ~converged)
    # no Newton direction at all (every regularisation refused): the next pass would fail again
    unsolved = ~step.solved & ~converged
    # keep the iterate whose residuals are reported when the loop ends on this pass
    hold = converged | ~finite | stalled | unsolved
    return IPState(
        iterate=jax.tree.map(lambda new, old: jnp.where(hold, old, new), trial, it),
        hessian=d.H, mu=mu,
        delta_last=jnp.where(reset, 0.0, jnp.where((step.delta > 0) & ~setup, step.delta,
                                                   st.delta_last)),
        delta_step=jnp.where(setup, st.delta_step, step.delta),
        filter=jax.tree.map(lambda a, b: jnp.where(setup, a, b), st.filter, filt),
        iteration=st.iteration + jnp.where(converged | setup, 0, 1),
        done=converged | ~finite | stalled | unsolved,
        result=RESULTS.where(
            unsolved & finite, RESULTS.ip_newton_system_failed,
            RESULTS.where(stalled & finite, RESULTS.ip_line_search_failed,
                          _outcome(converged, finite))),
        multipliers_ready=~reset | (options.multiplier_init == "zero"), objective=d.objective,
        residuals=res, log=log, failed_searches=failed_searches,
        best=None if st.best is None else st.best.update(it, res, d.objective),
        jacobians=None if st.jacobians is None else d,
    )


def _converged(res, options: IPOptions):
    """The convergence test: scaled KKT error within ``tol``, violation within ``constr_tol``."""
    return (res.error <= options.tol) & (res.inf_pr <= options.constr_tol)


def _outcome(converged, finite, infeasible=False) -> RESULTS:
    """The result of a pass: converged, not finite, or (at the iteration limit) stuck at a
    violation it does not reduce (``infeasible``) or not."""
    stopped = RESULTS.where(infeasible, RESULTS.ip_locally_infeasible, RESULTS.ip_max_iterations)
    return RESULTS.where(converged, RESULTS.successful,
                         RESULTS.where(finite, stopped, RESULTS.nonfinite))


def passes_without_progress(inf_pr: Float[Array, " L"], last) -> Int[Array, ""]:
    """The passes, up to entry ``last`` of the logged violations ``inf_pr``, since the last
    that made progress: a violation below the anchor (the violation of the last pass that
    made progress; at first infinite) by more than the fraction `VIOLATION_PROGRESS` of it.
    Read from the log after the loop, so that the loop's program is untouched; a pass that
    only re-estimates the multipliers is not logged. 0 where the log is shorter than
    ``last`` (nothing to judge by)."""

    def step(carry, entry):
        anchor, count = carry
        i, violation = entry
        progress = violation < (1.0 - VIOLATION_PROGRESS) * anchor
        logged = i <= last
        return (jnp.where(logged & progress, violation, anchor),
                jnp.where(logged, jnp.where(progress, 0, count + 1), count)), None

    size = inf_pr.shape[0]
    (_, count), _ = jax.lax.scan(step, (jnp.asarray(jnp.inf, inf_pr.dtype), jnp.asarray(0)),
                                 (jnp.arange(size), inf_pr))
    return jnp.where(last < size, count, 0)


def _final_evaluation(prob, lay: StageLayout, options: IPOptions, st: IPState) -> IPState:
    """The last pass of a solve that reached ``max_iter``: the residuals and the convergence
    test at the iterate returned, from values and Jacobians only (no step is taken, so no
    Hessian is needed; with ``jacobian_update='first'`` from the values and the Lagrangian
    gradient, `_adjoint_derivatives`); logged as a pass with no step (``alpha`` 0)."""
    it = st.iterate
    if options.jacobian_update == "first":  # exact from the adjoint, no Jacobian
        d = _adjoint_derivatives(prob, lay, it, st.jacobians, st.hessian)
    else:
        d = stage_jacobians(prob, lay, it.ys)
    res = kkt_residuals(lay, it, d)
    converged = _converged(res, options)
    zero = jnp.asarray(0.0)
    log = st.log.record(st.iteration, objective=d.objective, inf_pr=res.inf_pr,
                        inf_du=res.inf_du, mu=st.mu, alpha=zero, regularisation=zero,
                        factorisations=jnp.asarray(0), trials=jnp.asarray(0))
    if options.live:
        jax.debug.callback(_print_row, st.iteration, d.objective, res.inf_pr, res.inf_du,
                           st.mu, zero, zero, 0)
    finite = jnp.isfinite(res.error) & jnp.isfinite(d.objective)
    infeasible = ((passes_without_progress(log.inf_pr, st.iteration) >= INFEASIBLE_PASSES)
                  & (res.inf_pr > options.constr_tol)
                  & (jnp.nanmin(log.inf_pr) > VIOLATION_REACHED * log.inf_pr[0]))
    st = eqx.tree_at(
        lambda s: (s.iteration, s.done, s.result, s.objective, s.residuals, s.log), st,
        (st.iteration + jnp.where(converged, 0, 1), jnp.asarray(True),
         _outcome(converged, finite, infeasible),
         d.objective, res, log))
    if st.best is None:
        return st
    return eqx.tree_at(lambda s: s.best, st, st.best.update(it, res, d.objective))


def _barrier_update(error_mu, mu, tol):
    r"""Monotone Fiacco-McCormick rule, decreasing $\mu$ again while the barrier error at the
    same iterate stays below $10\mu$ (IPOPT's fast monotone decrease; ``error_mu``: $\mu
    \mapsto E_\mu$); also says whether $\mu$ changed."""

    def smaller(m):
        return (error_mu(m) <= MU_TEST * m) & (m > tol / 10.0)

    def body(m):
        return jnp.maximum(tol / 10.0, jnp.minimum(MU_DECREASE * m, m**MU_POWER))

    new = jax.lax.while_loop(smaller, body, mu)
    return new, new != mu


def _take_step(lay: StageLayout, it: Iterate, step: NewtonStep, alpha, alpha_dual, mu) -> Iterate:
    """Primal step ``alpha``, dual step ``alpha_dual`` for $z$ (then kept within a factor
    `KAPPA_SIGMA` of $\\mu S^{-1}$), ``alpha`` for $\\lambda$ and $\\nu$."""
    mg = lay.masks().g
    s = jnp.where(mg > 0, jnp.maximum(it.s + alpha * step.ds, 1e-300), 1.0)
    z = jnp.where(mg > 0, it.z + alpha_dual * step.dz, 0.0)
    z = jnp.where(mg > 0, jnp.clip(z, mu / (KAPPA_SIGMA * s), KAPPA_SIGMA * mu / s), 0.0)
    return Iterate(ys=it.ys + alpha * step.dy, s=s, z=z, lam=it.lam + alpha * step.dlam,
                   nu=it.nu + alpha * step.dnu)
