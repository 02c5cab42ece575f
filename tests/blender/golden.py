"""Bakes whose attributes are kept in ``tests/blender/data/golden_bakes.npz``: the demo Room and every
benchmark scene, baked through the operator with fixed settings.

The file holds the values of the release that wrote it; a restructuring of the code must
reproduce them (``tests/blender/test_golden.py``). A change that is meant to change the light
rewrites the file on purpose, with the reason in its commit:

    .venv/bin/python tests/blender/golden.py
"""

import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
PATH = os.path.join(HERE, "data", "golden_bakes.npz")
SCENES = ("room", "cornell", "courtyard", "white_box_0.95", "thin_wall")
LAYERS = ("CubeGI_direct", "CubeGI", "CubeGI_total", "CubeGI_bounce_1")
# Cheap but complete: a grid with probes inside and outside geometry, three bounces and
# the solved tail (the closed white box needs it), lit colour on.
SETTINGS = dict(grid=(5, 5, 3), cube_size=16, bounces=3, lit="ALL")


def bake_scene(name):
    """Build one benchmark scene, bake it, return ``{"<object>:<layer>": (v, 3) float32}``."""
    import bpy

    from benchmarks.sweep import SCENES

    SCENES[name]()
    assert bpy.ops.cubegi.bake(**SETTINGS) == {"FINISHED"}
    out = {}
    for ob in sorted(bpy.context.scene.objects, key=lambda o: o.name):
        if ob.type != "MESH":
            continue
        for layer in LAYERS + ("CubeGI_lit",):
            attr = ob.data.attributes[layer]
            data = np.empty(len(attr.data) * 4, dtype=np.float32)
            attr.data.foreach_get("color", data)
            out[f"{name}/{ob.name}:{layer}"] = data.reshape(-1, 4)[:, :3].copy()
    return out


def main():
    import tempfile

    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="cubegi-golden-"))
    sys.path.insert(0, os.path.dirname(os.path.dirname(HERE)))
    from tools import load_extension

    load_extension()
    arrays = {}
    for name in SCENES:
        arrays.update(bake_scene(name))
    tmp = PATH + ".tmp.npz"
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, PATH)
    print(f"wrote {PATH}: {len(arrays)} arrays, {os.path.getsize(PATH) / 1024:.0f} KiB")


if __name__ == "__main__":
    main()
