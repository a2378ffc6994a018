"""A guard against a thread-pool deadlock of XLA's CPU runtime in jaxlib 0.10.

jaxlib 0.10's CPU runtime schedules independent operations of one program concurrently (its
"concurrency-optimised scheduler"). A program with two independent batched LAPACK calls,
for example ``jax.vmap`` of a function that solves two linear systems, can then wait forever
on a machine with few cores: each call runs on a worker of the intra-op thread pool and
waits for work it queued on the same pool (two cores: two workers, both waiting). The
distributed 2D tire's steady state (one solve per axis) is such a program.

`guard_cpu_scheduler` switches that scheduler off through ``XLA_FLAGS`` before JAX starts
its CPU backend (it has no effect once the backend runs, and none on GPUs). A user who
sets ``--xla_cpu_enable_concurrency_optimized_scheduler`` in ``XLA_FLAGS`` keeps their
choice. Other jaxlib versions are left alone: XLA refuses flags it does not know.
"""

import os


FLAG = "--xla_cpu_enable_concurrency_optimized_scheduler"


def _affected(version: str) -> bool:
    try:
        major, minor = (int(p) for p in version.split(".")[:2])
    except ValueError:
        return False
    return (major, minor) == (0, 10)


def guard_cpu_scheduler(environ=os.environ) -> bool:
    """Add ``FLAG=false`` to ``XLA_FLAGS`` for the affected jaxlib; True if it was added."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        affected = _affected(version("jaxlib"))
    except PackageNotFoundError:
        return False
    flags = environ.get("XLA_FLAGS", "")
    if not affected or FLAG in flags:
        return False
    environ["XLA_FLAGS"] = f"{flags} {FLAG}=false".strip()
    return True
