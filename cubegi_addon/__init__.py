"""CubeGI's Blender side: properties, operators, the GPU capture and the bpy glue.

Registers in dependency order (preferences, properties, operators, panel, viewport drawing) and unregisters in reverse.
"""

from . import attributes, display, materials, operators, panel, pipeline, prefs, probe_view, props, reference, scene_data

_modules = (prefs, props, operators, panel, probe_view)


def register():
    for m in _modules:
        m.register()


def unregister():
    for m in reversed(_modules):
        m.unregister()
