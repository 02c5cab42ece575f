"""Which baked layer the viewport shows, and the 3D views' shading that shows it.

Showing a layer makes it the active colour attribute of every baked mesh and sets every 3D
view to Solid shading with colours from the attribute. :func:`view_state` and
:func:`restore_views` let a cancelled bake put the views back as they were.
"""

import bpy

from . import attributes

# Scene.cubegi.display -> attribute name (BOUNCE takes Scene.cubegi.display_bounce).
LAYERS = {
    "TOTAL": attributes.TOTAL,
    "DIRECT": attributes.DIRECT,
    "INDIRECT": attributes.INDIRECT,
    "LIT": attributes.LIT,
}

ITEMS = (
    ("TOTAL", "Total", "Direct plus indirect light (CubeGI_total)"),
    ("DIRECT", "Direct", "Direct light (CubeGI_direct)"),
    ("INDIRECT", "Indirect", "Indirect light, all bounces (CubeGI)"),
    ("BOUNCE", "Bounce", "The light of one bounce (CubeGI_bounce_k)"),
    ("LIT", "Lit Color", "Albedo times all light (CubeGI_lit), as exported"),
)


def layer_name(settings):
    """The attribute name a scene's display setting asks for."""
    if settings.display == "BOUNCE":
        return attributes.bounce_name(settings.display_bounce)
    return LAYERS[settings.display]


def baked_meshes(scene):
    """The distinct, local meshes of the scene's objects that hold CubeGI's attributes."""
    seen = {}
    for ob in scene.objects:
        if ob.type == "MESH" and ob.data.library is None and attributes.owned(ob.data):
            seen.setdefault(ob.data.name, ob.data)
    return list(seen.values())


def view_spaces():
    """Every 3D view space in the open screens."""
    return [
        space
        for screen in bpy.data.screens
        for area in screen.areas
        if area.type == "VIEW_3D"
        for space in area.spaces
        if space.type == "VIEW_3D"
    ]


def view_state():
    return [(space, space.shading.type, space.shading.color_type) for space in view_spaces()]


def restore_views(state):
    for space, shading_type, color_type in state:
        space.shading.type = shading_type
        space.shading.color_type = color_type


def show(scene):
    """Show the chosen layer; returns how many meshes have it (0: nothing to show yet)."""
    name = layer_name(scene.cubegi)
    shown = 0
    for mesh in baked_meshes(scene):
        if name in mesh.color_attributes:
            mesh.color_attributes.active_color_name = name
            shown += 1
    if shown:
        for space in view_spaces():
            if space.shading.type not in {"MATERIAL", "RENDERED"}:
                space.shading.type = "SOLID"
            space.shading.color_type = "VERTEX"
    return shown


def on_display_change(settings, context):
    """Update callback of Scene.cubegi.display and display_bounce."""
    show(settings.id_data)
