"""The CubeGI tab of the 3D view's sidebar: grid and bake settings, Bake and Clear, which light
to display, showing it in renders, and the last bake's report."""

import bpy

from ..cubegi_engine.report import BakeReport
from ..cubegi_engine.settings import OPTIONS, SECTIONS
from . import grid_objects


def report_lines(scene):
    """The last bake's report as lines of text (none before the first bake)."""
    text = scene.cubegi.last_report
    if not text:
        return []
    try:
        return BakeReport.from_json(text).summary_lines()
    except (ValueError, KeyError, TypeError):
        return ["the last report cannot be read; bake again"]


class _SidebarTab:
    """Where CubeGI's panels live: the 3D view's sidebar, tab CubeGI."""

    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "CubeGI"


class VIEW3D_PT_cubegi(_SidebarTab, bpy.types.Panel):
    """CubeGI's settings and the Bake and Clear buttons."""

    bl_label = "CubeGI"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        scene = context.scene
        settings = scene.cubegi
        grids = grid_objects.probe_grid_objects(scene)
        ob = context.active_object
        col = layout.column(heading="Probe Grid")
        if ob is not None and ob in grids:
            col.prop(ob.cubegi, "resolution")
            col.prop(ob.cubegi, "show_probes")
            col.prop(ob.cubegi, "show_irradiance")
        elif ob is not None and ob.type == "LIGHT":
            layout.prop(ob.data.cubegi, "shadow_size")
        elif ob is not None and ob.type == "MESH":
            col = layout.column(heading=ob.name)
            col.prop(ob.cubegi, "receive")
            col.prop(ob.cubegi, "contribute")
            col.prop(ob.cubegi, "dynamic")
        else:
            col.label(text=f"{len(grids)} probe grid objects" if grids else "Fitted to the scene (no grid object)")
        col.operator("cubegi.add_probe_grid", icon="LIGHTPROBE_VOLUME")
        layout.row().prop(settings, "quality", expand=True)
        for section in SECTIONS:
            col = layout.column(heading=section)
            for o in OPTIONS:
                if o.section == section:
                    col.prop(settings, o.name)
        layout.prop(settings, "lit")
        row = layout.row(align=True)
        row.operator("cubegi.bake", icon="RENDER_STILL")
        row.operator("cubegi.bake", text="Bake Selected", icon="RESTRICT_SELECT_OFF").selected_only = True
        row.operator("cubegi.clear", icon="TRASH")
        row = layout.row(align=True)
        row.operator("cubegi.update_light", icon="LIGHT")
        row.operator("cubegi.bake_animation", icon="RENDER_ANIMATION")
        row.prop(settings, "live", toggle=True, icon="PLAY")
        if settings.last_update:
            layout.label(text=settings.last_update)


class VIEW3D_PT_cubegi_display(_SidebarTab, bpy.types.Panel):
    """Which baked light the viewport shows, and showing it in renders."""

    bl_label = "Display"
    bl_parent_id = "VIEW3D_PT_cubegi"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings = context.scene.cubegi
        layout.prop(settings, "display")
        if settings.display == "BOUNCE":
            layout.prop(settings, "display_bounce")
        row = layout.row(align=True)
        row.operator("cubegi.wire_materials", icon="MATERIAL")
        row.operator("cubegi.unwire_materials", icon="X")


class VIEW3D_PT_cubegi_report(_SidebarTab, bpy.types.Panel):
    """The last bake's report: time, bounces, estimated remaining error."""

    bl_label = "Last Bake"
    bl_parent_id = "VIEW3D_PT_cubegi"

    def draw(self, context):
        lines = report_lines(context.scene)
        col = self.layout.column(align=True)
        for line in lines or ["no bake yet"]:
            col.label(text=line.strip())
        if lines:
            self.layout.operator("cubegi.open_report", icon="TEXT")


classes = (VIEW3D_PT_cubegi, VIEW3D_PT_cubegi_display, VIEW3D_PT_cubegi_report)
register, unregister = bpy.utils.register_classes_factory(classes)
