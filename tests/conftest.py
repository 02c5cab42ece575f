"""Test set-up shared by both folders: this source tree loaded as the extension package
``cubegi`` (one copy of every module; see ``tools/launch.py``).

``tests/engine`` holds the engine's pure-numpy tests and runs without bpy;
``tests/blender`` holds the tests that drive real Blender (bpy, the GPU module on llvmpipe,
Cycles) and is skipped where bpy is missing. Blender's user folder is redirected to a
temporary one so the tests never touch the user's configuration.
"""

import atexit
import os
import shutil
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if "BLENDER_USER_RESOURCES" not in os.environ:
    os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="cubegi-test-user-")
    atexit.register(shutil.rmtree, os.environ["BLENDER_USER_RESOURCES"], ignore_errors=True)
sys.path.insert(0, ROOT)

from tools import load_extension  # noqa: E402

load_extension(register=False)
