"""The layers: the engine imports without bpy; no module imports one above its layer; the
import graph has no circle."""

import ast
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PACKAGES = ("cubegi_engine", "cubegi_addon")


def _modules(package):
    folder = os.path.join(ROOT, package)
    return sorted(f[:-3] for f in os.listdir(folder) if f.endswith(".py"))


def _imports(package, module):
    """The CubeGI modules ``package.module`` imports (anywhere in it), as "package.module"."""
    path = os.path.join(ROOT, package, f"{module}.py")
    tree = ast.parse(open(path).read(), path)
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level:
            base = package if node.level == 1 else (node.module or "").split(".")[0]
            if node.level == 1 and node.module:
                found.add(f"{package}.{node.module.split('.')[0]}")
            elif node.level == 1:
                found.update(f"{package}.{a.name}" for a in node.names)
            elif node.module and "." in node.module:
                found.add(".".join(node.module.split(".")[:2]))
            else:
                found.update(f"{base}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "import_module" and node.args:
            arg = node.args[0]
            if isinstance(arg, ast.Constant) and str(arg.value).startswith("."):
                found.add(f"{package}.{arg.value[1:]}")
    return {m for m in found if m.split(".")[0] in PACKAGES and not m.endswith(".__init__")}


def _graph():
    return {f"{p}.{m}": _imports(p, m) for p in PACKAGES for m in _modules(p) if m != "__init__"}


def test_the_engine_imports_without_bpy():
    modules = [f"cubegi.cubegi_engine.{m}" for m in _modules("cubegi_engine") if m not in ("__init__", "__main__")]
    code = (
        "import sys; sys.modules['bpy'] = None; sys.modules['gpu'] = None; sys.modules['mathutils'] = None\n"
        "from tools import load_extension\n"
        f"import {', '.join(modules)}\n"
        "import cubegi.cubegi_addon, cubegi.cubegi_addon.files\n"  # the add-on package and file checks: no bpy either
    )
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True)


def test_no_module_reaches_up_a_layer():
    graph = _graph()
    assert graph["cubegi_addon.pipeline"] >= {"cubegi_engine.bake", "cubegi_addon.grid_objects"}  # the parser sees imports
    for module, imports in graph.items():
        if module.startswith("cubegi_engine.") and module != "cubegi_engine.__main__":
            assert not any(i.startswith("cubegi_addon.") for i in imports), (module, imports)


def test_what_ships_imports_nothing_that_stays_in_the_source_tree():
    """tools/ and benchmarks/ are left out of the extension's zip (by folder): a shipped
    module that imported them would fail in an installed Blender."""
    assert _graph()["cubegi_addon.cli"]  # the walk sees the add-on's imports
    for package in PACKAGES:
        for module in _modules(package):
            if (package, module) == ("cubegi_engine", "__main__"):  # the source tree's entry point, forwards to tools/
                continue
            path = os.path.join(ROOT, package, f"{module}.py")
            for node in ast.walk(ast.parse(open(path).read(), path)):
                names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                    [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
                assert not [n for n in names if n.split(".")[0] in ("tools", "benchmarks")], (path, names)


def test_the_import_graph_has_no_circle():
    graph = _graph()
    state = {}

    def visit(m, path):
        if state.get(m) == "done":
            return
        assert state.get(m) != "open", " -> ".join(path + [m])
        state[m] = "open"
        for n in sorted(graph.get(m, ())):
            visit(n, path + [m])
        state[m] = "done"

    for m in graph:
        visit(m, [])


def test_the_engine_run_as_a_module_outside_the_source_tree_says_where_it_runs(tmp_path):
    """``cubegi_engine/__main__.py`` ships with the engine; ``tools/`` does not. Run from an
    installed copy, it refuses with one line (status 2) instead of a traceback."""
    import shutil

    shutil.copytree(os.path.join(ROOT, "cubegi_engine"), tmp_path / "cubegi_engine", ignore=shutil.ignore_patterns("__pycache__"))
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    r = subprocess.run([sys.executable, "-m", "cubegi_engine", "bake", "in.blend", "-o", "out.blend"], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "runs from CubeGI's source tree" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert sorted(os.listdir(tmp_path)) == ["cubegi_engine"]  # nothing written
