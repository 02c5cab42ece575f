"""A path-traced reference: Cycles' Diffuse bake to vertex colours, per pass.

Cycles writes, with the colour pass off, the diffuse light a white surface reflects
(irradiance / pi), the same quantity as CubeGI's attributes. Every render and bake setting,
the selection and active colour attributes are put back afterwards.
"""

import bpy

from . import attributes

REF_NAMES = {"DIRECT": "CubeGI_ref_direct", "INDIRECT": "CubeGI_ref_indirect"}
_TMP = "CubeGI_ref_tmp"


def bake_reference(context, meshes, passes=("DIRECT", "INDIRECT"), samples=128, seed=0):
    """Bake Cycles' ``passes`` into ``CubeGI_ref_*`` POINT attributes of ``meshes``' objects.

    meshes: the mesh objects to bake. Returns ``{pass: {object name: (v, 3) array}}``.
    """
    scene = context.scene
    view_layer = context.view_layer
    saved = {
        "engine": scene.render.engine,
        "samples": scene.cycles.samples,
        "seed": scene.cycles.seed,
        "device": scene.cycles.device,
        "use_pass_color": scene.render.bake.use_pass_color,
        "target": scene.render.bake.target,
        "selected": [o for o in view_layer.objects if o.select_get()],
        "active": view_layer.objects.active,
        "active_colour": {o.name: o.data.color_attributes.active_color_name for o in meshes},
    }
    out = {p: {} for p in passes}
    try:
        scene.render.engine = "CYCLES"
        scene.cycles.samples = samples
        scene.cycles.seed = seed
        scene.cycles.device = "CPU"
        scene.render.bake.use_pass_color = False
        scene.render.bake.target = "VERTEX_COLORS"
        for o in view_layer.objects:
            o.select_set(False)
        for o in meshes:
            attr = o.data.color_attributes.new(_TMP, "FLOAT_COLOR", "POINT")
            o.data.color_attributes.active_color = attr
            o.select_set(True)
        view_layer.objects.active = meshes[0]
        for p in passes:
            bpy.ops.object.bake(type="DIFFUSE", pass_filter={p}, target="VERTEX_COLORS", use_clear=True)
            for o in meshes:
                out[p][o.name] = attributes.read(o.data, _TMP)
    finally:
        for o in meshes:
            tmp = o.data.color_attributes.get(_TMP)
            if tmp is not None:
                o.data.color_attributes.remove(tmp)
            name = saved["active_colour"][o.name]
            if name and name in o.data.color_attributes:
                o.data.color_attributes.active_color = o.data.color_attributes[name]
        scene.render.engine = saved["engine"]
        scene.cycles.samples = saved["samples"]
        scene.cycles.seed = saved["seed"]
        scene.cycles.device = saved["device"]
        scene.render.bake.use_pass_color = saved["use_pass_color"]
        scene.render.bake.target = saved["target"]
        for o in view_layer.objects:
            o.select_set(o in saved["selected"])
        view_layer.objects.active = saved["active"]
    return out
