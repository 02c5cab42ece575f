"""``blender -c cubegi ...``: the command line inside a stock Blender, on any OS, without the
``bpy`` module from PyPI.

Registered with ``bpy.utils.register_cli_command`` while the extension is enabled; it runs
the same :func:`.cli.main` as ``python -m cubegi_engine`` (the same options, messages and
exit statuses). ``demo`` and ``benchmark`` run from the source tree only (``tools/cli.py``).
"""

import bpy

COMMAND = "cubegi"
_handle = None


def execute(argv):
    """The command's entry: ``argv`` are the words after ``blender -c cubegi``."""
    from . import cli

    return cli.main(list(argv), prog=f"blender -c {COMMAND}")


def register():
    global _handle
    _handle = bpy.utils.register_cli_command(COMMAND, execute)


def unregister():
    global _handle
    if _handle is not None:
        bpy.utils.unregister_cli_command(_handle)
        _handle = None
