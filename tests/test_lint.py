"""The code base passes the project's ruff configuration (pyproject.toml)."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest


@pytest.mark.skipif(importlib.util.find_spec("ruff") is None, reason="ruff not installed")
def test_ruff_clean():
    root = Path(__file__).parent.parent
    out = subprocess.run([sys.executable, "-m", "ruff", "check", str(root)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr
