"""The extension's preferences: what new probe grids start with and how probes are drawn.

Preferences belong to the user, not the file, so nothing a bake computes depends on them
(the shadow-map sizes are the file's: Scene and Light settings). :func:`get` returns them,
or their defaults when the extension was registered without being enabled (scripts that
load it by hand).
"""

import bpy
from bpy.props import FloatProperty, IntVectorProperty

# The extension's module name: "cubegi" from source, "bl_ext.<repo>.cubegi" when installed.
ADDON = __package__.rpartition(".")[0]


class CubeGIPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON

    grid_resolution: IntVectorProperty(
        name="New Grid Resolution", description="Probes along X, Y and Z of a newly added probe grid",
        size=3, default=(4, 4, 2), min=1, max=256,
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


class _Defaults:
    """The preferences' defaults, for when the extension is not enabled as an add-on."""

    def __getattr__(self, name):
        value = CubeGIPreferences.__annotations__[name].keywords["default"]
        return tuple(value) if isinstance(value, (list, tuple)) else value


def get(context=None):
    """The extension's preferences (or their defaults)."""
    addon = (context or bpy.context).preferences.addons.get(ADDON)
    return addon.preferences if addon is not None and addon.preferences is not None else _Defaults()


classes = (CubeGIPreferences,)
register, unregister = bpy.utils.register_classes_factory(classes)
