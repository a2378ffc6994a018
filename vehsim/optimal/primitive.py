"""A solved maneuver (`Primitive`): the problem and its interior-point solution, with the
quantities read off it (final time, exit speed, signals at every node, constraint
violations), and its JSON record (`solution_record`).

Three jitted programs compute everything read off a car's solution: the nodes (`_nodes`),
the constraint arrays (`_violation_arrays`) and the named signals (`_signals`); each takes
the problem (or vehicle) and arrays only. A primitive runs them through its ``runner``
(default `run_program`: a plain call), which a caller may replace, as the compilation layer
does with its exported programs."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._results import result_name, result_record
from .ip import IPSolution
from .shooting import DELTA_MAX, ManeuverOCP


SUBSTEPS = 20
"""RK4 substeps per integration step of the re-integration between the nodes."""


def run_program(name: str, program: Callable, args: tuple):
    """``program(*args)``: how a `Primitive` runs its read-off programs by default. ``name``
    names the program for a runner that keeps it elsewhere (the compilation layer's
    `vehsim._compilation.exported_call` has this signature)."""
    return program(*args)


class AbstractSolvedDrive(eqx.Module):
    """A solved drive (a ``problem`` with ``final_time`` and ``speed`` of its knot states, and
    its interior-point ``solution``): ``t_f`` [s], ``exit_speed`` [m/s] read off the last
    knot, and ``result`` (`vehsim.RESULTS`)."""

    problem: eqx.AbstractVar[Any]
    solution: eqx.AbstractVar[IPSolution]

    @property
    def t_f(self):
        return self.problem.final_time(self.solution.xs[..., -1, :])

    @property
    def exit_speed(self):
        return self.problem.speed(self.solution.xs[..., -1, :])

    @property
    def result(self):
        return self.solution.result


class Primitive(AbstractSolvedDrive):
    """A solved maneuver: ``problem`` (`ManeuverOCP` or `PointMassOCP`) and the interior-point
    ``solution``; ``t_f`` [s], ``exit_speed`` [m/s] (read off the last knot by the problem's
    ``final_time`` and ``speed``: the car's and the point mass's states differ) and
    ``result`` (`vehsim.RESULTS`); ``starts``: the solutions from every start of a
    multi-start solve (batched along axis 0), or None; ``runner``: how the nodes, signals and
    violations are computed, ``runner(name, program, args)`` (default `run_program`)."""

    problem: Any
    solution: IPSolution
    starts: IPSolution | None = None
    runner: Callable = eqx.field(static=True, default=run_program)

    def nodes(self):
        """States at every integration node (M S + 1, nx), uniform in tau."""
        return self.runner("nodes", _nodes, (self.problem, self.solution.xs, self.solution.us))

    def time(self):
        n = self.nodes()
        return jnp.linspace(0.0, 1.0, n.shape[0]) * self.t_f

    def signals(self) -> dict:
        """Named signals at every node (car problems): pose, speeds, sideslip, slips, forces."""
        return _node_signals(self.problem.vehicle, self.nodes(), self.runner)

    def violations(self, substeps: int = SUBSTEPS) -> dict:
        """Constraint violations of the solution, measured exactly at every node: distance off
        the road (union of legs, not the smooth corridor) [m], boundary conditions (max abs,
        m/rad/(m/s)), input bounds, axle-speed floor [m/s], shooting defects; and
        ``corridor_between_nodes``: the distance off the road between the nodes, where the
        constraints are not imposed, found by re-integrating every segment with `substeps`
        RK4 steps per step (`fine_nodes`)."""
        prob = self.problem
        n, fine, bc, defects = (np.asarray(a) for a in self.runner(
            "violations", _violation_arrays, (prob, self.solution.xs, self.solution.us,
                                              substeps)))
        rd = prob.road
        off = rd.distance_off_road(n[:, 0], n[:, 1])
        between = rd.distance_off_road(fine[:, 0], fine[:, 1])
        out = dict(corridor=float(np.max(off)), corridor_between_nodes=float(np.max(between)),
                   boundary=float(bc), defects=float(defects))
        if isinstance(prob, ManeuverOCP):
            kF, kR, d = n[:, 6], n[:, 7], n[:, 8]
            inp = np.concatenate([-0.99 - kF, kF - 1.0, -0.99 - kR, kR - 1.0,
                                  np.abs(d) - float(DELTA_MAX)])
            out["inputs"] = float(max(np.max(inp), 0.0))
            sig = _node_signals(prob.vehicle, n, self.runner)  # the nodes computed above
            out["axle_speed_floor"] = float(max(0.0, 1.0 - min(sig["Vx_F"].min(),
                                                               sig["Vx_R"].min())))
            if prob.objective == "max-exit":
                t_f, _ = _final_time_and_speed(prob, self.solution)
                out["time_budget"] = max(0.0, t_f - float(prob.tf_max))
        return out


@eqx.filter_jit
def _nodes(prob, xs, us):
    return prob.nodes(xs, us)


@eqx.filter_jit
def _signals(vehicle, nodes) -> dict:
    return jax.vmap(vehicle.signals)(nodes[:, :6], nodes[:, 6:9])


def _node_signals(vehicle, nodes, runner: Callable = run_program) -> dict:
    """Named signals of `vehicle` at the car's nodes (states, then the inputs)."""
    nodes = nodes if isinstance(nodes, jax.Array) else np.asarray(nodes, float)
    signals = runner("signals", _signals, (vehicle, nodes))
    return {k: np.asarray(v) for k, v in signals.items()}


@eqx.filter_jit
def _violation_arrays(prob, xs, us, substeps: int):
    """Nodes, the re-integrated states between them, the largest boundary-condition
    violation and the largest shooting defect of the knots ``xs`` and inputs ``us`` (one
    compiled program)."""
    rd = prob.road
    bc = jnp.maximum(jnp.max(jnp.abs(prob.initial_equality(xs[0])), initial=0.0),
                     jnp.max(jnp.abs(prob.terminal_equality(xs[-1])), initial=0.0))
    for b in (rd.boundary_inequality(rd.start, xs[0]), rd.boundary_inequality(rd.end, xs[-1])):
        bc = jnp.maximum(bc, jnp.max(jnp.maximum(-b, 0.0), initial=0.0))
    defects = xs[1:] - jax.vmap(prob.transition)(xs[:-1], us, jnp.arange(prob.num_stages))
    return (prob.nodes(xs, us), prob.fine_nodes(xs, us, substeps), bc,
            jnp.max(jnp.abs(defects)))


def solution_record(prim: Primitive, bound: Primitive | None = None) -> dict:
    """JSON-ready record of a solved car primitive: t_f, exit_speed, ``status`` (the result's
    name) and ``message``, iterations, residuals, violations, the point-mass ``bound`` and
    the ratio to it, states and inputs at every node. A drive on a centre-line road (a
    primitive with a ``record`` method, `RoadPrimitive`) gives its own record, with the same
    fields."""
    if hasattr(prim, "record"):
        return prim.record(bound)
    sol = prim.solution
    sig = prim.signals()
    # read off host copies: each eager operation on a device array is a program of its own
    t_f, exit_speed = _final_time_and_speed(prim.problem, sol)
    rec = dict(
        road=prim.problem.road.name, objective=prim.problem.objective,
        t_f=t_f, exit_speed=exit_speed, **result_record(sol.result),
        iterations=int(sol.iterations),
        residuals=dict(inf_pr=float(sol.inf_pr), inf_du=float(sol.inf_du),
                       compl=float(sol.compl)),
        segments=prim.problem.num_stages, nodes=len(sig["x"]),
        steps_per_stage=prim.problem.steps_per_stage,
        corner_clearance=prim.problem.corner_clearance,
        interior_points=prim.problem.interior_points,
    )
    v = prim.violations()
    rec["violations"] = v
    rec["max_corridor_violation"] = v["corridor"]
    rec["max_corridor_violation_between_nodes"] = v["corridor_between_nodes"]
    if bound is not None:
        rec["point_mass_t_f"], rec["point_mass_exit_speed"] = _final_time_and_speed(
            bound.problem, bound.solution)
        rec["point_mass_status"] = result_name(bound.result)
        rec["t_f_over_bound"] = t_f / rec["point_mass_t_f"]
        # the max-exit objective's own ratio (its t_f is the budget's, about the bound's)
        rec["exit_speed_over_bound"] = rec["exit_speed"] / rec["point_mass_exit_speed"]
    if prim.starts is not None:
        rec["starts"] = [dict(objective=float(o), status=r, iterations=int(i))
                         for o, r, i in zip(np.asarray(prim.starts.objective),
                                            result_name(prim.starts.result),
                                            np.asarray(prim.starts.iterations))]
    rec["t"] = np.linspace(0.0, 1.0, rec["nodes"]) * t_f
    rec["states"] = {k: sig[k] for k in ("x", "y", "psi", "vx", "vy", "yaw_rate")}
    rec["inputs"] = {k: sig[k] for k in ("kappa_F", "kappa_R", "delta")}
    rec["signals"] = {k: sig[k] for k in ("speed", "sideslip", "Fz_F", "Fz_R", "Fx_F", "Fx_R",
                                          "Fy_F", "Fy_R", "Vx_F", "Vx_R")}
    return rec


def _final_time_and_speed(prob, sol: IPSolution) -> tuple[float, float]:
    """t_f and the exit speed of a solution of ``prob``, from a host copy of its last
    knot."""
    x = np.asarray(sol.xs)[-1]
    return float(prob.final_time(x)), float(prob.speed(x))
