"""The source tree is clean under ruff with the settings in pyproject.toml (pyflakes,
pycodestyle, import order), and the engine under mypy."""

import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def test_ruff_finds_nothing():
    pytest.importorskip("ruff", reason="ruff is installed by scripts/setup.sh (requirements-dev.txt)")
    r = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", ROOT], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr


def test_mypy_finds_nothing_in_the_engine():
    pytest.importorskip("mypy", reason="mypy is installed by scripts/setup.sh (requirements-dev.txt)")
    r = subprocess.run([sys.executable, "-m", "mypy", "--config-file", os.path.join(ROOT, "pyproject.toml")], cwd=ROOT,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr


# What ships stays readable: modules of at most MAX_MODULE_LINES lines, functions of at most
# MAX_FUNCTION_LINES (their docstrings included).
MAX_MODULE_LINES, MAX_FUNCTION_LINES = 500, 80


def test_no_shipped_module_or_function_is_too_long():
    import ast

    long = []
    for package in ("cubegi_engine", "cubegi_addon"):
        folder = os.path.join(ROOT, package)
        for name in sorted(f for f in os.listdir(folder) if f.endswith(".py")):
            path = os.path.join(folder, name)
            source = open(path).read()
            if len(source.splitlines()) > MAX_MODULE_LINES:
                long.append(f"{package}/{name}: {len(source.splitlines())} lines")
            for node in ast.walk(ast.parse(source, path)):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES:
                    long.append(f"{package}/{name}: {node.name} is {node.end_lineno - node.lineno + 1} lines")
    assert long == [], long
