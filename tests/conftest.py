"""Test conventions (after equinox/diffrax): float64, strict rank promotion, small problems."""

import os


# Two host devices (the sharding tests), and LLVM's backend optimisation off: the suite is
# bound by XLA compile time, not run time (docs/performance.md). Benchmarks and
# `vehsim reproduce` keep XLA's default.
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2 "
                                   "--xla_backend_optimization_level=0")

import jax  # noqa: E402


jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")
