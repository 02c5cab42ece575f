"""The CubeGI tab of the 3D view's sidebar: settings, Bake, Clear and the last bake's report."""

import json

import bpy

from ..cubegi_engine.report import summary_lines


def report_lines(scene):
    """The last bake's report as lines of text (none before the first bake)."""
    text = scene.cubegi.last_report
    if not text:
        return []
    try:
        return summary_lines(json.loads(text))
    except (ValueError, KeyError, TypeError):
        return ["the last report cannot be read; bake again"]


class CUBEGI_PT_bake(bpy.types.Panel):
    bl_label = "CubeGI"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "CubeGI"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.cubegi
        col = layout.column()
        col.prop(settings, "cube_size")
        col.prop(settings, "bounces")
        col.prop(settings, "tolerance")
        col.prop(settings, "add_tail")
        col.prop(settings, "visibility")
        row = layout.row(align=True)
        row.operator("cubegi.bake", icon="RENDER_STILL")
        row.operator("cubegi.clear", icon="TRASH")
        lines = report_lines(context.scene)
        if lines:
            box = layout.box()
            box.label(text="Last bake", icon="INFO")
            for line in lines:
                box.label(text=line.strip())


classes = (CUBEGI_PT_bake,)
register, unregister = bpy.utils.register_classes_factory(classes)
