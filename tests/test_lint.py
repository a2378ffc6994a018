"""The code base passes the project's ruff configuration (pyproject.toml), and every
dependency it declares is bounded above."""

import importlib.util
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest


@pytest.mark.skipif(importlib.util.find_spec("ruff") is None, reason="ruff not installed")
def test_ruff_clean():
    root = Path(__file__).parent.parent
    out = subprocess.run([sys.executable, "-m", "ruff", "check", str(root)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


def test_every_dependency_has_an_upper_bound():
    """Each requirement of pyproject.toml, runtime and optional, names an upper bound (``<``)
    or one release (``==``), so that a fresh install next month gets the releases the tests
    were written against (README.md, "Dependencies"); the project's own extras excepted."""
    project = tomllib.loads((Path(__file__).parent.parent / "pyproject.toml").read_text())[
        "project"]
    requirements = list(project["dependencies"])
    for extra in project["optional-dependencies"].values():
        requirements += [r for r in extra if not r.startswith(project["name"] + "[")]
    assert len(requirements) > 20
    unbounded = [r for r in requirements if not re.search(r"<|==", r)]
    assert not unbounded, f"requirements without an upper bound: {unbounded}"
