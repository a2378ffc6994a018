"""Execute the notebooks of notebooks/ and store them with their outputs.

    python docs/refresh_notebooks.py [NAME ...]     # all notebooks, or those named
    python docs/refresh_notebooks.py --check        # which stored outputs are out of date

A reader on the web (GitHub, the docs site) sees the outputs stored in the notebook files;
the docs build renders them as stored and never executes a notebook (mkdocs-jupyter with
``execute: false``), and the tests execute every notebook to check it
(tests/test_notebooks.py). This script is the one way outputs get into the files: it runs
each notebook top to bottom in a fresh kernel, in a temporary folder (files a notebook
writes are discarded), with two forced host devices as in the tests (unless XLA_FLAGS is
set), and records a hash of the code cells it ran in the notebook's metadata, so the tests
can tell when the stored outputs no longer belong to the code. Run it after changing a
notebook or what it shows, and commit the result.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import tempfile
import time
from pathlib import Path


ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = ROOT / "notebooks"
KEY = "vehsim"  # notebook metadata: {"vehsim": {"code_sha256": ...}}


def code_hash(nb) -> str:
    """SHA-256 of the sources of the code cells, in order."""
    sources = "\n\0\n".join(c.source for c in nb.cells if c.cell_type == "code")
    return hashlib.sha256(sources.encode()).hexdigest()


def status(nb) -> str:
    """``"no outputs"`` (no code cell has run), ``"current"`` (outputs stored by this
    script for the present code) or ``"stale"`` (outputs of other code, or not stored by
    this script)."""
    code = [c for c in nb.cells if c.cell_type == "code"]
    if not any(c.outputs or c.execution_count for c in code):
        return "no outputs"
    current = nb.metadata.get(KEY, {}).get("code_sha256") == code_hash(nb)
    return "current" if current else "stale"


def refresh(path: Path, timeout: int = 600) -> float:
    """Execute the notebook at `path` and write it back with its outputs; returns the
    execution time [s]."""
    import nbclient
    import nbformat

    nb = nbformat.read(path, as_version=4)
    os.environ["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(ROOT), os.environ.get("PYTHONPATH")) if p)
    os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=2")
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as work:
        nbclient.NotebookClient(nb, timeout=timeout, kernel_name="python3",
                                resources={"metadata": {"path": work}}).execute()
    elapsed = time.perf_counter() - t0
    for cell in nb.cells:
        cell.metadata.pop("execution", None)
    nb.metadata[KEY] = {"code_sha256": code_hash(nb)}
    nbformat.validate(nb)
    tmp = path.with_name(f".{path.name}.tmp")
    nbformat.write(nb, tmp)
    os.replace(tmp, path)
    return elapsed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("names", nargs="*", help="notebook names (default: all)")
    ap.add_argument("--check", action="store_true",
                    help="only report which notebooks have current outputs (exit 1 if not all)")
    args = ap.parse_args(argv)
    paths = sorted(NOTEBOOKS.glob("*.ipynb"))
    if args.names:
        paths = [p for p in paths if p.stem in args.names or p.name in args.names]
    if args.check:
        import nbformat

        states = {p.name: status(nbformat.read(p, as_version=4)) for p in paths}
        for name, state in states.items():
            print(f"{name}: {state}")
        return 0 if all(s == "current" for s in states.values()) else 1
    for p in paths:
        print(f"{p.name}: executing...", file=sys.stderr, flush=True)
        print(f"{p.name}: refreshed in {refresh(p):.1f} s", file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
