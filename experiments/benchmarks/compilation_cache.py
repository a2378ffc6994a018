"""Benchmark `compilation_cache`: a notebook's second run with `vehsim.enable_compilation_cache`.

Each notebook runs top to bottom in a fresh kernel: without the cache (``no_cache_s``),
then with the cache on in an empty folder (``first_run_s``: compiles and writes) and again
with the same folder (``second_run_s``: loads what was written). The cache is switched on by
a first cell ``vehsim.enable_compilation_cache(folder)``; nothing else changes. JAX does not
write programs that contain host callbacks, and equinox's runtime checks (``eqx.error_if``,
inside diffrax's solves) are host callbacks unless ``EQX_ON_ERROR=nan``; so the cached runs
are made twice, with equinox's default (``eqx_on_error: "raise"``) and with
``EQX_ON_ERROR=nan`` in the kernel's environment. Times are wall seconds of ``nbclient``
execution, kernel start included. The headline ``ratio`` is first run / second run (> 1:
the cache helps), beside the folder's size. Every run is repeated ``--repeats`` times (a
new folder for each first run) and the least kept; ``*_cpu_s`` is the kernel process's CPU
time (user + system), which a loaded machine disturbs less than the wall time.

    PYTHONPATH=. python experiments/benchmarks/compilation_cache.py
        [--notebooks parameter_sweep,combined_slip_tires] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path


ROOT = Path(__file__).resolve().parents[2]


def run(path: Path, cache: Path | None) -> tuple[float, float]:
    """Wall time and kernel CPU time [s] of executing the notebook at `path` in a fresh
    kernel."""
    import nbclient
    import nbformat

    nb = nbformat.read(path, as_version=4)
    if cache is not None:
        nb.cells.insert(0, nbformat.v4.new_code_cell(
            f"import vehsim\nvehsim.enable_compilation_cache({str(cache)!r})"))
    with tempfile.TemporaryDirectory() as work:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        nbclient.NotebookClient(nb, timeout=1200, kernel_name="python3",
                                resources={"metadata": {"path": work}}).execute()
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def best(runs) -> tuple[float, float]:
    return min(w for w, _ in runs), min(c for _, c in runs)


def cached_runs(path: Path, repeats: int):
    """(first runs, second runs, cache entries, cache bytes) over `repeats` fresh folders."""
    first, second, entries, size = [], [], 0, 0
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as folder:
            cache = Path(folder) / "cache"
            first.append(run(path, cache))
            second.append(run(path, cache))
            entries = sum(1 for f in cache.iterdir() if f.name.endswith("-cache"))
            size = sum(f.stat().st_size for f in cache.rglob("*") if f.is_file())
    return best(first), best(second), entries, size


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--notebooks", default="parameter_sweep,combined_slip_tires")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    os.environ["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    for name in args.notebooks.split(","):
        path = ROOT / "notebooks" / f"{name}.ipynb"
        no_cache = best([run(path, None) for _ in range(args.repeats)])
        for on_error in ("raise", "nan"):
            os.environ["EQX_ON_ERROR"] = on_error
            first, second, entries, size = cached_runs(path, args.repeats)
            del os.environ["EQX_ON_ERROR"]
            print(json.dumps(dict(
                name="compilation_cache", notebook=name, eqx_on_error=on_error,
                no_cache_s=round(no_cache[0], 2), first_run_s=round(first[0], 2),
                second_run_s=round(second[0], 2), ratio=round(first[0] / second[0], 2),
                saved_s=round(first[0] - second[0], 2), no_cache_cpu_s=round(no_cache[1], 2),
                first_run_cpu_s=round(first[1], 2), second_run_cpu_s=round(second[1], 2),
                cpu_ratio=round(first[1] / second[1], 2), cache_entries=entries,
                cache_mb=round(size / 2**20, 2), repeats=args.repeats,
                xla_flags=os.environ.get("XLA_FLAGS", ""), load_average=os.getloadavg())),
                flush=True)
            print(f"{name} (EQX_ON_ERROR={on_error}): {no_cache[0]:.1f} s without cache, "
                  f"{first[0]:.1f} s first run, {second[0]:.1f} s second run", file=sys.stderr,
                  flush=True)


if __name__ == "__main__":
    main()
