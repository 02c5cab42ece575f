"""Operators: bake (``cubegi.bake``), clear (``cubegi.clear``), add a probe grid."""

import json

import bpy
from bpy.props import BoolProperty, FloatProperty, IntProperty, IntVectorProperty, StringProperty

from ..cubegi_engine.bake import BakeSettings, run
from . import attributes, pipeline


def _settings_from(op, scene):
    s = scene.cubegi
    def pick(name):
        return getattr(op, name) if op.properties.is_property_set(name) else getattr(s, name)
    tolerance = pick("tolerance")
    return BakeSettings(
        cube_size=pick("cube_size"), bounces=pick("bounces"), visibility=pick("visibility"),
        tolerance=tolerance if tolerance > 0 else None, add_tail=pick("add_tail"),
    )


class CUBEGI_OT_bake(bpy.types.Operator):
    """Bake direct and indirect diffuse light into CubeGI colour attributes on every mesh"""

    bl_idname = "cubegi.bake"
    bl_label = "Bake CubeGI"
    bl_options = {"REGISTER", "UNDO"}

    cube_size: IntProperty(name="Cube-Map Size", description="Cube-map face size (default: the scene's setting)", default=32, min=1)
    bounces: IntProperty(name="Bounces", description="Indirect bounces (default: the scene's setting)", default=5, min=0)
    visibility: BoolProperty(name="Probe Visibility", description="Leave out probes that cannot see a vertex", default=True)
    grid: IntVectorProperty(name="Grid", description="Probes along X, Y, Z (default: probe grid object, or fitted)", size=3, default=(0, 0, 0))
    tolerance: FloatProperty(
        name="Tolerance", description="Stop once the estimated missing share of the indirect light is below this (0: run all bounces)",
        default=0.0, min=0.0, max=0.5,
    )
    add_tail: BoolProperty(name="Add Tail", description="Add the estimated light after the last bounce to CubeGI", default=True)
    reference_samples: IntProperty(
        name="Cycles Reference Samples", description="Also bake a Cycles reference with this many samples (0: none)", default=0, min=0
    )
    lit: BoolProperty(name="Lit Colour", description="Also write CubeGI_lit, albedo times all light", default=False)
    report_path: StringProperty(name="Report", description="Write the bake report (JSON) to this file", default="", subtype="FILE_PATH")

    @classmethod
    def poll(cls, context):
        if context.scene is None:
            cls.poll_message_set("No scene to bake")
            return False
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to bake")
            return False
        return True

    def execute(self, context):
        settings = _settings_from(self, context.scene)
        resolution = tuple(self.grid) if any(self.grid) else None
        try:
            report = run(
                pipeline.bake_steps(context, settings, resolution, lit=self.lit, reference_samples=self.reference_samples or None)
            )
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        for warning in report["warnings"]:
            self.report({"WARNING"}, f"CubeGI: {warning}")
        context.scene.cubegi.last_report = json.dumps(report)
        if self.report_path:
            pipeline.write_report(report, bpy.path.abspath(self.report_path))
        self.report(
            {"INFO"},
            f"CubeGI: baked {len(report['scene']['meshes_baked'])} meshes, {len(report['bounces'])} bounces in "
            f"{report['total_seconds']:.2f} s; estimated missing indirect light {100 * report['estimated_remaining_error']:.2g}%"
            + (" (added as the tail)" if report["tail"].get("added") else ""),
        )
        return {"FINISHED"}


class CUBEGI_OT_clear(bpy.types.Operator):
    """Remove CubeGI's colour attributes from every mesh in the scene"""

    bl_idname = "cubegi.clear"
    bl_label = "Clear CubeGI"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        seen, removed = set(), 0
        for ob in context.scene.objects:
            if ob.type == "MESH" and ob.data.name not in seen and ob.data.library is None:
                seen.add(ob.data.name)
                removed += len(attributes.clear(ob.data, attributes.is_any))
        self.report({"INFO"}, f"CubeGI: removed {removed} attributes")
        return {"FINISHED"}


class CUBEGI_OT_add_probe_grid(bpy.types.Operator):
    """Add a CubeGI probe grid fitted to the visible geometry"""

    bl_idname = "cubegi.add_probe_grid"
    bl_label = "CubeGI Probe Grid"
    bl_options = {"REGISTER", "UNDO"}

    resolution: IntVectorProperty(name="Resolution", description="Probes along X, Y, Z", size=3, default=(4, 4, 2), min=1, max=256)

    def execute(self, context):
        bounds = pipeline.world_bounds([ob for ob in context.visible_objects if ob.type == "MESH"])
        lo, hi = bounds if bounds is not None else ((-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))
        pipeline.new_probe_grid(context.collection, lo, hi, self.resolution)
        return {"FINISHED"}


def menu_add(self, context):
    self.layout.operator(CUBEGI_OT_add_probe_grid.bl_idname, icon="LIGHTPROBE_VOLUME")


classes = (CUBEGI_OT_bake, CUBEGI_OT_clear, CUBEGI_OT_add_probe_grid)
_register, _unregister = bpy.utils.register_classes_factory(classes)


def register():
    _register()
    bpy.types.VIEW3D_MT_add.append(menu_add)


def unregister():
    bpy.types.VIEW3D_MT_add.remove(menu_add)
    _unregister()
