"""Test set-up: real bpy in background mode, the extension loaded from this source tree.

Blender's user folder is redirected to a temporary one so the tests never touch the
user's configuration. Each test that uses the scene starts from an empty factory file.
"""

import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_USER = tempfile.mkdtemp(prefix="cubegi-test-user-")
os.environ.setdefault("BLENDER_USER_RESOURCES", _USER)
sys.path.insert(0, ROOT)

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def cubegi():
    """The extension package (``cubegi``), registered."""
    from cubegi_engine.cli import load_extension

    return load_extension()


@pytest.fixture
def empty_scene(cubegi):
    """An empty factory file with the extension registered."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene
