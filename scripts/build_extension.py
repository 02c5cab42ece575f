"""Build the installable extension zip with Blender's own extension tool.

Usage: python scripts/build_extension.py [OUT_DIR]   (default: dist/)

What goes in is set by ``[build] paths_exclude_pattern`` in blender_manifest.toml (tests,
scripts, benchmarks, docs and dev files stay out). The manifest is validated first. Prints
the zip's path.
"""

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def extension_tool():
    """Path of Blender's bundled ``blender_ext.py`` (ships inside the bpy module)."""
    import bpy

    return os.path.join(bpy.utils.system_resource("SCRIPTS"), "addons_core", "bl_pkg", "cli", "blender_ext.py")


def build(out_dir):
    tool = extension_tool()
    os.makedirs(out_dir, exist_ok=True)
    subprocess.run([sys.executable, tool, "validate", ROOT], check=True, stdout=subprocess.DEVNULL)
    before = set(os.listdir(out_dir))
    subprocess.run([sys.executable, tool, "build", "--source-dir", ROOT, "--output-dir", out_dir], check=True, stdout=subprocess.DEVNULL)
    made = sorted(set(os.listdir(out_dir)) - before) or sorted(f for f in os.listdir(out_dir) if f.endswith(".zip"))
    return os.path.join(out_dir, made[-1])


if __name__ == "__main__":
    print(build(os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "dist"))))
