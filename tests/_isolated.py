"""Running a test's CasADi part in a fresh Python process.

CasADi (the IPOPT and do-mpc peers of the benchmarks) brings its own native libraries, among
them its own OpenMP runtime. The test workers do not load it: a worker with CasADi loaded
aborted inside XLA's compiler late in a run, twice, and the run then stalled. The peer's
solve, or a whole check against it, runs in a spawned process instead (about five seconds
to start), configured as the suite configures JAX, and returns picklable results;
an assertion raised there fails the test here with its message."""

import importlib.util
import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

import pytest


def _configure():
    # the environment (XLA_FLAGS, the compilation cache, two CPU devices) is inherited;
    # these are the suite's `jax.config` settings (tests/conftest.py)
    import jax

    jax.config.update("jax_num_cpu_devices", 2)
    jax.config.update("jax_compilation_cache_dir", os.environ["VEHSIM_TEST_JAX_CACHE"])
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_numpy_rank_promotion", "raise")


def require_casadi():
    """Skip (under CI: fail) where CasADi is not installed, without importing it."""
    if importlib.util.find_spec("casadi") is None:
        pytest.skip("casadi is not installed (pip install -e '.[test]')")


def in_subprocess(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` in a fresh spawned process; ``fn`` must be importable by name
    (a module-level function of a test module)."""
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=context, initializer=_configure) as pool:
        return pool.submit(fn, *args, **kwargs).result()
