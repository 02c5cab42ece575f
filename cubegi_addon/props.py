"""CubeGI's settings on scenes (``Scene.cubegi``), objects (``Object.cubegi``: probe grids,
Receive, Contribute, Dynamic) and lights (``Light.cubegi``: the shadow-map size), all saved in
the file."""

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, IntVectorProperty, PointerProperty, StringProperty

from ..cubegi_engine.settings import MAX_BOUNCES, OPTIONS, QUALITY, BakeSettings
from . import attributes, display, live, session

LIT_ITEMS = attributes.LIT_ITEMS


QUALITY_ITEMS = (
    ("DRAFT", "Draft", "4 cells along the longest side, 16^2 faces, 3 bounces: the fastest look"),
    ("BALANCED", "Balanced", "8 cells, 16^2 faces, 5 bounces: the default"),
    ("FINAL", "Final", "12 cells, 32^2 faces, 5 bounces: the lowest error, about 5x the time"),
)


def bake_settings(scene, given=None):
    """The BakeSettings a bake of ``scene`` uses: the values in ``given`` (name -> value, what
    an operator call or the command line set), then those of a ``quality`` preset among
    them, then the scene's own CubeGI settings, which are saved in the file (an option not
    in the file: its default)."""
    given = dict(given or {})
    quality = given.pop("quality", None)
    preset = QUALITY[str(quality).upper()] if quality else {}
    s = scene.cubegi
    values = {}
    for o in OPTIONS:
        if o.name in given or o.name in preset:
            values[o.name] = o.given(given[o.name] if o.name in given else preset[o.name])
        elif o.section is not None:
            values[o.name] = o.given(getattr(s, o.name))
    return BakeSettings(**values)


def _property(o, operator):
    """The bpy property of the option ``o``: the scene's (held to the option's range) or the
    operator's (a soft range: validate refuses a script's bad value with the reason)."""
    description = f"{o.help} (default: the scene's setting)" if operator and o.section else o.help
    kw = dict(name=o.label, description=description, default=o.stored(o.default))
    if o.kind is bool:
        return BoolProperty(**kw)
    if o.subtype != "NONE":
        kw["subtype"] = o.subtype
        if o.subtype == "DISTANCE":
            kw["unit"] = "LENGTH"
    low, high = ("soft_min", "soft_max") if operator else ("min", "max")
    if o.minimum is not None:
        kw[low] = o.minimum
    if o.maximum is not None:
        kw[high] = o.maximum
    if o.soft_maximum is not None:
        kw["soft_max"] = o.soft_maximum
    return (IntProperty if o.kind is int else FloatProperty)(**kw)


def with_bake_options(cls, operator=False):
    """``cls`` (a property group or an operator) with a property for every bake option
    (for a property group, the options saved in the file), before it is registered."""
    made = {o.name: _property(o, operator) for o in OPTIONS if operator or o.section is not None}
    cls.__annotations__ = {**made, **cls.__annotations__}
    return cls


def _apply_quality(settings, context):
    """Write the chosen preset's values into the settings (they stay editable)."""
    for name, value in QUALITY[settings.quality].items():
        setattr(settings, name, value)


class CubeGISceneSettings(bpy.types.PropertyGroup):
    quality: EnumProperty(
        name="Quality", description="Set the grid cells, cube-map size and bounces to a preset (from the benchmark's "
        "error-time front); each stays editable", items=QUALITY_ITEMS, default="BALANCED", update=_apply_quality,
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


with_bake_options(CubeGISceneSettings)


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
