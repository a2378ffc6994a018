"""Test conventions (after equinox/diffrax): float64, strict rank promotion, small problems;
two host devices for the sharding tests, whatever ``XLA_FLAGS`` says; and under CI
(``CI=true``) a skipped test fails, so that a missing test dependency cannot pass unseen.

One compilation cache per test run, on disk: the xdist workers, the notebook kernels and
the command-line runs of tests/test_cli_faces.py are separate processes, and a program one of
them compiled (the corner90 primitive, its replay) is loaded, not compiled again, by the
others. It is a fresh temporary folder, removed at the end, unless ``VEHSIM_TEST_JAX_CACHE``
names one to keep (then later runs reuse it)."""

import atexit
import gc
import os
import shutil
import sys
import tempfile

import pytest


# LLVM's backend optimisation and its expensive passes off: the suite is bound by XLA
# compile time, not run time (docs/performance.md). Added to the user's XLA_FLAGS (kept),
# each unless they set it themselves; benchmarks and `vehsim reproduce` keep XLA's default.
_flags = os.environ.get("XLA_FLAGS", "")
_FAST_COMPILE = (("--xla_backend_optimization_level", "0", 2),
                 ("--xla_llvm_disable_expensive_passes", "true", False))
"""Each flag of the suite's fast compilation, its value here and XLA's default."""
for _flag, _value, _ in _FAST_COMPILE:
    if _flag not in _flags:
        _flags = f"{_flags} {_flag}={_value}".strip()
os.environ["XLA_FLAGS"] = _flags

if not os.environ.get("VEHSIM_TEST_JAX_CACHE"):  # the first process of the run (not a worker)
    os.environ["VEHSIM_TEST_JAX_CACHE"] = tempfile.mkdtemp(prefix="vehsim-test-jax-cache-")
    atexit.register(shutil.rmtree, os.environ["VEHSIM_TEST_JAX_CACHE"], ignore_errors=True)
# this process and its children (workers, kernels, command-line runs) read these when JAX
# starts, so that they compile exactly what this process compiles and share the cache; set
# before vehsim (and so JAX) is imported. VEHSIM_CACHE_DIR too: a command-line run whose
# JAX_COMPILATION_CACHE_DIR a test removed still never writes to the user's own cache
os.environ["JAX_COMPILATION_CACHE_DIR"] = os.environ["VEHSIM_TEST_JAX_CACHE"]
os.environ["VEHSIM_CACHE_DIR"] = os.environ["VEHSIM_TEST_JAX_CACHE"]
os.environ["JAX_NUM_CPU_DEVICES"] = "2"

# importing vehsim guards against jaxlib 0.10's CPU-scheduler deadlock (vehsim/_xla_cpu.py)
# and starts no JAX backend. The command line's code generator (`prefer_fast_compilation`)
# for every process of the run, so that the command-line runs load what the tests compiled
# (the flags key the cache)
from vehsim._xla_cpu import guard_cpu_scheduler, prefer_fast_compilation  # noqa: E402


guard_cpu_scheduler()
prefer_fast_compilation()

import jax  # noqa: E402


# The sharding tests need two host devices: set here, where it wins over any
# --xla_force_host_platform_device_count in XLA_FLAGS (JAX reads it when its backend starts).
jax.config.update("jax_num_cpu_devices", 2)
jax.config.update("jax_compilation_cache_dir", os.environ["VEHSIM_TEST_JAX_CACHE"])
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")


@pytest.fixture(scope="session")
def default_codegen() -> dict:
    """``compiler_options`` that undo the suite's fast compilation for one program (XLA's
    default code generation), for a test whose result depends on rounding, such as a
    closed loop of converged solves."""
    return {flag.lstrip("-"): default for flag, _, default in _FAST_COMPILE}


def in_ci() -> bool:
    """True under CI (``CI`` set to anything but empty, 0, false or no)."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Under CI a skip is a failure (a missing test dependency, a missing data file)."""
    outcome = yield
    report = outcome.get_result()
    if in_ci() and report.skipped and not hasattr(report, "wasxfail"):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else report.longrepr
        report.outcome = "failed"
        report.longrepr = f"skipped under CI (CI=true), which must run every test: {reason}"


@pytest.fixture(autouse=True, scope="module")
def _release_compiled_programs():
    """After each test module, JAX's in-memory caches are dropped (`jax.clear_caches`): a
    worker that kept every program the suite compiled grew past 10 GB and its XLA compiler
    failed late in the run. A program a later module needs again is loaded from the run's
    compilation cache on disk (above), not compiled again."""
    yield
    jax.clear_caches()
    gc.collect()
    # CasADi's native libraries stay out of the test processes (tests/_isolated.py)
    assert "casadi" not in sys.modules, "a test module imported casadi: use tests/_isolated.py"
