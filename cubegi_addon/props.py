"""CubeGI's settings on scenes (``Scene.cubegi``), objects (``Object.cubegi``: probe grids,
Receive, Contribute, Dynamic) and lights (``Light.cubegi``: the shadow-map size), all saved in
the file."""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, IntVectorProperty, PointerProperty, StringProperty

from ..cubegi_engine.settings import MAX_BOUNCES, MAX_CELLS, MAX_CUBE_SIZE, MIN_CUBE_SIZE, QUALITY, BakeSettings
from . import display, live, session

LIT_ITEMS = (
    ("NONE", "None", "Write no lit colour"),
    ("ALL", "Direct + Indirect", "CubeGI_lit = albedo x (direct + indirect light): the complete lighting, for export"),
    ("INDIRECT", "Indirect Only", "CubeGI_lit = albedo x indirect light: for engines that light directly themselves"),
)


QUALITY_ITEMS = (
    ("DRAFT", "Draft", "4 cells along the longest side, 16^2 faces, 3 bounces: the fastest look"),
    ("BALANCED", "Balanced", "8 cells, 16^2 faces, 5 bounces: the default"),
    ("FINAL", "Final", "12 cells, 32^2 faces, 5 bounces: the lowest error, about 5x the time"),
)


# The scene settings a bake reads (BakeSettings fields of the same names).
BAKE_FIELDS = ("cube_size", "bounces", "cells", "visibility", "tolerance", "add_tail", "capture_triangles", "near_field",
               "move_probes", "sky_per_vertex", "shadow_size", "sun_shadow_size", "area_shadow_size", "probe_spacing")


def bake_settings(scene, given=None, **fixed):
    """The BakeSettings a bake of ``scene`` uses: the values in ``given`` (name -> value, what
    an operator call or the command line set), then those of a ``quality`` preset among
    them, then the scene's own CubeGI settings, which are saved in the file. ``fixed``: other
    BakeSettings fields. Tolerance and Capture Triangles of 0 mean none."""
    given = dict(given or {})
    quality = given.pop("quality", None)
    preset = QUALITY[str(quality).upper()] if quality else {}
    s = scene.cubegi
    values = {name: given[name] if name in given else preset[name] if name in preset else getattr(s, name) for name in BAKE_FIELDS}
    values["tolerance"] = values["tolerance"] or None
    values["capture_triangles"] = values["capture_triangles"] or None
    values["probe_spacing"] = values["probe_spacing"] or None
    return BakeSettings(**values, **fixed)


def _apply_quality(settings, context):
    """Write the chosen preset's values into the settings (they stay editable)."""
    for name, value in QUALITY[settings.quality].items():
        setattr(settings, name, value)


class CubeGISceneSettings(bpy.types.PropertyGroup):
    quality: EnumProperty(
        name="Quality", description="Set the grid cells, cube-map size and bounces to a preset (from the benchmark's "
        "error-time front); each stays editable", items=QUALITY_ITEMS, default="BALANCED", update=_apply_quality,
    )
    cells: IntProperty(
        name="Grid Cells", description="Cells along the longest side of the grid fitted to the scene (when it has no "
        "probe grid object)", default=BakeSettings.cells, min=1, max=MAX_CELLS,
    )
    probe_spacing: FloatProperty(
        name="Probe Spacing", description="Distance between the probes of the grid fitted to the scene (0: Grid Cells sets it)",
        default=0.0, min=0.0, soft_max=10.0, subtype="DISTANCE", unit="LENGTH",
    )
    cube_size: IntProperty(
        name="Cube-Map Size",
        description="Edge length in texels of each probe's cube-map faces",
        default=BakeSettings.cube_size,
        min=MIN_CUBE_SIZE,
        max=MAX_CUBE_SIZE,
    )
    bounces: IntProperty(
        name="Bounces", description="Number of indirect bounces to compute (at most; Tolerance can stop earlier)",
        default=BakeSettings.bounces, min=0, max=MAX_BOUNCES,
    )
    visibility: BoolProperty(
        name="Probe Visibility",
        description="Leave out, per vertex, the probes that cannot see it (stops light leaking through thin walls)",
        default=BakeSettings.visibility,
    )
    tolerance: FloatProperty(
        name="Tolerance",
        description="Stop once the estimated missing share of the indirect light is below this; Bounces is the cap (0: run all bounces)",
        default=0.0, min=0.0, max=0.5, subtype="FACTOR",
    )
    add_tail: BoolProperty(
        name="Add Tail", description="Add the estimated light after the last bounce to CubeGI (the total)", default=BakeSettings.add_tail
    )
    capture_triangles: IntProperty(
        name="Capture Triangles",
        description="The probes draw a simplified copy of the scene with at most about this many triangles (0: the full "
        "scene). Direct light, shadows and the baked vertices always use every triangle",
        default=BakeSettings.capture_triangles, min=0, soft_max=1_000_000,
    )
    near_field: BoolProperty(
        name="Near Field",
        description="Gather each vertex's near surroundings (surfaces within a quarter of a cell: where walls meet, under "
        "furniture) by rays, instead of the probes' view of them from up to a cell away",
        default=BakeSettings.near_field,
    )
    move_probes: BoolProperty(
        name="Move Probes Out",
        description="Move probes found inside geometry (walls, furniture) out of it, within their cells, before the "
        "capture; a probe with no way out is left out. Off: every probe stays at its cell centre",
        default=BakeSettings.move_probes,
    )
    sky_per_vertex: BoolProperty(
        name="Sky per Vertex",
        description="Shadow the sky at every vertex along 256 lines of sight of its own, instead of through the "
        "probes: the sky's contact shadows and open edges exact to a few per cent, at several times a small bake's "
        "time (it grows with vertices x directions)",
        default=BakeSettings.sky_per_vertex,
    )
    shadow_size: IntProperty(
        name="Point and Spot Shadows", description="Shadow cube-map face size of point and spot lights, in texels",
        default=BakeSettings.shadow_size, min=16, max=4096, subtype="PIXEL",
    )
    sun_shadow_size: IntProperty(
        name="Sun Shadows", description="Shadow map size of sun lights, in texels", default=BakeSettings.sun_shadow_size,
        min=16, max=8192, subtype="PIXEL",
    )
    area_shadow_size: IntProperty(
        name="Area Shadows", description="Shadow map size of each sample point of an area light, in texels",
        default=BakeSettings.area_shadow_size, min=16, max=2048, subtype="PIXEL",
    )
    lit: EnumProperty(
        name="Lit Color", description="Also write CubeGI_lit, the lit color that glTF export carries as COLOR_0",
        items=LIT_ITEMS, default="NONE",
    )
    display: EnumProperty(
        name="Display", description="Which baked light the viewport shows (as the meshes' active color attribute)",
        items=display.ITEMS, default="TOTAL", update=display.on_display_change,
    )
    display_bounce: IntProperty(
        name="Bounce", description="Which bounce to show", default=1, min=1, max=MAX_BOUNCES, update=display.on_display_change
    )
    last_report: StringProperty(name="Last Report", description="JSON report of the last bake", default="")
    live: BoolProperty(
        name="Live", description="After a bake, apply edits of lights, the world and materials at once, on the kept "
        "capture (no new capture); also on every frame of playback",
        default=False, update=live.on_live_toggle,
    )
    last_update: StringProperty(name="Last Update", description="What the last update did", default="")
    bake_id: StringProperty(
        name="Bake", description="Which bake made the light in this file (set by each bake; an undo step holds it, so "
        "the kept bake is used after undo only while it is the file's)", default="", options={"HIDDEN"},
    )
    animation_cache: StringProperty(
        name="Animation Cache", description="Folder of a baked animation's light, one file per frame (set by Bake "
        "Animation); each frame's light is shown when the frame changes", default="", subtype="DIR_PATH",
        options={"PATH_SUPPORTS_BLEND_RELATIVE"},
    )


class CubeGIObjectSettings(bpy.types.PropertyGroup):
    is_probe_grid: BoolProperty(name="Probe Grid", description="This Empty's cube is a CubeGI probe grid", default=False)
    dynamic: BoolProperty(
        name="Dynamic", description="Left out of the capture and lit from the kept probe field: moving or deforming it "
        "updates its light at once, without a new bake (it does not shadow or light the rest of the scene). "
        "Turning it on or off needs a new bake",
        default=False, update=lambda settings, context: session.forget(context.scene),
    )
    receive: BoolProperty(
        name="Receive", description="Bake CubeGI's light into this mesh (off: it keeps the light it has, and still lights "
        "and shadows the rest)", default=True,
    )
    contribute: BoolProperty(
        name="Contribute", description="This object shadows the rest, passes light on and is seen by the probes (off: it "
        "is lit as a dynamic object is, invisible to the probes and to shadows)",
        default=True, update=lambda settings, context: session.forget(context.scene),
    )
    resolution: IntVectorProperty(
        name="Resolution", description="Probes along X, Y and Z", size=3, default=(4, 4, 2), min=1, max=256, subtype="XYZ"
    )
    show_probes: BoolProperty(name="Show Probes", description="Draw this grid's probes in the viewport", default=True)
    show_irradiance: BoolProperty(
        name="Show Irradiance", description="After a bake, draw each probe as a small sphere shaded with its light", default=True
    )


class CubeGILightSettings(bpy.types.PropertyGroup):
    shadow_size: IntProperty(
        name="CubeGI Shadow Size", description="This light's shadow-map size in texels (0: the scene's for its type)",
        default=0, min=0, max=8192, subtype="PIXEL",
    )


classes = (CubeGISceneSettings, CubeGIObjectSettings, CubeGILightSettings)
_register, _unregister = bpy.utils.register_classes_factory(classes)


def register():
    _register()
    bpy.types.Scene.cubegi = PointerProperty(type=CubeGISceneSettings)
    bpy.types.Object.cubegi = PointerProperty(type=CubeGIObjectSettings)
    bpy.types.Light.cubegi = PointerProperty(type=CubeGILightSettings)


def unregister():
    del bpy.types.Light.cubegi
    del bpy.types.Object.cubegi
    del bpy.types.Scene.cubegi
    _unregister()
