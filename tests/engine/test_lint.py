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


def _defined(path):
    """The names a module's source defines at its top level (functions, classes, assignments,
    imports)."""
    import ast

    names = set()
    for node in ast.parse(open(path).read()).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for t in targets:
                names.update(n.id for n in ast.walk(t) if isinstance(n, ast.Name))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return names


def test_every_import_of_the_benchmarks_and_tools_names_what_is_there():
    """The benchmarks and the tools import the tree inside their ``main`` (after bpy loads),
    where no test reaches every line: each ``from cubegi.X import Y`` (and ``from tools`` /
    ``from benchmarks``) must name a module file, or a name that module defines."""
    import ast

    packages = {"cubegi": "", "tools": "tools", "benchmarks": "benchmarks"}
    missing = []
    for folder in ("benchmarks", "tools"):
        for name in sorted(f for f in os.listdir(os.path.join(ROOT, folder)) if f.endswith(".py")):
            path = os.path.join(ROOT, folder, name)
            for node in ast.walk(ast.parse(open(path).read())):
                if not isinstance(node, ast.ImportFrom) or node.level or not node.module:
                    continue
                head, *rest = node.module.split(".")
                if head not in packages:
                    continue
                base = os.path.join(ROOT, packages[head], *rest)
                module = base + ".py" if os.path.isfile(base + ".py") else os.path.join(base, "__init__.py")
                if not os.path.isfile(module):
                    missing.append(f"{folder}/{name}:{node.lineno}: no module {node.module}")
                    continue
                defined = _defined(module)
                for alias in node.names:
                    if alias.name not in defined and not os.path.isfile(os.path.join(base, alias.name + ".py")):
                        missing.append(f"{folder}/{name}:{node.lineno}: {node.module} has no {alias.name}")
    assert missing == [], missing
