"""One coarse corner90 min-time primitive shared by the optimal-driving test modules
(tests/test_optimal_primitives.py and tests/test_optimal_replay.py): building it (compile and
solve) is the slowest step of both, so it is built once per test run. Import it as
``from optimal_cache import ...`` everywhere (one module object, one cache)."""

import functools

from vehsim.optimal.ip import IPOptions
from vehsim.optimal.primitives import min_time_primitive


M = 30  # coarse: the benchmark uses >= 150 nodes (docs/maneuvers.md, the reproduce section)


@functools.cache
def corner90_min_time():
    """corner90 min-time on M segments x 1 RK4 step (a `Primitive`; treat it as read-only)."""
    return min_time_primitive("corner90", num_stages=M, steps_per_stage=1,
                              options=IPOptions(max_iter=300))


@functools.cache
def corner90_min_time_nodes_only():
    """The same problem with the corridor at the nodes only (no corner clearance)."""
    return min_time_primitive("corner90", num_stages=M, steps_per_stage=1,
                              options=IPOptions(max_iter=300), corner_clearance=False)
