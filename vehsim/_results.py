r"""One way to ask "did it work?": the `RESULTS` enumeration every solve in vehsim returns.

As optimistix extends lineax's `RESULTS` and diffrax extends optimistix's, `vehsim.RESULTS`
extends diffrax's with the cases of our own solvers. `Trajectory`, `TireSolution`,
`IPSolution`, `FitResult` and `SweepResult` each carry a `.result`; ``throw=True`` raises
with the case's message (``result.error_if(...)`` under `jit`), ``throw=False`` leaves the
result for the caller (what batched runs use). Result files write the case's name and its
message (`result_record`).
"""

from __future__ import annotations

import diffrax as dfx
import numpy as np


class RESULTS(dfx.RESULTS):  # pyright: ignore
    """The outcome of a vehsim solve: diffrax's cases (and through it optimistix's and
    lineax's) plus those of vehsim's own solvers."""

    ip_max_iterations = (
        "The interior-point method reached its iteration limit before the scaled KKT error "
        "met its tolerance. Increase `IPOptions.max_iter`, or start from a better guess."
    )
    ip_locally_infeasible = (
        "The interior-point method reached its iteration limit with the constraint violation "
        "above `IPOptions.constr_tol`, not reduced by 1 % over its last 25 passes and never "
        "below a thousandth of the starting one: "
        "the constraints are probably infeasible near this iterate (a final time too short "
        "for the road, a bound that contradicts the boundary conditions). More iterations "
        "are unlikely to help: relax the constraints, or start from a guess that meets them."
    )
    ip_line_search_failed = (
        "The interior-point line search accepted no step on consecutive passes, with the "
        "multipliers not re-estimated (`IPOptions.reestimate_multipliers` off): the solve "
        "stopped at the point where it stalled. Start from a better guess, or switch the "
        "re-estimate on."
    )
    ip_newton_system_failed = (
        "The interior-point method could not solve its Newton system: no regularisation up "
        "to the last one tried gave a factor of the right inertia and an accurate solve "
        "(non-finite derivatives at the iterate, or a precision too low for the problem). "
        "The solve stopped at the iterate where it happened."
    )
    not_identifiable = (
        "The data do not determine the parameters: the Jacobian (in relative parameters) is "
        "numerically rank deficient. Is there slip excitation in the data?"
    )
    step_size_collapsed = (
        "The adaptive step size was rejected down to its floor (`DTMIN_FRACTION` of the time "
        "span) and the time stopped advancing: the vector field is not finite (NaN or inf) "
        "just past the last time reached (a control function or input that turns NaN there, "
        "a state outside the model's domain), or the solution blows up in finite time. The "
        "saved states after that time are inf."
    )


def result_names(enumeration=RESULTS) -> tuple[str, ...]:
    """The names of the cases of `enumeration` (default `RESULTS`: those of the installed
    lineax, optimistix and diffrax first, then vehsim's), in the order of their values.

    Read from the enumeration, so that a case a parent gains appears here: equinox's
    metaclass takes the cases out of the class namespace and keeps them in the class's
    name-to-item table (``_name_to_item``, typed on `equinox.Enumeration`; what its
    ``len`` and attribute lookup read), inherited cases first."""
    return tuple(enumeration._name_to_item)


def _message_of(name: str) -> str:
    message = RESULTS[getattr(RESULTS, name)]
    return message.split("\n")[0] if message else "successful"


def result_name(result) -> str | list:
    """The name of a concrete `RESULTS` item (``"successful"``, ``"ip_max_iterations"``, ...);
    nested lists of names for a batched item (e.g. a sweep's per-member results)."""
    result = as_result(result)
    shape = np.shape(np.asarray(result == RESULTS.successful))
    out = np.full(shape, "unknown", dtype=object)
    for name in result_names():
        out[np.asarray(result == getattr(RESULTS, name))] = name
    return out.item() if out.ndim == 0 else out.tolist()


def result_message(result) -> str | list:
    """The first line of the message of a concrete `RESULTS` item (nested lists of messages
    for a batched item)."""
    return _map_nested(result_name(result), result_message_of_name)


def _map_nested(x, fn):
    return fn(x) if isinstance(x, str) else [_map_nested(v, fn) for v in x]


def result_message_of_name(name: str) -> str:
    """The message of the case called `name` (``"successful"`` for success)."""
    return _message_of(name) if name in result_names() else "unknown result"


def result_record(result) -> dict:
    """``{"status": name, "message": message}`` of a concrete (scalar) `RESULTS` item, the
    fields result files carry."""
    name = result_name(result)
    return {"status": name, "message": result_message_of_name(name)}


def result_of_record(record) -> RESULTS:
    """The `RESULTS` item whose `result_record` is `record` (read from its ``status``)."""
    name = record["status"]
    if name not in result_names():
        raise ValueError(f"status {name!r} is not a case of vehsim.RESULTS")
    return getattr(RESULTS, name)


def is_successful(result):
    """Boolean array: where `result` is `RESULTS.successful`."""
    return as_result(result) == RESULTS.successful


def as_result(result) -> RESULTS:
    """`result` as an item of `RESULTS` (a diffrax, optimistix or lineax item is promoted)."""
    return result if isinstance(result, RESULTS) else RESULTS.promote(result)
