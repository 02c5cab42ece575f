"""CubeGI's Blender side: properties, operators, the GPU capture and the bpy glue.

Registers in dependency order (properties, then operators) and unregisters in reverse.
"""

from . import attributes, operators, pipeline, props, reference, scene_data

_modules = (props, operators)


def register():
    for m in _modules:
        m.register()


def unregister():
    for m in reversed(_modules):
        m.unregister()
