"""Maneuver primitives on the benchmark problems (coarse grids to keep CI small)."""

import math
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _isolated import in_subprocess, require_casadi
from optimal_cache import M, corner90_min_time

from vehsim import result_name
from vehsim.optimal import roads
from vehsim.optimal.guesses import car_guess
from vehsim.optimal.ip import IPOptions
from vehsim.optimal.primitive import solution_record
from vehsim.optimal.primitives import (
    MAX_EXIT_MU0,
    max_exit_primitive,
    min_time_primitive,
    point_mass_bound,
    primitive_and_bound,
    primitive_options,
    rally_gravel_car,
)
from vehsim.optimal.shooting import DELTA_MAX, IDX_TF


# one worker for this module and its peer: they share the compiled, solved primitive
pytestmark = pytest.mark.xdist_group("corner90_min_time")


def _check_solution(prim):
    sol = prim.solution
    assert sol.converged, (sol.message, float(sol.inf_pr), float(sol.inf_du))
    v = prim.violations()
    assert v["corridor"] <= 1e-3  # exact distance off the road at every node [m]
    assert v["boundary"] <= 1e-3
    assert v["defects"] <= 1e-6
    assert v["inputs"] <= 1e-6
    assert v["axle_speed_floor"] <= 1e-3
    xs = np.asarray(sol.xs)
    assert np.all(np.abs(xs[:, 8]) <= DELTA_MAX + 1e-6)


@pytest.fixture(scope="module")
def corner_min_time():
    return corner90_min_time()  # shared with tests/test_optimal_replay.py


def test_corner90_min_time_feasible_and_above_point_mass_bound(corner_min_time):
    prim = corner_min_time
    _check_solution(prim)
    bound = point_mass_bound("corner90", num_stages=M, steps_per_stage=1)
    assert bound.solution.converged
    # the point mass with |a| <= D g bounds every min-time result from below (how far above
    # it the optimum lies is checked against IPOPT's optimum below)
    assert float(bound.t_f) < float(prim.t_f)
    # read off each problem's own states: the point mass (x, y, vx, vy, t_f), the car
    # (x, y, psi, vx, vy, r, kappa_F, kappa_R, delta, t_f)
    pm, car = np.asarray(bound.solution.xs[-1]), np.asarray(prim.solution.xs[-1])
    assert float(bound.t_f) == pm[4] and float(bound.exit_speed) == pytest.approx(
        math.hypot(pm[2], pm[3]), rel=1e-14)
    assert float(prim.t_f) == car[9] and float(prim.exit_speed) == pytest.approx(
        math.hypot(car[3], car[4]), rel=1e-14)
    rec = solution_record(prim, bound)
    assert rec["point_mass_exit_speed"] == pytest.approx(math.hypot(pm[2], pm[3]), rel=1e-14)
    assert rec["t_f_over_bound"] == pytest.approx(car[9] / pm[4], rel=1e-14)
    assert rec["exit_speed_over_bound"] == pytest.approx(
        math.hypot(car[3], car[4]) / math.hypot(pm[2], pm[3]), rel=1e-14)
    # boundary conditions of Table 4 (literal heading)
    x0, xT = np.asarray(prim.solution.xs[0]), np.asarray(prim.solution.xs[-1])
    assert abs(x0[0] + 5.0) < 1e-6 and 8.0 <= x0[1] <= 10.0
    assert abs(xT[1] + 5.0) < 1e-6 and 8.0 <= xT[0] <= 10.0
    assert abs(xT[2] + math.pi / 2) < 1e-6


def _ipopt_benchmark():
    """The benchmark's CasADi + IPOPT transcription (experiments/benchmarks/ocp_vs_ipopt.py):
    its own CasADi model of the reduced half-car (eqs. 61-63), friction ellipse and
    quasi-static loads, the same corridor, bounds, objective and RK4 nodes."""
    import importlib.util

    path = Path(__file__).parent.parent / "experiments" / "benchmarks" / "ocp_vs_ipopt.py"
    spec = importlib.util.spec_from_file_location("ocp_vs_ipopt", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _ipopt_solve(road, objective, num_stages, xs0, us0, tf_max):
    """The IPOPT solve from the given start, in the spawned process (tests/_isolated.py)."""
    return _ipopt_benchmark().ipopt_solve(roads.road(road), objective, 0.52, num_stages,
                                          jnp.asarray(xs0), jnp.asarray(us0), tf_max=tf_max)


def _against_ipopt(prim, road, objective, tf_max=4.0, start=None):
    """IPOPT from the centreline guess (or `start`, knots and controls); returns (vehsim,
    IPOPT) t_f or exit speed and IPOPT's knots."""
    xs0, us0 = car_guess(rally_gravel_car(), roads.road(road), M, 1) if start is None \
        else start
    if objective == "max-exit" and start is None:
        xs0 = xs0.at[:, IDX_TF].set(jnp.minimum(xs0[:, IDX_TF], 0.98 * tf_max))
    require_casadi()
    ip = in_subprocess(_ipopt_solve, road, objective, M, np.asarray(xs0), np.asarray(us0),
                       tf_max)
    assert ip["ok"], ip["status"]
    value = ((lambda x: x[-1, IDX_TF]) if objective == "min-time"
             else (lambda x: math.hypot(x[-1, 3], x[-1, 4])))
    return float(value(np.asarray(prim.solution.xs))), float(value(ip["xs"])), ip["xs"]


def test_primitive_and_bound_are_the_primitive_and_the_bound(corner_min_time):
    """`primitive_and_bound`, and the compilation layer's arrangement of it (the car's
    program compiled on a thread while the bound is solved): the same programs from the
    same starts, so the same numbers to the last bit; a wrong objective is named."""
    from vehsim import _compilation

    alone = point_mass_bound("corner90", num_stages=M, steps_per_stage=1)
    for solve in (primitive_and_bound, _compilation.primitive_and_bound):
        prim, bound = solve("corner90", num_stages=M, steps_per_stage=1,
                            options=IPOptions(max_iter=300))
        np.testing.assert_array_equal(np.asarray(prim.solution.xs),
                                      np.asarray(corner_min_time.solution.xs))
        np.testing.assert_array_equal(np.asarray(bound.solution.xs),
                                      np.asarray(alone.solution.xs))
        assert float(bound.t_f) < float(prim.t_f)
        with pytest.raises(ValueError, match="objective.*'fastest'"):
            solve("corner90", "fastest", num_stages=M)


def test_every_solve_goes_through_the_solver_given(corner_min_time):
    """``solver=`` replaces the interior-point solve of the seeds and the car (and of the
    bound): a wrapper sees every problem, and the numbers are `interior_point`'s."""
    from vehsim.optimal.ip import interior_point

    seen = []

    def solver(prob, *args, **kwargs):
        seen.append(type(prob).__name__)
        return interior_point(prob, *args, **kwargs)

    prim = min_time_primitive("corner90", num_stages=M, steps_per_stage=1,
                              options=IPOptions(max_iter=300), solver=solver)
    assert seen == ["PointMassOCP", "ManeuverOCP"]
    np.testing.assert_array_equal(np.asarray(prim.solution.xs),
                                  np.asarray(corner_min_time.solution.xs))
    point_mass_bound("corner90", num_stages=M, steps_per_stage=1, solver=solver)
    assert seen[2:] == ["PointMassOCP", "PointMassOCP"]  # two centreline starts


def test_record_programs_prepared_from_a_guess_are_the_solution_s(corner_min_time):
    """`prepare_record_programs` with a starting guess prepares the very programs the record of
    the solution and its figure run through the compilation layer's exported programs
    (``runner=exported_call``, as its `primitive_and_bound` returns them): after it, they
    need no other program (the tests run with the cache of compiled programs on,
    tests/conftest.py), and the record is the plain primitive's."""
    import dataclasses

    from vehsim import _compilation
    from vehsim.plot import primitive_figure

    prob = corner_min_time.problem
    xs0, us0 = car_guess(prob.vehicle, prob.road, M, 1)
    held = dict(_compilation._programs)
    _compilation._programs.clear()  # this process's programs: loaded again from disk
    try:
        _compilation.prepare_record_programs(prob, xs0, us0)
        loaded = set(_compilation._programs)
        exported = dataclasses.replace(corner_min_time, runner=_compilation.exported_call)
        rec = solution_record(exported)
        primitive_figure(exported)
        assert set(_compilation._programs) == loaded and len(loaded) == 3
        assert None not in _compilation._programs.values()
    finally:
        _compilation._programs.clear()
        _compilation._programs.update(held)
    plain = solution_record(corner_min_time)
    assert rec["t_f"] == plain["t_f"] == float(corner_min_time.t_f)
    assert rec["violations"] == plain["violations"]
    np.testing.assert_array_equal(rec["signals"]["Fy_F"], plain["signals"]["Fy_F"])


def test_corner90_min_time_is_ipopts_optimum(corner_min_time):
    """An independent optimum: IPOPT on the benchmark's CasADi model (the same corner
    clearance), started at vehsim's solution, stays there: the same t_f (to 1e-6) and the
    same knots (positions within 1 mm, speeds 1 mm/s, angles and slips 1e-4). From the
    shared guess the two solvers reach different local optima on this coarse grid (3.685 s
    for vehsim, 3.625 s for IPOPT; each solver stays at the other's): vehsim's is within 2 %."""
    prim = corner_min_time
    ours, theirs, xs = _against_ipopt(prim, "corner90", "min-time",
                                      start=(prim.solution.xs, prim.solution.us))
    assert abs(ours - theirs) <= 1e-6 * theirs, (ours, theirs)
    _, from_guess, _ = _against_ipopt(prim, "corner90", "min-time")
    assert ours <= 1.02 * from_guess, (ours, from_guess)
    diff = np.abs(np.asarray(corner_min_time.solution.xs) - xs)
    assert np.all(diff[:, :2] < 1e-3) and np.all(diff[:, 3:5] < 1e-3), diff.max(axis=0)
    assert np.all(diff[:, [2, 5, 6, 7, 8]] < 1e-4), diff.max(axis=0)


def test_warm_start_reproduces_the_optimum(corner_min_time):
    prim = corner_min_time
    # warm start: a small initial barrier keeps the iterates near the given optimum
    again = min_time_primitive("corner90", num_stages=M, steps_per_stage=1,
                               options=IPOptions(max_iter=300, mu0=1e-4),
                               guess=(prim.solution.xs, prim.solution.us))
    assert again.solution.converged
    assert abs(float(again.t_f) - float(prim.t_f)) < 1e-6


@pytest.mark.slow
@pytest.mark.parametrize("road, objective", [("corner90", "max-exit"), ("uturn", "min-time"),
                                             ("sturn", "min-time")])
def test_other_benchmark_problems_feasible_and_ipopts_optimum(road, objective):
    """The other benchmark problems: feasible; an optimum for IPOPT too (started at vehsim's
    solution, IPOPT converges to the same value, to 1e-6), and no worse than IPOPT's from
    the centreline guess by more than 1e-3 (the problems have several local optima, and the
    primitive starts from the point-mass solution instead)."""
    f = min_time_primitive if objective == "min-time" else max_exit_primitive
    prim = f(road, num_stages=M, steps_per_stage=1,
             options=primitive_options(objective, max_iter=400))  # max-exit: mu0 0.01
    _check_solution(prim)
    if objective == "max-exit":
        assert float(prim.t_f) <= 4.0 + 1e-6
    ours, theirs, _ = _against_ipopt(prim, road, objective)
    sign = 1.0 if objective == "min-time" else -1.0
    assert sign * (ours - theirs) <= 1e-3 * theirs, (ours, theirs)
    _, at_ours, _ = _against_ipopt(prim, road, objective,
                                   start=(prim.solution.xs, prim.solution.us))
    assert abs(ours - at_ours) <= 1e-6 * at_ours, (ours, at_ours)


def test_re_integration_between_the_nodes(corner_min_time):
    """`fine_nodes`: one substep reproduces the nodes; with 20, the state halfway through a
    segment equals an independent tight integration from its knot (diffrax, 8th order); the
    corridor is imposed at the nodes only, and the record reports both violations."""
    import diffrax as dfx

    prim = corner_min_time
    prob, sol = prim.problem, prim.solution
    np.testing.assert_allclose(np.asarray(prob.fine_nodes(sol.xs, sol.us, 1)),
                               np.asarray(prim.nodes()), rtol=0, atol=1e-12)
    fine = np.asarray(prob.fine_nodes(sol.xs, sol.us, 20))
    assert fine.shape == (20 * M + 1, 10)
    k = M // 2
    ref = dfx.diffeqsolve(dfx.ODETerm(lambda t, y, u: prob._rhs(y, u)), dfx.Dopri8(), 0.0,
                          0.5 / M, 1e-3 / M, sol.xs[k], args=sol.us[k],
                          stepsize_controller=dfx.PIDController(rtol=1e-11, atol=1e-11))
    np.testing.assert_allclose(fine[20 * k + 10], np.asarray(ref.ys[0]), rtol=1e-7, atol=1e-9)
    v = prim.violations()
    off = prob.road.distance_off_road(fine[:, 0], fine[:, 1])
    assert v["corridor_between_nodes"] == pytest.approx(float(off.max()), abs=1e-15)
    assert v["corridor_between_nodes"] >= v["corridor"]


def test_multistart_solves_every_start_in_one_call_and_keeps_the_best(corner_min_time):
    """``starts=3``: the default point-mass seed, the centreline at 5 m/s and a second seed,
    solved in one compiled call split over the session's two host devices (padded to 4
    starts, each device solving its starts one after another). The default seed's solve is
    the single-start primitive's (same optimum to 1e-9); the primitive is the best converged
    start; the record (with the point-mass bound, computed on one device) lists every
    start's objective and status."""
    prim = min_time_primitive("corner90", num_stages=M, steps_per_stage=1,
                              options=IPOptions(max_iter=300), starts=3)
    starts = prim.starts
    assert jax.device_count() == 2  # tests/conftest.py
    assert starts.xs.shape == (3, M + 1, 10)
    objective = np.asarray(starts.objective)
    assert objective[0] == pytest.approx(float(corner_min_time.solution.objective), rel=1e-9)
    converged = np.asarray(starts.converged)
    best = int(np.argmin(np.where(converged, objective, np.inf)))
    np.testing.assert_array_equal(np.asarray(prim.solution.xs), np.asarray(starts.xs[best]))
    assert prim.solution.converged and float(prim.solution.objective) <= objective[
        converged].min()
    # with the bound: the batch came back from two devices, the bound from one
    bound = point_mass_bound("corner90", num_stages=M, steps_per_stage=1)
    rec = solution_record(prim, bound)
    assert rec["t_f_over_bound"] == pytest.approx(float(prim.t_f) / float(bound.t_f), rel=1e-14)
    assert [s["status"] for s in rec["starts"]] == result_name(starts.result)
    assert [s["objective"] for s in rec["starts"]] == pytest.approx(list(objective), rel=1e-12)
    with pytest.raises(ValueError, match="starts must be an integer >= 1, got 0"):
        min_time_primitive("corner90", num_stages=M, steps_per_stage=1, starts=0)
    with pytest.raises(ValueError, match="objective must be 'min-time' or 'max-exit'"):
        primitive_options("fastest")
    # max-exit from point-mass seeds starts at the small barrier, a multi-start at IPOPT's
    assert float(primitive_options("max-exit").mu0) == MAX_EXIT_MU0 < 0.1
    assert float(primitive_options("max-exit", ((0.5, 0.6), (0.3, 0.8))).mu0) == MAX_EXIT_MU0
    assert float(primitive_options("max-exit", 8).mu0) == 0.1
    assert float(primitive_options("min-time").mu0) == 0.1


def test_the_bound_starts_from_the_cars_path_too():
    """The point-mass problem has local optima: on sturn (150 stages, one RK4 step each)
    its centreline starts end above the car's own optimum (6.5055 s). Started also from
    the car's path (knots of vehsim's car optimum, tests/data), the bound lies below it."""
    xs = np.load(Path(__file__).parent / "data" / "sturn_min_time_150_knots.npz")["xs"]
    car_tf = float(xs[-1, IDX_TF])
    assert abs(car_tf - 6.505518) < 1e-5
    bound = point_mass_bound("sturn", "min-time", num_stages=150, steps_per_stage=1,
                             throw=False, car_xs=xs)
    assert bool(bound.solution.converged)
    assert float(bound.t_f) < car_tf


def test_primitives_refuse_float32():
    """With float64 off, the car's primitive and the point-mass bound say so before any
    solve (in float32 they run to their iteration limit far from the optimum)."""
    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.raises(ValueError, match=r"car's primitive needs float64: call "
                                             r"jax.config.update\('jax_enable_x64', True\)"):
            min_time_primitive("corner90", num_stages=10, steps_per_stage=1)
        with pytest.raises(ValueError, match=r"point-mass bound needs float64"):
            point_mass_bound("corner90", num_stages=10, steps_per_stage=1)
    finally:
        jax.config.update("jax_enable_x64", True)
