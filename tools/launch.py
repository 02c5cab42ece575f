"""The source tree loaded as the extension package ``cubegi``, the name Blender gives it when
installed from source, so that every module is loaded once, under that one name.

Scripts and tests outside the package (``tests/``, ``benchmarks/``, ``tools/``) load CubeGI
through :func:`load_extension` and import its modules as ``cubegi.cubegi_engine.*`` and
``cubegi.cubegi_addon.*``; ``python -m cubegi_engine`` runs :mod:`tools.cli`, which does the
same.
"""

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
    if register:
        module.register_in_process()
    return module
