"""Test set-up shared by both folders: this source tree loaded as the extension package
``cubegi`` (one copy of every module; see ``cubegi_engine/__main__.py``).

``tests/engine`` holds the engine's pure-numpy tests and runs without bpy;
``tests/blender`` holds the tests that drive real Blender (bpy, the GPU module on llvmpipe,
Cycles) and is skipped where bpy is missing. Blender's user folder is redirected to a
temporary one so the tests never touch the user's configuration.
"""

import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="cubegi-test-user-"))
sys.path.insert(0, ROOT)

from cubegi_engine.__main__ import load_extension  # noqa: E402

load_extension(register=False)
