"""Maneuver primitives on the benchmark problems (coarse grids to keep CI small)."""

import math

import jax.numpy as jnp
import numpy as np
import pytest
from optimal_cache import M, corner90_min_time

from vehsim.optimal.ip import IPOptions
from vehsim.optimal.primitives import (
    max_exit_primitive,
    min_time_primitive,
    point_mass_bound,
)
from vehsim.optimal.shooting import DELTA_MAX


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
    # the point mass with |a| <= D g bounds every min-time result from below
    assert float(bound.t_f) < float(prim.t_f)
    assert float(prim.t_f) < 1.25 * float(bound.t_f)
    # boundary conditions of Table 4 (literal heading)
    x0, xT = np.asarray(prim.solution.xs[0]), np.asarray(prim.solution.xs[-1])
    assert abs(x0[0] + 5.0) < 1e-6 and 8.0 <= x0[1] <= 10.0
    assert abs(xT[1] + 5.0) < 1e-6 and 8.0 <= xT[0] <= 10.0
    assert abs(xT[2] + math.pi / 2) < 1e-6


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
def test_other_benchmark_problems_feasible(road, objective):
    f = min_time_primitive if objective == "min-time" else max_exit_primitive
    prim = f(road, num_stages=M, steps_per_stage=1, options=IPOptions(max_iter=400))
    _check_solution(prim)
    if objective == "max-exit":
        assert float(prim.t_f) <= 4.0 + 1e-6
        assert float(jnp.hypot(prim.solution.xs[-1, 3], prim.solution.xs[-1, 4])) > 5.0
