"""CubeGI: diffuse global illumination from a grid of cube-map light probes, baked into
per-vertex colour attributes. The extension's entry point; see README.md."""

import atexit


def register():
    from . import cubegi_addon

    cubegi_addon.register()


def unregister():
    from . import cubegi_addon

    cubegi_addon.unregister()


_registered_in_process = False


def register_in_process():
    """Register in the ``bpy`` module, where no Blender start-up enables the extension (a
    ``python`` script, the command line run from the source tree), once per process, and
    unregister before Python ends, as Blender itself disables every add-on on quitting
    (``bpy.utils._on_exit()``). Left registered, the handlers and classes keep the ``bpy``
    module alive past the interpreter's end; on 4.5 LTS bpy's teardown then runs in C++
    static destructors and the process crashes (a draw handler freed without an interpreter,
    status 139) or hangs (its audio thread's condition variable destroyed while waited on)."""
    global _registered_in_process
    if not _registered_in_process:
        register()
        _registered_in_process = True
        atexit.register(_unregister_at_exit)


def _unregister_at_exit():
    global _registered_in_process
    if _registered_in_process:
        unregister()
        _registered_in_process = False
