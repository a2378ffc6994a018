"""The code base passes the project's ruff configuration (pyproject.toml)."""

import shutil
import subprocess
from pathlib import Path

import pytest


@pytest.mark.skipif(shutil.which("ruff") is None, reason="ruff not installed")
def test_ruff_clean():
    root = Path(__file__).parent.parent
    out = subprocess.run(["ruff", "check", str(root)], capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
