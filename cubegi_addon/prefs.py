"""The extension's preferences: defaults for new probe grids and the capture settings.

Preferences belong to the user, not the file: they set what new grids start with and how
finely lights' shadows are captured. :func:`get` returns them, or their defaults when the
extension was registered without being enabled (scripts that load it by hand).
"""

import bpy
from bpy.props import FloatProperty, IntProperty, IntVectorProperty

from ..cubegi_engine.settings import BakeSettings

# The extension's module name: "cubegi" from source, "bl_ext.<repo>.cubegi" when installed.
ADDON = __package__.rpartition(".")[0]


class CubeGIPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON

    grid_resolution: IntVectorProperty(
        name="New Grid Resolution", description="Probes along X, Y and Z of a newly added probe grid",
        size=3, default=(4, 4, 2), min=1, max=256,
    )
    shadow_size: IntProperty(
        name="Point and Spot Shadow Size", description="Shadow cube-map face size for point and spot lights",
        default=BakeSettings.shadow_size, min=16, max=4096,
    )
    sun_shadow_size: IntProperty(
        name="Sun Shadow Size", description="Shadow map size for sun lights", default=BakeSettings.sun_shadow_size, min=16, max=8192
    )
    area_shadow_size: IntProperty(
        name="Area Shadow Size", description="Shadow map size for each sample point of an area light",
        default=BakeSettings.area_shadow_size, min=16, max=2048,
    )
    sphere_scale: FloatProperty(
        name="Probe Sphere Size", description="Radius of the irradiance spheres drawn at probes, in grid cells",
        default=0.12, min=0.01, max=0.5,
    )

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        col = layout.column(heading="New Probe Grids")
        col.prop(self, "grid_resolution")
        col.prop(self, "sphere_scale")
        col = layout.column(heading="Capture")
        col.prop(self, "shadow_size")
        col.prop(self, "sun_shadow_size")
        col.prop(self, "area_shadow_size")


class _Defaults:
    """The preferences' defaults, for when the extension is not enabled as an add-on."""

    def __getattr__(self, name):
        value = CubeGIPreferences.__annotations__[name].keywords["default"]
        return tuple(value) if isinstance(value, (list, tuple)) else value


def get(context=None):
    """The extension's preferences (or their defaults)."""
    addon = (context or bpy.context).preferences.addons.get(ADDON)
    return addon.preferences if addon is not None and addon.preferences is not None else _Defaults()


def capture_settings(context=None):
    """The capture preferences as BakeSettings keyword arguments."""
    p = get(context)
    return {"shadow_size": p.shadow_size, "sun_shadow_size": p.sun_shadow_size, "area_shadow_size": p.area_shadow_size}


classes = (CubeGIPreferences,)
register, unregister = bpy.utils.register_classes_factory(classes)
