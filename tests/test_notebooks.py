"""Execute every notebook in notebooks/; each one asserts its own results in its cells."""

import os
from pathlib import Path

import pytest


NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))
# the corner90 notebook solves the tests' primitive (30 segments): on the worker of the
# corner90 tests it loads the compiled programs from the run's cache (tests/conftest.py)
GROUPS = {"optimal_cornering.ipynb": "corner90_min_time"}


@pytest.mark.skipif(not NOTEBOOKS, reason="no notebooks yet")
@pytest.mark.parametrize("path", [
    pytest.param(p, marks=[pytest.mark.xdist_group(GROUPS[p.name])] if p.name in GROUPS else [])
    for p in NOTEBOOKS], ids=lambda p: p.name)
def test_notebook_executes_and_asserts_its_results(path, tmp_path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    nb = nbformat.read(path, as_version=4)
    code = [c.source for c in nb.cells if c.cell_type == "code"]
    assert any("assert " in src for src in code), f"{path.name} asserts nothing"
    root = str(path.parent.parent)
    monkeypatch.setenv("PYTHONPATH", root + os.pathsep + os.environ.get("PYTHONPATH", ""))
    client = nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()  # raises CellExecutionError (with the failing cell) on any error
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if o.get("output_type") == "error"]
    assert not errors
