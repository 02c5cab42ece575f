"""The extension's manifest passes Blender's own validator, and the package registers and
unregisters cleanly."""

import os
import subprocess
import sys

import bpy

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_manifest_validates_with_blenders_tool():
    tool = os.path.join(bpy.utils.system_resource("SCRIPTS"), "addons_core", "bl_pkg", "cli", "blender_ext.py")
    r = subprocess.run([sys.executable, tool, "validate", ROOT], capture_output=True, text=True)
    assert r.returncode == 0 and "Success" in r.stdout, r.stdout + r.stderr


def test_unregister_removes_everything_and_register_restores_it(cubegi):
    cubegi.unregister()
    try:
        assert not hasattr(bpy.types.Scene, "cubegi") and not hasattr(bpy.types.Object, "cubegi")
        assert getattr(bpy.types, "CUBEGI_OT_bake", None) is None
    finally:
        cubegi.register()
    assert hasattr(bpy.types.Scene, "cubegi")
    assert getattr(bpy.types, "CUBEGI_OT_bake", None) is not None
