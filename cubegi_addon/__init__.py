"""CubeGI's Blender side: properties, operators, the GPU capture and the bpy glue.

Registers in dependency order (properties, operators, panel) and unregisters in reverse.
"""

from . import attributes, operators, panel, pipeline, props, reference, scene_data

_modules = (props, operators, panel)


def register():
    for m in _modules:
        m.register()


def unregister():
    for m in reversed(_modules):
        m.unregister()
