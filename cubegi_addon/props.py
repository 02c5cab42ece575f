"""CubeGI's settings on scenes (``Scene.cubegi``) and probe grid objects (``Object.cubegi``)."""

import bpy
from bpy.props import BoolProperty, FloatProperty, IntProperty, IntVectorProperty, PointerProperty, StringProperty

from ..cubegi_engine.bake import MAX_CUBE_SIZE, MIN_CUBE_SIZE


class CubeGISceneSettings(bpy.types.PropertyGroup):
    cube_size: IntProperty(
        name="Cube-Map Size",
        description="Edge length in texels of each probe's cube-map faces",
        default=32,
        min=MIN_CUBE_SIZE,
        max=MAX_CUBE_SIZE,
    )
    bounces: IntProperty(name="Bounces", description="Number of indirect bounces to compute", default=5, min=0, max=1000)
    visibility: BoolProperty(
        name="Probe Visibility",
        description="Leave out, per vertex, the probes that cannot see it (stops light leaking through thin walls)",
        default=True,
    )
    tolerance: FloatProperty(
        name="Tolerance",
        description="Stop once the estimated missing share of the indirect light is below this; Bounces is the cap (0: run all bounces)",
        default=0.0, min=0.0, max=0.5, subtype="FACTOR",
    )
    add_tail: BoolProperty(
        name="Add Tail", description="Add the estimated light after the last bounce to CubeGI (the total)", default=True
    )
    last_report: StringProperty(name="Last Report", description="JSON report of the last bake", default="")


class CubeGIObjectSettings(bpy.types.PropertyGroup):
    is_probe_grid: BoolProperty(name="Probe Grid", description="This Empty's cube is a CubeGI probe grid", default=False)
    resolution: IntVectorProperty(
        name="Resolution", description="Probes along X, Y and Z", size=3, default=(4, 4, 2), min=1, max=256
    )


classes = (CubeGISceneSettings, CubeGIObjectSettings)
_register, _unregister = bpy.utils.register_classes_factory(classes)


def register():
    _register()
    bpy.types.Scene.cubegi = PointerProperty(type=CubeGISceneSettings)
    bpy.types.Object.cubegi = PointerProperty(type=CubeGIObjectSettings)


def unregister():
    del bpy.types.Object.cubegi
    del bpy.types.Scene.cubegi
    _unregister()
