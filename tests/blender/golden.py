"""Bakes whose attributes are kept in ``tests/blender/data/golden_bakes.npz``: the demo Room and every
benchmark scene, baked through the operator with fixed settings.

The file holds the values of the release that wrote it; a restructuring of the code must
reproduce them (``tests/blender/test_golden.py``). A change that is meant to change the light
rewrites the file on purpose, with the reason in its commit:

    .venv/bin/python tests/blender/golden.py          # every scene
    .venv/bin/python tests/blender/golden.py --add    # only scenes the file does not hold yet
"""

import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
PATH = os.path.join(HERE, "data", "golden_bakes.npz")
SCENES = ("room", "cornell", "courtyard", "white_box_0.95", "thin_wall",
          "cornell@turned", "courtyard@turned", "white_box_0.95@turned", "thin_wall@turned")
# A scene "@turned" is the benchmark scene turned off the grid's axes (0.2 rad about X, then
# 0.3 about the world's Z): its walls meet the probes' and the near field's rays at every angle, where an
# axis-aligned scene's meet them square on (a change to the ray kernels shows there first).
TURN = ((0.3, "Z"), (0.2, "X"))
LAYERS = ("CubeGI_direct", "CubeGI", "CubeGI_total", "CubeGI_bounce_1")
# Cheap but complete: a grid with probes inside and outside geometry, three bounces and
# the solved tail (the closed white box needs it), lit colour on.
SETTINGS = dict(grid=(5, 5, 3), cube_size=16, bounces=3, lit="ALL")


def bake_scene(name):
    """Build one benchmark scene, bake it, return ``{"<object>:<layer>": (v, 3) float32}``."""
    import bpy
    import mathutils

    from benchmarks.sweep import SCENES

    base, _, turned = name.partition("@")
    SCENES[base]()
    if turned:
        turn = mathutils.Matrix.Identity(4)
        for angle, axis in TURN:
            turn = turn @ mathutils.Matrix.Rotation(angle, 4, axis)
        bpy.context.view_layer.update()  # the builders set locations: their world matrices follow here
        for ob in bpy.context.scene.objects:
            if ob.parent is None:
                ob.matrix_world = turn @ ob.matrix_world
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


def main(add=False):
    """Bake every scene and write the file; with ``add`` (``--add``), bake only the scenes the
    file does not hold yet and add them, the kept values of the others as they are."""
    import tempfile

    os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="cubegi-golden-"))
    sys.path.insert(0, os.path.dirname(os.path.dirname(HERE)))
    from tools import load_extension

    load_extension()
    import bpy

    arrays = dict(np.load(PATH)) if add and os.path.exists(PATH) else {}
    for name in SCENES:
        if add and any(k.startswith(name + "/") for k in arrays):
            continue
        bpy.ops.wm.read_factory_settings(use_empty=True)
        arrays.update(bake_scene(name))
    tmp = PATH + ".tmp.npz"
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, PATH)
    print(f"wrote {PATH}: {len(arrays)} arrays, {os.path.getsize(PATH) / 1024:.0f} KiB")


if __name__ == "__main__":
    main(add="--add" in sys.argv[1:])
