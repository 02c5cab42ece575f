"""Small test scenes built in code: the add-on's builders (``cubegi_addon.bench_scenes``).

Looked up on first use, once the ``cubegi`` fixture has loaded the extension.
"""

import importlib

_NAMES = {
    "material": "bench_scenes", "mesh_object": "bench_scenes", "set_world": "bench_scenes",
    "add_light": "bench_scenes", "closed_box": "bench_scenes", "cornell": "bench_scenes", "thin_wall": "bench_scenes", "grid_patch": "demo",
}


def __getattr__(name):
    if name not in _NAMES:
        raise AttributeError(name)
    return getattr(importlib.import_module(f"cubegi.cubegi_addon.{_NAMES[name]}"), name)


def box_mesh(lo, hi, cells, inward):
    return importlib.import_module("cubegi.cubegi_addon.demo").box(lo, hi, cells, inward=inward)
