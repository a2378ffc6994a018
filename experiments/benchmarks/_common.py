"""Shared timing helpers for the benchmarks (JSON lines on stdout)."""

from __future__ import annotations

import json
import sys
import time

import jax


def emit(**record) -> None:
    """Print one JSON line (the benchmark's output format)."""
    print(json.dumps(record), flush=True)


def block(x):
    return jax.tree_util.tree_map(lambda a: a.block_until_ready() if hasattr(a, "block_until_ready")
                                  else a, x)


def best_time(fn, *args, repeats: int = 5) -> float:
    """Best wall time of ``fn(*args)`` over ``repeats`` runs (after one warm-up call)."""
    block(fn(*args))
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        block(fn(*args))
        best = min(best, time.perf_counter() - t0)
    return best


def cpu_time(fn, *args, repeats: int = 5) -> float:
    """Process CPU time [s] of one call of ``fn(*args)`` (mean of ``repeats`` after one warm-up
    call, all threads together): XLA may spread one large fused loop over the cores where
    NumPy runs on one, so wall times alone can hide a difference in the cores used."""
    block(fn(*args))
    c0 = time.process_time()
    for _ in range(repeats):
        block(fn(*args))
    return (time.process_time() - c0) / repeats


def compile_time(fn, *args) -> float:
    t0 = time.perf_counter()
    block(fn(*args))
    return time.perf_counter() - t0


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)
