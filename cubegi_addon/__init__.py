"""CubeGI's Blender side: properties, operators, the GPU capture and the bpy glue.

Registers in dependency order (preferences, properties, operators, panel, viewport drawing)
and unregisters in reverse. Importing this package imports no bpy: the command line
(:mod:`.cli`) checks its arguments and paths before Blender starts.
"""

import importlib

# Registered in this order, unregistered in reverse.
MODULES = ("prefs", "props", "operators", "panel", "probe_view", "session", "live", "animation", "command")


def _modules():
    return [importlib.import_module(f".{name}", __name__) for name in MODULES]


def register():
    for m in _modules():
        m.register()


def unregister():
    for m in reversed(_modules()):
        m.unregister()
