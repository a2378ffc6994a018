"""Running a test's CasADi part in a fresh Python process.

CasADi (the IPOPT and do-mpc peers of the benchmarks) brings its own native libraries, among
them its own OpenMP runtime. The test workers do not load it: a worker with CasADi loaded
aborted inside XLA's compiler late in a run, twice, and the run then stalled. The peer's
solve, or a whole check against it, runs in a spawned process instead (about five seconds
to start), configured as the suite configures JAX, and returns picklable results;
an assertion raised there fails the test here with its message."""

import importlib.util
import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import pytest


def _configure():
    # the suite's own set-up (tests/conftest.py: XLA flags, x64, rank promotion, two CPU
    # devices, the run's compilation cache, which the environment already names), run by
    # importing it: tests/ is on the spawned process's path, as on its parent's
    importlib.import_module("conftest")


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
