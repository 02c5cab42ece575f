"""The source tree is clean under ruff with the settings in pyproject.toml (pyflakes,
pycodestyle, import order)."""

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_ruff_finds_nothing():
    pytest.importorskip("ruff", reason="ruff is installed by scripts/setup.sh (requirements-dev.txt)")
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", ROOT], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
