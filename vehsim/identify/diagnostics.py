r"""What the data say at a fit's optimum: force errors, standard errors, identifiability,
first-order optimality, and the outcome as a `vehsim.RESULTS` item.

**Standard errors** come from the Gauss-Newton covariance
$\operatorname{cov}\theta = s^2(J^\top J)^{-1}$, $s^2 = \sum r_k^2/(N-p)$, with $J$ the
Jacobian in the physical parameters. They assume white residuals; sensor lag and
sample-and-hold correlate real residuals, so read them as lower bounds.

**Identifiability.** A Jacobian of condition number $> 10^9$ in relative parameters
($J\operatorname{diag}\theta$) means the data cannot determine the parameters (e.g. no slip
excitation): `RESULTS.not_identifiable`.

**Convergence** is declared when optimistix's Levenberg-Marquardt terminates, or when
MINPACK-style tests certify the optimum: relative gradient cosine $\le$ `gtol` or a
Gauss-Newton-predicted relative loss reduction $\le$ `ftol`. optimistix stops on small steps
and small loss changes; with noisy data at the optimum every trial step is rejected, so a
fit can run out of steps although it sits at the minimum. Parameters the data drive to
their bound 0 are set aside first (`at_lower_bound`): the log transform reaches 0 only at
$u = -\infty$, where Levenberg-Marquardt crawls.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from .._optimality import (
    FTOL as FTOL,  # MINPACK's ftol and gtol
    GTOL as GTOL,
    max_gradient_cosine,
    predicted_reduction as _predicted_reduction,
)
from .._results import RESULTS, is_successful
from .parameters import PARAMETER_NAMES, dtheta_du


MAX_CONDITION_NUMBER = 1e9


def force_errors(F_pred, F_meas) -> dict[str, float]:
    """RMS and peak force errors [N], also relative to the peak measured |F_x|."""
    F_pred, F_meas = np.asarray(F_pred), np.asarray(F_meas)
    e = F_pred - F_meas
    peak = float(np.max(np.abs(F_meas)))
    with np.errstate(over="ignore"):  # inf for forces past 1e154 N
        rms = float(np.sqrt(np.mean(e**2)))
    return {
        "rms_error_N": rms,
        "rms_error_rel_peak": rms / peak,
        "max_abs_error_N": float(np.max(np.abs(e))),
        "peak_force_measured_N": peak,
        "peak_force_predicted_N": float(np.max(np.abs(F_pred))),
        "peak_force_error_N": float(np.max(np.abs(F_pred)) - peak),
    }


@dataclasses.dataclass(frozen=True)
class Diagnostics:
    """The numbers `outcome` judges a fit by (see the module docstring)."""

    std_errors: dict[str, float]
    singular_values: np.ndarray  # of the Jacobian in relative parameters, descending
    condition_number: float
    at_bound: tuple[str, ...]
    max_cosine: float  # the largest gradient cosine of the parameters not at a bound
    predicted_reduction: float  # relative, of the Gauss-Newton step


def singular_values(A) -> np.ndarray:
    r"""Singular values of a tall `A`, descending: from the eigenvalues of the small
    $A^\top A$ when they resolve the smallest one (condition number below ~1e6), else from
    a QR of `A` (a tall LAPACK call, the slower way)."""
    ev = np.linalg.eigvalsh(A.T @ A)[::-1]
    if ev[-1] > 1e-12 * ev[0]:
        return np.sqrt(ev)
    return np.linalg.svd(np.linalg.qr(A, mode="r"), compute_uv=False)


def physical_jacobian(J_u, theta_all, names: Sequence[str]) -> np.ndarray:
    r"""$J_\theta = J_u(\partial\theta/\partial u)^{-1}$ of the free `names`: the chain
    rule, $J_u = J_\theta\,\partial\theta/\partial u$ (fixed values do not depend on $u$)."""
    cols = [PARAMETER_NAMES.index(n) for n in names]
    return J_u @ np.linalg.inv(dtheta_du(theta_all, names)[cols, :])


def standard_errors(J, r, names: Sequence[str], condition_number: float) -> dict[str, float]:
    r"""$\sqrt{\operatorname{diag}(s^2(J^\top J)^{-1})}$, NaN where not determined.

    From the singular values of $J$ ($(J^\top J)^{-1} = V \Sigma^{-2} V^\top$), not by
    inverting $J^\top J$, whose condition number is the square of $J$'s: a column scaled
    far above the others (a parameter the data barely move) makes it singular in float64
    while $J$ still determines every parameter."""
    N, p = J.shape
    if not (np.isfinite(condition_number) and N > p):
        return {n: math.nan for n in names}
    _, sv, vt = np.linalg.svd(J, full_matrices=False)
    if not sv[-1] > 0:
        return {n: math.nan for n in names}
    with np.errstate(over="ignore"):  # inf where the residuals barely move: `outcome`
        var = float(np.sum(r**2) / (N - p)) * np.sum((vt / sv[:, None]) ** 2, axis=0)
    return {n: float(math.sqrt(var[i])) for i, n in enumerate(names)}


def at_lower_bound(grad_u, theta_all, names: Sequence[str], std_errors) -> np.ndarray:
    r"""Free parameters the data push towards 0 ($\partial L/\partial u > 0$) whose value
    (for $\mu_s$: $\mu_s - \mu_c$) is within two standard errors of 0."""
    values = dict(zip(PARAMETER_NAMES, theta_all.tolist()))
    size = np.array([values[n] - (values["mu_c"] if n == "mu_s" else 0.0) for n in names])
    se = np.array([std_errors[n] for n in names])
    return (grad_u > 0) & np.isfinite(se) & (size < 2.0 * se)


def predicted_reduction(J, r) -> float:
    """MINPACK's ftol test: the loss reduction the Gauss-Newton model predicts for its full
    (undamped) step, relative to the loss (`vehsim._optimality.predicted_reduction`)."""
    return float(_predicted_reduction(np.asarray(J), np.asarray(r)))


def diagnose(J_u, r, prior_residual, theta_all, names: Sequence[str],
             prior_weight: float) -> Diagnostics:
    r"""The diagnostics of an optimum: `J_u` the Jacobian of the data residuals `r` in the
    free $u$, `prior_residual` the prior's residuals $w(u - u_0)$, `theta_all` the values
    of `PARAMETER_NAMES`, `names` the free ones."""
    theta = theta_all[[PARAMETER_NAMES.index(n) for n in names]]
    J = physical_jacobian(J_u, theta_all, names)
    J_rel = J * theta[None, :]
    sv = singular_values(J_rel) if np.all(np.isfinite(J_rel)) else np.array([0.0])
    # fewer samples than free parameters: J has a null space its len(sv) = N values miss
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 and J_rel.shape[0] >= J_rel.shape[1] \
        else math.inf
    std = standard_errors(J, r, names, cond)
    # the optimality tests in the solver's coordinates u, prior included
    Ju = np.concatenate([J_u, float(prior_weight) * np.eye(len(names))])
    ru = np.concatenate([r, prior_residual])
    bound = at_lower_bound(Ju.T @ ru, theta_all, names, std)
    return Diagnostics(
        std_errors=std, singular_values=sv, condition_number=cond,
        at_bound=tuple(n for n, b in zip(names, bound) if b),
        max_cosine=float(max_gradient_cosine(Ju[:, ~bound], ru)),
        predicted_reduction=predicted_reduction(Ju[:, ~bound], ru),
    )


def stationary(diag: Diagnostics, gtol: float = GTOL, ftol: float = FTOL) -> bool:
    """MINPACK's tests certify the optimum: gradient cosine <= `gtol` or predicted relative
    loss reduction <= `ftol`."""
    return diag.max_cosine <= gtol or diag.predicted_reduction <= ftol


def outcome(diag: Diagnostics, loss: float, theta, solver_result: RESULTS) -> RESULTS:
    """The fit's `RESULTS` item: `nonfinite`, `not_identifiable` (the Jacobian's condition
    number, or standard errors that are not finite: residuals the parameters barely move,
    as forces recorded in the wrong units give), else `successful` where the solver
    converged or the optimum is `stationary`, else the solver's own result."""
    if not (np.isfinite(loss) and np.all(np.isfinite(theta))):
        return RESULTS.nonfinite
    if (not np.isfinite(diag.condition_number) or diag.condition_number > MAX_CONDITION_NUMBER
            or diag.singular_values[0] == 0.0
            or not np.all(np.isfinite(list(diag.std_errors.values())))):
        return RESULTS.not_identifiable
    if bool(is_successful(solver_result)) or stationary(diag):
        return RESULTS.successful
    return solver_result
