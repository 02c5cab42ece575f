"""``python -m cubegi_engine ...``: the command line of CubeGI's source tree, which lives in
``tools/cli.py`` (it drives Blender and adds the source tree's commands to the add-on's)."""

import os
import signal
import sys

if __name__ == "__main__":
    # A cluster worker starts its bakes with Ctrl-C ignored (cubegi_addon.cluster): a bake
    # stops on it all the same, from its first step (importing bpy takes a second or two).
    if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    # This package was imported only to run this file: every CubeGI module loads once, as
    # ``cubegi.*`` (tools/launch.py).
    sys.modules.pop(__package__ or "cubegi_engine", None)
    try:
        from tools.cli import main
    except KeyboardInterrupt:  # Ctrl-C while CubeGI loads
        print("cubegi: interrupted; nothing was written", file=sys.stderr)
        sys.exit(128 + signal.SIGINT)
    except ModuleNotFoundError as exc:
        if exc.name != "tools":
            raise
        # An installed extension (this file ships with the engine; tools/ does not).
        print("cubegi: error: python -m cubegi_engine runs from CubeGI's source tree; in Blender, run "
              "blender -c cubegi ...", file=sys.stderr)
        sys.exit(2)
    sys.exit(main())
