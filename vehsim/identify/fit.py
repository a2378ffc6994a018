r"""Fit the lumped LuGre model (eqs. 22-25) to brakings, through the simulator.

$\min_u \tfrac12\sum_k r_k(u)^2 + \tfrac12\|w(u - u_0)\|^2$: $r$ the scaled residuals of a
braking model (`OpenLoopBraking` for `fit_open_loop`, `ClosedLoopBraking` for
`fit_closed_loop`), $u$ the unconstrained coordinates of `parameters`, $w$ a weak prior. A
batch of starts is solved by Levenberg-Marquardt in one compiled call
(`levenberg_marquardt`), the best kept, and its optimum judged by `diagnostics`. A fit runs
in four steps: prepare (check the arguments), solve, diagnose, assemble the `FitResult`.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._checks import check_count, check_integer, check_nonnegative, check_range
from .._results import RESULTS, is_successful, result_message, result_name, result_record
from ..progress import progress_bar, resolve
from ..tire.lugre import LumpedLuGre
from .base import AbstractBrakingModel, peak_scales
from .braking import BrakingData
from .closed_loop import ClosedLoopBraking
from .diagnostics import FTOL, GTOL, Diagnostics, diagnose, force_errors, outcome
from .levenberg_marquardt import solve_batch
from .open_loop import OpenLoopBraking
from .parameters import (
    DEFAULT_FREE,
    PARAMETER_NAMES,
    UNITS,
    default_initial_guess,
    from_unconstrained,
    keeps_mu_s,
    parameter_values,
    to_unconstrained,
    values_batch,
    with_values,
)
from .sensitivities import FORCE_ONLY


class FitError(RuntimeError):
    """A fit did not converge (raised with `throw=True`); the message gives the residual and
    `.result` holds the `FitResult` (its `.result`, parameters reached, residuals)."""

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


@dataclasses.dataclass(frozen=True)
class FitResult:
    """Outcome of `fit_open_loop` / `fit_closed_loop`.

    `model` holds the best parameters; `values` every quantity by name; `std_errors` those
    of the free ones (Gauss-Newton); `result` is a `vehsim.RESULTS` item (`successful`,
    `not_identifiable`, `nonfinite`, or the solver's own failure, e.g.
    `nonlinear_max_steps_reached`), judged by the `condition_number` of the Jacobian and
    MINPACK's `gradient_cosine` and `predicted_reduction` (`vehsim.identify.diagnostics`);
    `message` says why in words, with the residual; `at_bound` names parameters the data
    drive to 0 (within 2 standard errors); `errors` the force errors per training braking;
    `starts` every start's loss and Levenberg-Marquardt's own outcome
    (``solver_status``), `solver_status` the best start's: a fit is `successful` where the
    solver converged or, having stopped short, MINPACK's tests find its optimum stationary,
    and `message` says which.
    """

    model: LumpedLuGre
    mode: str
    free: tuple[str, ...]
    values: dict[str, float]
    std_errors: dict[str, float]
    loss: float
    rms_force_residual_N: float
    result: RESULTS
    num_steps: int
    condition_number: float
    gradient_cosine: float
    predicted_reduction: float
    errors: dict[str, dict[str, float]]
    starts: dict[str, Any]
    wall_time_s: float
    at_bound: tuple[str, ...] = ()
    solver_status: str = "successful"

    @property
    def converged(self) -> bool:
        """Whether `result` is `RESULTS.successful`."""
        return bool(is_successful(self.result))

    @property
    def message(self) -> str:
        """Why `result`, in words: the numbers it was judged by, then the loss and the RMS
        force residual."""
        return (f"{self._reason()}; loss {self.loss:.6g}, RMS force residual "
                f"{self.rms_force_residual_N:.4g} N")

    def _reason(self) -> str:
        cosine, reduction = self.gradient_cosine, self.predicted_reduction
        if self.converged:
            bound = ", ".join(f"{n} = {self.values[n]:.3g} +/- {self.std_errors[n]:.2g}"
                              for n in self.at_bound)
            how = "converged" if self.solver_status == "successful" else (
                f"stationary by MINPACK's tests, although Levenberg-Marquardt stopped with "
                f"{self.solver_status} after {self.num_steps} steps")
            return (f"{how} (gradient cosine {cosine:.2g}, predicted relative loss "
                    f"reduction {reduction:.2g})") + (
                f"; at the lower bound 0 (within 2 standard errors): {bound}" if bound else "")
        if bool(self.result == RESULTS.nonfinite):
            return "the fit produced non-finite values"
        if bool(self.result == RESULTS.not_identifiable):
            if not all(math.isfinite(v) for v in self.std_errors.values()):
                measured = max(e["peak_force_measured_N"] for e in self.errors.values())
                return ("parameters not identifiable from these data: their standard errors "
                        "are not finite, the residuals barely depend on them (the largest "
                        f"measured |F_x| is {measured:.3g} N: check the force's units)")
            return (f"parameters not identifiable from these data (Jacobian condition number "
                    f"{self.condition_number:.3g}; is there slip excitation?)")
        return (f"Levenberg-Marquardt stopped after {self.num_steps} steps: "
                f"{result_message(self.result)} (gradient cosine {cosine:.2g} > {GTOL:g}, "
                f"predicted relative loss reduction {reduction:.2g} > {FTOL:g})")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary with the equations' parameter names; the outcome as
        `vehsim.result_record` (``status``, ``message``)."""
        return {
            "mode": self.mode,
            **result_record(self.result),
            "parameters": self.values,
            "free": list(self.free),
            "std_errors": self.std_errors,
            "at_lower_bound": list(self.at_bound),
            "units": {n: UNITS[n] for n in PARAMETER_NAMES},
            "L": float(self.model.params.L),
            "loss": self.loss,
            "rms_force_residual_N": self.rms_force_residual_N,
            "num_steps": self.num_steps,
            "condition_number": self.condition_number,
            "gradient_cosine": self.gradient_cosine,
            "predicted_reduction": self.predicted_reduction,
            "train_errors": self.errors,
            "multistart": self.starts,
            "wall_time_s": self.wall_time_s,
        }


def braking_model(mode: str | AbstractBrakingModel = "open_loop", substeps: int = 2,
                  rtol: float = 1e-6) -> AbstractBrakingModel:
    """`mode` as a braking model: ``"open_loop"`` is `OpenLoopBraking(substeps)`,
    ``"closed_loop"`` is `ClosedLoopBraking(rtol=rtol)`; a braking model is returned as is."""
    if isinstance(mode, AbstractBrakingModel):
        return mode
    if mode == "open_loop":
        return OpenLoopBraking(substeps)
    if mode == "closed_loop":
        return ClosedLoopBraking(rtol=rtol)
    raise ValueError(f"unknown mode {mode!r}; known: 'open_loop', 'closed_loop', or a "
                     "braking model (OpenLoopBraking, ClosedLoopBraking)")


def fit_loss(model: LumpedLuGre, data: Sequence[BrakingData],
             mode: str | AbstractBrakingModel = "open_loop", substeps: int = 2,
             rtol: float = 1e-6):
    r"""$\tfrac12\sum_k r_k^2$ with $r_k$ the force (and, closed loop, speed) errors scaled by
    the peak measured $|F_x|$ ($|v|$, $|\omega|$). `substeps` and `rtol` apply to a `mode`
    given by name (see `braking_model`).

    Differentiable in `model`: open loop in reverse mode (forward mode raises
    `vehsim._integrate.FORWARD_MODE_MESSAGE`; `predict_open_loop` with
    ``adjoint=diffrax.ForwardMode()`` serves it); closed loop (an adaptive solve with
    forward-mode sensitivities, as the fit uses) in forward mode only (`jax.jvp`,
    `jax.jacfwd`): reverse mode stops with JAX's error that a `while_loop` cannot be
    reverse-differentiated."""
    data = list(data)
    r = braking_model(mode, substeps, rtol).residuals(model, data, peak_scales(data))
    return 0.5 * jnp.sum(r**2)


def evaluate(model: LumpedLuGre, data: BrakingData,
             mode: str | AbstractBrakingModel = "open_loop") -> tuple[np.ndarray, dict]:
    """Predicted force on `data` and its `force_errors` (e.g. on a held-out braking);
    `mode` a braking model or its name (see `braking_model`)."""
    F = braking_model(mode).predict_force(model, _unnamed(data))
    return np.asarray(F), force_errors(F, data.F_x)


def fit_open_loop(data, init: LumpedLuGre | None = None, *, free=DEFAULT_FREE, fixed=None,
                  n_starts: int = 8, spread: float = 0.3, key: int = 0, tol: float = 1e-6,
                  max_steps: int = 100, substeps: int = 2, prior_weight: float = 1e-4,
                  throw: bool = True, verbose: bool = False,
                  progress: bool | None = None) -> FitResult:
    r"""Fit the lumped LuGre model (eqs. 22-25) to brakings, driven by measured $v$, $\omega$
    (`OpenLoopBraking`).

    **Arguments:**

    - `data`: a `BrakingData` or a sequence of them (fitted together).
    - `init`: starting `LumpedLuGre` (default `default_initial_guess()`); also supplies the
      fixed quantities (`L`, and `alpha`, `theta` unless freed).
    - `free`: names to fit (default sigma0, sigma1, mu_c, mu_s, v_s, kappa0; sigma2 stays
      at the initial guess unless freed, see `DEFAULT_FREE`; alpha, theta may be freed).
    - `fixed`: ``{name: value}`` held fixed (e.g. ``{"kappa0": 1.0}``, report Fig. 10): a
      finite number, positive, or 0 for `MAY_BE_HELD_AT_0` (checked before anything runs).
    - `n_starts`, `spread`, `key`: multi-start: the initial guess plus `n_starts - 1` starts
      at $\log\theta_0 + $ `spread` $\cdot N(0, 1)$, all solved in one vmapped call.
    - `tol`: Levenberg-Marquardt `rtol` = `atol`; `max_steps` its step limit.
    - `substeps`: integrator substeps per sample interval.
    - `prior_weight` $w$: a weak prior (ridge) $w(\log\theta - \log\theta_0)$ on the free
      parameters, appended to the residuals (scaled by the peak force): it keeps nearly flat
      directions from wandering. $w = 10^{-4}$ changes well-determined parameters by far
      less than their standard errors (and exact data are recovered to ~1e-5); 0 turns it off.
    - `throw`: raise `FitError` (with the residual) if the best start did not converge or
      the parameters are not identifiable; with `False` check `FitResult.result`.
    - `verbose`: the stages of the fit on stderr.
    - `progress`: the Levenberg-Marquardt steps and the best loss on stderr, step by step
      (`vehsim.progress`; default off, on in the command line).

    **Returns:** a `FitResult`.
    """
    return _fit(data, init, free, fixed, OpenLoopBraking(substeps), n_starts, spread, key, tol,
                max_steps, throw, verbose, prior_weight, progress)


def fit_closed_loop(data, init: LumpedLuGre | None = None, *, free=DEFAULT_FREE, fixed=None,
                    n_starts: int = 1, spread: float = 0.3, key: int = 0, tol: float = 1e-8,
                    max_steps: int = 100, rtol: float = 1e-6, solver=None,
                    prior_weight: float = 1e-4, throw: bool = True,
                    verbose: bool = False, progress: bool | None = None) -> FitResult:
    r"""Fit the quarter car (lumped tire) driven by the measured brake torque $T_b(t)$,
    predicting $v$, $\omega$, $F_x$ together (`ClosedLoopBraking`).

    Needs `T_b` and the side-file `m`, `J` in every braking. The solve is adaptive, with
    relative tolerance `rtol`, by `solver` (default `Kvaerno5`; see `predict_closed_loop`),
    with forward-mode sensitivities. Other arguments as in `fit_open_loop`.
    """
    return _fit(data, init, free, fixed, ClosedLoopBraking(solver, rtol), n_starts, spread,
                key, tol, max_steps, throw, verbose, prior_weight, progress)


# --------------------------------------------------------------------------------------
# The driver: prepare, solve, diagnose, assemble
# --------------------------------------------------------------------------------------


class _Problem(NamedTuple):
    data: list[BrakingData]  # as given (their names label the errors)
    anon: list[BrakingData]  # without names, strongly typed: shared compilations
    model: LumpedLuGre  # the initial guess with the fixed values
    names: tuple[str, ...]  # the free parameters, in the order of PARAMETER_NAMES
    mask: np.ndarray  # over PARAMETER_NAMES: free
    scales: tuple  # peak |F_x|, |v|, |omega|


def _fit(data, init, free, fixed, braking: AbstractBrakingModel, n_starts, spread, key, tol,
         max_steps, throw, verbose, prior_weight, progress=None) -> FitResult:
    t_start = time.perf_counter()
    _check_options(n_starts, spread, key, tol, max_steps, prior_weight)
    problem = _prepare(data, init, free, fixed)
    core = _solve(problem, braking, n_starts, spread, key, tol, max_steps, prior_weight,
                  verbose, t_start, resolve(progress))
    diag = _diagnose(problem, core, prior_weight)
    result = _assemble(problem, braking, core, diag, t_start)
    _log(verbose, f"{result_name(result.result)}: {result.message} "
         f"({result.wall_time_s:.1f}s)")
    if throw and not result.converged:
        raise FitError(f"fit did not converge: {result.message}", result)
    return result


def _check_options(n_starts, spread, key, tol, max_steps, prior_weight) -> None:
    """The fit's numeric options in their ranges, before anything is compiled."""
    check_integer("fit", "n_starts", n_starts, lower=1)
    check_count("fit", "key", key, lower=0)  # the starts' random seed
    check_nonnegative("fit", "spread", spread)
    check_range("fit", "tol", tol, lower=0.0, upper=1.0, lower_open=True, upper_open=True)
    check_integer("fit", "max_steps", max_steps, lower=1)
    check_nonnegative("fit", "prior_weight", prior_weight)


MAY_BE_HELD_AT_0 = ("sigma1", "sigma2", "kappa0")
"""The quantities a fit may hold at 0 (damping or the lumped term switched off); every other
one is held at a positive value."""


def _prepare(data, init, free, fixed) -> _Problem:
    """The arguments checked, the initial guess with the fixed values, the scales."""
    data = [data] if isinstance(data, BrakingData) else list(data)
    if not data:
        raise ValueError("fit needs at least one braking")
    model = default_initial_guess() if init is None else init
    fixed = dict(fixed or {})
    for n in list(fixed) + list(free):
        if n not in PARAMETER_NAMES:
            raise ValueError(f"unknown parameter {n!r}; known: {list(PARAMETER_NAMES)}")
    for n, v in fixed.items():  # before `with_values`, which skips the models' checks
        if isinstance(v, bool) or not isinstance(v, int | float | np.number | np.ndarray
                                                  | jax.Array):
            raise TypeError(f"fixed.{n} must be a number, got {type(v).__name__}")
        check_range("fixed", n, v, lower=0.0, lower_open=n not in MAY_BE_HELD_AT_0)
    if fixed:
        model = with_values(model, fixed)
    names = tuple(n for n in PARAMETER_NAMES if n in free and n not in fixed)
    if not names:
        raise ValueError("no free parameters")
    _check_start(model, names, fixed)
    # the scales from the concrete data in NumPy (no eager JAX dispatches)
    scales = tuple(np.asarray(s) for s in peak_scales(data, np))
    for column, scale in zip(("F_x", "v", "omega"), scales):
        if scale == 0:  # (NaN is left to the fit, which reports it as nonfinite)
            raise ValueError(f"the brakings' column {column!r} is 0 throughout: nothing to fit "
                             f"(the residuals are scaled by its peak |{column}|)")
    if all(np.max(np.abs(np.asarray(d.F_n))) == 0 for d in data):
        raise ValueError("the brakings' column 'F_n' is 0 throughout: the predicted force "
                         "mu F_n is 0 whatever the parameters, nothing to fit")
    return _Problem(data=data, anon=[_unnamed(d) for d in data],
                    model=jax.tree.map(_strong_float, model), names=names,
                    mask=np.asarray([n in names for n in PARAMETER_NAMES]), scales=scales)


def _check_start(model: LumpedLuGre, names, fixed) -> None:
    """The start must lie inside the fitted coordinates (`vehsim.identify.parameters`):
    every free quantity above 0 and, with either friction level free, mu_c < mu_s. A held
    value may be 0 (sigma2 or kappa0 switched off)."""
    values = {n: float(v) for n, v in parameter_values(model).items()}
    mu_c, mu_s = values["mu_c"], values["mu_s"]
    for n in names:
        if not values[n] > 0:
            raise ValueError(f"the initial {n} = {values[n]:g} must be > 0 to be fitted (the fit "
                             f"works in log {n}, which reaches 0 only at -inf); hold it fixed "
                             f"with fixed={{{n!r}: {values[n]:g}}}, or start above 0")
    if ("mu_c" in names or "mu_s" in names) and not mu_c < mu_s:
        held = [n for n in ("mu_c", "mu_s") if n in fixed]
        which = (f"fixed {held[0]}" if held else "initial mu_c and mu_s")
        raise ValueError(f"mu_c = {mu_c:g} must be below mu_s = {mu_s:g} ({which}): the fit "
                         "keeps mu_c < mu_s; give values with mu_c below mu_s")


def _solve(problem: _Problem, braking, n_starts, spread, key, tol, max_steps, prior_weight,
           verbose, t_start, progress=False) -> _FitCore:
    """Every start solved in one compiled call (`_fit_core`); the outputs but the model in
    NumPy."""
    _log(verbose, f"{braking.name}: {len(problem.names)} parameters {list(problem.names)}, "
         f"{n_starts} start(s), {sum(len(d) for d in problem.data)} samples in "
         f"{len(problem.data)} braking(s); solving (the first call compiles)...")
    # rows for the free directions that move the friction state (open loop): 5 keep the
    # state and its tangents in one solve
    slots = 5 if int(np.sum(problem.mask & ~FORCE_ONLY)) <= 5 else 7
    with progress_bar("fit", max_steps, "steps", enabled=progress,
                      value_name="loss", eta=False):
        core = _fit_core(problem.model, problem.anon, problem.mask,
                         np.asarray(float(prior_weight)), np.asarray(key),
                         np.asarray(float(spread)), n_starts, braking, problem.scales, tol,
                         max_steps, slots, progress)
        core = eqx.tree_at(lambda c: c.model, jax.tree.map(np.asarray, core), core.model)
    losses, finite = core.losses, np.isfinite(core.losses)
    n_converged = int(np.sum(is_successful(core.results)))
    _log(verbose, f"solved {n_starts} start(s) in {time.perf_counter() - t_start:.1f}s: "
         f"Levenberg-Marquardt converged in {n_converged}, stopped short in "
         f"{n_starts - n_converged} (each start's solver_status is in the result), best loss "
         f"{np.nanmin(np.where(finite, losses, np.nan)):.4g}; the best start is judged next"
         if finite.any() else "no start gave a finite loss")
    return core


class _FitCore(eqx.Module):
    """What `_fit_core` computes: every start (axis S) over the quantities of
    `PARAMETER_NAMES` (axis P), and the best start's data residuals (axis N)."""

    u_fixed: Float[Array, " P"]  # the initial guess with the fixed values, unconstrained
    initial: Float[Array, "S P"]  # the starts' values
    us: Float[Array, "S P"]  # the solutions, unconstrained
    values: Float[Array, "S P"]  # ... and their values
    losses: Float[Array, " S"]
    results: RESULTS  # Levenberg-Marquardt's outcome per start (batched)
    steps: Int[Array, " S"]
    best: Int[Array, ""]  # `best_start`
    model: LumpedLuGre  # the best start's
    theta: Float[Array, " P"]  # the best start's values
    r: Float[Array, " N"]  # the best start's data residuals (the prior's rows left out)
    J_u: Float[Array, "N P"]  # their Jacobian in u, the solver's last


def best_start(losses, results: RESULTS):
    """Index of the least finite loss among the starts whose solve succeeded, else among
    all the starts with a finite loss (0 where none has one)."""
    finite = jnp.isfinite(losses)
    succeeded = finite & is_successful(results)
    among = jnp.where(jnp.any(succeeded), succeeded, finite)
    return jnp.argmin(jnp.where(among, losses, jnp.inf))


@eqx.filter_jit
def _fit_core(model, data, mask, prior_weight, key, spread, n_starts, braking, scales, tol,
              max_steps, slots, progress=False) -> _FitCore:
    """Everything of a fit that runs in JAX, in one compiled call (eager dispatches of the
    small pre- and post-fit steps cost more than a Levenberg-Marquardt step): the starts,
    the batched solve, the best start, and its data residuals and Jacobian (the solver's
    last, in the unconstrained coordinates u)."""
    keep = keeps_mu_s(mask)
    u_fixed = to_unconstrained(model, PARAMETER_NAMES, keep)
    noise = jax.random.normal(jax.random.PRNGKey(key), (n_starts - 1, len(PARAMETER_NAMES)))
    u0s = jnp.concatenate([u_fixed[None], u_fixed[None] + spread * noise * mask[None, :]])
    us, losses, results, steps, rs, Js = solve_batch(
        u0s, u_fixed, mask, prior_weight, model, data, braking, scales, tol, max_steps, slots,
        progress)
    best = best_start(losses, results)
    values = values_batch(model, us, keep)
    n_data = rs.shape[1] - len(PARAMETER_NAMES)  # the prior's rows are last
    return _FitCore(u_fixed=u_fixed, initial=values_batch(model, u0s, keep), us=us,
                    values=values, losses=losses, results=results, steps=steps, best=best,
                    model=from_unconstrained(us[best], model, PARAMETER_NAMES, keep),
                    theta=values[best], r=rs[best, :n_data], J_u=Js[best, :n_data])


def _diagnose(problem: _Problem, core: _FitCore, prior_weight) -> Diagnostics:
    """`diagnose` the best start: its data residuals and Jacobian in the free u, and the
    prior's residuals."""
    best, cols = int(core.best), [PARAMETER_NAMES.index(n) for n in problem.names]
    prior = float(prior_weight) * (core.us[best][cols] - core.u_fixed[cols])
    return diagnose(core.J_u[:, cols], core.r, prior, core.theta, problem.names,
                    prior_weight)


def _assemble(problem: _Problem, braking, core: _FitCore, diag: Diagnostics,
              t_start) -> FitResult:
    """The `FitResult` of the best start: outcome, errors, the starts' summary."""
    best, names, r = int(core.best), problem.names, core.r
    values = dict(zip(PARAMETER_NAMES, core.theta.tolist()))
    loss = float(0.5 * np.sum(r**2))  # data term only (without the prior)
    forces = braking.fitted_forces(core.model, problem.anon, r, problem.scales)
    with np.errstate(over="ignore"):  # inf for forces past 1e154 N
        rms_F = float(np.sqrt(np.mean(np.concatenate(
            [(F - np.asarray(d.F_x)) ** 2 for F, d in zip(forces, problem.data)]))))
    theta = core.theta[[PARAMETER_NAMES.index(n) for n in names]]
    solver_result = jax.tree.map(lambda x: x[best], core.results)
    return FitResult(
        model=core.model, mode=braking.name, free=names, values=values,
        std_errors=diag.std_errors, loss=loss, rms_force_residual_N=rms_F,
        result=outcome(diag, loss, theta, solver_result), num_steps=int(core.steps[best]),
        condition_number=diag.condition_number, gradient_cosine=diag.max_cosine,
        predicted_reduction=diag.predicted_reduction,
        errors={d.name: force_errors(F, d.F_x) for F, d in zip(forces, problem.data)},
        starts=_starts_summary(core, names), wall_time_s=time.perf_counter() - t_start,
        at_bound=diag.at_bound, solver_status=result_name(solver_result),
    )


def _starts_summary(core: _FitCore, names) -> dict[str, Any]:
    """Every start's loss, Levenberg-Marquardt's outcome (``solver_status``, a
    `vehsim.RESULTS` case) and steps, and the spread of the free values over the starts that
    reached (within 1e-6 relative) the best loss."""
    losses, best = core.losses, int(core.best)
    n_starts = len(losses)
    rows = [dict(zip(PARAMETER_NAMES, row)) for row in core.values.tolist()]
    near = [i for i in range(n_starts) if np.isfinite(losses[i])
            and losses[i] <= losses[best] * (1 + 1e-6) + 1e-300]
    return {
        "n_starts": n_starts,
        "losses": [float(x) if np.isfinite(x) else None for x in losses],
        "solver_status": result_name(core.results),
        "num_steps": [int(x) for x in core.steps],
        "best": best,
        "n_at_best": len(near),
        "spread_at_best": {
            n: {"min": float(min(rows[i][n] for i in near)),
                "max": float(max(rows[i][n] for i in near))} if near else None
            for n in names},
        "initial": [{n: v for n, v in dict(zip(PARAMETER_NAMES, row)).items() if n in names}
                    for row in core.initial.tolist()],
    }


def _unnamed(d: BrakingData) -> BrakingData:
    """`d` without its (static) name, so that compiled fits are shared between brakings."""
    f = _strong_float
    return BrakingData(t=f(d.t), v=f(d.v), omega=f(d.omega), F_x=f(d.F_x), F_n=f(d.F_n),
                       r=f(d.r), T_b=f(d.T_b), m=f(d.m), J=f(d.J))


def _strong_float(x):
    """`x` as a strong (not weak-typed) float64 array, without a JAX dispatch: weak-typed and
    strong leaves would compile separately, and an eager conversion costs more than a
    NumPy one."""
    if x is None:
        return None
    if isinstance(x, jax.Array) and x.dtype == jnp.float64 and not x.weak_type:
        return x
    return np.asarray(x, dtype=float)


def _log(verbose, msg):
    if verbose:
        print(f"  fit: {msg}", file=sys.stderr, flush=True)
