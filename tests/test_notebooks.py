"""Execute every notebook in notebooks/ (each one asserts its own results in its cells), and
check that the outputs stored in the files, which the web and the docs site show, belong to
the present code (they are written by docs/refresh_notebooks.py only)."""

import importlib.util
import os
from pathlib import Path

import pytest


ROOT = Path(__file__).parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))
# the corner90 notebook solves the tests' primitive (30 segments): on the worker of the
# corner90 tests it loads the compiled programs from the run's cache (tests/conftest.py)
GROUPS = {"optimal_cornering.ipynb": "corner90_min_time"}


def _refresh_module():
    spec = importlib.util.spec_from_file_location("refresh_notebooks",
                                                  ROOT / "docs" / "refresh_notebooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


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


@pytest.mark.skipif(not NOTEBOOKS, reason="no notebooks yet")
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_stored_outputs_belong_to_the_code(path):
    """A notebook stored with outputs was executed by the refresh script for exactly its
    present code cells, without errors; one stored without any output is reported (skipped,
    which fails under CI) until the script is run."""
    nbformat = pytest.importorskip("nbformat")
    refresh = _refresh_module()
    nb = nbformat.read(path, as_version=4)
    state = refresh.status(nb)
    if state == "no outputs":
        pytest.skip(f"{path.name} is stored without outputs: python docs/refresh_notebooks.py")
    assert state == "current", (f"{path.name}: the stored outputs are not those of its code; "
                                "run python docs/refresh_notebooks.py")
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert [c.execution_count for c in code] == list(range(1, len(code) + 1))
    assert not [o for c in code for o in c.outputs if o.output_type == "error"]
