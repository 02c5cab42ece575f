"""``python -m cubegi_engine ...``: forwards to the command line, which lives in the add-on
(:mod:`cubegi_addon.cli`) because it drives Blender.

:func:`load_extension` loads this source tree as the extension package ``cubegi`` (the name
Blender gives it when installed from source). Every module is then loaded once, under that
one name: this engine package, already imported as ``cubegi_engine`` to run this file, is
the same object as ``cubegi.cubegi_engine``. Scripts and tests outside the package
(``tests/``, ``benchmarks/``) load CubeGI through this function too and import its modules
as ``cubegi.cubegi_engine.*`` and ``cubegi.cubegi_addon.*``.
"""

import atexit
import importlib.util
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGE = "cubegi"


def load_extension(register=True):
    """The extension package ``cubegi`` from this source tree; registered in Blender if
    ``register`` (which needs bpy; loading alone does not)."""
    module = sys.modules.get(PACKAGE)
    if module is None:
        spec = importlib.util.spec_from_file_location(
            PACKAGE, os.path.join(ROOT, "__init__.py"), submodule_search_locations=[ROOT]
        )
        module = importlib.util.module_from_spec(spec)
        sys.modules[PACKAGE] = module
        spec.loader.exec_module(module)
        engine = sys.modules.get(__package__ or "cubegi_engine")
        if engine is not None and os.path.dirname(os.path.abspath(engine.__file__)) == os.path.join(ROOT, "cubegi_engine"):
            # This package is already loaded (as ``cubegi_engine``, to run this file): one module,
            # two names. Its own name becomes the package's, so that ``from ..cubegi_engine
            # import x`` (which imports ``<the package's __name__>.x``) loads x once, as
            # ``cubegi.cubegi_engine.x``, like every relative import does.
            sys.modules[f"{PACKAGE}.cubegi_engine"] = engine
            engine.__name__ = engine.__package__ = f"{PACKAGE}.cubegi_engine"
            module.cubegi_engine = engine
    if register and not getattr(module, "_registered", False):
        module.register()
        module._registered = True
        atexit.register(_unregister_at_exit, module)
    return module


def _unregister_at_exit(module):
    """Unregister before Python ends, as Blender itself disables every add-on on quitting
    (``bpy.utils._on_exit()``; with the ``bpy`` module, from bpy's own ``atexit`` hook, for
    the add-ons it enabled). This loader registers the package itself, so it unregisters it
    too. Left registered, the handlers and classes keep the ``bpy`` module alive past the
    interpreter's end; on 4.5 LTS bpy's teardown then runs in C++ static destructors and the
    process crashes (a draw handler freed without an interpreter, status 139) or hangs (its
    audio thread's condition variable destroyed while waited on)."""
    if getattr(module, "_registered", False):
        module.unregister()
        module._registered = False


if __name__ == "__main__":
    import signal

    # A cluster worker starts its bakes with Ctrl-C ignored (cubegi_addon.cluster): a bake
    # stops on it all the same, from its first step (importing bpy takes a second or two).
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        load_extension(register=False)
        cli = importlib.import_module(f"{PACKAGE}.cubegi_addon.cli")
    except KeyboardInterrupt:  # Ctrl-C while Blender loads
        print("cubegi: interrupted; nothing was written", file=sys.stderr)
        sys.exit(128 + signal.SIGINT)
    sys.exit(cli.main())
